"""Process-wide thread defaults for BLAS and Clarabel, whatever was imported first.

Every matrix the suite factors in its default work is small, and its workers run side by side
on a few cores: multi-threaded BLAS only adds overhead there, and busy-waiting BLAS threads slow
the other workers. ``RAYON_NUM_THREADS``: Clarabel (through faer and Rayon) starts a thread pool
at its first solve, and a worker forked from a process whose pool had started waits forever in
its first solve (the pool's threads do not exist in the child); one Rayon thread keeps every
solve on the calling thread.

The environment variables are set (when not set already) for libraries loaded later; BLAS
libraries already loaded (numpy imported before :mod:`bench`) are limited at once by
threadpoolctl, to ``OPENBLAS_NUM_THREADS`` (1 unless the user set it). Forked workers inherit
the limit.
"""

import os
import sys

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "RAYON_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def blas_threads() -> int:
    """The suite's BLAS thread count: ``OPENBLAS_NUM_THREADS`` (default 1)."""
    try:
        return max(1, int(os.environ.get("OPENBLAS_NUM_THREADS", "1")))
    except ValueError:
        return 1


def limit_blas() -> None:
    """Limit the BLAS libraries loaded in this process to :func:`blas_threads` (threadpoolctl)."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=blas_threads(), user_api="blas")


if "numpy" in sys.modules:  # too late for the environment: numpy's BLAS is loaded already
    limit_blas()

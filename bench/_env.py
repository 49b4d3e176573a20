"""Process-wide thread defaults for BLAS and Clarabel, whatever was imported first.

One BLAS thread (the suite's matrices are small and its workers share the cores) and one Rayon
thread (a worker forked after Clarabel's thread pool started would wait forever in its first
solve): set in the environment unless already set, and applied by threadpoolctl to a BLAS that
numpy loaded before :mod:`bench`.
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

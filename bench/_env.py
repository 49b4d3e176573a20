"""Process-wide thread defaults for BLAS and Clarabel, whatever was imported first.

One BLAS thread and one Rayon thread (a worker forked after Clarabel's thread pool started would
wait forever in its first solve): set in the environment unless already set, and applied by
threadpoolctl to a BLAS that numpy loaded before :mod:`bench`.
"""

import os
import sys

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "RAYON_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


if "numpy" in sys.modules:  # too late for the environment: numpy's BLAS is loaded already
    from threadpoolctl import threadpool_limits

    try:
        _threads = max(1, int(os.environ.get("OPENBLAS_NUM_THREADS", "1")))
    except ValueError:  # not an integer: one thread
        _threads = 1
    threadpool_limits(limits=_threads, user_api="blas")


def cores() -> int:
    """The CPU cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


#: Below this matrix size :func:`parallel` runs serially: starting threads costs more than the work.
PARALLEL_FROM_N = 256


def parallel(calls: list, n: int = PARALLEL_FROM_N) -> list:
    """Run zero-argument callables concurrently in threads and return their results in order.

    For independent dense linear algebra on matrices of size ``n`` (LAPACK and BLAS release the GIL).
    Serial on one core or below :data:`PARALLEL_FROM_N`. An exception in a call is raised here.
    """
    if len(calls) < 2 or cores() < 2 or n < PARALLEL_FROM_N:
        return [c() for c in calls]
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=min(len(calls), cores())) as pool:
        return list(pool.map(lambda c: c(), calls))

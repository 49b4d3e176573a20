"""Cores and threads: :func:`cores` (the CPU cores this process may run on) and :func:`parallel` (independent
dense linear algebra in threads). The BLAS and Rayon thread counts themselves are set when :mod:`bench` is
imported (one each, unless the environment says otherwise).
"""

from __future__ import annotations

import os

__all__ = ["PARALLEL_FROM_N", "cores", "parallel"]


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

"""Process-wide thread defaults for BLAS and Clarabel, whatever was imported first.

One BLAS thread and one Rayon thread (a worker forked after Clarabel's thread pool started would
wait forever in its first solve): set in the environment unless already set, and applied by
threadpoolctl to a BLAS that numpy loaded before :mod:`bench`. Importing :mod:`bench` (or ``plants``,
``designs``) runs this first. The cores and the thread helper are public in :mod:`bench.threads`.
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


# the public home of these names is bench.threads; kept here for the modules of bench that import them from _env
from bench.threads import PARALLEL_FROM_N, cores, parallel  # noqa: E402,F401

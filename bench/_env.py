"""Process-wide defaults set before numpy (and Clarabel) first start their thread pools.

Every matrix in this suite is small (n <= ~100 for the SDPs): multi-threaded BLAS only adds
overhead, and with another busy core (a second worker of ``--jobs 2``, or any other process)
OpenBLAS threads busy-wait. Measured on 2 cores: ``scipy.linalg.expm`` of a 4 x 4 matrix took
6 ms per call under load with 2 BLAS threads and ~0.1 ms with 1; an EKF run went from 14.5 s
to 1.1 s.

``RAYON_NUM_THREADS``: Clarabel (through faer and Rayon) starts a thread pool at its first
solve. The harness forks its workers (:mod:`bench.executors`), and a worker forked from a
process whose pool had started waits forever inside its first Clarabel solve (the pool's
threads do not exist in the child). One Rayon thread keeps every solve on the calling thread,
so nothing is inherited; the suite's SDPs are too small to gain from more.

The defaults apply only when the variables are not already set, and only before the pools
start: import :mod:`bench` before solving anything with Clarabel in the same process.
"""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "RAYON_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

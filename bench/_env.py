"""Process-wide defaults set before numpy is first imported.

Every matrix in this suite is small (n <= ~100): multi-threaded BLAS only adds overhead, and
with another busy core (a second worker of ``--jobs 2``, or any other process) OpenBLAS threads
busy-wait. Measured on 2 cores: ``scipy.linalg.expm`` of a 4 x 4 matrix took 6 ms per call under
load with 2 BLAS threads and ~0.1 ms with 1; an EKF run went from 14.5 s to 1.1 s. The defaults
below apply only when the variables are not already set.
"""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

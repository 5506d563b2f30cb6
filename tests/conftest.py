"""Test-session settings.

One BLAS thread: the filters' matrices are small, and on a 2-core machine
OpenBLAS's threads cost far more in synchronisation than they gain (a 53x53
covariance took 30 ms with two threads, 0.09 ms with one). Set before numpy
is imported by any test module.
"""

import os

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

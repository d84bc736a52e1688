"""camcal's tests, mirroring the package (docs/testing.md).

The suite runs on two xdist workers sharing two cores, so each process runs BLAS on one thread: OpenBLAS's own
threads would spin against the other worker's and only add CPU time. Set here, before any test module imports
numpy; a value the caller set is kept.
"""

import os

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

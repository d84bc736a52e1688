"""camcal's tests, mirroring the package (docs/testing.md).

Two settings for the test run, made here before any test module imports numpy or camcal (a value the caller set
for the BLAS threads is kept):

- the suite runs on two xdist workers sharing two cores, so each process runs BLAS on one thread: OpenBLAS's own
  threads would spin against the other worker's and only add CPU time;
- the suite starts a few hundred Python processes (CLI subprocesses, notebook kernels), so compiled modules are
  cached (``__pycache__``, ignored by git) even where the environment asks Python not to write them: otherwise
  every one of those processes compiles camcal's modules again.
"""

import os
import sys

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_name, "1")
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
sys.dont_write_bytecode = False

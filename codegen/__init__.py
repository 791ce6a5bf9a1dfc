"""printer-codegen: host-side motion maths, firmware that only plays tables back."""

import os

# numpy's BLAS would run its small matrix products (4 x 4 kinematics over millions of rows) on every core, and
# its waiting threads spin: twice the CPU for no gain, and a core taken from codegen/overlap.py. Set before numpy
# loads; a user's own setting wins.
for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

__version__ = "0.1.0"

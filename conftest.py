"""The test session's set-up, loaded before any test module imports numpy.

One BLAS thread, as the `pencilcal` command line runs (cli/entry.py): the tests' own work is
small matrices, and OpenBLAS's spinning threads only slow a machine whose cores are shared.
"""
import os

for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS"):
    os.environ.setdefault(_var, "1")

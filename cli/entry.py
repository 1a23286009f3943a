"""The `pencilcal` console script: the stop signals' first handlers, then the command line.

A signal that arrives while Python imports the command line (a few tenths of a second,
before any work) ends the process at once with pencilcal's one line and the status a shell
expects (130 for Ctrl-C, 143 for SIGTERM), not with a traceback of the import;
`main.main` then installs the handlers that clean up on the way out.
"""
from __future__ import annotations

import os
import signal

_WORDS = {signal.SIGINT: b"interrupted", signal.SIGTERM: b"terminated", getattr(signal, "SIGHUP", -1): b"hung up"}


#: The BLAS libraries' thread-count variables (OpenBLAS, as numpy's wheels carry; MKL; Apple's).
_BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS")


def _before_any_work(signum, frame):
    os.write(2, b"pencilcal: error: " + _WORDS.get(signum, b"stopped") + b"\n")
    os._exit(128 + signum)


def main():
    for s in _WORDS:
        if s > 0 and signal.getsignal(s) is not signal.SIG_IGN:
            signal.signal(s, _before_any_work)
    # One BLAS thread unless the user asks for more, set before numpy loads: pencilcal's
    # parallelism is its own (decoding and overlay threads, --workers processes), and
    # OpenBLAS's spinning threads fight them and any other job for the cores (a calibration
    # of 24 da Vinci views took 23-47 s with the default threads against 6-11 s with one, on
    # the 2-core development machine with other jobs running: docs/performance.md).
    for var in _BLAS_THREADS:
        os.environ.setdefault(var, "1")
    from pencilcal.cli.main import main as command_line

    return command_line()

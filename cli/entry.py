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


def _before_any_work(signum, frame):
    os.write(2, b"pencilcal: error: " + _WORDS.get(signum, b"stopped") + b"\n")
    os._exit(128 + signum)


def main():
    for s in _WORDS:
        if s > 0 and signal.getsignal(s) is not signal.SIG_IGN:
            signal.signal(s, _before_any_work)
    from pencilcal.cli.main import main as command_line

    return command_line()

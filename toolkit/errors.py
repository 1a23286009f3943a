"""Exceptions pencilcal raises on purpose.

`InputError` is for anything the user can fix (a file, an option, a value); its message is
one line that names the file or value and the problem, and the command line prints it as is
and exits with status 1. `EstimationError` is raised where no estimate exists for the data
given (fewer than three spokes, all lines parallel, ...); per-frame commands catch it and
record ``ok: false`` with the message instead of stopping.
"""
from __future__ import annotations

__all__ = ["PencilcalError", "InputError", "EstimationError"]


class PencilcalError(Exception):
    """Base class of the errors pencilcal raises deliberately."""


class InputError(PencilcalError, ValueError):
    """Bad input the user can fix: message is one line naming the file/value and problem."""


class EstimationError(PencilcalError, ArithmeticError):
    """No estimate exists for these data (too few lines, degenerate geometry, ...)."""

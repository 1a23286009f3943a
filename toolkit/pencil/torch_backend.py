"""The optional torch dependency: whether it is there, the device, the dtype, tensors.

torch and kornia are optional (``pip install torch==2.13.0 && pip install -e ".[torch]"``);
they are imported only when a function here runs, never on import. Without them every
entry point of the torch paths (estimator_torch.py, points_torch.py) raises
`TorchUnavailableError` (an `InputError` and an `ImportError`) whose one-line message says
how to install them; `torch_available()` tells without raising.

Example
-------
>>> isinstance(torch_available(), bool)
True
>>> issubclass(TorchUnavailableError, ImportError)
True
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.errors import InputError

__all__ = ["INSTALL_HINT", "TorchUnavailableError", "torch_available", "import_torch", "require_torch",
           "resolve_device", "as_tensor", "torch_dtype"]

#: The command that installs the ``[torch]`` extra (torch pinned to the CPU build).
INSTALL_HINT = 'pip install torch==2.13.0 && pip install -e ".[torch]"'


class TorchUnavailableError(InputError, ImportError):
    """torch/kornia missing, or a CUDA device asked for where there is none.

    An `InputError` (the command line prints its one-line message and exits 1) and an
    `ImportError` (``except ImportError`` works as for any optional dependency).
    """


def torch_available() -> bool:
    """True when torch and kornia can be imported (the ``[torch]`` extra is installed)."""
    try:
        import_torch()
        return True
    except TorchUnavailableError:
        return False


def import_torch():
    """(torch, kornia) modules; TorchUnavailableError (one line, with `INSTALL_HINT`) if either
    is missing."""
    try:
        import torch  # noqa: F401
        import kornia  # noqa: F401
    except ImportError as e:
        missing = getattr(e, "name", None) or "torch"
        raise TorchUnavailableError(f"{missing} is not installed; the torch path needs it: {INSTALL_HINT}") from None
    return torch, kornia


def require_torch(device="cpu"):
    """Import torch (and kornia) and check `device`; return the torch module.

    Raises TorchUnavailableError with a one-line message naming the install command when
    torch/kornia are missing or when ``device`` is a CUDA device that torch cannot use.
    """
    torch, _ = import_torch()
    resolve_device(device)
    return torch


def resolve_device(device="cpu"):
    """``torch.device`` for "cpu", "cuda", "cuda:1" or a torch.device; raises
    TorchUnavailableError when CUDA is asked for and is not available."""
    torch, _ = import_torch()
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as e:
        raise InputError(f"unknown device {device!r}: {e}") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        build = "a CPU-only build" if torch.version.cuda is None else f"CUDA {torch.version.cuda}, but no GPU is visible"
        raise TorchUnavailableError(
            f"device {device!r} asked for, but torch {torch.__version__} is {build}: "
            f"use --device cpu, or install a CUDA build of torch on a machine with a GPU")
    return dev


def as_tensor(torch, v, dt, dev):
    """A tensor of dtype `dt` on device `dev` from array_like `v` of any shape (copied: numpy
    views may be read-only, which torch warns about); InputError if `v` is not numbers."""
    try:
        arr = np.array(v, dtype=float)
    except (TypeError, ValueError):
        raise InputError("expected an array of numbers") from None
    return torch.as_tensor(arr, dtype=dt, device=dev)


def torch_dtype(torch, dtype):
    """torch.float64 or torch.float32 for None (float64), "float64", "float32" or the torch
    dtype itself; InputError for anything else."""
    if dtype is None:
        return torch.float64
    if isinstance(dtype, str):
        if dtype not in ("float64", "float32"):
            raise InputError(f"dtype must be 'float64' or 'float32', got {dtype!r}")
        return getattr(torch, dtype)
    if dtype not in (torch.float64, torch.float32):
        raise InputError(f"dtype must be torch.float64 or torch.float32, got {dtype!r}")
    return dtype

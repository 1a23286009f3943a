"""The validation.json file (docs/formats.md): its writer, its readers and their checks.

`pencilcal validate` writes it (`write_validation`); `pencilcal report` reads it with
`load_validation` (frames and a summary, each an object) and `pencilcal experiment` with
`load_pencil_validation` (frames and a pencil of at least three spoke angles; the summary
is not needed there, so the experiments also run on `experiments.synthetic_validation`).
Every problem is an `InputError` of one line that names the file.

Example
-------
>>> import tempfile, pathlib
>>> path = pathlib.Path(tempfile.mkdtemp()) / "validation.json"
>>> write_validation(path, {"frames": [], "summary": {}, "pencil": {"angles_deg": [0, 20, 40]}})
>>> sorted(load_validation(path)), len(load_pencil_validation(path)["pencil"]["angles_deg"])
(['frames', 'pencil', 'summary'], 3)
>>> check_validation({"frames": []}, "v.json")  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
pencilcal.toolkit.errors.InputError: v.json: not a validation file (expected an object with a 'frames' list ...)
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import check_magnitudes, load_structured, write_json

__all__ = ["write_validation", "check_validation", "load_validation", "load_pencil_validation"]


def write_validation(path, data, force=False):
    """Write a validation dict (numpy inside is fine) as validation.json, atomically, never
    over an existing file unless `force` (`files.write_json`)."""
    write_json(path, data, force=force)


def check_validation(data, source="validation file"):
    """Raise InputError (naming `source`) unless `data` looks like a validation.json: an
    object with a 'frames' list of objects and a 'summary' object of objects, no number in
    it beyond files.MAX_MAGNITUDE (the report's figures and verdict overflowed on 1e308).
    Returns `data`."""
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list) \
            or not isinstance(data.get("summary"), dict):
        raise InputError(f"{source}: not a validation file (expected an object with a 'frames' list and a "
                         f"'summary', as `pencilcal validate` writes)")
    for i, fr in enumerate(data["frames"]):
        if not isinstance(fr, dict):
            raise InputError(f"{source}: frame {i} is not an object")
    for k, s in data["summary"].items():
        if not isinstance(s, dict):
            raise InputError(f"{source}: summary[{k!r}] is not an object")
    return check_magnitudes(data, source)


def load_validation(path):
    """Read and check a validation.json (`check_validation`); InputError naming the file on
    any problem (missing, a folder, not JSON, not a validation file)."""
    p = Path(path)
    if p.is_dir():
        raise InputError(f"{p}: is a folder, not a validation file")
    return check_validation(load_structured(p, "validation file"), str(p))


def load_pencil_validation(path):
    """Read a validation.json and check what a refit of the pencil's lines needs.

    Returns the dict. Raises InputError (one line) for a missing or unreadable file, or a
    file that is not a validation file (no ``frames`` list, no pencil spoke angles: at
    least three numbers in ``pencil.angles_deg``, in degrees). The summary is not needed.
    """
    data = load_structured(path, "validation file")
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
        raise InputError(f"{path}: not a validation file (no 'frames' list; write one with `pencilcal validate`)")
    pencil = data.get("pencil")
    if not isinstance(pencil, dict) or not isinstance(pencil.get("angles_deg"), list) or len(pencil["angles_deg"]) < 3:
        raise InputError(f"{path}: not a validation file (no pencil with at least three 'angles_deg')")
    try:
        np.asarray(pencil["angles_deg"], float)
    except (TypeError, ValueError):
        raise InputError(f"{path}: pencil 'angles_deg' must be numbers") from None
    return check_magnitudes(data, str(path))

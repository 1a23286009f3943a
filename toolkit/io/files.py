"""Reading structured files and writing outputs atomically, without clobbering.

Every writer in pencilcal goes through `atomic_write` (or `atomic_path` for libraries that
insist on writing a path themselves, such as cv2.FileStorage): the data land in a temporary
file beside the target and are renamed over it only when complete, so an interrupted run
never leaves a file that looks finished. Existing files are kept unless ``force`` is true.

Example
-------
>>> import tempfile, os
>>> d = tempfile.mkdtemp()
>>> write_json(os.path.join(d, "a.json"), {"x": 1})
>>> load_structured(os.path.join(d, "a.json"))
{'x': 1}
"""
from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np

from pencilcal.toolkit.errors import InputError

__all__ = [
    "check_writable",
    "atomic_path",
    "atomic_write",
    "write_json",
    "load_structured",
    "to_jsonable",
    "load_frames",
]


def check_writable(path, force=False):
    """Raise InputError if `path` exists and `force` is false, or its folder is missing."""
    p = Path(path)
    if p.exists() and not force:
        raise InputError(f"{p}: already exists; pass --force to overwrite it")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"{p}: folder {parent} does not exist")


@contextlib.contextmanager
def atomic_path(path, force=False):
    """Yield a temporary path beside `path` (same suffix); rename it over `path` on success.

    On an exception the temporary file is removed and `path` is left as it was.
    """
    p = Path(path)
    check_writable(p, force)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.stem}.", suffix=p.suffix, dir=p.parent if str(p.parent) else ".")
    os.close(fd)
    # mkstemp makes the file private (0600); outputs get the permissions of any new file
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    try:
        yield Path(tmp)
        os.replace(tmp, p)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def atomic_write(path, data, force=False):
    """Write `data` (str or bytes) to `path` atomically."""
    mode = "wb" if isinstance(data, (bytes, bytearray)) else "w"
    with atomic_path(path, force) as tmp:
        with open(tmp, mode, **({} if mode == "wb" else {"encoding": "utf-8"})) as f:
            f.write(data)


def to_jsonable(obj):
    """Numpy arrays and scalars to lists and floats; NaN and inf to None (JSON has neither)."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        f = float(obj)
        return f if math.isfinite(f) else None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_json(path, obj, force=False, indent=1):
    """Write `obj` as JSON atomically; floats keep full precision (repr round-trips)."""
    atomic_write(path, json.dumps(to_jsonable(obj), indent=indent, allow_nan=False) + "\n", force)


def load_structured(path, what="file"):
    """Load a YAML or JSON file into Python objects, with a one-line error on any problem.

    `what` names the kind of file in error messages ("camera file", "pencil file", ...).
    """
    import yaml

    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: {what} not found")
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{p}: cannot read {what}: {e}") from None
    try:
        if p.suffix.lower() == ".json":
            return json.loads(text)
        return yaml.safe_load(text)
    except (json.JSONDecodeError, yaml.YAMLError) as e:
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise InputError(f"{p}: not valid {'JSON' if p.suffix.lower() == '.json' else 'YAML'}: {msg}") from None


def load_frames(path, what, required=()):
    """The 'frames' list of a pencilcal JSON/YAML file, each frame checked to be an object
    with the `required` keys. Returns (whole document, [(frame dict, where)]) with `where`
    naming the file and frame for error messages; InputError otherwise."""
    data = load_structured(path, what)
    frames = data.get("frames") if isinstance(data, dict) else None
    if not isinstance(frames, list):
        raise InputError(f"{path}: a {what} is an object with a 'frames' list")
    out = []
    for i, f in enumerate(frames):
        where = f"{path}: frame {i}"
        if not isinstance(f, dict):
            raise InputError(f"{where}: must be an object")
        missing = [k for k in required if k not in f]
        if missing:
            raise InputError(f"{where}: missing {', '.join(missing)}")
        out.append((f, where))
    return data, out

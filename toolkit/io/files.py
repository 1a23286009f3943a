"""Reading structured files and writing outputs atomically, without clobbering.

Every writer in pencilcal goes through this module, the one home of atomic output:
`atomic_write` (or `atomic_path` for libraries that insist on writing a path themselves,
such as cv2.FileStorage; `atomic_paths` for several files that stand or fall together):
the data land in a temporary file beside the target and are renamed over it only when
complete, so an interrupted run never leaves a file that looks finished. Output folders
(simulate, sfm, a COLMAP model) are built in a `staging_folder` and put in place by
`replace_folder` (`atomic_folder` does both). Existing files are kept unless ``force``
is true.

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
import re
import shutil
import tempfile
from pathlib import Path

import numpy as np

from pencilcal.toolkit.errors import InputError

__all__ = [
    "check_writable",
    "atomic_path",
    "atomic_paths",
    "atomic_write",
    "atomic_folder",
    "staging_folder",
    "replace_folder",
    "write_json",
    "load_structured",
    "read_input_text",
    "nesting_depth",
    "MAX_INPUT_BYTES",
    "MAX_NESTING",
    "to_jsonable",
    "load_frames",
    "is_number",
]


def check_writable(path, force=False):
    """Raise InputError if `path` exists and `force` is false, or its folder is missing."""
    p = Path(path)
    if p.exists() and not force:
        raise InputError(f"{p}: already exists; pass --force to overwrite it")
    if p.is_dir():
        raise InputError(f"{p}: is a folder; give a file name")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"{p}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{p}: cannot write in folder {parent} (permission denied)")


def _normal_permissions(path, mode):
    """mkstemp/mkdtemp make private files (0600) and folders (0700); outputs get the
    permissions of any new file or folder (`mode` masked by the umask)."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, mode & ~umask)


@contextlib.contextmanager
def atomic_paths(paths, force=False):
    """Yield temporary paths beside each of `paths` (same suffixes); once the block has
    written them all, rename each over its target.

    Nothing is overwritten without `force` (checked before the block and again before
    the renames). On an exception the temporary files are removed, and an output this
    call created before the failure is removed too, so a failed run leaves no output
    that looks complete; earlier outputs are left as they were.

    Example
    -------
    >>> import tempfile, os
    >>> d = tempfile.mkdtemp()
    >>> with atomic_paths([os.path.join(d, "a.txt"), os.path.join(d, "b.txt")]) as (a, b):
    ...     _ = a.write_text("1"), b.write_text("2")
    >>> sorted(os.listdir(d))
    ['a.txt', 'b.txt']
    """
    targets = [Path(p) for p in paths]
    for p in targets:
        check_writable(p, force)
    staged, committed = [], []
    try:
        try:
            for p in targets:
                fd, tmp = tempfile.mkstemp(prefix=f".{p.stem}.", suffix=p.suffix,
                                           dir=p.parent if str(p.parent) else ".")
                os.close(fd)
                staged.append(Path(tmp))
                _normal_permissions(tmp, 0o666)
            yield staged
        except OSError as e:
            # the temporary file is ours, not the user's: name the output (a full disk
            # says only "[Errno 28]" while writing)
            names = ", ".join(str(p) for p in targets)
            raise InputError(f"{names}: cannot write: {e.strerror or e}") from None
        for p in targets:
            if p.exists() and not force:
                raise InputError(f"{p}: already exists; pass --force to overwrite it")
        for p, tmp in zip(targets, staged):
            existed = p.exists()
            os.replace(tmp, p)
            committed.append((p, existed))
    except BaseException:
        for p, existed in committed:
            if not existed:
                with contextlib.suppress(OSError):
                    p.unlink()
        raise
    finally:
        for tmp in staged:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()


@contextlib.contextmanager
def atomic_path(path, force=False):
    """Yield a temporary path beside `path` (same suffix); rename it over `path` on success.

    On an exception the temporary file is removed and `path` is left as it was.
    """
    with atomic_paths([path], force) as (tmp,):
        yield tmp


def staging_folder(path) -> Path:
    """A new, empty folder beside `path` (``.NAME.XXXX.partial``, normal permissions), in
    which an output folder is built before `replace_folder` puts it in place."""
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    tmp = Path(tempfile.mkdtemp(prefix=f".{p.name}.", suffix=".partial", dir=parent))
    _normal_permissions(tmp, 0o777)
    return tmp


def replace_folder(tmp, out):
    """Put the finished folder `tmp` at `out`. An earlier `out` is moved aside first and
    removed only once the new one is in place (and put back if that fails)."""
    tmp, out = Path(tmp), Path(out)
    if out.is_dir() and not any(out.iterdir()):
        out.rmdir()
    if not out.exists():
        os.replace(tmp, out)
        return
    old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old.", dir=tmp.parent))
    try:
        os.replace(out, old / out.name)
        try:
            os.replace(tmp, out)
        except BaseException:
            os.replace(old / out.name, out)  # put the earlier output back
            raise
    finally:
        shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def atomic_folder(path):
    """Yield a staging folder for the output folder `path`; on success it replaces `path`
    (`replace_folder`), on an exception it is removed and `path` is left as it was.

    The caller decides beforehand whether an existing `path` may be replaced (--force, and
    whether it looks like an earlier output of the same command).

    Example
    -------
    >>> import tempfile, os
    >>> d = tempfile.mkdtemp()
    >>> with atomic_folder(os.path.join(d, "out")) as tmp:
    ...     _ = (tmp / "a.txt").write_text("1")
    >>> os.listdir(os.path.join(d, "out")), [f for f in os.listdir(d) if f.startswith(".")]
    (['a.txt'], [])
    """
    tmp = staging_folder(path)
    try:
        yield tmp
        replace_folder(tmp, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


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


def is_number(value) -> bool:
    """True for a number of a parsed file: an int or a float (numpy's too), never a bool
    (True is 1 to Python) nor a string (np.asarray("12", float) would quietly convert it).

    >>> [is_number(v) for v in (1, 2.5, float("nan"), "2", True, None)]
    [True, True, True, False, False, False]
    """
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


# Limits on the structured files pencilcal reads (camera, pencil, board, lines, poses,
# validation): no real one comes near them, and past them a parser can exhaust memory or
# the stack (a 1 kB YAML of aliases expands to GBs; deep nesting crashes recursive parsers,
# OpenCV's FileStorage with a segmentation fault).
MAX_INPUT_BYTES = 512 * 1024 * 1024
MAX_NESTING = 64



def nesting_depth(data: bytes, kind: str) -> int:
    """The deepest nesting of a JSON/YAML/XML text, without parsing it (linear time).

    kind: "json", "yaml" (flow brackets and block indentation) or "xml" (elements).
    Brackets in double-quoted strings do not count. For YAML's block style every
    indentation step is taken as one level, which can only overestimate.
    """
    if kind == "xml":
        tags = re.findall(rb"<(/?)[A-Za-z_][^>]*?(/?)>", data)
        steps = np.array([0] + [-1 if close else (0 if empty else 1) for close, empty in tags])
        return int(np.max(np.cumsum(steps)))
    text = re.sub(rb"\\.", b"", data) if b"\\" in data else data  # escaped characters out first
    b = np.frombuffer(text, np.uint8)
    inside = (np.cumsum(b == ord('"')) % 2).astype(bool)  # within a double-quoted string
    step = np.zeros(b.shape, np.int32)
    step[(b == ord("[")) | (b == ord("{"))] = 1
    step[(b == ord("]")) | (b == ord("}"))] = -1
    step[inside] = 0
    depth = int(np.max(np.cumsum(step), initial=0))
    if kind == "yaml":
        indents = {len(m) for m in re.findall(rb"^( *)\S", text, re.M)}
        depth += len(indents)
    return depth


def read_input_text(path, what="file", kind=None) -> str:
    """The text of a structured input file, after the checks every reader needs: it
    exists, is under MAX_INPUT_BYTES, is UTF-8, and nests at most MAX_NESTING deep.
    InputError (one line, naming the file) otherwise. kind: "json", "yaml" or "xml"
    (default: from the suffix)."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: {what} not found")
    try:
        size = p.stat().st_size
        if size > MAX_INPUT_BYTES:
            raise InputError(f"{p}: {what} of {size:,} bytes is over the limit of {MAX_INPUT_BYTES:,}")
        data = p.read_bytes()
        text = data.decode("utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{p}: cannot read {what}: {e}") from None
    kind = kind or {".json": "json", ".xml": "xml"}.get(p.suffix.lower(), "yaml")
    depth = nesting_depth(data, kind)
    if depth > MAX_NESTING:
        raise InputError(f"{p}: {what} nests {depth} levels deep, over the limit of {MAX_NESTING}")
    return text


def _yaml_loader():
    """PyYAML's safe loader without aliases: no pencilcal file needs one, and aliases of
    aliases expand a few hundred bytes to gigabytes."""
    import yaml

    class NoAliasLoader(yaml.SafeLoader):
        def compose_node(self, parent, index):
            if self.check_event(yaml.AliasEvent):
                event = self.peek_event()
                raise yaml.composer.ComposerError(None, None, "YAML aliases (*name) are not accepted",
                                                  event.start_mark)
            return super().compose_node(parent, index)

    return NoAliasLoader


def load_structured(path, what="file"):
    """Load a YAML or JSON file into Python objects, with a one-line error on any problem.

    `what` names the kind of file in error messages ("camera file", "pencil file", ...).
    The file is checked first (`read_input_text`: size, encoding, nesting); YAML aliases
    are refused.
    """
    import yaml

    p = Path(path)
    text = read_input_text(p, what)
    try:
        if p.suffix.lower() == ".json":
            return json.loads(text)
        return yaml.load(text, Loader=_yaml_loader())  # noqa: S506 - a safe loader, aliases refused
    except (json.JSONDecodeError, yaml.YAMLError, RecursionError) as e:
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

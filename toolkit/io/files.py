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

import collections
import contextlib
import errno
import json
import math
import os
import re
import shutil
import signal
import tempfile
import threading
from pathlib import Path

import numpy as np

from pencilcal.toolkit.errors import InputError

__all__ = [
    "check_writable",
    "check_folder_writable",
    "signals_deferred",
    "write_error",
    "outputs_written",
    "put_in_place",
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
    "MAX_MAGNITUDE",
    "check_magnitudes",
    "to_jsonable",
    "load_frames",
    "is_number",
]


def _folder_unwritable(folder):
    """Why nothing can be created in `folder` (None when something can): a read-only file
    system, or no permission. os.access answers for this process (root included: it is
    refused on a read-only file system too)."""
    if os.access(folder, os.W_OK | os.X_OK):
        return None
    try:
        if os.statvfs(folder).f_flag & os.ST_RDONLY:
            return "read-only file system"
    except OSError:
        pass
    return "permission denied"


def check_writable(path, force=False):
    """Raise InputError if `path` exists and `force` is false, is a folder, or its folder is
    missing or cannot be written in (a read-only file system, no permission)."""
    p = Path(path)
    if (p.exists() or p.is_symlink()) and not force:
        raise InputError(f"{p}: already exists; pass --force to overwrite it")
    if p.is_dir():
        raise InputError(f"{p}: is a folder; give a file name")
    if p.exists() and not p.is_file():
        # an output is renamed into place: it would replace the device or pipe itself
        raise InputError(f"{p}: is not a regular file (a device, a pipe); give a file name")
    check_folder_writable(p)


def check_folder_writable(path):
    """Raise InputError if the output `path` (a file, or a folder: it is built beside
    itself, `staging_folder`) could not be created: its parent folder is missing or cannot
    be written in."""
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"{p}: folder {parent} does not exist")
    why = _folder_unwritable(parent)
    if why:
        raise InputError(f"{p}: cannot write in folder {parent} ({why})")


def _normal_permissions(path, mode):
    """mkstemp/mkdtemp make private files (0600) and folders (0700); outputs get the
    permissions of any new file or folder (`mode` masked by the umask)."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, mode & ~umask)


# The signals that end a run (Ctrl-C, kill, a closed terminal): held back while outputs are
# put in place, so that a run stopped by one has either put all of them there or none.
_DEFERRED = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n))


@contextlib.contextmanager
def signals_deferred():
    """Hold back SIGINT, SIGTERM and SIGHUP while the block runs; one that arrives meanwhile
    is handled (by the handler it had) as soon as the block ends.

    The renames that put outputs in place run in such a block: a signal cannot land between
    two of them. Signal handlers belong to the main thread; in another thread this does
    nothing.

    >>> with signals_deferred():
    ...     pass
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught = []
    previous = {s: signal.getsignal(s) for s in _DEFERRED}

    def hold(signum, frame):
        caught.append(signum)

    for s in _DEFERRED:
        if previous[s] not in (signal.SIG_IGN, None):
            signal.signal(s, hold)
    try:
        yield
    finally:
        for s in _DEFERRED:
            if previous[s] not in (signal.SIG_IGN, None):
                signal.signal(s, previous[s])
        if caught:
            signal.raise_signal(caught[0])


# the outputs this process has put in place: how many, and the latest (bounded: a live run
# writing a PNG a frame for hours must not grow a list)
_WRITTEN = collections.deque(maxlen=64)
_WRITTEN_COUNT = [0]


def _record(paths):
    for p in paths:
        _WRITTEN.append(p)
        _WRITTEN_COUNT[0] += 1


def outputs_written(since=0):
    """(how many outputs this process has put in place, the latest of those after the first
    `since`, at most 64): what a run stopped by a signal had already written.

    >>> n, _ = outputs_written()
    >>> outputs_written(since=n)
    (0, [])
    """
    n = _WRITTEN_COUNT[0]
    return n - since, list(_WRITTEN)[len(_WRITTEN) - min(n - since, len(_WRITTEN)):]


# What an OSError while writing an output means to the user
_WRITE_REASONS = {errno.ENOSPC: "no space left on device (the disk is full)",
                  errno.EDQUOT: "disk quota exceeded",
                  errno.EROFS: "read-only file system",
                  errno.EACCES: "permission denied",
                  errno.EPERM: "operation not permitted",
                  errno.EFBIG: "file too large for this file system"}


def write_error(targets, e):
    """The InputError for an OSError `e` while writing the outputs `targets`: it names the
    outputs (never the temporary files beside them), says why in words (a full disk, a
    read-only file system, a folder removed meanwhile) and what is left: each earlier output
    is kept, and nothing new is there.

    >>> str(write_error(["/nowhere/out.json"], OSError(errno.ENOSPC, "No space left on device")))
    '/nowhere/out.json: cannot write: no space left on device (the disk is full); nothing was written'
    """
    targets = [Path(p) for p in targets]
    names = ", ".join(str(p) for p in targets)
    reason = _WRITE_REASONS.get(e.errno) or (e.strerror or str(e)).lower()
    if e.errno == errno.ENOENT:
        gone = [p.parent for p in targets if not (p.parent if str(p.parent) else Path(".")).is_dir()]
        if gone:
            reason = f"folder {gone[0]} no longer exists (removed during the run?)"
    kept = [str(p) for p in targets if p.exists()]
    left = f"the earlier {', '.join(kept)} {'is' if len(kept) == 1 else 'are'} kept" if kept else \
        "nothing was written"
    return InputError(f"{names}: cannot write: {reason}; {left}")


def _fsync(path, folder=False):
    """Data of `path` (a file, or a folder's entries) on the disk before a rename makes it
    the output: a crash right after cannot leave an empty file under the output's name, and
    a disk that fills at the last moment (delayed allocation) says so here, not later."""
    try:
        fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if folder else 0))
    except OSError:
        if folder:
            return  # some file systems cannot open a folder for this: nothing to flush then
        raise
    try:
        os.fsync(fd)
    except OSError as e:
        if not folder or e.errno not in (errno.EINVAL, errno.EBADF, errno.ENOTSUP):
            raise
    finally:
        os.close(fd)


def _place(tmp, target, force):
    """Rename the finished `tmp` to `target`. Without `force` an output that appeared
    meanwhile (another run writing the same output) is never replaced: the link that puts
    `tmp` there fails if `target` exists."""
    if force:
        os.replace(tmp, target)
        return
    try:
        os.link(tmp, target)
    except FileExistsError:
        raise InputError(f"{target}: already exists (written meanwhile, by another run?); pass --force to "
                         "overwrite it") from None
    except OSError as e:
        if e.errno not in (errno.EPERM, errno.ENOTSUP, errno.EXDEV, errno.EMLINK):
            raise
        # a file system without hard links: the check just made is all there is
        if target.exists() or target.is_symlink():
            raise InputError(f"{target}: already exists; pass --force to overwrite it") from None
        os.replace(tmp, target)
        return
    tmp.unlink()


def _staged(path):
    """Whether `path` lies in a staging folder (`staging_folder`): not an output yet."""
    return any(part.startswith(".") and part.endswith(".partial") for part in Path(path).parts[:-1])


def put_in_place(tmp, target, force=False):
    """Rename the finished file `tmp` (written by a library that chose its own temporary
    name, such as OpenCV's video writer) to `target`, as `atomic_paths` does: flushed to the
    disk, signals held back, never over an existing `target` without `force`."""
    tmp, target = Path(tmp), Path(target)
    try:
        _commit([target], [tmp], force)
    except OSError as e:
        raise write_error([target], e) from None


def _backup(path):
    """A hard link to the existing output `path` beside it (None when there is none or the
    file system has no hard links): what a failed commit of several outputs puts back."""
    if not path.is_file():
        return None
    for _ in range(100):
        bak = path.with_name(f".{path.name}.{os.urandom(4).hex()}.old")
        try:
            os.link(path, bak)
            return bak
        except FileExistsError:
            continue
        except OSError:
            return None
    return None


def _commit(targets, staged, force):
    """Put every staged file in place, all or none: signals are held back meanwhile, and when
    one rename fails the outputs already placed are undone (an earlier file put back, a new
    one removed)."""
    for tmp in staged:  # before the signals are held: a flush can take a while
        _fsync(tmp)
    with signals_deferred():
        backups = [_backup(p) if force and len(targets) > 1 else None for p in targets]
        done = []
        try:
            for p, tmp, bak in zip(targets, staged, backups):
                existed = p.exists()
                _place(tmp, p, force)
                done.append((p, existed, bak))
        except BaseException:
            for p, existed, bak in reversed(done):
                with contextlib.suppress(OSError):
                    if bak is not None:
                        os.replace(bak, p)
                    elif not existed:
                        p.unlink()
            raise
        finally:
            for bak in backups:
                if bak is not None:
                    with contextlib.suppress(OSError):
                        bak.unlink()
        _record(p for p in targets if not _staged(p))
        for folder in {p.parent for p in targets}:  # the renames themselves on the disk: best effort, they are done
            with contextlib.suppress(OSError):
                _fsync(folder if str(folder) else Path("."), folder=True)


@contextlib.contextmanager
def atomic_paths(paths, force=False):
    """Yield temporary paths beside each of `paths` (same suffixes); once the block has
    written them all, put each in place of its target: all of them, or none.

    Nothing is overwritten without `force` (checked before the block, and again as each
    file is put in place: an output another run wrote meanwhile is kept). The files are
    flushed to the disk first; the renames run with SIGINT, SIGTERM and SIGHUP held back,
    and a rename that fails undoes the ones before it (earlier outputs put back). On an
    exception the temporary files are removed and every earlier output is left as it was;
    an OSError while writing (a full disk, a folder removed meanwhile) becomes an InputError
    naming the outputs (`write_error`).

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
    staged = []
    try:
        try:
            for p in targets:
                # the stem shortened: a name near the file system's limit must not fail for the
                # temporary's few characters more
                fd, tmp = tempfile.mkstemp(prefix=f".{p.stem[:48]}.", suffix=p.suffix[:16],
                                           dir=p.parent if str(p.parent) else ".")
                os.close(fd)
                staged.append(Path(tmp))
                _normal_permissions(tmp, 0o666)
            yield staged
        except OSError as e:
            # the temporary file is ours, not the user's: name the output
            if e.filename is None or Path(e.filename) in staged or not staged:
                raise write_error(targets, e) from None
            raise
        for p in targets:
            if (p.exists() or p.is_symlink()) and not force:
                raise InputError(f"{p}: already exists (written meanwhile, by another run?); pass --force to "
                                 "overwrite it")
        try:
            _commit(targets, staged, force)
        except OSError as e:
            raise write_error(targets, e) from None
    finally:
        for tmp in staged:  # best effort: a file system turned read-only keeps it
            with contextlib.suppress(OSError):
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
    which an output folder is built before `replace_folder` puts it in place. A folder that
    cannot be made is an InputError naming `path` (not the temporary name)."""
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    check_folder_writable(p)
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{p.name[:48]}.", suffix=".partial", dir=parent))
    except OSError as e:
        raise write_error([p], e) from None
    _normal_permissions(tmp, 0o777)
    return tmp


def replace_folder(tmp, out):
    """Put the finished folder `tmp` at `out`. An earlier `out` is moved aside first and
    removed only once the new one is in place (and put back if that fails); signals are held
    back meanwhile (`signals_deferred`)."""
    tmp, out = Path(tmp), Path(out)
    for f in tmp.rglob("*"):  # before the signals are held: a flush can take a while
        if f.is_file() and not f.is_symlink():
            _fsync(f)
    with signals_deferred():
        if out.is_dir() and not any(out.iterdir()):
            out.rmdir()
        if not out.exists():
            os.replace(tmp, out)
            _record([out])
            return
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old.", dir=tmp.parent))
        try:
            os.replace(out, old / out.name)
            try:
                os.replace(tmp, out)
            except BaseException:
                os.replace(old / out.name, out)  # put the earlier output back
                raise
            _record([out])
        finally:
            shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def atomic_folder(path):
    """Yield a staging folder for the output folder `path`; on success it replaces `path`
    (`replace_folder`), on an exception it is removed and `path` is left as it was.

    Errors say `path`, never the staging folder's name: an OSError (a full disk) becomes an
    InputError naming the file under `path`, and an InputError that names the staging folder
    names `path` instead.

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
        try:
            yield tmp
            replace_folder(tmp, path)
        except OSError as e:
            where = Path(e.filename) if e.filename else tmp
            if where != tmp and tmp not in where.parents:
                raise  # not the output's: an input, say, with its own name
            raise write_error([Path(path) / where.relative_to(tmp)], e) from None
        except InputError as e:
            if str(tmp) in str(e):
                raise InputError(str(e).replace(str(tmp), str(path))) from None
            raise
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
        # numbers only, all finite: tolist() is already what the elements would give (a
        # frame's record holds dozens of arrays, written as each frame is done)
        if obj.dtype.kind in "biu" or (obj.dtype.kind == "f" and bool(np.isfinite(obj).all())):
            return obj.tolist()
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
        raise InputError(f"{p}: {what} {'is not a regular file' if p.exists() else 'not found'}")
    try:
        size = p.stat().st_size
        if size > MAX_INPUT_BYTES:
            raise InputError(f"{p}: {what} of {size:,} bytes is over the limit of {MAX_INPUT_BYTES:,}")
        data = p.read_bytes()
        text = data.decode("utf-8")
    except OSError as e:
        raise InputError(f"{p}: cannot read {what}: {(e.strerror or str(e)).lower()}") from None
    except UnicodeDecodeError as e:
        raise InputError(f"{p}: cannot read {what}: not UTF-8 text (byte 0x{data[e.start]:02x} at offset "
                         f"{e.start})") from None
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
    are refused, and so is a number beyond MAX_MAGNITUDE (`check_magnitudes`).
    """
    import yaml

    p = Path(path)
    text = read_input_text(p, what)
    try:
        if p.suffix.lower() == ".json":
            data = json.loads(text)
        else:
            data = yaml.load(text, Loader=_yaml_loader())  # noqa: S506 - a safe loader, aliases refused
    except (json.JSONDecodeError, yaml.YAMLError, RecursionError) as e:
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise InputError(f"{p}: not valid {'JSON' if p.suffix.lower() == '.json' else 'YAML'}: {msg}") from None
    # only a text with an exponent of 100 or more (or 101 digits in a row) can hold one: the
    # walk through a 14 MB lines file is saved
    if _MAYBE_HUGE.search(text):
        check_magnitudes(data, str(p))
    return data


#: No number a pencilcal file holds comes near this magnitude; a file that holds one is
#: refused as it is read (squared, or multiplied a few times, such numbers overflow: lines
#: of 1e300 px overflowed in the vertex, a validation.json of 1e308 in the report).
MAX_MAGNITUDE = 1e100
_MAYBE_HUGE = re.compile(r"[eE]\+?0*[1-9]\d{2,}|\d{101,}")


def check_magnitudes(data, source, limit=MAX_MAGNITUDE):
    """InputError (naming `source` and where) if a number in the parsed file `data` is
    larger in magnitude than `limit`; returns `data`.

    >>> check_magnitudes({"frames": [{"tilt_deg": 1e308}]}, "v.json")
    Traceback (most recent call last):
    ...
    pencilcal.toolkit.errors.InputError: v.json: frames[0].tilt_deg is 1e+308, beyond 1e+100: no measurement is that large
    """
    stack = [(data, "")]
    while stack:
        obj, where = stack.pop()
        if isinstance(obj, dict):  # reversed: the first in the file is said first
            stack.extend(reversed([(v, f"{where}.{k}" if where else str(k)) for k, v in obj.items()]))
        elif isinstance(obj, list):
            stack.extend(reversed([(v, f"{where}[{i}]") for i, v in enumerate(obj)]))
        elif is_number(obj) and math.isfinite(obj) and abs(obj) > limit:
            raise InputError(f"{source}: {where} is {float(obj):g}, beyond {limit:g}: no measurement is that large")
    return data


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

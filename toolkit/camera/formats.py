"""Camera files: read and write `Camera` intrinsics in the formats labs already use.

The format follows the path (docs/formats.md, "Camera files"):

=====================  ==============================================================
``.json``              ``{"model", "width", "height", "K": 3x3, "dist": [...]}``; any other
                       key (``rms_px``, ``std_intrinsics``, ...) is kept in ``camera.meta``.
``.yaml .yml .xml``    OpenCV FileStorage: ``camera_matrix``, ``distortion_coefficients``
                       (also read: ``dist_coeffs``, ``D``, ``dist``; ``K``),
                       ``image_width``, ``image_height`` and a string ``distortion_model``
                       (``opencv`` | ``fisheye`` | ``pinhole``; ROS's ``plumb_bob``,
                       ``rational_polynomial`` and ``equidistant`` are read too). Without it
                       a file is opencv, or pinhole if it has no coefficients. Other keys
                       are kept in ``camera.meta``.
``.cameramodel``       mrcal: LENSMODEL_PINHOLE, LENSMODEL_OPENCV4/5/8/12 and
                       LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=.._Ny=.._fov_x_deg=..
                       (pencilcal's splined_stereographic_...). Parsed as a Python literal
                       (never evaluated); any other lens model is an error.
``.txt`` ``.bin``      COLMAP ``cameras.txt`` / ``cameras.bin``, read and written through
                       pycolmap (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV,
                       FULL_OPENCV, OPENCV_FISHEYE).
a folder               a COLMAP sparse model holding ``cameras.bin`` or ``cameras.txt``
                       (a path without extension is written as one).
=====================  ==============================================================

Conventions
-----------
- pencilcal and OpenCV put pixel (0, 0) at the centre of the top-left pixel; so does mrcal
  (``mrcal.sample_imager`` spans 0 .. width-1), and its OPENCVn models are OpenCV's
  equations with the same parameter order, so .cameramodel values are copied unchanged.
- COLMAP puts the centre of the top-left pixel at (0.5, 0.5) (colmap doc/database.rst):
  ``cx_colmap = cx + 0.5``, ``cy_colmap = cy + 0.5``. The shift is exact in floating point
  unless ``cx + 0.5`` crosses a power of two (e.g. cx = 1023.7 -> 1024.2), where COLMAP's
  value can hold one bit less: a round trip through COLMAP may then move cx by 1 ulp
  (~1e-13 px).
- Values are written with full double precision (17 significant digits or repr), so every
  format round-trips exactly (COLMAP with the caveat above).
- Writers never overwrite an existing output unless ``force`` is true, and write atomically
  (files.py): an interrupted write never leaves a half-written camera file.
- Readers raise `InputError` with a one-line ``"<path>: <problem>"`` message.

Example
-------
>>> import os, tempfile
>>> from pencilcal.toolkit.camera.model import Camera
>>> cam = Camera("opencv", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]],
...              [-0.1, 0.01, 0.0, 0.0], meta={"rms_px": 0.2})
>>> d = tempfile.mkdtemp()
>>> for name in ("cam.json", "cam.yaml", "cam.cameramodel", "cameras.txt", "sparse"):
...     write_camera(os.path.join(d, name), cam)
...     assert read_camera(os.path.join(d, name)) == cam
>>> read_camera(os.path.join(d, "cam.json")).meta
{'rms_px': 0.2}
"""
from __future__ import annotations

import ast
import contextlib
import math
import os
import re
import shutil
import struct
import tempfile
from numbers import Integral, Real
from pathlib import Path

import numpy as np

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.camera.splined import MRCAL_PREFIX as MRCAL_SPLINED_PREFIX, PREFIX as SPLINED_PREFIX, \
    is_splined, splined_config, splined_name
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import (atomic_path, load_structured, read_input_text, signals_deferred, staging_folder,
                                        write_json)

__all__ = [
    "read_camera",
    "write_camera",
    "camera_to_dict",
    "camera_from_dict",
    "camera_from_colmap",
    "camera_to_colmap",
    "camera_format",
    "COLMAP_MODELS",
    "MRCAL_LENSMODELS",
]

#: COLMAP camera models pencilcal reads, with their parameter names (COLMAP's order).
COLMAP_MODELS = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    "OPENCV_FISHEYE": ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
}

#: mrcal lens models pencilcal reads and writes, and their opencv coefficient counts.
MRCAL_LENSMODELS = {"LENSMODEL_PINHOLE": 0, "LENSMODEL_OPENCV4": 4, "LENSMODEL_OPENCV5": 5,
                    "LENSMODEL_OPENCV8": 8, "LENSMODEL_OPENCV12": 12}

_JSON_KEYS = ("model", "width", "height", "K", "dist")
_FS_NAMES = {
    "K": ("camera_matrix", "K"),
    "dist": ("distortion_coefficients", "dist_coeffs", "D", "dist"),
    "width": ("image_width", "width"),
    "height": ("image_height", "height"),
    "model": ("distortion_model", "model"),
}
_FS_MODELS = {"opencv": "opencv", "plumb_bob": "opencv", "rational_polynomial": "opencv",
              "radtan": "opencv", "fisheye": "fisheye", "equidistant": "fisheye",
              "pinhole": "pinhole"}
_FS_SUFFIXES = (".yaml", ".yml", ".xml")
_COLMAP_FILES = ("cameras", "images", "points3D", "rigs", "frames")
_FS_KEY = re.compile(r"^[A-Za-z_][A-Za-z0-9_-]*$")
# COLMAP: the centre of the top-left pixel is (0.5, 0.5); pencilcal/OpenCV: (0, 0)
_COLMAP_SHIFT = 0.5


def _one_line(e) -> str:
    """The informative first line of an exception message (OpenCV and COLMAP write several)."""
    text = str(e).strip()
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    line = lines[0] if lines else type(e).__name__
    # "OpenCV(5.0.0) /path/file.cpp:83: error: (-5:Bad argument) message in function 'f'"
    m = re.search(r"error: \(-?\d+:[^)]*\) (.*)", line)
    return m.group(1) if m else line


def camera_format(path) -> str:
    """The format a camera path stands for: json, filestorage, cameramodel, colmap_txt,
    colmap_bin or colmap_folder. Raises InputError for an unknown extension."""
    p = Path(path)
    suffix = p.suffix.lower()
    if p.is_dir() or suffix == "":
        return "colmap_folder"
    if suffix == ".json":
        return "json"
    if suffix in _FS_SUFFIXES:
        return "filestorage"
    if suffix == ".cameramodel":
        return "cameramodel"
    if suffix == ".txt":
        return "colmap_txt"
    if suffix == ".bin":
        return "colmap_bin"
    raise InputError(
        f"{p}: unknown camera file type {p.suffix!r}; expected .json, .yaml, .yml, .xml, "
        ".cameramodel, COLMAP cameras.txt/.bin or a COLMAP model folder")


# --------------------------------------------------------------------------- public API
def read_camera(path, camera_id=None) -> Camera:
    """Read camera intrinsics; the format follows the extension (module docstring).

    Parameters
    ----------
    path : str or Path
        Camera file, or a COLMAP sparse model folder.
    camera_id : int, optional
        COLMAP only: the camera to read when the file holds several.

    Returns
    -------
    Camera

    Raises
    ------
    InputError
        ``"<path>: <problem>"`` for a missing or unreadable file, a missing key, a wrong
        shape, a non-finite or invalid value, an unsupported lens model, a non-literal in a
        .cameramodel, a truncated COLMAP .bin, several COLMAP cameras without `camera_id`.
    """
    p = Path(path)
    fmt = camera_format(p)
    if not p.exists():
        raise InputError(f"{p}: camera file not found")
    if camera_id is not None and not fmt.startswith("colmap"):
        raise InputError(f"{p}: a camera id applies to COLMAP cameras files only")
    if fmt != "colmap_folder" and not p.is_file():
        raise InputError(f"{p}: not a file")
    if fmt == "json":
        return camera_from_dict(load_structured(p, "camera file"), source=str(p))
    if fmt == "filestorage":
        # OpenCV's parser crashes the process on deep nesting: checked before it sees the file
        read_input_text(p, "camera file", kind="xml" if p.suffix.lower() == ".xml" else "yaml")
        return _read_filestorage(p)
    if fmt == "cameramodel":
        return _read_cameramodel(p)
    return _read_colmap(p, camera_id)


def write_camera(path, camera: Camera, force=False) -> None:
    """Write camera intrinsics; the format follows the extension (module docstring).

    Parameters
    ----------
    path : str or Path
        Output file; a path without extension (or an existing folder) gets a COLMAP model.
    camera : Camera
    force : bool
        Overwrite an existing output. Without it an existing output is an InputError.

    Raises
    ------
    InputError
        If the output exists (and not `force`), its folder is missing, or the format cannot
        hold this camera exactly: .cameramodel takes no skew, fisheye or 14 coefficients;
        COLMAP takes no skew and no 12 or 14 coefficients.
    """
    if not isinstance(camera, Camera):
        raise TypeError(f"expected a Camera, got {type(camera).__name__}")
    p = Path(path)
    fmt = camera_format(p)
    if fmt == "json":
        write_json(p, camera_to_dict(camera), force=force)
    elif fmt == "filestorage":
        _write_filestorage(p, camera, force)
    elif fmt == "cameramodel":
        text = _cameramodel_text(camera, p)
        with atomic_path(p, force) as tmp:
            tmp.write_text(text, encoding="utf-8")
    else:
        _write_colmap(p, camera, force, fmt)


# ----------------------------------------------------------------------------- JSON
def _is_number(v) -> bool:
    return isinstance(v, Real) and not isinstance(v, (bool, np.bool_))


def _matrix(value, shape, key, source):
    """Nested lists of numbers of exactly `shape` -> float array, else InputError."""
    def check(v, dims):
        if not dims:
            return _is_number(v)
        return isinstance(v, (list, tuple)) and len(v) == dims[0] and all(check(x, dims[1:]) for x in v)

    if not check(value, shape):
        want = "a " + "x".join(map(str, shape)) + " matrix of" if len(shape) > 1 else f"a list of {shape[0]}"
        raise InputError(f"{source}: '{key}' must be {want} numbers, got {_short(value)}")
    return np.array(value, dtype=float).reshape(shape)


def _short(value, n=60) -> str:
    text = repr(value).replace("\n", " ")
    return text if len(text) <= n else text[: n - 3] + "..."


def _int_value(value, key, source) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, Real) or not math.isfinite(value) \
            or value != int(value):
        raise InputError(f"{source}: '{key}' must be a whole number of pixels, got {_short(value)}")
    return int(value)


def _build(source, **kw) -> Camera:
    try:
        return Camera(**kw)
    except InputError as e:
        raise InputError(f"{source}: {e}") from None


def camera_to_dict(camera: Camera) -> dict:
    """The JSON form of a camera: model, width, height, K (3x3), dist, then camera.meta.

    Raises InputError if a meta key collides with one of those five.
    """
    d = {"model": camera.model, "width": camera.width, "height": camera.height,
         "K": camera.K.tolist(), "dist": camera.dist.tolist()}
    for k, v in (camera.meta or {}).items():
        if k in d:
            raise InputError(f"camera meta key {k!r} collides with a camera field")
        d[str(k)] = v
    return d


def camera_from_dict(d, source="camera") -> Camera:
    """Build a Camera from the JSON form (`camera_to_dict`); other keys go to meta.

    `source` names the file in error messages. ``dist`` may be left out for a pinhole.

    Example
    -------
    >>> cam = camera_from_dict({"model": "pinhole", "width": 4, "height": 3,
    ...                         "K": [[2.0, 0, 1.5], [0, 2.0, 1.0], [0, 0, 1]], "rms_px": 0.1})
    >>> cam.fx, cam.meta
    (2.0, {'rms_px': 0.1})
    """
    if not isinstance(d, dict):
        raise InputError(f"{source}: expected a mapping with keys {list(_JSON_KEYS)}")
    missing = [k for k in ("model", "width", "height", "K") if k not in d]
    if missing:
        raise InputError(f"{source}: missing key(s) {missing}; a camera needs {list(_JSON_KEYS)}")
    model = d["model"]
    if not isinstance(model, str):
        raise InputError(f"{source}: 'model' must be a string, got {_short(model)}")
    K = _matrix(d["K"], (3, 3), "K", source)
    dist = d.get("dist", [])
    if dist is None:
        dist = []
    if not isinstance(dist, (list, tuple)):
        raise InputError(f"{source}: 'dist' must be a list of numbers, got {_short(dist)}")
    dist = _matrix(list(dist), (len(dist),), "dist", source)
    meta = {k: v for k, v in d.items() if k not in _JSON_KEYS}
    return _build(source, model=model, width=_int_value(d["width"], "width", source),
                  height=_int_value(d["height"], "height", source), K=K, dist=dist, meta=meta or None)


# ---------------------------------------------------------------- OpenCV FileStorage
def _fs_value(node):
    """A FileStorage node as Python: dict, list, int, float, str, None; matrices as lists."""
    import cv2

    if node.isMap():
        keys = list(node.keys())
        if "dt" in keys and "data" in keys:
            mat = node.mat()
            return None if mat is None else np.asarray(mat).tolist()
        return {k: _fs_value(node.getNode(k)) for k in keys}
    if node.isSeq():
        return [_fs_value(node.at(i)) for i in range(node.size())]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    if node.type() == cv2.FileNode_NONE:
        return None
    return None


def _fs_array(value, key, source):
    """Numbers from a FileStorage value: a matrix, a (nested) sequence, a ROS-style
    ``{rows, cols, data}`` map or a single number -> flat float array."""
    if isinstance(value, dict) and "data" in value:
        value = value["data"]
    flat = []

    def walk(v):
        if isinstance(v, list):
            for x in v:
                walk(x)
        elif _is_number(v):
            flat.append(float(v))
        else:
            raise InputError(f"{source}: '{key}' must hold numbers only, got {_short(v)}")

    walk(value)
    return np.array(flat, dtype=float)


def _read_filestorage(p) -> Camera:
    import cv2

    source = str(p)
    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as e:  # a parse error in the constructor surfaces as SystemError
        if isinstance(e, SystemError) and e.__cause__ is not None:
            e = e.__cause__
        raise InputError(f"{source}: not a valid OpenCV FileStorage file: {_one_line(e)}") from None
    if not fs.isOpened():
        raise InputError(f"{source}: cannot open as an OpenCV FileStorage file")
    try:
        root = fs.root()
        if not root.isMap():
            raise InputError(f"{source}: expected a mapping with 'camera_matrix', 'distortion_coefficients', "
                             "'image_width', 'image_height'")
        data = {k: _fs_value(root.getNode(k)) for k in root.keys()}
    except (cv2.error, SystemError) as e:
        raise InputError(f"{source}: cannot read OpenCV FileStorage file: {_one_line(e)}") from None
    finally:
        fs.release()

    def find(field):
        for name in _FS_NAMES[field]:
            if name in data and data[name] is not None:
                return name, data[name]
        return None, None

    k_name, k_val = find("K")
    if k_name is None:
        raise InputError(f"{source}: missing 'camera_matrix'")
    K = _fs_array(k_val, k_name, source)
    if K.size != 9:
        raise InputError(f"{source}: '{k_name}' must be a 3x3 matrix, got {K.size} numbers")
    d_name, d_val = find("dist")
    dist = np.zeros(0) if d_name is None else _fs_array(d_val, d_name, source)
    size = {}
    for field in ("width", "height"):
        name, val = find(field)
        if name is None:
            raise InputError(f"{source}: missing 'image_{field}'")
        size[field] = _int_value(val, name, source)
    m_name, m_val = find("model")
    if m_name is None:
        model = "opencv" if dist.size else "pinhole"
    else:
        if isinstance(m_val, str) and is_splined(m_val.strip()):
            model = m_val.strip()
        elif not isinstance(m_val, str) or m_val.strip().lower() not in _FS_MODELS:
            raise InputError(f"{source}: unknown '{m_name}' {_short(m_val)}; expected 'opencv', 'fisheye', 'pinhole' "
                             f"or {SPLINED_PREFIX}_...")
        else:
            model = _FS_MODELS[m_val.strip().lower()]
    used = {n for names in _FS_NAMES.values() for n in names}
    meta = {k: v for k, v in data.items() if k not in used}
    return _build(source, model=model, K=K.reshape(3, 3), dist=dist, meta=meta or None, **size)


def _fs_write_value(fs, key, value):
    """Write one meta value; False if FileStorage cannot hold it (it is then left out)."""
    import cv2

    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (bool, np.bool_)):
        value = int(value)
    if isinstance(value, Integral):
        value = int(value)
        # FileStorage holds 32-bit ints; larger Python ints come out as 'true'
        if -(2**31) <= value < 2**31:
            fs.write(key, value)
            return True
        if float(value) != value:
            return False
        value = float(value)
    if isinstance(value, Real):
        fs.write(key, float(value))
        return True
    if isinstance(value, str):
        fs.write(key, value)
        return True
    if isinstance(value, (list, tuple)):
        fs.startWriteStruct(key, cv2.FileNode_SEQ)
        for v in value:
            _fs_write_value(fs, "", v)
        fs.endWriteStruct()
        return True
    if isinstance(value, dict):
        fs.startWriteStruct(key, cv2.FileNode_MAP)
        for k, v in value.items():
            if isinstance(k, str) and _FS_KEY.match(k):
                _fs_write_value(fs, k, v)
        fs.endWriteStruct()
        return True
    return False


def _write_filestorage(p, camera, force):
    import cv2

    names = {n for names in _FS_NAMES.values() for n in names}
    for k in (camera.meta or {}):
        if k in names:
            raise InputError(f"{p}: camera meta key {k!r} collides with a camera field")
    with atomic_path(p, force) as tmp:
        fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
        if not fs.isOpened():
            raise InputError(f"{p}: cannot write an OpenCV FileStorage file")
        try:
            fs.write("image_width", camera.width)
            fs.write("image_height", camera.height)
            fs.write("camera_matrix", np.array(camera.K))
            if camera.dist.size:
                fs.write("distortion_coefficients", np.array(camera.dist).reshape(1, -1))
            fs.write("distortion_model", camera.model)
            # meta: numbers, strings, lists and mappings of them; other values and keys
            # FileStorage cannot name are left out (JSON keeps everything)
            for k, v in (camera.meta or {}).items():
                if isinstance(k, str) and _FS_KEY.match(k):
                    _fs_write_value(fs, k, v)
        finally:
            fs.release()


# ---------------------------------------------------------------------- mrcal
# what ast.literal_eval accepts: containers, constants, signed numbers and complex sums
_LITERAL_NODES = (ast.Expression, ast.Constant, ast.Dict, ast.List, ast.Tuple, ast.Set, ast.UnaryOp,
                  ast.BinOp, ast.Load)


def _parse_literal(text, source):
    """ast.literal_eval with a one-line message naming the first non-literal. Never evaluates."""
    try:
        tree = ast.parse(text, mode="eval")
    except SyntaxError as e:
        raise InputError(f"{source}: not a mrcal .cameramodel (Python literal syntax error on line {e.lineno}: "
                         f"{e.msg})") from None
    except (ValueError, RecursionError, MemoryError) as e:
        raise InputError(f"{source}: not a mrcal .cameramodel: {_one_line(e)}") from None
    for node in ast.walk(tree):
        if isinstance(node, (ast.operator, ast.unaryop, ast.expr_context)):
            continue  # judged with their parent below
        bad_op = (isinstance(node, ast.BinOp) and not isinstance(node.op, (ast.Add, ast.Sub))) or \
            (isinstance(node, ast.UnaryOp) and not isinstance(node.op, (ast.UAdd, ast.USub)))
        if bad_op or not isinstance(node, _LITERAL_NODES):
            snippet = ast.get_source_segment(text, node) or type(node).__name__
            raise InputError(f"{source}: line {getattr(node, 'lineno', '?')}: {_short(snippet, 50)!s} is not a "
                             "literal; a .cameramodel may hold only literals and is never evaluated")
    try:
        return ast.literal_eval(tree)
    except (ValueError, TypeError, SyntaxError, RecursionError, MemoryError) as e:
        lineno = getattr(e, "lineno", None) or re.search(r"line (\d+)", str(e))
        where = f" (line {lineno.group(1) if hasattr(lineno, 'group') else lineno})" if lineno else ""
        raise InputError(f"{source}: not a mrcal .cameramodel: an expression{where} is not a literal") from None


def _read_cameramodel(p) -> Camera:
    source = str(p)
    text = read_input_text(p, "camera file", kind="json")  # a Python literal nests like JSON
    d = _parse_literal(text, source)
    if not isinstance(d, dict):
        raise InputError(f"{source}: a .cameramodel must be a dict, got {type(d).__name__}")
    # mrcal's legacy names: 'lens_model' and 'distortion_model' with DISTORTION_* values
    key = next((k for k in ("lensmodel", "lens_model", "distortion_model") if k in d), None)
    if key is None:
        raise InputError(f"{source}: missing key 'lensmodel'")
    for k in ("intrinsics", "imagersize"):
        if k not in d:
            raise InputError(f"{source}: missing key {k!r}")
    lensmodel = d[key]
    if not isinstance(lensmodel, str):
        raise InputError(f"{source}: '{key}' must be a string, got {_short(lensmodel)}")
    lensmodel = lensmodel.replace("DISTORTION", "LENSMODEL")
    if lensmodel.startswith(MRCAL_SPLINED_PREFIX):
        try:
            n = splined_config(lensmodel).parameters
        except InputError as e:
            raise InputError(f"{source}: {e}") from None
    elif lensmodel not in MRCAL_LENSMODELS:
        raise InputError(f"{source}: lens model {lensmodel} is not supported; pencilcal reads "
                         f"{', '.join(MRCAL_LENSMODELS)} and {MRCAL_SPLINED_PREFIX}_order=3_...")
    else:
        n = MRCAL_LENSMODELS[lensmodel]
    intr = d["intrinsics"]
    if not isinstance(intr, (list, tuple)):
        raise InputError(f"{source}: 'intrinsics' must be a list of {4 + n} numbers, got {_short(intr)}")
    if len(intr) != 4 + n:
        raise InputError(f"{source}: {lensmodel} needs {4 + n} intrinsics (fx, fy, cx, cy"
                         f"{', ' + str(n) + ' coefficients' if n else ''}), got {len(intr)}")
    intr = _matrix(list(intr), (4 + n,), "intrinsics", source)
    size = d["imagersize"]
    if not isinstance(size, (list, tuple)) or len(size) != 2:
        raise InputError(f"{source}: 'imagersize' must be [width, height], got {_short(size)}")
    fx, fy, cx, cy = intr[:4]
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    model = lensmodel if lensmodel.startswith(MRCAL_SPLINED_PREFIX) else "opencv" if n else "pinhole"
    return _build(source, model=model, K=K, dist=intr[4:],
                  width=_int_value(size[0], "imagersize", source),
                  height=_int_value(size[1], "imagersize", source))


def _cameramodel_text(camera, p) -> str:
    if camera.model == "fisheye":
        raise InputError(f"{p}: a fisheye camera cannot be written as a .cameramodel "
                         "(mrcal has no Kannala-Brandt lens model)")
    if camera.skew != 0:
        raise InputError(f"{p}: a camera with skew (K[0,1] = {camera.skew!r}) cannot be written as a .cameramodel")
    n = camera.dist.size
    if camera.spline is not None:
        cfg = camera.spline
        lensmodel = splined_name(cfg.Nx, cfg.Ny, cfg.fov_x_deg, cfg.order, mrcal=True)
    elif camera.model == "pinhole":
        lensmodel = "LENSMODEL_PINHOLE"
    else:
        lensmodel = next((m for m, c in MRCAL_LENSMODELS.items() if c == n and m != "LENSMODEL_PINHOLE"), None)
    if lensmodel is None:
        raise InputError(f"{p}: {n} opencv coefficients (sensor tilt) cannot be written as a .cameramodel; "
                         "mrcal takes 4, 5, 8 or 12")
    values = [camera.fx, camera.fy, camera.cx, camera.cy] + camera.dist.tolist()
    # repr() round-trips every double exactly (mrcal itself writes %.10g)
    intr = ", ".join(repr(float(v)) for v in values)
    return (
        "# Camera intrinsics written by pencilcal in mrcal's .cameramodel format.\n"
        "# Pixel (0,0) is the centre of the top-left pixel (mrcal and OpenCV alike).\n"
        "# The camera sits at the reference frame: extrinsics are zero.\n"
        "{\n"
        f"    'lensmodel':  '{lensmodel}',\n"
        "\n"
        "    # intrinsics are fx,fy,cx,cy,distortion0,distortion1,....\n"
        f"    'intrinsics': [ {intr} ],\n"
        "\n"
        "    # extrinsics are rt_fromref\n"
        "    'extrinsics': [ 0.0, 0.0, 0.0, 0.0, 0.0, 0.0 ],\n"
        "\n"
        f"    'imagersize': [ {camera.width}, {camera.height} ],\n"
        "}\n"
    )


# ---------------------------------------------------------------------- COLMAP
def camera_from_colmap(colmap_camera, source="COLMAP camera") -> Camera:
    """Convert a pycolmap.Camera to a Camera (principal point shifted by -0.5 px).

    SIMPLE_PINHOLE and PINHOLE become pinhole; SIMPLE_RADIAL, RADIAL and OPENCV become
    opencv with 4 coefficients; FULL_OPENCV becomes opencv with 8, or with 5 when
    k4 = k5 = k6 = 0 (as `camera_to_colmap` writes a 5-coefficient camera);
    OPENCV_FISHEYE becomes fisheye. Any other model is an InputError.
    """
    name = colmap_camera.model.name
    if name not in COLMAP_MODELS:
        raise InputError(f"{source}: COLMAP camera model {name} is not supported; pencilcal reads "
                         f"{', '.join(COLMAP_MODELS)}")
    p = np.array(colmap_camera.params, dtype=float)
    if p.size != len(COLMAP_MODELS[name]):
        raise InputError(f"{source}: COLMAP {name} needs {len(COLMAP_MODELS[name])} parameters, got {p.size}")
    if name in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = p[0]
        cx, cy = p[1], p[2]
        rest = p[3:]
    else:
        fx, fy, cx, cy = p[:4]
        rest = p[4:]
    if name in ("SIMPLE_PINHOLE", "PINHOLE"):
        model, dist = "pinhole", np.zeros(0)
    elif name == "SIMPLE_RADIAL":
        model, dist = "opencv", np.array([rest[0], 0.0, 0.0, 0.0])
    elif name == "RADIAL":
        model, dist = "opencv", np.array([rest[0], rest[1], 0.0, 0.0])
    elif name == "OPENCV":
        model, dist = "opencv", rest
    elif name == "FULL_OPENCV":
        model, dist = "opencv", rest[:5] if np.all(rest[5:] == 0) else rest
    else:
        model, dist = "fisheye", rest
    K = np.array([[fx, 0.0, cx - _COLMAP_SHIFT], [0.0, fy, cy - _COLMAP_SHIFT], [0.0, 0.0, 1.0]])
    return _build(source, model=model, width=int(colmap_camera.width), height=int(colmap_camera.height),
                  K=K, dist=dist)


def camera_to_colmap(camera: Camera, camera_id=1, source="COLMAP"):
    """Convert a Camera to the simplest pycolmap.Camera that holds it exactly.

    pinhole -> PINHOLE; opencv with 4 coefficients -> OPENCV; with 5 or 8 -> FULL_OPENCV
    (missing k4..k6 zero); fisheye -> OPENCV_FISHEYE. The principal point is shifted by
    +0.5 px to COLMAP's pixel convention. Skew or 12/14 coefficients raise InputError.

    Example
    -------
    >>> cam = Camera("pinhole", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
    >>> c = camera_to_colmap(cam)
    >>> c.model.name, c.params.tolist()
    ('PINHOLE', [500.0, 500.0, 320.0, 240.0])
    """
    import pycolmap

    if camera.skew != 0:
        raise InputError(f"{source}: COLMAP camera models have no skew; this camera has K[0,1] = {camera.skew!r}")
    if camera.spline is not None:
        raise InputError(f"{source}: COLMAP has no splined lens model; write the camera as .cameramodel or .json "
                         "(or convert it to an opencv model first)")
    core = [camera.fx, camera.fy, camera.cx + _COLMAP_SHIFT, camera.cy + _COLMAP_SHIFT]
    d = camera.dist.tolist()
    if camera.model == "pinhole":
        name, params = "PINHOLE", core
    elif camera.model == "fisheye":
        name, params = "OPENCV_FISHEYE", core + d
    elif len(d) == 4:
        name, params = "OPENCV", core + d
    elif len(d) in (5, 8):
        name, params = "FULL_OPENCV", core + (d + [0.0, 0.0, 0.0])[:8]
    else:
        raise InputError(f"{source}: COLMAP has no camera model for {len(d)} opencv coefficients "
                         "(thin prism / sensor tilt); it takes 4, 5 or 8")
    return pycolmap.Camera(model=name, width=camera.width, height=camera.height,
                           params=np.array(params, dtype=float), camera_id=int(camera_id))


def _check_cameras_bin(src, size, cameras=None):
    """pycolmap reads past the end of a truncated cameras.bin without complaint (it returns
    zeros or repeats values), so check the file's length against its own structure."""
    if size < 8:
        raise InputError(f"{src}: truncated COLMAP cameras.bin ({size} bytes)")
    with open(src, "rb") as f:
        (n,) = struct.unpack("<Q", f.read(8))
    # each camera takes at least 24 bytes (id, model, width, height) before its parameters
    if n > (size - 8) // 24:
        raise InputError(f"{src}: truncated or corrupt COLMAP cameras.bin (says {n} cameras in {size} bytes)")
    if cameras is not None:
        want = 8 + sum(24 + 8 * len(c.params) for c in cameras.values())
        if len(cameras) != n or want != size:
            raise InputError(f"{src}: truncated or corrupt COLMAP cameras.bin ({size} bytes where its "
                             f"{n} camera(s) need {want})")


def _read_colmap(p, camera_id) -> Camera:
    import pycolmap

    if p.is_dir():
        src = next((p / f for f in ("cameras.bin", "cameras.txt") if (p / f).is_file()), None)
        if src is None:
            raise InputError(f"{p}: folder holds no COLMAP cameras.bin or cameras.txt")
    else:
        src = p
    binary = src.suffix.lower() == ".bin"
    size = src.stat().st_size
    if binary:
        _check_cameras_bin(src, size)
    # pycolmap reads whole models: give it the cameras file beside an empty model, so the
    # rest of a large (or damaged) reconstruction is never read
    with tempfile.TemporaryDirectory(prefix="pencilcal-colmap-") as tmp:
        t = Path(tmp)
        if binary:
            shutil.copyfile(src, t / "cameras.bin")
            for f in ("images.bin", "points3D.bin"):
                (t / f).write_bytes(struct.pack("<Q", 0))
        else:
            shutil.copyfile(src, t / "cameras.txt")
            for f in ("images.txt", "points3D.txt"):
                (t / f).write_text("")
        rec = pycolmap.Reconstruction()
        try:
            (rec.read_binary if binary else rec.read_text)(str(t))
        except Exception as e:  # pycolmap raises ValueError/RuntimeError with C++ check text
            raise InputError(f"{src}: not a valid COLMAP cameras file: {_one_line(e)}") from None
        cameras = rec.cameras
        if binary:
            _check_cameras_bin(src, size, cameras)
        ids = sorted(int(i) for i in cameras.keys())
        if not ids:
            raise InputError(f"{src}: holds no cameras")
        if camera_id is None:
            if len(ids) > 1:
                raise InputError(f"{src}: holds cameras {ids}; choose one with a camera id (--camera-id)")
            camera_id = ids[0]
        if isinstance(camera_id, bool) or not isinstance(camera_id, Integral) or int(camera_id) not in ids:
            raise InputError(f"{src}: no camera with id {camera_id!r}; it holds {ids}")
        cam = cameras[int(camera_id)]
        return camera_from_colmap(cam, source=f"{src}: camera {int(camera_id)}")


def _write_colmap(p, camera, force, fmt):
    import pycolmap

    cam = camera_to_colmap(camera, 1, source=str(p))
    rec = pycolmap.Reconstruction()
    rec.add_camera(cam)
    if fmt in ("colmap_txt", "colmap_bin"):
        name = "cameras.txt" if fmt == "colmap_txt" else "cameras.bin"
        with atomic_path(p, force) as tmp:
            with tempfile.TemporaryDirectory(prefix=".pencilcal-colmap-", dir=tmp.parent) as d:
                (rec.write_text if fmt == "colmap_txt" else rec.write_binary)(d)
                shutil.copyfile(Path(d) / name, tmp)
        return
    # a model folder: keep the format of a model already there (readers prefer .bin)
    if p.exists() and not p.is_dir():
        raise InputError(f"{p}: exists and is not a folder")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"{p}: folder {parent} does not exist")
    present = sorted(f.name for f in p.iterdir() if f.stem in _COLMAP_FILES and f.suffix in (".txt", ".bin")) \
        if p.is_dir() else []
    if present and not force:
        raise InputError(f"{p}: already holds a COLMAP model ({', '.join(present)}); pass --force to overwrite it")
    binary = (p / "cameras.bin").is_file()
    tmp = staging_folder(p)
    try:
        (rec.write_binary if binary else rec.write_text)(str(tmp))
        with signals_deferred():  # Ctrl-C cannot land between two of the renames
            if not p.exists():
                os.replace(tmp, p)
            else:
                # cameras last: a reader never sees new cameras beside old images
                names = sorted(os.listdir(tmp), key=lambda f: f.startswith("cameras"))
                for f in names:
                    os.replace(tmp / f, p / f)
    finally:
        with contextlib.suppress(FileNotFoundError):
            shutil.rmtree(tmp)

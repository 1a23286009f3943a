"""The stereo file: where a second camera sits relative to the first.

A stereo calibration gives the rigid transform from the left camera's frame to the right
one's, ``p_right = R_right_from_left p_left + t_right_from_left`` (OpenCV camera frames,
the translation in the calibration's length unit: that of its board's square). Read from

- an OpenCV FileStorage file (``.yml``, ``.yaml``, ``.xml``, ``.json``) as
  ``cv2.stereoCalibrate``'s samples write it (``extrinsics.yml`` of OpenCV's stereo_calib:
  ``R``, ``T``, and ``R1 R2 P1 P2 Q`` which are ignored): ``R`` a 3x3 matrix or a 3-vector
  rotation (Rodrigues), ``T`` three numbers;
- a JSON or YAML mapping with ``R_right_from_left`` (3x3) and ``t_right_from_left`` (3),
  also under a ``stereo`` key.

OpenCV's ``R`` and ``T`` are exactly ``R_right_from_left`` and ``t_right_from_left``
(stereoCalibrate: "R: rotation from the first camera's coordinate system to the second's").
A rotation more than 1e-3 from orthonormal is refused; a nearly orthonormal one (written
with few digits) is projected onto the nearest rotation. Optionally the calibration's
uncertainty, ``cov_right_from_left``: the 6x6 covariance of the rotation's error as a
rotation vector [rad] (``R = exp(w) R_right_from_left``) and of the translation [length],
in that order, symmetric and positive semi-definite.

`pair_frames` pairs the two eyes' frames by their file names (``left/0001.png`` with
``right/0001.png``, ``img_L_0001.png`` with ``img_R_0001.png``), in order only where the
names say nothing.

`write_stereo` writes a rig back: OpenCV FileStorage (``R``, ``T``, as stereoCalibrate's
samples do) for ``.yml``, ``.yaml`` and ``.xml``; the JSON mapping for ``.json``; the
covariance, where the rig has one, as ``cov_right_from_left`` in both.

>>> import tempfile, os, json
>>> d = tempfile.mkdtemp()
>>> p = os.path.join(d, "rig.json")
>>> _ = open(p, "w").write(json.dumps({"R_right_from_left": np.eye(3).tolist(), "t_right_from_left": [-5, 0, 0]}))
>>> rig = read_stereo(p)
>>> rig.t_right_from_left.tolist(), round(rig.baseline, 6)
([-5.0, 0.0, 0.0], 5.0)
>>> write_stereo(os.path.join(d, "extrinsics.yml"), rig)
>>> read_stereo(os.path.join(d, "extrinsics.yml")).t_right_from_left.tolist()
[-5.0, 0.0, 0.0]
"""
from __future__ import annotations

from dataclasses import dataclass
import re
from pathlib import Path, PurePath

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.frames import project_to_rotation, rotation_from_rotvec
from pencilcal.toolkit.io.files import atomic_path, load_structured, read_input_text, write_json

__all__ = ["StereoRig", "read_stereo", "write_stereo", "pair_frames", "ORTHONORMAL_TOLERANCE"]

# Largest |R^T R - I| (any entry) of a rotation read from a file; below it R is projected
# onto the nearest rotation, above it refused.
ORTHONORMAL_TOLERANCE = 1e-3

_ROTATION_KEYS = ("R_right_from_left", "R")
_TRANSLATION_KEYS = ("t_right_from_left", "T", "t")


@dataclass(frozen=True)
class StereoRig:
    """The right camera's pose relative to the left one.

    R_right_from_left: (3, 3) rotation; t_right_from_left: (3,) translation [the
    calibration's length unit]; ``p_right = R p_left + t``. source: the file it came from.
    cov: (6, 6) or None, the covariance of the rotation's error (rotation vector [rad],
    ``R = exp(w) R_right_from_left``) and of the translation [length].
    """

    R_right_from_left: np.ndarray
    t_right_from_left: np.ndarray
    source: str = ""
    cov: np.ndarray | None = None

    @property
    def baseline(self) -> float:
        """Distance between the two camera centres [length]: |t| (the right centre is
        ``-R^T t`` in the left frame)."""
        return float(np.linalg.norm(self.t_right_from_left))

    @property
    def right_centre_in_left(self) -> np.ndarray:
        """(3,) the right camera's centre in the left camera frame [length]."""
        return -self.R_right_from_left.T @ self.t_right_from_left

    def to_dict(self) -> dict:
        """``{file, R_right_from_left, t_right_from_left, baseline}`` as plain lists."""
        out = {"file": self.source, "R_right_from_left": self.R_right_from_left.tolist(),
               "t_right_from_left": self.t_right_from_left.tolist(), "baseline": self.baseline}
        if self.cov is not None:
            out["cov_right_from_left"] = np.asarray(self.cov, float).tolist()
        return out


def _filestorage(p):
    """The top-level keys of an OpenCV FileStorage file: matrices as float arrays, numbers
    as floats, the rest as None. InputError naming the file when it cannot be parsed."""
    import cv2

    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as e:
        cause = e.__cause__ if isinstance(e, SystemError) and e.__cause__ is not None else e
        first = (str(cause).strip().splitlines() or [type(cause).__name__])[-1]
        raise InputError(f"{p}: not a valid OpenCV FileStorage file: {first}") from None
    if not fs.isOpened():
        raise InputError(f"{p}: cannot open as an OpenCV FileStorage file")
    try:
        root = fs.root()
        out = {}
        for k in (root.keys() if root.isMap() else []):
            node = root.getNode(k)
            if node.isMap() and "data" in node.keys():
                m = node.mat()
                out[k] = None if m is None else np.asarray(m, float)
            elif node.isSeq():
                vals = [node.at(i) for i in range(node.size())]
                out[k] = (np.array([v.real() for v in vals], float) if vals and all(v.isReal() or v.isInt()
                                                                                    for v in vals) else None)
            elif node.isReal() or node.isInt():
                out[k] = float(node.real())
            else:
                out[k] = None
        return out
    except (cv2.error, SystemError) as e:
        raise InputError(f"{p}: cannot read OpenCV FileStorage file: {str(e).strip().splitlines()[-1]}") from None
    finally:
        fs.release()


def _numbers(value, key, p):
    """Flat float array of a file's value (a matrix, nested lists, or OpenCV's JSON
    ``{"type_id": "opencv-matrix", "rows", "cols", "data"}``), or InputError naming the
    file and key."""
    if isinstance(value, dict) and "data" in value:
        value = value["data"]
    try:
        a = np.asarray(value, float).ravel()
    except (TypeError, ValueError):
        raise InputError(f"{p}: '{key}' must hold numbers only") from None
    if not np.all(np.isfinite(a)):
        raise InputError(f"{p}: '{key}' must be finite numbers")
    return a


def _rotation(value, key, p):
    a = _numbers(value, key, p)
    if a.size == 3:
        return rotation_from_rotvec(a)
    if a.size != 9:
        raise InputError(f"{p}: '{key}' must be a 3x3 rotation matrix or a 3-vector rotation, got {a.size} numbers")
    R = a.reshape(3, 3)
    off = float(np.max(np.abs(R.T @ R - np.eye(3))))
    if off > ORTHONORMAL_TOLERANCE or np.linalg.det(R) <= 0:
        det = np.linalg.det(R)
        raise InputError(f"{p}: '{key}' is not a rotation (R^T R differs from I by {off:.2g}, det {det:.3g})")
    return project_to_rotation(R)


def _pick(data, keys):
    for k in keys:
        if k in data and data[k] is not None:
            return k, data[k]
    return None, None


def read_stereo(path) -> StereoRig:
    """Read a stereo calibration (module docstring) as a `StereoRig`.

    path: an OpenCV FileStorage file with ``R`` and ``T``, or a JSON / YAML file with
    ``R_right_from_left`` and ``t_right_from_left``. InputError, one line naming the file
    and the problem (no such file, not parseable, a key missing, not a rotation, a zero
    baseline).
    """
    p = Path(path)
    text = read_input_text(p, "stereo file")
    if p.suffix.lower() in (".xml",) or text.lstrip().startswith("%YAML"):
        data = _filestorage(p)
    else:
        data = load_structured(p, "stereo file")
        if isinstance(data, dict) and isinstance(data.get("stereo"), dict):
            data = data["stereo"]
        if not isinstance(data, dict):
            raise InputError(f"{p}: expected a mapping with R_right_from_left and t_right_from_left (or R and T)")
    rk, rv = _pick(data, _ROTATION_KEYS)
    tk, tv = _pick(data, _TRANSLATION_KEYS)
    if rk is None or tk is None:
        missing = " and ".join(w for w, k in (("R", rk), ("T", tk)) if k is None)
        hint = ""
        if "imagelist" in data or not data:
            hint = " (an image list, the input of OpenCV's stereo_calib; its output extrinsics.yml holds R and T)"
        elif "M1" in data or "camera_matrix" in data:
            hint = " (a file of intrinsics; the stereo pose is in the calibration's extrinsics file)"
        raise InputError(f"{p}: no {missing} (R_right_from_left, t_right_from_left) in the stereo file{hint}")
    R = _rotation(rv, rk, p)
    t = _numbers(tv, tk, p)
    if t.size != 3:
        raise InputError(f"{p}: '{tk}' must be three numbers, got {t.size}")
    if not np.linalg.norm(t) > 0:
        raise InputError(f"{p}: '{tk}' is zero: the two cameras share a centre (no baseline to triangulate with)")
    cov = None
    if data.get("cov_right_from_left") is not None:
        c = _numbers(data["cov_right_from_left"], "cov_right_from_left", p)
        if c.size != 36:
            raise InputError(f"{p}: 'cov_right_from_left' must be a 6x6 matrix, got {c.size} numbers")
        cov = c.reshape(6, 6)
        if not np.allclose(cov, cov.T, rtol=1e-6, atol=1e-15) or np.linalg.eigvalsh(0.5 * (cov + cov.T))[0] < \
                -1e-9 * max(float(np.max(np.abs(cov))), 1e-300):
            raise InputError(f"{p}: 'cov_right_from_left' is not a covariance (symmetric, positive semi-definite)")
        cov = 0.5 * (cov + cov.T)
    return StereoRig(R, t, str(p), cov)


_FILESTORAGE_SUFFIXES = (".yml", ".yaml", ".xml")


def write_stereo(path, rig: StereoRig, force=False) -> None:
    """Write a stereo calibration that `read_stereo` (and OpenCV) reads back.

    path: ``.yml``, ``.yaml`` or ``.xml`` for an OpenCV FileStorage file with ``R`` (3x3)
    and ``T`` (3x1), exactly as ``cv2.stereoCalibrate``'s samples write them; ``.json`` for
    the mapping ``{R_right_from_left, t_right_from_left}``. The rig's covariance, if any,
    goes with it as ``cov_right_from_left`` (6x6). Written atomically; an existing file is
    an InputError unless ``force``; so is any other suffix.
    """
    import cv2

    p = Path(path)
    suffix = p.suffix.lower()
    R = np.asarray(rig.R_right_from_left, float).reshape(3, 3)
    t = np.asarray(rig.t_right_from_left, float).reshape(3)
    cov = None if rig.cov is None else np.asarray(rig.cov, float).reshape(6, 6)
    if suffix == ".json":
        out = {"R_right_from_left": R, "t_right_from_left": t}
        if cov is not None:
            out["cov_right_from_left"] = cov
        write_json(p, out, force=force)
        return
    if suffix not in _FILESTORAGE_SUFFIXES:
        raise InputError(f"{p}: a stereo file is written as .yml, .yaml, .xml (OpenCV FileStorage) or .json")
    with atomic_path(p, force) as tmp:  # same suffix: FileStorage picks its format from it
        fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
        if not fs.isOpened():
            raise InputError(f"{p}: cannot write an OpenCV FileStorage file")
        try:
            fs.write("R", R)
            fs.write("T", t.reshape(3, 1))
            if cov is not None:
                fs.write("cov_right_from_left", cov)
        finally:
            fs.release()


# a side's token in a file name: left/right, l/r, as a word of its own or next to digits
_SIDE = re.compile(r"(?i)(?<![a-z])(left|right|l|r)(?![a-z])")


def _stem(name):
    """A frame's name without folder and extension (a video's frame names have none)."""
    return PurePath(str(name)).stem


def _sideless(name):
    """The stem with the eye's token taken out (``img_L_0001`` -> ``img_0001``)."""
    words = [w for w in re.split(r"[_\-. ]+", _SIDE.sub(" ", _stem(name))) if w]
    return "_".join(words)


def pair_frames(names_left, names_right):
    """[(i, j)]: which frame j of the right view was taken with frame i of the left one.

    names_left, names_right: each view's frame names (image file names or paths, a video's
    ``frame_000012``; None or "" where a frame has none). Frames pair by their stems, the
    names without folder and extension (``left/0001.png`` with ``right/0001.jpg``); where
    the stems differ in every frame, by the stems without the eye's token (``left``,
    ``right``, ``L``, ``R`` as a word or beside digits: ``L_0001`` with ``R_0001``,
    ``frame3_left`` with ``frame3_right``). When the names pair some frames but not all,
    InputError says which left frame has no partner (a frame dropped in one eye pairs
    every later one wrongly in order). Only where the names say nothing (a frame without
    a name, names repeated in a view, or no stem shared by the two views) are the frames
    paired in order, which needs as many in each view (InputError otherwise).

    >>> pair_frames(["a/0002.png", "a/0001.png"], ["b/0001.png", "b/0002.png"])
    [(0, 1), (1, 0)]
    >>> pair_frames(["img_L_7.png", "img_L_8.png"], ["img_R_8.png", "img_R_7.png"])
    [(0, 1), (1, 0)]
    >>> pair_frames(["x.png", "y.png"], ["p.png", "q.png"])      # the names say nothing
    [(0, 0), (1, 1)]
    """
    names_left, names_right = list(names_left), list(names_right)
    if all(names_left) and all(names_right):
        best = None
        for key in (_stem, _sideless):
            kl, kr = [key(n) for n in names_left], [key(n) for n in names_right]
            if len(set(kl)) < len(kl) or len(set(kr)) < len(kr):
                continue  # a view's names repeat under this key: they do not tell frames apart
            by_key = {k: j for j, k in enumerate(kr)}
            shared = [k for k in kl if k in by_key]
            if shared and len(shared) == len(kl) == len(kr):
                return [(i, by_key[k]) for i, k in enumerate(kl)]
            if shared and (best is None or len(shared) > best[0]):
                lone = [n for n, k in zip(names_left, kl) if k not in by_key]
                lone_r = [n for n, k in zip(names_right, kr) if k not in set(kl)]
                best = (len(shared), lone, lone_r)
        if best is not None:
            n, lone, lone_r = best
            which = (f"left frame {lone[0]} has no right frame of its name" if lone
                     else f"right frame {lone_r[0]} has no left frame of its name")
            raise InputError(f"the stereo pair's frames do not pair by name: {which} ({n} of {len(names_left)} left "
                             f"and {len(names_right)} right frames pair); give both views the same frames")
    if len(names_left) != len(names_right):
        raise InputError(f"the stereo pair's views have {len(names_left)} and {len(names_right)} frames and their "
                         "names do not pair them")
    return [(i, i) for i in range(len(names_left))]

"""The robot's kinematics file: the tool's pose in the robot base, one row a frame.

A CSV file (docs/formats.md), one header row, then one row per frame; ``#`` starts a
comment line. Columns (any order, names case-insensitive):

- ``image`` (the frame's image name, as in lines.json) or ``frame`` (its 0-based index in
  the sequence): which frame the pose belongs to;
- the tool frame's origin in the base frame: ``x_mm, y_mm, z_mm``, or ``x_m, y_m, z_m``
  in metres (as the dVRK and ROS publish it; read as mm);
- its orientation, ``R_base_from_tool``: a unit quaternion ``qw, qx, qy, qz`` (Hamilton,
  as ROS and Eigen), or the matrix ``r11, r12, ..., r33`` row by row;
- optionally ``sigma_deg`` and ``sigma_mm``: the kinematics' error of the shaft's axis, an
  isotropic angle [deg] and offset [mm] at the tool origin (default 0: taken as exact).

The shaft's axis is the tool frame's z axis through its origin (the dVRK's tool frame with
the wrist straight); `ToolPoses.axes` takes another axis of the tool frame.

Example
-------
>>> import tempfile, os
>>> p = os.path.join(tempfile.mkdtemp(), "kin.csv")
>>> _ = open(p, "w").write("image,x_m,y_m,z_m,qw,qx,qy,qz\\na.png,0.01,0,-0.1,1,0,0,0\\n")
>>> poses = read_tool_poses(p)
>>> poses.keys, poses.positions.tolist()
(['a.png'], [[10.0, 0.0, -100.0]])
"""
from __future__ import annotations

import csv
from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.frames import normalize, project_to_rotation, rotation_from_quaternion
from pencilcal.toolkit.io.files import read_input_text

__all__ = ["ToolPoses", "read_tool_poses", "QUATERNION", "MATRIX"]

#: The quaternion's columns, in their order (w first).
QUATERNION = ("qw", "qx", "qy", "qz")
#: The rotation matrix's columns, row by row.
MATRIX = tuple(f"r{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3))

# A unit quaternion or rotation matrix written with few digits is accepted within this and
# made exact; beyond it a column is likely misplaced.
_UNIT_TOL = 1e-3


@dataclass(frozen=True, eq=False)
class ToolPoses:
    """The tool's poses in the robot base (`read_tool_poses`).

    keys: N image names (str) or frame indices (int); positions: (N, 3) the tool origin in
    the base frame [mm]; R_base_from_tool: (N, 3, 3); sigma_deg, sigma_mm: (N,) the
    kinematics' error of the axis (0: exact); source: the file, for messages; rows: (N,)
    the file's line number of each pose.
    """

    keys: list
    positions: np.ndarray
    R_base_from_tool: np.ndarray
    sigma_deg: np.ndarray
    sigma_mm: np.ndarray
    source: str
    rows: np.ndarray

    def axes(self, tool_axis=(0.0, 0.0, 1.0)):
        """(points (N, 3) [mm], unit directions (N, 3)): the shaft's axis in the base frame,
        the tool frame's `tool_axis` through its origin.

        >>> ToolPoses(["a"], np.zeros((1, 3)), np.eye(3)[None], np.zeros(1), np.zeros(1), "", np.ones(1)
        ...           ).axes((1.0, 0, 0))[1].tolist()
        [[1.0, 0.0, 0.0]]
        """
        return self.positions, normalize(self.R_base_from_tool @ normalize(tool_axis))

    def index(self, names, first=0):
        """Per frame its pose's row in this file, or -1: names (F,) the frames' image names,
        matched by image name (``image``) or by position in the sequence (``frame``; first:
        the sequence index of names[0], for a part of the sequence)."""
        at = {k: i for i, k in enumerate(self.keys)}
        if self.keys and isinstance(self.keys[0], int):
            return np.array([at.get(first + f, -1) for f in range(len(names))], int)
        return np.array([at.get(str(n), -1) for n in names], int)


def _numbers(row, cols, p, line):
    """The floats of `cols` in one row; InputError naming the file and line otherwise."""
    out = []
    for name, k in cols:
        try:
            v = float(row[k])
        except (ValueError, IndexError):
            raise InputError(f"{p}:{line}: {name} is not a number ({row[k] if k < len(row) else 'missing'!r})") \
                from None
        if not np.isfinite(v):
            raise InputError(f"{p}:{line}: {name} is not finite")
        out.append(v)
    return np.array(out)


def _columns(head, p, line):
    """(key column (name, index), position columns, unit factor to mm, rotation kind and
    columns, sigma columns or None) of the header (the file's line `line`); InputError
    naming what is missing."""
    at = {h: k for k, h in enumerate(head)}
    if len(at) != len(head):
        raise InputError(f"{p}:{line}: a column is named twice")
    key = next(((n, at[n]) for n in ("image", "frame") if n in at), None)
    if key is None:
        raise InputError(f"{p}:{line}: no 'image' or 'frame' column (the frame each pose belongs to)")
    for names, scale in ((("x_mm", "y_mm", "z_mm"), 1.0), (("x_m", "y_m", "z_m"), 1000.0)):
        if all(n in at for n in names):
            position = [(n, at[n]) for n in names]
            break
    else:
        raise InputError(f"{p}:{line}: no tool position: columns x_mm,y_mm,z_mm (or x_m,y_m,z_m in metres)")
    if all(n in at for n in QUATERNION):
        rotation = ("quaternion", [(n, at[n]) for n in QUATERNION])
    elif all(n in at for n in MATRIX):
        rotation = ("matrix", [(n, at[n]) for n in MATRIX])
    else:
        raise InputError(f"{p}:{line}: no tool orientation: columns qw,qx,qy,qz (unit quaternion) or r11..r33")
    sigmas = [(n, at[n]) for n in ("sigma_deg", "sigma_mm") if n in at]
    if len(sigmas) == 1:
        raise InputError(f"{p}:{line}: sigma_deg and sigma_mm go together")
    return key, position, scale, rotation, sigmas or None


def _rotation(kind, v, p, line):
    """R_base_from_tool of one row's numbers; InputError when not a rotation."""
    if kind == "quaternion":
        n = float(np.linalg.norm(v))
        if abs(n - 1.0) > _UNIT_TOL:
            raise InputError(f"{p}:{line}: the quaternion (qw,qx,qy,qz) has norm {n:.4g}, not 1")
        return rotation_from_quaternion(v)
    M = v.reshape(3, 3)
    R = project_to_rotation(M)
    if np.linalg.det(M) < 0 or np.max(np.abs(M - R)) > _UNIT_TOL:
        raise InputError(f"{p}:{line}: r11..r33 is not a rotation matrix")
    return R


def read_tool_poses(path) -> ToolPoses:
    """The kinematics file (module docstring) as `ToolPoses`. InputError naming the file and
    its line for anything it cannot take: a missing column, a cell that is not a finite
    number, a quaternion or matrix that is not a rotation, a negative sigma, a frame listed
    twice, no rows."""
    p = str(path)
    text = read_input_text(path, "kinematics file", kind="json")
    lines = [(k + 1, ln) for k, ln in enumerate(text.splitlines()) if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise InputError(f"{p}: kinematics file has no header")
    head_line, head = lines[0]
    head = [c.strip().lower() for c in next(csv.reader([head]))]
    key, position, scale, (kind, rot_cols), sigmas = _columns(head, p, head_line)
    keys, pos, rots, sig, rows, seen = [], [], [], [], [], {}
    for line, text_row in lines[1:]:
        row = [c.strip() for c in next(csv.reader([text_row]))]
        if len(row) != len(head):
            raise InputError(f"{p}:{line}: {len(row)} fields, the header has {len(head)}")
        k = row[key[1]]
        if key[0] == "frame":
            if not (k.isascii() and k.isdigit()):  # str.isdigit alone takes "²", which int() refuses
                raise InputError(f"{p}:{line}: frame must be a frame index (0, 1, ...), got {k!r}")
            k = int(k)
        elif not k:
            raise InputError(f"{p}:{line}: the image name is empty")
        if k in seen:
            raise InputError(f"{p}:{line}: {key[0]} {k!r} is listed twice (also line {seen[k]})")
        seen[k] = line
        keys.append(k)
        pos.append(_numbers(row, position, p, line) * scale)
        rots.append(_rotation(kind, _numbers(row, rot_cols, p, line), p, line))
        s = _numbers(row, sigmas, p, line) if sigmas else np.zeros(2)
        if np.any(s < 0):
            raise InputError(f"{p}:{line}: sigma_deg and sigma_mm must not be negative")
        sig.append(s)
        rows.append(line)
    if not keys:
        raise InputError(f"{p}: kinematics file has a header (line {head_line}) but no poses")
    sig = np.array(sig, float)
    return ToolPoses(keys, np.array(pos, float), np.array(rots, float), sig[:, 0], sig[:, 1], p, np.array(rows))

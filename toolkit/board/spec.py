"""Calibration boards: the board file, OpenCV board objects and corner coordinates.

Board file (``board.yaml`` or ``.json``, docs/formats.md)::

    type: charuco            # charuco | chessboard
    squares: [19, 26]        # charuco: squares along x and y; chessboard: inner corners [cols, rows]
    square: 5.0              # square side (length unit)
    marker: 4.0              # charuco only
    dictionary: DICT_4X4_250 # any cv2.aruco predefined dictionary name
    legacy: true             # charuco only: layout of OpenCV < 4.6 (default false)

Board frame = target frame (frames.py): x to the right along the first row of squares, y
down the sheet, z into the sheet, origin at the outer corner of the first square (OpenCV's
ChArUco convention). ChArUco corner k is the inner chessboard corner number k in OpenCV's
row-major order, at ((i + 1) square, (j + 1) square, 0); a chessboard's inner corner
(i, j) sits at (i square, j square, 0) with the first detected corner as the origin.

Example
-------
>>> b = board_from_dict({"type": "charuco", "squares": [5, 7], "square": 40.0,
...                      "marker": 20.0, "dictionary": "DICT_6X6_250"})
>>> b.corner_count, b.object_points()[:2].tolist()
(24, [[40.0, 40.0, 0.0], [80.0, 40.0, 0.0]])
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import atomic_write, load_structured

__all__ = ["Board", "board_from_dict", "read_board", "write_board", "aruco_dictionary"]


def aruco_dictionary(name, source="board"):
    """The cv2.aruco predefined dictionary called `name` (e.g. "DICT_4X4_250")."""
    import cv2

    names = sorted(d for d in dir(cv2.aruco) if d.startswith("DICT_"))
    if not isinstance(name, str) or name not in names:
        raise InputError(f"{source}: unknown ArUco dictionary {name!r}; expected one of {', '.join(names)}")
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


@dataclass(frozen=True)
class Board:
    """A ChArUco board or a chessboard.

    type: "charuco" | "chessboard".
    squares: (2,) charuco: squares along x and y; chessboard: inner corners (cols, rows).
    square: square side (length unit). marker: marker side (charuco). dictionary: name.
    legacy: charuco layout of OpenCV < 4.6.
    """

    type: str
    squares: tuple
    square: float
    marker: float | None = None
    dictionary: str | None = None
    legacy: bool = False

    @property
    def inner_corners(self):
        """(cols, rows) of inner chessboard corners."""
        if self.type == "charuco":
            return (self.squares[0] - 1, self.squares[1] - 1)
        return tuple(self.squares)

    @property
    def corner_count(self) -> int:
        c, r = self.inner_corners
        return c * r

    def object_points(self):
        """(corner_count, 3) board-frame coordinates of every corner id, row-major."""
        c, r = self.inner_corners
        j, i = np.mgrid[0:r, 0:c]
        off = 1.0 if self.type == "charuco" else 0.0
        pts = np.stack([(i.ravel() + off) * self.square, (j.ravel() + off) * self.square, np.zeros(c * r)], -1)
        return pts.astype(float)

    @property
    def size(self):
        """(width, height) of the printed pattern in length units (squares for charuco,
        the squares around the inner corners for a chessboard)."""
        if self.type == "charuco":
            return (self.squares[0] * self.square, self.squares[1] * self.square)
        return ((self.squares[0] + 1) * self.square, (self.squares[1] + 1) * self.square)

    def cv2_board(self):
        """The cv2.aruco.CharucoBoard (charuco only)."""
        import cv2

        if self.type != "charuco":
            raise InputError("a chessboard has no ArUco board object")
        b = cv2.aruco.CharucoBoard(tuple(int(s) for s in self.squares), float(self.square), float(self.marker),
                                   aruco_dictionary(self.dictionary))
        b.setLegacyPattern(bool(self.legacy))
        return b

    def to_dict(self):
        d = {"type": self.type, "squares": list(self.squares), "square": self.square}
        if self.type == "charuco":
            d.update(marker=self.marker, dictionary=self.dictionary, legacy=self.legacy)
        return d


# a board's lengths, in its unit (mm: a micron to a kilometre): past them OpenCV's board
# fails inside (a square of 1e-300 mm was an internal error) and the layout overflows
_LENGTH_RANGE = (1e-6, 1e6)


def _positive(d, key, source):
    v = d.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v <= 0:
        raise InputError(f"{source}: '{key}' must be a positive number, got {v!r}")
    lo, hi = _LENGTH_RANGE
    if not lo <= v <= hi:
        raise InputError(f"{source}: '{key}' must be from {lo:g} to {hi:g} (the board's length unit), got {v!r}")
    return float(v)


def board_from_dict(d, source="board"):
    """Validate a parsed board file into a Board; InputError naming `source` on any problem."""
    if not isinstance(d, dict):
        raise InputError(f"{source}: expected a mapping with 'type', 'squares', 'square'")
    kind = d.get("type")
    if kind not in ("charuco", "chessboard"):
        raise InputError(f"{source}: 'type' must be charuco or chessboard, got {kind!r}")
    known = {"type", "squares", "square", "marker", "dictionary", "legacy", "name", "units"}
    unknown = sorted(set(d) - known)
    if unknown:
        raise InputError(f"{source}: unknown key(s) {unknown}")
    sq = d.get("squares")
    if (not isinstance(sq, (list, tuple)) or len(sq) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) for v in sq)):
        raise InputError(f"{source}: 'squares' must be two integers, got {sq!r}")
    minimum = 3 if kind == "charuco" else 2
    if min(sq) < minimum:
        raise InputError(f"{source}: 'squares' must be at least {minimum} each for a {kind}, got {sq!r}")
    square = _positive(d, "square", source)
    if kind == "chessboard":
        return Board("chessboard", (int(sq[0]), int(sq[1])), square)
    marker = _positive(d, "marker", source)
    if marker >= square:
        raise InputError(f"{source}: 'marker' ({marker}) must be smaller than 'square' ({square})")
    name = d.get("dictionary")
    aruco_dictionary(name, source)
    legacy = d.get("legacy", False)
    if not isinstance(legacy, bool):
        raise InputError(f"{source}: 'legacy' must be true or false, got {legacy!r}")
    board = Board("charuco", (int(sq[0]), int(sq[1])), square, marker, name, legacy)
    # the board needs enough markers in the dictionary

    n_markers = (sq[0] * sq[1]) // 2
    dict_size = aruco_dictionary(name).bytesList.shape[0]
    if n_markers > dict_size:
        raise InputError(f"{source}: {n_markers} markers do not fit in {name} ({dict_size} markers)")
    return board


def read_board(path):
    """Read a board file (.yaml/.yml/.json)."""
    return board_from_dict(load_structured(path, "board file"), source=str(path))


def write_board(path, board, force=False):
    """Write a board file; YAML or JSON by extension."""
    import json
    import yaml

    p = Path(path)
    text = json.dumps(board.to_dict(), indent=1) + "\n" if p.suffix.lower() == ".json" else \
        yaml.safe_dump(board.to_dict(), default_flow_style=None, sort_keys=False)
    atomic_write(p, text, force)

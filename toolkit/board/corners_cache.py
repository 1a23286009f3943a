"""mrcal's corner cache (``corners.vnl``): board detections as a vnlog table.

``mrcal-calibrate-cameras --corners-cache corners.vnl`` reads the corners of a grid
detector from this file instead of running mrgingham, so a calibration can be redone
(or cross-checked) with mrcal from pencilcal's detections. The format, as mrcal documents
it (doc/how-to-calibrate.org, doc/recipes.org "Using a non-mrgingham corner detector",
and the parser ``mrcal.compute_chessboard_corners`` in mrcal/calibration.py)::

    # filename x y level
    img_000.png 412.837 301.112 0
    img_000.png 455.001 300.873 0
    img_000.png - - -
    ...
    img_001.png - - -

- The first ``#`` line is the legend (vnlog); other lines starting with ``#`` are comments
  (pencilcal writes ``##`` comments after the legend, naming the board and the mrcal
  options that match it). Fields are whitespace-separated, ``-`` is an empty field.
- Every image with a detection has *exactly* ``object-width-n * object-height-n`` rows,
  contiguous, in the grid's row-major order: the first row of corners left to right, then
  the next row (the corner in row i, column j is record ``i * width_n + j``).
  A corner that was not detected is a row ``filename - - -`` (mrcal: a level of ``-`` or
  < 0 means "skip this point"; this is how partial boards are given).
- An image with no detection is one row ``filename - - -`` (mrcal drops it).
- ``level`` is the decimation level at which the corner was found: 0 = full resolution,
  1 = half, ...; mrcal weights a corner by 2^-level. pencilcal detects at full
  resolution, so every detected corner has level 0.
- x, y are pixels with (0, 0) at the centre of the top-left pixel: mrcal's convention
  (``mrcal.sample_imager`` spans 0 .. width-1) and OpenCV's, so pencilcal's corners are
  written unchanged. mrcal's parser also drops corners with x < 0 or y < 0 (possible
  only within half a pixel of the border).

Grid mapping: the grid is the board's inner chessboard corners, ``Board.inner_corners``
= (width_n, height_n) -- for a ChArUco board (squaresX - 1, squaresY - 1), and the grid
order is OpenCV's ChArUco corner id order; for a chessboard the inner corners as
detected. mrcal's object spacing is the board's ``square`` (mrcal documents metres; pass
the value in metres, or keep the board's unit and read mrcal's lengths in it). mrcal
ignores images whose detection has no more than 2 * min(width_n, height_n) corners (its
default ``Npoint_observations_per_board_min``).

Filenames: mrcal looks an image up by the path written here (relative paths are tried
against the current folder, then the folder of corners.vnl), so writers should use the
path relative to the cache's folder. A name may not contain whitespace or start with
``#`` (vnlog could not read it back).

Example
-------
>>> import os, tempfile, numpy as np
>>> from pencilcal.toolkit.board.spec import board_from_dict
>>> from pencilcal.toolkit.board.detect import BoardDetection
>>> board = board_from_dict({"type": "chessboard", "squares": [3, 2], "square": 10.0})
>>> det = BoardDetection(np.array([0, 1, 2, 4]), np.array([[10.0, 20.0], [20.5, 20.0], [31.0, 20.25],
...                      [20.0, 30.0]]), (64, 48), np.zeros(0, int), np.zeros((0, 4, 2)))
>>> text = corners_vnl_text([("a.png", det), ("b.png", None)], board)
>>> print("\\n".join(l for l in text.splitlines() if not l.startswith("##")))
# filename x y level
a.png 10.0 20.0 0
a.png 20.5 20.0 0
a.png 31.0 20.25 0
a.png - - -
a.png 20.0 30.0 0
a.png - - -
b.png - - -
>>> path = os.path.join(tempfile.mkdtemp(), "corners.vnl")
>>> write_corners_vnl(path, [("a.png", det), ("b.png", None)], board)
>>> [(name, None if d is None else d.ids.tolist()) for name, d in read_corners_vnl(path, board)]
[('a.png', [0, 1, 2, 4]), ('b.png', None)]
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from pencilcal.toolkit.board.detect import BoardDetection
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import atomic_write

__all__ = ["write_corners_vnl", "read_corners_vnl", "corners_vnl_text", "check_image_name", "LEGEND"]

#: The legend mrgingham writes and mrcal-calibrate-cameras expects.
LEGEND = "# filename x y level"

_BAD_NAME = re.compile(r"\s")


def check_image_name(name):
    """InputError unless `name` can be written as a vnlog field (no whitespace, no leading
    '#', not '-')."""
    if not isinstance(name, str) or not name:
        raise InputError(f"corners.vnl: image name must be a non-empty string, got {name!r}")
    if _BAD_NAME.search(name) or name.startswith("#") or name == "-":
        raise InputError(f"corners.vnl: image name {name!r} cannot be written to a vnlog "
                         "(no whitespace, no leading '#', not '-'); rename the file")


def _num(v):
    # repr round-trips every double exactly; vnlog and mrcal parse it with float()
    return repr(float(v))


def corners_vnl_text(records, board) -> str:
    """The text of a corners.vnl for `records` (see `write_corners_vnl`)."""
    w_n, h_n = board.inner_corners
    n = w_n * h_n
    lines = [LEGEND,
             f"## written by pencilcal: {board.type} board, grid of {w_n} x {h_n} inner corners "
             f"(row-major), spacing {board.square:g} (board length unit)",
             f"## mrcal-calibrate-cameras --corners-cache THIS_FILE --object-width-n {w_n} "
             f"--object-height-n {h_n} --object-spacing {board.square:g} ...",
             "## pixels: (0,0) is the centre of the top-left pixel; level 0 = full resolution; "
             "'-' = not detected"]
    seen = set()
    for item in records:
        try:
            name, det = item
        except (TypeError, ValueError):
            raise InputError("corners.vnl: each record must be (image name, BoardDetection or None)") from None
        check_image_name(name)
        if name in seen:
            raise InputError(f"corners.vnl: image {name!r} appears twice; mrcal needs each image once")
        seen.add(name)
        if det is None or det.count == 0:
            lines.append(f"{name} - - -")
            continue
        if not isinstance(det, BoardDetection):
            raise InputError(f"corners.vnl: {name}: expected a BoardDetection, got {type(det).__name__}")
        ids = np.asarray(det.ids, int).ravel()
        xy = np.asarray(det.corners, float).reshape(-1, 2)
        if ids.size != xy.shape[0]:
            raise InputError(f"corners.vnl: {name}: {ids.size} ids but {xy.shape[0]} corners")
        if ids.min() < 0 or ids.max() >= n:
            raise InputError(f"corners.vnl: {name}: corner ids outside 0..{n - 1}; wrong board?")
        if np.unique(ids).size != ids.size:
            raise InputError(f"corners.vnl: {name}: the same corner id appears twice")
        if not np.all(np.isfinite(xy)):
            raise InputError(f"corners.vnl: {name}: non-finite corner coordinates")
        grid = [None] * n
        for k, (x, y) in zip(ids.tolist(), xy):
            grid[k] = (x, y)
        for g in grid:
            lines.append(f"{name} - - -" if g is None else f"{name} {_num(g[0])} {_num(g[1])} 0")
    return "\n".join(lines) + "\n"


def write_corners_vnl(path, records, board, force=False) -> None:
    """Write mrcal's corner cache for board detections, atomically.

    Parameters
    ----------
    path : str or Path
        Output file (``corners.vnl``).
    records : iterable of (str, BoardDetection or None)
        Per image, in the order to write: the image name as mrcal should find it (a path
        relative to the folder of `path` is best), and its detection (None or an empty
        detection: "no board in this image").
    board : Board
        Sets the grid: ``board.inner_corners`` = (object-width-n, object-height-n).
    force : bool
        Overwrite an existing file.

    Raises
    ------
    InputError
        The file exists (without `force`) or its folder does not; a name vnlog cannot hold;
        an image listed twice; a detection that does not fit the board.
    """
    text = corners_vnl_text(records, board)
    atomic_write(Path(path), text, force)


def read_corners_vnl(path, board, image_size=None) -> list:
    """Read a corners.vnl back into detections, with mrcal's rules.

    Parameters
    ----------
    path : str or Path
    board : Board
        The grid is ``board.inner_corners``; every image with a detection must have
        exactly width_n * height_n rows.
    image_size : (width, height), optional
        Stored in each BoardDetection (the file does not hold it).

    Returns
    -------
    list of (str, BoardDetection or None)
        In file order. A detection holds the corners that have numeric x, y and a level
        >= 0 (or a weight > 0 when the legend's fourth column is ``weight``), with their
        grid index as id; images without any such corner give None. x < 0 or y < 0 are
        kept (mrcal would drop them).

    Raises
    ------
    InputError
        ``"<path>:<line>: <problem>"`` for a missing legend, a wrong column count, a
        non-number, an image whose rows are not contiguous or are not width_n * height_n.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: corners file not found")
    try:
        lines = p.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{p}: cannot read corners file: {e}") from None
    w_n, h_n = board.inner_corners
    n = w_n * h_n
    legend = None
    groups = []  # [name, first line number, rows]
    done = set()
    for lineno, line in enumerate(lines, 1):
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            if legend is None and not s.startswith("##") and not s.startswith("#!"):
                legend = s[1:].split()
                if legend[:3] != ["filename", "x", "y"] or len(legend) > 4 or \
                        (len(legend) == 4 and legend[3] not in ("level", "weight")):
                    raise InputError(f"{p}:{lineno}: legend must be '# filename x y [level|weight]', got {s!r}")
            continue
        if legend is None:
            raise InputError(f"{p}:{lineno}: data before the legend '{LEGEND}'")
        fields = s.split()
        if len(fields) != len(legend):
            raise InputError(f"{p}:{lineno}: expected {len(legend)} fields ({' '.join(legend)}), got {len(fields)}")
        name = fields[0]
        if not groups or groups[-1][0] != name:
            if name in done:
                raise InputError(f"{p}:{lineno}: rows of image {name!r} are not contiguous")
            if groups:
                done.add(groups[-1][0])
            groups.append([name, lineno, []])
        groups[-1][2].append((lineno, fields[1:]))
    if legend is None:
        raise InputError(f"{p}: no legend line '{LEGEND}'; not a corners.vnl")
    weights = len(legend) == 4 and legend[3] == "weight"
    out = []
    for name, first, rows in groups:
        if len(rows) == 1 and n != 1:
            if any(v != "-" for v in rows[0][1][:2]):
                raise InputError(f"{p}:{first}: image {name!r} has 1 row; a detection needs {n} "
                                 f"({w_n} x {h_n}), no detection is '{name} - - -'")
            out.append((name, None))
            continue
        if len(rows) != n:
            raise InputError(f"{p}:{first}: image {name!r} has {len(rows)} rows; the {w_n} x {h_n} grid needs {n}")
        ids, xy = [], []
        for k, (lineno, vals) in enumerate(rows):
            if vals[0] == "-" or vals[1] == "-" or (len(vals) == 3 and vals[2] == "-"):
                continue
            try:
                x, y = float(vals[0]), float(vals[1])
                lev = float(vals[2]) if len(vals) == 3 else 0.0
            except ValueError:
                raise InputError(f"{p}:{lineno}: x, y and {legend[3] if len(legend) == 4 else 'level'} "
                                 f"must be numbers or '-', got {' '.join(vals)!r}") from None
            if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(lev)):
                raise InputError(f"{p}:{lineno}: non-finite value in {' '.join(vals)!r}")
            if (weights and lev <= 0) or (not weights and lev < 0):
                continue
            ids.append(k)
            xy.append((x, y))
        if not ids:
            out.append((name, None))
            continue
        size = None if image_size is None else (int(image_size[0]), int(image_size[1]))
        out.append((name, BoardDetection(np.array(ids, int), np.array(xy, float), size,
                                         np.zeros(0, int), np.zeros((0, 4, 2)))))
    return out

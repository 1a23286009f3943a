"""Real-looking synthetic frames with exact truth: the printed sheet, a table scene, a shaft.

Three things live here:

- `Sheet`: the printed target. A ChArUco board and, beside it, a fan of dark bars (the
  spokes), on a sheet of paper, all defined analytically as polygons in the *target frame*
  (= the board frame, frames.py: x right, y down the sheet, z into the sheet, origin at the
  outer corner of the board's first square; millimetres). `layout_sheet` builds the default
  layout; `sheet_raster`, `write_sheet_png` and `write_sheet_pdf` print it at true scale.
- `Backdrop` and `Instrument`: a textured table (the plane z = 0 around the sheet) with
  boxes standing on it and a wall beyond, for structure from motion; and a cylindrical
  instrument shaft pivoting about a fulcrum.
- `render_frame`: what a camera with any supported lens model sees.

Rendering method
----------------
Every geometric edge in a frame (squares, marker cells, spoke bars, the paper, the table,
the boxes, the shaft's silhouette) is the image of a straight 3D segment. Each polygon is
clipped in 3D against the camera's viewing volume (the planes through the camera centre
bounding the back-projected image border, and a near plane), its edges are subdivided until
every chord is at most 1 px long in the image and projected with `Camera.project` (exact
for every lens model, fisheye included), and the resulting outlines are scan-converted
with *exact area coverage*: the signed-area accumulation rasteriser used by font renderers
(the trapezoid under every piece of every edge inside every pixel, then a running sum
along rows). A pixel's value is therefore the box-filter average of the scene over its
square, as a sensor with 100 % fill factor integrates it, up to the chord error of the 1 px
subdivision. Measured edge positions agree with the projected truth to 1e-11 px (pinhole),
1e-5 px (strong opencv distortion) and 1e-4 px (fisheye) (tests/toolkit/synth/test_render.py),
far inside a 0.05 px budget.

Shading (the table's procedural texture, the boxes, the shaft's metallic look) needs a
viewing ray per pixel; those are interpolated (bicubic, 8 px grid) from exact
`Camera.rays_from_pixels` values and cached per camera: they only colour surfaces, the
geometry of every edge comes from the exact forward projection.

After the scene: optional smooth multiplicative lighting field (vignetting and a random
gradient), Gaussian blur (the optics), gamma encoding and signal-dependent sensor noise,
all drawn from the generator passed in, so a seed gives the same image bit for bit.

Conventions: OpenCV camera frame and pixels (pixel (0, 0) is the centre of the top-left
pixel); transforms ``a_from_b``; lengths in the target's unit (mm).

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.camera.model import Camera
>>> sheet = layout_sheet()
>>> cam = Camera("pinhole", 320, 240, [[250.0, 0, 159.5], [0, 250.0, 119.5], [0, 0, 1]])
>>> R, t = np.eye(3), np.array([-131.0, -62.0, 400.0])   # frontal, 400 mm away
>>> img = render_frame(cam, R, t, sheet, background="plain")
>>> img.shape, img.dtype.name
((240, 320), 'uint8')
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from pencilcal.toolkit.board.spec import Board, board_from_dict
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.pencil.spec import Pencil

__all__ = [
    "PAPER_SIZES",
    "DEFAULT_BOARD",
    "Sheet",
    "layout_sheet",
    "default_board",
    "Backdrop",
    "Instrument",
    "render_frame",
    "coverage",
    "polygon_coverage",
    "target_coverage",
    "sheet_raster",
    "write_sheet_png",
    "write_sheet_pdf",
    "REFLECTANCE",
]

#: Paper sizes (long side, short side) [mm].
PAPER_SIZES = {"a4": (297.0, 210.0), "a3": (420.0, 297.0), "letter": (279.4, 215.9)}

#: The default printed board: 7 x 5 squares of 25 mm, 18 mm markers.
DEFAULT_BOARD = {"type": "charuco", "squares": [7, 5], "square": 25.0, "marker": 18.0,
                 "dictionary": "DICT_5X5_100"}

#: Linear reflectances (0..1) of the scene's materials before lighting.
REFLECTANCE = {"paper": 0.85, "ink": 0.045, "wall": 0.22, "plain": 0.30}

# Tints (B, G, R) for colour output; luminance comes from the reflectances above.
_TINT = {
    "paper": np.array([0.97, 0.99, 1.0]),
    "ink": np.array([1.0, 1.0, 1.0]),
    "table": np.array([0.62, 0.86, 1.12]),   # a warm wood-like brown
    "wall": np.array([1.10, 1.0, 0.90]),
    "plain": np.array([1.0, 1.0, 1.0]),
    "shaft": np.array([1.0, 1.0, 1.0]),
}

# Longest chord [px] of a subdivided edge under a distorting lens; the chord's sagitta
# L^2 / (8 R) stays below 1e-3 px for the radii of curvature (> 150 px) lenses give.
_MAX_CHORD_PX = 1.0
# Pixels beyond the image border that the clipping volume keeps (so border pixels see
# their whole neighbourhood), and the step of the border samples that define it.
_CLIP_MARGIN_PX = 4.0
_CLIP_STEP_PX = 16.0
# Rays further than this off the optical axis are not rendered: polygons are clipped in
# normalised coordinates, which end at 90 deg (fisheye lenses can see beyond; those pixels
# show the backdrop's wall).
_MAX_RAY_ANGLE = np.radians(89.5)
_NEAR = 1e-3  # near clipping plane [target units]
_RAY_GRID_PX = 8


def default_board() -> Board:
    """The default printed board (`DEFAULT_BOARD`) as a `Board`."""
    return board_from_dict(dict(DEFAULT_BOARD), source="default board")


# --------------------------------------------------------------------------- the sheet
def _rect(x0, y0, x1, y1):
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float)


def _signed_area(p):
    q = np.roll(p, -1, axis=0)
    return 0.5 * float(np.sum(p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]))


def _oriented(p, positive=True):
    """The polygon with positive (or negative) signed area in its own coordinates."""
    return p if (_signed_area(p) > 0) == positive else p[::-1].copy()


def _bar_corners(vertex, theta, radius, width):
    """(4, 2) corners of the bar whose centre line runs from radius[0] to radius[1]."""
    d = np.array([np.cos(theta), np.sin(theta)])
    n = np.array([-d[1], d[0]])
    v = np.asarray(vertex, float)
    h = width / 2.0
    return np.array([v + radius[0] * d - h * n, v + radius[1] * d - h * n,
                     v + radius[1] * d + h * n, v + radius[0] * d + h * n])


def _convex_overlap(a, b, tol=1e-9):
    """True if two convex polygons (N, 2) overlap with positive area (separating axes)."""
    for poly in (a, b):
        e = np.roll(poly, -1, axis=0) - poly
        for nx, ny in np.stack([-e[:, 1], e[:, 0]], -1):
            pa = a @ [nx, ny]
            pb = b @ [nx, ny]
            if pa.max() <= pb.min() + tol or pb.max() <= pa.min() + tol:
                return False
    return True


@dataclass(frozen=True, eq=False)
class Sheet:
    """The printed target: a ChArUco board and a fan of dark bars on a sheet of paper.

    All geometry is in the target frame (the board frame: x right, y down the sheet, origin
    at the outer corner of the board's first square) in the board's length unit (mm).

    Parameters
    ----------
    board : Board
        A ChArUco board (`boards.Board`, type "charuco").
    pencil : Pencil
        The printed fan: ``angles`` [rad], ``vertex`` (2,), ``radius`` (2,) and ``width``
        all required. Bar k is the rectangle of width ``width`` whose centre line runs
        from ``radius[0]`` to ``radius[1]`` from the vertex along (cos theta_k, sin theta_k).
    paper_size : (2,) float
        Paper (width, height) as printed [mm]; (297, 210) is A4 landscape.
    paper_origin : (2,) float
        Top-left corner of the paper in the target frame [mm]; the paper spans
        ``[x0, x0 + width] x [y0, y0 + height]``.
    margin : float
        Blank border the printed content must keep from the paper's edges [mm].
    paper : str
        Name of the paper, for captions and messages ("a4 landscape").

    Raises
    ------
    InputError
        If the board is not ChArUco, the pencil lacks vertex/radius/width, two bars
        overlap, a bar overlaps the board, or the content does not fit inside the margins.

    Example
    -------
    >>> sheet = layout_sheet()                      # A4 landscape, 7x5 board, 8 spokes
    >>> [round(float(v), 3) for v in sheet.pencil.vertex], sheet.paper_size
    ([179.0, 62.5], (297.0, 210.0))
    >>> bool(sheet.ink_at([[12.5, 12.5], [37.5, 12.5], [-5.0, -5.0]]).tolist() == [True, False, False])
    True
    """

    board: Board
    pencil: Pencil
    paper_size: tuple
    paper_origin: tuple
    margin: float = 10.0
    paper: str = "a4 landscape"

    def __post_init__(self):
        b = self.board
        if not isinstance(b, Board) or b.type != "charuco":
            raise InputError("the sheet's board must be a ChArUco board")
        p = self.pencil
        if p.vertex is None or p.radius is None or p.width is None:
            raise InputError("the sheet's pencil needs a vertex, a radius and a width")
        size = tuple(float(v) for v in self.paper_size)
        origin = tuple(float(v) for v in self.paper_origin)
        object.__setattr__(self, "paper_size", size)
        object.__setattr__(self, "paper_origin", origin)
        if not (size[0] > 0 and size[1] > 0) or self.margin < 0:
            raise InputError(f"paper size must be positive and the margin non-negative, got {size}, {self.margin}")
        bars = self.bars
        for i in range(len(bars)):
            for j in range(i + 1, len(bars)):
                if _convex_overlap(bars[i], bars[j]):
                    raise InputError(
                        f"spokes {i} and {j} overlap: at radius {p.radius[0]:g} they are closer than "
                        f"their width {p.width:g}; use a larger inner radius, a larger step or thinner bars")
        bw, bh = b.size
        board_rect = _rect(0.0, 0.0, bw, bh)
        for i, bar in enumerate(bars):
            if _convex_overlap(bar, board_rect):
                raise InputError(f"spoke {i} overlaps the board; move the fan's vertex")
        x0, y0, x1, y1 = self.content_bounds
        px0, py0 = origin
        px1, py1 = px0 + size[0], py0 + size[1]
        m = self.margin
        if x0 < px0 + m - 1e-9 or y0 < py0 + m - 1e-9 or x1 > px1 - m + 1e-9 or y1 > py1 - m + 1e-9:
            raise InputError(
                f"the layout ({x1 - x0:.1f} x {y1 - y0:.1f} mm) does not fit on {self.paper} paper "
                f"({size[0]:g} x {size[1]:g} mm) with {m:g} mm margins; use larger paper, the other "
                f"orientation, or a smaller board or fan")

    # ------------------------------------------------------------------ geometry
    @cached_property
    def bars(self):
        """List of (4, 2) corner arrays, one rotated rectangle per spoke [target mm]."""
        p = self.pencil
        return [_bar_corners(p.vertex, th, p.radius, p.width) for th in p.angles]

    @property
    def content_bounds(self):
        """(x0, y0, x1, y1) [mm] of everything printed: the board and the bars."""
        bw, bh = self.board.size
        pts = np.concatenate([_rect(0.0, 0.0, bw, bh)] + list(self.bars))
        return (float(pts[:, 0].min()), float(pts[:, 1].min()), float(pts[:, 0].max()), float(pts[:, 1].max()))

    @property
    def content_center(self):
        """(3,) centre of `content_bounds` on the sheet (z = 0) [mm]."""
        x0, y0, x1, y1 = self.content_bounds
        return np.array([(x0 + x1) / 2.0, (y0 + y1) / 2.0, 0.0])

    def paper_polygon(self):
        """(4, 2) corners of the paper [target mm]."""
        x0, y0 = self.paper_origin
        return _rect(x0, y0, x0 + self.paper_size[0], y0 + self.paper_size[1])

    @cached_property
    def ink_polygons(self):
        """The printed (dark) area as polygons with signs: list of ((N, 2) array, +1 | -1).

        +1 polygons are filled, -1 polygons are holes in them (the white cells of each
        marker, merged into horizontal runs). Fills have positive signed area in (x, y),
        holes negative, so the list is also a valid compound path under the nonzero rule.
        Fills never overlap each other; holes lie inside their marker's square.
        """
        import cv2

        board = self.board
        cv_board = board.cv2_board()
        dictionary = cv_board.getDictionary()
        bits = int(dictionary.markerSize)
        ids = np.asarray(cv_board.getIds(), int).ravel()
        corners = np.asarray(cv_board.getObjPoints(), float)[:, :, :2]  # (M, 4, 2)
        s = board.square
        nx, ny = board.squares
        out = []
        # black squares: exactly the squares that hold no marker (so legacy layouts too)
        with_marker = {(int(c[:, 0].mean() // s), int(c[:, 1].mean() // s)) for c in corners}
        for j in range(ny):
            for i in range(nx):
                if (i, j) not in with_marker:
                    out.append((_oriented(_rect(i * s, j * s, (i + 1) * s, (j + 1) * s)), 1))
        for mid, c in zip(ids, corners):
            # marker image: row r, column c of the (bits + 2)^2 cells; corner 0 is its
            # top-left, then clockwise (OpenCV's marker convention)
            cells = cv2.aruco.generateImageMarker(dictionary, int(mid), bits + 2) > 127
            p0, ex, ey = c[0], (c[1] - c[0]) / (bits + 2), (c[3] - c[0]) / (bits + 2)
            out.append((_oriented(c.copy()), 1))
            for r in range(bits + 2):
                row = cells[r]
                col = 0
                while col < bits + 2:
                    if not row[col]:
                        col += 1
                        continue
                    start = col
                    while col < bits + 2 and row[col]:
                        col += 1
                    quad = np.array([p0 + start * ex + r * ey, p0 + col * ex + r * ey,
                                     p0 + col * ex + (r + 1) * ey, p0 + start * ex + (r + 1) * ey])
                    out.append((_oriented(quad, positive=False), -1))
        for bar in self.bars:
            out.append((_oriented(bar), 1))
        return out

    def ink_at(self, xy):
        """True where the sheet is printed dark. xy: (..., 2) target points [mm] -> (...) bool.

        Evaluates the same polygons the renderer uses (point-in-polygon, nonzero rule).
        """
        xy = np.asarray(xy, float)
        flat = xy.reshape(-1, 2)
        wind = np.zeros(len(flat))
        for poly, sign in self.ink_polygons:
            wind += sign * _inside(poly, flat)
        return (wind > 0.5).reshape(xy.shape[:-1])

    def to_dict(self):
        """Paper and layout, for truth files (the board and pencil have their own files)."""
        return {"paper": self.paper, "paper_size_mm": list(self.paper_size),
                "paper_origin": list(self.paper_origin), "margin": self.margin,
                "content_bounds": list(self.content_bounds)}


def _inside(poly, pts):
    """Point-in-convex-or-not polygon by crossing number. poly (N, 2), pts (M, 2) -> (M,) 0/1."""
    x, y = pts[:, 0], pts[:, 1]
    inside = np.zeros(len(pts), bool)
    q = np.roll(poly, -1, axis=0)
    for (xa, ya), (xb, yb) in zip(poly, q):
        cond = (ya > y) != (yb > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = xa + (y - ya) * (xb - xa) / (yb - ya)
        inside ^= cond & (x < xc)
    return inside.astype(float)


def layout_sheet(board=None, *, paper="a4", orientation="landscape", margin=10.0, gap=8.0,
                 spokes=8, step_deg=20.0, start_deg=None, angles_deg=None, radius=(15.0, 80.0),
                 width=1.0, side="right", vertex=None):
    """The default printable layout: a ChArUco board with a fan of spokes beside it.

    Parameters
    ----------
    board : Board, optional
        Default: 7 x 5 squares of 25 mm, 18 mm markers, DICT_5X5_100.
    paper : {"a4", "a3", "letter"}
    orientation : {"landscape", "portrait"}
    margin : float
        Blank border kept free on the paper [mm].
    gap : float
        Clearance between the board and the nearest bar [mm] (8 mm lets the default
        layout fit US letter as well as A4).
    spokes, step_deg, start_deg : int, float [deg], float [deg]
        A regular fan; `start_deg` defaults to the fan opening away from the board
        (centred on +x for ``side="right"``, on +y for ``side="below"``).
    angles_deg : sequence of float, optional
        Explicit spoke angles [deg] in the target frame instead of the regular fan.
    radius : (2,) float
        Inner and outer end of every bar's centre line from the vertex [mm].
    width : float
        Bar width [mm].
    side : {"right", "below"}
        Where the fan goes relative to the board.
    vertex : (2,) float, optional
        Explicit vertex in the target frame [mm] instead of the automatic placement.

    Returns
    -------
    Sheet
        Content centred on the paper (origin rounded to 1e-3 mm); an automatic vertex is
        placed at a whole millimetre, so the pencil file states exactly what is printed.

    Raises
    ------
    InputError
        If the layout does not fit the paper or bars overlap (see `Sheet`).

    Example
    -------
    >>> s = layout_sheet(paper="a3", spokes=10, step_deg=15)
    >>> s.pencil.count, s.paper_size
    (10, (420.0, 297.0))
    """
    board = default_board() if board is None else board
    if paper not in PAPER_SIZES:
        raise InputError(f"unknown paper {paper!r}; expected one of {sorted(PAPER_SIZES)}")
    if orientation not in ("landscape", "portrait"):
        raise InputError(f"orientation must be landscape or portrait, got {orientation!r}")
    if side not in ("right", "below"):
        raise InputError(f"side must be right or below, got {side!r}")
    r = np.asarray(radius, float)
    if r.shape != (2,) or not (0 <= r[0] < r[1]):
        raise InputError(f"radius must be [inner, outer] with 0 <= inner < outer, got {list(radius)}")
    if not width > 0:
        raise InputError(f"the bar width must be positive, got {width}")
    if angles_deg is None:
        if int(spokes) < 3:
            raise InputError(f"a pencil needs at least three spokes, got {spokes}")
        if start_deg is None:
            centre = 0.0 if side == "right" else 90.0
            start_deg = centre - (int(spokes) - 1) * float(step_deg) / 2.0
        angles_deg = float(start_deg) + float(step_deg) * np.arange(int(spokes))
    from pencilcal.toolkit.pencil.spec import pencil_from_dict

    proto = pencil_from_dict({"angles_deg": [float(a) for a in angles_deg], "vertex": [0.0, 0.0],
                              "radius": r.tolist(), "width": float(width)}, source="fan")
    pts = np.concatenate([_bar_corners((0.0, 0.0), th, r, width) for th in proto.angles])
    fx0, fy0 = pts.min(0)
    fx1, fy1 = pts.max(0)
    bw, bh = board.size
    if vertex is None:
        # whole millimetres away from the board, so the gap is at least `gap`
        if side == "right":
            vertex = (math.ceil(bw + gap - fx0 - 1e-9), bh / 2.0 - (fy0 + fy1) / 2.0)
        else:
            vertex = (bw / 2.0 - (fx0 + fx1) / 2.0, math.ceil(bh + gap - fy0 - 1e-9))
    vertex = np.round(np.asarray(vertex, float), 3) + 0.0
    pencil = Pencil(proto.angles, vertex, r, float(width))
    long_side, short_side = PAPER_SIZES[paper]
    size = (long_side, short_side) if orientation == "landscape" else (short_side, long_side)
    cx0 = min(0.0, vertex[0] + fx0)
    cy0 = min(0.0, vertex[1] + fy0)
    cx1 = max(bw, vertex[0] + fx1)
    cy1 = max(bh, vertex[1] + fy1)
    origin = (round((cx0 + cx1) / 2.0 - size[0] / 2.0, 3), round((cy0 + cy1) / 2.0 - size[1] / 2.0, 3))
    return Sheet(board, pencil, size, origin, float(margin), f"{paper} {orientation}")


# ------------------------------------------------------------------- the rasteriser
def coverage(x0, y0, x1, y1, weight, width, height):
    """Exact area coverage of pixels by closed outlines given as directed edges.

    The signed-area accumulation rasteriser: each edge piece inside a pixel adds the
    trapezoid between it and the pixel's right side; a running sum along each row turns
    that into the area of the outlines inside every pixel. Exact for straight edges;
    independent of the order of the edges.

    Parameters
    ----------
    x0, y0, x1, y1 : (E,) array_like
        Edge end points [pixels, OpenCV convention: pixel (0, 0) is the centre of the
        top-left pixel, which covers [-0.5, 0.5] x [-0.5, 0.5]].
    weight : (E,) array_like
        +1 for edges of a polygon with positive signed area that is to be filled (in
        pixel coordinates, x right, y down), -1 to subtract; any real weight works.
    width, height : int
        Image size [pixels].

    Returns
    -------
    (height, width) ndarray
        Covered fraction of every pixel (the weighted area of the outlines inside it).

    Example
    -------
    >>> sq = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])   # 2 x 1 px box
    >>> a, b = sq, np.roll(sq, -1, 0)
    >>> coverage(a[:, 0], a[:, 1], b[:, 0], b[:, 1], np.ones(4), 3, 2).round(3).tolist()
    [[0.25, 0.5, 0.25], [0.25, 0.5, 0.25]]
    """
    W, H = int(width), int(height)
    cov, (r0, c0) = _coverage_window(x0, y0, x1, y1, weight, W, H)
    out = np.zeros((H, W))
    out[r0:r0 + cov.shape[0], c0:c0 + cov.shape[1]] = cov
    return out


def _coverage_window(x0, y0, x1, y1, weight, W, H):
    """`coverage` restricted to the rows and columns the outlines touch.

    Returns (cov, (row0, col0)): cov (h, w) is the coverage of the image window starting
    at (row0, col0); outside it the coverage is zero.
    """
    seg = np.stack([np.asarray(x0, float), np.asarray(y0, float), np.asarray(x1, float),
                    np.asarray(y1, float), np.broadcast_to(np.asarray(weight, float), np.shape(x0))], -1)
    seg = seg.reshape(-1, 5) + np.array([0.5, 0.5, 0.5, 0.5, 0.0])  # pixel cells [c, c+1)
    seg = seg[np.all(np.isfinite(seg), axis=1) & (seg[:, 1] != seg[:, 3]) & (seg[:, 4] != 0)]
    # rows outside the image never show: clip in y; columns right of it neither
    seg = _split_at(seg, 1, 0.0)
    seg = _split_at(seg, 1, float(H))
    ym = (seg[:, 1] + seg[:, 3]) / 2.0
    seg = seg[(ym > 0) & (ym < H)]
    seg = _split_at(seg, 0, 0.0)
    seg = _split_at(seg, 0, float(W))
    xm = (seg[:, 0] + seg[:, 2]) / 2.0
    seg = seg[xm < W]
    if len(seg) == 0:
        return np.zeros((0, 0)), (0, 0)
    # left of the image only an edge's vertical extent matters: collapse it to one column
    left = xm[xm < W] < 0
    seg[left, 0] = -0.5
    seg[left, 2] = -0.5
    xa, ya, xb, yb, w = _pieces(seg)
    col = np.floor((xa + xb) / 2.0)
    row = np.floor((ya + yb) / 2.0).astype(np.int64)
    frac = (xa + xb) / 2.0 - col
    area = w * (ya - yb)  # positive-area outlines give positive coverage
    ok = (row >= 0) & (row < H) & (area != 0)
    if not np.any(ok):
        return np.zeros((0, 0)), (0, 0)
    col = np.maximum(col.astype(np.int64)[ok], -1)
    row, frac, area = row[ok], frac[ok], area[ok]
    # window: rows touched; columns from the leftmost piece to the rightmost (the running
    # sum is back to zero right of the last edge of closed outlines)
    r0, r1 = int(row.min()), int(row.max()) + 1
    c0, c1 = max(int(col.min()), 0), min(int(col.max()) + 2, W)
    ww = c1 - c0 + 2  # column 0 of acc collects everything left of the window
    idx = (row - r0) * ww + np.clip(col - c0 + 1, 0, ww - 1)
    idx2 = (row - r0) * ww + np.clip(col - c0 + 2, 0, ww - 1)
    n = (r1 - r0) * ww
    acc = np.bincount(idx, area * (1.0 - frac), minlength=n)[:n]
    acc += np.bincount(idx2, area * frac, minlength=n)[:n]
    cov = np.cumsum(acc.reshape(r1 - r0, ww), axis=1)[:, 1:1 + c1 - c0]
    if c1 < W and np.any(np.abs(cov[:, -1]) > 1e-12):
        # outlines closed right of the image (edges dropped above): the running sum
        # stays constant from the last piece to the image's right border
        cov = np.concatenate([cov, np.repeat(cov[:, -1:], W - c1, axis=1)], axis=1)
    return cov, (r0, c0)


def _split_at(seg, axis, value):
    """Split segments (N, 5) that cross coordinate `axis` == value into two."""
    a, b = seg[:, axis], seg[:, 2 + axis]
    cross = (a - value) * (b - value) < 0
    if not np.any(cross):
        return seg
    s = seg[cross]
    t = (value - s[:, axis]) / (s[:, 2 + axis] - s[:, axis])
    mid = s[:, 0:2] + t[:, None] * (s[:, 2:4] - s[:, 0:2])
    mid[:, axis] = value
    first, second = s.copy(), s.copy()
    first[:, 2:4] = mid
    second[:, 0:2] = mid
    return np.concatenate([seg[~cross], first, second])


def _pieces(seg):
    """Split segments at every integer x and y so each piece lies inside one pixel cell."""
    n = len(seg)
    x0, y0, x1, y1, w = seg.T
    ids, ts = [np.arange(n), np.arange(n)], [np.zeros(n), np.ones(n)]
    for a, b in ((x0, x1), (y0, y1)):
        lo = np.floor(np.minimum(a, b))
        hi = np.ceil(np.maximum(a, b))
        cnt = np.maximum(hi - lo - 1, 0).astype(np.int64)
        total = int(cnt.sum())
        if total:
            idx = np.repeat(np.arange(n), cnt)
            k = np.repeat(lo, cnt) + 1 + (np.arange(total) - np.repeat(np.cumsum(cnt) - cnt, cnt))
            ids.append(idx)
            ts.append((k - a[idx]) / (b[idx] - a[idx]))
    ids = np.concatenate(ids)
    ts = np.concatenate(ts)
    order = np.lexsort((ts, ids))
    ids, ts = ids[order], ts[order]
    same = ids[1:] == ids[:-1]
    sid, ta, tb = ids[:-1][same], ts[:-1][same], ts[1:][same]
    dx, dy = (x1 - x0)[sid], (y1 - y0)[sid]
    return x0[sid] + ta * dx, y0[sid] + ta * dy, x0[sid] + tb * dx, y0[sid] + tb * dy, w[sid]


def polygon_coverage(polygons, width, height):
    """Exact pixel coverage of polygons given in pixel coordinates.

    polygons: iterable of ((N, 2) array, sign): sign +1 fills the polygon, -1 removes it
    (a hole), whatever the polygon's orientation. Returns (height, width) float.

    Example
    -------
    >>> polygon_coverage([(np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5]]), 1)], 2, 1).tolist()
    [[0.5, 0.0]]
    """
    a, b, w = [], [], []
    for poly, sign in polygons:
        p = np.asarray(poly, float)
        if len(p) < 3:
            continue
        area = _signed_area(p)
        if area == 0 or not np.isfinite(area):
            continue
        a.append(p)
        b.append(np.roll(p, -1, axis=0))
        w.append(np.full(len(p), float(sign) * np.sign(area)))
    if not a:
        return np.zeros((int(height), int(width)))
    a, b, w = np.concatenate(a), np.concatenate(b), np.concatenate(w)
    return coverage(a[:, 0], a[:, 1], b[:, 0], b[:, 1], w, width, height)


# ------------------------------------------------------------- camera-side helpers
_CAMERA_CACHE = {}


def _camera_key(camera):
    return (camera.model, camera.width, camera.height, camera.K.tobytes(), camera.dist.tobytes())


def _camera_data(camera):
    """Clip planes and per-pixel rays of a camera, computed once and cached."""
    key = _camera_key(camera)
    data = _CAMERA_CACHE.get(key)
    if data is None:
        if len(_CAMERA_CACHE) > 8:
            _CAMERA_CACHE.clear()
        data = {"planes": _view_planes(camera)}
        _CAMERA_CACHE[key] = data
    return data


def _rays(camera):
    """(H, W, 3) float32 unit viewing rays of every pixel (camera frame), cached.

    Exact rays on an 8 px grid, bicubic in between: used only for shading and textures.
    """
    import cv2

    data = _camera_data(camera)
    if "rays" not in data:
        W, H = camera.width, camera.height
        g = _RAY_GRID_PX
        us = np.arange(0, W - 1 + 2 * g, g, dtype=float)
        vs = np.arange(0, H - 1 + 2 * g, g, dtype=float)
        uu, vv = np.meshgrid(us, vs)
        r = camera.rays_from_pixels(np.stack([uu, vv], -1))
        grid = np.nan_to_num(r, nan=0.0).astype(np.float32)
        mx = (np.arange(W, dtype=np.float32) / g)[None, :].repeat(H, 0)
        my = (np.arange(H, dtype=np.float32) / g)[:, None].repeat(W, 1)
        rays = cv2.remap(grid, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
        n = np.linalg.norm(rays, axis=-1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            rays = rays / n
        bad = cv2.remap(np.isnan(r[..., 0]).astype(np.float32), mx, my, cv2.INTER_LINEAR) > 0
        rays[bad | ~(n[..., 0] > 0.5)] = np.nan
        rays.setflags(write=False)
        data["rays"] = rays
    return data["rays"]


def _convex_hull(pts):
    """Convex hull (monotone chain) of (N, 2) points, positive signed area, (M, 2)."""
    p = np.unique(np.asarray(pts, float), axis=0)
    if len(p) < 3:
        return p

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower, upper = [], []
    for q in p:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], q) <= 0:
            lower.pop()
        lower.append(q)
    for q in p[::-1]:
        while len(upper) >= 2 and cross(upper[-2], upper[-1], q) <= 0:
            upper.pop()
        upper.append(q)
    return np.array(lower[:-1] + upper[:-1])


def _view_planes(camera):
    """Half-spaces N . X + d >= 0 (camera frame) bounding what the image can show.

    The back-projected image border (expanded by a few pixels) in normalised coordinates,
    its convex hull, and the planes through the camera centre along the hull's edges;
    plus a near plane. Inside them the lens model is used only where it is invertible,
    so no polygon folds back into the image from beyond the valid field of view.
    Returns (P, 4): rows (Nx, Ny, Nz, d).
    """
    W, H = camera.width, camera.height
    m = _CLIP_MARGIN_PX
    x0, x1, y0, y1 = -0.5 - m, W - 0.5 + m, -0.5 - m, H - 0.5 + m
    nx = int(np.ceil((x1 - x0) / _CLIP_STEP_PX)) + 1
    ny = int(np.ceil((y1 - y0) / _CLIP_STEP_PX)) + 1
    xs, ys = np.linspace(x0, x1, nx), np.linspace(y0, y1, ny)
    border = np.concatenate([np.stack([xs, np.full(nx, y0)], -1), np.stack([xs, np.full(nx, y1)], -1),
                             np.stack([np.full(ny, x0), ys], -1), np.stack([np.full(ny, x1), ys], -1)])
    rays = camera.rays_from_pixels(border)
    rays = rays[np.all(np.isfinite(rays), axis=1)]
    if len(rays) < 3:
        raise InputError("the camera's lens model cannot be inverted at the image border")
    ang = np.arccos(np.clip(rays[:, 2], -1.0, 1.0))
    over = ang > _MAX_RAY_ANGLE
    if np.any(over):
        xy = rays[over, :2] / np.linalg.norm(rays[over, :2], axis=1, keepdims=True)
        rays[over] = np.concatenate([np.sin(_MAX_RAY_ANGLE) * xy, np.full((over.sum(), 1), np.cos(_MAX_RAY_ANGLE))], 1)
    hull = _convex_hull(rays[:, :2] / rays[:, 2:3])
    if len(hull) < 3:
        raise InputError("the camera's field of view is degenerate")
    e = np.roll(hull, -1, axis=0) - hull
    n = np.stack([-e[:, 1], e[:, 0]], -1)  # left of each edge = inside (positive area)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    planes = np.concatenate([n, -np.sum(n * hull, axis=1, keepdims=True), np.zeros((len(n), 1))], 1)
    near = np.array([[0.0, 0.0, 1.0, -_NEAR]])
    return np.concatenate([near, planes])


def _clip_convex(P, planes):
    """Sutherland-Hodgman: polygon P (N, 3) clipped by half-spaces N . X + d >= 0."""
    for Nx, Ny, Nz, d in planes:
        s = P @ np.array([Nx, Ny, Nz]) + d
        if np.all(s >= 0):
            continue
        if np.all(s < 0):
            return None
        P1 = np.roll(P, -1, axis=0)
        s1 = np.roll(s, -1)
        ins0, ins1 = s >= 0, s1 >= 0
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(ins0 != ins1, s / (s - s1), 0.0)
        X = P + t[:, None] * (P1 - P)
        cand = np.stack([P, X], 1)
        keep = np.stack([ins0, ins0 != ins1], 1)
        P = cand[keep]
        if len(P) < 3:
            return None
    return P


def _project_polygons(camera, polygons):
    """Pixel-space directed edges of camera-frame polygons, clipped and subdivided.

    polygons: list of ((N, 3) camera-frame vertices, sign). Returns (pa, pb, w): edge
    end points (E, 2) [pixels] and weights (E,) ready for `coverage`.
    """
    planes = _camera_data(camera)["planes"]
    A, B, Wt = [], [], []
    if polygons:
        verts = np.concatenate([p for p, _ in polygons])
        s = verts @ planes[:, :3].T + planes[:, 3]  # (V, P)
        starts = np.cumsum([0] + [len(p) for p, _ in polygons])[:-1]
        all_in = np.minimum.reduceat(s.min(axis=1), starts) >= 0
        any_plane_all_out = np.any(np.maximum.reduceat(s, starts, axis=0) < 0, axis=1)
    for k, (P, sign) in enumerate(polygons):
        if any_plane_all_out[k]:
            continue
        if not all_in[k]:
            P = _clip_convex(P, planes)
            if P is None:
                continue
        xy = P[:, :2] / P[:, 2:3]
        area = _signed_area(xy)
        if area == 0 or not np.isfinite(area):
            continue
        A.append(P)
        B.append(np.roll(P, -1, axis=0))
        Wt.append(np.full(len(P), float(sign) * np.sign(area)))
    if not A:
        z = np.zeros((0, 2))
        return z, z, np.zeros(0)
    A, B, Wt = np.concatenate(A), np.concatenate(B), np.concatenate(Wt)
    pa, pb = camera.project(A), camera.project(B)
    if camera.model == "pinhole" or camera.dist.size == 0 or not np.any(camera.dist):
        return pa, pb, Wt  # straight lines stay straight: no subdivision needed
    out_a, out_b, out_w = [], [], []
    for _ in range(16):
        L = np.linalg.norm(pb - pa, axis=1)
        long_ = ~(L <= _MAX_CHORD_PX)
        out_a.append(pa[~long_])
        out_b.append(pb[~long_])
        out_w.append(Wt[~long_])
        if not np.any(long_):
            break
        A, B, Wt, L = A[long_], B[long_], Wt[long_], L[long_]
        n = np.clip(np.ceil(np.nan_to_num(L, nan=2.0) / _MAX_CHORD_PX), 2, 4096).astype(np.int64)
        idx = np.repeat(np.arange(len(A)), n)
        j = np.arange(idx.size) - np.repeat(np.cumsum(n) - n, n)
        t0 = (j / n[idx])[:, None]
        t1 = ((j + 1) / n[idx])[:, None]
        D = B - A
        # each new vertex is projected once and shared by the two chords meeting there
        T = np.concatenate([t0, t1[np.cumsum(n) - 1]])
        I = np.concatenate([idx, np.arange(len(A))])
        proj = camera.project(A[I] + T * D[I])
        pa = proj[:idx.size]
        pb = np.empty_like(pa)
        pb[:-1] = pa[1:]
        last = np.cumsum(n) - 1
        pb[last] = proj[idx.size:]
        A, B, Wt = A[idx] + t0 * D[idx], A[idx] + t1 * D[idx], Wt[idx]
    else:
        raise InputError("edge subdivision did not converge (lens model folds inside the view?)")
    return np.concatenate(out_a), np.concatenate(out_b), np.concatenate(out_w)


def _render_coverage(camera, polygons, window=False):
    """Exact coverage of camera-frame polygons [((N, 3), sign), ...].

    Returns (H, W), or with ``window=True`` (cov, (slice_rows, slice_cols)) covering only
    where it may be non-zero (empty slices if nothing shows).
    """
    pa, pb, w = _project_polygons(camera, polygons)
    cov, (r0, c0) = _coverage_window(pa[:, 0], pa[:, 1], pb[:, 0], pb[:, 1], w, camera.width, camera.height)
    if window:
        return cov, (slice(r0, r0 + cov.shape[0]), slice(c0, c0 + cov.shape[1]))
    out = np.zeros((camera.height, camera.width))
    out[r0:r0 + cov.shape[0], c0:c0 + cov.shape[1]] = cov
    return out


def target_coverage(camera, R_cam_from_target, t_cam_from_target, polygons):
    """Exact pixel coverage of polygons in the target frame, as `render_frame` draws them.

    Parameters
    ----------
    camera : Camera
    R_cam_from_target, t_cam_from_target : (3, 3), (3,)
        Pose of the target [mm].
    polygons : iterable of ((N, 2) or (N, 3) array, sign)
        Target-frame vertices [mm] (z = 0 when 2-D); sign +1 fills, -1 cuts a hole.

    Returns
    -------
    (H, W) ndarray
        Covered fraction of every pixel (box filter over the pixel's square).

    Example
    -------
    >>> from pencilcal.toolkit.camera.model import Camera
    >>> cam = Camera("pinhole", 4, 2, [[100.0, 0, 1.5], [0, 100.0, 0.5], [0, 0, 1]])
    >>> half = [(np.array([[0.0, -1e3], [1e3, -1e3], [1e3, 1e3], [0.0, 1e3]]), 1)]   # x > 0
    >>> target_coverage(cam, np.eye(3), [0.0, 0.0, 100.0], half).tolist()
    [[0.0, 0.0, 1.0, 1.0], [0.0, 0.0, 1.0, 1.0]]
    """
    R = np.asarray(R_cam_from_target, float)
    t = np.asarray(t_cam_from_target, float).reshape(3)
    return _render_coverage(camera, [(_to_camera(R, t, p), s) for p, s in polygons])


def _to_camera(R, t, pts2_or_3):
    p = np.asarray(pts2_or_3, float)
    if p.shape[-1] == 2:
        p = np.concatenate([p, np.zeros(p.shape[:-1] + (1,))], -1)
    return p @ R.T + t


# --------------------------------------------------------------------- the backdrop
@functools.lru_cache(maxsize=4)
def _texture_pyramid(seed, shape):
    """Procedural multi-octave noise with a soft contrast curve: blobs at every scale,
    never repeating, rich in SIFT features. Returns a tuple of float32 mip levels."""
    import cv2

    rng = np.random.default_rng([int(seed), 7919])
    H, W = shape
    acc = np.zeros((H, W), np.float32)
    for cell in (2, 4, 8, 16, 32, 64, 128, 256):
        gh, gw = H // cell + 4, W // cell + 4
        g = rng.standard_normal((gh, gw)).astype(np.float32)
        up = cv2.resize(g, (gw * cell, gh * cell), interpolation=cv2.INTER_CUBIC)
        oy, ox = rng.integers(0, cell, 2)
        # a nearly flat spectrum: features at every scale from 1 mm to 10 cm
        acc += (cell / 2.0) ** 0.15 * up[oy:oy + H, ox:ox + W]
    acc = (acc - acc.mean()) / acc.std()
    tex = (0.30 + 0.20 * np.tanh(1.3 * acc)).astype(np.float32)
    levels = [tex]
    while min(levels[-1].shape) > 16:
        levels.append(cv2.pyrDown(levels[-1]))
    for lv in levels:
        lv.setflags(write=False)
    return tuple(levels)


def _sample_texture(pyramid, u, v, footprint):
    """Trilinear (mip-mapped) texture lookup, wrapping around the texture's edges.

    u, v: (N,) texel coordinates at level 0 (texel centres at integers); footprint: (N,)
    texels per pixel. Returns (N,) float32; non-finite inputs give the texture's mean.
    """
    import cv2

    u, v, footprint = (np.asarray(a, float).ravel() for a in (u, v, footprint))
    n = u.size
    ok = np.isfinite(u) & np.isfinite(v) & np.isfinite(footprint)
    out = np.full(n, float(pyramid[-1].mean()), np.float32)
    if not np.any(ok):
        return out
    u, v = u[ok], v[ok]
    level = np.clip(np.log2(np.maximum(footprint[ok], 1.0)), 0.0, len(pyramid) - 1.0)
    # cv2.remap wants 2-D maps below 32767 a side: fold the samples into rows of 1024
    m = u.size
    rows = -(-m // 1024)
    pad = rows * 1024 - m
    acc = np.zeros(m, np.float32)
    for lv in range(int(np.floor(level.min())), int(np.ceil(level.max())) + 1):
        w = np.maximum(0.0, 1.0 - np.abs(level - lv))
        sel = w > 0
        if not np.any(sel):
            continue
        s = 2.0 ** lv
        # level-0 coordinate u sits at (u + 0.5) / 2^l - 0.5 on level l (texel centres)
        mx = np.pad(((u + 0.5) / s - 0.5).astype(np.float32), (0, pad)).reshape(rows, 1024)
        my = np.pad(((v + 0.5) / s - 0.5).astype(np.float32), (0, pad)).reshape(rows, 1024)
        val = cv2.remap(pyramid[lv], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP).ravel()[:m]
        acc += (w * val).astype(np.float32)
    out[ok] = acc
    return out


@dataclass(frozen=True, eq=False)
class Backdrop:
    """A textured table (the plane z = 0 of the target frame), boxes on it, a wall beyond.

    Parameters
    ----------
    table : (4,) float
        Table extent (x0, y0, x1, y1) in the target frame [mm]; the sheet lies on it.
    boxes : tuple of (5,) float
        Boxes standing on the table, each (x0, y0, x1, y1, height) [mm]; a box occupies
        ``z`` from ``-height`` to 0 (towards a camera that sees the printed face).
    seed : int
        Seed of the procedural texture (the same seed, the same scene).
    texel : float
        Texture resolution [mm per texel].

    Notes
    -----
    All geometry is consistent 3D in the target frame, so the scene suits structure from
    motion: the texture is fixed to the surfaces, and the boxes give depth off the plane.

    Example
    -------
    >>> bd = Backdrop.around(layout_sheet(), seed=3)
    >>> len(bd.boxes) > 0, bd.table[2] - bd.table[0]
    (True, 1000.0)
    """

    table: tuple = (-400.0, -300.0, 600.0, 500.0)
    boxes: tuple = ()
    seed: int = 0
    texel: float = 0.5

    @classmethod
    def around(cls, sheet, seed=0, size=(1000.0, 800.0), boxes=6, clearance=60.0):
        """A table of `size` [mm] centred on the sheet's paper, with `boxes` random boxes
        at least `clearance` [mm] from the paper (so they never hide it from the views
        `scenes` makes)."""
        rng = np.random.default_rng([int(seed), 104729])
        px0, py0 = sheet.paper_origin
        pw, ph = sheet.paper_size
        cx, cy = px0 + pw / 2.0, py0 + ph / 2.0
        table = (cx - size[0] / 2.0, cy - size[1] / 2.0, cx + size[0] / 2.0, cy + size[1] / 2.0)
        placed = []
        for _ in range(400):
            if len(placed) >= boxes:
                break
            w, d = rng.uniform(40.0, 110.0, 2)
            h = rng.uniform(20.0, 55.0)
            x = rng.uniform(table[0] + 20, table[2] - 20 - w)
            y = rng.uniform(table[1] + 20, table[3] - 20 - d)
            cand = (x, y, x + w, y + d, h)
            c = clearance + h * 0.3
            if x + w > px0 - c and x < px0 + pw + c and y + d > py0 - c and y < py0 + ph + c:
                continue
            if any(x < b[2] + 15 and x + w > b[0] - 15 and y < b[3] + 15 and y + d > b[1] - 15 for b in placed):
                continue
            placed.append(tuple(round(float(v), 3) for v in cand))
        return cls(tuple(float(v) for v in table), tuple(placed), int(seed))

    @property
    def texture(self):
        x0, y0, x1, y1 = self.table
        shape = (int(np.ceil((y1 - y0) / self.texel)), int(np.ceil((x1 - x0) / self.texel)))
        return _texture_pyramid(self.seed, shape)

    def to_dict(self):
        return {"table": list(self.table), "boxes": [list(b) for b in self.boxes], "seed": self.seed,
                "texel": self.texel}


# Direction towards the light of the table scene (target frame; -z points up from the table).
_TO_LIGHT = np.array([0.35, -0.45, -1.0]) / np.linalg.norm([0.35, -0.45, -1.0])


def _face_shade(normal_t):
    """Lambert shade (ambient 0.45) of a surface with outward normal `normal_t` (target frame)."""
    return 0.45 + 0.55 * max(0.0, float(np.dot(normal_t, _TO_LIGHT)))


def _plane_texture(pyramid, texel, rays_t, C_t, Q, n, e1, e2, offset, pixel_angle):
    """Texture seen along target-frame unit rays (N, 3) from C_t on the plane through Q
    with unit normal n and in-plane unit axes e1, e2 [mm]; `offset` (2,) [mm] shifts the
    texture. Returns (N,) float32 (the texture's mean where a ray misses the plane).

    The mip level follows the pixel's footprint on the plane, distance * pixel_angle /
    sqrt(|cos(incidence)|): the geometric mean of its two axes, a fair compromise
    between blur and aliasing at grazing angles.
    """
    cos_i = rays_t @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.dot(Q - C_t, n) / cos_i
    s = np.where(s > 0, s, np.nan)
    P = C_t + s[:, None] * rays_t - Q
    u = (P @ e1 + offset[0]) / texel - 0.5
    v = (P @ e2 + offset[1]) / texel - 0.5
    fp = s * pixel_angle / np.sqrt(np.abs(cos_i)) / texel
    return _sample_texture(pyramid, u, v, fp)


# -------------------------------------------------------------------- the instrument
@dataclass(frozen=True, eq=False)
class Instrument:
    """A cylindrical instrument shaft (a capsule: a cylinder with a rounded tip).

    Parameters
    ----------
    fulcrum : (3,) float
        A point of the shaft's axis, the pivot point [target frame, mm].
    direction : (3,) float
        Axis direction from the fulcrum towards the tip (normalised here) [target frame].
    radius : float
        Shaft radius [mm].
    tip : float
        Distance from the fulcrum to the centre of the rounded tip [mm].
    back : float
        Length of shaft behind the fulcrum (towards the handle) [mm].
    albedo : float
        Diffuse reflectance; a specular stripe is added on top.

    Example
    -------
    >>> ins = Instrument.in_plane([182.0, 62.5], height=4.5, angle_deg=90.0)
    >>> ins.fulcrum.tolist(), np.round(ins.direction, 12).tolist()
    ([182.0, 62.5, -4.5], [0.0, 1.0, 0.0])
    """

    fulcrum: np.ndarray
    direction: np.ndarray
    radius: float = 2.5
    tip: float = 60.0
    back: float = 300.0
    albedo: float = 0.35

    def __post_init__(self):
        f = np.asarray(self.fulcrum, float).reshape(3)
        d = np.asarray(self.direction, float).reshape(3)
        if not np.all(np.isfinite(f)) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
            raise InputError("instrument fulcrum and direction must be finite, direction non-zero")
        if not (self.radius > 0 and self.tip > -self.back):
            raise InputError("instrument radius must be positive and tip > -back")
        object.__setattr__(self, "fulcrum", f)
        object.__setattr__(self, "direction", d / np.linalg.norm(d))

    @classmethod
    def in_plane(cls, fulcrum_xy, height, angle_deg, **kw):
        """A shaft pivoting in the plane z = -height (parallel to the sheet, towards the
        camera), at angle `angle_deg` from the target x axis (towards +y), through the
        fulcrum (fulcrum_xy, -height)."""
        a = np.radians(float(angle_deg))
        return cls(np.array([fulcrum_xy[0], fulcrum_xy[1], -float(height)]),
                   np.array([np.cos(a), np.sin(a), 0.0]), **kw)

    def axis_cam(self, R, t):
        """(fulcrum, unit direction) of the axis in the camera frame."""
        return np.asarray(R, float) @ self.fulcrum + t, np.asarray(R, float) @ self.direction

    def silhouette_planes(self, R, t):
        """(2, 3) unit normals m of the two planes through the camera centre tangent to the
        (infinite) shaft, oriented so that m . X >= 0 on the shaft. In normalised image
        coordinates the silhouette edges are the lines m . (x, y, 1) = 0."""
        F, a = self.axis_cam(R, t)
        Fp = F - np.dot(F, a) * a
        D = np.linalg.norm(Fp)
        if D <= self.radius:
            raise InputError("the camera is inside the instrument shaft")
        e1 = Fp / D
        e2 = np.cross(a, e1)
        c = self.radius / D
        s = np.sqrt(1.0 - c * c)
        return np.array([c * e1 + s * e2, c * e1 - s * e2])

    def _outline(self, R, t):
        """Camera-frame polygon (N, 3) on z = 1 whose projection is the shaft's outline,
        or None if it is behind the camera. Convex hull of the images of the two end
        spheres' silhouette circles, with the exact tangent points added, so the hull's
        long edges are exactly the silhouette lines."""
        F, a = self.axis_cam(R, t)
        r = self.radius
        ends = [F + self.tip * a, F - self.back * a]
        near = 2.0 * r + 1.0
        za, zb = ends[0][2], ends[1][2]
        if za < near and zb < near:
            return None
        if za < near or zb < near:  # keep the part of the axis in front of the camera
            s = (near - za) / (zb - za)
            cut = ends[0] + s * (ends[1] - ends[0])
            ends = [cut, ends[1]] if za < near else [ends[0], cut]
        m = self.silhouette_planes(R, t)
        pts = []
        phi = np.linspace(0.0, 2 * np.pi, 256, endpoint=False)
        for E in ends:
            D2 = float(E @ E)
            if D2 <= r * r:
                raise InputError("the camera is inside the instrument")
            c0 = E * (1.0 - r * r / D2)
            rho = r * np.sqrt(D2 - r * r) / np.sqrt(D2)
            u = np.cross(E, [1.0, 0.0, 0.0] if abs(E[0]) < 0.9 * np.sqrt(D2) else [0.0, 1.0, 0.0])
            u /= np.linalg.norm(u)
            v = np.cross(E / np.sqrt(D2), u)
            circ = c0 + rho * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v)
            pts.append(circ)
            pts.append(E - r * m)  # the exact tangent points of the silhouette planes
        P = np.concatenate(pts)
        if np.any(P[:, 2] <= 0):
            return None
        hull = _convex_hull(P[:, :2] / P[:, 2:3])
        return np.concatenate([hull, np.ones((len(hull), 1))], 1)

    def shade(self, R, t, rays):
        """Luminance (linear, 0..~1.2) of the shaft seen along camera-frame rays (..., 3).

        Metallic grey: a little diffuse light and a sharp specular stripe from a light
        beside the camera (an endoscope's). Rays that miss get the grazing shade."""
        F, a = self.axis_cam(R, t)
        r = self.radius
        d = rays
        da = d @ a
        w = d - da[..., None] * a
        Fp = F - np.dot(F, a) * a
        ww = np.sum(w * w, -1)
        wf = w @ Fp
        with np.errstate(invalid="ignore", divide="ignore"):
            disc = wf * wf - ww * (np.dot(Fp, Fp) - r * r)
            s = (wf - np.sqrt(np.maximum(disc, 0.0))) / ww
            s_close = wf / ww
        s = np.where(disc > 0, s, s_close)
        P = s[..., None] * d
        h = (P - F) @ a
        h_c = np.clip(h, -self.back, self.tip)
        # beyond the tip: the rounded end (sphere)
        tipc = F + self.tip * a
        dt = d @ tipc
        with np.errstate(invalid="ignore"):
            disc_t = dt * dt - (np.dot(tipc, tipc) - r * r)
            s_t = dt - np.sqrt(np.maximum(disc_t, 0.0))
        on_tip = h > self.tip
        P = np.where(on_tip[..., None], np.where((disc_t > 0)[..., None], s_t[..., None] * d,
                                                 dt[..., None] * d), P)
        centre = F + h_c[..., None] * a
        n = P - np.where(on_tip[..., None], tipc, centre)
        nn = np.linalg.norm(n, axis=-1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            n = n / nn
        v = -d
        light = -d + np.array([-0.25, -0.35, 0.0])
        light /= np.linalg.norm(light, axis=-1, keepdims=True)
        ndl = np.clip(np.sum(n * light, -1), 0.0, 1.0)
        refl = 2.0 * ndl[..., None] * n - light
        spec = np.clip(np.sum(refl * v, -1), 0.0, 1.0) ** 60
        ndv = np.clip(np.sum(n * v, -1), 0.0, 1.0)
        lum = self.albedo * (0.12 + 0.55 * ndl) + 0.9 * spec + 0.05 * ndv
        return np.nan_to_num(lum, nan=self.albedo * 0.12)

    def to_dict(self):
        return {"fulcrum": self.fulcrum.tolist(), "direction": self.direction.tolist(), "radius": self.radius,
                "tip": self.tip, "back": self.back}


# ------------------------------------------------------------------------- rendering
def _as_rng(rng):
    if isinstance(rng, np.random.Generator):
        return rng
    return np.random.default_rng(rng)


def _lighting_gain(W, H, strength, rng):
    """A smooth multiplicative gain: vignetting plus a random tilted, slightly curved field."""
    if strength <= 0:
        return None
    u = (np.arange(W) - (W - 1) / 2.0) / (max(W, H) / 2.0)
    v = (np.arange(H) - (H - 1) / 2.0) / (max(W, H) / 2.0)
    uu, vv = np.meshgrid(u, v)
    a, b, c, d = rng.uniform(-1.0, 1.0, 4)
    gain = 1.0 + strength * (0.5 * a * uu + 0.5 * b * vv + 0.25 * c * uu * vv + 0.25 * d * (uu * uu - vv * vv))
    vignette = 1.0 - 0.35 * strength * (uu * uu + vv * vv)
    return np.maximum(gain * vignette, 0.05)


def render_frame(camera, R_cam_from_target, t_cam_from_target, sheet, *, instrument=None,
                 background="table", blur_px=0.0, noise=0.0, lighting=0.0, gamma=1.0, exposure=1.0,
                 color=False, rng=None):
    """Render what `camera` sees of the sheet (and a backdrop and an instrument).

    Parameters
    ----------
    camera : Camera
        Any supported lens model (pinhole, opencv, fisheye).
    R_cam_from_target : (3, 3) array_like
    t_cam_from_target : (3,) array_like
        Pose of the sheet: p_cam = R p_target + t [mm]. The camera must see the printed
        face (its centre on the -z side of the sheet).
    sheet : Sheet
    instrument : Instrument, optional
        A shaft drawn over everything else (it is closer to the camera than the sheet).
    background : "table" | "plain" | float | Backdrop
        "table": `Backdrop.around(sheet)` (textured table, boxes, wall); "plain" or a
        number: a uniform grey (linear reflectance, default 0.3) around the paper.
    blur_px : float
        Standard deviation of a Gaussian blur (the optics) [pixels]; 0 for none.
    noise : float
        Sensor noise: standard deviation at mid grey [grey levels of the 8-bit output];
        it scales as sqrt(0.25 + 0.75 I / 128) with the level I (shot plus read noise).
    lighting : float
        Strength (0..1) of the smooth uneven lighting field (vignetting and a random
        gradient); 0 for uniform light.
    gamma : float
        Encoding gamma: output = 255 (linear)^(1/gamma). 1 keeps the image linear, which
        keeps a blurred edge's 50 % level exactly on the edge; 2.2 looks like a camera.
    exposure : float
        Multiplies the linear image before encoding.
    color : bool
        (H, W, 3) BGR output instead of (H, W) grey.
    rng : numpy Generator or int or None
        Source of the lighting field and noise; a seed gives identical images.

    Returns
    -------
    (H, W) or (H, W, 3) uint8 ndarray

    Raises
    ------
    InputError
        If the camera is behind the sheet or inside the instrument.

    Notes
    -----
    Without blur and noise, a pixel is the exact box-filter average of the scene over its
    square (module docstring): edges of the printed pattern lie where the projected truth
    puts them, to ~1e-3 px, for every lens model. Shading colours (texture, shaft) are
    evaluated at the pixel centre.

    Example
    -------
    >>> from pencilcal.toolkit.camera.model import Camera
    >>> cam = Camera("opencv", 160, 120, [[150.0, 0, 79.5], [0, 150.0, 59.5], [0, 0, 1]], [-0.1, 0.02, 0, 0])
    >>> img = render_frame(cam, np.eye(3), [-131.0, -62.0, 600.0], layout_sheet(), noise=2.0, rng=1)
    >>> img.shape
    (120, 160)
    """
    R = np.asarray(R_cam_from_target, float)
    t = np.asarray(t_cam_from_target, float).reshape(3)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)) or not np.all(np.isfinite(t)):
        raise InputError("R_cam_from_target must be a finite 3x3 matrix and t a finite 3-vector")
    rng = _as_rng(rng)
    W, H = camera.width, camera.height
    C_t = -R.T @ t  # camera centre in the target frame
    if C_t[2] >= 0:
        raise InputError("the camera is behind the sheet (it must see the printed face, z < 0 side)")
    nch = 3 if color else 1

    def tint(name):
        return _TINT[name] if color else np.ones(1)

    sheet_polys = [(_to_camera(R, t, p), s) for p, s in sheet.ink_polygons]
    c_ink = _render_coverage(camera, sheet_polys)
    c_paper = _render_coverage(camera, [(_to_camera(R, t, sheet.paper_polygon()), 1)])
    c_paper = np.clip(c_paper, 0.0, 1.0)
    c_ink = np.clip(c_ink, 0.0, c_paper)

    if isinstance(background, str) and background == "table":
        backdrop = Backdrop.around(sheet)
    elif isinstance(background, Backdrop):
        backdrop = background
    else:
        backdrop = None
    img = np.empty((H, W, nch), np.float64)
    paper_term = REFLECTANCE["paper"] * (c_paper - c_ink)[..., None] * tint("paper")
    ink_term = REFLECTANCE["ink"] * c_ink[..., None] * tint("ink")
    if backdrop is None:
        if isinstance(background, str):
            if background != "plain":
                raise InputError(f"background must be 'table', 'plain', a number or a Backdrop, got {background!r}")
            grey = REFLECTANCE["plain"]
        else:
            grey = float(background)
        img[:] = grey * (1.0 - c_paper)[..., None] * tint("plain")
        img += paper_term + ink_term
    else:
        rays = _rays(camera)
        x0, y0, x1, y1 = backdrop.table
        c_table = np.clip(_render_coverage(camera, [(_to_camera(R, t, _rect(x0, y0, x1, y1)), 1)]), 0.0, 1.0)
        c_paper = np.minimum(c_paper, c_table)
        img[:] = paper_term + ink_term
        # the texture only where the table shows, the wall only where the table does not
        sel = (c_table - c_paper) > 0
        if np.any(sel):
            rays_t = rays[sel].astype(np.float64) @ R  # R^T d
            tex = _plane_texture(backdrop.texture, backdrop.texel, rays_t, C_t, np.array([x0, y0, 0.0]),
                                 np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]),
                                 (0.0, 0.0), _pixel_angle(camera))
            tex *= _face_shade(np.array([0.0, 0.0, -1.0]))
            img[sel] += (tex * (c_table - c_paper)[sel])[:, None] * tint("table")
        sel = c_table < 1
        if np.any(sel):
            # the room beyond the table: the texture, blurred and faint, on a sphere far away
            rt = rays[sel].astype(np.float64) @ R
            az = np.arctan2(rt[:, 1], rt[:, 0])
            el = np.arcsin(np.clip(rt[:, 2], -1.0, 1.0))
            room = _sample_texture(backdrop.texture, az * 400.0, el * 400.0, np.full(az.shape, 16.0))
            wall = REFLECTANCE["wall"] * (0.7 + 1.0 * room)
            img[sel] += (wall * (1.0 - c_table[sel]))[:, None] * tint("wall")
        _draw_boxes(img, camera, R, t, C_t, rays, backdrop, color)
    if instrument is not None:
        outline = instrument._outline(R, t)
        if outline is not None:
            c_shaft, sl = _render_coverage(camera, [(outline, 1)], window=True)
            if c_shaft.size:
                c = np.clip(c_shaft, 0.0, 1.0)
                sel = c > 0
                lum = instrument.shade(R, t, _rays(camera)[sl][sel].astype(np.float64))
                win = img[sl]
                win[sel] = win[sel] * (1.0 - c[sel])[:, None] + (c[sel] * lum)[:, None] * tint("shaft")
    gain = _lighting_gain(W, H, float(lighting), rng)
    if gain is not None:
        img *= gain[..., None]
    img *= float(exposure)
    if blur_px and blur_px > 0:
        import cv2

        img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), float(blur_px), borderType=cv2.BORDER_REFLECT)
        img = img.reshape(H, W, nch).astype(np.float64)
    out = 255.0 * np.clip(img, 0.0, 1.0) ** (1.0 / float(gamma))
    if noise and noise > 0:
        sigma = float(noise) * np.sqrt(0.25 + 0.75 * out / 128.0)
        out = out + sigma * rng.standard_normal(out.shape)
    out = np.clip(np.rint(out), 0, 255).astype(np.uint8)
    return out[..., 0] if nch == 1 else out


def _pixel_angle(camera):
    """Angle one pixel subtends near the image centre [rad]."""
    return 1.0 / math.sqrt(camera.K[0, 0] * camera.K[1, 1])


def _draw_boxes(img, camera, R, t, C_t, rays, backdrop, color):
    """Composite the backdrop's boxes over img (H, W, C), far to near (painter's order).

    The visible faces of one box partition its silhouette, so they are added up before
    compositing: no background leaks through the seams between faces.
    """
    if not backdrop.boxes:
        return
    order = sorted(backdrop.boxes, key=lambda b: -np.linalg.norm(
        np.array([(b[0] + b[2]) / 2, (b[1] + b[3]) / 2, -b[4] / 2]) - C_t))
    pyr = backdrop.texture
    trng = np.random.default_rng([backdrop.seed, 31337])
    tints = {b: (trng.uniform(0.75, 1.2, 3) if color else np.ones(1)) for b in backdrop.boxes}
    H, W = img.shape[:2]
    pa = _pixel_angle(camera)
    for k, box in enumerate(order):
        x0, y0, x1, y1, h = box
        z0 = -h
        faces = [  # (corners (4, 3), outward normal)
            (np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0]]), np.array([0, 0, -1.0])),
            (np.array([[x0, y0, 0], [x1, y0, 0], [x1, y0, z0], [x0, y0, z0]]), np.array([0, -1.0, 0])),
            (np.array([[x0, y1, 0], [x1, y1, 0], [x1, y1, z0], [x0, y1, z0]]), np.array([0, 1.0, 0])),
            (np.array([[x0, y0, 0], [x0, y1, 0], [x0, y1, z0], [x0, y0, z0]]), np.array([-1.0, 0, 0])),
            (np.array([[x1, y0, 0], [x1, y1, 0], [x1, y1, z0], [x1, y0, z0]]), np.array([1.0, 0, 0])),
        ]
        parts = []
        for fi, (corners, n) in enumerate(faces):
            if np.dot(n, C_t - corners.mean(0)) <= 0:
                continue  # faces away from the camera
            cov, sl = _render_coverage(camera, [(_to_camera(R, t, corners), 1)], window=True)
            if cov.size == 0:
                continue
            cov = np.clip(cov, 0.0, 1.0)
            sel = cov > 0
            e1 = corners[1] - corners[0]
            e2 = corners[3] - corners[0]
            e1 /= np.linalg.norm(e1)
            e2 /= np.linalg.norm(e2)
            rays_t = rays[sl][sel].astype(np.float64) @ R
            off = (97.0 * (fi + 1) + 401.0 * k, 53.0 * (fi + 1) + 211.0 * k)
            # boxes: the same texture at 2.5x finer scale and brighter, so they stand out
            val = _plane_texture(pyr, backdrop.texel / 2.5, rays_t, C_t, corners[0], n, e1, e2, off, pa)
            parts.append((cov, sel, sl, (0.25 + 1.2 * val) * _face_shade(n)))
        if not parts:
            continue
        total = np.zeros((H, W))
        acc = np.zeros((H, W, img.shape[2]))
        for cov, sel, sl, val in parts:
            total[sl] += cov
            acc[sl][sel] += (cov[sel] * val)[:, None] * tints[box]
        total = np.clip(total, 0.0, 1.0)
        img *= (1.0 - total)[..., None]
        img += acc


# ------------------------------------------------------------------ printing the sheet
def sheet_raster(sheet, dpi):
    """The sheet as printed: a (H, W) uint8 image at `dpi`, exact area anti-aliasing.

    Pixel (i, j) covers target x in [x0 + j p, x0 + (j + 1) p] with p = 25.4 / dpi mm and
    x0 the paper's left edge (likewise y), so board corners are spaced exactly
    ``square * dpi / 25.4`` pixels apart. The image has round(paper / p) pixels a side.

    Example
    -------
    >>> img = sheet_raster(layout_sheet(), 50)
    >>> img.shape, int(img.max()), int(img.min())
    ((413, 585), 255, 0)
    """
    if not dpi > 0:
        raise InputError(f"dpi must be positive, got {dpi}")
    p = 25.4 / float(dpi)
    x0, y0 = sheet.paper_origin
    W = int(round(sheet.paper_size[0] / p))
    H = int(round(sheet.paper_size[1] / p))
    if W * H > 400e6:
        raise InputError(f"{W} x {H} pixels is too large; lower the dpi")
    polys = [((poly - [x0, y0]) / p - 0.5, s) for poly, s in sheet.ink_polygons]
    ink = np.clip(polygon_coverage(polys, W, H), 0.0, 1.0)
    return np.rint(255.0 * (1.0 - ink)).astype(np.uint8)


def _caption(sheet):
    """Two caption lines: what is printed, and how to check the print's scale."""
    b, p = sheet.board, sheet.pencil
    steps = np.degrees(np.diff(p.angles))
    fan = (f"{p.count} spokes {steps[0]:g} deg apart" if np.allclose(steps, steps[0])
           else f"{p.count} spokes")
    return [f"pencilcal target: ChArUco {b.squares[0]}x{b.squares[1]}, square {b.square:g} mm, marker {b.marker:g} mm, "
            f"{b.dictionary}; fan of {fan}, radius {p.radius[0]:g}-{p.radius[1]:g} mm, width {p.width:g} mm",
            f"Print at 100 % (actual size, no fit to page). A square must measure {b.square:g} mm."]


_CAPTION_MM = 2.2  # letter height [mm]


def _caption_y(sheet):
    """Baseline of the first caption line [target y, mm], or None if there is no room."""
    y_bottom = sheet.paper_origin[1] + sheet.paper_size[1]
    free = y_bottom - sheet.content_bounds[3]
    if free < 4.0 * _CAPTION_MM + 2.0:
        return None
    return sheet.content_bounds[3] + min(free / 2.0 - _CAPTION_MM, 5.0) + _CAPTION_MM


def write_sheet_png(path, sheet, dpi=300, force=False, caption=True):
    """Write the sheet as a grey PNG at `dpi` with the dpi in its metadata (true scale).

    The caption (two lines in the bottom margin, when there is room) is not part of the
    analytic sheet: `render_frame` does not draw it.
    """
    from PIL import Image

    from pencilcal.toolkit.io.files import atomic_path

    img = sheet_raster(sheet, dpi)
    y = _caption_y(sheet) if caption else None
    if y is not None:
        import cv2

        p = 25.4 / float(dpi)
        x0 = (sheet.content_bounds[0] - sheet.paper_origin[0]) / p
        room = (sheet.paper_origin[0] + sheet.paper_size[0] - sheet.margin - sheet.content_bounds[0]) / p
        scale = _CAPTION_MM / p / 22.0  # Hershey simplex capitals are ~22 units tall at scale 1
        widest = max(cv2.getTextSize(t, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0] for t in _caption(sheet))
        scale *= min(1.0, room / max(widest, 1))
        thick = max(1, int(round(scale * 1.2)))
        for k, text in enumerate(_caption(sheet)):
            org = (int(round(x0)), int(round((y - sheet.paper_origin[1] + 1.8 * _CAPTION_MM * k) / p)))
            cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, 90, thick, cv2.LINE_AA)
    with atomic_path(path, force) as tmp:
        Image.fromarray(img).save(tmp, format="PNG", dpi=(float(dpi), float(dpi)))


def write_sheet_pdf(path, sheet, force=False, caption=True):
    """Write the sheet as a one-page vector PDF whose page is exactly the paper size.

    The dark area is one compound path (fills and holes), so no hairline seams appear
    between touching cells whatever the viewer's anti-aliasing. The caption (bottom margin)
    is text only, not part of the analytic sheet.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure
    from matplotlib.patches import PathPatch
    from matplotlib.path import Path as MPath

    from pencilcal.toolkit.io.files import atomic_path

    w, h = sheet.paper_size
    x0, y0 = sheet.paper_origin
    fig = Figure(figsize=(w / 25.4, h / 25.4))
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.set_xlim(x0, x0 + w)
    ax.set_ylim(y0 + h, y0)  # y down the sheet
    ax.set_axis_off()
    verts, codes = [], []
    for poly, _ in sheet.ink_polygons:
        verts.extend(poly.tolist() + [poly[0].tolist()])
        codes.extend([MPath.MOVETO] + [MPath.LINETO] * (len(poly) - 1) + [MPath.CLOSEPOLY])
    ax.add_patch(PathPatch(MPath(verts, codes), facecolor="black", edgecolor="none", linewidth=0))
    y = _caption_y(sheet) if caption else None
    if y is not None:
        for k, text in enumerate(_caption(sheet)):
            ax.text(sheet.content_bounds[0], y + 1.8 * _CAPTION_MM * k, text, fontsize=6.0, color="0.35",
                    va="baseline", ha="left")
    with atomic_path(path, force) as tmp:
        fig.savefig(tmp, format="pdf", metadata={"Title": "pencilcal target", "Creator": "pencilcal"})

"""The printed target: a ChArUco board and a fan of dark bars (the spokes), or a Siemens star, on a
sheet of paper.

`Sheet` defines everything printed analytically, as polygons in the *target frame* (= the
board frame, frames.py: x right, y down the sheet, z into the sheet, origin at the outer
corner of the board's first square; millimetres). `layout_sheet` builds the default
layout; `sheet_raster`, `write_sheet_png` and `write_sheet_pdf` print it at true scale,
with a caption in the bottom margin that says how to check the print's scale. render.py
draws the same polygons as a camera sees them.

Example
-------
>>> sheet = layout_sheet()
>>> sheet.paper, sheet.board.squares, sheet.pencil.count
('a4 landscape', (7, 5), 8)
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from types import MappingProxyType

import numpy as np

from pencilcal.toolkit.board.spec import Board, board_from_dict
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.pencil.spec import Pencil, pencil_from_dict
from pencilcal.toolkit.synth.polygons import annular_sector, convex_overlap, oriented, point_in_polygon, rect
from pencilcal.toolkit.synth.raster import polygon_coverage

__all__ = ["PAPER_SIZES", "DEFAULT_BOARD", "Sheet", "layout_sheet", "default_board", "star_pencil", "sheet_raster",
           "write_sheet_png", "write_sheet_pdf"]

#: Paper sizes (long side, short side) [mm].
PAPER_SIZES = MappingProxyType({"a4": (297.0, 210.0), "a3": (420.0, 297.0), "letter": (279.4, 215.9)})

#: The default printed board: 7 x 5 squares of 25 mm, 18 mm markers.
DEFAULT_BOARD = MappingProxyType({"type": "charuco", "squares": (7, 5), "square": 25.0, "marker": 18.0,
                                  "dictionary": "DICT_5X5_100"})

_CAPTION_MM = 2.2  # caption letter height [mm]


def default_board() -> Board:
    """The default printed board (`DEFAULT_BOARD`) as a `Board`."""
    return board_from_dict(dict(DEFAULT_BOARD), source="default board")


def _bar_corners(vertex, theta, radius, width):
    """(4, 2) corners [mm] of the bar of `width` [mm] whose centre line runs from radius[0]
    to radius[1] [mm] from `vertex` (2,) [mm] along angle `theta` [rad]."""
    d = np.array([np.cos(theta), np.sin(theta)])
    n = np.array([-d[1], d[0]])
    v = np.asarray(vertex, float)
    h = width / 2.0
    return np.array([v + radius[0] * d - h * n, v + radius[1] * d - h * n,
                     v + radius[1] * d + h * n, v + radius[0] * d + h * n])


@dataclass(frozen=True, eq=False)
class Sheet:
    """The printed target: a ChArUco board and a fan of dark bars (or a Siemens star) on a sheet
    of paper.

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
        Or a Siemens star (shape "wedge"): wedge k runs from the vertex out to ``radius[1]``
        between theta_k -+ ``wedge`` / 2, its outer end an arc of the star's outline.
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
        if p.vertex is None or p.radius is None or (p.width is None and p.shape != "wedge"):
            raise InputError("the sheet's pencil needs a vertex, a radius and a width (or wedges)")
        if p.shape == "edge":
            raise InputError("the sheet prints bars or a star's wedges, not sector boundaries")
        size = tuple(float(v) for v in self.paper_size)
        origin = tuple(float(v) for v in self.paper_origin)
        object.__setattr__(self, "paper_size", size)
        object.__setattr__(self, "paper_origin", origin)
        if not (size[0] > 0 and size[1] > 0) or self.margin < 0:
            raise InputError(f"paper size must be positive and the margin non-negative, got {size}, {self.margin}")
        bars = self.bars
        for i in range(len(bars)):
            for j in range(i + 1, len(bars)):
                if convex_overlap(bars[i], bars[j]):
                    raise InputError(
                        f"spokes {i} and {j} overlap: at radius {p.radius[0]:g} they are closer than "
                        f"their width {p.width:g}; use a larger inner radius, a larger step or thinner bars")
        bw, bh = b.size
        board_rect = rect(0.0, 0.0, bw, bh)
        for i, bar in enumerate(bars):
            if convex_overlap(bar, board_rect):
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
        """List of (K, 2) polygons, one per spoke [target mm]: the rotated rectangle of a bar,
        or a star's wedge."""
        p = self.pencil
        if p.shape == "wedge":
            h = 0.5 * p.wedge
            return [annular_sector(0.0, float(p.radius[1]), th - h, th + h, p.vertex) for th in p.angles]
        return [_bar_corners(p.vertex, th, p.radius, p.width) for th in p.angles]

    @property
    def content_bounds(self):
        """(x0, y0, x1, y1) [mm] of everything printed: the board and the bars."""
        bw, bh = self.board.size
        pts = np.concatenate([rect(0.0, 0.0, bw, bh)] + list(self.bars))
        return (float(pts[:, 0].min()), float(pts[:, 1].min()), float(pts[:, 0].max()), float(pts[:, 1].max()))

    @property
    def content_center(self):
        """(3,) centre of `content_bounds` on the sheet (z = 0) [mm]."""
        x0, y0, x1, y1 = self.content_bounds
        return np.array([(x0 + x1) / 2.0, (y0 + y1) / 2.0, 0.0])

    def paper_polygon(self):
        """(4, 2) corners of the paper [target mm]."""
        x0, y0 = self.paper_origin
        return rect(x0, y0, x0 + self.paper_size[0], y0 + self.paper_size[1])

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
                    out.append((oriented(rect(i * s, j * s, (i + 1) * s, (j + 1) * s)), 1))
        for mid, c in zip(ids, corners):
            # marker image: row r, column c of the (bits + 2)^2 cells; corner 0 is its
            # top-left, then clockwise (OpenCV's marker convention)
            cells = cv2.aruco.generateImageMarker(dictionary, int(mid), bits + 2) > 127
            p0, ex, ey = c[0], (c[1] - c[0]) / (bits + 2), (c[3] - c[0]) / (bits + 2)
            out.append((oriented(c.copy()), 1))
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
                    out.append((oriented(quad, positive=False), -1))
        for bar in self.bars:
            out.append((oriented(bar), 1))
        return out

    def ink_at(self, xy):
        """True where the sheet is printed dark. xy: (..., 2) target points [mm] -> (...) bool.

        Evaluates the same polygons the renderer uses (point-in-polygon, nonzero rule).
        """
        xy = np.asarray(xy, float)
        flat = xy.reshape(-1, 2)
        wind = np.zeros(len(flat))
        for poly, sign in self.ink_polygons:
            wind += sign * point_in_polygon(poly, flat)
        return (wind > 0.5).reshape(xy.shape[:-1])

    def to_dict(self):
        """Paper and layout, for truth files (the board and pencil have their own files)."""
        return {"paper": self.paper, "paper_size_mm": list(self.paper_size),
                "paper_origin": list(self.paper_origin), "margin": self.margin,
                "content_bounds": list(self.content_bounds)}


def layout_sheet(board=None, *, paper="a4", orientation="landscape", margin=10.0, gap=8.0,
                 spokes=8, step_deg=20.0, start_deg=None, angles_deg=None, radius=(15.0, 80.0),
                 width=1.0, side="right", vertex=None, star=None, star_radius=None):
    """The default printable layout: a ChArUco board with a fan of spokes (or a Siemens star)
    beside it.

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
    star : int, optional
        A Siemens star of this many dark wedges instead of the fan (`star_pencil`): wedge k
        centred at k 360 / star deg, as wide as the gaps, from the vertex out to
        `star_radius` [mm] (default: the largest whole millimetre that fits beside the board).

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
    if star is not None:
        return _star_sheet(board, paper, orientation, margin, gap, int(star), star_radius, side, vertex)
    size = _paper(paper, orientation, side)
    r = np.asarray(radius, float)
    if r.shape != (2,) or not (0 <= r[0] < r[1]):
        raise InputError(f"radius must be [inner, outer] with 0 <= inner < outer, got {list(radius)}")
    if not width > 0:
        raise InputError(f"the bar width must be positive, got {width}")
    # no larger fan fits; said before the layout's arithmetic, which overflows past 1e150 mm
    page = max(PAPER_SIZES[paper])
    for what, v in (("outer radius", r[1]), ("bar width", width)):
        if v > page:
            raise InputError(f"the fan's {what} of {float(v):g} mm is larger than {paper} paper ({page:g} mm): it "
                             "cannot fit")
    if angles_deg is None:
        if int(spokes) < 3:
            raise InputError(f"a pencil needs at least three spokes, got {spokes}")
        if start_deg is None:
            centre = 0.0 if side == "right" else 90.0
            start_deg = centre - (int(spokes) - 1) * float(step_deg) / 2.0
        angles_deg = float(start_deg) + float(step_deg) * np.arange(int(spokes))
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
    cx0 = min(0.0, vertex[0] + fx0)
    cy0 = min(0.0, vertex[1] + fy0)
    cx1 = max(bw, vertex[0] + fx1)
    cy1 = max(bh, vertex[1] + fy1)
    origin = (round((cx0 + cx1) / 2.0 - size[0] / 2.0, 3), round((cy0 + cy1) / 2.0 - size[1] / 2.0, 3))
    return Sheet(board, pencil, size, origin, float(margin), f"{paper} {orientation}")


def _paper(paper, orientation, side):
    """(width, height) [mm] of the paper, checked."""
    if paper not in PAPER_SIZES:
        raise InputError(f"unknown paper {paper!r}; expected one of {sorted(PAPER_SIZES)}")
    if orientation not in ("landscape", "portrait"):
        raise InputError(f"orientation must be landscape or portrait, got {orientation!r}")
    if side not in ("right", "below"):
        raise InputError(f"side must be right or below, got {side!r}")
    long_side, short_side = PAPER_SIZES[paper]
    return (long_side, short_side) if orientation == "landscape" else (short_side, long_side)


def star_pencil(wedges, radius, vertex=(0.0, 0.0)):
    """The pencil of a printed Siemens star: `wedges` dark wedges centred at k 360 / wedges
    deg, each half the step wide, from the vertex out to `radius` [mm], whose outline is a
    circle (its pencil file: shape wedge, circles [radius]).

    >>> p = star_pencil(64, 40.0)
    >>> p.count, p.shape, round(float(np.degrees(p.wedge)), 4), p.circles.tolist()
    (64, 'wedge', 2.8125, [40.0])
    """
    if int(wedges) < 4:
        raise InputError(f"a Siemens star needs at least 4 wedges, got {wedges}")
    step = 360.0 / int(wedges)
    return pencil_from_dict({"angles_deg": [float(a) for a in step * np.arange(int(wedges))], "shape": "wedge",
                             "vertex": [float(v) for v in vertex], "radius": [0.0, float(radius)],
                             "circles": [float(radius)], "polarity": "dark"}, source="star")


def _star_sheet(board, paper, orientation, margin, gap, wedges, radius, side, vertex):
    """`layout_sheet` with a Siemens star of `wedges` beside the board (its arguments)."""
    size = _paper(paper, orientation, side)
    bw, bh = board.size
    if side == "right":
        room = (size[0] - 2 * margin - bw - gap, size[1] - 2 * margin)
    else:
        room = (size[0] - 2 * margin, size[1] - 2 * margin - bh - gap)
    fits = math.floor(min(room) / 2.0 - 1e-9)
    if radius is None:
        radius = fits
    if not radius > 0:
        raise InputError(f"no room for a star beside the board on {paper} {orientation} paper; use larger paper")
    if vertex is None:
        r = float(radius)
        vertex = (math.ceil(bw + gap + r - 1e-9), bh / 2.0) if side == "right" else \
            (bw / 2.0, math.ceil(bh + gap + r - 1e-9))
    pencil = star_pencil(wedges, radius, np.round(np.asarray(vertex, float), 3) + 0.0)
    v, r = pencil.vertex, float(radius)
    cx0, cy0 = min(0.0, v[0] - r), min(0.0, v[1] - r)
    cx1, cy1 = max(bw, v[0] + r), max(bh, v[1] + r)
    origin = (round((cx0 + cx1) / 2.0 - size[0] / 2.0, 3), round((cy0 + cy1) / 2.0 - size[1] / 2.0, 3))
    return Sheet(board, pencil, size, origin, float(margin), f"{paper} {orientation}")


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
    what = (f"Siemens star of {p.count} wedges, radius {p.radius[1]:g} mm" if p.shape == "wedge" else
            f"fan of {fan}, radius {p.radius[0]:g}-{p.radius[1]:g} mm, width {p.width:g} mm")
    return [f"pencilcal target: ChArUco {b.squares[0]}x{b.squares[1]}, square {b.square:g} mm, marker {b.marker:g} mm, "
            f"{b.dictionary}; {what}",
            f"Print at 100 % (actual size, no fit to page). A square must measure {b.square:g} mm."]


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

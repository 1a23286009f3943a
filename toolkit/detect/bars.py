"""Thin bars (the printed spokes of a pencil): midlines of antiparallel edge pairs.

`detect_bars` pairs the two opposite edges of thin dark bars and returns their midlines
(`Bars`, a `segments.Segments` whose rows are midlines). Each bar has two long edges of
opposite polarity (dark inside): oriented by polarity (`segments.orient_by_polarity`),
they run in opposite directions, their dark sides face each other. Candidate pairs are
found on the detector's merged lines (`_antiparallel_candidates`, with slack), their edges
refitted (`refit`), the pairs tested again on the refitted edges (angle, sides, width,
overlap, a dark strip between them), each edge given to one bar at most, and the midline
(bisector of the two edges, `pairs.EdgePairs`) run between the bar's two end caps.
`bar_midlines_on_plane` moves the midlines onto the exact images of the bars' centre lines
once the plane they are printed on is known. Light bars on a dark ground are the dark bars
of the image with its levels turned over (``polarity="light"``); ``polarity="either"``
takes whichever the frame shows.

Conventions as in `segments`: ``[x1, y1, x2, y2]`` [px], raw pixels out, widths and
uncertainties in undistorted pixels.

Example
-------
>>> import numpy as np
>>> img = np.full((120, 200), 220, np.uint8); img[55:61, 20:180] = 30   # a 6 px bar
>>> bars = detect_bars(img, "lsd")
>>> len(bars), np.round(bars.ideal[0], 2).tolist(), np.round(bars.width_px, 2).tolist()
(1, [179.5, 57.5, 19.5, 57.5], [6.0])
"""
from __future__ import annotations

import inspect
from dataclasses import dataclass, fields, replace

import numpy as np

from pencilcal.toolkit.detect.edges import best_run
from pencilcal.toolkit.detect.image import GrayImage
from pencilcal.toolkit.detect.pairs import pair_geometry
from pencilcal.toolkit.detect.refit import EdgeFit, EdgeRefit, RefitOptions, refit_lines
from pencilcal.toolkit.detect.segments import (
    MERGE_ANGLE_TOL_DEG,
    MERGE_DIST_TOL_PX,
    Segments,
    detect_fragments,
    in_valid_region,
    merge_collinear,
    proposal_detector,
)
from pencilcal.toolkit.detect.working import check_camera_image, to_raw, to_raw_points, to_working
from pencilcal.toolkit.geometry.neighbours import neighbours_within
from pencilcal.toolkit.errors import InputError

__all__ = ["Bars", "BarOptions", "BAR_POLARITIES", "TRACK_SEARCH_PX", "detect_bars", "find_bars",
           "bar_midlines_on_plane"]

#: Half-width [px] of the first edge search around a previous frame's edge (`find_bars` with
#: a prior): a target moved by hand at 30 fps shifts its edges by up to ~5 px a frame (the
#: bench's tilt sweep, 2 deg a frame); an edge of the other polarity (the bar's other side)
#: is never taken, so the window may be wider than the bar.
TRACK_SEARCH_PX = 6.0
#: Stations along a prior edge in the coarse search for it (`find_bars` with a prior): enough
#: for its line and extent; the refit that measures it samples every `step_px` again.
_TRACK_STATIONS = 24

_PENCIL_BIN_DEG = 3.0  # directions closer than this count as one (`_pencil_support`)
_PENCIL_TOL_PX, _PENCIL_TOL_REL = 2.0, 0.005  # a line passes through a point within 2 px + 0.5 % of its distance
_PENCIL_MAX_LINES = 64  # at most this many lines are looked at (the longest)

#: What `detect_bars` looks for: dark bars on a light ground, light ones on a dark ground,
#: or whichever of the two the frame shows.
BAR_POLARITIES = ("dark", "light", "either")

_DARK_GROW = 1  # [px] dark features widened on the reduced image for the proposals


@dataclass(frozen=True, eq=False)
class Bars(Segments):
    """Midlines of thin dark bars (`detect_bars`): a `Segments` whose rows are midlines.

    Extra attributes: ``width_px`` (M,) [px] the bar's width across the midline at its
    centre (undistorted pixels); ``edges`` (M, 2, 4) [px] its two edge segments in raw pixels
    (first edge along the midline's direction, second reversed).
    The midline is the bisector of the two edge lines; its angle sd is
    sqrt(sigma_1^2 + sigma_2^2) / 2. It runs between the bar's two end caps, located along
    the midline where the grey level crosses half-way between the bar and the background.
    """

    width_px: np.ndarray
    edges: np.ndarray

    @classmethod
    def empty(cls, **extra):
        return super().empty(width_px=np.zeros(0), edges=np.zeros((0, 2, 4)), **extra)


@dataclass(frozen=True)
class BarOptions:
    """The settings of one `detect_bars` call, defaults resolved for the image.

    wmin, wmax [px]: accepted widths; conv [rad]: largest angle between a bar's edges; the
    others as the keywords of `detect_bars`.
    """

    wmin: float
    wmax: float
    conv: float
    min_length: float
    min_aspect: float
    min_overlap: float
    refine_ends: bool
    search_px: float
    sigma_px: float
    step_px: float
    max_gap_px: float
    min_gradient: float
    proposal_scale: float

    @classmethod
    def resolve(cls, shape, *, width_px_range, max_convergence_deg, search_px, proposal_scale, **kw):
        """The options for an image of `shape` (H, W): the defaults of `detect_bars` filled in
        and checked (InputError)."""
        H, W = shape
        wmin, wmax = (2.5, max(min(H, W) / 8.0, 10.0)) if width_px_range is None else map(float, width_px_range)
        if not (0 < wmin < wmax):
            raise InputError(f"width_px_range must be (min, max) with 0 < min < max, got {width_px_range!r}")
        if search_px is None:
            search_px = float(np.clip(0.5 * wmin, 0.75, 2.0))
        if proposal_scale is None:
            proposal_scale = 0.5 if min(H, W) >= 720 else 1.0
        if not 0.25 <= proposal_scale <= 1.0:
            raise InputError(f"proposal_scale must be in [0.25, 1], got {proposal_scale!r}")
        return cls(wmin=wmin, wmax=wmax, conv=np.radians(max_convergence_deg), search_px=search_px,
                   proposal_scale=proposal_scale, **kw)

    def refit_options(self):
        """The refit of the edges: continuous edges (gaps of at most 2.5 station steps)."""
        return RefitOptions(search=self.search_px, sigma_px=self.sigma_px, step_px=self.step_px,
                            max_gap_px=2.5 * self.step_px, min_gradient=self.min_gradient)


# ============================================================================ candidate pairs


def _antiparallel_candidates(lines, max_conv, max_width, min_aspect, min_overlap=0.0):
    """Index pairs (a, b), a < b, of oriented lines that may be the two edges of one bar.

    Necessary conditions only, each with slack, on (M, 4) lines running with their bright
    side on the left (`orient_by_polarity`), for bars at most `max_width` wide whose
    edges overlap by at least `min_aspect` times the width and by `min_overlap`:
    directions opposite within `max_conv` [rad]; each line's centre on the other's dark
    side (the test `pair_geometry` calls side_a, side_b < 0) and within the widest bar
    the shorter line allows (+ half the other's length times tan(max_conv) + 1 px) of the
    other line; and the two overlap along a's direction by more than `min_overlap` - 2 px
    - width * sin(max_conv).

    The aspect bound makes this near-linear on busy frames: a bar is at most a quarter as
    wide as its shorter edge is long, so the centres of a pair lie within ~1.4 lengths of
    the longer line's centre, and each line looks only at the centres within that radius
    (`neighbours_within`: short texture fragments meet only their close neighbours).
    """
    P = np.asarray(lines, float)
    M = P.shape[0]
    if M < 2:
        return np.zeros(0, int), np.zeros(0, int)
    p1, p2 = P[:, :2], P[:, 2:]
    d = p2 - p1
    L = np.hypot(d[:, 0], d[:, 1])
    u = d / np.maximum(L, 1e-12)[:, None]
    n = np.stack([-u[:, 1], u[:, 0]], -1)  # bright side
    c = 0.5 * (p1 + p2)
    off = -np.sum(n * p1, -1)
    tan_c = np.tan(min(max_conv, 1.0))
    wcap = np.minimum(max_width, (L + 2.0) / min_aspect)  # the widest bar each line allows
    # every pair is found from its longer line (ties: the larger index)
    R = L + wcap + 0.5 * L * tan_c + 3.0
    a, b = neighbours_within(c, R)
    keep = (L[b] < L[a]) | ((L[b] == L[a]) & (b > a))
    a, b = a[keep], b[keep]
    ok = np.sum(u[a] * u[b], -1) <= -np.cos(max_conv)
    a, b = a[ok], b[ok]
    # each centre on the other's dark side, within the widest bar (+ the tilt's reach)
    sa = np.sum(n[a] * c[b], -1) + off[a]
    sb = np.sum(n[b] * c[a], -1) + off[b]
    w = np.minimum(wcap[a], wcap[b])
    ok = (sa < 0) & (sb < 0)
    ok &= (sa >= -(w + 0.5 * L[b] * tan_c + 1.0)) & (sb >= -(w + 0.5 * L[a] * tan_c + 1.0))
    a, b, sa, sb = a[ok], b[ok], sa[ok], sb[ok]
    # overlap along a: b's end points projected on a's direction against [0, L_a] (the
    # bisector's direction differs by up to max_conv / 2: slack in proportion to the width)
    ua, pa = u[a], p1[a]
    t1 = np.sum((p1[b] - pa) * ua, -1)
    t2 = np.sum((p2[b] - pa) * ua, -1)
    ov = np.minimum(L[a], np.maximum(t1, t2)) - np.maximum(0.0, np.minimum(t1, t2))
    ok = ov > min_overlap - 2.0 - np.maximum(-sa, -sb) * np.sin(min(max_conv, 1.0))
    a, b = a[ok], b[ok]
    swap = a > b
    a[swap], b[swap] = b[swap], a[swap]
    return a, b


def _bar_darkness(img, camera, pr, contrast=None):
    """How much of the strip between two edges is dark, at 15 places along its overlap.

    Returns (K,) the fraction of places where the midline is darker than the surroundings
    (3 px beyond each edge) by half the edges' contrast (by default the median of that
    difference itself): ~1 for a bar; a row of squares whose edges line up, or two bars'
    outer edges, leave bright gaps on the midline.
    """
    f = np.linspace(0.05, 0.95, 15)
    al = pr.lo[:, None] + f[None, :] * (pr.hi - pr.lo)[:, None]
    m = pr.point(al)  # (K, 15, 2)
    off = (0.5 * pr.width + 3.0)[:, None, None] * pr.N[:, None, :]
    pts = to_raw_points(camera, np.stack([m, m + off, m - off]))  # (3, K, 15, 2)
    v = img.sample(pts[..., 0], pts[..., 1])
    diff = 0.5 * (v[1] + v[2]) - v[0]
    if contrast is None:
        contrast = np.median(diff, -1)
    return np.mean(diff > 0.5 * np.maximum(contrast, 1e-9)[:, None], -1)


def _rough_pairs(img, camera, lines, o):
    """Candidate pairs (a, b, overlap [px]) on the unrefined lines (M, 4), with slack, whose
    strip is dark all along (checked on the rough lines already: refitting the edges of
    every square of a ChArUco board beside the fan would cost more than the detector)."""
    a, b = _antiparallel_candidates(lines, o.conv + np.radians(3.0), 1.4 * o.wmax + 1.0, 0.7 * o.min_aspect,
                                    0.3 * o.min_length)
    if a.size == 0:
        return a, b, np.zeros(0)
    pr = pair_geometry(lines, a, b)
    ok = ((pr.hi - pr.lo) >= 0.3 * o.min_length) & (pr.width >= 0.6 * o.wmin - 1.0) & (pr.width <= 1.4 * o.wmax + 1.0)
    ok &= (pr.side_a < 0) & (pr.side_b < 0) & ((pr.hi - pr.lo) >= 0.7 * o.min_aspect * pr.width)
    sel = np.flatnonzero(ok)
    ok[sel] = _bar_darkness(img, camera, pr.take(sel)) >= 0.7
    return a[ok], b[ok], (pr.hi - pr.lo)[ok]


def _complete_partners(img, camera, lines, idx, max_width, min_aspect, max_conv, min_length, stations=5):
    """Second edges for lines `idx` of (M, 4) oriented working lines that have none.

    A detector on a reduced image often reports one edge of a thin bar only (its two edges
    blur into one outline), or a piece of it. Across each line at least `min_length` long,
    into its dark side, the grey-level profile at `stations` places along it is searched for
    the bar's far edge: the first place where the profile, having fallen below half-way
    between the bright side's level and the darkest value, climbs back above it, within the
    widest bar the line allows (max_width, and 1/min_aspect of its length). Where at least
    4 stations agree on a straight edge within max_conv of antiparallel and 1 px, that edge
    (reversed: its bright side outwards, spanning the line's extent) is a proposal like the
    detector's own. Accuracy comes from the refit later; this only has to land within its
    search window, so each profile is mapped to raw pixels by its two ends (the lens map
    is smooth over a bar's width).

    Returns (new lines (K, 4), origin index into `lines` of each (K,)).
    """
    idx = np.asarray(idx, int)
    P = np.asarray(lines, float)[idx]
    p1, p2 = P[:, :2], P[:, 2:]
    d = p2 - p1
    L = np.hypot(d[:, 0], d[:, 1])
    long_enough = L >= min_length
    idx, p1, p2, d, L = idx[long_enough], p1[long_enough], p2[long_enough], d[long_enough], L[long_enough]
    K = idx.size
    if K == 0:
        return np.zeros((0, 4)), np.zeros(0, int)
    u = d / L[:, None]
    n = np.stack([-u[:, 1], u[:, 0]], -1)  # bright side
    reach = np.minimum(max_width, (L + 2.0) / min_aspect) + 2.0
    T = 32
    step = np.maximum(0.5, reach / T)
    f = (np.arange(stations) + 0.5) / stations
    base = p1[:, None, :] + (f[None, :, None] * d[:, None, :])  # (K, S, 2)
    t0, t1 = -3.0 * step, T * step  # 3 samples on the bright side, T into the dark side
    ends = np.stack([base - t0[:, None, None] * n[:, None, :], base - t1[:, None, None] * n[:, None, :]])
    r0, r1 = to_raw_points(camera, ends)  # (K, S, 2) each
    g = (np.arange(-3, T + 1) + 3.0) / (T + 3.0)  # (T + 4,) from t0 to t1
    pts = r0[:, :, None, :] + g[None, None, :, None] * (r1 - r0)[:, :, None, :]
    prof = img.sample(pts[..., 0], pts[..., 1]).astype(float)  # (K, S, T + 4)
    bright = prof[..., :2].mean(-1)
    inner = prof[..., 4:]  # t = step, 2 step, ... into the dark side
    dark = inner.min(-1)
    half = 0.5 * (bright + dark)
    below = inner < half[..., None]
    # the bar's interior starts at the line (within 2 px) and the far edge is the first
    # climb back above half-way after it
    first_below = np.argmax(below, -1)
    above_after = ~below & (np.cumsum(below, -1) > 0)
    k = np.clip(np.argmax(above_after, -1), 1, T - 1)
    found = above_after.any(-1) & ((first_below + 1) * step[:, None] <= 2.0 + step[:, None])
    found &= (bright - dark) >= 8.0
    q0 = np.take_along_axis(inner, (k - 1)[..., None], -1)[..., 0]
    q1 = np.take_along_axis(inner, k[..., None], -1)[..., 0]
    with np.errstate(all="ignore"):
        fr = np.clip((half - q0) / (q1 - q0), 0.0, 1.0)
    tk = (k + fr) * step[:, None]
    ok = found.sum(-1) >= stations - 1
    if not np.any(ok):
        return np.zeros((0, 4)), np.zeros(0, int)
    # a straight far edge: least squares of the crossing distance against the position along
    s = f[None, :] * L[:, None]
    w = found.astype(float)
    W_ = np.maximum(w.sum(-1), 1.0)
    sm = (w * s).sum(-1) / W_
    tm = (w * tk).sum(-1) / W_
    ds = s - sm[:, None]
    slope = (w * ds * (tk - tm[:, None])).sum(-1) / np.maximum((w * ds * ds).sum(-1), 1e-12)
    res = np.where(found, tk - tm[:, None] - slope[:, None] * ds, 0.0)
    ok &= np.sqrt((res * res).sum(-1) / W_) <= 1.0
    ok &= (np.abs(np.arctan(slope)) <= max_conv) & (tm >= 1.0)
    o = np.flatnonzero(ok)
    if o.size == 0:
        return np.zeros((0, 4)), np.zeros(0, int)
    # far edge across the line's whole extent, reversed
    e1 = tm[o] - slope[o] * sm[o]
    e2 = tm[o] + slope[o] * (L[o] - sm[o])
    q1 = p1[o] - e1[:, None] * n[o]
    q2 = p2[o] - e2[:, None] * n[o]
    return np.concatenate([q2, q1], -1), idx[o]


def _proposed_pairs(img, detector, camera, o, detector_params, roi=None):
    """The detector's merged lines (M, 4) [working px] and their candidate pairs (a, b).

    On a reduced image (proposal_scale < 1) the detector often sees one edge of a thin bar
    only, or a piece of it: the other is looked for across the dark side of every line that
    no partner covers along most of its length (`_complete_partners`), and FLD (EDLines) is
    asked for no fragment shorter than 0.9 min_length: a bar's edges are as long as the bar.
    """
    params = dict(detector_params or {})
    if o.proposal_scale < 1.0:
        # fragments of a bar's edges on the reduced image are (nearly) as long as the bar
        shortest = max(10, int(0.9 * o.proposal_scale * o.min_length))
        if detector == "fld":
            params.setdefault("length_threshold", shortest)
        elif detector == "edlines":
            params.setdefault("MinLineLength", shortest)
    _, work = detect_fragments(img, detector, camera, params, scale=o.proposal_scale, dark_grow=_DARK_GROW, roi=roi)
    lines = merge_collinear(work, MERGE_ANGLE_TOL_DEG, MERGE_DIST_TOL_PX, o.max_gap_px)[0]
    L = np.hypot(lines[:, 2] - lines[:, 0], lines[:, 3] - lines[:, 1])
    keep = L >= max(0.5 * o.min_length, 4.0)
    lines, L = lines[keep], L[keep]
    a, b, ov = _rough_pairs(img, camera, lines, o)
    if o.proposal_scale < 1.0:
        cover = np.zeros(lines.shape[0])
        for idx in (a, b):
            np.maximum.at(cover, idx, ov / np.maximum(L[idx], 1e-9))
        lone = np.flatnonzero(cover < 0.7)
        new, _ = _complete_partners(img, camera, lines, lone, 1.4 * o.wmax + 1.0, 0.7 * o.min_aspect,
                                    o.conv + np.radians(3.0), o.min_length)
        if new.shape[0]:
            # a completed edge and a piece of it the detector did see become one line
            lines = merge_collinear(np.concatenate([lines, new]), MERGE_ANGLE_TOL_DEG, MERGE_DIST_TOL_PX,
                                    o.max_gap_px)[0]
            a, b, _ = _rough_pairs(img, camera, lines, o)
    return lines, a, b


# ============================================================================ refitted pairs


def _refitted_edges(img, camera, lines, o, opts):
    """The refitted edges (K, 4) [working px] of the candidate lines (M, 4) and their
    `EdgeFit` (K rows: the lines that could be refitted).

    Further passes (a window that was off-centre, an edge that runs on past the stations
    and grows by a quarter of its length each time) cost more than the first one on a busy
    frame, where most edges touch their ends (rows of squares): they are run only for edges
    that still pair as a bar after the first (angles, sides, width). No second merge here:
    each edge goes into one bar at most, so a duplicate edge costs nothing but itself.
    """
    st = EdgeRefit(img, lines, camera, opts)
    fit = st.fit()
    okf = np.flatnonzero(fit.ok)
    E = fit.lines()[okf]
    a, b = _antiparallel_candidates(E, o.conv, o.wmax + 2.0, 0.7 * o.min_aspect)
    if a.size:
        pr = pair_geometry(E, a, b)
        ok = (pr.conv <= o.conv) & (pr.side_a < 0) & (pr.side_b < 0) & (pr.width >= o.wmin) & (pr.width <= o.wmax)
        ok &= (pr.hi - pr.lo) >= 0.7 * o.min_aspect * pr.width
        st.more(okf[np.unique(np.concatenate([a[ok], b[ok]]))], grow=True)
        fit = st.fit()
    sub = fit.take(fit.ok)
    return sub.lines(), sub


def _bar_pairs(img, camera, E, sub, o):
    """The bars among the refitted edges E (K, 4) (`EdgeFit` sub): `EdgePairs` of the pairs
    that pass every test, each edge in one bar at most (narrowest pair first); None when
    there are none."""
    a, b = _antiparallel_candidates(E, o.conv, o.wmax + 2.0, o.min_aspect)
    if a.size == 0:
        return None
    pr = pair_geometry(E, a, b)
    La = np.hypot(*(sub.p2 - sub.p1).T)
    ok = (pr.conv <= o.conv) & (pr.side_a < 0) & (pr.side_b < 0)
    ok &= (pr.width >= o.wmin) & (pr.width <= o.wmax)
    ok &= (pr.hi - pr.lo) >= np.maximum(o.min_overlap * np.minimum(La[a], La[b]), o.min_aspect * pr.width)
    pr = pr.take(np.flatnonzero(ok))
    if pr.a.size:
        dark = _bar_darkness(img, camera, pr, np.minimum(sub.contrast[pr.a], sub.contrast[pr.b]))
        pr = pr.take(np.flatnonzero(dark >= 0.85))
    if pr.a.size == 0:
        return None
    return pr.take(_greedy(pr.a, pr.b, pr.width, E.shape[0]))


def _greedy(a, b, cost, M):
    """Pairs in order of increasing cost, each line used at most once. Returns indices."""
    used = np.zeros(M, bool)
    chosen = []
    for k in np.argsort(cost, kind="stable"):
        if not used[a[k]] and not used[b[k]]:
            used[a[k]] = used[b[k]] = True
            chosen.append(k)
    return np.asarray(chosen, int)


def _edge_frame(P):
    """p1 (N, 2), d (N, 2), L (N,), u (N, 2) of segments P (N, 4)."""
    p1 = P[:, :2]
    d = P[:, 2:] - p1
    L = np.hypot(d[:, 0], d[:, 1])
    u = d / np.maximum(L, 1e-12)[:, None]
    return p1, d, L, u


def _close_pairs(P, partner, reach):
    """Index pairs (pi, pj) of the segments P (N, 4) that cross or come within `reach` [px]
    of each other, each segment's `partner` (N,) left out."""
    n2 = P.shape[0]
    p1, d, L, u = _edge_frame(P)
    c = p1 + 0.5 * d
    # pairs of edges that can come within reach: centres closer than half their lengths + reach
    cd = np.hypot(*(c[:, None, :] - c[None, :, :]).transpose(2, 0, 1))
    close = cd <= 0.5 * (L[:, None] + L[None, :]) + reach
    np.fill_diagonal(close, False)
    close[np.arange(n2), partner] = False
    pi, pj = np.nonzero(close)
    # the pairs that do come within reach: segment-to-segment distance (0 when they cross)
    p2 = P[:, 2:]

    def to_seg(x, j):  # distance of points x (K, 2) from segments j
        t = np.clip(np.sum((x - p1[j]) * u[j], -1), 0.0, L[j])
        return np.hypot(*(x - p1[j] - t[:, None] * u[j]).T)

    def side(o, v, x):
        return np.sign(v[:, 0] * (x[:, 1] - o[:, 1]) - v[:, 1] * (x[:, 0] - o[:, 0]))

    cross = ((side(p1[pi], d[pi], p1[pj]) * side(p1[pi], d[pi], p2[pj]) < 0)
             & (side(p1[pj], d[pj], p1[pi]) * side(p1[pj], d[pj], p2[pi]) < 0))
    seg_d = np.minimum.reduce([to_seg(p1[pi], pj), to_seg(p2[pi], pj), to_seg(p1[pj], pi), to_seg(p2[pj], pi)])
    within = cross | (seg_d < reach)
    return pi[within], pj[within]


def _clear_runs(P, pi, pj, reach, step):
    """The part of each segment of P (N, 4) that lies `reach` [px] or more from the others
    it comes close to (pairs pi, pj): stations every `step` px along it, the longest clear
    run. Returns (hit, s_lo, s_hi): the segments worth a refit on their clear run [s_lo,
    s_hi] [px along] (at least 40 % of it and 15 px long, leaving out at least 2 reach)."""
    p1, d, L, u = _edge_frame(P)
    n2 = P.shape[0]
    S = int(np.ceil(L[np.unique(pi)].max() / step)) + 1
    s = np.minimum(np.arange(S)[None, :] * step, L[:, None])  # (n2, S) stations along each edge
    valid = np.arange(S)[None, :] * step <= L[:, None] + 1e-9
    pts = p1[:, None, :] + s[..., None] * u[:, None, :]
    q = pts[pi] - p1[pj][:, None, :]  # (pairs, S, 2)
    t = np.clip(np.sum(q * u[pj][:, None, :], -1), 0.0, L[pj][:, None])
    dist = np.hypot(*(q - t[..., None] * u[pj][:, None, :]).transpose(2, 0, 1))
    near = np.zeros((n2, S), bool)
    np.logical_or.at(near, pi, dist < reach)
    near &= valid
    hit = np.flatnonzero(near.any(1))
    if hit.size == 0:
        return hit, np.zeros(0), np.zeros(0)
    clear = best_run(s[hit], valid[hit] & ~near[hit], np.ones((hit.size, S)), 1.5 * step)
    has = clear.any(1)
    k1 = np.argmax(clear, 1)
    k2 = S - 1 - np.argmax(clear[:, ::-1], 1)
    r = np.arange(hit.size)
    s_lo, s_hi = s[hit][r, k1], s[hit][r, k2]
    # an edge that only meets another near its end (squares touching at a corner, a row of
    # them) lost nothing the refit used (it drops the stations by its ends anyway); a spoke
    # converging on its neighbour at a small angle loses reach / sin(angle), tens of px
    worth = has & ((s_hi - s_lo) >= np.maximum(0.4 * L[hit], 15.0)) & (L[hit] - (s_hi - s_lo) >= 2.0 * reach)
    return hit[worth], s_lo[worth], s_hi[worth]


def _clear_of_neighbours(img, camera, E, sub, a, b, opts, reach, step=2.0):
    """Refit the edges of the chosen bars (pairs a, b of the (M, 4) edges E, `EdgeFit` sub)
    on the part of each that lies `reach` px or more from every other chosen edge but its
    partner; returns (E, sub) with those edges replaced.

    A fan's spokes crowd near the vertex: there a neighbouring bar's edge falls inside an
    edge's profile window (`reach`: search + 3 sd of the kernel), pulls the derivative's peak
    towards it, and turns the edge by up to ~0.05 deg, the same way on every spoke, which
    reads as tilt (measured: +1 sd on a 13-spoke fan 10 deg apart, +0.2 sd after). Only
    pairs of edges whose segments come within `reach` are looked at. The refit then uses the
    clear run of stations only, if it is at least 40% of the edge and 15 px long and leaves
    out at least 2 reach (less is what the refit drops by an edge's ends anyway); the edge's
    ends stay where they were, moved onto the new line, so the bar keeps its extent.
    """
    K = a.size
    if K < 2:
        return E, sub
    idx = np.concatenate([a, b])
    partner = np.r_[np.arange(K, idx.size), np.arange(K)]
    P = E[idx]
    pi, pj = _close_pairs(P, partner, reach)
    if pi.size == 0:
        return E, sub
    hit, s_lo, s_hi = _clear_runs(P, pi, pj, reach, step)
    if hit.size == 0:
        return E, sub
    p1, _, _, u = _edge_frame(P)
    trimmed = np.concatenate([p1[hit] + s_lo[:, None] * u[hit], p1[hit] + s_hi[:, None] * u[hit]], -1)
    new = EdgeRefit(img, trimmed, camera, replace(opts, extend=0.0)).fit()
    good = new.ok
    rows = idx[hit[good]]
    if rows.size == 0:
        return E, sub
    # the new line through the new centroid; the old ends moved across onto it
    nu = new.p2[good] - new.p1[good]
    nu /= np.maximum(np.linalg.norm(nu, axis=-1, keepdims=True), 1e-12)
    cen = new.centroid[good]

    def onto(p):
        return cen + np.sum((p - cen) * nu, -1)[:, None] * nu

    E = E.copy()
    E[rows] = np.concatenate([onto(E[rows, :2]), onto(E[rows, 2:])], -1)
    fields_new = {f.name: getattr(sub, f.name).copy() for f in fields(sub)}
    for name in ("angle_sigma", "centre_sigma", "centroid", "residual", "count", "contrast"):
        fields_new[name][rows] = getattr(new, name)[good]
    fields_new["p1"][rows], fields_new["p2"][rows] = E[rows, :2], E[rows, 2:]
    return E, EdgeFit(**fields_new)


# ============================================================================ midlines


def _duplicates(seg, valid, score, tol_px=1.5):
    """(K,) True for segments (K, 4) that repeat a valid one: both ends within `tol_px` of
    its line and inside its extent (either way round), and it longer or, when the two
    cover each other, better by `score`. Two copies of one edge that the merge left apart
    (a detector's fragment and a completed edge a pixel off) refit to the same edge, and
    their pairs to the same bar or a piece of it."""
    K = seg.shape[0]
    dup = np.zeros(K, bool)
    idx = np.flatnonzero(valid)
    if idx.size < 2:
        return dup
    S = seg[idx]
    d = S[:, 2:] - S[:, :2]
    L = np.hypot(d[:, 0], d[:, 1])
    u = d / np.maximum(L, 1e-12)[:, None]
    n = np.stack([-u[:, 1], u[:, 0]], -1)
    e1 = S[None, :, :2] - S[:, None, :2]  # [i, j]: j's ends from i's first end
    e2 = S[None, :, 2:] - S[:, None, :2]
    perp = np.maximum(np.abs(np.sum(e1 * n[:, None], -1)), np.abs(np.sum(e2 * n[:, None], -1)))
    a1, a2 = np.sum(e1 * u[:, None], -1), np.sum(e2 * u[:, None], -1)
    inside = (np.minimum(a1, a2) >= -tol_px) & (np.maximum(a1, a2) <= L[:, None] + tol_px)
    within = (perp <= tol_px) & inside  # [i, j]: j lies on i
    np.fill_diagonal(within, False)
    order = np.argsort(-score[idx], kind="stable")
    rank = np.empty(idx.size, int)
    rank[order] = np.arange(idx.size)
    better = rank[:, None] < rank[None, :]  # [i, j]: i ranks above j
    dup[idx] = np.any(within & (~within.T | better), 0)
    return dup


def _refine_caps(img, camera, p1, p2, width, contrast):
    """Move the midline's ends (K, 2) to the bar's end caps: along the midline the grey level
    steps from the bar's to the background's; the cap is where it crosses half-way (the
    blurred step is symmetric about the true end). Ends without a clear step stay."""
    K = p1.shape[0]
    if K == 0:
        return p1, p2
    d = p2 - p1
    L = np.linalg.norm(d, axis=-1)
    u = d / L[:, None]
    nrm = np.stack([-u[:, 1], u[:, 0]], -1)
    A = np.minimum(np.maximum(2.0 * width, 6.0), 0.4 * L)  # reach of the profile [px]
    tau = np.linspace(-1.0, 1.0, 41)  # in units of A, outward positive
    lat = np.array([-0.25, 0.0, 0.25])
    ends = np.stack([p1, p2])  # (2, K, 2)
    dirn = np.stack([-u, u])  # outwards
    pts = (ends[:, :, None, None, :]
           + (A[:, None, None] * tau[None, None, :])[None, ..., None] * dirn[:, :, None, None, :]
           + (width[:, None, None] * lat[None, :, None])[None, ..., None] * nrm[None, :, None, None, :])
    pts = to_raw_points(camera, pts)  # (2, K, 3, T, 2)
    prof = img.sample(pts[..., 0], pts[..., 1]).mean(2).reshape(2 * K, -1)  # (2K, T)
    inner = np.median(prof[:, :10], -1)
    outer = np.median(prof[:, -10:], -1)
    half = 0.5 * (inner + outer)
    good = (outer - inner) > 0.3 * np.tile(contrast, 2)
    above = prof >= half[:, None]
    # crossings from below to above going outwards; take the one nearest the old end
    cross = ~above[:, :-1] & above[:, 1:]
    q0, q1 = prof[:, :-1], prof[:, 1:]
    with np.errstate(all="ignore"):
        fr = (half[:, None] - q0) / (q1 - q0)
    tc = tau[:-1][None, :] + fr * (tau[1] - tau[0])
    dist = np.where(cross, np.abs(tc), np.inf)
    k = np.argmin(dist, 1)
    r = np.arange(2 * K)
    has = np.isfinite(dist[r, k]) & good
    shift = np.where(has, tc[r, k] * np.tile(A, 2), 0.0).reshape(2, K)
    new = ends + shift[..., None] * dirn
    return new[0], new[1]


def _bars_from_pairs(img, camera, E, sub, a, b, o):
    """`Bars` from the chosen pairs (a, b) of refitted edges E (`EdgeFit` sub): the bisector
    between the means of the two edges' ends (then the caps), its sd from the edges'."""
    pr = pair_geometry(E, a, b)
    # ends: the mean of the two edges' ends, then the caps
    s1 = 0.5 * (pr.a_lo + pr.b_lo)
    s2 = 0.5 * (pr.a_hi + pr.b_hi)
    m1, m2 = pr.point(s1), pr.point(s2)
    width = pr.width_at(0.5 * (s1 + s2))
    contrast = np.minimum(sub.contrast[a], sub.contrast[b])
    if o.refine_ends:
        m1, m2 = _refine_caps(img, camera, m1, m2, width, contrast)
    mid = 0.5 * (m1 + m2)
    ang_sig = 0.5 * np.sqrt(sub.angle_sigma[a] ** 2 + sub.angle_sigma[b] ** 2)
    off_sig = 0.5 * np.sqrt(sub.take(a).offset_sigma_at(mid) ** 2 + sub.take(b).offset_sigma_at(mid) ** 2)
    ideal = np.concatenate([m1, m2], -1)
    Lm = np.hypot(*(m2 - m1).T)
    keep = (Lm >= o.min_length) & np.all(np.isfinite(ideal), -1)
    raw = to_raw(camera, ideal)
    keep &= np.all(np.isfinite(raw), -1)
    keep &= ~_duplicates(ideal, keep, (sub.count[a] + sub.count[b]).astype(float))
    edges = np.stack([to_raw(camera, E[a]), to_raw(camera, E[b])], 1)
    return Bars(
        segments=raw[keep],
        ideal=ideal[keep],
        angle_sigma=ang_sig[keep],
        offset_sigma=off_sig[keep],
        length=Lm[keep],
        contrast=contrast[keep],
        residual_px=np.sqrt(0.5 * (sub.residual[a] ** 2 + sub.residual[b] ** 2))[keep],
        stations=(sub.count[a] + sub.count[b])[keep].astype(int),
        width_px=width[keep],
        edges=edges[keep],
    )


def detect_bars(image, detector="auto", *, camera=None, width_px_range=None, min_length=30.0, min_aspect=4.0,
                max_convergence_deg=3.0, min_overlap=0.5, refine_ends=True, search_px=None,
                sigma_px=RefitOptions.sigma_px, step_px=RefitOptions.step_px, max_gap_px=RefitOptions.max_gap_px,
                min_gradient=RefitOptions.min_gradient, detector_params=None, proposal_scale=None,
                valid_region=None, polarity="dark"):
    """Midlines of thin bars (the printed spokes of a pencil) with angle uncertainty.

    Each bar has two long edges of opposite polarity (dark inside). Pairs of edges running
    in opposite directions (`orient_by_polarity`), within `max_convergence_deg`, whose dark
    sides face each other, that overlap along at least `min_overlap` of the shorter, enclose
    a strip that is dark at 85 % of 15 places along it, and are at least `min_aspect` times
    longer than wide, are bars; each edge belongs to one bar at most (narrowest pair first).
    An edge whose profile windows reach another chosen bar's edge (spokes crowding near a
    fan's vertex) is refitted on its part clear of it (`_clear_of_neighbours`).
    Only edges of candidate pairs (the same tests, with slack, on the unrefined lines) are
    refitted, and only edges that still pair after the first pass of the refit get further
    passes (growing along their length), so a busy image (a ChArUco board beside the fan)
    costs little more than the detector: its squares are too short for their width, and
    rows of squares are not dark all along.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
    detector : {"auto", "lsd", "fld", "edlines"}
        The proposals' detector; "auto": FLD on a reduced image (proposal_scale < 1), LSD on
        the full-resolution one (`segments.proposal_detector`).
    camera : Camera, optional
        Lens model; see `detect_segments`. Midlines are returned in raw pixels.
    width_px_range : (2,) [px], optional
        Accepted bar widths (undistorted pixels); default 2.5 px to 1/8 of the image's
        smaller side. Bars narrower than ~2.5 px have no separate edges for the detectors.
    min_length : float
        Shortest midline [px].
    refine_ends : bool
        Locate the end caps along the midline (half-way crossing of the grey level); else the
        ends are the mean of the two edges' ends.
    search_px : float, optional
        Edge search half-width of the refit; default half the smallest width, within
        [0.75, 2] px, so that the refit never jumps to the bar's other edge.
    max_gap_px : float
        Largest gap between fragments merged into one edge [px]. After the refit an edge must
        be continuous (gaps of at most 2.5 station steps): squares in a row, whose edges line
        up with gaps between them, make no bar.
    sigma_px, step_px, min_gradient, detector_params
        As in `detect_segments`.
    proposal_scale : float in [0.25, 1] or None
        The detector runs on the image reduced by this factor (area averaging); its lines
        are proposals that the refit then fits at full resolution, so the accuracy of what
        is found does not depend on it. On the reduced image the detector often reports one
        edge of a thin bar only (the two blur into one outline), or a piece of it: each line
        that no partner covers along most of its length is given one by a search across its
        dark side at full resolution (`_complete_partners`), and FLD (EDLines) is asked for
        no fragment shorter than 0.9 `min_length` (full-resolution pixels): a bar's edges are
        as long as the bar. Default None: 0.5 when the image's smaller side is 720 px or
        more (1080p: orientation from a frame ~2x faster, the same bars on the test scenes),
        else 1.
    valid_region : region.ValidRegion, optional
        Where the scene is (a field stop, letterbox bars): edges are measured only on
        profiles inside it and bars not in it (`segments.in_valid_region`) are dropped.
        None: the image.
    polarity : {"dark", "light", "either"}
        Dark bars on a light ground (the description above), light bars on a dark ground
        (the same on the image with its levels turned over, `GrayImage.inverted`), or
        whichever of the two looks more like a pencil on this frame (`_pencil_support`: the
        most directions through one point; both are looked for, so a fan printed either
        way is found without being told).

    Returns
    -------
    Bars
        Midlines (M, 4) in raw pixels, running like their first edge (so n points from the
        midline towards that edge; `orient.orient_segments` orients spokes from the vertex
        itself), with ``angle_sigma`` = sqrt(s1^2 + s2^2) / 2 of the edge fits,
        ``offset_sigma`` at the midline's midpoint, ``width_px`` and ``edges``. Under
        perspective the bisector sits ~w^2 / (4 D) off the true centre line (D the distance
        to the plane's horizon): no angle error, but a few offset sd; once the plane is
        known, `bar_midlines_on_plane` removes it.

    Example
    -------
    See the module docstring.
    """
    return find_bars(image, detector, camera=camera, width_px_range=width_px_range, min_length=min_length,
                     min_aspect=min_aspect, max_convergence_deg=max_convergence_deg, min_overlap=min_overlap,
                     refine_ends=refine_ends, search_px=search_px, sigma_px=sigma_px, step_px=step_px,
                     max_gap_px=max_gap_px, min_gradient=min_gradient, detector_params=detector_params,
                     proposal_scale=proposal_scale, valid_region=valid_region, polarity=polarity)[0]


def find_bars(image, detector="auto", *, polarity="dark", prior=None, prior_search=None, roi=None,
              valid_region=None, detector_params=None, camera=None, **options):
    """`detect_bars` (the same arguments) and the polarity of what it found: (Bars,
    "dark" or "light"), and with a prior, the bars of the previous frame looked for again.

    prior : (M, 2, 4) array, optional
        The ``edges`` [raw px] of the previous frame's bars (`Bars.edges`), or where a motion
        model predicts them (`bar_track.BarTracker`), the same camera, found with the same
        polarity, which must then be "dark" or "light": instead of proposing lines over the
        whole frame, each edge is looked for within `prior_search` of it (its own polarity
        only; a coarse pass with `_TRACK_STATIONS` stations along it), then refitted,
        paired and measured exactly as a full detection's candidates are. Bars further off,
        and bars new in the frame, are not found: the caller falls back on a detection.
    prior_search : float or (M,) [px], optional
        Half-width of the search around each prior bar's edges; default `TRACK_SEARCH_PX`.
    roi : (4,) int [raw px], optional
        Without a prior: (x0, y0, x1, y1), the lines are proposed in this part of the frame
        only (around where a lost track predicts the bars), then refitted, paired and
        measured in the whole frame as any detection's.
    """
    if polarity not in BAR_POLARITIES:
        raise InputError(f"unknown bar polarity {polarity!r}; expected one of {', '.join(BAR_POLARITIES)}")
    if prior is not None and polarity == "either":
        raise InputError("find_bars: a prior needs the polarity it was found with (dark or light)")
    img = GrayImage(image, valid_region)
    check_camera_image(camera, img)
    o = BarOptions.resolve(img.shape, **{**_BAR_DEFAULTS, **options})
    detector = proposal_detector(detector, bars=o.proposal_scale < 1.0)
    if prior is not None:
        prior = np.asarray(prior, float).reshape(-1, 2, 4)
        search = np.broadcast_to(TRACK_SEARCH_PX if prior_search is None else np.asarray(prior_search, float),
                                 prior.shape[:1])
        lines = to_working(camera, prior.reshape(-1, 4))
        seen = img.inverted() if polarity == "light" else img
        found = _tracked_lines(seen, camera, lines, np.repeat(search, 2), o)
        return _bars_from_candidates(seen, camera, found, o), polarity
    if polarity == "dark":
        return _dark_bars(img, detector, camera, o, detector_params, roi), "dark"
    light = _dark_bars(img.inverted(), detector, camera, o, detector_params, roi)
    if polarity == "light":
        return light, "light"
    dark = _dark_bars(img, detector, camera, o, detector_params, roi)
    # the frame's own polarity: the one whose bars look more like a pencil (the gaps between
    # a fan's spokes are wedges, no bars; the other polarity finds strips of other print)
    if _pencil_support(light.ideal, light.length) > _pencil_support(dark.ideal, dark.length):
        return light, "light"
    return dark, "dark"


def _tracked_lines(img, camera, lines, search, o):
    """The prior edges (M, 4) [working px] found again, each within search (M,) [px] of
    it: a coarse refit (`_TRACK_STATIONS` stations along each line, passes that grow it
    where the edge runs on), whose lines (those refitted) are then this frame's
    candidates. Lines with the same window are refitted together."""
    search = np.maximum(np.ceil(np.asarray(search, float)), o.search_px)
    L = np.hypot(lines[:, 2] - lines[:, 0], lines[:, 3] - lines[:, 1])
    out = []
    for w in np.unique(search):
        sel = search == w
        step = max(o.step_px, float(np.median(L[sel])) / _TRACK_STATIONS)
        opts = replace(o.refit_options(), search=float(w), step_px=step, max_gap_px=2.5 * step)
        # the lines only: the candidates are refitted and measured again (`_bars_from_candidates`)
        fit = refit_lines(img, lines[sel], camera, opts, max_passes=3, measure=False)
        out.append(fit.lines()[fit.ok])
    return np.concatenate(out) if out else np.zeros((0, 4))


# the options `BarOptions.resolve` takes, with detect_bars' defaults (one source: its signature)
_BAR_DEFAULTS = {k: v.default for k, v in inspect.signature(detect_bars).parameters.items()
                 if k not in ("image", "detector", "camera", "detector_params", "valid_region", "polarity")}


def _pencil_support(lines, length):
    """How much lines (M, 4) [working px] of lengths (M,) look like a pencil: over the
    points where two of them cross at more than `_PENCIL_BIN_DEG`, the most directions
    (`_PENCIL_BIN_DEG` bins) among the lines through one point (within `_PENCIL_TOL_PX` +
    `_PENCIL_TOL_REL` of its distance), then their total length; a tuple, larger is better.

    A fan's spokes meet at its vertex from directions spread over up to 180 deg; strips of
    other print (the white margins of a board's markers, rows of text) are parallel in
    families, meeting only at vanishing points from a few directions.

    >>> fan = np.array([[10 * np.cos(a), 10 * np.sin(a), 90 * np.cos(a), 90 * np.sin(a)] for a in (0, 0.5, 1, 1.5)])
    >>> rows = np.array([[0.0, y, 80.0, y + 0.01 * y] for y in (0, 10, 20, 30, 40, 50)])
    >>> _pencil_support(fan, np.full(4, 80.0))[0], _pencil_support(rows, np.full(6, 80.0))[0]
    (4, 1)
    """
    if lines.shape[0] > _PENCIL_MAX_LINES:  # the longest ones: a fan's spokes are among them
        keep = np.argsort(-length, kind="stable")[:_PENCIL_MAX_LINES]
        lines, length = lines[keep], length[keep]
    M = lines.shape[0]
    if M < 2:
        return (M, float(np.sum(length)))
    p, d = lines[:, :2], lines[:, 2:] - lines[:, :2]
    u = d / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)[:, None]
    n = np.stack([-u[:, 1], u[:, 0]], -1)
    c = -np.sum(n * p, -1)
    theta = np.degrees(np.arctan2(u[:, 1], u[:, 0])) % 180.0
    i, j = np.triu_indices(M, 1)
    cross = u[i, 0] * u[j, 1] - u[i, 1] * u[j, 0]
    keep = np.abs(cross) > np.sin(np.radians(_PENCIL_BIN_DEG))
    i, j, cross = i[keep], j[keep], cross[keep]
    if i.size == 0:
        return (1, float(np.max(length)))
    # the crossing of lines i and j: n_i . v + c_i = 0 = n_j . v + c_j
    v = np.stack([(n[i, 1] * c[j] - n[j, 1] * c[i]), (n[j, 0] * c[i] - n[i, 0] * c[j])], -1) / cross[:, None]
    mid = 0.5 * (lines[:, :2] + lines[:, 2:])
    dist = np.abs(v @ n.T + c[None, :])  # (P, M) of each crossing from each line
    reach = np.linalg.norm(v[:, None, :] - mid[None, :, :], axis=-1)
    through = dist <= _PENCIL_TOL_PX + _PENCIL_TOL_REL * reach
    bins = np.floor(theta / _PENCIL_BIN_DEG).astype(int)
    onehot = np.zeros((M, int(180 / _PENCIL_BIN_DEG) + 1), bool)
    onehot[np.arange(M), bins] = True
    ndir = (through.astype(np.int32) @ onehot.astype(np.int32) > 0).sum(-1)
    total = through @ length
    best = np.lexsort((total, ndir))[-1]
    return (int(ndir[best]), float(total[best]))


def _dark_bars(img, detector, camera, o, detector_params, roi=None):
    """`detect_bars` of dark bars in the `GrayImage` img with the options o (`BarOptions`),
    proposed within roi (`find_bars`) when given."""
    lines, a, b = _proposed_pairs(img, detector, camera, o, detector_params, roi)
    if a.size == 0:
        return Bars.empty()
    return _bars_from_candidates(img, camera, lines[np.unique(np.concatenate([a, b]))], o)


def _bars_from_candidates(img, camera, lines, o):
    """The dark bars of img whose edges are among the candidate lines (M, 4) [working px,
    oriented by polarity]: refitted, paired, cleared of neighbours and measured."""
    if lines.shape[0] < 2:
        return Bars.empty()
    # a printed bar's edge is continuous: the refit keeps only an unbroken run of stations
    # (fragments are merged across gaps first), so edges of squares in a row, lined up
    # with gaps between them, do not make a bar
    opts = o.refit_options()
    E, sub = _refitted_edges(img, camera, lines, o, opts)
    pr = _bar_pairs(img, camera, E, sub, o)
    if pr is None:
        return Bars.empty()
    # edges whose profiles reach a neighbouring bar (near a fan's vertex) are refitted on
    # their clear part; reach = the profile window, search + 3 sd of the kernel (a wider
    # margin for the other bar's blur trimmed so much that the normal's error grew)
    E, sub = _clear_of_neighbours(img, camera, E, sub, pr.a, pr.b, opts, o.search_px + 3.0 * o.sigma_px)
    bars = _bars_from_pairs(img, camera, E, sub, pr.a, pr.b, o)
    return bars if img.region is None else bars.select(in_valid_region(img, bars.segments))


def bar_midlines_on_plane(bars, camera, normal):
    """The exact images of the bars' centre lines once the plane they are printed on is known.

    The bisector of a bar's two edges (`detect_bars`) is not quite the image of its centre
    line under perspective: along a cut across the bar, the image of the 3D midpoint is the
    harmonic conjugate of the plane's horizon with respect to the two edges, w^2 / (4 D)
    from the bisector towards the horizon (w the bar's width, D the distance to the
    horizon, both in pixels): ~0.006-0.02 px for 8 px bars at 20-45 deg tilt. That turns no
    angle, but it is several times the bisector's offset sd. With the plane's normal (e.g.
    the `normal` of orientation.json, R_cam_from_target[:, 2]) each edge's back-projected
    plane meets the target plane in a 3D line, the centre line lies midway between the two
    and its image is exact.

    Parameters
    ----------
    bars : Bars
        From `detect_bars` with the same camera.
    camera : Camera
    normal : (3,) array_like
        Unit normal of the printed plane in the camera frame (either sign).

    Returns
    -------
    Bars
        A copy whose `segments` / `ideal` lie on the exact centre lines, their ends the old
        ends moved across onto them; everything else unchanged.

    Example
    -------
    See tests/toolkit/detect/test_bars.py (test_bar_midlines_on_plane).
    """
    if len(bars) == 0:
        return bars
    n = np.asarray(normal, float).reshape(3)
    n = n / np.linalg.norm(n)
    K = np.asarray(camera.K, float)
    K2, k = K[:2, :2], K[:2, 2]
    K2inv = np.linalg.inv(K2)
    E = np.stack([to_working(camera, bars.edges[:, 0]), to_working(camera, bars.edges[:, 1])], 1)  # (M, 2, 4)

    def plane(seg):
        # back-projected plane m . (x, y, 1) = 0 of a segment in undistorted pixels
        p1, p2 = seg[..., :2], seg[..., 2:]
        d = p2 - p1
        npx = np.stack([-d[..., 1], d[..., 0]], -1)
        c = -np.sum(npx * p1, -1)
        m = np.concatenate([npx @ K2, (np.sum(npx * k, -1) + c)[..., None]], -1)
        return m / np.linalg.norm(m, axis=-1, keepdims=True)

    m = plane(E)  # (M, 2, 3)
    d = np.cross(m, n)  # directions of the two 3D edges
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    d[:, 1] *= np.sign(np.sum(d[:, 0] * d[:, 1], -1))[:, None]
    dm = d[:, 0] + d[:, 1]
    dm /= np.linalg.norm(dm, axis=-1, keepdims=True)
    # on each edge, the point with d . X = 0 (the same cut across the bar) on n . X = 1
    A = np.stack([m, np.broadcast_to(n, m.shape), np.broadcast_to(dm[:, None, :], m.shape)], -2)  # (M, 2, 3, 3)
    X = np.linalg.solve(A, np.broadcast_to(np.array([0.0, 1.0, 0.0]), m.shape)[..., None])[..., 0]
    M3 = 0.5 * (X[:, 0] + X[:, 1])
    mm = np.cross(M3, dm)  # the centre line's plane through the camera centre
    # back to a line in undistorted pixels: mm[:2] . K2^-1 (p - k) + mm[2] = 0
    npx = mm[:, :2] @ K2inv
    c = mm[:, 2] - np.sum(npx * k, -1)
    nn = np.linalg.norm(npx, axis=-1)
    npx, c = npx / nn[:, None], c / nn
    ideal = bars.ideal.copy()
    for j in (0, 2):
        p = ideal[:, j:j + 2]
        ideal[:, j:j + 2] = p - (np.sum(npx * p, -1) + c)[:, None] * npx
    return replace(bars, ideal=ideal, segments=to_raw(camera, ideal))

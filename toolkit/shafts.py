"""Instrument shafts: the two long edges of a cylinder, their axis and apparent width.

A rigid instrument's shaft is a cylinder. Its image is bounded by two long, straight edges
(in undistorted pixels) that converge under perspective towards the far end, by more than
10 degrees on close-range endoscope frames; the image of its axis lies between them. On
real frames those edges come in fragments, broken by specular highlights, tissue texture
and occlusion, so `detect_shafts` collects the evidence along the whole shaft:

1. *proposals*: LSD on a reduced copy of the image (fine tissue texture averages out, the
   shaft's edges do not), fragments oriented by polarity and undistorted;
2. *line hypotheses*: collinear fragments grouped with generous gaps (lines.merge_collinear);
   the hypotheses with enough fragment support are kept;
3. *edge evidence*: each hypothesis is refitted at full resolution to the gradient across
   it (lines.refine_segments' station fit: only edge points of the hypothesis' polarity,
   near the line, count), and grown along the line while the evidence continues, bridging
   gaps up to `max_gap_px` (a highlight or an occluder);
4. *pairs*: two long edges running in opposite directions (opposite gradient polarity with
   respect to the axis), enclosing a region darker (or brighter) than both sides, converging
   by at most `max_convergence_deg`, not crossing over the shaft, and reaching the image
   border (an instrument enters the view from outside). The enclosed cross-section must
   look like one object: a strip of it that matches the background (the gap between two
   instruments) rejects the pair; a specular stripe does not (it is far brighter than the
   background). The bands beside a specular stripe, and the stripe itself, give way to the
   silhouette around them. The edges of the shafts kept are refitted once more with each
   edge point corrected for the grey-level slopes beside it (shading, tissue texture);
5. *axis*: with a camera, the plane through the camera centre that bisects the two planes
   back-projected from the edges; it contains the cylinder's axis exactly (the cylinder is
   symmetric about any plane through its axis, so its two tangent planes from the camera
   are mirror images in the plane through the axis). Its image is the midline. Without a
   camera the image bisector of the two edges is used (exact for a shaft viewed
   symmetrically, 0.03-0.16 px off in the geometries of tests/toolkit/test_shafts.py).

Limits: a shaft is told from other bands only by its two edges and its cross-section. In a
scene full of long straight edges (a printed sheet on a table: its margins and rows make
bands too) pass the width you expect (`width_px_range`), or keep the shafts consistent over
a sequence; on tissue the shaft is usually the best-scored band. A shaft whose edges flip
polarity along their length (grey metal over black and white print) is found from its
longest consistent stretch.

Conventions as in lines.py: pixels with (0, 0) the centre of the top-left pixel; midlines
and edges in raw pixels, widths and uncertainties in undistorted pixels.

Example
-------
>>> import numpy as np
>>> img = np.full((240, 320), 170, np.uint8)
>>> pts = np.array([[0, 80], [0, 160], [300, 135], [300, 105]], np.int32)   # converging
>>> import cv2; _ = cv2.fillConvexPoly(img, pts, 40)
>>> sh = detect_shafts(cv2.GaussianBlur(img, (0, 0), 1.0), min_length=100)
>>> len(sh), round(float(sh[0].width_px))                  # 55 px at x = 150, plus the fill's rims
(1, 56)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InputError
from .lines import (
    _antiparallel_candidates,
    _check_camera_image,
    _Gray,
    _pair_geometry,
    _refit,
    _to_raw,
    _to_raw_pts,
    _to_working,
    detect_raw,
    merge_collinear,
    orient_by_polarity,
)

__all__ = ["Shaft", "detect_shafts", "estimate_noise"]


@dataclass(frozen=True, eq=False)
class Shaft:
    """One instrument shaft.

    Attributes
    ----------
    midline : (4,) [px]
        Image of the axis ``[x1, y1, x2, y2]`` in raw pixels, over the visible shaft, from
        the wide (near) end to the narrow (far) end.
    width_px : float
        Apparent width across the midline at its centre [undistorted px].
    angle_sigma : float
        sd of the midline's angle [rad] (undistorted), sqrt(s1^2 + s2^2) / 2 of the edge fits.
    offset_sigma : float
        sd of its perpendicular position at its centre [px].
    edges : (2, 4) [px]
        The two edges in raw pixels.
    score : float
        Evidence [px]: the length along which both edges are seen, times the fraction of
        the cross-section that looks like the shaft.
    ideal_midline : (4,) [px]
        The midline in undistorted pixels.
    convergence_deg : float
        Angle between the two edges [deg].
    polarity : str
        "dark" (shaft darker than its surroundings) or "bright".
    """

    midline: np.ndarray
    width_px: float
    angle_sigma: float
    offset_sigma: float
    edges: np.ndarray
    score: float
    ideal_midline: np.ndarray
    convergence_deg: float
    polarity: str

    def to_dict(self) -> dict:
        """The lines.json record: midline, width_px, angle_sigma_deg (INTERFACES.md) + extras."""
        return {
            "midline": [float(v) for v in self.midline],
            "width_px": float(self.width_px),
            "angle_sigma_deg": float(np.degrees(self.angle_sigma)),
            "offset_sigma_px": float(self.offset_sigma),
            "edges": [[float(v) for v in e] for e in self.edges],
            "convergence_deg": float(self.convergence_deg),
            "polarity": self.polarity,
            "score": float(self.score),
        }


def estimate_noise(image):
    """Standard deviation of white image noise [grey levels] (Immerkaer 1996).

    The image is filtered with the difference of two Laplacians, which cancels structure up
    to second order; sd = sqrt(pi / 2) / 6 * mean |response|. Image edges inflate it
    slightly; textured images more.

    >>> rng = np.random.default_rng(0)
    >>> round(estimate_noise(100 + rng.normal(0, 3, (200, 200))), 1)
    3.0
    """
    import cv2

    g = _Gray(image).src.astype(np.float32)
    if min(g.shape) < 3:
        return 0.0
    k = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    r = cv2.filter2D(g, -1, k, borderType=cv2.BORDER_REFLECT)[1:-1, 1:-1]
    # edges and texture give a few large responses: the median of |r| (scaled to the mean of
    # a half-normal) resists them
    return float(np.median(np.abs(r)) / 0.6745 / 6.0)


def _proposals(img, detector, camera, scale, detector_params):
    """Fragments from the detector on a reduced image, in full-resolution working pixels."""
    import cv2

    u8 = img.u8
    H, W = img.shape
    if scale < 1.0:
        small = cv2.resize(u8, (max(int(round(W * scale)), 8), max(int(round(H * scale)), 8)),
                           interpolation=cv2.INTER_AREA)
        sx, sy = W / small.shape[1], H / small.shape[0]
        raw = detect_raw(small, detector, detector_params)
        # pixel centres: x_full + 0.5 = (x_small + 0.5) * s
        raw = (raw + 0.5) * np.array([sx, sy, sx, sy]) - 0.5
    else:
        raw = detect_raw(u8, detector, detector_params)
    L = np.hypot(raw[:, 2] - raw[:, 0], raw[:, 3] - raw[:, 1])
    raw = raw[L >= 8.0]
    raw = orient_by_polarity(img, raw, 1.0 / min(scale, 1.0))[0]
    work = _to_working(camera, raw)
    return work[np.all(np.isfinite(work), -1)]


_N_OUT, _N_IN = 6, 24  # cross-section bins beside each edge and inside the strip


def _cross_section(img, camera, pr, blur_px, n_along=24):
    """Median cross-section of each pair's strip, (K, 2 _N_OUT + _N_IN) grey levels: _N_OUT
    bins beyond edge a, _N_IN inside, _N_OUT beyond edge b, each the median over n_along
    places along the overlap.

    Inside, the bins keep max(0.1 w, 2 blur_px) away from the edges (w the local width);
    outside they run from 2 blur_px + 1 to that plus max(0.3 w, 4) px beyond them, so that
    neither side reads the blur of an edge, however thin the shaft.
    """
    f = np.linspace(0.05, 0.95, n_along)
    al = pr.lo[:, None] + f[None, :] * (pr.hi - pr.lo)[:, None]  # (K, A)
    m = pr.point(al)  # (K, A, 2)
    na, ca, nb, cb = pr._lines
    N = pr.N[:, None, :]
    lam_a = -(np.sum(na[:, None, :] * m, -1) + ca[:, None]) / np.sum(na * pr.N, -1)[:, None]
    lam_b = -(np.sum(nb[:, None, :] * m, -1) + cb[:, None]) / np.sum(nb * pr.N, -1)[:, None]
    A = m + lam_a[..., None] * N  # points on edge a
    B = m + lam_b[..., None] * N
    w = np.linalg.norm(B - A, axis=-1)  # (K, A)
    e = (B - A) / np.maximum(w, 1e-9)[..., None]  # unit, from a to b
    d_in = np.minimum(np.maximum(0.1 * w, 2.0 * blur_px), 0.4 * w)
    d0 = np.full_like(w, 2.0 * blur_px + 1.0)
    d1 = d0 + np.maximum(0.3 * w, 4.0)
    q_out = np.linspace(0.0, 1.0, _N_OUT)
    q_in = np.linspace(0.0, 1.0, _N_IN)
    off_a = -(d0[..., None] + q_out * (d1 - d0)[..., None])[..., ::-1]  # beyond a, outer first
    off_in = d_in[..., None] + q_in * (w - 2 * d_in)[..., None]
    off_b = w[..., None] + d0[..., None] + q_out * (d1 - d0)[..., None]
    off = np.concatenate([off_a, off_in, off_b], -1)  # (K, A, U) from edge a along e
    P = A[:, :, None, :] + off[..., None] * e[:, :, None, :]
    P = _to_raw_pts(camera, P)
    v = img.sample(P[..., 0], P[..., 1])
    return np.median(v, axis=1)


def _assess(prof, dark):
    """Contrast, background-like fraction and glare of each strip's cross-section (K, U).

    Outside level O from both sides, the inside bins. For a dark shaft the contrast is the
    darker side's level minus the median inside (mirrored for a bright one); a bin is
    background-like when it is within half the contrast of O, unless it is on the flank of a
    specular stripe on a dark shaft (within two bins of one brighter than O by half the
    contrast: glare). On a bright shaft a bin darker than the background counts against it
    too (a board's black squares inside a sheet of paper). The third result flags strips
    with a highlight: glare on a dark shaft, a bin brighter than a bright shaft's median by
    half the contrast.
    """
    sign = np.where(dark, 1.0, -1.0)[:, None]
    p = sign * prof  # dark shafts: background high, shaft low
    pa, pin, pb = p[:, :_N_OUT], p[:, _N_OUT:_N_OUT + _N_IN], p[:, _N_OUT + _N_IN:]
    O1, O2 = np.median(pa, -1), np.median(pb, -1)
    O = np.median(np.concatenate([pa, pb], -1), -1)
    # each side on its own as well: a strip between two different backgrounds is no shaft
    C = np.minimum(O1, O2) - np.median(pin, -1)
    half = 0.5 * np.maximum(C, 1e-9)[:, None]
    like = np.abs(pin - O[:, None]) < half
    beyond = pin > O[:, None] + half  # further from the shaft's level than the background
    # on a dark shaft that is glare (specular highlights are brighter than anything): its
    # flanks pass through the background's level and are not background; on a bright shaft
    # it is something darker than the background, not part of a shaft
    glare = beyond & dark[:, None]
    near = glare.copy()
    for k in (1, 2):
        near[:, k:] |= glare[:, :-k]
        near[:, :-k] |= glare[:, k:]
    bg = np.mean((like & ~near) | (beyond & ~dark[:, None]), -1)
    # a highlight on a bright shaft: brighter than the shaft's own median by half the contrast
    shine = (pin < np.median(pin, -1)[:, None] - half) & ~dark[:, None]
    return C, bg, np.any(glare | shine, -1)


def _plane_bisector(camera, pr):
    """Bisecting line (N, C) (K, 2), (K,) in undistorted pixels of the two planes through the
    camera centre that the edges back-project to (see the module docstring)."""
    K = np.asarray(camera.K, float)
    K2, k = K[:2, :2], K[:2, 2]
    K2inv = np.linalg.inv(K2)
    na, ca, nb, cb = pr._lines
    # interior point: the image bisector at the overlap centre
    q = pr.point(0.5 * (pr.lo + pr.hi))
    xq = np.concatenate([(q - k) @ K2inv.T, np.ones((q.shape[0], 1))], -1)

    def plane(n, c):
        m = np.concatenate([n @ K2, (np.sum(n * k, -1) + c)[:, None]], -1)  # m . (x, 1) = 0
        m /= np.linalg.norm(m, axis=-1, keepdims=True)
        return m * np.where(np.sum(m * xq, -1) < 0, -1.0, 1.0)[:, None]

    m = plane(na, ca) - plane(nb, cb)
    # back to pixels: m[:2] . K2^-1 (p - k) + m[2] = 0
    Np = m[:, :2] @ K2inv
    Cp = m[:, 2] - np.sum(Np * k, -1)
    nrm = np.linalg.norm(Np, axis=-1)
    Np, Cp = Np / nrm[:, None], Cp / nrm
    # same orientation as the image bisector
    flip = np.sum(Np * pr.N, -1) < 0
    return np.where(flip[:, None], -Np, Np), np.where(flip, -Cp, Cp)


def _signed_width(pr, along):
    """Width across the bisector at `along` (K,), signed: it changes sign where the edges cross."""
    m = pr.point(along)
    na, ca, nb, cb = pr._lines
    lam_a = -(np.sum(na * m, -1) + ca) / np.sum(na * pr.N, -1)
    lam_b = -(np.sum(nb * m, -1) + cb) / np.sum(nb * pr.N, -1)
    return lam_b - lam_a


def _contains(pr, i, j):
    """(Ki, Kj) bool: pair j's strip lies inside pair i's strip (both of j's edges between
    i's edges at j's overlap centre, which lies within i's overlap), j != i."""
    na, ca, nb, cb = pr._lines
    q = pr.point(0.5 * (pr.lo + pr.hi))  # (K, 2) centre of each strip
    # a point is inside strip i when it is on the dark side of a... use signed distances:
    # inside <=> e_a(p) and e_b'(p) have the signs of strip i's own centre
    ends = []
    for (n, c) in ((na, ca), (nb, cb)):
        # the two edge points of strip j at its centre, along N
        lam = -(np.sum(n * q, -1) + c) / np.sum(n * pr.N, -1)
        ends.append(q + lam[:, None] * pr.N)
    pts = np.stack(ends, 1)[j]  # (Kj, 2, 2)
    ea = np.einsum("id,jkd->ijk", na[i], pts) + ca[i][:, None, None]
    eb = np.einsum("id,jkd->ijk", nb[i], pts) + cb[i][:, None, None]
    sa = np.sign(np.sum(na[i] * q[i], -1) + ca[i])[:, None, None]
    sb = np.sign(np.sum(nb[i] * q[i], -1) + cb[i])[:, None, None]
    tol = 1.5  # px: an edge shared with the outer pair still counts as inside
    inside = np.all((ea * sa > -tol) & (eb * sb > -tol), -1)
    # ... and within the stretch where both of strip i's edges are seen
    along = np.einsum("id,jd->ij", pr.D[i], q[j]) - np.sum(pr.D[i] * pr.O[i], -1)[:, None]
    inside &= (along >= pr.lo[i][:, None]) & (along <= pr.hi[i][:, None])
    same = i[:, None] == j[None, :]
    return inside & ~same


def detect_shafts(image, camera=None, *, detector="lsd", min_length=None, width_px_range=None,
                  max_convergence_deg=30.0, max_shafts=4, scale=None, max_gap_px=None, search_px=3.0,
                  sigma_px=1.5, min_support=0.5, max_background=0.25, slope_correction=True, from_border=True,
                  border_px=None, min_score_ratio=0.25, detector_params=None):
    """Instrument shafts in one image: midline (the axis image), width, angle uncertainty.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        Grey or BGR frame.
    camera : Camera, optional
        Lens model. Edges are fitted straight in undistorted pixels and the midline is the
        exact image of the axis (module docstring); its image size must match.
    detector : {"lsd", "fld", "edlines"}
        Proposal detector (run on the reduced image).
    min_length : float, optional
        Shortest edge [px]; default 1/8 of the image diagonal.
    width_px_range : (2,) [px], optional
        Accepted apparent widths (at the overlap centre); default 6 px to 0.7 of the
        image's smaller side.
    max_convergence_deg : float
        Largest angle between the two edges.
    max_shafts : int
        At most this many shafts, best score first.
    min_score_ratio : float
        Drop shafts whose score is below this fraction of the best one's.
    scale : float, optional
        Reduction of the image for the proposals; default so that its larger side is ~800 px.
    max_gap_px : float, optional
        Longest stretch without edge evidence inside one edge; default 1/10 of the diagonal.
    search_px, sigma_px : float
        Edge search half-width and Gaussian-derivative sd of the full-resolution refit [px].
    min_support : float
        The two edges must overlap along at least this fraction of the shorter one
        (occlusion allowed), and along at least half of `min_length`.
    max_background : float
        Largest fraction of the cross-section that may look like the background.
    from_border : bool
        Keep only pairs whose edges reach the image border (within `border_px`, default 3 %
        of the diagonal + 8 px): an instrument enters the view from outside, whereas the
        long strips of a scene (a sheet's margin, a row of a board, a table's edge) end inside
        it. False also finds a shaft whose near part is hidden.
    slope_correction : bool
        Refit the chosen shafts' edges with each edge point corrected for the grey-level
        slopes beside it (the shading of the metal, tissue texture): between ramps of slopes
        bL and bR a blurred step of height a has its gradient peak sigma^2 (bR - bL) / a off
        the edge. Without it, edges on textured tissue carry biases that are smooth along
        the edge, invisible in the residuals, and turn the midline by a few sd (measured on
        14 synthetic frames like those of tests/toolkit/test_shafts.py: rms angle error / sd
        1.3 without, 1.0 with). Only for shafts wider than twice the profile's reach
        (~2 (search + 6 sigma + 2.5) px, 24 px by default): on a thinner one the slopes
        would be read off the other edge.
    detector_params : dict, optional
        Passed to the detector.

    Returns
    -------
    list of Shaft
        Best score first; empty when none is found.

    Example
    -------
    See the module docstring.
    """
    img = _Gray(image)
    _check_camera_image(camera, img)
    H, W = img.shape
    diag = float(np.hypot(H, W))
    if min_length is None:
        min_length = diag / 8.0
    if border_px is None:
        border_px = 0.03 * diag + 8.0
    if max_gap_px is None:
        max_gap_px = diag / 10.0
    wmin, wmax = (6.0, 0.7 * min(H, W)) if width_px_range is None else map(float, width_px_range)
    if not (0 < wmin < wmax):
        raise InputError(f"width_px_range must be (min, max) with 0 < min < max, got {width_px_range!r}")
    if scale is None:
        scale = min(1.0, 800.0 / max(H, W))
    if not (0 < scale <= 1):
        raise InputError(f"scale must be in (0, 1], got {scale!r}")
    conv_max = np.radians(max_convergence_deg)

    work = _proposals(img, detector, camera, scale, detector_params)
    if work.shape[0] == 0:
        return []
    # line hypotheses: fragments grouped along one line, gaps allowed; support = the total
    # length of the fragments (a merged line spanning gaps is not evidence by itself)
    dist_tol = 1.5 / scale
    merged, lab = merge_collinear(work, 3.0, dist_tol, max_gap_px)
    Lf = np.hypot(work[:, 2] - work[:, 0], work[:, 3] - work[:, 1])
    support = np.bincount(lab[lab >= 0], Lf[lab >= 0], merged.shape[0])
    hyp = merged[support >= 0.4 * min_length]
    if hyp.shape[0] < 2:
        return []
    # evidence along the whole line, at full resolution; the noise sets the weakest edge
    sig_n = estimate_noise(img.src if max(H, W) <= 1000 else img.src[::2, ::2])
    min_grad = max(2.0, 1.5 * sig_n)
    fit = _refit(img, hyp, camera, search=search_px, extend=max(min_length, 40.0), sigma_px=sigma_px,
                 step_px=3.0, max_gap_px=max_gap_px, min_gradient=min_grad, rel_gradient=0.35,
                 floor_px=0.2, max_passes=4, grow=True, long_blocks=8)
    L = np.hypot(*(fit.p2 - fit.p1).T)
    good = fit.ok & (L >= 0.5 * min_length)
    idx = np.flatnonzero(good)
    if idx.size < 2:
        return []
    E = np.concatenate([fit.p1, fit.p2], -1)[idx]
    sig_a, cen, csig = fit.angle_sigma[idx], fit.centroid[idx], fit.centre_sigma[idx]
    L = L[idx]
    a, b = _antiparallel_candidates(E, conv_max, wmax)
    if a.size == 0:
        return []
    pr = _pair_geometry(E, a, b)
    ov = pr.hi - pr.lo
    dark = (pr.side_a < 0) & (pr.side_b < 0)
    bright = (pr.side_a > 0) & (pr.side_b > 0)
    ok = (dark | bright) & (pr.conv <= conv_max) & (pr.width >= wmin) & (pr.width <= wmax)
    ok &= (ov >= min_support * np.minimum(L[a], L[b])) & (ov >= 0.5 * min_length)
    # the edges must not cross over the shaft: the width keeps its sign over the union
    w0 = _signed_width(pr, 0.5 * (pr.lo + pr.hi))
    ok &= (_signed_width(pr, pr.span_lo) * w0 > 0.25 * w0**2) & (_signed_width(pr, pr.span_hi) * w0 > 0.25 * w0**2)
    if from_border:
        # an instrument enters the view from outside: its edges run to the image border
        ends = _to_raw_pts(camera, np.stack([pr.point(pr.span_lo), pr.point(pr.span_hi)], 1))  # (K, 2, 2)
        gap = np.minimum(np.minimum(ends[..., 0], W - 1 - ends[..., 0]), np.minimum(ends[..., 1], H - 1 - ends[..., 1]))
        ok &= np.nan_to_num(gap, nan=np.inf).min(-1) <= border_px
    pr = pr.take(np.flatnonzero(ok))
    dark = dark[ok]
    if pr.a.size == 0:
        return []
    prof = _cross_section(img, camera, pr, sigma_px)
    C, bg, glare = _assess(prof, dark)
    valid = (C > max(3.0 * sig_n, 4.0)) & (bg <= max_background)
    score = (pr.hi - pr.lo) * (1.0 - bg)
    keep = np.flatnonzero(valid)
    if keep.size == 0:
        return []
    pr, dark, score, bg, glare = pr.take(keep), dark[keep], score[keep], bg[keep], glare[keep]
    # nested pairs give way to the pair around them when they are parts of a shaft with a
    # specular stripe: the bands beside the stripe share an edge with the silhouette, the
    # stripe runs along its axis. Only an outer pair with a clean cross-section and glare
    # in it counts (two instruments side by side enclose a strip of background; a shaft
    # lying across a sheet of paper is no part of the sheet's strip around it).
    K = pr.a.size
    ii = np.arange(K)
    inside = _contains(pr, ii, ii)  # [i, j]: j inside i
    shares = ((pr.a[:, None] == pr.a[None, :]) | (pr.a[:, None] == pr.b[None, :])
              | (pr.b[:, None] == pr.a[None, :]) | (pr.b[:, None] == pr.b[None, :]))
    q = pr.point(0.5 * (pr.lo + pr.hi))
    off_axis = np.abs(np.einsum("id,jd->ij", pr.N, q) + pr.C[:, None])  # [i, j]: j's centre from i's axis
    parallel = np.abs(np.einsum("id,jd->ij", pr.D, pr.D)) > np.cos(np.radians(3.0) + pr.conv[:, None])
    along_axis = parallel & (off_axis < 0.25 * pr.width[:, None])
    wider = pr.width[:, None] > pr.width[None, :] + 2.0
    part = inside & wider & (shares | along_axis)
    nested = np.any(part & ((score[:, None] >= 0.5 * score[None, :]) & (bg[:, None] <= 0.1) & glare[:, None]), 0)
    keep = np.flatnonzero(~nested)
    pr, dark, score = pr.take(keep), dark[keep], score[keep]
    # best first, each edge in one shaft
    used = np.zeros(E.shape[0], bool)
    chosen = []
    for k in np.argsort(-score, kind="stable"):
        if used[pr.a[k]] or used[pr.b[k]]:
            continue
        used[pr.a[k]] = used[pr.b[k]] = True
        chosen.append(k)
        if len(chosen) >= max_shafts:
            break
    if not chosen:
        return []
    # much weaker evidence than the best is more likely a vessel or a fold than a shaft
    chosen = [k for k in chosen if score[k] >= min_score_ratio * score[chosen[0]]]
    chosen = np.asarray(chosen)
    pr, dark, score = pr.take(chosen), dark[chosen], score[chosen]
    if slope_correction:
        # refit the chosen edges once more, each edge point corrected for the grey-level
        # slopes beside it; only where the shaft is wide enough for the profile's inner end
        # (search + 3 sd + 2.5 px inside) to stay off the other edge, with room for its blur
        reach = search_px + 3.0 * sigma_px + 2.5 + 3.0 * sigma_px
        wide = np.minimum(np.abs(_signed_width(pr, pr.span_lo)), np.abs(_signed_width(pr, pr.span_hi))) > 2 * reach
        if np.any(wide):
            edges = np.unique(np.concatenate([pr.a[wide], pr.b[wide]]))
            fit2 = _refit(img, E[edges], camera, search=min(search_px, 2.0), extend=0.0, sigma_px=sigma_px,
                          step_px=3.0, max_gap_px=max_gap_px, min_gradient=min_grad, rel_gradient=0.35,
                          floor_px=0.2, max_passes=1, grow=False, long_blocks=8, slope_correction=True)
            good = fit2.ok & (np.hypot(*(fit2.p2 - fit2.p1).T) >= 0.5 * L[edges])
            upd = edges[good]
            E = E.copy()
            E[upd] = np.concatenate([fit2.p1, fit2.p2], -1)[good]
            sig_a, cen, csig = sig_a.copy(), cen.copy(), csig.copy()
            sig_a[upd], cen[upd], csig[upd] = fit2.angle_sigma[good], fit2.centroid[good], fit2.centre_sigma[good]
            pr = _pair_geometry(E, pr.a, pr.b)
    if camera is not None:
        N, Cc = _plane_bisector(camera, pr)
    else:
        N, Cc = pr.N, pr.C
    D = np.stack([N[:, 1], -N[:, 0]], -1)
    O = -Cc[:, None] * N
    # extent: the union of the two edges, projected on the midline
    pa1, pa2 = E[pr.a, :2], E[pr.a, 2:]
    pb1, pb2 = E[pr.b, :2], E[pr.b, 2:]
    al = np.stack([np.sum((q - O) * D, -1) for q in (pa1, pa2, pb1, pb2)], -1)
    s1, s2 = al.min(-1), al.max(-1)
    m1, m2 = O + s1[:, None] * D, O + s2[:, None] * D
    # from the wide (near) end to the narrow (far) end
    na, ca, nb, cb = pr._lines

    def width(m):
        lam_a = -(np.sum(na * m, -1) + ca) / np.sum(na * N, -1)
        lam_b = -(np.sum(nb * m, -1) + cb) / np.sum(nb * N, -1)
        return np.abs(lam_a - lam_b)

    swap = width(m1) < width(m2)
    m1, m2 = np.where(swap[:, None], m2, m1), np.where(swap[:, None], m1, m2)
    mid = 0.5 * (m1 + m2)
    w_mid = width(mid)
    ang_sig = 0.5 * np.sqrt(sig_a[pr.a] ** 2 + sig_a[pr.b] ** 2)

    def off_sig(e):
        u_ = E[e, 2:] - E[e, :2]
        u_ /= np.linalg.norm(u_, axis=-1, keepdims=True)
        r = np.sum((mid - cen[e]) * u_, -1)
        return csig[e] ** 2 + (r * sig_a[e]) ** 2

    o_sig = 0.5 * np.sqrt(off_sig(pr.a) + off_sig(pr.b))
    ideal = np.concatenate([m1, m2], -1)
    raw = _to_raw(camera, ideal)
    ea, eb = _to_raw(camera, E[pr.a]), _to_raw(camera, E[pr.b])
    out = []
    for k in range(pr.a.size):
        if not np.all(np.isfinite(raw[k])):
            continue
        out.append(Shaft(
            midline=raw[k],
            width_px=float(w_mid[k]),
            angle_sigma=float(ang_sig[k]),
            offset_sigma=float(o_sig[k]),
            edges=np.stack([ea[k], eb[k]]),
            score=float(score[k]),
            ideal_midline=ideal[k],
            convergence_deg=float(np.degrees(pr.conv[k])),
            polarity="dark" if dark[k] else "bright",
        ))
    return out

"""Shafts by the pixel cue: bands of instrument-like pixels between two straight silhouettes.

1. *likeness*: each pixel of the work frame (`pixels.WORK_PX` on its longer side, undistorted)
   gets its probability of being instrument from the pixel model (`pixels`). Streaks, slots
   and a wrist inside an instrument are instrument too, so the map's boundaries are the
   instrument's outline, not its inner structure.
2. *outline lines*: straight stretches of that outline: LSD on the map, each segment oriented
   with the instrument on its left (n = (-d_y, d_x) into it), collinear pieces merged, those at
   least `MIN_LINE` of the frame's longer side kept, and not those on the valid region's
   boundary (the map stops there; that is no silhouette).
3. *bands*: every two lines facing each other (each one's instrument side towards the other),
   within `MAX_PAIR_DEG` of each other (a shaft close to the lens converges strongly), seen
   together along at least `MIN_OVERLAP` of the shorter and one width, `WIDTH_RANGE` of the
   longer side apart.
4. *evidence*: at `STATIONS` stations along each band, the likeness inside (the middle 60 %
   across) and on either side (a strip as wide as 30 % of the band, beyond 15 %): the band's
   contrast is the median inside less the larger of the two sides' medians. An instrument is
   instrument-like inside and not on either side; a band between two instruments, or inside
   one, is not. The bands are taken best contrast first, each not along a taken one
   (`_same_instrument`), at least `min_contrast`.
5. *silhouettes*: each band's two lines refitted at full resolution in a corridor
   (`silhouette.fit_edges`), and the midline is their plane bisector with its covariance
   (`axis.midline_from_edges`).

Work pixels in steps 1-4 (``ideal = (work + 0.5) / scale + origin``), ideal pixels in step 5.

Example
-------
>>> import numpy as np
>>> rng = np.random.default_rng(1)
>>> img = np.zeros((360, 640, 3), np.uint8); img[:] = (70, 90, 180)                  # tissue
>>> import cv2; _ = cv2.fillConvexPoly(img, np.array([[0, 150], [400, 165], [400, 205], [0, 220]]), (95, 95, 95))
>>> img = cv2.GaussianBlur(np.clip(img + rng.normal(0, 3, img.shape), 0, 255).astype(np.uint8), (0, 0), 1.0)
>>> from pencilcal.toolkit.detect.shaft.work import Validity, axis_matrix
>>> found = pixel_cue(img, None, Validity(None, img.shape[:2]), axis_matrix(None, img.shape[:2])[0], 3.0)
>>> len(found), round(float(found[0].midline.width_px))      # 52 px wide at x = 200
(1, 52)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.detect.segments import merge_collinear
from pencilcal.toolkit.detect.shaft.axis import midline_from_edges
from pencilcal.toolkit.detect.shaft.pixels import WORK_PX, instrument_probability
from pencilcal.toolkit.detect.shaft.silhouette import fit_edges
from pencilcal.toolkit.detect.shaft.work import WorkFrame

__all__ = ["PixelShaft", "pixel_cue", "MIN_CONTRAST", "MAX_PAIR_DEG", "MIN_LINE", "WIDTH_RANGE", "STATIONS"]

#: The least contrast of instrument likeness between a band and its sides.
MIN_CONTRAST = 0.5
#: The largest angle between a band's two lines [deg].
MAX_PAIR_DEG = 25.0
#: The shortest outline line, as a fraction of the work frame's longer side.
MIN_LINE = 0.04
#: The band widths accepted, as fractions of the work frame's longer side.
WIDTH_RANGE = (0.012, 0.45)
#: The two lines of a band are seen together along at least this fraction of the shorter.
MIN_OVERLAP = 0.3
#: Stations along a band where its evidence is sampled.
STATIONS = 16
#: A band that does not reach the border of the view is an instrument only if its instrument
#: runs along this many widths and this fraction of the work frame's longer side.
LONG_WIDTHS, LONG_FRACTION = 4.0, 0.15
_ACROSS = np.linspace(-0.5, 1.5, 48)  # samples across a band: 0 and 1 its lines, beyond its sides
_CORRIDOR_WORK_PX = 2.0  # half-width of the full-resolution edge search [work px]
#: ... and at least this fraction of the band's width: the likeness map's outline lies up to
#: a few work pixels off the silhouette (its texture features see 15 work px)
CORRIDOR_WIDTHS = 0.25
_MIN_CORRIDOR_PX = 3.0  # ... at least [ideal px]
_MERGE_DEG, _MERGE_PX = 4.0, 1.5  # collinear pieces of one outline line [deg], [work px]
_OFF_BOUNDARY_PX = 2.0  # an outline line's middle at least this far inside the valid region [work px]
_MAX_BANDS = 12  # bands refitted at full resolution, best contrast first


@dataclass(frozen=True, eq=False)
class PixelShaft:
    """A shaft of the pixel cue: its `axis.Midline` (ideal px), the band's likeness contrast
    and the score (contrast x seen length [ideal px])."""

    midline: object
    contrast: float
    score: float


def _outline_lines(p, dist, ms):
    """Oriented outline lines (K, 4) [work px] of the likeness map p (step 2)."""
    import cv2

    from pencilcal.toolkit.detect.segments import orient_by_polarity

    u8 = (np.clip(cv2.GaussianBlur(p, (0, 0), 1.0), 0, 1) * 255).astype(np.uint8)
    seg = cv2.createLineSegmentDetector().detect(u8)[0]
    if seg is None:
        return np.zeros((0, 4))
    seg = seg.reshape(-1, 4).astype(float)
    seg = seg[np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]) >= 4.0]
    seg = orient_by_polarity(u8, seg)[0]
    m, _ = merge_collinear(seg, angle_tol_deg=_MERGE_DEG, dist_tol_px=_MERGE_PX, max_gap_px=0.05 * ms)
    m = m[np.hypot(m[:, 2] - m[:, 0], m[:, 3] - m[:, 1]) >= MIN_LINE * ms]
    mid = 0.5 * (m[:, :2] + m[:, 2:])
    h, w = dist.shape
    xi = np.clip(np.round(mid[:, 0]).astype(int), 0, w - 1)
    yi = np.clip(np.round(mid[:, 1]).astype(int), 0, h - 1)
    return m[dist[yi, xi] >= _OFF_BOUNDARY_PX]


def _bands(lines, ms):
    """The bands (step 3): dict of (P,) arrays: o, u, n (P, 2) its frame, lo, hi its extent
    along u from o, and its lines t = a1 + b1 s (the one at smaller t) and t = a2 + b2 s
    [work px]."""
    p, q = lines[:, :2], lines[:, 2:]
    d = q - p
    L = np.hypot(d[:, 0], d[:, 1])
    u = d / L[:, None]
    nrm = np.stack([-u[:, 1], u[:, 0]], 1)  # into the instrument
    i, j = np.triu_indices(len(lines), 1)
    c = 0.5 * (p + q)
    # facing each other: each one's instrument side towards the other, directions opposite
    facing = (np.sum(nrm[i] * (c[j] - c[i]), 1) > 0) & (np.sum(nrm[j] * (c[i] - c[j]), 1) > 0)
    ok = facing & (-np.sum(u[i] * u[j], 1) >= np.cos(np.radians(MAX_PAIR_DEG)))
    i, j = i[ok], j[ok]
    ua = u[i] - u[j]
    ua /= np.linalg.norm(ua, axis=1)[:, None]
    na = np.stack([-ua[:, 1], ua[:, 0]], 1)
    o = c[i]
    si = np.stack([np.sum((p[i] - o) * ua, 1), np.sum((q[i] - o) * ua, 1)], 1)
    sj = np.stack([np.sum((p[j] - o) * ua, 1), np.sum((q[j] - o) * ua, 1)], 1)
    lo, hi = np.maximum(si.min(1), sj.min(1)), np.minimum(si.max(1), sj.max(1))

    def offsets(k):
        dn, du = np.sum(d[k] * na, 1), np.sum(d[k] * ua, 1)
        b = dn / du
        return np.sum((p[k] - o) * na, 1) - b * np.sum((p[k] - o) * ua, 1), b

    (a1, b1), (a2, b2) = offsets(i), offsets(j)
    sm = 0.5 * (lo + hi)
    width = np.abs((a2 - a1) + (b2 - b1) * sm)
    keep = ((hi - lo) >= MIN_OVERLAP * np.minimum(L[i], L[j])) & ((hi - lo) >= width) \
        & (width >= WIDTH_RANGE[0] * ms) & (width <= WIDTH_RANGE[1] * ms)
    swap = (a1 + b1 * sm) > (a2 + b2 * sm)
    a1, a2 = np.where(swap, a2, a1), np.where(swap, a1, a2)
    b1, b2 = np.where(swap, b2, b1), np.where(swap, b1, b2)
    return {k: v[keep] for k, v in dict(o=o, u=ua, n=na, lo=lo, hi=hi, a1=a1, b1=b1, a2=a2, b2=b2).items()}


def _contrast(B, p, dist):
    """Each band's likeness contrast and the fraction of its stations inside the valid region
    (step 4)."""
    import cv2

    P = len(B["o"])
    if P == 0:
        return np.zeros(0)
    s = B["lo"][:, None] + (np.arange(STATIONS) + 0.5)[None, :] / STATIONS * (B["hi"] - B["lo"])[:, None]
    t1 = B["a1"][:, None] + B["b1"][:, None] * s
    t2 = B["a2"][:, None] + B["b2"][:, None] * s
    t = t1[..., None] + _ACROSS[None, None, :] * (t2 - t1)[..., None]
    X = B["o"][:, None, None, 0] + s[..., None] * B["u"][:, None, None, 0] + t * B["n"][:, None, None, 0]
    Y = B["o"][:, None, None, 1] + s[..., None] * B["u"][:, None, None, 1] + t * B["n"][:, None, None, 1]
    mx, my = X.reshape(P, -1).astype(np.float32), Y.reshape(P, -1).astype(np.float32)
    v = cv2.remap(p, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    ok = cv2.remap(dist, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0) > 0.5
    v = np.where(ok, v, np.nan).reshape(P, STATIONS, _ACROSS.size)
    f = _ACROSS

    def med(sel):
        a = v[:, :, sel].reshape(P, -1)
        cnt = np.sum(np.isfinite(a), 1)
        out = np.full(P, np.nan)
        has = cnt > 0
        out[has] = np.nanmedian(a[has], 1)
        return out

    inside = med((f > 0.2) & (f < 0.8))
    left, right = med((f < -0.15) & (f > -0.45)), med((f > 1.15) & (f < 1.45))
    side = np.fmax(np.nan_to_num(left, nan=-1.0), np.nan_to_num(right, nan=-1.0))
    side = np.where(side < 0, 0.0, side)  # a band whose sides are both out of view: no side evidence
    return np.nan_to_num(inside - side, nan=-1.0)


def _reach(B, k, p, dist):
    """How far band k's instrument runs along its axis beyond the band, each way, while the
    likeness on the axis stays instrument-like (gaps of up to half a width bridged), and
    whether either way reaches the valid region's boundary: (s_lo, s_hi, from_border)."""
    s_mid = 0.5 * (B["lo"][k] + B["hi"][k])
    w = abs((B["a2"][k] - B["a1"][k]) + (B["b2"][k] - B["b1"][k]) * s_mid)
    h, wd = p.shape
    ends, border = [], False
    for sgn, s0 in ((-1.0, B["lo"][k]), (1.0, B["hi"][k])):
        s, gap, last = s0, 0.0, s0
        while True:
            s += sgn
            t_mid = 0.5 * (B["a1"][k] + B["a2"][k] + (B["b1"][k] + B["b2"][k]) * s)
            x, y = B["o"][k] + s * B["u"][k] + t_mid * B["n"][k]
            xi, yi = int(round(x)), int(round(y))
            if not (0 <= xi < wd and 0 <= yi < h) or dist[yi, xi] < 1.5:
                border = border or gap <= 0.5 * w
                break
            if p[yi, xi] > 0.5:
                gap, last = 0.0, s
            else:
                gap += 1.0
                if gap > 0.5 * w:
                    break
        ends.append(last)
    return ends[0], ends[1], border


def _polygon(B, k, lo=None, hi=None):
    """The band's quadrilateral (4, 2) float32 [work px] between its lines over [lo, hi]."""
    lo = B["lo"][k] if lo is None else lo
    hi = B["hi"][k] if hi is None else hi
    pts = [B["o"][k] + s * B["u"][k] + (a + b * s) * B["n"][k]
           for s, (a, b) in ((lo, (B["a1"][k], B["b1"][k])), (hi, (B["a1"][k], B["b1"][k])),
                             (hi, (B["a2"][k], B["b2"][k])), (lo, (B["a2"][k], B["b2"][k])))]
    return np.array(pts, np.float32)


def _overlaps(P, taken):
    """Whether polygon P overlaps a taken one by more than 30 % of the smaller's area."""
    import cv2

    a = abs(cv2.contourArea(P))
    return a <= 0 or any(cv2.intersectConvexConvex(P, Q)[0] > 0.3 * min(a, abs(cv2.contourArea(Q))) for Q in taken)


def _specs(B, k, work):
    """The two lines of band k as `silhouette.fit_edges` specs (p0, u, n_out, s0, s1) [ideal
    px], each with its normal out of the band."""
    specs = []
    for a, b, out in ((B["a1"][k], B["b1"][k], -1.0), (B["a2"][k], B["b2"][k], 1.0)):
        ends = [B["o"][k] + s * B["u"][k] + (a + b * s) * B["n"][k] for s in (B["lo"][k], B["hi"][k])]
        P0, P1 = work.to_ideal(np.array(ends))
        u = (P1 - P0) / np.linalg.norm(P1 - P0)
        n = np.array([-u[1], u[0]])
        n_band = B["n"][k] / work.scale
        n = n if out * float(n @ n_band) > 0 else -n
        specs.append((P0, u, n, 0.0, float(np.linalg.norm(P1 - P0))))
    return specs


def pixel_cue(image, camera, validity, K, noise, *, min_contrast=MIN_CONTRAST, max_convergence_deg=MAX_PAIR_DEG,
              model=None, gamma=1.0):
    """Shafts by the pixel cue (module docstring): `PixelShaft` per band that held up, best
    score first.

    image: (H, W, 3) BGR raw frame; camera: Camera or None; validity: `work.Validity`; K: (3, 3)
    the axis camera (`work.axis_matrix`); noise: the image noise sd [grey levels]; model: a
    `pixels.PixelModel` (default the shipped one); gamma: the frame's encoding gamma the
    edges are located with (`silhouette.fit_edges`).
    """
    work = WorkFrame(image, camera, validity, WORK_PX)
    p = instrument_probability(work, model)
    ms = float(max(work.shape))
    lines = _outline_lines(p, work.dist, ms)
    if len(lines) < 2:
        return []
    B = _bands(lines, ms)
    contrast = _contrast(B, p, work.dist)
    taken, chosen = [], []
    for k in np.argsort(-contrast):
        if contrast[k] < min_contrast or len(chosen) >= _MAX_BANDS:
            break
        s_lo, s_hi, border = _reach(B, k, p, work.dist)
        s_mid = 0.5 * (B["lo"][k] + B["hi"][k])
        w = abs((B["a2"][k] - B["a1"][k]) + (B["b2"][k] - B["b1"][k]) * s_mid)
        # an instrument enters the view from its border; a band inside the view is one only
        # when it is long
        if not border and (s_hi - s_lo < LONG_WIDTHS * w or s_hi - s_lo < LONG_FRACTION * ms):
            continue
        P = _polygon(B, k, s_lo, s_hi)
        if _overlaps(P, taken):
            continue
        taken.append(P)
        chosen.append((k, w))
    if not chosen:
        return []
    specs = [sp for k, _ in chosen for sp in _specs(B, k, work)]
    widths = np.array([w for _, w in chosen]) / work.mean_scale
    corridor = np.repeat(np.maximum(np.maximum(_CORRIDOR_WORK_PX / work.mean_scale, _MIN_CORRIDOR_PX),
                                    CORRIDOR_WIDTHS * widths), 2)
    fimg = np.ascontiguousarray(image, dtype=np.float32)
    fits = fit_edges(fimg, camera, validity, noise, specs, corridor, gamma=gamma)
    out = []
    for q, (k, _) in enumerate(chosen):
        e1, e2 = fits[2 * q], fits[2 * q + 1]
        if e1 is None or e2 is None:
            continue
        m = midline_from_edges(K, e1, e2)
        if m is None or m.convergence_deg > max_convergence_deg:
            continue
        seen = float(np.hypot(*(m.ends[1] - m.ends[0])))
        out.append(PixelShaft(midline=m, contrast=float(contrast[k]), score=float(contrast[k]) * seen))
    return sorted(out, key=lambda s: -s.score)

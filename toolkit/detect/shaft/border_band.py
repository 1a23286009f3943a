"""A shaft the border of the view cuts lengthwise: one silhouette edge in view, the other
beyond the border (`border_shafts`).

An instrument close to the lens and near the edge of the view shows one long silhouette edge;
its other edge lies beyond the view's border (a da Vinci shaft across a corner of the frame,
a grasper's shaft along the field stop of a laparoscope). No band between two edges is there
to be found: the material cue's bands (`shaft.material_cue`), the single edge's partner
(`shaft.partner`: its far edge searched across the band) and the edge pairs all need the
second edge. What the frame shows is a region of one instrument material bounded by a
straight edge on one side and by the border of the view on the other. Here:

1. *seeds*: the straight boundaries of the material cue's region maps (`shaft.regions`), the
   longest first (at most `MAX_SEEDS`), that enter the view from its border (an end within the
   least width of it: the instrument comes in from outside);
2. *profiles*: at stations along each seed, the colours along its normal into its region
   (the instrument-like side) out to the widest band: the band reaches the border of the view
   at `BORDER_FRACTION` of the stations, at least the least width from the seed (median), and
   between the seed and the border its colour is one material: `INSIDE_FRACTION` of the
   samples nearer the inside's median colour than the outside's (beyond the seed), which
   differ by `Z_999` noise sds. A far edge inside the view (tissue beyond a shaft, a fold's
   other side) fails here: the band's far part has the outside's colour. And the border cuts
   it obliquely (`MIN_OBLIQUE`): a strip of one width along the border is the view's rim;
   and the material ends with the seed: past the seed's end away from the border (over the
   band's median width) the profiles up to the border are not `INSIDE_FRACTION` of the
   inside's colour (a scene's edge, a pad's or a phantom's, with the drape or the dark
   beyond it up to the border, runs on where the straight edge stops); and it is no
   vignetted rim (`vignetted_rim`): a ring of tissue the vignetting darkens along a circular
   field stop, whose inner edge reads as a straight boundary from the border, keeps the
   tissue's chromaticity (vignetting scales the light) and falls towards the stop, where a
   shaft's material differs from the tissue beside it, vignetted or not;
3. *region*: the strip between the seed and the border, across the seed's stretch, where the
   colour is nearer the inside's than the outside's; its largest connected part, unless it is
   glare (over `work.MAX_CLIPPED` of its pixels at the 8-bit ceiling, `work.CLIPPED_LEVEL`:
   the light, not a material, as `shaft.parts` judges its regions; nor is a seed with glare
   outside it a silhouette) or a void (its median at most `VOID_LEVEL`:
   no light returned), carried to raw pixels;
4. *axis*: the region read as an instrument mask is (`shaft.mask.mask_axis`, the reading the
   masks' references get): its outline on the border of the view is no silhouette, so a
   region with one straight silhouette stretch gets its principal axis, kind "part", with a
   part's sigmas (the angle's sd its half-angle atan(width / length), the offset's half its
   width; the same where two straight stretches give kind "shaft": not refitted on the
   image); kept when it runs along at least `MIN_BORDER_ELONGATION` of its widths and
   overlaps none of the shafts already found, each one's band run on along its axis across
   the view (the instrument has its axis).

Each is a `shaft.detector.Shaft` with cue `BORDER_CUE`; the detector judges it as every
shaft (`shaft.detector.judged`: pixel evidence, tissue colour). Work pixels in steps 1-3.

Example
-------
>>> import numpy as np, cv2
>>> from pencilcal.toolkit.detect.shaft.regions import BoundaryLines
>>> from pencilcal.toolkit.detect.shaft.work import Validity, WorkFrame
>>> img = np.zeros((240, 320, 3), np.uint8); img[:] = (60, 80, 170)              # tissue
>>> _ = cv2.fillConvexPoly(img, np.array([[150, 0], [319, 0], [319, 90], [150, 40]], np.int32), (95, 95, 98))
>>> img = cv2.GaussianBlur(img, (0, 0), 1.0)     # a grey shaft from the right, its far edge beyond the top
>>> wf = WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=320)
>>> u = np.array([169.0, 50.0]) / np.hypot(169.0, 50.0)
>>> seed = BoundaryLines(p=np.array([[150.0, 40.0]]), u=u[None], n=np.array([[u[1], -u[0]]]),
...                      lo=np.array([4.0]), hi=np.array([172.0]), support=np.array([168.0]))
>>> regions = border_regions(wf, seed, 6.0, 120.0, 1.0)
>>> len(regions), bool(regions[0][0][10, 300]), bool(regions[0][0][120, 100]), regions[0][1]
(1, True, False, True)
>>> _ = cv2.rectangle(img, (0, 0), (150, 40), (95, 95, 98), -1)   # the grey runs on past the edge's end
>>> border_regions(WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=320), seed, 6.0, 120.0, 1.0)
[]
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.shaft.mask import mask_axis
from pencilcal.toolkit.detect.shaft.regions import Z_999, BoundaryLines
from pencilcal.toolkit.detect.shaft.work import CLIPPED_LEVEL, MAX_CLIPPED, axis_matrix, raw_masks
from pencilcal.toolkit.detect.working import to_working

__all__ = ["border_regions", "border_shafts", "BORDER_CUE", "MAX_SEEDS", "BORDER_FRACTION", "INSIDE_FRACTION",
           "MIN_BORDER_ELONGATION", "VOID_LEVEL", "MIN_OBLIQUE", "RIM_MAX_HUE_DEG", "RIM_MIN_FALL", "vignetted_rim"]

#: The cue of the axes found here (`shaft.detector.Shaft.cue`).
BORDER_CUE = "border"
#: Seeds searched per frame, the longest first.
MAX_SEEDS = 6
#: The least fraction of a seed's stations whose profile reaches the border of the view within
#: the widest band: the band is cut by the border along most of the seed, not at one end.
BORDER_FRACTION = 0.75
#: The least fraction of the samples between the seed and the border nearer the inside's
#: colour than the outside's: one material up to the border, no far edge before it.
INSIDE_FRACTION = 0.85
#: The least length of a region's axis in its widths: a principal axis is read as the parts'
#: are (`shaft.parts.MIN_PART_ELONGATION`: an angle sd, atan(width / length), of at most 27
#: deg); not tuned.
MIN_BORDER_ELONGATION = 2.0
_OFFSET_SIGMA_FRAC = 0.5  # a principal axis' offset sd: half its width (`shaft.from_mask`'s parts)
#: A region whose median luma is at most this 8-bit level shows no light returned: the space
#: beyond the scene (a phantom's black surround), not a material; the mirror of the glare's
#: `work.CLIPPED_LEVEL` (set after looking at the dVRK phantom's surround, 3-6, and the
#: darkest shaft cut by the border on the masked sources, 43; not from the protocol).
VOID_LEVEL = 16
#: The least ratio of the band's largest width to its smallest (90th to 10th percentile of
#: the stations' distances to the border): the border cuts a shaft across a corner or along a
#: curve, obliquely; a strip of one width all along the border is the view's rim.
MIN_OBLIQUE = 1.5
#: A vignetted rim: the most angle [deg] between the strip's median colour and the outside's
#: (BGR vectors): vignetting scales the light, so the ring it darkens keeps the tissue's
#: chromaticity (0.3-6 deg measured on synthetic vignetted fields), where a shaft's material
#: differs from the tissue beside it (19.7-21.4 deg on the real shafts this cue finds); in
#: the gap, near its middle in ratio, not fitted.
RIM_MAX_HUE_DEG = 10.0
#: A vignetted rim: the least correlation of the strip's luma with its distance to the border
#: of the view (its samples between the seed and the border): the light falls towards the
#: field stop (0.67-0.99 measured on the rims), where a shaft's luma follows its own shading
#: (-0.60 to 0.27 on the real shafts this cue finds; a grey shaft vignetted with the tissue rises
#: too, 0.83-0.90, and is told by its colour); near the middle of the gap, not fitted.
RIM_MIN_FALL = 0.5
_STATIONS = 24
_EDGE_PX = 1.5  # samples this close to the seed or the border belong to neither side [work px]
_TOUCH = 0.2  # a region overlapping a found shaft's band by this fraction of the smaller is its instrument's


def _seeds(regions):
    """The straight boundaries of every region level (`shaft.regions`; regions: the frame's
    `FrameRegions`), as one BoundaryLines, those entering the view from its border, the
    longest first (module docstring, step 1)."""
    got = regions.lines
    if not got:
        return None
    P = np.concatenate([L.p for L in got]).reshape(-1, 2)
    U = np.concatenate([L.u for L in got]).reshape(-1, 2)
    N = np.concatenate([L.n for L in got]).reshape(-1, 2)
    lo, hi = np.concatenate([L.lo for L in got]), np.concatenate([L.hi for L in got])
    sup = np.concatenate([L.support for L in got])
    return BoundaryLines(p=P, u=U, n=N, lo=lo, hi=hi, support=sup)


def _profiles(work, P, m, t):
    """Colours (S, T, C) float32 and the view's distance (S, T) at P (S, 2) + t (T,) m (2,)."""
    import cv2

    X = (P[:, None, 0] + t[None, :] * m[0]).astype(np.float32)
    Y = (P[:, None, 1] + t[None, :] * m[1]).astype(np.float32)
    col = cv2.remap(work.colours, X, Y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    dist = cv2.remap(work.dist, X, Y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1)
    return col.reshape(X.shape + (-1,)), dist


def _nearer_inside(X, c_in, c_out):
    """The fraction of colours X (N, C) nearer c_in than c_out."""
    return float(np.mean(np.linalg.norm(X - c_in, axis=1) < np.linalg.norm(X - c_out, axis=1)))


def vignetted_rim(col, dist, c_in, c_out):
    """Whether a strip is a ring of tissue the vignetting darkens towards the field stop, not
    an instrument's material (module docstring, step 2): its median colour c_in (C,) the
    outside's c_out (C,) scaled, within `RIM_MAX_HUE_DEG`, and its luma rising with the
    distance to the border, correlation at least `RIM_MIN_FALL`. col: (N, C) its colours
    [grey levels]; dist: (N,) their distances to the border [px]. Grey frames (C = 1) have
    no chromaticity: never a rim.

    >>> d = np.arange(1.0, 20.0); tissue = np.array([70.0, 85.0, 175.0])
    >>> rim = tissue[None] * (0.4 + 0.02 * d)[:, None]        # the tissue, darker towards the stop
    >>> vignetted_rim(rim, d, np.median(rim, 0), tissue)
    True
    >>> shaft = np.array([95.0, 95.0, 98.0])[None] * (0.4 + 0.02 * d)[:, None]   # grey, vignetted too
    >>> vignetted_rim(shaft, d, np.median(shaft, 0), tissue)
    False
    """
    if col.shape[-1] < 3 or len(dist) < 3 or np.ptp(dist) == 0:
        return False
    cos = float(c_in @ c_out) / max(float(np.linalg.norm(c_in) * np.linalg.norm(c_out)), 1e-9)
    if np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))) > RIM_MAX_HUE_DEG:
        return False
    luma = col[:, :3] @ np.array([0.114, 0.587, 0.299], np.float32)  # BGR
    if np.ptp(luma) == 0:
        return False
    return bool(np.corrcoef(dist, luma)[0, 1] >= RIM_MIN_FALL)


def _pixel(work, q):
    """(row, col) of the work pixel nearest to q (2,), clipped to the frame."""
    return (int(np.clip(np.rint(q[1]), 0, work.shape[0] - 1)), int(np.clip(np.rint(q[0]), 0, work.shape[1] - 1)))


def _region(work, p, u, m, lo, hi, t_b, c_in, c_out, ceiling):
    """The strip between a seed (p, u, [lo, hi]) and the border (t_b: how far along m the
    border lies, per station) where the colour is nearer c_in than c_out: (h, w) bool, its
    largest connected part, or None where that is glare (ceiling: the clipped level) or a
    void (module docstring, step 3)."""
    import cv2

    a, b = p + lo * u, p + hi * u
    reach = float(np.max(t_b)) + 3.0  # beyond the border: the view's own bound cuts it there
    poly = np.rint(np.array([a, b, b + reach * m, a + reach * m], np.float32)).astype(np.int32)
    # the strip's bounding box with a margin of 2 px (the opening's reach, so that it sees the
    # zeros around the strip as over the whole frame): every reading below bit for bit the
    # whole frame's, at the cost of the strip's pixels only
    h, w = work.shape
    x0, y0 = max(int(poly[:, 0].min()) - 2, 0), max(int(poly[:, 1].min()) - 2, 0)
    x1, y1 = min(int(poly[:, 0].max()) + 3, w), min(int(poly[:, 1].max()) + 3, h)
    if x1 <= x0 or y1 <= y0:
        return None
    box = (slice(y0, y1), slice(x0, x1))
    strip = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.fillConvexPoly(strip, poly - np.array([x0, y0], np.int32), 1)
    C = work.colours[box]
    near = np.linalg.norm(C - c_in, axis=-1) < np.linalg.norm(C - c_out, axis=-1)
    B = (strip > 0) & near & work.valid[box]
    B = cv2.morphologyEx(B.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, lab, stats, _ = cv2.connectedComponentsWithStats(B, connectivity=8)
    if n <= 1:
        return None
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    Rb = lab == k
    # glare: a region mostly at the 8-bit ceiling shows the light, not a material; a void at
    # the floor shows none
    if work.bgr.dtype == np.uint8 and (np.count_nonzero(work.bgr[box].max(-1)[Rb] >= ceiling) > MAX_CLIPPED * Rb.sum()
                                       or np.median(work.luma[box][Rb]) <= VOID_LEVEL):
        return None
    R = np.zeros(work.shape, bool)
    R[box] = Rb
    return R


def border_regions(work, seeds, wmin, wmax, noise, max_seeds=MAX_SEEDS):
    """The regions of shafts cut lengthwise by the border (module docstring, steps 1-3): a
    list of ((h, w) bool work-frame mask, whether its inside is darker than the outside).

    work: `shaft.work.WorkFrame`; seeds: `shaft.regions.BoundaryLines` (n into their region)
    [work px]; wmin, wmax: the band widths [work px]; noise: the work frame's noise sd per
    channel [grey levels].
    """
    if seeds is None or len(seeds.p) == 0:
        return []
    ends = np.concatenate([seeds.p + seeds.lo[:, None] * seeds.u, seeds.p + seeds.hi[:, None] * seeds.u])
    x = np.clip(np.rint(ends[:, 0]).astype(int), 0, work.shape[1] - 1)
    y = np.clip(np.rint(ends[:, 1]).astype(int), 0, work.shape[0] - 1)
    entering = (work.dist[y, x] <= wmin).reshape(2, -1).any(0)
    order = [k for k in np.argsort(-(seeds.hi - seeds.lo), kind="stable") if entering[k]][:max_seeds]
    t = np.arange(-wmin, wmax + 1.0, 1.0)
    ceiling = CLIPPED_LEVEL if work.bgr.dtype == np.uint8 else np.inf
    out = []
    for k in order:
        p, u, m = seeds.p[k], seeds.u[k], seeds.n[k]
        lo, hi = float(seeds.lo[k]), float(seeds.hi[k])
        s = lo + (np.arange(_STATIONS) + 0.5) * (hi - lo) / _STATIONS
        col, dist = _profiles(work, p[None, :] + s[:, None] * u[None, :], m, t)
        beyond = (t[None, :] > 0) & (dist <= 1.0)
        cut = beyond.any(1)
        if cut.mean() < BORDER_FRACTION:
            continue
        t_b = np.where(cut, t[np.argmax(beyond, 1)], np.inf)
        if np.median(t_b[cut]) < wmin or np.percentile(t_b[cut], 90) < MIN_OBLIQUE * np.percentile(t_b[cut], 10):
            continue
        inside = (t[None, :] >= _EDGE_PX) & (t[None, :] <= t_b[:, None] - _EDGE_PX) & cut[:, None]
        outside = (t[None, :] <= -_EDGE_PX) & (dist > 1.0)
        if inside.sum() < 10 or outside.sum() < 10:
            continue
        c_in, c_out = np.median(col[inside], 0), np.median(col[outside], 0)
        # a glare's boundary is the light's edge, not a silhouette
        if np.linalg.norm(c_in - c_out) < Z_999 * noise * np.sqrt(col.shape[-1]) or c_out.max() >= ceiling:
            continue
        if _nearer_inside(col[inside], c_in, c_out) < INSIDE_FRACTION:
            continue
        # vignetting darkens a ring of tissue along a field stop whose inner edge reads as a
        # straight boundary entering from the border: the tissue's colour, falling to the stop
        if vignetted_rim(col[inside], dist[inside], c_in, c_out):
            continue
        # a silhouette ends with its instrument: where the material runs on past the seed's far
        # end, up to the border, the seed is a scene's edge with background beyond it
        far = hi if work.dist[_pixel(work, p + hi * u)] > work.dist[_pixel(work, p + lo * u)] else lo
        ext = far + np.sign(far - 0.5 * (lo + hi)) * np.linspace(_EDGE_PX, np.median(t_b[cut]), _STATIONS)
        col_e, dist_e = _profiles(work, p[None, :] + ext[:, None] * u[None, :], m, t)
        on = (t[None, :] >= _EDGE_PX) & (t[None, :] <= wmax) & (dist_e > 1.0)
        on &= np.cumsum(dist_e <= 1.0, axis=1) == 0  # up to the border
        if on.sum() >= 10 and _nearer_inside(col_e[on], c_in, c_out) >= INSIDE_FRACTION:
            continue
        R = _region(work, p, u, m, lo, hi, t_b[cut], c_in, c_out, ceiling)
        if R is not None and not any(np.count_nonzero(R & Q) > 0.5 * min(R.sum(), Q.sum()) for Q, _ in out):
            out.append((R, bool(c_in.mean() < c_out.mean())))
    return out


def _band_quads(work, camera, shafts):
    """Each found shaft's band between its edges, run on along its axis across the view (its
    instrument goes on to where it enters), as a (h, w) bool work-frame mask."""
    import cv2

    out = []
    reach = float(np.hypot(*work.shape))
    for sh in shafts:
        e = np.asarray(sh.edges, float).reshape(-1, 4)
        if e.shape[0] != 2:
            continue
        q = work.to_work(to_working(camera, e).reshape(4, 2))
        d = (q[1] - q[0]) / max(float(np.linalg.norm(q[1] - q[0])), 1e-9)
        q = np.concatenate([q[0::2] - reach * d, q[1::2] + reach * d])
        B = np.zeros(work.shape, np.uint8)
        cv2.fillConvexPoly(B, cv2.convexHull(np.rint(q).astype(np.int32)), 1)
        out.append(B > 0)
    return out


def _fields(camera, ax, polarity):
    """The `shaft.detector.Shaft` fields of a region's axis (`mask.MaskAxis`, raw px): drawn
    over its length, with a part's sigmas (module docstring, step 4), or None where it leaves
    the lens model's reach."""
    seg = ax.segment()
    ideal = to_working(camera, seg).reshape(-1)
    if not np.all(np.isfinite(ideal)):
        return None
    sa = float(np.arctan2(ax.width_px, ax.length_px))
    so = _OFFSET_SIGMA_FRAC * float(ax.width_px)
    cov = np.diag([sa**2, so**2])
    return dict(midline=np.asarray(seg, float), width_px=float(ax.width_px), angle_sigma=sa, offset_sigma=so,
                edges=np.zeros((0, 4)), score=float(ax.length_px), ideal_midline=np.asarray(ideal, float),
                convergence_deg=0.0, polarity=polarity, cue=BORDER_CUE, cov=cov, cov_stat=cov,
                cov_floor=np.zeros((2, 2)), kind=ax.kind)


def border_shafts(image, camera, validity, work, mm, regions, o, found):
    """The axes of the shafts cut lengthwise by the border of the view (module docstring): a
    list of dicts of `shaft.detector.Shaft` fields, cue `BORDER_CUE`, the longest first.

    image: (H, W, 3) the raw frame; validity: `shaft.work.Validity`; work: its
    `shaft.work.WorkFrame`; mm: its `shaft.regions.MaterialMap`; regions: its
    `shaft.regions.FrameRegions` (the material cue's); o: `detector.ShaftOptions`;
    found: the shafts found already (`shaft.detector.Shaft`): a region overlapping one of
    their bands is that instrument's.
    """
    s = work.mean_scale
    got = border_regions(work, _seeds(regions), o.region_wmin * s, o.region_wmax * s, mm.luma_noise)
    bands = _band_quads(work, camera, found)
    got = [(R, dark) for R, dark in got
           if not any(np.count_nonzero(R & Q) > _TOUCH * min(R.sum(), Q.sum()) for Q in bands)]
    if not got:
        return []
    lab = np.zeros(work.shape, np.int32)
    for i, (R, _) in enumerate(got, 1):
        lab[R & (lab == 0)] = i
    shape = np.asarray(image).shape[:2]
    valid = None if validity.region is None else validity.region.mask(shape)
    K = axis_matrix(camera, shape)[0]
    out = []
    for mk, (_, dark) in zip(raw_masks(work, camera, lab, len(got), shape), got):
        if not mk.any():
            continue
        ax = mask_axis(mk, valid, K)
        f = _fields(camera, ax, "dark" if dark else "bright") if ax.length_px >= MIN_BORDER_ELONGATION * ax.width_px \
            else None
        if f is not None:
            out.append(f)
    return sorted(out, key=lambda f: -f["score"])

"""Line segments with subpixel precision and an honest angle uncertainty.

Pipeline of `detect_segments` (one grey image, one call):

1. *detect*: OpenCV's LSD (``cv2.createLineSegmentDetector``), FLD
   (``cv2.ximgproc.createFastLineDetector``) or EDLines (``cv2.ximgproc.createEdgeDrawing``)
   on the 8-bit image (`detect_raw`);
2. *orient* every fragment by its edge polarity (`orient_by_polarity`), so that opposite
   edges of a thin bar are never merged;
3. *undistort* the fragments when a camera is given: lens distortion bends long lines, so
   everything after this step works in ideal (undistorted) pixels (`working`);
4. *merge* collinear fragments, gaps allowed (`merge_collinear`);
5. *refit* every merged line to its edge pixels (`refine_segments`, `refit`): Gaussian-
   derivative profiles across the line at stations every 2 px, the subpixel edge at each
   (`edges.edge_profiles`), a robust weighted line fit trimmed to the longest run of
   supporting stations, its end points where the edge response falls to half, grown while
   the edge continues beyond them. Under a camera the stations lie on the *undistorted*
   line and are sampled in the raw image through the lens model.

Conventions
-----------
- Pixels: OpenCV's, pixel (0, 0) is the centre of the top-left pixel; u right, v down.
- A segment is ``[x1, y1, x2, y2]`` [px]. Returned segments are in RAW (distorted) pixels,
  their end points are the ends of the fit in undistorted pixels mapped back through the
  lens model (``Segments.ideal`` keeps the undistorted ones).
- Direction and polarity: with d = (p2 - p1) / |p2 - p1| and n = (-d_y, d_x) (the normal of
  pencil.vertex), the image gets *brighter* along n. On screen (v down) the dark side is on
  the left when walking from p1 to p2.
- Uncertainty (the noise model of pencil.vertex): ``angle_sigma`` [rad] is the sd of the
  line's angle, ``offset_sigma`` [px] the sd of its perpendicular position at the segment
  midpoint (angle errors pivot about the weighted centroid of the stations, near the
  midpoint). Both come from the scatter of the station edges about the fitted line, made
  honest for correlated station errors (`edges.fit_variances`). On the synthetic edges of
  tests/toolkit/detect/test_segments.py the angle error over its sd is N(0, 1) within 5 %
  (coverage of +-1 sd 0.65-0.72). When a camera is given they refer to the undistorted
  line, which is what the estimators use.

Example
-------
>>> import numpy as np
>>> from scipy.special import ndtr
>>> v, u = np.mgrid[0:240, 0:320].astype(float)
>>> n = np.array([-np.sin(0.3), np.cos(0.3)])                   # an edge at 0.3 rad
>>> img = 60 + 140 * ndtr((n[0] * (u - 160) + n[1] * (v - 120)) / 1.04)
>>> segs = detect_segments(img.astype(np.uint8), "lsd", min_length=50)
>>> len(segs), round(float(segs.angle[0]), 4), bool(segs.angle_sigma[0] < 1e-4)
(1, 0.3, True)
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from functools import lru_cache

import numpy as np

from pencilcal.toolkit.detect.image import GrayImage
from pencilcal.toolkit.detect.refit import EdgeFit, RefitOptions, refit_lines
from pencilcal.toolkit.detect.working import check_camera_image, to_raw, to_working
from pencilcal.toolkit.geometry.neighbours import pairs_within
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.pencil.defaults import ENDPOINT_SIGMA_PX
from pencilcal.toolkit.pencil.vertex import segment_angle_sigma

__all__ = [
    "DETECTORS",
    "DETECTOR_CHOICES",
    "proposal_detector",
    "MERGE_ANGLE_TOL_DEG",
    "MERGE_DIST_TOL_PX",
    "MIN_LENGTH_PX",
    "Segments",
    "detect_raw",
    "orient_by_polarity",
    "merge_collinear",
    "detect_fragments",
    "refine_segments",
    "detect_segments",
    "in_valid_region",
]

DETECTORS = ("lsd", "fld", "edlines")
#: What a caller may ask for: a detector, or "auto" (`proposal_detector`).
DETECTOR_CHOICES = ("auto",) + DETECTORS


def proposal_detector(detector, bars=False):
    """The OpenCV detector to run: `detector` itself, or for "auto" FLD where it proposes
    printed bars on a reduced image (`bars`: `detect_bars` with proposal_scale < 1, frames
    of 720 lines or more) and LSD elsewhere (small frames, edge segments, shaft proposals).

    On rendered fans without their width (thin 1.2 mm and thick 4 mm spokes, dark on light
    and light on dark, 1280x720 and 1920x1080, noise sd 5 and 12, blur 1.5 and 3 px) FLD
    proposals on the half-resolution image let as many frames through as LSD's, or more
    (the blurred thick bars: 5 of 5 frames against 2), with the same tilt errors, at about a
    fifth of LSD's cost. On a 640x360 sweep, proposed at full resolution, FLD's bars gave
    single-angle errors 3.6 times their sd at 50-70 deg tilt (LSD's: within it), so small
    frames keep LSD; its a-contrario test also keeps the long, low-contrast edges of plain
    segments and shafts.

    >>> proposal_detector("auto", bars=True), proposal_detector("auto"), proposal_detector("edlines", True)
    ('fld', 'lsd', 'edlines')
    """
    if detector == "auto":
        return "fld" if bars else "lsd"
    return detector
MERGE_ANGLE_TOL_DEG = 2.0  # fragments of one line differ in direction by less [deg] (merge_collinear)
MERGE_DIST_TOL_PX = 1.5  # ... and lie within this distance of each other's line [px]
MIN_LENGTH_PX = 20.0  # shortest segment detect_segments returns by default [px]


# ============================================================================ results


@dataclass(frozen=True, eq=False)
class Segments:
    """Refined line segments of one image. M segments, every array has leading shape (M,).

    Attributes
    ----------
    segments : (M, 4) [px]
        ``[x1, y1, x2, y2]`` in raw (distorted) pixels, oriented so that the image is brighter
        on the side of n = (-d_y, d_x) (dark on the left on screen).
    ideal : (M, 4) [px]
        The same segments in undistorted pixels (``camera.undistort_pixels``); equal to
        `segments` without a camera.
    angle_sigma : (M,) [rad]
        sd of the angle of each (undistorted) line.
    offset_sigma : (M,) [px]
        sd of its perpendicular position at the segment midpoint.
    length : (M,) [px]
        Length of the undistorted segment.
    contrast : (M,) [grey levels]
        Median step across the edge (bright side minus dark side), > 0.
    residual_px : (M,) [px]
        RMS distance of the inlier station edges from the fitted line.
    stations : (M,) int
        Number of inlier stations (edge points) in the fit.
    """

    segments: np.ndarray
    ideal: np.ndarray
    angle_sigma: np.ndarray
    offset_sigma: np.ndarray
    length: np.ndarray
    contrast: np.ndarray
    residual_px: np.ndarray
    stations: np.ndarray

    def __len__(self) -> int:
        return int(self.segments.shape[0])

    @property
    def angle(self) -> np.ndarray:
        """(M,) [rad] oriented angle atan2(dv, du) of each undistorted segment."""
        d = self.ideal[:, 2:] - self.ideal[:, :2]
        return np.arctan2(d[:, 1], d[:, 0])

    def select(self, mask):
        """A new result with the rows `mask` (bool (M,) or indices) selects."""
        return type(self)(**{f.name: getattr(self, f.name)[mask] for f in fields(self)})

    @classmethod
    def empty(cls, **extra):
        """No segments (`extra`: the empty arrays of a subclass's own fields)."""
        z = np.zeros(0)
        base = dict(segments=np.zeros((0, 4)), ideal=np.zeros((0, 4)), angle_sigma=z, offset_sigma=z,
                    length=z, contrast=z, residual_px=z, stations=np.zeros(0, int))
        base.update(extra)
        return cls(**base)

    @classmethod
    def from_fit(cls, fit: EdgeFit, camera, min_length):
        """The refitted lines of `fit` (working pixels) that are ok, at least `min_length`
        [px] long and map back to finite raw pixels, in their order."""
        ideal = fit.lines()
        L = np.hypot(*(fit.p2 - fit.p1).T)
        keep = fit.ok & (L >= min_length) & np.all(np.isfinite(ideal), -1)
        ideal = ideal[keep]
        raw = to_raw(camera, ideal)
        good = np.all(np.isfinite(raw), -1)
        idx = np.flatnonzero(keep)[good]
        mid = 0.5 * (fit.p1[idx] + fit.p2[idx])
        return cls(
            segments=raw[good],
            ideal=ideal[good],
            angle_sigma=fit.angle_sigma[idx],
            offset_sigma=fit.take(idx).offset_sigma_at(mid),
            length=L[idx],
            contrast=fit.contrast[idx],
            residual_px=fit.residual[idx],
            stations=fit.count[idx].astype(int),
        )


# ============================================================================ detectors


@lru_cache(maxsize=32)
def _detector(name, params):
    """The OpenCV detector `name` built with `params` (a sorted tuple of (key, value))."""
    import cv2

    params = dict(params)
    if name == "lsd":
        return cv2.createLineSegmentDetector(**params)
    if name == "fld":
        return cv2.ximgproc.createFastLineDetector(**{"length_threshold": 10, **params})
    ed = cv2.ximgproc.createEdgeDrawing()
    p = cv2.ximgproc.EdgeDrawing.Params()
    p.MinLineLength = 10
    for k, v in params.items():
        if not hasattr(p, k):
            raise InputError(f"edlines: unknown parameter {k!r}")
        setattr(p, k, v)
    ed.setParams(p)
    return ed


def detect_raw(image, detector="lsd", params=None):
    """The chosen OpenCV detector's segments, as it returns them.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array or GrayImage
        Grey or BGR image (8/16 bit or float); detectors run on its 8-bit version.
    detector : {"lsd", "fld", "edlines"}
        ``cv2.createLineSegmentDetector`` (LSD, default refinement), FLD
        (``cv2.ximgproc.createFastLineDetector``, ``length_threshold=10``) or EDLines
        (``cv2.ximgproc.createEdgeDrawing`` + ``detectLines``, ``MinLineLength=10``).
    params : dict, optional
        Keyword arguments of the OpenCV constructor (lsd, fld) or fields of
        ``cv2.ximgproc.EdgeDrawing.Params`` (edlines), e.g. ``{"canny_th1": 20}``.

    Returns
    -------
    (N, 4) float64 [px]
        ``[x1, y1, x2, y2]`` in the image's (raw) pixels, in no particular orientation.

    Example
    -------
    >>> img = np.zeros((100, 100), np.uint8); img[:, 50:] = 200
    >>> detect_raw(img, "fld").shape[1]
    4
    """
    detector = proposal_detector(detector)
    if detector not in DETECTORS:
        raise InputError(f"unknown detector {detector!r}; expected one of {', '.join(DETECTOR_CHOICES)}")
    params = dict(params or {})
    u8 = (image if isinstance(image, GrayImage) else GrayImage(image)).u8
    try:
        det = _detector(detector, tuple(sorted(params.items())))
        if detector == "lsd":
            out = det.detect(u8)[0]
        elif detector == "fld":
            out = det.detect(u8)
        else:
            det.detectEdges(u8)
            out = det.detectLines()
    except TypeError as e:
        raise InputError(f"{detector}: bad detector parameters {params}: {e}") from None
    if out is None:
        return np.zeros((0, 4))
    return np.asarray(out, float).reshape(-1, 4)


def orient_by_polarity(image, segments, offset_px=1.0):
    """Orient segments so that the image is brighter on the side of n = (-d_y, d_x).

    image: grey/BGR image or GrayImage; segments: (N, 4) [px]. Sums the grey-level
    differences across each segment at 1, 2 and 3 times `offset_px` on both sides, at 1/4,
    1/2 and 3/4 of its length (several distances: a segment a pixel or two off its edge
    still sees it). Returns (oriented (N, 4), flipped (N,) bool).

    >>> img = np.zeros((50, 50), np.float32); img[25:] = 100        # bright below
    >>> orient_by_polarity(img, [[40.0, 24.5, 10.0, 24.5]])[0].tolist()   # d = +u: n = +v
    [[10.0, 24.5, 40.0, 24.5]]
    """
    seg = np.asarray(segments, float).reshape(-1, 4)
    img = image if isinstance(image, GrayImage) else GrayImage(image)
    if seg.shape[0] == 0:
        return seg.copy(), np.zeros(0, bool)
    p1, p2 = seg[:, None, :2], seg[:, None, 2:]
    d = p2 - p1
    L = np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)
    nrm = np.concatenate([-d[..., 1:], d[..., :1]], -1) / L
    pts = p1 + np.array([0.25, 0.5, 0.75])[None, :, None] * d  # (N, 3, 2)
    off = (offset_px * np.array([1.0, 2.0, 3.0]))[None, :, None, None] * nrm[:, None]  # (N, 3, 1, 2)
    # the nearest pixels are enough for a sign, and need no float copy of the image
    a = img.nearest(*(pts[:, None] + off).transpose(3, 0, 1, 2))
    b = img.nearest(*(pts[:, None] - off).transpose(3, 0, 1, 2))
    flip = np.sum(a - b, (-1, -2)) < 0
    out = seg.copy()
    out[flip] = seg[flip][:, [2, 3, 0, 1]]
    return out, flip


# ============================================================================ merging


def _line_frame(seg):
    p1, p2 = seg[:, :2], seg[:, 2:]
    d = p2 - p1
    L = np.hypot(d[:, 0], d[:, 1])
    u = d / np.maximum(L, 1e-12)[:, None]
    n = np.stack([-u[:, 1], u[:, 0]], -1)
    return p1, u, n, L


def _nearby_pairs(s, u, L, tol, max_gap_px, dist_tol_px):
    """Candidate pairs (P, 2) of fragments (K, 4) that come within max_gap of each other
    with similar directions (unit u (K, 2), lengths L).

    Points every max_gap along each fragment (ends included) are paired (`pairs_within`) on
    (position, direction scaled so that the angle tolerance `tol` [rad] weighs like the
    gap); a Hough-like (angle, offset) key would need an offset tolerance growing with the
    distance from its origin and flood a busy image with candidates.
    """
    reach = max(max_gap_px, 2.0) + dist_tol_px
    npts = np.ceil(L / max(max_gap_px, 2.0)).astype(int) + 1
    owner = np.repeat(np.arange(L.size), npts)
    first = np.cumsum(npts) - npts
    frac = (np.arange(owner.size) - first[owner]) / np.maximum(npts[owner] - 1, 1)
    pts = s[owner, :2] + frac[:, None] * (s[owner, 2:] - s[owner, :2])
    dscale = reach / (2.0 * np.sin(min(2.0 * tol, 1.5) / 2.0))
    feat = np.column_stack([pts, dscale * u[owner]])
    pp = pairs_within(feat, np.sqrt(2.0) * reach)
    if not pp.size:
        return np.zeros((0, 2), int)
    i, j = owner[pp[:, 0]], owner[pp[:, 1]]
    i, j = np.minimum(i, j), np.maximum(i, j)
    key = np.unique(i[i != j] * L.size + j[i != j])
    return np.stack([key // L.size, key % L.size], -1)


def _collinear_pairs(pairs, s, c, u, n, L, theta, tol_b, dist_tol_px, max_gap_px):
    """The candidate pairs (P, 2) that join: directions within the shorter's tolerance
    tol_b, its ends within dist_tol_px (growing with the extrapolation) of the longer's
    line, the gap along it at most max_gap_px. Returns the index arrays i, j."""
    if not pairs.size:
        return np.zeros(0, int), np.zeros(0, int)
    i, j = pairs[:, 0], pairs[:, 1]
    a = np.where(L[i] >= L[j], i, j)  # the longer one is the reference line
    b = np.where(L[i] >= L[j], j, i)
    dth = np.abs(np.angle(np.exp(1j * (theta[a] - theta[b]))))
    ok = dth <= tol_b[b]
    # the shorter's end points in the longer's frame (along, across)
    e1 = s[b, :2] - c[a]
    e2 = s[b, 2:] - c[a]
    al1, al2 = np.sum(e1 * u[a], -1), np.sum(e2 * u[a], -1)
    ac1, ac2 = np.sum(e1 * n[a], -1), np.sum(e2 * n[a], -1)
    half = 0.5 * L[a]
    lo, hi = np.minimum(al1, al2), np.maximum(al1, al2)
    gap = np.maximum(0.0, np.maximum(lo - half, -half - hi))
    # allowed offset grows with the distance the longer line is extrapolated over
    reach = np.maximum(np.abs(np.stack([al1, al2], -1)) - half[:, None], 0.0).max(-1)
    dtol = dist_tol_px + reach / L[a]  # the longer line's angle is known to ~1 px / L
    ok &= (np.abs(ac1) <= dtol) & (np.abs(ac2) <= dtol) & (gap <= max_gap_px)
    return i[ok], j[ok]


def _group_lines(lab, c, u, L):
    """Per group of `lab`: (inv (K,) group of each fragment, m (G, 2) the length-weighted
    centre, dirs (G, 2) the total-least-squares direction of the fragments, each taken as a
    uniform mass along it, oriented along their mean direction)."""
    mid, inv = np.unique(lab, return_inverse=True)
    G = mid.size
    w = L
    W = np.bincount(inv, w, G)
    m = np.stack([np.bincount(inv, w * c[:, 0], G), np.bincount(inv, w * c[:, 1], G)], -1) / W[:, None]
    dc = c - m[inv]
    # second moments: centres' scatter plus each fragment's own extent (L^2 / 12 along u)
    sxx = np.bincount(inv, w * (dc[:, 0] ** 2 + L**2 / 12 * u[:, 0] ** 2), G)
    syy = np.bincount(inv, w * (dc[:, 1] ** 2 + L**2 / 12 * u[:, 1] ** 2), G)
    sxy = np.bincount(inv, w * (dc[:, 0] * dc[:, 1] + L**2 / 12 * u[:, 0] * u[:, 1]), G)
    phi = 0.5 * np.arctan2(2 * sxy, sxx - syy)
    dirs = np.stack([np.cos(phi), np.sin(phi)], -1)
    # orient along the fragments' mean direction
    mean_u = np.stack([np.bincount(inv, w * u[:, 0], G), np.bincount(inv, w * u[:, 1], G)], -1)
    dirs *= np.where(np.sum(dirs * mean_u, -1) < 0, -1.0, 1.0)[:, None]
    return inv, m, dirs


def _group_extents(s, m, dirs, inv):
    """One segment (G, 4) per group: its line spanning the projections of its fragments."""
    G = m.shape[0]
    t1 = np.sum((s[:, :2] - m[inv]) * dirs[inv], -1)
    t2 = np.sum((s[:, 2:] - m[inv]) * dirs[inv], -1)
    tmin = np.full(G, np.inf)
    tmax = np.full(G, -np.inf)
    np.minimum.at(tmin, inv, np.minimum(t1, t2))
    np.maximum.at(tmax, inv, np.maximum(t1, t2))
    return np.concatenate([m + tmin[:, None] * dirs, m + tmax[:, None] * dirs], -1)


def merge_collinear(segments, angle_tol_deg=MERGE_ANGLE_TOL_DEG, dist_tol_px=MERGE_DIST_TOL_PX,
                    max_gap_px=RefitOptions.max_gap_px, min_length_px=0.0):
    """Merge oriented fragments that lie on one line, gaps allowed.

    Two fragments join when their oriented directions differ by less than `angle_tol_deg`
    (plus up to 1/L_short rad, at most as much again: a short fragment's own angle is that
    uncertain), both end points of
    the shorter lie within `dist_tol_px` (growing with the extrapolation) of the longer's
    line, and the gap between them along it is at most `max_gap_px`. Joins are transitive
    (connected components); a fragment that ends up farther than 2 `dist_tol_px` from its
    group's line is split off again, so a slow drift cannot chain unrelated fragments.
    Orientation matters: fragments in opposite directions are edges of opposite polarity
    (`orient_by_polarity`) and never merge.

    Parameters
    ----------
    segments : (N, 4) [px]
        Oriented fragments, undistorted pixels (straight lines).
    min_length_px : float
        Fragments shorter than this are ignored (label -1).

    Returns
    -------
    merged : (K, 4) [px]
        One segment per group: the length-weighted total-least-squares line through the
        fragments (each taken as a uniform mass along it), spanning their projections.
    labels : (N,) int
        Group of each fragment (row of `merged`), -1 for ignored fragments.

    Example
    -------
    >>> m, lab = merge_collinear([[0, 0, 40, 0], [55, 0, 100, 0], [100, 10, 0, 10]])
    >>> np.round(m, 6).tolist(), lab.tolist()                     # the third runs the other way
    ([[0.0, 0.0, 100.0, 0.0], [100.0, 10.0, 0.0, 10.0]], [0, 0, 1])
    """
    seg = np.asarray(segments, float).reshape(-1, 4)
    N = seg.shape[0]
    labels = np.full(N, -1)
    p1, u, n, L = _line_frame(seg)
    keep = np.flatnonzero((L >= max(min_length_px, 1e-9)) & np.all(np.isfinite(seg), -1))
    if keep.size == 0:
        return np.zeros((0, 4)), labels
    s, p1, u, n, L = seg[keep], p1[keep], u[keep], n[keep], L[keep]
    c = p1 + 0.5 * L[:, None] * u
    theta = np.arctan2(u[:, 1], u[:, 0])
    tol = np.radians(angle_tol_deg)
    # a short fragment's own angle is uncertain by ~1 px / L: the tolerance grows for it,
    # up to twice the nominal one
    tol_b = tol + np.minimum(1.0 / L, tol)
    pairs = _nearby_pairs(s, u, L, tol, max_gap_px, dist_tol_px)
    i, j = _collinear_pairs(pairs, s, c, u, n, L, theta, tol_b, dist_tol_px, max_gap_px)
    lab = _components(keep.size, i, j)
    inv, m, dirs = _group_lines(lab, c, u, L)
    nd = np.stack([-dirs[:, 1], dirs[:, 0]], -1)
    far = np.maximum(np.abs(np.sum((s[:, :2] - m[inv]) * nd[inv], -1)),
                     np.abs(np.sum((s[:, 2:] - m[inv]) * nd[inv], -1)))
    split = far > 2 * dist_tol_px
    if np.any(split):
        lab = lab.copy()
        lab[split] = lab.max() + 1 + np.arange(int(split.sum()))
        inv, m, dirs = _group_lines(lab, c, u, L)
    labels[keep] = inv
    return _group_extents(s, m, dirs, inv), labels


def _components(n, i, j):
    """The connected components (n,) of the undirected graph on n nodes with edges (i, j),
    numbered as scipy.sparse.csgraph.connected_components numbers them (in the order of
    their lowest node): labels only fall, to the lowest node reachable, by the edges and by
    pointer jumping, until nothing changes (a few passes for the short chains of collinear
    fragments; scipy.sparse would cost a command a third of a second to import).

    >>> _components(6, np.array([0, 3, 4]), np.array([2, 5, 3])).tolist()
    [0, 1, 0, 2, 2, 2]
    """
    lab = np.arange(n)
    i, j = np.asarray(i, int), np.asarray(j, int)
    while i.size:
        low = np.minimum(lab[i], lab[j])
        new = lab.copy()
        np.minimum.at(new, i, low)
        np.minimum.at(new, j, low)
        new = new[new]
        if np.array_equal(new, lab):
            break
        lab = new
    return np.unique(lab, return_inverse=True)[1]


# ============================================================================ pipeline


def in_valid_region(img, raw):
    """(M,) bool: the segments raw (M, 4) [raw px] whose midpoint lies in the interior of the
    valid region of the `GrayImage` img (at least `region.DETECTION_MARGIN_PX` inside its
    boundary): what lies beyond the region or runs along its boundary (a field stop's edge)
    is not kept; an edge that enters the view across the boundary is (a detector's ends are
    a few pixels uncertain, and a refitted line ends where its edge profiles leave the
    region anyway). All True without a region.

    >>> from pencilcal.toolkit.detect.region.valid import ValidRegion
    >>> img = GrayImage(np.zeros((100, 100), np.uint8), ValidRegion.from_circle(50, 50, 40, 100, 100))
    >>> in_valid_region(img, [[20, 50, 80, 50], [50, 5, 50, 60], [10, 51, 11, 60], [0, 0, 5, 5]]).tolist()
    [True, True, False, False]
    """
    raw = np.asarray(raw, float).reshape(-1, 4)
    if img.region is None or raw.shape[0] == 0:
        return np.ones(raw.shape[0], bool)
    mid = 0.5 * (raw[:, :2] + raw[:, 2:])
    return img.in_region(mid[:, 0], mid[:, 1])



def detect_fragments(img, detector, camera, detector_params, min_fragment=4.0, scale=1.0, dark_grow=0, roi=None):
    """The detector's fragments of a `GrayImage`, oriented by polarity, at least
    `min_fragment` [px] long, whose working pixels are finite; with `roi` (x0, y0, x1, y1)
    [raw px, integers, x1 and y1 excluded] the detector sees that part of the image only
    (its fragments in the whole image's pixels).

    With `scale` < 1 the detector runs on the image reduced by that factor (area
    averaging) and its fragments are mapped back to full-resolution pixels: proposals for
    a refit on the full image, which alone sets the accuracy. With `dark_grow` = k > 0 (and
    `scale` < 1) the reduced image is first eroded by a (2k+1)^2 square, which widens dark
    features by k px on each side, and the fragments are moved back by k px towards their
    dark side.

    Returns (raw (N, 4) [raw px], work (N, 4) [working px]).
    """
    x0, y0, x1, y1 = (0, 0, img.shape[1], img.shape[0]) if roi is None else (int(v) for v in roi)
    if scale < 1.0:
        import cv2

        src = img.u8 if roi is None else np.ascontiguousarray(img.u8[y0:y1, x0:x1])
        H, W = src.shape
        if dark_grow > 0:
            src = cv2.erode(src, np.ones((2 * dark_grow + 1, 2 * dark_grow + 1), np.uint8))
        small = cv2.resize(src, (max(int(round(W * scale)), 8), max(int(round(H * scale)), 8)),
                           interpolation=cv2.INTER_AREA)
        sx, sy = W / small.shape[1], H / small.shape[0]
        # pixel centres: x_full + 0.5 = (x_small + 0.5) * s
        raw = (detect_raw(small, detector, detector_params) + 0.5) * np.array([sx, sy, sx, sy]) - 0.5
    else:
        raw = detect_raw(img.u8 if roi is None else np.ascontiguousarray(img.u8[y0:y1, x0:x1]), detector,
                         detector_params)
        dark_grow = 0
    raw = raw + np.array([x0, y0, x0, y0], float)
    L = np.hypot(raw[:, 2] - raw[:, 0], raw[:, 3] - raw[:, 1])
    raw = raw[L >= min_fragment]
    raw, _ = orient_by_polarity(img, raw, 1.0 / min(scale, 1.0))
    if dark_grow > 0 and raw.shape[0]:
        d = raw[:, 2:] - raw[:, :2]
        n = np.stack([-d[:, 1], d[:, 0]], -1) / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)[:, None]
        raw = raw - dark_grow * np.concatenate([n, n], -1)  # n points to the bright side
    work = to_working(camera, raw)
    good = np.all(np.isfinite(work), -1)
    return raw[good], work[good]


def refine_segments(image, segments, camera=None, *, search_px=RefitOptions.search, sigma_px=RefitOptions.sigma_px,
                    step_px=RefitOptions.step_px, max_gap_px=RefitOptions.max_gap_px, extend_px=RefitOptions.extend,
                    min_gradient=RefitOptions.min_gradient, min_length=0.0):
    """Refit given segments (raw pixels) to the image's edges with subpixel precision.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        The image the segments were found in.
    segments : (M, 4) [px]
        Raw pixel segments, each within ~`search_px` of an edge; any orientation.
    camera : Camera, optional
        Fit straight lines in undistorted pixels (the image of a straight edge is curved).
    search_px : float
        Half-width [px] of the search for the edge across the line.
    sigma_px : float
        sd [px] of the Gaussian-derivative kernel across the edge (~ the edge blur).
    step_px : float
        Spacing of the stations along the line [px]; ~2 px keeps them nearly independent
        (each station's bilinear samples reach 1 px to either side).
    max_gap_px : float
        Longest run of stations without edge support [px] inside one segment.
    extend_px : float
        The first pass looks this far beyond each end for the edge to continue.
    min_gradient : float
        Weakest edge accepted at a station [grey levels / px].
    min_length : float
        Shorter refitted segments are dropped [px].

    Returns
    -------
    Segments
        Oriented (bright on the n side), one row per segment that could be refitted, in the
        input order.

    Example
    -------
    >>> img = np.zeros((60, 80), np.float32); img[:, 40:] = 200     # vertical edge at u = 39.5
    >>> r = refine_segments(img, [[41.0, 10.0, 41.0, 50.0]])
    >>> np.round(r.segments[0, [0, 2]], 3).tolist(), bool(r.stations[0] > 10)
    ([39.5, 39.5], True)
    """
    img = GrayImage(image)
    check_camera_image(camera, img)
    seg, _ = orient_by_polarity(img, segments)
    work = to_working(camera, seg)
    opts = RefitOptions(search=search_px, extend=extend_px, sigma_px=sigma_px, step_px=step_px,
                        max_gap_px=max_gap_px, min_gradient=min_gradient)
    return Segments.from_fit(refit_lines(img, work, camera, opts), camera, min_length)


def _merge_refitted(img, camera, fit, opts, angle_tol_deg, dist_tol_px, max_gap_px):
    """Merge refitted lines that turned out to be one edge (`merge_collinear`), and refit
    the merged ones; the others stay as they are (first, in their order)."""
    lines = fit.lines()[fit.ok]
    if lines.shape[0] < 2:
        return fit
    merged, lab = merge_collinear(lines, angle_tol_deg, dist_tol_px, max_gap_px)
    counts = np.bincount(lab[lab >= 0], minlength=merged.shape[0])
    if np.all(counts <= 1):
        return fit
    ok_idx = np.flatnonzero(fit.ok)
    single = ok_idx[counts[lab] == 1]
    fit2 = refit_lines(img, merged[counts > 1], camera, opts)
    return EdgeFit(**{f.name: np.concatenate([getattr(fit, f.name)[single], getattr(fit2, f.name)], 0)
                      for f in fields(EdgeFit)})


def _plain_segments(lines, camera, min_length):
    """The (merged) detector lines (M, 4) [working px] at least min_length long, with the
    end-point noise model of pencil.vertex (ENDPOINT_SIGMA_PX per end point)."""
    L = np.hypot(lines[:, 2] - lines[:, 0], lines[:, 3] - lines[:, 1])
    lines = lines[L >= min_length]
    L = L[L >= min_length]
    z = np.zeros(len(lines))
    return Segments(segments=to_raw(camera, lines), ideal=lines,
                    angle_sigma=segment_angle_sigma(lines, ENDPOINT_SIGMA_PX),
                    offset_sigma=np.full(len(lines), ENDPOINT_SIGMA_PX / np.sqrt(2.0)), length=L, contrast=z,
                    residual_px=z, stations=np.zeros(len(lines), int))


def detect_segments(image, detector="lsd", *, camera=None, min_length=MIN_LENGTH_PX, merge=True, refine=True,
                    angle_tol_deg=MERGE_ANGLE_TOL_DEG, dist_tol_px=MERGE_DIST_TOL_PX,
                    max_gap_px=RefitOptions.max_gap_px, search_px=RefitOptions.search,
                    sigma_px=RefitOptions.sigma_px, step_px=RefitOptions.step_px,
                    min_gradient=RefitOptions.min_gradient, detector_params=None, valid_region=None):
    """Line segments of an image: OpenCV detector, merging, subpixel refit with uncertainty.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        Grey or BGR, 8/16 bit or float.
    detector : {"lsd", "fld", "edlines"}
        The OpenCV detector that proposes fragments (`detect_raw`).
    camera : Camera, optional
        Lens model: lines are merged and fitted straight in undistorted pixels and returned
        in raw pixels (their ends mapped back). Its image size must match the image's.
    min_length : float
        Shortest segment returned [px].
    merge : bool
        Merge collinear fragments first (`merge_collinear` with `angle_tol_deg`,
        `dist_tol_px`, `max_gap_px`); after the refit, lines that turn out to lie on one
        edge are merged again.
    refine : bool
        Refit to the edge pixels (default). False returns the (merged) detector output with
        the end-point model of pencil.vertex (``ENDPOINT_SIGMA_PX`` = 0.5 px per end point)
        for the uncertainty; it is there for comparisons.
    search_px, sigma_px, step_px, min_gradient
        Refit settings, see `refine_segments`.
    detector_params : dict, optional
        Passed to the OpenCV detector (`detect_raw`).
    valid_region : region.ValidRegion, optional
        Where the scene is (a field stop, letterbox bars): edges are measured only on
        profiles inside it (`edges.edge_profiles`), and segments not in it
        (`in_valid_region`) are dropped, so a field stop's edge gives none. None: the image.

    Returns
    -------
    Segments
        Oriented segments (bright side along n = (-d_y, d_x)) with angle and offset sd.

    Example
    -------
    >>> import cv2
    >>> img = np.zeros((200, 300), np.uint8); img[60:140, 50:250] = 180   # a bright box
    >>> segs = detect_segments(cv2.GaussianBlur(img, (0, 0), 1.0), "lsd", min_length=50)
    >>> len(segs), np.round(np.sort(segs.length)).tolist()
    (4, [80.0, 80.0, 200.0, 200.0])
    """
    img = GrayImage(image, valid_region)
    check_camera_image(camera, img)
    _, work = detect_fragments(img, detector, camera, detector_params)
    opts = RefitOptions(search=search_px, sigma_px=sigma_px, step_px=step_px, max_gap_px=max_gap_px,
                        min_gradient=min_gradient)
    lines = merge_collinear(work, angle_tol_deg, dist_tol_px, max_gap_px)[0] if merge else work
    L = np.hypot(lines[:, 2] - lines[:, 0], lines[:, 3] - lines[:, 1])
    # the refit can grow a line by 8 px or more at each end: keep the ones that might make it
    lines = lines[L >= max(0.5 * min_length, min_length - 16.0, 4.0)]
    if not refine:
        out = _plain_segments(lines, camera, min_length)
    else:
        fit = refit_lines(img, lines, camera, opts)
        if merge:
            fit = _merge_refitted(img, camera, fit, opts, min(angle_tol_deg, 1.0), min(dist_tol_px, 1.0), max_gap_px)
        out = Segments.from_fit(fit, camera, min_length)
    return out if img.region is None else out.select(in_valid_region(img, out.segments))

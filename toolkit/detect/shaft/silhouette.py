"""A shaft's silhouette edges at full resolution, in a corridor around a proposed line: the
edge fit of the shaft detector's material cue (`shaft.detector`).

Each edge is proposed by a line in ideal pixels (`shaft.work`: the boundary of a region
found in the reduced work frame, good to about 1.5 work px) with its normal pointing out of
the shaft. At stations along it (at most `MAX_STATIONS`, at least 2 px apart) the colour
profile across it is sampled in the raw image along the image of that normal (`working.
raw_frame`: the lens map's local Jacobian; `edges.SAMPLE_STEP_PX` steps of the ideal
normal), over +-corridor px plus the kernel's reach plus `_STRIP_PX` beyond. It is projected
on the edge's own colour difference ``e = median(colour just outside - just inside)`` and
differentiated with `edges.derivative_kernel` (sd `SIGMA_PX`): a matched response to the
material transition, with its polarity. A sheen edge inside a black shaft is a brightness
step along grey, which projects weakly, and it lies outside the corridor anyway.

Per station the edge is the largest positive local maximum of the response above `Z_999`
noise sd (one-sided 0.999) and `_REL_STRENGTH` of the edge's median (an edge goes on where
its contrast does), refined by a parabola; with the frame's encoding gamma (`fit_edges`) it
is located on the profile linearised (blur acts on linear light: the gradient peak of a
blurred, gamma-encoded edge leans towards its dark side), found where it is as encoded. A station is observable when its whole
profile lies in the image and at least `region.DETECTION_MARGIN_PX` inside the valid
region. The line is the robust weighted fit of the stations' edges (`edges.
robust_line_fit`, weights: the squared response), cut where its ends bend away (a wrist, a
tip: the running median of 9 residuals leaves 3 sd of its own noise for 5 stations; with
a largest gap, the best run of stations), and its
variances are the a-posteriori ones of `edges.fit_variances`: the scatter of the stations
about the line, inflated for correlated station errors (AR(1), batch means).

Ideal pixels throughout (s along the proposed line, t along its outward normal).

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.detect.shaft.work import Validity
>>> img = np.zeros((200, 300, 3), np.uint8); img[:] = (90, 110, 200); img[80:120] = 50
>>> import cv2; img = cv2.GaussianBlur(img, (0, 0), 1.0)
>>> e = fit_edges(img, None, Validity(None, img.shape[:2]), 1.0,
...               [(np.array([10.0, 80.0]), np.array([1.0, 0.0]), np.array([0.0, -1.0]), 0.0, 280.0)], 4.0)[0]
>>> round(float(e.point_at(100.0)[1]), 2), e.count > 100                     # the edge at y = 79.5
(79.5, True)
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.detect.edges import (
    MIN_STATIONS,
    SAMPLE_STEP_PX,
    derivative_kernel,
    fit_variances,
    linearised,
    mean_over,
    peak_near,
    robust_line_fit,
    stations,
)
from pencilcal.toolkit.detect.shaft.regions import Z_999
from pencilcal.toolkit.detect.working import raw_frame
from pencilcal.toolkit.geometry.quantiles import median

__all__ = ["SIGMA_PX", "MAX_STATIONS", "EdgeLine", "fit_edges"]

SIGMA_PX = 1.5  # sd of the Gaussian-derivative kernel [px]
MAX_STATIONS = 160  # stations per edge
_STATION_PX = 2.0  # least spacing of the stations [px]
_STRIP_PX = 3.0  # colour strips this far beyond the corridor give the edge's colour difference [px]
_MARGIN_PX = 2.0  # the profile keeps this far inside the valid region (region.DETECTION_MARGIN_PX)
_REL_STRENGTH = 0.35  # a station's edge at least this fraction of the edge's median strength
_BEND_WIN = 9  # stations of the running median of the residuals (bend cut)


@dataclass(frozen=True, eq=False)
class EdgeLine:
    """One silhouette edge, fitted in ideal pixels: t = tm + b (s - sm), s along u from p0,
    t along n (out of the shaft).

    Attributes
    ----------
    p0, u, n : (2,)
        The frame: a point [px], the unit direction and the unit outward normal.
    sm, tm, b : float
        The weighted centroid of the stations along u [px], the line's offset there [px]
        and its slope.
    var_t, var_b : float
        Variances of tm [px^2] and of b (uncorrelated at sm).
    s_lo, s_hi : float [px]
        The extent of the inlier stations along u.
    count : int
        Inlier stations.
    frac : float
        Inliers over observable stations.
    rms : float [px]
        RMS residual of the inliers.
    """

    p0: np.ndarray
    u: np.ndarray
    n: np.ndarray
    sm: float
    tm: float
    b: float
    var_t: float
    var_b: float
    s_lo: float
    s_hi: float
    count: int
    frac: float
    rms: float

    def point_at(self, s):
        """The edge's point (2,) [ideal px] at s [px] along u."""
        return self.p0 + s * self.u + (self.tm + self.b * (s - self.sm)) * self.n

    def line(self, tm=None, b=None):
        """The homogeneous line (3,) ``a x + b y + c = 0``, a^2 + b^2 = 1 (optionally with
        another offset tm and slope b)."""
        tm = self.tm if tm is None else tm
        b = self.b if b is None else b
        q = self.p0 + self.sm * self.u + tm * self.n
        d = self.u + b * self.n
        nrm = np.array([-d[1], d[0]]) / np.hypot(d[0], d[1])
        return np.array([nrm[0], nrm[1], -float(nrm @ q)])

    def ends(self):
        """(2, 2) [ideal px] the line's points at s_lo and s_hi."""
        return np.stack([self.point_at(self.s_lo), self.point_at(self.s_hi)])


def _samples(image, camera, cx, cy, nx, ny, t):
    """Colour profiles (M, S, T, C) float32 of the raw image at stations (M, S) [ideal px]
    along their ideal normals (M, 1) at offsets t (T,) [px]; and the raw profile ends (M,
    S, 2, 2)."""
    import cv2

    rx, ry, jx, jy = raw_frame(camera, cx, cy, nx, ny)
    X = (rx[..., None] + jx[..., None] * t).astype(np.float32)
    Y = (ry[..., None] + jy[..., None] * t).astype(np.float32)
    ends = np.stack([X[..., ::X.shape[-1] - 1], Y[..., ::X.shape[-1] - 1]], -1)  # (M, S, 2 ends, x y)
    fin = np.isfinite(X) & np.isfinite(Y)
    M, S, T = X.shape
    whole = image.dtype == np.float32 and image.flags.c_contiguous  # a float frame is sampled as it is
    # else only the parts the samples need, as float32 (converting a whole frame costs more)
    groups = [(0, M, (0, image.shape[1], 0, image.shape[0]))] if whole else _crop_groups(ends, image.shape[:2])
    parts = []
    for m0, m1, (x0, x1, y0, y1) in groups:
        crop = image if whole else np.ascontiguousarray(image[y0:y1, x0:x1], dtype=np.float32)
        # shifting by the crop's integer corner is exact in float32 (the coordinates are
        # below 2^24), so each sample reads the same pixels with the same weights as on
        # the whole frame, and the crop's border is the frame's wherever a sample leaves it
        mx = np.where(fin[m0:m1], X[m0:m1] - x0, -1e4).reshape(-1, T)
        my = np.where(fin[m0:m1], Y[m0:m1] - y0, -1e4).reshape(-1, T)
        parts.append(cv2.remap(crop, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE))
    prof = (parts[0] if len(parts) == 1 else np.concatenate(parts)).reshape(M, S, T, -1)
    return prof, ends


#: A crop's fixed cost in pixels converted (`_crop_groups`): a remap call and its crop cost
#: about as much as converting this many more pixels of a larger crop.
_CALL_PX = 12000


def _crop_groups(ends, shape):
    """The edges sampled together, [m0, m1) each, and its crop (x0, x1, y0, y1) of a frame (H, W):
    the bounding box of its finite samples with their bilinear neighbours, from the
    profiles' ends (M, S, 2, 2) (a profile's samples lie on a segment, in float32 too:
    rounding is monotonic). Consecutive edges share a crop where converting the union costs
    less than a crop of their own (`_CALL_PX`): the two edges of a band do, edges across the
    frame do not (their common box would be most of it)."""
    H, W = shape
    M = ends.shape[0]
    big = np.float32(np.inf)
    fin = np.all(np.isfinite(ends), -1).reshape(M, -1)
    E = ends.reshape(M, -1, 2)
    # per edge, in Python floats (a few edges: numpy's scalar overheads would be the cost)
    lo_x, hi_x = np.where(fin, E[..., 0], big).min(1).tolist(), np.where(fin, E[..., 0], -big).max(1).tolist()
    lo_y, hi_y = np.where(fin, E[..., 1], big).min(1).tolist(), np.where(fin, E[..., 1], -big).max(1).tolist()
    seen = fin.any(1).tolist()

    def box(m0, m1):
        if not any(seen[m0:m1]):
            return 0, W, 0, H
        x0 = min(max(math.floor(min(lo_x[m0:m1])) - 1, 0), W - 1)
        x1 = min(max(math.ceil(max(hi_x[m0:m1])) + 2, x0 + 1), W)
        y0 = min(max(math.floor(min(lo_y[m0:m1])) - 1, 0), H - 1)
        y1 = min(max(math.ceil(max(hi_y[m0:m1])) + 2, y0 + 1), H)
        return x0, x1, y0, y1

    def area(b):
        return (b[1] - b[0]) * (b[3] - b[2])

    starts, boxes = [0], [box(0, 1)]
    for m in range(1, M):
        own, both = box(m, m + 1), box(starts[-1], m + 1)
        if area(both) <= area(boxes[-1]) + area(own) + _CALL_PX:
            boxes[-1] = both
        else:
            starts.append(m)
            boxes.append(own)
    return list(zip(starts, starts[1:] + [M], boxes))


def _peaks(g, thr, inside, allowed):
    """Per station of the responses g (M, S, nwin): the largest positive local maximum above
    thr where allowed (M, 1, nwin) (each edge's corridor), refined by a parabola. Returns t_idx (M, S) [samples, fractional] and strength (M,
    S), found (M, S) bool."""
    pk = np.zeros(g.shape, bool)
    pk[..., 1:-1] = (g[..., 1:-1] >= g[..., :-2]) & (g[..., 1:-1] > g[..., 2:]) & (g[..., 1:-1] > thr)
    gm = np.where(pk & allowed, g, -np.inf)
    jm = np.argmax(gm, -1)
    a0 = np.take_along_axis(gm, jm[..., None], -1)[..., 0]
    found = np.isfinite(a0) & inside
    jm = np.clip(jm, 1, g.shape[-1] - 2)
    am = np.take_along_axis(g, (jm - 1)[..., None], -1)[..., 0]
    ac = np.take_along_axis(g, jm[..., None], -1)[..., 0]
    ap = np.take_along_axis(g, (jm + 1)[..., None], -1)[..., 0]
    den = am - 2 * ac + ap
    with np.errstate(all="ignore"):
        off = np.where(den < 0, 0.5 * (am - ap) / np.where(den < 0, den, -1.0), 0.0)
    return jm + np.clip(off, -0.5, 0.5), np.where(found, ac, 0.0), found


def _linear_peaks(prof, e, kern, j, gamma):
    """The subpixel peaks (M, S) [samples] of the responses of the profiles (M, S, T, C)
    linearised (`edges.linearised`) and projected on the colour differences e (M, S, C),
    each the local maximum the encoded response's peak j (M, S) climbs to
    (`edges.peak_near`), refined by a parabola (as `_peaks`); and whether that climb ended
    on a peak (M, S) bool (where not, the station has no edge)."""
    pe = np.einsum("mstc,msc->mst", linearised(prof, gamma), e.astype(np.float32))
    nwin = pe.shape[-1] - kern.size + 1
    g = kern[0] * pe[..., :nwin]
    for q in range(1, kern.size):
        g += kern[q] * pe[..., q:q + nwin]
    g2 = g.reshape(-1, nwin)
    jm, top = peak_near(g2, np.clip(np.rint(j), 1, nwin - 2).astype(int).reshape(-1))
    rr = np.arange(g2.shape[0])
    am, ac, ap = (g2[rr, jm + o].astype(float) for o in (-1, 0, 1))
    den = am - 2 * ac + ap
    with np.errstate(all="ignore"):
        off = np.where(den < 0, 0.5 * (am - ap) / np.where(den < 0, den, -1.0), 0.0)
    return (jm + np.clip(off, -0.5, 0.5)).reshape(j.shape), top.reshape(j.shape)


@functools.lru_cache(maxsize=1024)
def _window_index(n):
    """The indices (n, `_BEND_WIN`) of each of n stations' window, the ends repeated: made once
    per n (read-only; a frame's edges have a few station counts)."""
    h = _BEND_WIN // 2
    idx = np.clip(np.arange(n)[:, None] + np.arange(-h, h + 1)[None, :], 0, n - 1)
    idx.flags.writeable = False
    return idx


def _running_median(x, axis):
    """The median of every `_BEND_WIN` (odd) neighbours along `axis`, the ends repeated:
    scipy.ndimage.median_filter's with mode "nearest", in numpy (the same values, without
    importing scipy.ndimage at the first frame).

    >>> x = np.random.default_rng(0).normal(size=(3, 20, 2))
    >>> win = np.lib.stride_tricks.sliding_window_view(np.pad(x, [(0, 0), (4, 4), (0, 0)], mode="edge"), 9, axis=1)
    >>> bool(np.array_equal(_running_median(x, 1), np.median(win, axis=-1)))
    True
    """
    h = _BEND_WIN // 2
    # the windows gathered with the ends repeated (np.pad's "edge"), the window axis after
    # `axis`; of an odd count the median is the middle order statistic (np.median's value,
    # without its mean and NaN checks)
    win = np.take(x, _window_index(x.shape[axis]), axis=axis)
    return np.take(np.partition(win, h, axis=axis + 1), h, axis=axis + 1)


def _bend_cut(s, res, inl):
    """Inliers (S,) of one edge without the ends that bend away from its line: where the
    running median of `_BEND_WIN` residuals leaves 3 sd of its own noise for at least half
    the window, the edge is cut, keeping the straight stretch around its middle; None when
    less than `MIN_STATIONS` stations stay."""
    idx = np.flatnonzero(inl)
    if idx.size < 3 * _BEND_WIN:
        return inl
    r = res[idx]
    rc = r - r.mean()
    rho = float(np.clip(np.sum(rc[1:] * rc[:-1]) / max(np.sum(rc * rc), 1e-12), 0.0, 0.9))
    sd_t = 1.2533 * np.sqrt(np.mean(r * r) * (1 + rho) / (1 - rho) / _BEND_WIN)
    bad = np.abs(_running_median(r, 0)) > 3.0 * sd_t
    if not bad.any():
        return inl
    run = np.convolve(bad.astype(float), np.ones(_BEND_WIN // 2 + 1), "same") >= _BEND_WIN // 2 + 1
    c = idx.size // 2
    lo, hi = c, c
    while lo > 0 and not run[lo - 1]:
        lo -= 1
    while hi < idx.size - 1 and not run[hi + 1]:
        hi += 1
    if hi - lo + 1 < MIN_STATIONS:
        return None
    out = np.zeros_like(inl)
    out[idx[lo:hi + 1]] = True
    return out


def _line_fits(s, t, w, base, count_obs, specs, max_gap):
    """Robust line fits of the stations (M, S) (the best run with gaps up to max_gap (M, 1)
    [px], or all with None) with the bend cut, and their variances: one `EdgeLine` (or None)
    per spec."""
    sm, tm, b, Sss, Wt, res, inl = robust_line_fit(s, t, w, base, max_gap)
    cut = inl.copy()
    ok = inl.sum(-1) >= MIN_STATIONS
    for m in np.flatnonzero(ok):
        c = _bend_cut(s[m], res[m], inl[m])
        if c is None:
            ok[m] = False
        else:
            cut[m] = c
    changed = ok & np.any(cut != inl, -1)
    if np.any(changed):
        got = robust_line_fit(s[changed], t[changed], w[changed], cut[changed],
                              None if max_gap is None else max_gap[changed])
        for arr, new in zip((sm, tm, b, Sss, Wt, res, inl), got):
            arr[changed] = new
    var_b, var_t = fit_variances(res, w, inl, Sss, Wt)
    out = []
    for m, (p0, u, n, _, _) in enumerate(specs):
        k = int(inl[m].sum())
        if not ok[m] or k < MIN_STATIONS:
            out.append(None)
            continue
        sv = s[m][inl[m]]
        out.append(EdgeLine(p0=np.asarray(p0, float), u=np.asarray(u, float), n=np.asarray(n, float),
                            sm=float(sm[m]), tm=float(tm[m]), b=float(b[m]), var_t=float(var_t[m]),
                            var_b=float(var_b[m]), s_lo=float(sv.min()), s_hi=float(sv.max()), count=k,
                            frac=k / max(int(count_obs[m]), 1),
                            rms=float(np.sqrt(np.mean(res[m][inl[m]] ** 2)))))
    return out


def _inside_median(d, inside):
    """The median (M, C) of d (M, S, C) over the stations inside (M, S) bool, 0 for an edge
    with none: np.nanmedian's value with the others NaN (the mean of the middle two sorted,
    NaN last), without its masked-array route (most of the edge fit's time).

    >>> rng = np.random.default_rng(1)
    >>> d = rng.normal(size=(5, 12, 3)).astype(np.float32)
    >>> ins = rng.random((5, 12)) < 0.5; ins[1, :7] = True; ins[0] = False
    >>> got = _inside_median(d, ins)
    >>> bool(np.array_equal(got[1:], np.nanmedian(np.where(ins[1:, :, None], d[1:], np.nan), axis=1))), got[0].tolist()
    (True, [0.0, 0.0, 0.0])
    """
    V = np.sort(np.where(inside[..., None], d, np.nan), axis=1)
    n = inside.sum(1)[:, None, None]
    h = n // 2
    lo = np.maximum(np.where(n % 2 == 1, h, h - 1), 0)
    pair = np.take_along_axis(V, np.concatenate([lo, np.minimum(h, V.shape[1] - 1)], 1), axis=1)
    return np.where(n[:, 0] > 0, (pair[:, 0] + pair[:, 1]) / 2, 0)


def _projected(prof, e):
    """``np.einsum("mstc,msc->mst", prof, e)`` of profiles (M, S, T, C) and colour directions
    (M, S, C), both float32: the same values (the channels' products added in their order, in
    float32), as C whole-array products, a third of einsum's cost.

    >>> rng = np.random.default_rng(0)
    >>> p, e = rng.random((4, 9, 30, 3)).astype(np.float32), rng.normal(size=(4, 9, 3)).astype(np.float32)
    >>> bool(np.array_equal(_projected(p, e), np.einsum("mstc,msc->mst", p, e)))
    True
    """
    out = prof[..., 0] * e[:, :, None, 0]
    for c in range(1, prof.shape[-1]):
        out += prof[..., c] * e[:, :, None, c]
    return out


def _colour_difference(prof, inside, mc):
    """The unit colour difference (M, S, C) of each station's edge: outside minus inside
    (means of the `_STRIP_PX` strips beyond the corridor), the running median over
    `_BEND_WIN` stations (what lies beside a shaft changes along it: tissue, then a drape),
    the edge's median where a station has none."""
    d = mean_over(prof, 2, -mc) - mean_over(prof, 2, 0, mc)  # (M, S, C), `edges.mean_over`
    glob = _inside_median(d, inside)  # (M, C)
    d = np.where(inside[..., None], d, glob[:, None, :])
    out = _running_median(d, 1)
    return out / np.maximum(np.linalg.norm(out, axis=-1, keepdims=True), 1e-9)


def fit_edges(image, camera, validity, noise, specs, corridor, max_gap=None, gamma=1.0):
    """Silhouette edges at full resolution in corridors around proposed lines (module
    docstring).

    Parameters
    ----------
    image : (H, W, 3) or (H, W) array
        The raw frame (a contiguous float32 one is sampled without a copy: convert once
        for several calls).
    camera : Camera or None
    validity : shaft.work.Validity
        Where the image may be sampled.
    noise : float [grey levels]
        The image noise sd (per channel).
    specs : list of (p0 (2,), u (2,), n (2,), s0, s1)
        Each proposed edge: a point [ideal px], its unit direction and unit outward normal,
        and the range [s0, s1] [px] along u to measure.
    corridor : float or (M,) [px]
        Half-width of the search across each proposed line.
    max_gap : float or (M,) [px], optional
        Each edge is the best run of stations with gaps up to this (None: all stations).
    gamma : float
        The frame's encoding gamma (`edges.linearised`). Other than 1, each station's edge
        is found on the profile as sampled (its peak above the noise, its strength: the
        weights) and located on the profile linearised: the peak of that one's response
        the encoded one's climbs to (`edges.peak_near`), refined there.

    Returns
    -------
    list of EdgeLine or None
        One per spec (None: too few stations with an edge).
    """
    if not specs:
        return []
    kern, r = derivative_kernel(SIGMA_PX)
    DT = SAMPLE_STEP_PX
    corr = np.broadcast_to(np.asarray(corridor, float), (len(specs),))
    nw, mc = int(np.ceil(corr.max() / DT)), int(np.ceil(_STRIP_PX / DT))
    half = nw + r + mc
    t = np.arange(-half, half + 1) * DT
    lo = np.array([sp[3] for sp in specs], float)
    hi = np.array([sp[4] for sp in specs], float)
    cnt = np.clip(np.round((hi - lo) / _STATION_PX).astype(int) + 1, MIN_STATIONS + 2, MAX_STATIONS)
    s, st_valid = stations(lo, hi, cnt)
    P0 = np.array([sp[0] for sp in specs], float)
    U = np.array([sp[1] for sp in specs], float)
    Nn = np.array([sp[2] for sp in specs], float)
    # stations on the proposed line; the profiles along the outward normal
    cx = P0[:, 0, None] + s * U[:, 0, None]
    cy = P0[:, 1, None] + s * U[:, 1, None]
    prof, ends = _samples(image, camera, cx, cy, Nn[:, 0, None], Nn[:, 1, None], t)
    inside = st_valid & np.all(validity.ok(ends, _MARGIN_PX), -1)
    e = _colour_difference(prof, inside, mc)
    pe = _projected(prof, e.astype(np.float32))
    nwin = 2 * nw + 1
    g = kern[0] * pe[..., mc:mc + nwin]
    for q in range(1, kern.size):
        g += kern[q] * pe[..., mc + q:mc + q + nwin]
    thr = Z_999 * noise * float(np.sqrt(np.sum(kern.astype(float) ** 2)))
    allowed = (np.abs(np.arange(nwin) - nw) * DT)[None, None, :] <= corr[:, None, None]
    j, strength, found = _peaks(g, thr, inside, allowed)
    if gamma != 1.0:  # located on linear light (the docstring)
        j, top = _linear_peaks(prof[:, :, mc:mc + nwin + kern.size - 1], e, kern, j, gamma)
        found &= top
    # an edge goes on where its contrast does: a station's peak at least _REL_STRENGTH of the
    # edge's median (texture beside a shaft's end gives weaker peaks)
    med = np.array([median(strength[m][found[m]]) if found[m].any() else 0.0 for m in range(len(specs))])
    found &= strength >= _REL_STRENGTH * med[:, None]
    tt = (j - nw) * DT
    with np.errstate(over="ignore"):  # an edge without a found station has no median
        w = np.where(found, (strength / np.maximum(med, 1e-300)[:, None]) ** 2, 0.0)
    gap = None if max_gap is None else np.broadcast_to(np.asarray(max_gap, float), (len(specs),))[:, None]
    return _line_fits(s, tt, w, found, inside.sum(-1), specs, gap)

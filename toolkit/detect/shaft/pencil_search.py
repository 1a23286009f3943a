"""The shaft found by its angle about a known fulcrum image: the search of an `AxisPrior`.

An instrument pivoting about a port images as a band whose axis passes through the port's
image X (`shaft.prior`). Resampled on circles about X (*pencil coordinates*: rows at radii
rho from X, columns at angles phi about it, one work pixel apart at the farthest radius),
every line through X is a column, and such a band is a stripe centred on one column, as wide
as the shaft (w / rho in angle). Its edges are the only structure of the scene that keeps
a pair of opposite gradients centred on one column from row to row: tissue bands, folds
and drapes cross the columns obliquely. So:

1. *pairs*: in the reduced, undistorted work frame (`shaft.work.WorkFrame`), its
   instrument-likeness where the frame has a colour (`shaft.regions.material_map`: grey,
   black and metal against tissue; a pale fold keeps the tissue's colour), else its luma,
   resampled in pencil coordinates; per row, the gradient across the columns (a Gaussian
   derivative, sd `_SIGMA_COLS` columns, in grey levels per work px), its local maxima
   above `_Z_PEAK` noise sd (the `_PEAKS` strongest), and every pair of them of opposite
   sign (a band darker or brighter than both sides; more instrument-like than both, on
   the likeness) whose width is a shaft's, weighted by the weaker one's gradient;
2. *votes*: each pair votes for its centre column and its width (bins of `_WIDTH_STEP`),
   and the angle with most votes (smoothed over neighbouring widths: the band narrows
   along the shaft in perspective) is the shaft's. Where X itself is uncertain (the
   prior's sd across the lines, `AxisPrior.offset_sigma`), a line through a point delta
   beside X moves by delta / rho in angle: the votes are also counted for shifts delta
   within 3 sd (`_MAX_SHIFTS` of them), the best kept. A shaft pointing at or away from
   the camera from a port near the view images as a cone whose width grows with rho while
   its angle about X stays: the pairs vote a second time by their width in columns, each
   peak of that vote suppressing its neighbouring columns at its own widths only (a bright
   tip beyond the cone, on the same line through X, must not take the column from it);
3. *band*: the pairs near the winning centre and width, the best per row, over the heaviest
   run of rows with gaps up to `_GAP_ROWS`. On the instrument-likeness a band gives way to the
   outermost pair of edges around it whose inside beside it is instrument too (`_outermost`:
   a highlight stripe along a matte shaft, or the matte part beside it, is a band of its own
   that the vote may prefer to the shaft's). Each side's points fitted by a line, extended along
   it while the band's cross-section goes on looking like its run's, refitted at full
   resolution in a corridor of 2 work px (`shaft.silhouette.fit_edges`, as the material
   cue's edges) and the midline their plane bisector (`shaft.axis`). Kept where
   both edges are seen together along 1.5 widths at least and the band reaches the border
   of the view (an instrument enters from outside), or along one width where it runs from
   X itself (`_ends_at`: a port in view, where the instrument enters), `_entering`. Only
   where no band of the vote by widths is kept so, a band of either vote is kept that is
   seen along half a width (close to the camera a shaft's visible part is short and wide)
   and reaches the border, or runs from X, or is joined to the border by instrument
   material along its line towards X (`_joins_border`: a distal part whose band stops at
   its collar, the shaft running on), `_entering_close`: these looser rules find shafts
   close to the camera or along its line of sight without changing a frame where a long
   band enters the view. The score is the length seen [raw px] times the least fraction
   of stations with an edge.

The thresholds are looser than the cues' (one pair of edges over a short run is enough):
the prior does what the cues' elongation and material tests do, and every result is then
gated by the prior (`shaft.prior.select_through`). A point at infinity, or so far that the
circles are straight (beyond `_FAR` image diagonals), is searched on parallel lines.

Work pixels throughout, ideal pixels from the edges on.

Example
-------
>>> import numpy as np, cv2
>>> from pencilcal.toolkit.detect.shaft.prior import AxisPrior
>>> from pencilcal.toolkit.detect.shaft.detector import detect_shafts
>>> img = np.full((240, 320, 3), (120, 140, 190), np.uint8)                  # pink "tissue"
>>> _ = cv2.fillConvexPoly(img, np.array([[319, 90], [319, 130], [120, 125], [120, 105]], np.int32), (40, 40, 40))
>>> prior = AxisPrior.from_point([-200.0, 115.0], np.eye(2) * 4.0)           # the port, left of the view
>>> sh = detect_shafts(cv2.GaussianBlur(img, (0, 0), 1.0), axis_prior=prior, min_length=80)
>>> len(sh), sh[0].cue in ("material", "prior")
(1, True)
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.shaft.axis import midline_from_edges
from pencilcal.toolkit.detect.shaft.silhouette import fit_edges
from pencilcal.toolkit.geometry.projective import line_meet, line_through

__all__ = ["pencil_search"]

_SIGMA_COLS = 1.0  # sd of the derivative across the columns [columns]
_Z_PEAK = 3.0  # a gradient peak exceeds this many noise sd
_Z_CAP = 1e9  # a pair's vote is at most this
_PEAKS = 40  # strongest peaks per row
_WIDTH_STEP = 0.05  # relative width of a vote's bin
_WIDTH_TOL = 0.2  # a pair belongs to a band within this relative width (perspective)
_MAX_SHIFTS = 25  # shifts of the line beside X tried at most
_ROW_STEP = 2.0  # rows (radii) this far apart [work px]
_MAX_COLS = 2048  # columns at most
_MIN_ROWS = 6  # a band seen at fewer rows is none
_GAP_ROWS = 4  # a band's run bridges gaps of up to this many rows
_INSIDE_FRACTION = 0.7  # a band's inside lies on its side of the halfway level at least so much
_MIN_WIDTHS = 1.5  # a band seen along fewer widths is none ...
_MIN_WIDTHS_AT_PORT = 1.0  # ... or, running from the prior's point (`_ends_at`), fewer than this ...
_MIN_WIDTHS_CLOSE = 0.5  # ... or, where no band is that long (`_entering_close`), fewer than this
_MAX_CONVERGENCE_AT_PORT_DEG = 45.0  # a band from the prior's point converges at most so much (either way)
_JOIN_FRACTION = 0.8  # a band joins the border through instrument material along this much of the way
_WIDER = 1.15  # an enclosing pair is at least this much wider than the band it encloses ...
_ENCLOSE_COLS = 1.0  # ... and reaches to within this many columns of the band's edges at least
_ONE_INSTRUMENT = 0.5  # the inside beside an enclosed band lies this far from the sides towards its level at least
_OUTWARD_STEPS = 3  # enclosing bands looked for in turn at most
_PEAK_CANDIDATES = 16  # vote peaks looked at
_CANDIDATES = 3  # bands measured at full resolution at most
_FAR = 1e4  # beyond this many work-frame diagonals a point is at infinity
_CORRIDOR_WORK = 2.0  # the full-resolution corridor [work px]


class _Grid:
    """Pencil coordinates about X in a work frame (module docstring): maps (rows, cols) of
    work-frame coordinates, the spacing of the columns per row [work px per column], and
    the shift of a line beside X per unit of that shift [columns] per row (``1 / (rho
    dphi)``; parallel lines: the tilt's, per radian)."""

    def __init__(self, X, shape, diag):
        h, w = shape
        corners = np.array([[0.0, 0.0], [w - 1.0, 0.0], [0.0, h - 1.0], [w - 1.0, h - 1.0]])
        centre = corners.mean(0)
        far = abs(X[2]) < 1e-12 or np.linalg.norm(X[:2] / X[2] - centre) > _FAR * diag
        if far:
            u = X[:2] / np.linalg.norm(X[:2])
            n = np.array([-u[1], u[0]])
            s = (corners - centre) @ u
            t = (corners - centre) @ n
            rows = np.arange(s.min(), s.max() + _ROW_STEP, _ROW_STEP)
            cols = np.arange(t.min(), t.max() + 1.0, 1.0)[:_MAX_COLS]
            pts = centre + rows[:, None, None] * u + cols[None, :, None] * n
            self.spacing = np.ones(rows.size)
            self.shift = rows - rows.mean()
            self.radius = rows - rows.min()
        else:
            x = X[:2] / X[2]
            d = corners - x
            inside = (0 <= x[0] <= w - 1) and (0 <= x[1] <= h - 1)
            rmax = float(np.max(np.linalg.norm(d, axis=1)))
            if inside:
                rmin, a0, a1 = 2.0, -np.pi, np.pi
            else:
                rmin = float(np.linalg.norm(np.clip(x, 0, [w - 1, h - 1]) - x))
                ac = np.arctan2(*(centre - x)[::-1])
                rel = np.angle(np.exp(1j * (np.arctan2(d[:, 1], d[:, 0]) - ac)))
                a0, a1 = ac + rel.min(), ac + rel.max()
            dphi = max(1.0 / rmax, (a1 - a0) / _MAX_COLS)
            phi = np.arange(a0, a1, dphi)
            rho = np.arange(max(rmin, 1.0), rmax + _ROW_STEP, _ROW_STEP)
            pts = x + rho[:, None, None] * np.stack([np.cos(phi), np.sin(phi)], -1)[None]
            self.spacing = rho * dphi
            self.shift = 1.0 / self.spacing
            self.radius = rho
        self.far = far
        self.pts = pts
        self.mx = pts[..., 0].astype(np.float32)
        self.my = pts[..., 1].astype(np.float32)

    def sample(self, im):
        import cv2

        return cv2.remap(np.ascontiguousarray(im, np.float32), self.mx, self.my, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)

    def point(self, row, col):
        """Work-frame points (..., 2) at fractional columns of integer rows."""
        c0 = np.clip(np.floor(col).astype(int), 0, self.pts.shape[1] - 2)
        f = (col - c0)[..., None]
        return (1.0 - f) * self.pts[row, c0] + f * self.pts[row, c0 + 1]


def _pairs(grid, P, D, noise, wmin, wmax, bright_only):
    """Step 1: (row, left col, right col, centre col, width [work px], weight, dark) of every
    pair of opposite gradient peaks at a shaft's width in the resampled channel P (rows,
    cols) (D: the distance to the view's border there); bright_only: only bands above
    both sides (the instrument-likeness)."""
    import cv2

    r = int(np.ceil(3 * _SIGMA_COLS))
    x = np.arange(-r, r + 1, dtype=np.float32)
    k = -x * np.exp(-0.5 * (x / _SIGMA_COLS) ** 2)
    k /= np.sum(x * k)
    g = cv2.filter2D(P, cv2.CV_32F, k[None, :], borderType=cv2.BORDER_REPLICATE)  # grey levels per column
    ok = cv2.erode((D >= 2.0).astype(np.uint8), np.ones((1, 2 * r + 3), np.uint8)) > 0
    z = np.abs(g) / (noise * float(np.linalg.norm(k)))
    mx = cv2.dilate(z, np.ones((1, 5), np.uint8))
    zp = np.where(ok & (z >= mx) & (z >= _Z_PEAK), z, 0.0)
    idx = np.sort(np.argsort(-zp, axis=1, kind="stable")[:, :_PEAKS], axis=1)
    rows = np.arange(P.shape[0])[:, None]
    zs, sg = zp[rows, idx], np.sign(g[rows, idx])
    valid = zs > 0
    wd = (idx[:, None, :] - idx[:, :, None]) * grid.spacing[:, None, None]  # [row, i, j]
    good = valid[:, :, None] & valid[:, None, :] & (sg[:, :, None] * sg[:, None, :] < 0) & (wd >= wmin) & (wd <= wmax)
    if bright_only:
        good &= (sg > 0)[:, :, None]
    R, I, J = np.nonzero(good)
    ci, cj = idx[R, I].astype(float), idx[R, J].astype(float)
    return (R, ci, cj, 0.5 * (ci + cj), wd[R, I, J], np.minimum(np.minimum(zs[R, I], zs[R, J]), _Z_CAP),
            sg[R, I] < 0)


def _votes(grid, pairs, shifts, wmin, ncols):
    """Step 2: the accumulators (shifts, columns, width bins) of the pairs' votes, and each
    pair's width bin."""
    import cv2

    R, _, _, c, wd, wt, _ = pairs
    nb = int(np.ceil(np.log(max(wd.max(), wmin * 1.01) / wmin) / np.log1p(_WIDTH_STEP))) + 2
    b = np.clip(np.rint(np.log(wd / wmin) / np.log1p(_WIDTH_STEP)).astype(int), 0, nb - 1)
    A = np.zeros((len(shifts), ncols, nb), np.float32)
    tol = max(1, int(round(_WIDTH_TOL / _WIDTH_STEP / 2)))
    for q, dl in enumerate(shifts):
        cc = np.rint(c - dl * grid.shift[R]).astype(int)
        inb = (cc >= 0) & (cc < ncols)
        acc = np.bincount(cc[inb] * nb + b[inb], wt[inb], ncols * nb).reshape(ncols, nb).astype(np.float32)
        A[q] = cv2.blur(acc, (2 * tol + 1, 3), borderType=cv2.BORDER_CONSTANT)
    return A, b


def _peaks(A, wmin, own_widths=False):
    """The best (shift index, column, width bin) of the accumulators, up to
    `_PEAK_CANDIDATES`, each suppressing the columns within half its width (at every width;
    own_widths: at its own widths only)."""
    out = []
    A = A.copy()
    mean_w = np.exp(np.arange(A.shape[2]) * np.log1p(_WIDTH_STEP)) * wmin
    tol = int(round(_WIDTH_TOL / _WIDTH_STEP))
    for _ in range(_PEAK_CANDIDATES):
        q, c, b = np.unravel_index(int(np.argmax(A)), A.shape)
        if A[q, c, b] <= 0:
            break
        out.append((int(q), int(c), int(b)))
        half = int(np.ceil(0.5 * mean_w[b])) + 1
        A[:, max(c - half, 0):c + half + 1, max(b - tol, 0) if own_widths else 0:b + tol + 1 if own_widths else None] = 0
    return out


def _line_fit(P):
    """(point (2,), unit direction (2,), inliers (N,) bool) of the total least-squares line
    through P (N, 2), refitted without the points beyond 3 MADs (and 0.5 px)."""
    keep = np.ones(P.shape[0], bool)
    for _ in range(3):
        c = P[keep].mean(0)
        _, V = np.linalg.eigh(np.cov((P[keep] - c).T))
        u = V[:, 1]
        r = (P - c) @ np.array([-u[1], u[0]])
        mad = 1.4826 * np.median(np.abs(r[keep] - np.median(r[keep]))) + 1e-6
        new = np.abs(r) <= 3 * mad + 0.5
        if new.sum() < 3 or np.array_equal(new, keep):
            break
        keep = new
    return c, u, keep


def _inside_ok(P, D, pairs, sel):
    """(sel,) bool: the inside of each pair `sel` is a band's: darker (brighter) than both
    sides, and `_INSIDE_FRACTION` of its inner 80 % on its side of the level halfway to the
    nearer side's (a specular stripe along a black shaft is allowed; tissue between two
    unrelated edges is as bright as around them)."""
    R, ci, cj, _, _, _, dark = pairs
    out = np.zeros(sel.size, bool)
    for q, k in enumerate(sel):
        a, b = ci[k], cj[k]
        w = b - a
        row, seen = P[R[k]], D[R[k]] >= 0
        i0, i1 = int(np.ceil(a + 0.1 * w)), int(np.floor(b - 0.1 * w)) + 1
        side = max(2, int(0.3 * w))
        l0, l1, r0, r1 = max(int(a) - 1 - side, 0), max(int(a) - 1, 0), int(b) + 2, int(b) + 2 + side
        inner, left, right = row[i0:i1][seen[i0:i1]], row[l0:l1][seen[l0:l1]], row[r0:r1][seen[r0:r1]]
        if inner.size < 2 or left.size < 1 or right.size < 1:
            continue
        m, l_, r_ = float(np.median(inner)), float(np.median(left)), float(np.median(right))
        sgn = 1.0 if dark[k] else -1.0
        near = min(sgn * l_, sgn * r_)  # the nearer side's level, signed so that the band lies below it
        if near - sgn * m <= 0:
            continue
        out[q] = float(np.mean(sgn * inner < 0.5 * (near + sgn * m))) >= _INSIDE_FRACTION
    return out


def _band_points(grid, P, D, pairs, b_of, c, b, shift):
    """Step 3: the best pair per row near a peak (column c, width bin b, shift) whose inside
    is a band's (`_inside_ok`), over the run of rows (gaps up to `_GAP_ROWS`) of largest weight, its two
    sides' points on two lines: (rows, left cols, right cols, dark, weight) or None."""
    R, ci, cj, cc, wd, wt, dark = pairs
    near = (np.abs(cc - shift * grid.shift[R] - c) <= 1.5 + 0.05 * (cj - ci)) & \
        (np.abs(b_of - b) <= int(round(_WIDTH_TOL / _WIDTH_STEP)))
    idx = np.flatnonzero(near)
    if idx.size < _MIN_ROWS:
        return None
    order = idx[np.lexsort((-wt[idx], R[idx]))]
    best = order[np.r_[True, R[order][1:] != R[order][:-1]]]  # the heaviest pair of each row
    best = best[_inside_ok(P, D, pairs, best)]
    if best.size < _MIN_ROWS:
        return None
    rows = R[best]
    cut = np.flatnonzero(np.diff(rows) > _GAP_ROWS)
    starts, ends = np.r_[0, cut + 1], np.r_[cut + 1, rows.size]
    k = int(np.argmax([np.sum(wt[best[a:e]]) for a, e in zip(starts, ends)]))
    sel = best[starts[k]:ends[k]]
    if sel.size < _MIN_ROWS:
        return None
    keep = np.ones(sel.size, bool)
    for col in (ci, cj):
        keep &= _line_fit(grid.point(R[sel], col[sel]))[2]
    sel = sel[keep]
    if sel.size < _MIN_ROWS:
        return None
    return R[sel], ci[sel], cj[sel], bool(np.mean(dark[sel]) > 0.5), float(np.sum(wt[sel]))


def _one_instrument(P, D, pairs, idx, lo, hi):
    """(idx.size,) bool: whether the inside of each enclosing pair `idx` is one instrument with
    the band it encloses (columns lo to hi on its row): beside the band, each part of its
    inside (median) lies `_ONE_INSTRUMENT` of the way from the nearer of its own two sides
    (a fifth to a third of its width beyond its edges, as `_inside_ok`) to the band's level
    at least (a shaft's matte part beside a highlight along it, a collar beside a
    highlight; not a fold of tissue or a shadow beside the shaft)."""
    R, ci, cj, _, _, _, dark = pairs
    out = np.zeros(idx.size, bool)
    for q, k in enumerate(idx):
        row, seen = P[R[k]], D[R[k]] >= 0
        a, b, w = ci[k], cj[k], cj[k] - ci[k]
        sgn = -1.0 if dark[k] else 1.0  # the band above its sides in sgn * P

        def level(i0, i1):
            i0, i1 = max(int(i0), 0), min(int(i1), row.size)
            v = row[i0:i1][seen[i0:i1]]
            return float(np.median(sgn * v)) if v.size >= 2 else None

        side = max(2, int(0.3 * w))
        sides = [level(a - 1 - side, a - 1), level(b + 2, b + 2 + side)]
        band = level(np.ceil(lo[q]) + 1, np.floor(hi[q]))
        if None in sides or band is None or band <= max(sides):
            continue
        near = max(sides)
        parts = [level(np.ceil(a) + 2, np.floor(lo[q]) - 1), level(np.ceil(hi[q]) + 2, np.floor(b) - 1)]
        parts = [v for v in parts if v is not None]
        out[q] = bool(parts) and all(v - near >= _ONE_INSTRUMENT * (band - near) for v in parts)
    return out


def _outermost(grid, P, D, pairs, band, lo, shift):
    """The outermost band whose inside is one instrument with a band (`_band_points`) or the
    band itself: pairs at least `_WIDER` wider, reaching past its edges (within
    `_ENCLOSE_COLS`) on its rows, whose inside beside it is instrument too
    (`_one_instrument`), voted on and measured as a band of their own (`_band_points`, at
    the band's shift) sharing half its rows at least; again from that one, up to
    `_OUTWARD_STEPS` times. A highlight along a matte shaft, a dark stripe along a metal
    one, a collar: the band the vote finds may be a stripe of the shaft; the shaft is
    the outermost pair of edges around it that encloses instrument only."""
    R, ci, cj = pairs[:3]
    for _ in range(_OUTWARD_STEPS):
        rows, cl, cr = band[:3]
        L, H = np.full(P.shape[0], np.nan), np.full(P.shape[0], np.nan)
        L[rows], H[rows] = cl, cr
        l_, h_ = L[R], H[R]
        with np.errstate(invalid="ignore"):
            idx = np.flatnonzero((ci <= l_ + _ENCLOSE_COLS) & (cj >= h_ - _ENCLOSE_COLS) & (cj - ci >= _WIDER * (h_ - l_)))
        if idx.size < _MIN_ROWS:
            break
        idx = idx[_one_instrument(P, D, pairs, idx, l_[idx], h_[idx])]
        if np.unique(R[idx]).size < _MIN_ROWS:
            break
        sub = tuple(v[idx] for v in pairs)
        A, b_of = _votes(grid, sub, np.zeros(1) + shift, lo, grid.pts.shape[1])
        wider = None
        for _q, c, b in _peaks(A, lo)[:_CANDIDATES]:
            got = _band_points(grid, P, D, sub, b_of, c, b, shift)
            if got is not None and np.intersect1d(got[0], rows).size >= 0.5 * rows.size:
                wider = got
                break
        if wider is None:
            break
        band = wider
    return band


def _same_band(a, b):
    """Whether two bands' points (`_band_points`) are one band found by both votes: their
    centres within 2 columns of each other on the rows they share, half the rows at least."""
    ra, rb = a[0], b[0]
    common, ia, ib = np.intersect1d(ra, rb, return_indices=True)
    if common.size < 0.5 * min(ra.size, rb.size):
        return False
    ca, cb = 0.5 * (a[1][ia] + a[2][ia]), 0.5 * (b[1][ib] + b[2][ib])
    return bool(np.median(np.abs(ca - cb)) <= 2.0)


def _chord(work, p, u):
    """(s0, s1) [ideal px] of the line p + s u (ideal px) inside the work frame's rectangle."""
    h, w = work.shape
    lo, hi = work.to_ideal(np.array([[0.0, 0.0]]))[0], work.to_ideal(np.array([[w - 1.0, h - 1.0]]))[0]
    s0, s1 = -np.inf, np.inf
    for k in range(2):
        if abs(u[k]) < 1e-12:
            continue
        a, b = sorted(((lo[k] - p[k]) / u[k], (hi[k] - p[k]) / u[k]))
        s0, s1 = max(s0, a), min(s1, b)
    return float(s0), float(s1)


def _edge_specs(work, grid, rows, cl, cr):
    """The two proposed edges (p0, u, n_out, s0, s1) [ideal px] of a band's points, over the
    band's run."""
    left = work.to_ideal(grid.point(rows, cl))
    right = work.to_ideal(grid.point(rows, cr))
    specs = []
    for P, other in ((left, right), (right, left)):
        p, u, _ = _line_fit(P)
        s = (P - p) @ u
        n = np.array([-u[1], u[0]])
        n = n if n @ (p - other.mean(0)) >= 0 else -n
        specs.append((p, u, n, float(s.min()), float(s.max())))
    return specs


def _extended(work, chan, noise, specs, dark):
    """The edges' specs over the stretch of their chord through the frame along which the band
    goes on looking like its run (the band's run in the work frame stops where perspective
    has changed its width by `_WIDTH_TOL`; the shaft goes on): at stations 2 work px apart
    on the first edge, the channel inside the band (its median over the middle 60 %) against
    each side (a fifth of the width beyond the edges) differs by half the run's median
    contrast and 3 noise sd at least; the stretch of such stations (gaps up to `_GAP_ROWS`)
    around the run, inside the view."""
    import cv2

    (p, u, n, a0, a1), (q, v, m, _, _) = specs
    c0, c1 = _chord(work, p, u)
    st = np.arange(c0, c1, _ROW_STEP / work.mean_scale)
    if st.size < 2:
        return specs
    A = p + st[:, None] * u
    # the second edge where the first edge's normal through A meets it
    t = ((q - A) @ np.array([-v[1], v[0]])) / (n @ np.array([-v[1], v[0]]))
    B = A + t[:, None] * n
    w = np.abs(t)[:, None]
    inside = A[:, None] + np.linspace(0.2, 0.8, 7)[None, :, None] * (B - A)[:, None]
    sides = [A[:, None] + n * (w * np.array([0.15, 0.3]))[..., None], B[:, None] + m * (w * np.array([0.15, 0.3]))[..., None]]
    pts = np.concatenate([inside, *sides], 1)
    wk = work.to_work(pts).astype(np.float32)
    val = cv2.remap(np.ascontiguousarray(chan, np.float32), wk[..., 0], wk[..., 1], cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    seen = cv2.remap(work.dist, wk[..., 0], wk[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                     borderValue=-1.0).min(1) >= 0
    mid = np.median(val[:, :7], 1)
    l_, r_ = val[:, 7:9].mean(1), val[:, 9:].mean(1)
    con = (np.minimum(l_, r_) - mid) if dark else (mid - np.maximum(l_, r_))
    run = (st >= a0) & (st <= a1)
    ref = float(np.median(con[run])) if run.any() else 0.0
    ok = seen & (con >= max(0.5 * ref, 3.0 * noise))
    k0 = int(np.argmin(np.abs(st - 0.5 * (a0 + a1))))
    lo = hi = k0
    gap = 0
    while lo > 0 and seen[lo - 1] and gap <= _GAP_ROWS:
        lo -= 1
        gap = 0 if ok[lo] else gap + 1
    lo += gap
    gap = 0
    while hi < st.size - 1 and seen[hi + 1] and gap <= _GAP_ROWS:
        hi += 1
        gap = 0 if ok[hi] else gap + 1
    hi -= gap
    s0, s1 = min(float(st[lo]), a0), max(float(st[hi]), a1)
    e0, e1 = sorted(float((P - q) @ v) for P in (p + s0 * u, p + s1 * u))
    return [(p, u, n, s0, s1), (q, v, m, e0 - 1.0, e1 + 1.0)]


def _reaches_border(m, camera, validity, margin):
    """Whether a midline (ideal px) ends within a width and a margin of the view's border."""
    from pencilcal.toolkit.detect.working import to_raw_points

    return bool(np.min(validity.distance(to_raw_points(camera, m.ends))) <= m.width_px + margin)


def _ends_at(m, prior, margin, image_size, width=None):
    """Whether a midline (ideal px) ends at a finite prior's point (ideal px) inside the
    image (image_size (W, H) [px]): within its width, a margin [px] and 3 sd of the point
    along it. An instrument whose port is in view
    enters the view there, not at its border: its band runs from the port's image."""
    x = _finite_point(prior)
    if x is None or not (0.0 <= x[0] < image_size[0] and 0.0 <= x[1] < image_size[1]):
        return False  # a port beyond the view: the instrument enters at the border
    u = (m.ends[1] - m.ends[0]) / max(float(np.linalg.norm(m.ends[1] - m.ends[0])), 1e-12)
    sd = float(prior.offset_sigma(np.array([-u[1], u[0]])))  # the point's sd along the midline
    d = np.linalg.norm(m.ends - x, axis=1)
    k = int(np.argmin(d))
    # the band's width at its end towards the point: a shaft pointing away from the camera
    # is widest at its port, and its edges stop short of the port by that width's half
    w = max(m.width_px, _width_at(m, m.ends[k])) if width is None else width
    return bool(d[k] <= w + margin + 3.0 * sd)


def _width_at(m, p):
    """The distance [px] between a midline's two edge lines (ideal px) across the point p (2,)
    between them."""
    e = np.asarray(m.edges, float).reshape(2, 2, 2)
    out = 0.0
    for a, b in e:
        t = (b - a) / max(float(np.linalg.norm(b - a)), 1e-12)
        out += abs(float((p - a) @ np.array([-t[1], t[0]])))
    return out


def _joins_border(work, chan, m, prior):
    """Whether, on the instrument-likeness chan (work frame), a midline (ideal px) is joined to
    the view's border by instrument material along its line on the prior's point's side: a
    shaft's distal part (a wrist, jaws, a bright tip narrower or wider than the shaft) whose
    band stops at a collar, the shaft itself running on to the border. From the midline's end
    nearer the point (either end where the point lies at infinity) outwards to the border (not
    beyond the point), at stations 2 work px apart, the likeness across the middle half of
    that end's width lies above halfway between the band's own (across its centre) and the
    surround's (the higher of its two sides 0.8 widths from the axis) at `_JOIN_FRACTION` of
    them."""
    import cv2

    def at(P):
        q = work.to_work(P.reshape(-1, 2)).reshape(P.shape).astype(np.float32)
        return q[..., 0], q[..., 1]

    c = np.ascontiguousarray(chan, np.float32)
    u = (m.ends[1] - m.ends[0]) / max(float(np.linalg.norm(m.ends[1] - m.ends[0])), 1e-12)
    n = np.array([-u[1], u[0]])
    mid = 0.5 * (m.ends[0] + m.ends[1])
    lv = cv2.remap(c, *at(np.array([[mid + f * m.width_px * n for f in (-0.15, 0.0, 0.15, -0.8, 0.8)]])),
                   cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[0]
    band, surround = float(np.median(lv[:3])), float(np.max(lv[3:]))
    if band <= surround:
        return False
    x = _finite_point(prior)
    if x is None:
        ways = [(0, -u), (1, u)]
    else:
        k = int(np.argmin(np.linalg.norm(m.ends - x, axis=1)))
        ways = [(k, u if (x - m.ends[k]) @ u > 0 else -u)]
    for k, d in ways:
        st = np.arange(1.0, float(np.hypot(*work.shape)) / work.mean_scale, _ROW_STEP / work.mean_scale)
        if x is not None:
            st = st[st < float(np.linalg.norm(x - m.ends[k]))]  # not beyond the port
        w = _width_at(m, m.ends[k])
        pts = m.ends[k] + st[:, None, None] * d + (np.linspace(-0.25, 0.25, 5) * w)[None, :, None] * n
        if st.size < 2:
            continue
        xs, ys = at(pts)
        seen = cv2.remap(work.dist, xs, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=-1.0).min(1) >= 0
        out = int(np.argmin(seen)) if not seen.all() else 0
        if out <= 0:
            continue  # the line never leaves the view towards the point, or starts outside it
        val = np.median(cv2.remap(c, xs, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE), 1)[:out]
        if np.mean(val > 0.5 * (band + surround)) >= _JOIN_FRACTION:
            return True
    return False


def _narrows_to(m, prior):
    """Whether a midline's edges (ideal px) meet on the side of its band where the prior's
    (finite) point lies: a shaft narrows towards its port."""
    x = _finite_point(prior)
    if x is None:
        return False
    e = np.asarray(m.edges, float).reshape(2, 2, 2)
    v = line_meet(line_through(e[0, 0], e[0, 1]), line_through(e[1, 0], e[1, 1]))
    if abs(v[2]) < 1e-12:
        return False
    c = 0.5 * (m.ends[0] + m.ends[1])
    return bool((v[:2] / v[2] - c) @ (x - c) > 0)


def _finite_point(prior):
    """The prior's point (ideal px) (2,), or None where it lies at infinity (a fulcrum known
    only as a direction)."""
    X = prior.point
    return None if abs(X[2]) < 1e-12 else X[:2] / X[2]


def _shifts(grid, pw):
    """The shifts of the line beside X tried (module docstring, step 2), in the grid's unit:
    within 3 sd of the prior, at most one column apart, at most `_MAX_SHIFTS`."""
    if grid.far:
        sd = float(np.sqrt(max(np.trace(pw.cov), 0.0)))  # the direction's sd [rad], about
    else:
        ends = grid.pts[[0, -1], grid.pts.shape[1] // 2]
        d = ends[1] - ends[0]
        sd = float(pw.offset_sigma(d / max(np.linalg.norm(d), 1e-12)))
    span = 3.0 * sd if np.isfinite(sd) else 0.0
    unit = 1.0 / max(float(np.max(np.abs(grid.shift))), 1e-12)  # a shift of one column at most
    if span <= unit:
        return np.zeros(1)
    return np.linspace(-span, span, int(min(_MAX_SHIFTS, 2 * np.ceil(span / unit) + 1)))


def _channel(work):
    """(the channel searched (h, w) float32, whether only bands above their sides count):
    a colour frame's instrument-likeness (`shaft.regions.material_map`, x 100: grey, black
    and metal against tissue, where a pale fold of tissue keeps the tissue's colour), else
    the luma, either polarity."""
    from pencilcal.toolkit.detect.shaft.regions import material_map

    if work.bgr.ndim == 3:
        mm = material_map(work)
        if mm.informative:
            return (100.0 * mm.likeness).astype(np.float32), True
    return work.luma, False


def _bands(work, pw, wmin, wmax):
    """Steps 1-3 in the work frame: up to `_CANDIDATES` (grid, rows, left cols, right cols,
    dark, False) of the vote by widths, the heaviest first, then up to as many others of
    the vote by angles (..., True)."""
    from pencilcal.toolkit.detect.shaft.material_cue import robust_noise

    grid = _Grid(pw.point, work.shape, float(np.hypot(*work.shape)))
    chan, bright_only = _channel(work)
    P, D = grid.sample(chan), grid.sample(work.dist)
    pairs = _pairs(grid, P, D, max(robust_noise(chan), 0.5), wmin, wmax, bright_only)
    if pairs[0].size == 0:
        return []
    shifts = _shifts(grid, pw)
    found = []
    votes = [(pairs, wmin, False)]
    if not grid.far:
        # a shaft pointing at (or away from) the camera from a port near the view images as a
        # cone whose apex lies near X: its width grows with the radius, its angle about X
        # stays; its pairs also vote by their width in columns
        cols = pairs[2] - pairs[1]
        votes.append(((*pairs[:4], cols, *pairs[5:]), max(float(cols.min()), 1.0), True))
    out = []
    for cone, (pr, lo, own) in enumerate(votes):
        A, b_of = _votes(grid, pr, shifts, lo, grid.pts.shape[1])
        found = []
        for q, c, b in _peaks(A, lo, own):
            band = _band_points(grid, P, D, pr, b_of, c, b, shifts[q])
            if band is None:
                continue
            wide = _outermost(grid, P, D, pr, band, lo, shifts[q]) if bright_only else band
            if wide is not band and any(_same_band(wide, f) for f in found):
                continue  # the enclosing band is one already found
            if not any(_same_band(wide, f[1:]) for f in out):
                found.append(wide)
        found.sort(key=lambda t: -t[4])
        out += [(grid, *t[:4], bool(cone)) for t in found[:_CANDIDATES]]
    return out


def pencil_search(image, camera, validity, work, prior, o, K, noise, gamma=1.0):
    """Shafts through a prior's point (module docstring): a list of (`shaft.axis.Midline`,
    score [raw px], polarity) per band that held up, best score first.

    image: the raw frame; validity: `shaft.work.Validity`; work: its `shaft.work.WorkFrame`;
    prior: `shaft.prior.AxisPrior` (ideal px); o: `shaft.detector.ShaftOptions`; K: the
    axis camera (`shaft.work.axis_matrix`); noise: the image noise sd [grey levels];
    gamma: the frame's encoding gamma (`shaft.silhouette.fit_edges`).
    """
    s = work.mean_scale
    A_w = np.array([[work.scale[0], 0.0, -work.scale[0] * work.origin[0] - 0.5],
                    [0.0, work.scale[1], -work.scale[1] * work.origin[1] - 0.5], [0.0, 0.0, 1.0]])
    lo, hi = (o.region_wmin, o.region_wmax) if prior.widths is None else (0.8 * prior.widths[0],
                                                                             1.25 * prior.widths[1])
    out = []
    corridor = max(o.corridor_px, _CORRIDOR_WORK / s)
    chan, bright_only = _channel(work)
    from pencilcal.toolkit.detect.shaft.material_cue import robust_noise

    chan_noise = max(robust_noise(chan), 0.5)
    size = np.asarray(image).shape[1::-1]
    for grid, rows, cl, cr, dark, cone in _bands(work, prior.affine(A_w), max(lo * s, 3.0), hi * s):
        specs = _extended(work, chan, chan_noise, _edge_specs(work, grid, rows, cl, cr), dark)
        width = float(np.median(np.abs(cr - cl) * grid.spacing[rows])) / s
        e = fit_edges(image, camera, validity, noise, specs, corridor, max_gap=max(width, 10.0), gamma=gamma)
        if e[0] is None or e[1] is None:
            continue
        m = midline_from_edges(K, e[0], e[1])
        if m is None:
            continue
        seen = float(np.hypot(*(m.ends[1] - m.ends[0])))
        score = seen * min(e[0].frac, e[1].frac)
        if not cone and _entering(m, seen, prior, o, camera, validity, corridor, size):
            out.append((m, score, "dark" if dark else "bright", 0))
        elif _entering_close(m, seen, prior, o, camera, validity, corridor, size, work, chan, bright_only):
            out.append((m, score, "dark" if dark else "bright", 1))
    if any(t[3] == 0 for t in out):
        out = [t for t in out if t[3] == 0]  # a long band entering the view is the shaft
    kept = []
    for t in sorted(out, key=lambda t: -t[1]):
        if not any(np.allclose(t[0].edges, k[0].edges, atol=0.5) for k in kept):  # two vote peaks, one band
            kept.append(t[:3])
    return kept


def _entering(m, seen, prior, o, camera, validity, corridor, size):
    """Whether a band (midline m, seen along seen [px]) is a shaft entering the view: seen
    along 1.5 widths and reaching the view's border, or along one width running from the
    prior's point inside the view (`_ends_at`: a port in view, where the instrument enters);
    its edges converging by at most the edge cue's limit, or, from the point, up to
    `_MAX_CONVERGENCE_AT_PORT_DEG` narrowing towards it (pointing at the camera its edges
    converge steeply towards the port)."""
    at_port = _ends_at(m, prior, corridor, size, m.width_px)
    if m.convergence_deg > np.degrees(o.conv_max) and not (
            at_port and m.convergence_deg <= _MAX_CONVERGENCE_AT_PORT_DEG and _narrows_to(m, prior)):
        return False
    least = _MIN_WIDTHS_AT_PORT if at_port else _MIN_WIDTHS
    return seen >= least * m.width_px and (at_port or _reaches_border(m, camera, validity, corridor))


def _entering_close(m, seen, prior, o, camera, validity, corridor, size, work, chan, bright_only):
    """Where no band passes `_entering`: whether a band is a shaft close to the camera or
    along its line of sight entering the view: seen along `_MIN_WIDTHS_CLOSE` widths (close
    to the camera its visible part is short and wide) and reaching the border, or running
    from the prior's point (its width there, `_ends_at`: pointing away from the camera a
    shaft is widest at its port), or joined to the border by instrument material along its
    line towards the point (`_joins_border`, colour frames); converging by at most the edge
    cue's limit, or from the point up to `_MAX_CONVERGENCE_AT_PORT_DEG` either way."""
    at_port = _ends_at(m, prior, corridor, size)
    if m.convergence_deg > np.degrees(o.conv_max) and not (at_port and m.convergence_deg <=
                                                          _MAX_CONVERGENCE_AT_PORT_DEG):
        return False
    return seen >= _MIN_WIDTHS_CLOSE * m.width_px and (
        at_port or _reaches_border(m, camera, validity, corridor) or
        (bright_only and _joins_border(work, chan, m, prior)))

"""A band's two edges fitted along the whole line by a step averaged along it: the material
cue's edges where the fit at full resolution finds none (`shaft.material_cue`).

The full-resolution edge fit (`shaft.silhouette`) finds an edge per station, a peak above
the noise there. A dark shaft entering a vignetted field steps by 6-25 grey levels where
the light is and by ever less towards the black periphery, so its proposed band's run (the
region of the maps, the part in light) is short and its fit per station finds too few
stations; a thin shaft whose colour mirrors the tissue steps by 2-5 levels, under the noise
per station. The step exists as a mean along the edge. Here each edge of such a band is
taken from its run (its two boundary lines over it, work frame) and fitted in the edges'
channel of the work frame (`shaft.edge_pairs`' mean of luma and red):

1. *responses*: at stations every `_STATION_PX` along the edge's line, over the whole line
   within the frame, the profile across it, and at each offset a box step filter (the
   mean of `_HALF` px beyond less the mean of `_HALF` px before). The noise sd of one
   station's response is measured on the frame (the robust sd of the difference between
   stations `_LAG` apart, over all offsets: noise and fine texture, not a fixed level);
2. *the edge* (`_track`): blocks of `_BLOCK` stations, each block's response averaged
   along it and its peak searched within `_SEARCH_PX` of the line's prediction; the blocks
   of the run start it (their mean at least `_Z_START` sd of that mean, with the sign of
   the run's step), then it walks outwards block by block, the line refitted to the blocks
   kept, while a block's averaged step stays `_Z_BLOCK` sd of its mean with that sign (into
   the dark of a vignetted field as far as it is significant), across at most
   `_GAP_BLOCKS` blocks without it;
3. the edge (`edge_line`, ideal px) is the line through the blocks' peaks, its variances
   from their scatter about it; the judges (`shaft.material_cue.judge_band`, and after it
   the pixel evidence and the tissue colour) judge the band as every band.

Work pixels throughout but for `edge_line`.

Example
-------
>>> import numpy as np, cv2
>>> from pencilcal.toolkit.detect.shaft.work import Validity, WorkFrame
>>> rng = np.random.default_rng(0)
>>> img = np.full((240, 320, 3), (70, 80, 120), np.float64)
>>> img[:170, 150:164] -= 3.0                       # a thin shaft 3 levels darker, entering at the top
>>> img = np.clip(cv2.GaussianBlur(img, (0, 0), 1.2) + rng.normal(0, 2.0, img.shape), 0, 255).astype(np.uint8)
>>> wf = WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=320)
>>> ends = [(np.array([150.0, 100.0]), np.array([150.0, 130.0])), (np.array([164.0, 100.0]), np.array([164.0, 130.0]))]
>>> left, right = tracked_edges(wf, ends)                                  # 30 px of each edge's run
>>> [round(float(e.point_at(e.sm)[0]), 0) for e in (edge_line(wf, left), edge_line(wf, right))]
[150.0, 164.0]
>>> [bool(e.s_hi - e.s_lo > 120.0) for e in (edge_line(wf, left), edge_line(wf, right))]  # their run: 30 px
[True, True]
"""
from __future__ import annotations

import numpy as np

__all__ = ["tracked_edges", "edge_line", "band_ends"]

_STATION_PX = 2.0  # station spacing along the line [work px]
_HALF = 3  # the box step filter's half-length [work px]
_LAG = 2  # stations between the two responses whose difference gives the noise
_BLOCK = 6  # stations averaged per block (12 work px)
_SEARCH_PX = 2  # a block's peak searched within this of the line's prediction [work px]
_Z_START = 5.0  # the run's blocks together, in sd of their mean
_Z_BLOCK = 3.0  # each further block, in sd of its mean
_GAP_BLOCKS = 2
_MIN_BLOCKS = 3


def _channel(work):
    """The edges' channel (h, w) float32 (`shaft.edge_pairs`: mean of luma and red)."""
    if work.bgr.ndim == 3:
        return (0.5 * (work.luma + work.colours[..., 2])).astype(np.float32)
    return work.luma.astype(np.float32)


def _responses(ch, dist, p, u, n, s, t):
    """The box step responses D (S, T) at p + s u + t n (t: integer work px) and where they
    are observable (S, T) bool (every sample of the filter in the view)."""
    import cv2

    X = (p[0] + s[:, None] * u[0] + t[None, :] * n[0]).astype(np.float32)
    Y = (p[1] + s[:, None] * u[1] + t[None, :] * n[1]).astype(np.float32)
    prof = cv2.remap(ch, X, Y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0).astype(np.float64)
    ok = cv2.remap(dist, X, Y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1) > 1.0
    S, T = prof.shape
    c = np.zeros((S, T + 1))
    np.cumsum(prof, axis=1, out=c[:, 1:])
    co = np.zeros((S, T + 1), np.int32)
    np.cumsum(ok, axis=1, out=co[:, 1:])
    h = _HALF
    j = np.arange(h, T - h)
    D = np.zeros((S, T))
    D[:, j] = ((c[:, j + h + 1] - c[:, j + 1]) - (c[:, j] - c[:, j - h])) / h
    okD = np.zeros((S, T), bool)
    okD[:, j] = (co[:, j + h + 1] - co[:, j - h]) == 2 * h + 1
    return D, okD


def _station_noise(D, ok):
    """The sd of one station's response [grey levels]: the robust sd of the differences
    between stations `_LAG` apart (over all offsets), over sqrt 2."""
    d = D[_LAG:] - D[:-_LAG]
    m = ok[_LAG:] & ok[:-_LAG]
    if np.count_nonzero(m) < 50:
        return np.inf
    return float(1.4826 * np.median(np.abs(d[m])) / np.sqrt(2.0))


def _block_peak(D, ok, rows, tpred, j0, sg):
    """(t, mean, count) of one block's averaged signed response sg D near the predicted
    offsets tpred (rows,) [work px; profile index = t + j0], or None: the peak over
    +-_SEARCH_PX, refined by a parabola."""
    T = D.shape[1]
    base = np.rint(tpred).astype(int) + j0
    offs = np.arange(-_SEARCH_PX - 1, _SEARCH_PX + 2)
    J = base[:, None] + offs[None, :]
    inb = (J >= 0) & (J < T)
    Jc = np.clip(J, 0, T - 1)
    okb = ok[rows[:, None], Jc] & inb
    n = okb.sum(0)
    if n.min() < 0.5 * len(rows):
        return None
    v = np.where(okb, sg * D[rows[:, None], Jc], 0.0).sum(0) / np.maximum(n, 1)
    q = int(np.argmax(v[1:-1])) + 1
    a, b, c = v[q - 1], v[q], v[q + 1]
    den = a - 2 * b + c
    dq = 0.5 * (a - c) / den if den < 0 else 0.0
    dq = float(np.clip(dq, -0.5, 0.5))
    return float(np.mean(np.rint(tpred))) + offs[q] + dq, float(b), int(n[q])


def _fit(sk, tk, wk):
    """Weighted straight line t = a + b s through the blocks: (a, b)."""
    if len(sk) < 2:
        return float(tk[0]), 0.0
    A = np.c_[np.ones(len(sk)), sk]
    W = np.sqrt(wk)
    a, b = np.linalg.lstsq(A * W[:, None], tk * W, rcond=None)[0]
    return float(a), float(b)


def _track(D, ok, s, j0, sg, a, b, start, sigma, z_start):
    """The edge walked along the line (module docstring, step 2): (a, b, blocks [(s, t,
    count)]) or None. start: the block indices it starts from (must be significant together
    at z_start); a, b: its first line t = a + b s."""
    S = D.shape[0]
    nb = S // _BLOCK
    rows_of = [np.arange(k * _BLOCK, (k + 1) * _BLOCK) for k in range(nb)]
    got = {}
    vals, cnts = [], []
    for k in start:
        if k < 0 or k >= nb:
            continue
        r = rows_of[k]
        pk = _block_peak(D, ok, r, a + b * s[r], j0, sg)
        if pk is None:
            continue
        got[k] = pk
        vals.append(pk[1] * pk[2])
        cnts.append(pk[2])
    if not got or sum(vals) / sum(cnts) < z_start * sigma / np.sqrt(sum(cnts)):
        return None
    ks = sorted(got)

    def refit():
        kk = sorted(got)
        return _fit(np.array([s[rows_of[k]].mean() for k in kk]), np.array([got[k][0] for k in kk]),
                    np.array([got[k][2] for k in kk], float))

    a, b = refit()
    for direction in (-1, 1):
        k, gap = (ks[0] - 1, 0) if direction < 0 else (ks[-1] + 1, 0)
        while 0 <= k < nb and gap <= _GAP_BLOCKS:
            r = rows_of[k]
            pk = _block_peak(D, ok, r, a + b * s[r], j0, sg)
            if pk is not None and pk[1] >= _Z_BLOCK * sigma / np.sqrt(pk[2]):
                got[k] = pk
                gap = 0
                a, b = refit()
            else:
                gap += 1
                if pk is None and gap > _GAP_BLOCKS:
                    break
            k += direction
    kk = sorted(got)
    return a, b, [(float(s[rows_of[k]].mean()), got[k][0], got[k][2]) for k in kk]


def edge_line(work, edge):
    """One tracked edge (`tracked_edges`': p, u, n_out, a, b, blocks; work px) as a
    `shaft.silhouette.EdgeLine` in ideal px: the line through the blocks' points weighted by
    their stations, its variances from their scatter about it (at least a quarter work px
    per block), over the blocks' extent; frac: the blocks kept over the blocks between the
    first and last."""
    from pencilcal.toolkit.detect.shaft.silhouette import EdgeLine

    p, u, n_out, a, b, blocks = edge
    nrm = np.array([-u[1], u[0]])
    sk = np.array([q[0] for q in blocks])
    tk = np.array([q[1] for q in blocks])
    wk = np.array([q[2] for q in blocks], float)
    pts = work.to_ideal(p[None, :] + sk[:, None] * u[None, :] + tk[:, None] * nrm[None, :])
    ui = np.asarray(u) / work.scale
    ui = ui / np.linalg.norm(ui)
    ni = np.array([-ui[1], ui[0]])
    no = np.asarray(n_out) / work.scale
    ni = ni if ni @ no >= 0 else -ni
    p0 = pts[0]
    si = (pts - p0) @ ui
    ti = (pts - p0) @ ni
    W_ = wk / wk.sum()
    sm = float(W_ @ si)
    A = np.c_[np.ones(len(si)), si - sm]
    coef = np.linalg.lstsq(A * np.sqrt(W_)[:, None], ti * np.sqrt(W_), rcond=None)[0]
    res = ti - A @ coef
    k = len(si)
    floor = (0.25 / work.mean_scale) ** 2
    s2 = max(float(np.sum(res**2) / max(k - 2, 1)), floor)
    Sss = float(np.sum((si - sm) ** 2))
    lo, hi = float(si.min()), float(si.max())
    return EdgeLine(p0=p0, u=ui, n=ni, sm=sm, tm=float(coef[0]), b=float(coef[1]), var_t=s2 / k,
                    var_b=s2 / max(Sss, 1e-9), s_lo=lo, s_hi=hi, count=k, frac=min(1.0, k / max(1.0, (sk.max() - sk.min()) / (_BLOCK * _STATION_PX) + 1.0)),
                    rms=float(np.sqrt(np.mean(res**2))))


def band_ends(band):
    """The two edges of a band (`shaft.region_bands.RegionBand`) over its run: [(start (2,),
    end (2,))] x 2 [work px]."""
    i0, i1 = band.run
    C0, C1 = band.C[i0], band.C[i1 - 1]
    return [(C0 + off[i0] * band.na, C1 + off[i1 - 1] * band.na) for off in (band.oi, band.oj)]


def tracked_edges(work, ends):
    """A band's two edges, each tracked along its whole line from its run (module docstring,
    steps 1-2): ((p, u, n_out, a, b, blocks) x 2) [work px]: a point and unit direction of
    the run's line, the unit normal out of the band, the tracked line t = a + b s along
    (-u_y, u_x) and its blocks [(s, t, stations)]; or None where either edge's run is not
    significant. ends: the two edges' runs [(start (2,), end (2,))] x 2 [work px]
    (`band_ends`)."""
    ch = _channel(work)
    h, w = work.shape
    reach = float(np.hypot(h, w))
    mids = [0.5 * (a + b) for a, b in ends]
    out = []
    for k, (q0, q1) in enumerate(ends):
        d = q1 - q0
        L = float(np.hypot(*d))
        if L <= 0:
            return None
        u = d / L
        nrm = np.array([-u[1], u[0]])
        p = mids[k]
        n_out = -nrm if (mids[1 - k] - p) @ nrm > 0 else nrm
        s = np.arange(-reach, reach + _STATION_PX, _STATION_PX)
        X, Y = p[0] + s * u[0], p[1] + s * u[1]
        s = s[(X >= 0) & (X <= w - 1) & (Y >= 0) & (Y <= h - 1)]
        t = np.arange(-_SEARCH_PX - _HALF - 3, _SEARCH_PX + _HALF + 4)
        j0 = int(np.flatnonzero(t == 0)[0])
        D, ok = _responses(ch, work.dist, p, u, nrm, s, t)
        sigma = _station_noise(D, ok)
        nb = s.size // _BLOCK
        if not np.isfinite(sigma) or nb < _MIN_BLOCKS:
            return None
        bs = np.array([s[j * _BLOCK:(j + 1) * _BLOCK].mean() for j in range(nb)])
        start = np.flatnonzero(np.abs(bs) <= 0.5 * L)
        rows = np.flatnonzero((np.abs(s) <= 0.5 * L) & ok[:, j0])
        if start.size == 0 or rows.size == 0:
            return None
        sg = 1.0 if np.mean(D[rows, j0]) >= 0 else -1.0
        got = _track(D, ok, s, j0, sg, 0.0, 0.0, start, sigma, _Z_START)
        if got is None or len(got[2]) < _MIN_BLOCKS:
            return None
        a, b, blocks = got
        out.append((p, u, n_out, a, b, blocks))
    return tuple(out)

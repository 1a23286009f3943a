"""Bands of instrument-like region, judged along their whole chord: the material cue's band
test (`shaft.detector`).

A candidate band lies between two straight region boundaries (`shaft.regions.region_pairs`).
Its cross-section is sampled at `STATIONS` stations along the chord of its mean axis through
the work frame, at `_NU` positions across from -2 to +2 half-widths (the boundaries at -1
and +1), for all candidates in one remap (of all a frame's maps at once: `evaluate_many`).
Per station:

- fin, the fraction of the inside (|nu| <= `_NU_IN`) that is region; fL, fR the same for
  each side strip (`_NU_SIDE` <= |nu| <= 2);
- obs: the cross-section lies in the valid region; sup: both boundary lines are backed by
  boundary points there (a run may not extrapolate a short boundary line along a long one).

A station is *shaft* (+1) when fin >= `FILL_IN`, both sides <= `FILL_SIDE` and supported;
-0.5 when the inside is region but a side too or unsupported; -1.5 when the inside is not
region (a wrist or jaws are narrower); -3 not observable. The run is the stretch of largest
sum (`shaft.bands.best_segment`); it extends while the inside stays region (fin >= 0.5),
and the band *reaches the border* when that extension ends within 2 stations of the first
unobservable one. For the runs long enough, the material difference of the inside from each
side: the side is not instrument-like at this level (fraction of the "all" map <=
`FILL_SIDE`), or the spectral angle between the mean colours exceeds twice the scene's
colour variability (`shaft.regions.scene_angle`: a shade or a fold of one surface keeps its
colour direction, a grey shaft against a grey-blue drape not). `proposed` keeps the bands
that may be shafts, `suppress_overlaps` the better of overlapping ones.

Work pixels throughout; stations and strips in units of the band's local half-width.

Example
-------
>>> import numpy as np
>>> lab = np.array([[-3, 1, 1, -1.5, 1, 1, 1, -3]])
>>> best_run(lab)
(1, 7)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.detect.edges import mean_over
from pencilcal.toolkit.detect.shaft.bands import best_segment
from pencilcal.toolkit.detect.shaft.regions import BoundaryLines, RegionPairs
from pencilcal.toolkit.geometry.quantiles import median

__all__ = ["STATIONS", "FILL_IN", "FILL_SIDE", "RegionBand", "evaluate_bands", "evaluate_many", "best_run", "band_stretch", "proposed",
           "suppress_overlaps", "band_polygon"]

STATIONS = 96  # stations along a band's chord
FILL_IN = 0.8  # "mostly region": a thread or a highlight may cross the band
FILL_SIDE = 0.35  # "mostly not region"
_NU = np.linspace(-2.0, 2.0, 33)
_NU_IN, _NU_SIDE = 0.75, 1.3
_IN = np.abs(_NU) <= _NU_IN
_SL = (_NU >= -2.0) & (_NU <= -_NU_SIDE)
_SR = (_NU >= _NU_SIDE) & (_NU <= 2.0)


def _run(mask):
    """The slice of a mask (U,) bool whose True entries are one run (the offsets `_NU` are
    sorted, so each of their sets is).

    >>> _run(np.array([False, True, True, False]))
    slice(1, 3, None)
    """
    idx = np.flatnonzero(mask)
    if not (idx.size and idx[-1] - idx[0] + 1 == idx.size):
        raise ValueError("not one run")
    return slice(int(idx[0]), int(idx[-1]) + 1)


# the same sets as slices, for selections that copy what they select anyway (a boolean index of
# the stations): one gather fewer, the same elements in the same order
_IN_S, _SL_S, _SR_S = _run(_IN), _run(_SL), _run(_SR)
_OBS_S = _run(np.abs(_NU) <= 1.0)  # the cross-section between the two boundaries
_REACH_STATIONS = 2  # a run "reaches the border" when it ends this close to the first unobservable station
_RECENT = 8  # the extension's band test compares with the last this many stations of the band
_BAND_GAP = 2  # ... bridging gaps of up to this many stations
_MIN_CONTRAST_SD = 4.0  # ... where the inside differs from both sides by this many noise sd at least
_NMS_OVERLAP = 0.3  # bands overlapping by more than this fraction of the smaller one are one
# The least run of a band at least the least length wide that the border of the view cuts,
# in widths: a shaft close to the lens seen from the border to its collar along 1.25 widths
# (`shaft.material_cue._SHORT_WIDTHS`) has its cross-section whole in the view only from
# about half a width in (`_OBS_S`), a run of 0.75 widths, under the least length
CUT_RUN_WIDTHS = 0.75


@dataclass(eq=False)
class RegionBand:
    """One candidate band along its chord (`evaluate_bands`), work pixels.

    Attributes
    ----------
    lines : tuple of two (p (2,), u (2,), n (2,), lo, hi)
        The two boundary lines (`shaft.regions.BoundaryLines` rows, n into the region).
    C : (S, 2)
        Station points on the mean axis; ua, na (2,) its direction and normal.
    oi, oj : (S,)
        Offsets of the two boundary lines from the stations along na.
    run, ext : (int, int)
        Stations [i0, i1) of the run, and of its extension.
    reach : (bool, bool)
        The extension reaches the border before / after the run; reach_run: the run itself
        does, at either end.
    view : (int, int)
        Stations [v0, v1) of the observable stretch of the chord around the run.
    obs : (S,) bool
        The stations whose cross-section lies in the valid region.
    inside_colour, contrast : (S, C), (S,) [grey levels]
        Each station's mean colour inside, and its distance from the nearer side's
        (`band_stretch`).
    step : float [px]
        Station spacing.
    run_len, shaft_len : float [px]
        The run's length and the length of its shaft stations.
    fall, ang : (2,)
        Fraction of instrument-like pixels ("all" map) beside each side; spectral angle
        between the inside's and that side's mean colour [deg] (NaN: too few pixels).
    y_in : float, y_sides : (2,) [grey levels]
        Mean luma inside the run and beside each of its sides (`y_side`: their mean).
    level, kind : int, str
        The region level and map ("all", "dark" or "darker": `shaft.regions.DARK_SPLITS`)
        it came from.
    side_contrast : (2,) [grey levels]
        The median over the run of the inside's colour distance from each side's (NaN: that
        side not seen).
    """

    lines: tuple
    C: np.ndarray
    ua: np.ndarray
    na: np.ndarray
    oi: np.ndarray
    oj: np.ndarray
    run: tuple
    ext: tuple
    reach: tuple
    reach_run: bool
    view: tuple
    obs: np.ndarray
    inside_colour: np.ndarray
    contrast: np.ndarray
    step: float
    run_len: float
    shaft_len: float
    fall: tuple
    ang: tuple
    y_in: float
    y_sides: tuple
    level: int = 0
    kind: str = "all"
    side_contrast: tuple = (np.nan, np.nan)

    @property
    def y_side(self):
        """Mean luma beside the run [grey levels]: the mean of its two sides'."""
        return float(0.5 * (self.y_sides[0] + self.y_sides[1]))

    @property
    def width_run(self):
        """Mean width over the run [px]."""
        i0, i1 = self.run
        return float(np.mean(np.abs(self.oj[i0:i1] - self.oi[i0:i1])))


def best_run(labels):
    """Stations [i0, i1) of the stretch of largest sum of one row of labels (1, S).

    See the module docstring's example.
    """
    i, j, _ = best_segment(np.asarray(labels, float).reshape(1, -1))
    return int(i[0]), int(j[0]) + 1


def _chords(c0, ua, shape):
    """Along-axis range (t0, t1) (K,) of each line c0 + t ua (K, 2) inside a frame (h, w)."""
    h, w = shape
    with np.errstate(all="ignore"):
        tx = np.sort(np.c_[(0 - c0[:, 0]) / ua[:, 0], (w - 1 - c0[:, 0]) / ua[:, 0]], 1)
        ty = np.sort(np.c_[(0 - c0[:, 1]) / ua[:, 1], (h - 1 - c0[:, 1]) / ua[:, 1]], 1)
    tx = np.where(np.isfinite(tx), tx, np.array([-1e9, 1e9]))
    ty = np.where(np.isfinite(ty), ty, np.array([-1e9, 1e9]))
    return np.maximum(tx[:, 0], ty[:, 0]), np.minimum(tx[:, 1], ty[:, 1])


def _line_offsets(P, U, C, na):
    """Where the lines P + a U (K, 2) meet the cross-sections C + o na (K, S, 2): (o, a)
    (K, S) each."""
    u, p = U[:, None, :], P[:, None, :]
    det = -u[..., 0] * na[:, None, 1] + na[:, None, 0] * u[..., 1]
    d = C - p
    o = (u[..., 0] * d[..., 1] - u[..., 1] * d[..., 0]) / det
    a = (-d[..., 0] * na[:, None, 1] + na[:, None, 0] * d[..., 1]) / det
    return o, a


@dataclass(frozen=True, eq=False)
class _Geometry:
    """The cross-sections of K bands at S stations: C (K, S, 2), ua, na (K, 2), oi, oj, ai,
    aj (K, S) (each line's offset across and position along itself), step (K,), good (K,)
    (a chord of some length), X, Y (K, S, U) float32 the sample points' coordinates (as
    `cv2.remap` takes them)."""

    C: np.ndarray
    ua: np.ndarray
    na: np.ndarray
    oi: np.ndarray
    oj: np.ndarray
    ai: np.ndarray
    aj: np.ndarray
    step: np.ndarray
    good: np.ndarray
    X: np.ndarray
    Y: np.ndarray


def _geometry(lines, pairs, shape):
    """`_Geometry` of the candidate bands `pairs` between `lines` in a frame (h, w)."""
    I, J = pairs.i, pairs.j
    ua = lines.u[I] - lines.u[J]
    ua /= np.maximum(np.linalg.norm(ua, axis=1, keepdims=True), 1e-12)
    na = np.c_[-ua[:, 1], ua[:, 0]]
    c0 = 0.5 * (lines.p[I] + lines.p[J])
    t0, t1 = _chords(c0, ua, shape)
    good = t1 - t0 > 4
    T = t0[:, None] + np.linspace(0, 1, STATIONS)[None, :] * (t1 - t0)[:, None]
    C = c0[:, None, :] + T[..., None] * ua[:, None, :]
    oi, ai = _line_offsets(lines.p[I], lines.u[I], C, na)
    oj, aj = _line_offsets(lines.p[J], lines.u[J], C, na)
    offs = 0.5 * (oi + oj)[..., None] + _NU[None, None, :] * (0.5 * (oj - oi))[..., None]
    # the points C + offs na, each coordinate made and cast on its own (no (K, S, U, 2)
    # float64 array: the same values at a third of the cost)
    X, Y = ((C[:, :, None, k] + offs * na[:, None, None, k]).astype(np.float32) for k in (0, 1))
    return _Geometry(C=C, ua=ua, na=na, oi=oi, oj=oj, ai=ai, aj=aj, step=(t1 - t0) / (STATIONS - 1), good=good, X=X,
                     Y=Y)


def _sampler(X, Y):
    """A function sampling a work-frame image (h, w) or (h, w, 3) at the points (X, Y) (K, S,
    U) float32 each (bilinear, 0 outside): (K, S, U) or (K, S, U, 3)."""
    import cv2

    K, S, U = X.shape
    X, Y = X.reshape(K * S, U), Y.reshape(K * S, U)

    def sample(im):
        out = cv2.remap(np.ascontiguousarray(im), X, Y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                        borderValue=0)
        return out.reshape((K, S, U) + out.shape[2:])

    return sample


def _labels(g, lines, pairs, sB, sV):
    """Per-station labels (K, S) (module docstring), obs and fin (K, S), okL, okR (K, S):
    the side strips observable, shaft (K, S)."""
    I, J = pairs.i, pairs.j
    obs = np.all(sV[:, :, _OBS_S] > 1.0, 2)
    # a side observable where half its samples are: counted (a mean of booleans converts them
    # to float64 first; count / n >= 0.5 is 2 count >= n, the division correctly rounded)
    okL = 2 * np.count_nonzero(sV[:, :, _SL_S] > 1.0, 2) >= _SL_S.stop - _SL_S.start
    okR = 2 * np.count_nonzero(sV[:, :, _SR_S] > 1.0, 2) >= _SR_S.stop - _SR_S.start
    fin = sB[:, :, _IN].mean(2)
    fL = np.where(okL, sB[:, :, _SL].mean(2), 0.0)
    fR = np.where(okR, sB[:, :, _SR].mean(2), 0.0)
    mg = 2.0 * g.step[:, None]
    sup = ((g.ai >= lines.lo[I][:, None] - mg) & (g.ai <= lines.hi[I][:, None] + mg)
           & (g.aj >= lines.lo[J][:, None] - mg) & (g.aj <= lines.hi[J][:, None] + mg))
    shaft = (fin >= FILL_IN) & (fL <= FILL_SIDE) & (fR <= FILL_SIDE) & sup
    lab = np.where(~obs, -3.0, np.where(fin < FILL_IN, -1.5, np.where(shaft, 1.0, -0.5)))
    lab[~g.good] = -3.0
    return lab, obs, fin, okL, okR, shaft


def _extension(obs_m, fin_m, i0, i1):
    """The extension [j0, j1) of the run [i0, i1) while the inside stays region, whether it
    reaches the border before / after it, whether the run itself does, and the observable
    stretch [v0, v1) around it."""
    n = obs_m.size
    j0, j1 = i0, i1
    while j0 > 0 and obs_m[j0 - 1] and fin_m[j0 - 1] >= 0.5:
        j0 -= 1
    while j1 < n and obs_m[j1] and fin_m[j1] >= 0.5:
        j1 += 1
    nob = np.flatnonzero(~obs_m)
    before = (nob[nob < j0].max() + 1) if np.any(nob < j0) else 0
    after = nob[nob >= j1].min() if np.any(nob >= j1) else n
    reach = (bool(j0 - before <= _REACH_STATIONS), bool(after - j1 <= _REACH_STATIONS))
    return (j0, j1), reach, bool(i0 - before <= _REACH_STATIONS or after - i1 <= _REACH_STATIONS), (before, after)


def _side_colours(cc, oL, oR, ba):
    """(fall, ang) of one band's run: the instrument-like fraction beside each side (ba:
    the "all" map's samples (S', U)) and the spectral angle [deg] between the inside's mean
    colour and each side's (cc: (S', U, 3) colours; oL, oR (S',) the sides observable)."""
    # each selection a contiguous copy, as a gather of the masked offsets was: the same sums
    aL = float(np.mean(ba[:, _SL_S][oL])) if np.any(oL) else 1.0
    aR = float(np.mean(ba[:, _SR_S][oR])) if np.any(oR) else 1.0
    cin = cc[:, _IN_S].reshape(-1, cc.shape[-1]).mean(0)
    angs = []
    for okS, msk in ((oL, _SL_S), (oR, _SR_S)):
        qq = cc[:, msk][okS].reshape(-1, cc.shape[-1])
        if qq.shape[0] < 5:
            angs.append(np.nan)
            continue
        qq = qq.mean(0)
        c = cin @ qq / (np.linalg.norm(cin) * np.linalg.norm(qq) + 1e-9)
        angs.append(float(np.degrees(np.arccos(np.clip(c, -1, 1)))))
    return (aL, aR), tuple(angs)


def band_stretch(band, noise):
    """Stations [b0, b1) around a band's run along which its cross-section goes on looking
    like the run's (the band test of the extension): walking outwards, a station is the
    band's while its inside differs from both sides by at least half the recent contrast
    (and `_MIN_CONTRAST_SD` noise sd [grey levels]) and keeps the recent inside colour within
    half that contrast (a cylinder looks the same along its length; the recent stations,
    the mean of the last `_RECENT` accepted, follow slow shading). Gaps up to `_BAND_GAP`
    stations (a thread, a highlight) are bridged; it stops where the chord leaves the view."""
    i0, i1 = band.run
    cin, con, obs = band.inside_colour, band.contrast, band.obs
    floor = _MIN_CONTRAST_SD * noise
    ends = []
    for step, start, stop in ((-1, i0 - 1, -1), (1, i1, obs.size)):
        ref = list(range(i0, i1))
        ref = ref[-_RECENT:] if step > 0 else ref[:_RECENT]
        r_con = float(np.mean(con[ref]))
        r_cin = cin[ref].mean(0)
        last, k, gap = (i0 if step < 0 else i1 - 1), start, 0
        while k != stop and obs[k]:
            if con[k] >= max(0.5 * r_con, floor) and float(np.linalg.norm(cin[k] - r_cin)) <= 0.5 * r_con:
                last, gap = k, 0
                r_con += (con[k] - r_con) / _RECENT
                r_cin = r_cin + (cin[k] - r_cin) / _RECENT
            else:
                gap += 1
                if gap > _BAND_GAP:
                    break
            k += step
        ends.append(last)
    return ends[0], ends[1] + 1


def evaluate_bands(lines, pairs, work, Bm, Ball, min_run, level=0, kind="all"):
    """The candidate bands `pairs` between `lines` judged along their chords (module
    docstring): a `RegionBand` for each whose run is at least min_run [work px] long.

    Bm: (h, w) the map the boundaries came from; Ball: (h, w) the level's "all" map (for
    the material difference); work: `shaft.work.WorkFrame`.
    """
    return evaluate_many([(lines, pairs, Bm, Ball, level, kind)], work, min_run)[0]


def _joined(sets):
    """The lines (`shaft.regions.BoundaryLines`) and pairs (`shaft.regions.RegionPairs`) of
    several (lines, pairs, ...) as one of each, the pairs' indices shifted to the joined
    lines; and the start of each set's pairs (len(sets) + 1,)."""
    L = [x[0] for x in sets]
    off = np.cumsum([0] + [len(q.p) for q in L])
    lines = BoundaryLines(**{f: np.concatenate([getattr(q, f) for q in L]) for f in ("p", "u", "n", "lo", "hi",
                                                                                     "support")})
    P = [x[1] for x in sets]
    pairs = RegionPairs(i=np.concatenate([q.i + o for q, o in zip(P, off)]),
                        j=np.concatenate([q.j + o for q, o in zip(P, off)]),
                        width=np.concatenate([q.width for q in P]), overlap=np.concatenate([q.overlap for q in P]))
    return lines, pairs, np.cumsum([0] + [len(q.i) for q in P])


def _per_set(starts, rows, sample, maps):
    """Each set's map (maps) sampled at its own rows' points: the (len(rows), ...) stack, in
    rows' order; rows: ascending indices into the joined pairs, starts: each set's first."""
    rows = np.asarray(rows, int)
    owner = np.searchsorted(starts, rows, side="right") - 1
    parts = [sample(rows[owner == k], maps[k]) for k in range(len(maps)) if np.any(owner == k)]
    return np.concatenate(parts)


def _map_part(B, X, Y):
    """(X, Y, part): a region map B (h, w) as float32 where the points (X, Y) (float32) read
    it: the bounding box of their bilinear neighbours (converting a whole map for a few
    bands cost more than sampling it), the points shifted into it. The shift by whole pixels
    is exact and every neighbour lies inside the box (or beyond the map's own border), so
    the samples are those of the whole map's."""
    h, w = B.shape[:2]
    if X.size == 0 or not (np.all(np.isfinite(X)) and np.all(np.isfinite(Y))):
        return X, Y, B.astype(np.float32)
    x0 = min(max(math.floor(X.min()) - 1, 0), w - 1)
    x1 = min(max(math.ceil(X.max()) + 2, x0 + 1), w)
    y0 = min(max(math.floor(Y.min()) - 1, 0), h - 1)
    y1 = min(max(math.ceil(Y.max()) + 2, y0 + 1), h)
    return X - x0, Y - y0, np.ascontiguousarray(B[y0:y1, x0:x1], dtype=np.float32)


def evaluate_many(sets, work, min_run):
    """`evaluate_bands` of several candidate sets at once: sets a list of (lines, pairs, Bm,
    Ball, level, kind); the list of each set's bands, the same values as one call per set.
    The bands of all sets share one geometry, labelling and sampling of the work frame (each
    map sampled at its own set's points): a region map has 2 candidate pairs in the median,
    and numpy's per-call overheads were most of the cost of judging them one map at a time."""
    if sum(len(x[1].i) for x in sets) == 0:
        return [[] for _ in sets]
    lines, pairs, starts = _joined(sets)
    g = _geometry(lines, pairs, work.shape)

    def sample(rows, im):
        X, Y, part = _map_part(im, g.X[rows], g.Y[rows])
        return _sampler(X, Y)(part)

    every = np.arange(len(pairs.i))
    sB = _per_set(starts, every, sample, [x[2] for x in sets])
    sV = _sampler(g.X, g.Y)(work.dist)
    lab, obs, fin, okL, okR, shaft = _labels(g, lines, pairs, sB, sV)
    sel = [m for m in range(len(pairs.i)) if g.good[m]]
    runs = {m: best_run(lab[m]) for m in sel}
    # a band the least length wide whose run the border may cut is kept from `CUT_RUN_WIDTHS`
    # widths (`proposed`'s cut says whether it is one)
    least = np.where(pairs.width >= min_run, np.minimum(min_run, CUT_RUN_WIDTHS * pairs.width), min_run)
    sel = [m for m in sel if (runs[m][1] - runs[m][0]) * g.step[m] >= least[m]]
    out = [[] for _ in sets]
    if not sel:
        return out
    sA = _per_set(starts, sel, sample, [x[3] for x in sets])
    sub = _sampler(g.X[sel], g.Y[sel])
    sY = sub(work.luma)
    sC = sub(work.colours) if work.bgr.ndim == 3 else sY[..., None]
    for q, m in enumerate(sel):
        k = int(np.searchsorted(starts, m, side="right")) - 1
        out[k].append(_band(g, lines, pairs, m, runs[m], obs, fin, okL, okR, shaft, sC[q], sA[q], sY[q], sets[k][4],
                            sets[k][5]))
    return out


def _band(g, lines, pairs, m, run_ends, obs, fin, okL, okR, shaft, cc, ca, cy, level, kind):
    """The `RegionBand` of candidate m (`evaluate_many`): its run [i0, i1), its colours cc
    (S, U, C), "all" map ca (S, U) and luma cy (S, U) samples."""
    i0, i1 = run_ends
    ext, reach, reach_run, view = _extension(obs[m], fin[m], i0, i1)
    # the strips' means over slices (`edges.mean_over`: the same values as of the masks' copies)
    cin = mean_over(cc, 1, _IN_S.start, _IN_S.stop)
    cL = np.linalg.norm(cin - mean_over(cc, 1, _SL_S.start, _SL_S.stop), axis=-1)
    cR = np.linalg.norm(cin - mean_over(cc, 1, _SR_S.start, _SR_S.stop), axis=-1)
    con = np.minimum(cL, cR)
    run = slice(i0, i1)
    fall, ang = _side_colours(cc[run], okL[m, run], okR[m, run], ca[run])
    yy = cy[run]
    ySL, ySR = float(np.mean(yy[:, _SL])), float(np.mean(yy[:, _SR]))
    li, lj = pairs.i[m], pairs.j[m]
    return RegionBand(
        lines=tuple((lines.p[k], lines.u[k], lines.n[k], float(lines.lo[k]), float(lines.hi[k])) for k in (li, lj)),
        C=g.C[m], ua=g.ua[m], na=g.na[m], oi=g.oi[m], oj=g.oj[m], run=(i0, i1), ext=ext, reach=reach,
        reach_run=reach_run, view=view, obs=obs[m], inside_colour=cin, contrast=con, step=float(g.step[m]),
        run_len=float((i1 - i0) * g.step[m]), shaft_len=float(np.count_nonzero(shaft[m, run]) * g.step[m]), fall=fall,
        ang=ang, y_in=float(np.mean(yy[:, _IN])), y_sides=(ySL, ySR),
        level=int(level), kind=kind,
        side_contrast=(float(median(cL[run][okL[m, run]])) if np.any(okL[m, run]) else np.nan,
                       float(median(cR[run][okR[m, run]])) if np.any(okR[m, run]) else np.nan))


def proposed(band, min_len, ang_thr, cut=False):
    """Whether a band is a shaft candidate by its region evidence (all [work px]): a
    material difference from both sides (not instrument-like there, or a colour direction
    more than ang_thr [deg] away), a run of at least min_len, shaft stations along min_len /
    2. Whether it is long and reaches the border is judged on its edges
    (`shaft.material_cue`): a shaft running into a drape of its own material is a short
    region band whose edges go on. cut: instead, whether it is a candidate of a shaft close to
    the lens seen to its collar, wider than it is long in view: at least min_len wide, its run
    cut by the border of the view and at least `CUT_RUN_WIDTHS` of its width."""
    side_ok = all((f <= FILL_SIDE) or (np.isfinite(a) and a > ang_thr) for f, a in zip(band.fall, band.ang))
    w = band.width_run
    long = (band.reach_run and w >= min_len and band.run_len >= CUT_RUN_WIDTHS * w) if cut else band.run_len >= min_len
    return bool(side_ok and long and band.shaft_len >= 0.5 * min_len)


def band_polygon(band, ends=None):
    """The band's outline (2 S', 2) [work px] over its run (or stations ends [i0, i1))."""
    i0, i1 = band.run if ends is None else ends
    C = band.C[i0:i1]
    a = C + band.oi[i0:i1, None] * band.na
    b = C + band.oj[i0:i1, None] * band.na
    return np.concatenate([a, b[::-1]]).astype(np.float32)


def suppress_overlaps(bands):
    """The bands (best first) that do not overlap a better one by more than `_NMS_OVERLAP`
    of the smaller one's area (convex hulls)."""
    import cv2

    kept, polys = [], []
    for e in bands:
        hull = cv2.convexHull(band_polygon(e))[:, 0, :]
        area = abs(cv2.contourArea(hull))
        if area <= 0:
            continue
        if any(cv2.intersectConvexConvex(hull, Q)[0] > _NMS_OVERLAP * min(area, abs(cv2.contourArea(Q)))
               for Q in polys):
            continue
        kept.append(e)
        polys.append(hull)
    return kept

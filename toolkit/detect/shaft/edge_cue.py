"""The edge cue of the shaft detector: bands between two long edges, judged along their
length, for frames whose colour tells no material apart (`shaft.detector`).

What tells a shaft from the other bands of a grey scene is not its grey level against its
surroundings (a grey metal shaft is darker than white paper and brighter than black print,
so its edges flip polarity along their length) but the band itself: a cylinder looks the
same all along its length (its shading depends only on the angle around its axis), whatever
lies behind it, it is seen from the image border (an instrument enters the view from
outside) to its tip, and both its edges end where it ends. The edge cue therefore works
with unsigned edges and judges whole bands:

1. *proposals*: a line detector (LSD by default) on a reduced copy of the image (fine texture
   averages out, the shaft's edges do not), fragments undistorted (those not in the valid
   region left out: `segments.in_valid_region`) and grouped along lines *whatever their polarity*
   (`segments.merge_collinear` on unsigned directions), gaps allowed; the groups with enough
   fragment support are the line hypotheses;
2. *edges*: the hypotheses that have a partner at a shaft's width are refitted at full
   resolution to the peak of the gradient *magnitude* across them (`edges.edge_profiles`
   at stations along the line, a robust weighted line fit, the best run of stations with
   gaps up to `max_gap_px`), so an edge whose polarity flips is one line;
3. *bands*: pairs of edges, converging by at most `max_convergence_deg`, at a width in
   `width_px_range`, overlapping. The cross-section of each candidate band is sampled at
   stations along its whole chord through the valid part of the image, from boundary to
   boundary, and each station is a shaft, neutral or contradicting one (`shaft.bands`). The
   band is the run of stations with the largest score: it runs from the shaft's tip to
   where the shaft leaves the view, across polarity flips, and stops where a planar
   structure stops looking like a band. Kept: bands with few contradicting stations
   (`max_background`), whose cross-section holds no strip of background (the gap between
   two instruments), with both edges seen along at least half of `min_length` and, with
   `from_border`, reaching the border of the view (the margins of a sheet and the rows of a
   board end inside it; the gap is measured in raw pixels), or, where no band does, clean
   ones. The score is the length along which the band is seen as a shaft. A band inside a
   wider one that shares an edge with it or runs along its axis (the strips beside a
   specular stripe) gives way to it when the wider one is clean and has a highlight;
4. *edges again*: each kept band's two edges are measured once more at paired stations
   across it (`shaft.axis.measure_edge_pair`), which gives the midline
   (`shaft.axis.midline_from_edges`).

Limits: a shaft seen only over a background of its own grey level, or only in part of its
length without reaching the border (pass ``from_border=False``), is found from what remains;
a band of paper that reaches the image border with a clean cross-section (a sheet running
out of the view) is a shaft candidate too, scored by the length along which both its edges
are seen, so give the width you expect (`width_px_range`) where that can happen.

Lengths in working pixels (`working`), the options those of `shaft.detector.detect_shafts`.

Example
-------
>>> import numpy as np
>>> unsigned_lines(np.array([[10.0, 0.0, 0.0, 5.0]])).tolist()
[[0.0, 5.0, 10.0, 0.0]]
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.edges import (
    MIN_STATIONS,
    derivative_kernel,
    edge_profiles,
    masked_median,
    relative_weights,
    robust_line_fit,
    station_counts,
    stations,
)
from pencilcal.toolkit.detect.pairs import antiparallel_pairs, pair_geometry
from pencilcal.toolkit.detect.segments import detect_fragments, in_valid_region, merge_collinear
from pencilcal.toolkit.detect.shaft.axis import measure_edge_pair
from pencilcal.toolkit.detect.shaft.bands import assess_bands, assess_chords, border_polygon, nested_bands
from pencilcal.toolkit.detect.working import to_raw, to_working_points
from pencilcal.toolkit.geometry.neighbours import pairs_within

__all__ = ["edge_cue", "bands_from_edges", "refit_edges", "unsigned_lines", "drop_repeated"]

_MAX_ONE_SIDED = 0.3  # largest fraction of a band's stations with exactly one of its edges


def unsigned_lines(lines):
    """Lines (M, 4) oriented with d_x > 0 (d_y > 0 when vertical): one direction per line,
    whatever the polarity of its edge."""
    out = np.array(lines, float).reshape(-1, 4)
    d = out[:, 2:] - out[:, :2]
    flip = (d[:, 0] < 0) | ((d[:, 0] == 0) & (d[:, 1] < 0))
    out[flip] = out[flip][:, [2, 3, 0, 1]]
    return out


def _both_ways(lines):
    """Unsigned lines (`unsigned_lines`) plus, for those within 6 deg of vertical (where that
    orientation turns over), a reversed copy: collinear lines always meet in one direction."""
    work = unsigned_lines(lines)
    d = work[:, 2:] - work[:, :2]
    near_v = np.abs(d[:, 0]) < np.sin(np.radians(6.0)) * np.hypot(d[:, 0], d[:, 1])
    return np.concatenate([work, work[near_v][:, [2, 3, 0, 1]]])


def drop_repeated(lines, support, tol_px=2.0, tol_deg=1.0):
    """Indices of the lines (M, 4) to keep: a line that repeats a better-supported one (both
    ends within tol_px of its line, directions within tol_deg either way, overlapping it by
    half the shorter) is dropped; the near-vertical groups come twice (`_both_ways`)."""
    M = lines.shape[0]
    if M < 2:
        return np.arange(M)
    p1, p2 = lines[:, :2], lines[:, 2:]
    d = p2 - p1
    L = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
    u = d / L[:, None]
    n = np.stack([-u[:, 1], u[:, 0]], -1)
    c = np.sum(n * p1, -1)
    par = np.abs(u @ u.T) > np.cos(np.radians(tol_deg))
    d1 = np.abs(p1 @ n.T - c[None, :])  # [j, i]: line j's first end from line i
    d2 = np.abs(p2 @ n.T - c[None, :])
    # ... and mostly within line i's extent
    a1 = p1 @ u.T - np.sum(u * p1, -1)[None, :]  # [j, i] along line i
    a2 = p2 @ u.T - np.sum(u * p1, -1)[None, :]
    lo, hi = np.minimum(a1, a2), np.maximum(a1, a2)
    ov = np.minimum(hi, L[None, :]) - np.maximum(lo, 0.0)
    on = (d1 < tol_px) & (d2 < tol_px) & par & (ov >= 0.5 * np.minimum(L[:, None], L[None, :]))
    order = np.argsort(-support, kind="stable")
    keep = np.ones(M, bool)
    for i in order:
        if keep[i]:
            dup = on[:, i] & keep
            dup[i] = False
            keep[dup] = False
    return np.flatnonzero(keep)


def _parallel_candidates(E, max_conv, max_dist):
    """Index pairs (a, b), a < b, of unsigned lines within max_conv of parallel whose
    centres are within max_dist + half their lengths (`pairs_within` on doubled angles)."""
    M = E.shape[0]
    if M < 2:
        return np.zeros(0, int), np.zeros(0, int)
    d = E[:, 2:] - E[:, :2]
    th2 = 2.0 * np.arctan2(d[:, 1], d[:, 0])
    v = np.stack([np.cos(th2), np.sin(th2)], -1)
    r = 2.0 * np.sin(min(max_conv, 1.5))
    pp = pairs_within(v, r)
    if pp.size == 0:
        return np.zeros(0, int), np.zeros(0, int)
    a, b = pp[:, 0], pp[:, 1]
    c = 0.5 * (E[:, :2] + E[:, 2:])
    L = np.hypot(d[:, 0], d[:, 1])
    near = np.linalg.norm(c[a] - c[b], axis=-1) <= max_dist + 0.5 * (L[a] + L[b])
    return a[near], b[near]


def _partnered(E, conv_max, wmin, wmax, min_overlap):
    """Which lines (M, 4) (unsigned) have a possible partner: a nearly parallel line at a
    distance in [wmin, wmax] overlapping it by min_overlap."""
    a, b = _parallel_candidates(E, conv_max, wmax)
    if a.size == 0:
        return np.zeros(E.shape[0], bool)
    pr = pair_geometry(*antiparallel_pairs(E, a, b))
    ok = (pr.width >= 0.7 * wmin) & (pr.width <= 1.2 * wmax + 3.0) & (pr.hi - pr.lo >= min_overlap)
    out = np.zeros(E.shape[0], bool)
    out[a[ok]] = True
    out[b[ok]] = True
    return out


# --------------------------------------------------------------------- edges (unsigned)


def _refit_unsigned(img, camera, lines, *, search, sigma_px, step_px, extend_px, max_gap_px, min_gradient,
                    rel_gradient=0.35, passes=2, max_stations=48, grow=False):
    """Refit lines (M, 4) (working px) to the unsigned edges beside them, growing them
    along the edge while it goes on (each pass looks max(extend_px, L / 4) beyond the ends
    of the run found so far, bridging gaps up to max_gap_px). Returns the refitted lines
    (M, 4) (the run of inlier stations), ok (M,) and the number of inlier stations (M,)."""
    kernel = derivative_kernel(sigma_px)
    P1, P2 = lines[:, :2].copy(), lines[:, 2:].copy()
    M = P1.shape[0]
    ok = np.zeros(M, bool)
    count = np.zeros(M, int)
    todo = np.arange(M)
    for it in range(passes):
        if todo.size == 0:
            break
        p1, p2 = P1[todo], P2[todo]
        d = p2 - p1
        L = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
        u = d / L[:, None]
        e = np.maximum(extend_px, 0.25 * L) if (it > 0 and grow) else np.full(L.shape, float(extend_px))
        lo, hi = -e, L + e
        cnt = station_counts(lo, hi, step_px, max_stations)
        s, st_valid = stations(lo, hi, cnt)
        p = edge_profiles(img, camera, p1, u, s, search, kernel, sigma_px, unsigned=True)
        a = np.abs(p.g)
        base = p.inside & p.found & st_valid & (a >= min_gradient)
        med = masked_median(a, base)
        base &= a >= rel_gradient * np.nan_to_num(med, nan=np.inf)[:, None]
        w = relative_weights(a, base)
        sm, tm, b, Sss, Wt, res, inl = robust_line_fit(s, p.t, w, base, max_gap_px)
        n_in = inl.sum(-1)
        good_fit = n_in >= MIN_STATIONS
        rows = np.arange(todo.size)
        k1 = np.argmax(inl, 1)
        k2 = s.shape[1] - 1 - np.argmax(inl[:, ::-1], 1)
        s1, s2 = s[rows, k1], s[rows, k2]
        n = np.stack([-u[:, 1], u[:, 0]], -1)
        q1 = p1 + s1[:, None] * u + (tm + b * (s1 - sm))[:, None] * n
        q2 = p1 + s2[:, None] * u + (tm + b * (s2 - sm))[:, None] * n
        # a pass that loses the line keeps the previous one
        upd = good_fit | (it == 0)
        P1[todo[upd]], P2[todo[upd]] = q1[upd], q2[upd]
        ok[todo[upd]] = good_fit[upd]
        count[todo[upd]] = n_in[upd]
        # look again where the window was off-centre, or where the edge runs on past the
        # stations looked at
        dev = np.maximum(np.abs(tm + b * (s1 - sm)), np.abs(tm + b * (s2 - sm)))
        touch = ((k1 <= 1) | (k2 >= cnt - 2)) & grow
        todo = todo[good_fit & ((dev > 0.5 * search) | touch)]
    return np.concatenate([P1, P2], -1), ok, count


def _edge_hypotheses(frag, o):
    """Step 1: line hypotheses (M, 4) (unsigned, working px) from the detector's fragments
    (N, 4): groups of collinear fragments, whatever their polarity, with enough support, that
    have a possible partner at a shaft's width; None when fewer than two."""
    merged, lab = merge_collinear(frag, 3.0, 1.5 / o.scale, o.max_gap_px)
    Lf = np.hypot(frag[:, 2] - frag[:, 0], frag[:, 3] - frag[:, 1])
    support = np.bincount(lab[lab >= 0], Lf[lab >= 0], merged.shape[0])
    hyp = unsigned_lines(merged[support >= 0.2 * o.min_length])
    if hyp.shape[0] < 2:
        return None
    hyp = hyp[_partnered(hyp, o.conv_max + np.radians(2.0), o.wmin, o.wmax, 0.1 * o.min_length)]
    return hyp if hyp.shape[0] >= 2 else None


def _shaft_edges(img, camera, hyp, o, sig_n):
    """Step 2: the unsigned edge lines (E, 4) [working px] of the hypotheses (M, 4), or None
    when fewer than two: each refitted to the unsigned edge, then joined whatever their
    polarity (accurate pieces, tight tolerances: the two edges of a thin shaft are not
    chained together through the clutter between them). sig_n: the image noise sd."""
    P, ok = refit_edges(img, camera, hyp, o, sig_n)
    Lp = np.hypot(P[:, 2] - P[:, 0], P[:, 3] - P[:, 1])
    P = P[ok & (Lp >= 0.1 * o.min_length)]
    if P.shape[0] < 2:
        return None
    P2 = _both_ways(P)
    joined, lab = merge_collinear(P2, 1.0, 1.5, o.max_gap_px)
    Lj = np.hypot(P2[:, 2] - P2[:, 0], P2[:, 3] - P2[:, 1])
    support = np.bincount(lab[lab >= 0], Lj[lab >= 0], joined.shape[0])
    good = support >= 0.25 * o.min_length
    E, support = unsigned_lines(joined[good]), support[good]
    E = E[drop_repeated(E, support)]
    return E if E.shape[0] >= 2 else None


# ------------------------------------------------------------------------------- bands


def _candidate_bands(img, camera, E, o, sig_n):
    """The pairs of edges E (M, 4) that may bound a shaft (`EdgePairs`, pieces of edges
    allowed: the band is traced along its whole chord later), those whose cross-section
    holds at 12 stations along the overlap; None when there are none (most strips of the
    scene's patterns, rows of a board several squares wide, contradict themselves there
    already)."""
    a, b = _parallel_candidates(E, o.conv_max, o.wmax)
    if a.size == 0:
        return None
    pr = pair_geometry(*antiparallel_pairs(E, a, b))
    ov = pr.hi - pr.lo
    ok = (pr.conv <= o.conv_max) & (pr.width >= o.wmin) & (pr.width <= o.wmax)
    ok &= ov >= 0.25 * o.min_length
    w0 = pr.signed_width_at(0.5 * (pr.lo + pr.hi))
    ok &= (pr.signed_width_at(pr.span_lo) * w0 > 0.25 * w0**2) & (pr.signed_width_at(pr.span_hi) * w0 > 0.25 * w0**2)
    pr = pr.take(np.flatnonzero(ok))
    if pr.a.size == 0:
        return None
    s0 = pr.lo[:, None] + np.linspace(0.04, 0.96, 12)[None, :] * (pr.hi - pr.lo)[:, None]
    q0 = assess_bands(img, camera, pr, s0, np.ones(s0.shape, bool), sig_n, o.sigma_px, full=False)
    pr = pr.take(np.flatnonzero(q0.n_shaft >= 5))
    return pr if pr.a.size else None


def _chords(img, camera, pr, o, sig_n, poly):
    """A coarse look along each band's whole chord through the image (48 stations), then a
    fine one (every 5 px) at the most promising: the best 16, those that enter from the
    border first, and always the best few that do not (where none of the former holds up,
    they are what the from_border fallback judges: an instrument whose back end is in view,
    a short one, a wide-angle lens). Returns (pairs, `BandChords`) or None."""
    ch = assess_chords(img, camera, pr, poly, sig_n, o.sigma_px, o.border_px, 48, full=False)
    q = ch.q
    score = q.n_shaft * ch.step
    ok = (q.best > 0) & (score >= 0.3 * o.min_length) & (q.one_sided <= 0.4) & (q.contra <= 0.35)
    cand = np.flatnonzero(ok)
    if cand.size == 0:
        return None
    touch = ch.touch
    cand = cand[np.lexsort((-score[cand], ~touch[cand]))]
    cand = np.concatenate([cand[:16], cand[16:][~touch[cand[16:]]][:4]])
    pr = pr.take(cand)
    return pr, assess_chords(img, camera, pr, poly, sig_n, o.sigma_px, o.border_px, 300, min_step=5.0)


def _kept_bands(pr, ch, M, o):
    """(K,) bool: the bands that are shafts (module docstring, step 3); M the number of
    edges (the pairs index edges reversed beyond it)."""
    q = ch.q
    score = q.n_shaft * ch.step
    ok = (score >= 0.5 * o.min_length) & (q.contra <= o.max_background) & (q.bg <= o.max_background)
    ok &= q.best > 0
    ok &= q.n_shaft >= o.min_support * (q.j - q.i + 1)
    # a cylinder's two silhouettes see alike backgrounds: where one edge is lost, mostly so
    # is the other; a strip of a planar pattern loses one side at a time (a sheet's margin
    # beside the white squares of a board)
    ok &= q.one_sided <= _MAX_ONE_SIDED
    if not np.any(ok):
        return ok
    # nested bands give way to the band around them when they are parts of a shaft with a
    # specular stripe (module docstring, step 3); the band around them enters from the
    # border if they do (the stripe may be seen where an edge is hidden)
    inside = nested_bands(pr, ch.lo_run, ch.hi_run)
    Ea, Eb = pr.a % M, pr.b % M
    shares = ((Ea[:, None] == Ea[None, :]) | (Ea[:, None] == Eb[None, :])
              | (Eb[:, None] == Ea[None, :]) | (Eb[:, None] == Eb[None, :]))
    cq = pr.point(0.5 * (ch.lo_run + ch.hi_run))
    off_axis = np.abs(np.einsum("id,jd->ij", pr.N, cq) + pr.C[:, None])
    parallel = np.abs(np.einsum("id,jd->ij", pr.D, pr.D)) > np.cos(np.radians(3.0) + pr.conv[:, None])
    along_axis = parallel & (off_axis < 0.25 * pr.width[:, None])
    wider = pr.width[:, None] > pr.width[None, :] + 2.0
    outer_ok = ok & (q.bg <= 0.1) & (q.glare >= 0.3)
    gives = inside & wider & (shares | along_axis) & outer_ok[:, None] & ok[None, :] \
        & (score[:, None] >= 0.5 * score[None, :])  # [i, j]: j gives way to i
    nested = np.any(gives, 0)
    touch = ch.touch | np.any(gives & ch.touch[None, :], 1)
    ok &= ~nested
    if o.from_border:
        if np.any(ok & touch):
            ok &= touch
        else:
            # none enters from the border (the instrument's back end is in view: a short one, a
            # wide-angle lens; or its near part is hidden): only a clean band will do, with
            # little background or contradiction inside. Its one-sided stations count as for
            # any band: they tell what lies beside a shaft (on a textured table up to 0.3 of
            # them for shafts that do enter from the border), not where the shaft begins
            ok &= (q.bg <= 0.1) & (q.contra <= 0.1) & (q.one_sided <= _MAX_ONE_SIDED)
    return ok


def _alternatives(pr, ch, ok, score):
    """One band found from several pairs of pieces of its edges: the best one stays, the
    others stand by (where the axis of the best cannot be measured, its pieces of edges
    being too short to extrapolate, the next one is measured instead). Returns {band:
    [itself, its stand-ins]} and clears the stand-ins in ok (in place)."""
    cq = pr.point(0.5 * (ch.lo_run + ch.hi_run))
    order = np.argsort(-np.where(ok, score, -np.inf), kind="stable")
    alts = {}
    for ii, k in enumerate(order):
        if not ok[k]:
            continue
        alts[k] = [k]
        for k2 in order[ii + 1:]:
            if ok[k2] and abs(float(pr.N[k] @ cq[k2] + pr.C[k])) < 0.25 * pr.width[k] + 1.0 \
                    and abs(float(pr.D[k] @ pr.D[k2])) > np.cos(np.radians(2.0)) \
                    and abs(pr.width[k2] - pr.width[k]) < 0.25 * pr.width[k] + 2.0:
                ok[k2] = False
                alts[k].append(k2)
    return alts


def _chosen(pr, ok, score, M, o):
    """The bands to measure, best first, each edge in one shaft, at most max_shafts, none
    below min_score_ratio of the best's score."""
    Ea, Eb = pr.a % M, pr.b % M
    used = np.zeros(M, bool)
    chosen = []
    for k in np.argsort(-np.where(ok, score, -np.inf), kind="stable"):
        if not ok[k] or used[Ea[k]] or used[Eb[k]]:
            continue
        used[Ea[k]] = used[Eb[k]] = True
        chosen.append(k)
        if len(chosen) >= o.max_shafts:
            break
    return [k for k in chosen if score[k] >= o.min_score_ratio * score[chosen[0]]]


# -------------------------------------------------------------------------------- axis


def _measure(img, camera, pr, ch, k, o):
    """`shaft.axis.measure_edge_pair` of band k over its run; the slope correction only for a
    band wider than twice the profile's reach (on a thinner one the slopes would be read
    off the other edge)."""
    sk, shk = ch.s[k], ch.q.shaft[k]
    lo, hi = ch.lo_run[k], ch.hi_run[k]

    def shaft_at(sv):
        idx = np.clip(np.rint((sv - sk[0]) / (sk[1] - sk[0])).astype(int), 0, sk.size - 1)
        return shk[idx]

    reach = o.search_px + 3.0 * o.sigma_px + 2.5 + 3.0 * o.sigma_px
    one = pr.take(np.array([k]))
    wide = min(abs(float(one.signed_width_at(np.array([lo]))[0])),
               abs(float(one.signed_width_at(np.array([hi]))[0]))) > 2 * reach
    return measure_edge_pair(img, camera, pr, k, lo, hi, shaft_at, o.search_px, o.sigma_px,
                             o.slope_correction and wide, o.gamma)


def _view_polygon(camera, img):
    """The border of the view in working pixels, a closed polygon (P, 2): the outline of
    the `GrayImage`'s valid region (its sides densified to follow the lens), or the image
    border (`shaft.bands.border_polygon`) without one."""
    H, W = img.shape
    if img.region is None:
        return border_polygon(camera, W, H)
    raw = np.asarray(img.region.outline((H, W)), float)
    q = np.linspace(0.0, 1.0, 16, endpoint=False)[None, :, None]
    dense = (raw[:-1, None, :] + q * (raw[1:] - raw[:-1])[:, None, :]).reshape(-1, 2)
    work = to_working_points(camera, dense)
    work = work[np.all(np.isfinite(work), -1)]
    return np.concatenate([work, work[:1]]) if len(work) >= 3 else border_polygon(camera, W, H)


def edge_cue(img, camera, o, sig_n):
    """Shafts by the edge cue (module docstring): a list of (edges (2,) `EdgeLine`, score
    [px], polarity "dark" / "bright") per shaft, best score first.

    img: `image.GrayImage` (with its valid region: proposals and profiles keep inside it);
    camera: Camera or None; o: the options of `shaft.detector.detect_shafts` (`shaft.detector.ShaftOptions`);
    sig_n: the image noise sd.
    """
    frag = detect_fragments(img, o.detector, camera, o.detector_params, min_fragment=8.0, scale=o.scale)[1]
    frag = frag[in_valid_region(img, to_raw(camera, frag))]
    if frag.shape[0] < 2:
        return []
    hyp = _edge_hypotheses(frag, o)
    if hyp is None:
        return []
    E = _shaft_edges(img, camera, hyp, o, sig_n)
    return [] if E is None else bands_from_edges(img, camera, E, o, sig_n)


def refit_edges(img, camera, lines, o, sig_n):
    """Lines (M, 4) [working px] refitted to the unsigned edges beside them (within
    `search_px`), as the edge cue refits its hypotheses (step 2): (lines (M, 4), ok (M,))."""
    P, ok, _ = _refit_unsigned(img, camera, np.asarray(lines, float).reshape(-1, 4), search=o.search_px,
                               sigma_px=o.sigma_px, step_px=3.0, extend_px=5.0, max_gap_px=o.max_gap_px,
                               min_gradient=max(2.0, 1.5 * sig_n))
    return P, ok


def bands_from_edges(img, camera, E, o, sig_n):
    """Steps 3 and 4 of the edge cue on the unsigned edge lines E (M, 4) [working px]: the
    shafts between them, as `edge_cue` returns them (also what tracking from frame to frame
    gives its edges to: `shaft.detector.track_shafts`)."""
    if E.shape[0] < 2:
        return []
    pr = _candidate_bands(img, camera, E, o, sig_n)
    found = None if pr is None else _chords(img, camera, pr, o, sig_n, _view_polygon(camera, img))
    if found is None:
        return []
    pr, ch = found
    ok = _kept_bands(pr, ch, E.shape[0], o)
    if not np.any(ok):
        return []
    score = ch.q.n_shaft * ch.step
    alts = _alternatives(pr, ch, ok, score)
    out = []
    for k0 in _chosen(pr, ok, score, E.shape[0], o):
        for k in alts[k0]:
            m = _measure(img, camera, pr, ch, k, o)
            if m is not None:
                out.append((m, float(score[k]), "dark" if ch.q.dark[k] else "bright"))
                break
    return out

"""Assignment of unlabelled image lines to the spokes of a known pencil.

The segments found in an image carry no labels. The map from spoke angles to image line
directions is a 1-D homography, ``(cos a, sin a) ~ H (cos theta, sin theta)`` with H a 2x2
matrix (in normalised coordinates H = [[1, 0, -x], [0, 1, -y]] R[:, :2]), so three lines
with known spokes predict every other line. Hypotheses pair a triple of observed lines
with a triple of spokes in the same cyclic order (a pencil seen from its front keeps the
cyclic order of its spokes, i.e. det H > 0), allowing up to `max_gap` missing spokes or
spurious lines between the chosen ones. Each is scored by MSAC over all lines; the best
seeds an exact fit (estimator.fit_pencil), whose predictions then re-assign every line with
a tolerance set by its own angle sigma, and the fit is repeated.

Regular fans are partly self-similar: a frontal view of 8 spokes 20 deg apart with one
spoke missing is explained equally well with every label shifted by one. The result says
so (`labels_ambiguous`) rather than pretending to know the in-plane angle.

Spokes all around the vertex (a Siemens star's 128 edges) make the exhaustive screen too
large (O(M^2 N^2) residuals): there every hypothesis is scored only on the lines and spokes
next to its triple in the cyclic order (`_local_screen`), where a right triple predicts its
neighbours well and a wrong one does not, and the labelling then grows from it: each refit
labels the lines whose spoke it now predicts well enough to tell from its neighbours, until
nothing changes. Lines and spokes may have a *kind* (an edge's polarity: which side is
brighter): a line is then only ever given a spoke of its kind.

All angles are radians in normalised image coordinates.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pencilcal.toolkit.geometry.angles import wrap_angle, wrap_line
from pencilcal.toolkit.geometry.frames import rotvec_from_rotation
from pencilcal.toolkit.geometry.quantiles import chi2_isf
from pencilcal.toolkit.errors import EstimationError
from pencilcal.toolkit.pencil.defaults import CHI2_1_99, CHI2_2_DETECTION, DETECTION_LEVEL
from pencilcal.toolkit.pencil.estimator import fit_pencil, pencil_jacobian, PencilFit
from pencilcal.toolkit.pencil.sequence_noise import inflation

__all__ = ["Assignment", "assign_spokes", "grow_labels", "GROWTH_EVIDENCE", "GROWTH_AGREE", "GROWTH_LIKELIHOOD_LINES",
           "SCREEN_KEEP_LINES"]

# distinct labellings refitted after the MSAC screen
_TOP = 4
# refits of one labelling at most while it grows (a full circle of spokes grows from three
# neighbouring lines in a dozen or so)
_MAX_GROWTH = 64
# with this many assigned lines or fewer, every order-keeping labelling is fitted (batched)
_EXHAUSTIVE_MAX_LINES = 5
_EXHAUSTIVE_MAX_FITS = 5000
# The MSAC screen compares each of K hypotheses' N predicted spokes with each of the M lines:
# K M N residuals, K = (M G^2)(N G^2) with G = max_gap + 1, so O(M^2 N^2) in all. It runs in
# blocks of at most _SCORE_BLOCK residuals (16 MB per temporary; the memory no longer grows
# with the inputs), and scores at most _MAX_SCORE_WORK residuals in all (a second or two):
# beyond that, a seeded sample of the hypotheses (as vertex.intersect_lines samples pairs).
_SCORE_BLOCK = 1 << 21
_MAX_SCORE_WORK = 1 << 26
#: `grow_labels` gives a line its nearest predicted spoke only where that spoke explains it
#: better than the next predicted spoke of its kind by this much chi2 (odds of 1000 to 1),
#: the line's sd and the prediction's (from the fit's covariance) together
GROWTH_EVIDENCE = 2.0 * np.log(1000.0)
#: and keeps a grown labelling only while its refit explains the lines labelled before
#: within this rise of their chi2 (the chi2(3) quantile of 99.73 %, three sigmas), and, from
#: fewer than `GROWTH_LIKELIHOOD_LINES` lines, while its rotation also lies within it of
#: the last fit's by that fit's covariance (`_still_explained`)
GROWTH_AGREE = chi2_isf(1.0 - 0.9973, 3)
#: from this many labelled lines a grown labelling's refit is judged by how well it explains
#: them alone (fewer fit any rotation near theirs: three of them exactly), as `floored` and
#: `scatter` estimate the lines' shared error from 8 lines
GROWTH_LIKELIHOOD_LINES = 8
#: the local screen's labelling of a dense pencil's window stands, where its refinement
#: would label fewer lines, from this many lines (a right window labels 12-13 of the 13 it
#: looks at; wrong ones on small stars' sparse, noisy lines 5-8) that its fit explains
SCREEN_KEEP_LINES = 10


@dataclass(frozen=True)
class Assignment:
    """Labels of the observed lines and the fit they give.

    spoke: (M,) index into the pencil's spokes for each observed line, -1 if rejected.
    fit: the PencilFit on the assigned lines (batch shape ()).
    rivals: other labellings that explain as many lines about as well (chi-square within
        the detection quantile), or one line fewer about as well once that line is charged
        the 99% quantile of a squared residual and they label some line differently, as
        (spoke (M,), PencilFit) pairs. A regular fan's labels
        shifted by one spoke are a rival with the same normal (only the in-plane angle is
        unknown); a rival found by coincidence can have another normal.
    hypotheses: number of hypotheses scored.
    chance_lines: the number of the lines, besides the three any labelling fits exactly,
        expected within the assignment tolerance of some predicted spoke by chance alone
        (random directions): sum over the lines of min(1, 2 tol_k N' / period), N' distinct
        spoke directions. At 1 or more the labelling may not tell the pencil's lines from
        the clutter's: several labellings, each with lines that merely happen to fit, can
        then be as good as the true one (`clutter_ambiguous`), unless it labels far more
        lines than chance would.
    """

    spoke: np.ndarray
    fit: PencilFit
    rivals: list
    hypotheses: int
    chance_lines: float = 0.0

    @property
    def clutter_ambiguous(self) -> bool:
        """True when random lines would fit the labelling's spokes (`chance_lines` >= 1) and
        chance alone would label as many lines as it does beyond three (a Poisson count of
        mean `chance_lines` reaching them) with probability above the detection level: a
        Siemens star's 128 edges leave nine chance matches expected, but not 125."""
        if self.chance_lines < 1.0:
            return False
        from scipy.special import gammainc

        m = int(np.sum(self.spoke >= 0)) - 3
        return m <= 0 or float(gammainc(m, self.chance_lines)) > DETECTION_LEVEL

    @property
    def labels_ambiguous(self) -> bool:
        """True when another labelling explains the lines about as well (`rivals`)."""
        return bool(self.rivals)


def _conflict(lab, ref):
    """True when some line has a spoke in both labellings and not the same one."""
    both = (lab >= 0) & (ref >= 0)
    return bool(np.any(lab[both] != ref[both]))


def _triples(n, G):
    """Index triples (i, i+g1, i+g1+g2) mod n with 1 <= g <= G, all distinct. -> (T, 3)."""
    out = []
    for i in range(n):
        for g1 in range(1, G + 1):
            for g2 in range(1, G + 1):
                if g1 + g2 < n:
                    out.append((i, (i + g1) % n, (i + g1 + g2) % n))
    return np.array(out, int).reshape(-1, 3)


def _homographies(a, th):
    """Null vectors of the 3x4 DLT systems: a, th (K, 3) -> H (K, 2, 2).

    Row k: [sin a cos t, sin a sin t, -cos a cos t, -cos a sin t] . vec(H) = 0. The null
    vector of a 3x4 matrix is its generalised cross product (signed 3x3 minors).
    """
    ca, sa, ct, st = np.cos(a), np.sin(a), np.cos(th), np.sin(th)
    c = [sa * ct, sa * st, -ca * ct, -ca * st]  # the four columns, each (K, 3)

    def det3(p, q, r):
        return (p[:, 0] * (q[:, 1] * r[:, 2] - q[:, 2] * r[:, 1])
                - p[:, 1] * (q[:, 0] * r[:, 2] - q[:, 2] * r[:, 0])
                + p[:, 2] * (q[:, 0] * r[:, 1] - q[:, 1] * r[:, 0]))

    h = np.stack([det3(c[1], c[2], c[3]), -det3(c[0], c[2], c[3]), det3(c[0], c[1], c[3]), -det3(c[0], c[1], c[2])], -1)
    return h.reshape(-1, 2, 2)


def _one_per_spoke(labels, sigma):
    """Keep one line per spoke, the most precise: two segments of one spoke (fragments of
    the same bar) are not independent measurements and must not count twice. (M,) -> (M,)."""
    out = labels.copy()
    for k in np.unique(labels[labels >= 0]):
        idx = np.flatnonzero(labels == k)
        if idx.size > 1:
            out[idx[idx != idx[np.argmin(sigma[idx])]]] = -1
    return out


def _exhaustive(a, th, s, used, labels, fit, rivals, vertex, vertex_cov, oriented, period, kinds=None):
    """All cyclic-order-preserving labellings of the used lines (of their kinds, when
    `kinds` = (line kinds (M,), spoke kinds (N,)) is given), fitted in one batch.

    Returns (labels, fit, rivals) with the best labelling first and every other within the
    chi-square detection quantile of it as a rival."""
    from itertools import combinations
    from math import comb

    li = np.flatnonzero(used)
    li = li[np.argsort(np.remainder(a[li], period))]
    m = li.size
    order = np.argsort(np.remainder(th, period))
    if comb(order.size, m) * m > _EXHAUSTIVE_MAX_FITS:  # counted before any is made
        return labels, fit, rivals
    combos = list(combinations(order.tolist(), m))
    lab = np.array([[c[(i + r) % m] for i in range(m)] for c in combos for r in range(m)])  # (B, m)
    if kinds is not None:
        lab = lab[np.all(kinds[1][lab] == kinds[0][li], -1)]
        if len(lab) == 0:
            return labels, fit, rivals
    B = len(lab)
    fits = fit_pencil(np.broadcast_to(a[li], (B, m)), th[lab], np.broadcast_to(vertex, (B, 2)),
                      sigma=np.broadcast_to(s[li], (B, m)), vertex_cov=vertex_cov, oriented=oriented)
    chi2 = np.asarray(fits.chi2)
    best = int(np.argmin(chi2))
    M = a.size

    def full(b):
        out = np.full(M, -1)
        out[li] = lab[b]
        return out

    def one(b):
        return PencilFit(**{k: (v[b] if isinstance(v, np.ndarray) and v.shape[:1] == (B,) else v)
                            for k, v in fits.__dict__.items()})

    if chi2[best] < float(fit.chi2) - 1e-9 * max(1.0, float(fit.chi2)):
        labels, fit = full(best), one(best)
    ref = float(fit.chi2)
    rivals = [(full(b), one(b)) for b in np.flatnonzero(chi2 - ref < CHI2_2_DETECTION)
              if not np.array_equal(full(b), labels)]
    return labels, fit, rivals


def _score(a, period, sigma_tol, H, ct, st, kinds=None):
    """Nearest predicted spoke and MSAC cost for each hypothesis.

    a: (M,) observed; H: (K, 2, 2); ct, st: (N,); kinds: None or (line kinds (M,), spoke
    kinds (N,)): a line is only compared with spokes of its kind. Returns (cost (K,),
    nearest (K, M), residual (K, M)).
    """
    px = H[:, 0, 0, None] * ct + H[:, 0, 1, None] * st  # (K, N)
    py = H[:, 1, 0, None] * ct + H[:, 1, 1, None] * st
    p = np.arctan2(py, px)
    wrap = wrap_angle if period > np.pi else wrap_line
    res = wrap(a[None, :, None] - p[:, None, :])  # (K, M, N)
    if kinds is not None:
        res = np.where(kinds[0][:, None] == kinds[1][None, :], res, np.pi)
    k = np.argmin(np.abs(res), -1)
    r = np.take_along_axis(res, k[..., None], -1)[..., 0]
    cost = np.minimum((r / sigma_tol) ** 2, 1.0).sum(-1)
    return cost, k, r


def assign_spokes(line_angles, spoke_angles, vertex, sigma, vertex_cov=None, oriented=True,
                  max_gap=2, tolerance_sigmas=4.0, line_kind=None, spoke_kind=None):
    """Label observed lines with spokes and fit the pencil.

    line_angles: (M,) [rad] observed image angles (normalised coordinates), oriented from
        the vertex outwards when `oriented`, else lines (period pi).
    spoke_angles: (N,) [rad] the pencil's spokes in the target frame.
    vertex: (2,) normalised vertex; vertex_cov: (2, 2) or None.
    sigma: scalar or (M,) [rad] angle standard deviation of each observed line.
    max_gap: spokes missing, or spurious lines, tolerated between two hypothesis lines.
    tolerance_sigmas: a line is assigned to the predicted spoke within this many sigmas of
        the residual (its own angle noise and the prediction's uncertainty from the fitted
        rotation and the vertex; never tighter than 0.01 deg), once that many sigmas are
        within the largest tolerance (0.45 of the smallest gap between spokes): a spoke
        predicted less surely than that is left for a later refit to label.
    line_kind, spoke_kind: (M,), (N,) integers, or None: a line is only given a spoke of its
        own kind (an edge's polarity: which side of it is brighter).
    Returns an `Assignment`. Raises EstimationError when fewer than three spokes can be
    matched.

    Example
    -------
    >>> import numpy as np
    >>> from pencilcal.toolkit.geometry.frames import rotation_from_rotvec
    >>> from pencilcal.toolkit.pencil.spec import image_angles
    >>> R = rotation_from_rotvec([0.4, 0.3, 0.2]); x = np.array([0.05, 0.1])
    >>> spokes = np.radians(np.arange(8) * 20.0)
    >>> seen = image_angles(R, x, spokes)[[6, 0, 2, 4, 5, 7]]     # shuffled, two missing
    >>> res = assign_spokes(np.r_[seen, 0.3], spokes, x, np.radians(0.1))  # one spurious line
    >>> res.spoke.tolist(), res.labels_ambiguous
    ([6, 0, 2, 4, 5, 7, -1], False)
    >>> # without both end spokes a regular fan is self-similar: the labels could all shift
    >>> assign_spokes(image_angles(R, x, spokes)[1:7], spokes, x, np.radians(0.1)).labels_ambiguous
    True
    """
    a = np.asarray(line_angles, float).reshape(-1)
    th = np.asarray(spoke_angles, float).reshape(-1)
    M, N = a.size, th.size
    kinds = None
    if line_kind is not None and spoke_kind is not None:
        kinds = (np.asarray(line_kind, int).reshape(M), np.asarray(spoke_kind, int).reshape(N))
    s = np.broadcast_to(np.asarray(sigma, float), (M,)).copy()
    if M < 3:
        raise EstimationError(f"fewer than three lines through the vertex ({M})")
    if N < 3:
        raise EstimationError(f"the pencil has fewer than three spokes ({N})")
    period = 2 * np.pi if oriented else np.pi
    # tolerance: a few sigmas, at least 0.25 deg (a 3-line prediction is noisier than one
    # line) and below half the smallest spoke gap so neighbours are not confused
    gaps = np.diff(np.r_[np.sort(np.remainder(th, period)), np.sort(np.remainder(th, period))[0] + period])
    cap = 0.45 * max(np.min(gaps), 1e-6)
    tol = np.clip(5.0 * s, np.radians(0.25), cap)
    nearest, resid, scored = _screen(a, th, oriented, period, max_gap, tol, 4 * _TOP, kinds)
    fitter = _LabelFitter(a, th, s, vertex, vertex_cov, oriented, tolerance_sigmas, cap, kinds)
    candidates = _candidates(nearest, resid, tol, s, fitter)
    labels, fit, rivals, fewer = _best_and_rivals(candidates)
    used = labels >= 0
    if _EXHAUSTIVE_MAX_LINES >= used.sum() >= 3:
        # few lines: one redundancy or two, and many spoke subsets share a cross-ratio; fit
        # every labelling that keeps the cyclic order (a few hundred, batched) so that no
        # equally good labelling is missed
        labels, fit, rivals = _exhaustive(a, th, s, used, labels, fit, rivals, vertex, vertex_cov, oriented, period,
                                          kinds)
        rivals += [r for r in fewer if _conflict(r[0], labels)]
    else:
        rivals += fewer
        rivals += _shifted_rivals(fitter, labels, fit, rivals, period)
    return Assignment(spoke=labels, fit=fit, rivals=rivals, hypotheses=scored,
                      chance_lines=_chance_lines(fitter, fit, period, fitter.scatter(fit, labels)))


def _chance_lines(fitter, fit, period, scale=1.0):
    """Lines (besides the three a hypothesis fits exactly) expected by chance within the
    tolerance of a predicted spoke of `fit` (its variance factor `scale`): a random
    direction falls within tol_k of one of N' distinct spoke directions with probability
    min(1, 2 tol_k N' / period)."""
    _, _, tol = fitter.match(fit, scale)
    if fitter.kinds is None:
        dirs = np.unique(np.round(np.remainder(fitter.th, period), 9)).size
    else:  # a line can only match the spokes of its kind
        dirs = np.array([np.unique(np.round(np.remainder(fitter.th[fitter.kinds[1] == k], period), 9)).size
                         for k in fitter.kinds[0]])
    q = np.minimum(1.0, 2.0 * tol * dirs / period)
    return float(max(0.0, q.sum() - np.sort(q)[-3:].sum()))


def _ordered_triples(a, th, oriented, period, max_gap):
    """The triples a hypothesis pairs: of observed lines a (M,) and of spokes th (N,), each
    in cyclic order with up to `max_gap` missing spokes or spurious lines between the chosen
    ones. Returns (obs (To, 3) indices into a, spk (Ts, 3) indices into th); To = M G^2 and
    Ts = N G^2 at most, G = max_gap + 1."""
    M = a.size
    # cyclic order of observed lines and of spokes (for lines, spokes modulo pi)
    oa = np.argsort(np.remainder(a, period))
    sp_mod = np.remainder(th, period)
    ot = np.argsort(sp_mod)
    if not oriented:
        # spokes pi apart are the same line: keep one of them for hypotheses
        keep = np.r_[True, np.diff(sp_mod[ot]) > 1e-9]
        ot = ot[keep]
    G = max_gap + 1
    to = _triples(M, G)
    ts = _triples(ot.size, G)
    if to.size == 0 or ts.size == 0:
        raise EstimationError("fewer than three distinct lines or spokes to match")
    return oa[to], ot[ts]


def _orientation_sign(H, A3, T3):
    """(K,) the sign of each homography H (K, 2, 2) that best reproduces the orientation
    of its three lines A3 (K, 3) from the spokes T3 (K, 3) [rad]."""
    pxy = np.einsum("kij,kjl->kil", H, np.stack([np.cos(T3), np.sin(T3)], 1))  # (K, 2, 3)
    return np.sign((pxy[:, 0] * np.cos(A3) + pxy[:, 1] * np.sin(A3)).sum(-1))


def _homography_ok(H, A3, T3, oriented):
    """(K,) bool: the homographies H (K, 2, 2) of line angles A3 (K, 3) and spoke angles T3
    (K, 3) [rad] that reproduce their three lines (with their orientation when
    `oriented`) and see the pencil from its front (det H > 0, cyclic order kept)."""
    valid = np.all(np.isfinite(H.reshape(-1, 4)), -1) & (np.abs(H).reshape(-1, 4).max(-1) > 0)
    sgn = np.ones(len(H))
    if oriented:
        sgn = _orientation_sign(H, A3, T3)
        pxy = np.einsum("kij,kjl->kil", H, np.stack([np.cos(T3), np.sin(T3)], 1))
        dots = pxy[:, 0] * np.cos(A3) + pxy[:, 1] * np.sin(A3)
        valid &= np.all(dots * sgn[:, None] > 0, -1)
    # det(s H) = det(H) for 2x2 matrices: the sign does not change it
    return valid & (np.linalg.det(H) > 0)


def _valid_homographies(A3, T3, oriented):
    """Homographies H (K', 2, 2) of the hypotheses pairing line angles A3 (K, 3) with spoke
    angles T3 (K, 3) [rad], kept when they reproduce their three lines (with their
    orientation when `oriented`) and see the pencil from its front (det H > 0, cyclic
    order kept)."""
    H = _homographies(A3, T3)
    valid = _homography_ok(H, A3, T3, oriented)
    if oriented:
        H = H * _orientation_sign(H, A3, T3)[:, None, None]
    return H[valid]


def _screen(a, th, oriented, period, max_gap, tol, keep, kinds=None, seed=0):
    """MSAC screen of every hypothesis (`_ordered_triples` x `_valid_homographies`), in
    blocks, keeping the `keep` best.

    a: (M,) [rad] observed; th: (N,) [rad] spokes; tol: (M,) [rad] each line's tolerance;
    kinds: None or (line kinds (M,), spoke kinds (N,)): triples pair lines and spokes of
    the same kinds, and lines are scored only against spokes of their kind. Memory stays
    under a few blocks of `_SCORE_BLOCK` residuals whatever M and N; when all hypotheses
    would need more than `_MAX_SCORE_WORK` residuals, each is scored on its neighbours
    only (`_local_screen`). Returns (nearest (k, M) spoke of each line, resid (k, M)
    [rad] its residual, for the k <= keep best hypotheses in order of cost; the number of
    hypotheses scored). EstimationError when none is valid.
    """
    obs, spk = _ordered_triples(a, th, oriented, period, max_gap)
    if kinds is not None:
        io, js = _same_kinds(obs, spk, kinds)
    else:
        io, js = None, None
    per_hyp = a.size * th.size  # residuals of one hypothesis
    total = len(obs) * len(spk) if io is None else io.size
    if total * per_hyp > _MAX_SCORE_WORK:
        return _local_screen(a, th, oriented, period, max_gap, tol, keep, kinds, obs, spk, io, js, seed)
    block = max(1, _SCORE_BLOCK // per_hyp)
    ct, st = np.cos(th), np.sin(th)
    costs, nearest, resid, scored = [], [], [], 0
    for start in range(0, total, block):
        f = np.arange(start, min(start + block, total))
        bo, bs = np.divmod(f, len(spk)) if io is None else (io[f], js[f])
        H = _valid_homographies(a[obs[bo]], th[spk[bs]], oriented)
        if len(H) == 0:
            continue
        cost, k, r = _score(a, period, tol, H, ct, st, kinds)
        best = np.argsort(cost)[:keep]
        costs.append(cost[best]), nearest.append(k[best]), resid.append(r[best])
        scored += len(H)
    if not scored:
        raise EstimationError("no consistent assignment of lines to spokes (cyclic order never matches)")
    order = np.argsort(np.concatenate(costs), kind="stable")[:keep]  # blocks' bests, in order
    return np.concatenate(nearest)[order], np.concatenate(resid)[order], scored


def _same_kinds(obs, spk, kinds):
    """The pairs (io, js) of line triples obs (To, 3) and spoke triples spk (Ts, 3) whose
    kinds agree element by element."""
    code_o = kinds[0][obs] @ np.array([9, 3, 1]) if obs.size else np.zeros(0, int)
    code_s = kinds[1][spk] @ np.array([9, 3, 1]) if spk.size else np.zeros(0, int)
    io, js = [], []
    for c in np.unique(code_o):
        o, t = np.flatnonzero(code_o == c), np.flatnonzero(code_s == c)
        io.append(np.repeat(o, t.size)), js.append(np.tile(t, o.size))
    return (np.concatenate(io), np.concatenate(js)) if io else (np.zeros(0, int), np.zeros(0, int))


#: Lines on either side of a hypothesis's middle line its local score looks at.
_LOCAL_LINES = 6
# The local screen scores at most this many residuals (a quarter of a second), a seeded
# sample of its hypotheses beyond: every line triple of a dense pencil has a right spoke
# triple, so a sample of a tenth still holds a hundred right seeds.
_LOCAL_WORK = 1 << 22


def _local_screen(a, th, oriented, period, max_gap, tol, keep, kinds, obs, spk, io, js, seed):
    """`_screen` for pencils too large to score every hypothesis on every line (spokes all
    around the vertex): each hypothesis, a line triple and a spoke triple in cyclic order,
    is scored only on the `_LOCAL_LINES` lines either side of its middle line, against the
    spokes as far either side of its middle spoke (and `max_gap` more). Three neighbouring
    lines predict their neighbours well and the lines far away poorly, so this tells a
    right local labelling from a wrong one where the whole pencil would count mostly chance
    matches; the labelling then grows from it (`_LabelFitter.refine`). Beyond
    `_LOCAL_WORK` residuals in all, a seeded sample of the hypotheses."""
    M = a.size
    oa = np.argsort(np.remainder(a, period))
    rank_a = np.empty(M, int)
    rank_a[oa] = np.arange(M)
    sp_mod = np.remainder(th, period)
    ot = np.argsort(sp_mod, kind="stable")
    if not oriented:
        ot = ot[np.r_[True, np.diff(sp_mod[ot]) > 1e-9]]
    rank_t = np.full(th.size, -1)
    rank_t[ot] = np.arange(ot.size)
    W, G = _LOCAL_LINES, max_gap + 1
    wl = np.arange(-min(W, (M - 1) // 2), min(W, M // 2) + 1)
    ws = np.arange(-min(W + G, (ot.size - 1) // 2), min(W + G, ot.size // 2) + 1)
    total = len(obs) * len(spk) if io is None else io.size
    per_hyp = wl.size * ws.size
    flat = None
    if total * per_hyp > _LOCAL_WORK:
        flat = np.unique(np.random.default_rng(seed).integers(0, total, max(1, _LOCAL_WORK // per_hyp)))
    count = total if flat is None else flat.size
    block = max(1, _SCORE_BLOCK // per_hyp)
    wrap = wrap_angle if period > np.pi else wrap_line
    costs, nearest, resid, scored = [], [], [], 0
    for start in range(0, count, block):
        f = np.arange(start, min(start + block, count)) if flat is None else flat[start:start + block]
        bo, bs = np.divmod(f, len(spk)) if io is None else (io[f], js[f])
        H = _homographies(a[obs[bo]], th[spk[bs]])
        ok = _homography_ok(H, a[obs[bo]], th[spk[bs]], oriented)
        bo, bs, H = bo[ok], bs[ok], H[ok]
        if len(H) == 0:
            continue
        if oriented:  # the sign that reproduces the lines' orientation (`_homography_ok`)
            H = H * _orientation_sign(H, a[obs[bo]], th[spk[bs]])[:, None, None]
        lines = oa[(rank_a[obs[bo, 1]][:, None] + wl) % M]  # (K, Wl)
        spokes = ot[(rank_t[spk[bs, 1]][:, None] + ws) % ot.size]  # (K, Ws)
        pxy = np.einsum("kij,kjs->kis", H, np.stack([np.cos(th[spokes]), np.sin(th[spokes])], 1))
        pred = np.arctan2(pxy[:, 1], pxy[:, 0])  # (K, Ws)
        res = wrap(a[lines][:, :, None] - pred[:, None, :])  # (K, Wl, Ws)
        if kinds is not None:
            res = np.where(kinds[0][lines][:, :, None] == kinds[1][spokes][:, None, :], res, np.pi)
        k = np.argmin(np.abs(res), -1)
        r = np.take_along_axis(res, k[..., None], -1)[..., 0]
        cost = np.minimum((r / tol[lines]) ** 2, 1.0).sum(-1)
        best = np.argsort(cost)[:keep]
        # back to full rows: the lines outside the window are not labelled by the screen
        near = np.full((best.size, M), -1)
        rr = np.full((best.size, M), np.inf)
        rows = np.arange(best.size)[:, None]
        near[rows, lines[best]] = np.take_along_axis(spokes[best], k[best], -1)
        rr[rows, lines[best]] = r[best]
        costs.append(cost[best]), nearest.append(near), resid.append(rr)
        scored += len(H)
    if not scored:
        raise EstimationError("no consistent assignment of lines to spokes (cyclic order never matches)")
    order = np.argsort(np.concatenate(costs), kind="stable")[:keep]
    return np.concatenate(nearest)[order], np.concatenate(resid)[order], scored


@dataclass(frozen=True, eq=False)
class _LabelFitter:
    """The observed lines and the pencil, to fit labellings of them.

    a, s: (M,) [rad] line angles and their sigmas; th: (N,) [rad] spokes; vertex (2,),
    vertex_cov (2, 2) or None; cap [rad]: the largest assignment tolerance; kinds: None or
    (line kinds (M,), spoke kinds (N,)).
    """

    a: np.ndarray
    th: np.ndarray
    s: np.ndarray
    vertex: np.ndarray
    vertex_cov: np.ndarray | None
    oriented: bool
    tolerance_sigmas: float
    cap: float
    kinds: tuple | None = None

    def fit(self, lines, spokes):
        """PencilFit of the lines selected by `lines` (mask or indices) labelled `spokes`."""
        return fit_pencil(self.a[lines], self.th[spokes], self.vertex, sigma=self.s[lines],
                          vertex_cov=self.vertex_cov, oriented=self.oriented)

    def match(self, fit, scale=1.0):
        """Each line's nearest predicted spoke k (M,) (of its kind), its residual (M,)
        [rad] and the tolerance (M,) [rad] within which it is that spoke's, for a PencilFit:
        `tolerance_sigmas` sds of the residual (times sqrt(scale), the fit's own variance
        factor, `scatter`), at least 0.01 deg and at most `cap`; where those sds exceed
        `cap` (a spoke far from the lines fitted so far) the tolerance is 0: the prediction
        cannot tell that spoke from its neighbours yet."""
        wrap = wrap_angle if self.oriented else wrap_line
        pred, J, Jx = pencil_jacobian(fit.R_cam_from_target, self.vertex, self.th)
        # a line is compared with a prediction that is uncertain itself (rotation and
        # vertex): the tolerance covers both, else good short lines near the vertex drop
        var_pred = np.einsum("ni,ij,nj->n", J, fit.cov, J)
        if self.vertex_cov is not None:
            var_pred = var_pred + np.einsum("ni,ij,nj->n", Jx, self.vertex_cov, Jx)
        res = wrap(self.a[:, None] - pred[None, :])
        if self.kinds is not None:
            res = np.where(self.kinds[0][:, None] == self.kinds[1][None, :], res, np.pi)
        k = np.argmin(np.abs(res), -1)
        spread = self.tolerance_sigmas * np.sqrt(scale * (self.s**2 + var_pred[k]))
        tol_k = np.where(spread <= self.cap, np.clip(spread, np.radians(0.01), self.cap), 0.0)
        return k, res[np.arange(self.a.size), k], tol_k

    def scatter(self, fit, labels):
        """The fit's own variance factor: the robust scatter of the labelled lines' residuals
        over their sigmas, squared (1.4826 times their median absolute value), at least 1;
        1 with fewer than 8 lines (three fit exactly, a few more say little). Real lines
        miss a model the camera does not quite hold by more than their own scatter says."""
        used = labels >= 0
        if used.sum() < 8:
            return 1.0
        z = np.asarray(fit.residuals, float) / self.s[used]
        return float(max(1.0, (1.4826 * np.median(np.abs(z))) ** 2))

    def floored(self, fit, labels):
        """This fitter with each line's sigma widened by the model error the labelled lines
        share beyond their own sigmas: tau^2 = median(residual^2) / 0.455 - median(sigma^2)
        (the 1-dof chi2's median is 0.455), 0 with fewer than 8 lines. A camera model the
        lines do not quite hold (a lens's distortion, a dartboard's raised wire beside its
        printed edge) moves every line by about the same angle, whatever its own sigma: a
        long clean edge (sigma 0.002-0.04 deg) judged on its sigma alone, even scaled by the
        lines' typical excess (`scatter`), misses by many of its sds and is left out, or
        pulls the fit towards itself."""
        used = labels >= 0
        if used.sum() < 8:
            return self
        r2 = np.asarray(fit.residuals, float) ** 2
        tau2 = max(0.0, float(np.median(r2)) / 0.455 - float(np.median(self.s[used] ** 2)))
        return replace(self, s=np.sqrt(self.s**2 + tau2))

    def refine(self, labels):
        """Fit on the labelled lines, re-label all lines by the fit's prediction, repeat
        until the labels no longer change: a labelling grows from a few neighbouring lines
        to the spokes it then predicts surely enough (`match`).

        labels: (M,) spoke per line, -1 unassigned. Returns (labels, fit or None).
        """
        s, M = self.s, self.a.size
        fit = None
        fitter = self
        for _ in range(_MAX_GROWTH):
            used = labels >= 0
            if np.unique(labels[used]).size < 3:
                return labels, fit
            # each fit weights the lines by the previous fit's floor; the labels are judged
            # on this one's
            fit = fitter.fit(used, labels[used])
            fitter = self.floored(fit, labels)
            k, r, tol_k = fitter.match(fit, fitter.scatter(fit, labels))
            new = _one_per_spoke(np.where(np.abs(r) < tol_k, k, -1), s)
            if np.array_equal(new, labels) or np.unique(new[new >= 0]).size < 3:
                break
            labels = new
        used = labels >= 0
        if fit is None or np.unique(labels[used]).size < 3:
            return labels, None
        fit = self.fit(used, labels[used])
        return labels, fit

    def sure(self, fit, scale=1.0):
        """Each line's nearest predicted spoke of its kind where the evidence tells it from
        the next one, else -1: (M,). With the line's sd and its prediction's together (sd^2 =
        scale (s^2 + var_pred)) and the next predicted spoke g away, the nearer spoke
        explains the line better by GROWTH_EVIDENCE in chi2 or more where its residual r
        has |r| <= (g - GROWTH_EVIDENCE sd^2 / g) / 2; and the line is that spoke's only
        within `tolerance_sigmas` sds, and only where `tolerance_sigmas` sds of the
        prediction alone lie within g / 2. A prediction uncertain against the spacing of the
        spokes' images labels nothing (the shared error is estimated from the lines labelled
        so far, which their tolerance trimmed: without this gate a right labelling grew
        wrong on lines scattering 4 times their sigmas); a sure one labels the lines near
        it, however close its neighbours are in the target (a star's image is compressed on
        one side and stretched on the other)."""
        wrap = wrap_angle if self.oriented else wrap_line
        pred, J, Jx = pencil_jacobian(fit.R_cam_from_target, self.vertex, self.th)
        var_pred = np.einsum("ni,ij,nj->n", J, fit.cov, J)
        if self.vertex_cov is not None:
            var_pred = var_pred + np.einsum("ni,ij,nj->n", Jx, self.vertex_cov, Jx)
        res = wrap(self.a[:, None] - pred[None, :])  # (M, N)
        if self.kinds is not None:
            res = np.where(self.kinds[0][:, None] == self.kinds[1][None, :], res, np.pi)
        rows = np.arange(self.a.size)
        order = np.argsort(np.abs(res), -1)
        k = order[:, 0]
        # the next spoke of another direction (lines: spokes pi apart are one)
        other = np.abs(wrap(pred[order[:, 1:]] - pred[k][:, None])) > 1e-9
        k2 = order[rows, 1 + np.argmax(other, -1)]
        g = np.where(other.any(-1), np.abs(wrap(pred[k2] - pred[k])), np.pi)
        var_k = scale * np.maximum(var_pred[k], 0.0)
        sd2 = scale * self.s**2 + var_k
        window = np.minimum(self.tolerance_sigmas * np.sqrt(sd2), 0.5 * (g - GROWTH_EVIDENCE * sd2 / g))
        sure = self.tolerance_sigmas * np.sqrt(var_k) <= 0.5 * g
        return np.where(sure & (np.abs(res[rows, k]) < window), k, -1)

    def grow(self, labels):
        """The labelling grown from `labels` (M,) (a searched one: its lines are taken to be
        right): each round fits the labelled lines (their sigmas widened by the model error
        they share, `floored`), labels every line its prediction is `sure` of, and fits
        those; the new labelling is kept while its refit explains the lines labelled before
        (`_still_explained`), until nothing changes.
        Returns (labels, PencilFit on the lines' own sigmas)."""
        for _ in range(_MAX_GROWTH):
            used = labels >= 0
            wide = self.floored(self.fit(used, labels[used]), labels)
            fit = wide.fit(used, labels[used])
            # the labelled lines stand; a line is added only on a spoke none of them holds
            add = wide.sure(fit, wide.scatter(fit, labels))
            add = _one_per_spoke(np.where((labels < 0) & ~np.isin(add, labels[labels >= 0]), add, -1), self.s)
            new = np.where(labels >= 0, labels, add)
            if np.array_equal(new, labels) or np.unique(new[new >= 0]).size < 3:
                break
            if not _still_explained(wide.s, labels, fit, new, wide.fit(new >= 0, new[new >= 0])):
                break
            labels = new
        used = labels >= 0
        return labels, self.fit(used, labels[used])


def grow_labels(line_angles, spoke_angles, vertex, sigma, labels, vertex_cov=None, oriented=True,
                line_kind=None, spoke_kind=None, tolerance_sigmas=4.0):
    """A labelling grown to every line whose spoke its fit predicts surely enough.

    `assign_spokes` labels a line only where its prediction is within 0.45 of the smallest
    gap between the pencil's spokes by 4 sds: on a small tilted star, whose lines miss the
    model by more than their sigmas, that leaves most lines out. Here a line is given the
    spoke predicted nearest to it where the evidence for that spoke over the next predicted
    one (in the image, of the line's kind) is GROWTH_EVIDENCE in chi2 or more and the
    prediction itself is sure against that spacing (`_LabelFitter.sure`), and each round's
    refit must still explain the lines labelled before (`_LabelFitter.grow`). The labels
    given stand: a line is added only on a spoke none of them holds.

    line_angles (M,), spoke_angles (N,), vertex, sigma, vertex_cov, oriented, line_kind,
    spoke_kind: as `assign_spokes`; labels: (M,) a labelling of them (-1: none), three
    spokes or more. Returns (labels (M,), PencilFit of the labelled lines).

    Example
    -------
    >>> import numpy as np
    >>> from pencilcal.toolkit.geometry.frames import rotation_from_rotvec
    >>> from pencilcal.toolkit.pencil.spec import image_angles
    >>> R = rotation_from_rotvec([0.6, 0.3, 0.2]); x = np.array([0.05, 0.1])
    >>> spokes = np.radians(np.arange(36) * 10.0)
    >>> seen = image_angles(R, x, spokes) + np.radians(0.3) * np.random.default_rng(1).standard_normal(36)
    >>> start = np.full(36, -1); start[:4] = np.arange(4)          # four neighbours labelled
    >>> lab, fit = grow_labels(seen, spokes, x, np.radians(0.3), start)
    >>> int(np.sum(lab == np.arange(36)))
    36
    """
    a = np.asarray(line_angles, float).reshape(-1)
    th = np.asarray(spoke_angles, float).reshape(-1)
    lab = np.asarray(labels, int).reshape(a.size)
    if np.unique(lab[lab >= 0]).size < 3:
        raise EstimationError("fewer than three labelled spokes to grow from")
    kinds = None
    if line_kind is not None and spoke_kind is not None:
        kinds = (np.asarray(line_kind, int).reshape(a.size), np.asarray(spoke_kind, int).reshape(th.size))
    s = np.broadcast_to(np.asarray(sigma, float), a.shape).copy()
    fitter = _LabelFitter(a, th, s, vertex, vertex_cov, oriented, tolerance_sigmas, np.pi, kinds)
    return fitter.grow(lab)


def _still_explained(s, labels, fit, new, refit):
    """Whether a grown labelling is kept: `refit`, the PencilFit of the lines `new` (M,)
    labels, explains the lines `labels` (M,) labelled before (a subset of them, with the same
    labels) about as well as their own `fit`: their chi2 (sigmas s (M,) [rad]) rises by
    GROWTH_AGREE at most; and, from fewer than GROWTH_LIKELIHOOD_LINES lines, the refit's
    rotation lies within GROWTH_AGREE of `fit`'s by `fit`'s covariance (a few lines fit any
    rotation near theirs: a wrong search's 5 lines grew to 23 on chi2 alone).

    The chi2 and not the rotation's move alone: the covariance of an arc's lines is
    linearised far from where it holds, and a right growth moves the rotation by many of its
    sds (a 128-wedge star tilted 54 deg, its edges found on four arcs: grown to 24 lines on
    the first, the rotation 13.9 deg off at a sigma of 4.5 deg, the next round was refused
    and so was the frame; let on, it labels 100 lines on all four arcs, 0.047 deg off)."""
    old = labels >= 0
    r_old = np.asarray(fit.residuals, float) / s[old]
    r_new = np.asarray(refit.residuals, float)[old[new >= 0]] / s[old]
    if float(r_new @ r_new - r_old @ r_old) > GROWTH_AGREE:
        return False
    if np.count_nonzero(old) >= GROWTH_LIKELIHOOD_LINES:
        return True
    moved = rotvec_from_rotation(refit.R_cam_from_target @ fit.R_cam_from_target.T)
    try:
        return float(moved @ np.linalg.solve(np.asarray(fit.cov, float), moved)) <= GROWTH_AGREE
    except np.linalg.LinAlgError:
        return False

def _candidates(nearest, resid, tol, s, fitter):
    """Refit the few best distinct labellings of the MSAC screen (nearest, resid (k, M) of
    its best hypotheses, best first): [(lines used, chi2, labels (M,), PencilFit), ...].
    MSAC on 3-line predictions is only a screen, and two labellings may explain equally many
    lines (then the result says so)."""
    candidates = []
    seen_labels = set()
    for h in range(len(nearest)):
        lab0 = _one_per_spoke(np.where(np.abs(resid[h]) < tol, nearest[h], -1), s)
        key = lab0.tobytes()
        if key in seen_labels:
            continue
        seen_labels.add(key)
        lab, f = fitter.refine(lab0)
        if not np.all(np.isfinite(resid[h])):
            lab, f = _kept_screen_labels(fitter, lab0, lab, f)
        if f is not None:
            candidates.append(((lab >= 0).sum(), float(f.chi2), lab, f))
        if len(seen_labels) >= _TOP:
            break
    if not candidates:
        raise EstimationError("fewer than three spokes could be matched to the lines")
    return candidates


def _kept_screen_labels(fitter, lab0, lab, f):
    """The local screen's labelling `lab0` (M,) in place of its refinement (`lab`, fit `f`)
    where the refinement labels fewer than GROWTH_LIKELIHOOD_LINES lines (too few to grow
    from surely) and `lab0` labels `SCREEN_KEEP_LINES` or more
    that its own fit explains (chi2 within its 1 - DETECTION_LEVEL quantile): (labels,
    fit). On a small dense star the lines scatter so much (0.17-0.27 deg against edges
    1.4 deg apart) that the refinement's tolerance, 4 sds within 0.45 of the gap, labels only
    the few sharpest lines of a right window, and a fit of 3-5 neighbours grew wrong;
    the whole window grows right (`grow_labels`)."""
    used = lab0 >= 0
    n = int(np.count_nonzero(used))
    if n < SCREEN_KEEP_LINES or (f is not None and np.count_nonzero(lab >= 0) >= GROWTH_LIKELIHOOD_LINES):
        return lab, f
    f0 = fitter.fit(used, lab0[used])
    if float(f0.chi2) > chi2_isf(DETECTION_LEVEL, n - 3):
        return lab, f
    return lab0, f0


def _best_and_rivals(candidates):
    """(labels, fit, rivals, fewer) from the refitted candidates: the labelling that uses
    the most lines and fits best, those that use as many and fit about as well (rivals),
    and those that use fewer lines but rival it once the lines they leave out are charged
    (fewer); both lists of (labels, PencilFit)."""
    candidates.sort(key=lambda c: (-c[0], c[1]))
    n_best, chi2_best, labels, fit = candidates[0]
    rivals = [(lab, f) for n, chi2, lab, f in candidates[1:]
              if n == n_best and not np.array_equal(lab, labels) and chi2 - chi2_best < CHI2_2_DETECTION]
    # A labelling that explains one line fewer is a rival too when it gives a line another
    # spoke and fits about as well once the rejected line is charged the 99% quantile of
    # one squared residual: a spurious line that falls on a shifted labelling's prediction
    # otherwise wins just by being used. Residuals are judged against the best fit's own
    # scatter (real lines often scatter more than their stated sigmas).
    scale = inflation(chi2_best, max(n_best - 3, 1))
    fewer = [(lab, f) for n, chi2, lab, f in candidates[1:]
             if n < n_best and _conflict(lab, labels)
             and (chi2 - chi2_best) / scale + CHI2_1_99 * (n_best - n) < CHI2_2_DETECTION]
    return labels, fit, rivals, fewer


def _shifted_rivals(fitter, labels, fit, rivals, period):
    """Is the labelling unique? Every label shifted by one spoke in the cyclic order, as a
    list of (labels, PencilFit) rivals that fit about as well (and are not in `rivals`)."""
    th = fitter.th
    M, N = fitter.a.size, th.size
    used = labels >= 0
    kind = np.zeros(N, int) if fitter.kinds is None else fitter.kinds[1]
    out = []
    for shift in (-1, 1):
        # each label shifted to the next spoke of its kind in the cyclic order
        lab = labels[used].copy()
        for k in np.unique(kind):
            members = np.flatnonzero(kind == k)
            order = members[np.argsort(np.remainder(th[members], period))]
            rank = np.full(N, -1)
            rank[order] = np.arange(order.size)
            sel = kind[lab] == k
            lab[sel] = order[np.remainder(rank[lab[sel]] + shift, order.size)]
        if np.unique(lab).size < 3:
            continue
        full = np.full(M, -1)
        full[used] = lab
        if any(np.array_equal(full, r[0]) for r in rivals + out):
            continue
        alt = fitter.fit(used, lab)
        if float(alt.chi2) - float(fit.chi2) < CHI2_2_DETECTION:
            out.append((full, alt))
    return out

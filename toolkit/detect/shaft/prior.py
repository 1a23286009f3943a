"""The pencil as a prior: an instrument's axis passes through its fulcrum's image.

Where the camera holds still over a sequence, every frame's axis image of an instrument
pivoting about its port passes through one image point, the port's image: inside the view,
far outside it, or at infinity (a port in the camera's focal plane). Known (a previous run's
fulcrum, `pencilcal fulcrum`; robot kinematics), that point turns the search for the shaft
from four parameters (a band's two edges) into one, the angle about it
(`shaft.pencil_search`), and rules out what does not pass through it: a tissue band, a
drape's edge, another instrument.

An `AxisPrior` is that point as a homogeneous vector of undistorted ("ideal") pixels,
``X ~ K r`` for a viewing ray r, normalised to unit length, with its covariance (3, 3)
(singular along X): the fulcrum's ray covariance carried through K. A midline (the line l,
a^2 + b^2 = 1, with the covariance of its angle and of its offset at its centre c,
`shaft.axis.Midline`) passes through it when ``r = l . X`` is zero within

    var r = J cov_l J^T + l^T cov_X l,    J = (-d . (X[:2] - X[2] c), X[2]),

d the line's unit direction (`line_chi2`): a chi-square of 1 degree of freedom, finite for
a point at infinity too (X[2] = 0: then only the line's angle counts). `AXIS_GATE` is its
0.999 quantile.

One instrument pivots about one port: with a prior, `shaft.detector.detect_shafts` returns
at most one shaft per prior, the best-scored of its cues' shafts and of the angle search's
that pass through it (`select_through`). Give one prior per instrument.

Example
-------
>>> import numpy as np
>>> p = AxisPrior.from_point([1000.0, 200.0], np.diag([25.0, 25.0]))
>>> line = np.array([0.0, 1.0, -200.0])                        # y = 200, through the point
>>> cov = np.diag([np.radians(0.5) ** 2, 1.0])                 # angle [rad^2], offset [px^2]
>>> round(float(line_chi2(p, line, [300.0, 200.0], cov)), 6)
0.0
>>> off = np.array([0.0, 1.0, -230.0])                         # 30 px off at the point
>>> round(float(line_chi2(p, off, [300.0, 230.0], cov)), 2)    # ~ 30^2 / ((700 px 0.5 deg)^2 + 1 + 25)
14.15
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.detect.working import to_working_points
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.angles import circular_mean, line_diff, segment_angle
from pencilcal.toolkit.geometry.projective import line_through
from pencilcal.toolkit.geometry.quantiles import chi2_isf

__all__ = ["AxisPrior", "AXIS_GATE", "JACKKNIFE_GROUPS", "WIDTH_RANGE", "line_chi2", "select_through", "as_priors", "fulcrum_prior",
           "prior_chi2", "EPOCH_ALPHA", "epoch_priors", "prior_record",
           "read_priors"]

#: A midline passes through a prior when its chi-square (1 dof) is below this (0.999).
AXIS_GATE = chi2_isf(0.001, 1)
#: `fulcrum_prior`'s jackknife leaves out at most this many runs of frames in turn.
JACKKNIFE_GROUPS = 32
#: An epoch's own prior replaces the whole sequence's only where the two points differ at
#: this significance (`prior_chi2`; the change-point test's own level, `pencil.epochs.ALPHA`).
EPOCH_ALPHA = 0.01
#: A shaft through a prior that knows the instrument's widths (lo, hi) is WIDTH_RANGE[0] lo
#: to WIDTH_RANGE[1] hi wide (its distance changes as it pivots; the angle search looks
#: for 0.8 lo to 1.25 hi).
WIDTH_RANGE = (0.7, 1.4)


@dataclass(frozen=True, eq=False)
class AxisPrior:
    """The image of an instrument's fulcrum as a prior on its axis (module docstring).

    Attributes
    ----------
    point : (3,)
        Homogeneous undistorted pixels of the fulcrum's image, unit length (its third
        entry 0 for a point at infinity).
    cov : (3, 3)
        Its covariance (of the unit vector; singular along it).
    widths : (2,) [ideal px] or None
        The range of apparent widths the instrument had (e.g. over the sequence that gave
        the point): the angle search looks for these only; None: the detector's range.
    """

    point: np.ndarray
    cov: np.ndarray
    widths: tuple | None = None

    def __post_init__(self):
        X = np.asarray(self.point, float).reshape(-1)
        C = np.asarray(self.cov, float)
        if X.shape != (3,) or not np.all(np.isfinite(X)) or np.linalg.norm(X) == 0:
            raise InputError(f"axis prior: point must be a finite, non-zero homogeneous 3-vector, got {self.point!r}")
        if C.shape != (3, 3) or not np.all(np.isfinite(C)):
            raise InputError("axis prior: cov must be a finite 3x3 matrix")
        if self.widths is not None:
            w = np.asarray(self.widths, float).reshape(-1)
            if w.shape != (2,) or not (0 < w[0] <= w[1]) or not np.all(np.isfinite(w)):
                raise InputError(f"axis prior: widths must be (min, max) with 0 < min <= max, got {self.widths!r}")
            object.__setattr__(self, "widths", (float(w[0]), float(w[1])))
        n = float(np.linalg.norm(X))
        object.__setattr__(self, "point", X / n)
        object.__setattr__(self, "cov", 0.5 * (C + C.T) / n**2)

    @classmethod
    def from_point(cls, xy, cov_px2, widths=None):
        """The prior of a finite point xy (2,) [ideal px] with covariance (2, 2) [px^2]."""
        xy = np.asarray(xy, float).reshape(2)
        X = np.r_[xy, 1.0]
        n = np.linalg.norm(X)
        J = (np.eye(3) - np.outer(X, X) / n**2)[:, :2] / n
        return cls(X / n, J @ np.asarray(cov_px2, float).reshape(2, 2) @ J.T, widths)

    @classmethod
    def from_ray(cls, K, ray, ray_cov, widths=None):
        """The prior of a viewing ray (3,) (camera frame; a unit ray, the fulcrum's) with its
        covariance (3, 3): ``X = K r / |K r|``."""
        K = np.asarray(K, float)
        r = np.asarray(ray, float).reshape(3)
        X = K @ r
        n = float(np.linalg.norm(X))
        if not n > 0:
            raise InputError("axis prior: the ray has no image")
        Xn = X / n
        J = (np.eye(3) - np.outer(Xn, Xn)) @ K / n
        return cls(Xn, J @ np.asarray(ray_cov, float).reshape(3, 3) @ J.T, widths)

    def affine(self, A):
        """The prior in another pixel frame ``x' = A x`` (A (3, 3), e.g. the work frame's
        affine map), widths scaled by A's mean scale."""
        A = np.asarray(A, float)
        X = A @ self.point
        s = float(np.sqrt(abs(np.linalg.det(A[:2, :2]))))
        w = None if self.widths is None else (self.widths[0] * s, self.widths[1] * s)
        return AxisPrior(X, A @ self.cov @ A.T, w)

    def offset_sigma(self, direction):
        """sd [px] of the point's position across lines of the given unit direction(s)
        (..., 2) through it; inf at infinity (a finite point then)."""
        d = np.asarray(direction, float)
        n = np.stack([-d[..., 1], d[..., 0]], -1)
        X, C = self.point, self.cov
        w = X[2]
        if abs(w) < 1e-12:
            return np.full(d.shape[:-1], np.inf)
        # x = X[:2] / w; dx = (dX[:2] - x dX[2]) / w
        J = np.concatenate([np.eye(2), -(X[:2] / w)[:, None]], 1) / w
        Cx = J @ C @ J.T
        return np.sqrt(np.maximum(np.einsum("...i,ij,...j->...", n, Cx, n), 0.0))


def line_chi2(prior, line, centre, cov):
    """The chi-square (1 dof) of a line passing through the prior's point (module
    docstring): line (3,) with a^2 + b^2 = 1 [ideal px], centre (2,) where its offset
    covariance holds, cov (2, 2) of (angle [rad], offset [px]) (their correlation taken
    with the sign that gives the larger variance)."""
    l = np.asarray(line, float)
    c = np.asarray(centre, float)
    X, C = prior.point, prior.cov
    r = float(l @ X)
    d = np.array([l[1], -l[0]])
    J = np.array([-d @ (X[:2] - X[2] * c), X[2]])
    cv = np.asarray(cov, float)
    # the angle-offset covariance's sign follows the line's orientation, which a midline's
    # two ends do not fix: the larger of the two readings (the gate errs towards passing)
    var = float(J[0] ** 2 * cv[0, 0] + J[1] ** 2 * cv[1, 1] + 2.0 * abs(J[0] * J[1] * cv[0, 1]) + l @ C @ l)
    return r * r / var if var > 0 else (0.0 if r == 0 else np.inf)


def as_priors(axis_prior):
    """A list of `AxisPrior` from None, one prior or a sequence of them."""
    if axis_prior is None:
        return []
    if isinstance(axis_prior, AxisPrior):
        return [axis_prior]
    out = list(axis_prior)
    if not all(isinstance(p, AxisPrior) for p in out):
        raise InputError("axis_prior: expected an AxisPrior or a list of them")
    return out


def select_through(shafts, priors, gate=AXIS_GATE):
    """At most one shaft per prior (module docstring): for each prior in turn, the
    best-scored shaft not yet taken whose midline passes through it (chi-square below
    `gate`) and, where the prior knows the instrument's widths, whose width is within
    `WIDTH_RANGE` of them (a band half as wide, or twice, is something else). shafts:
    `shaft.detector.Shaft` with ``ideal_midline``, ``cov``, ``width_px``; returns them in the
    priors' order (a prior without one is skipped)."""
    out, used = [], set()
    for p in priors:
        best = None
        for k, s in enumerate(shafts):
            if k in used or s.cov is None:
                continue
            if p.widths is not None and not (WIDTH_RANGE[0] * p.widths[0] <= s.width_px
                                             <= WIDTH_RANGE[1] * p.widths[1]):
                continue
            m = np.asarray(s.ideal_midline, float).reshape(2, 2)
            ln = line_through(m[0], m[1])
            ln = ln / np.hypot(ln[0], ln[1])
            if line_chi2(p, ln, m.mean(0), s.cov) < gate and (best is None or s.score > shafts[best].score):
                best = k
        if best is not None:
            used.add(best)
            out.append(shafts[best])
    return out


def _direction_fit(ideal, st):
    """(unit point at infinity (3,), its covariance (3, 3), inliers (N,)) of lines (N, 4)
    [ideal px] with angle sds st (N,) [rad], or None (fewer than three agree): their robust
    common direction. Each line's direction is a hypothesis, scored by the MSAC cost of the
    lines' normalised angle residuals (truncated at `AXIS_GATE`, the point fit's inlier
    level too); the best one's inliers refitted by their weighted mean doubled angle until
    they stay the same. Its variance [rad^2] is 1 / sum(1 / st^2) over the inliers, times
    their chi2 / dof when above 1, along the direction's turn (the unit point's tangent).

    >>> import numpy as np
    >>> seg = np.array([[0, y, 100, y + 0.01 * y] for y in (0.0, 50.0, 90.0, 120.0)] + [[0, 0, 50, 50.0]])
    >>> X, C, inl = _direction_fit(seg, np.full(5, 0.01))
    >>> np.round(X, 3).tolist(), inl.tolist()
    ([1.0, 0.006, 0.0], [True, True, True, True, False])
    """
    phi = segment_angle(ideal)
    st = np.broadcast_to(np.asarray(st, float), phi.shape)
    w = 1.0 / st**2
    # line directions differ modulo pi
    E = (line_diff(phi[None, :], phi[:, None]) / st[None, :]) ** 2
    mask = E[int(np.argmin(np.minimum(E, AXIS_GATE).sum(1)))] < AXIS_GATE
    for _ in range(20):
        u = circular_mean(phi[mask], w[mask], period=np.pi)
        e2 = (line_diff(phi, u) / st) ** 2
        new = e2 < AXIS_GATE
        if np.array_equal(new, mask) or new.sum() < 3:
            break
        mask = new
    if mask.sum() < 3:
        return None
    dof = int(mask.sum()) - 1
    var = max(1.0, float(np.sum(e2[mask])) / dof) / float(np.sum(w[mask]))
    t = np.array([-np.sin(u), np.cos(u), 0.0])
    return np.array([np.cos(u), np.sin(u), 0.0]), var * np.outer(t, t), mask


def _point_fit(ideal, st, sc):
    """(unit homogeneous point (3,), its covariance (3, 3), inliers (N,)) of the robust
    common point of lines (N, 4) [ideal px] with their noise model (`pencil.vertex`), the
    covariance scaled by the residuals' chi2 / dof when above 1; where the lines meet at
    infinity (a point at infinity fits them as well as any finite one, or they are
    parallel: `intersect_lines` refuses), their common direction (`_direction_fit`); None
    without either."""
    from pencilcal.toolkit.errors import EstimationError
    from pencilcal.toolkit.pencil.vertex import intersect_lines

    try:
        v = intersect_lines(ideal, angle_sigma=st, offset_sigma=sc, robust=True, infinity_confidence=1e-12,
                            max_condition=np.inf)
    except EstimationError:
        return _direction_fit(ideal, st)
    dof = v.lines_used - 2
    scale = max(1.0, v.chi2 / dof) if dof > 0 else 1.0
    p = AxisPrior.from_point(v.vertex, v.cov * scale)
    return p.point, p.cov, v.inliers


def fulcrum_prior(camera, frames, endpoint_sigma_px=None):
    """The `AxisPrior` of a still camera's frames (one pivot epoch) from their instrument
    lines (lines.json frame dicts, the lines `pencil.fulcrum` fits: shaft midlines where
    there are any), or None (fewer than three lines, or no common point).

    The point is the robust common point (`pencil.vertex.intersect_lines`, allowed as far
    as infinity) of the lines that do not repeat from frame to frame (`pencil.epochs.
    distinct_lines`: a band of tissue detected in every frame would pull it onto itself),
    its covariance the larger (by trace) of the fit's, scaled by the
    residuals' chi2 / dof when above 1, and the jackknife's leaving out one frame (one run
    of consecutive frames, `JACKKNIFE_GROUPS` runs at most) at a time (a camera that
    drifted, a misdetected frame: the prior must hold the frames' spread, or it rejects
    the instrument it is for). widths: the inlier shafts' widths (undistorted px, as
    detected; their 20th to 80th percentile from five on) when the lines are shafts.
    """
    from pencilcal.toolkit.pencil.defaults import ENDPOINT_SIGMA_PX
    from pencilcal.toolkit.pencil.epochs import distinct_lines
    from pencilcal.toolkit.pencil.fulcrum import sequence_lines

    sl = sequence_lines(camera, frames, ENDPOINT_SIGMA_PX if endpoint_sigma_px is None else endpoint_sigma_px)
    idx = np.flatnonzero(sl.good)
    owners = np.array([sl.owner[k][0] for k in idx], int)
    idx = idx[distinct_lines(sl.ideal[idx], sl.angle_sigma[idx], sl.offset_sigma[idx], owners)]
    if idx.size < 3:
        return None
    fit = _point_fit(sl.ideal[idx], sl.angle_sigma[idx], sl.offset_sigma[idx])
    if fit is None:
        return None
    X, C, inl = fit
    owners = np.array([sl.owner[k][0] for k in idx])
    # delete-a-group jackknife over at most JACKKNIFE_GROUPS runs of consecutive frames
    frames_used = np.unique(owners)
    groups = np.array_split(frames_used, min(frames_used.size, JACKKNIFE_GROUPS))
    loo = []
    for g in groups:
        keep = ~np.isin(owners, g)
        if keep.sum() >= 3:
            f = _point_fit(sl.ideal[idx[keep]], sl.angle_sigma[idx[keep]], sl.offset_sigma[idx[keep]])
            if f is not None:
                loo.append(f[0] if f[0] @ X >= 0 else -f[0])
    if len(loo) >= 3:
        Y = np.asarray(loo)
        n = Y.shape[0]
        D = Y - Y.mean(0)
        J = (n - 1) / n * D.T @ D
        if np.trace(J) > np.trace(C):
            C = J
    widths = None
    if sl.lines_from == "shafts":
        w = [float(frames[sl.owner[k][0]]["shafts"][sl.owner[k][1]].get("width_px", np.nan)) for k in idx[inl]]
        w = np.array([x for x in w if np.isfinite(x) and x > 0])
        if w.size >= 5:  # the middle of the widths: an inlier may be a band of another width
            widths = tuple(float(v) for v in np.percentile(w, [20, 80]))
        elif w.size:
            widths = (float(w.min()), float(w.max()))
    return AxisPrior(X, C, widths)


def prior_chi2(p, q):
    """The chi-square (2 dof) of two priors' points differing, against the sum of their
    covariances, in the tangent plane of the unit sphere at q's point (the sign of p's
    point taken to agree with q's: a homogeneous point and its negative are one)."""
    X, Y = p.point if p.point @ q.point >= 0 else -p.point, q.point
    T = np.linalg.svd((np.eye(3) - np.outer(Y, Y)))[0][:, :2]
    d = T.T @ (X - Y)
    S = T.T @ (p.cov + q.cov) @ T
    try:
        return float(d @ np.linalg.solve(S, d))
    except np.linalg.LinAlgError:
        return np.inf


def epoch_priors(camera, frames, bounds, endpoint_sigma_px=None):
    """{image name: [priors to try in turn]} for lines.json `frames` split into pivot epochs
    (bounds [(start, stop)], `pencil.epochs.frame_epochs`): each frame its epoch's prior
    (`fulcrum_prior` of the epoch's frames); a frame without a shaft after its epoch's last
    one, where the fulcrum may already have moved (a change is placed at the first frame
    with a line after it), also the next epoch's; and, where the sequence has more than one
    epoch, the whole sequence's first (tried in turn, `shaft.detector.detect_through`); [None]
    where there is none.

    The whole sequence's prior (`fulcrum_prior` of all the frames) comes first: the
    change-point test splits where two points fit the lines better than one, which a camera
    drifting in every frame also makes true, and an epoch's prior, from fewer lines and its
    spread from fewer frames, then leaves out the frames at its ends (after a large move of
    the camera) that the whole sequence's spread holds, and passes a band beside the shaft
    there. An epoch's own prior is tried where the whole sequence's finds nothing (a fulcrum
    that really moved: its frames lie off the whole sequence's point), and only where its
    point differs from the whole sequence's at `EPOCH_ALPHA` (`prior_chi2`, chi-square of 2
    dof); an epoch without a prior of its own (fewer than three lines, no common point)
    takes the whole sequence's, not none."""
    priors = [fulcrum_prior(camera, frames[a:b], endpoint_sigma_px) for a, b in bounds]
    whole = None
    if len(bounds) > 1:
        whole = fulcrum_prior(camera, frames, endpoint_sigma_px)
        if whole is not None:
            priors = [whole if p is None or prior_chi2(p, whole) < chi2_isf(EPOCH_ALPHA, 2) else p for p in priors]
    out = {}
    for e, (a, b) in enumerate(bounds):
        with_shaft = [k for k in range(a, b) if frames[k].get("shafts")]
        last = with_shaft[-1] if with_shaft else a - 1
        for k in range(a, b):
            alts = [whole, priors[e]] + ([priors[e + 1]] if k > last and e + 1 < len(priors) else [])
            alts = [p for i, p in enumerate(alts) if p is not None and all(p is not q for q in alts[:i])]
            out[frames[k]["image"]] = alts or [None]
    return out


def prior_record(prior):
    """fulcrum.json's ``axis_prior`` record of a prior: ``point`` (3,) [ideal px,
    homogeneous, unit], ``cov`` (3, 3) and ``widths_px`` ([min, max] or null)."""
    return {"point": [float(v) for v in prior.point], "cov": np.asarray(prior.cov, float).tolist(),
            "widths_px": None if prior.widths is None else list(prior.widths)}


def _prior_of(rec, camera, where):
    """The `AxisPrior` of one record of a prior file (`read_priors`), or None without one."""
    if not isinstance(rec, dict):
        return None
    try:
        if isinstance(rec.get("axis_prior"), dict):
            a = rec["axis_prior"]
            return AxisPrior(np.asarray(a["point"], float), np.asarray(a["cov"], float), a.get("widths_px"))
        cov = rec.get("ray_cov_total", rec.get("ray_cov"))
        if rec.get("ray") is not None and cov is not None:
            return AxisPrior.from_ray(np.asarray(camera.K, float), np.asarray(rec["ray"], float),
                                      np.asarray(cov, float))
        if rec.get("vertex_px") is not None and rec.get("vertex_cov_px2") is not None:
            v = np.asarray(rec["vertex_px"], float).reshape(2)
            ideal = to_working_points(camera, v)
            # the lens map's Jacobian at the vertex, by central differences of +-0.5 px
            u = to_working_points(camera, np.stack([v + [0.5, 0], v - [0.5, 0], v + [0, 0.5], v - [0, 0.5]]))
            J = np.stack([u[0] - u[1], u[2] - u[3]], -1)
            if not np.all(np.isfinite(ideal)) or not np.all(np.isfinite(J)):
                raise InputError(f"{where}: vertex_px lies beyond the lens model's reach; give ray and ray_cov")
            return AxisPrior.from_point(ideal, J @ np.asarray(rec["vertex_cov_px2"], float) @ J.T)
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"{where}: not a fulcrum prior ({e})") from None
    return None


def read_priors(path, camera):
    """(default prior or None, {image name: prior}) from a fulcrum file: fulcrum.json
    (`pencilcal fulcrum`: its ``axis_prior``, else ``ray`` and ``ray_cov`` (``ray_cov_total``
    where the intrinsics' covariance is in it); each of its ``epochs`` for the images it
    lists), or any JSON/YAML object with those keys, or ``vertex_px`` [raw px] and
    ``vertex_cov_px2`` (e.g. the port's image from robot kinematics). InputError naming
    the file when it holds no prior."""
    from pencilcal.toolkit.io.files import load_structured

    data = load_structured(path, "fulcrum prior file")
    if not isinstance(data, dict):
        raise InputError(f"{path}: a fulcrum prior file is an object (fulcrum.json or ray and ray_cov)")
    default = _prior_of(data, camera, path)
    by_image = {}
    for k, ep in enumerate(data.get("epochs") or []):
        p = _prior_of(ep, camera, f"{path}: epoch {k}")
        if p is not None:
            for name in ep.get("images") or []:
                by_image[str(name)] = p
    if default is None and not by_image:
        raise InputError(f"{path}: no fulcrum prior in it (axis_prior, ray and ray_cov, or vertex_px and "
                         "vertex_cov_px2)")
    return default, by_image

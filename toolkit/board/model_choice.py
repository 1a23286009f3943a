"""The lens model chosen by how well it predicts views it was not fitted to.

A richer lens model always fits its own views better; whether it describes the lens better
shows only on views it has not seen. `choose_model` fits every candidate (pinhole, OpenCV's
4, 5, 8, 12 and 14 coefficients, Kannala-Brandt fisheye, mrcal's splined stereographic model
on a grid that covers the image, `splined_start`) with k-fold cross-validation over
the views: the views are dealt into `folds` groups (view i into group i mod k), each group
is left out in turn, the intrinsics (and the board's warp) are fitted to the others, and
each left-out view's pose alone is fitted to its corners through them. A view's score is
its held-out residual variance, ``sum |r|^2 / (2 K - 6)`` [px^2 per axis]: what is left when
only its pose could adapt. With the corner-noise model's weights (`calibrate` passes them
when it fits that model) every fit, held-out pose and score is weighted as the final
calibration is: ``sum w |r|^2 / (2 K - 6)``, the weights of mean 1.

The choice follows the one-standard-error rule: among the candidates whose mean held-out
score is within one standard error of the best one's (the standard error of the views'
paired differences to the best), the one with the fewest parameters. A model that wins
by less than the noise of the comparison does not earn its extra coefficients.

Only a model whose coefficients the views determine competes. A model's projection
uncertainty, and the two halves' predicted difference that checks it, are the first-order
response of the projection to its coefficients' covariance; where a one-sigma change of
them moves the projection over the covered region far from that linear response
(`projection_uncertainty.linearity`, more than `LINEAR_DEPARTURE` of it, under the fit's
covariance with the corner-noise model `calibrate` fitted, or white errors), the views do not hold those coefficients (OpenCV's rational model,
whose numerator and denominator can grow together into the thousands, is the usual case):
its held-out score is shown, with the status saying so, but it is not chosen.

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.board.spec import board_from_dict
>>> from pencilcal.toolkit.board.synthetic import synthetic_detections
>>> from pencilcal.toolkit.board.bundle import warp_basis
>>> from pencilcal.toolkit.camera.model import Camera
>>> board = board_from_dict({"type": "chessboard", "squares": [9, 6], "square": 25.0})
>>> cam = Camera("opencv", 640, 480, [[530.0, 0, 320.0], [0, 530.0, 240.0], [0, 0, 1]], [-0.3, 0.1, 0, 0, 0])
>>> dets = synthetic_detections(cam, board, views=10, noise_px=0.1, seed=4)
>>> objs = [board.object_points()] * 10
>>> choice = choose_model(objs, [d.corners for d in dets], [warp_basis(objs[0], o) for o in objs],
...                       cam.K, cam.dist, dets.truth, candidates=(("pinhole", 0), ("opencv", 4), ("opencv", 8)))
>>> (choice.model, choice.coefficients), [s.status[:14] for s in choice.scores]
(('opencv', 4), ['ok', 'ok', 'not determined'])
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pencilcal.toolkit.board.bundle import Layout, camera_parts, covariance, fit_pose, refine, splined_layout, \
    theta_of, view_residuals, warp_basis
from pencilcal.toolkit.camera import splined as _spl
from pencilcal.toolkit.camera.projection_uncertainty import LINEAR_DEPARTURE, linearity
from pencilcal.toolkit.errors import EstimationError

__all__ = ["CANDIDATES", "SPLINED", "FOLDS", "LINEAR_DEPARTURE", "ModelScore", "ModelChoice", "choose_model", "chosen_score",
           "simpler_choice", "splined_start", "choose_twist"]

#: The candidate name of the splined model on the grid `splined_start` places.
SPLINED = "splined"
#: The lens models `choose_model` compares by default: (model, coefficients); the splined
#: model's coefficient count (0 here) follows from its grid.
CANDIDATES = (("pinhole", 0), ("opencv", 4), ("opencv", 5), ("opencv", 8), ("opencv", 12), ("opencv", 14),
              ("fisheye", 4), (SPLINED, 0))
#: Groups of views left out in turn.
FOLDS = 5
# fewer views than this cannot be split into training and held-out views usefully
_MIN_VIEWS = 6
# a simpler model taken instead of one that failed a later check must predict the held-out
# views within this share of the best candidate's held-out RMS (not a pinhole for a lens
# that distorts)
_FALLBACK_RMS = 0.10


@dataclass
class ModelScore:
    """One candidate's cross-validation.

    model, coefficients : the candidate; parameters : its intrinsic count;
    fit_rms_px : RMS residual of the fit to all views [px] (OpenCV's definition);
    heldout_rms_px : sqrt of the mean held-out score [px per axis]; excess, excess_se :
    its mean score minus the best candidate's and that difference's standard error
    [px^2 per axis]; linear_departure : how far a one-sigma change of its coefficients
    moves the projection from its linear response, as a share of that response
    (`projection_uncertainty.linearity`); status : "ok", or why it could not be scored or
    is not chosen.
    """

    model: str
    coefficients: int
    parameters: int
    fit_rms_px: float | None = None
    heldout_rms_px: float | None = None
    excess: float | None = None
    excess_se: float | None = None
    linear_departure: float | None = None
    status: str = "ok"
    scores: np.ndarray | None = field(default=None, repr=False)
    solution: object = field(default=None, repr=False)
    layout: object = field(default=None, repr=False)

    def to_dict(self):
        return {"model": self.model, "coefficients": self.coefficients, "parameters": self.parameters,
                "fit_rms_px": self.fit_rms_px, "heldout_rms_px": self.heldout_rms_px, "excess_px2": self.excess,
                "excess_se_px2": self.excess_se,
                "linear_departure": _finite(self.linear_departure), "status": self.status}


@dataclass
class ModelChoice:
    """What `choose_model` picked (model, coefficients), every candidate's `ModelScore`
    (with its fit to all views, ``solution``), the folds and a sentence saying why."""

    model: str
    coefficients: int
    scores: list
    folds: int
    reason: str

    def to_dict(self):
        return {"model": self.model, "coefficients": self.coefficients, "folds": self.folds, "reason": self.reason,
                "rule": "fewest parameters within one standard error of the best held-out score, among the models "
                        "whose coefficients the views determine",
                "candidates": [s.to_dict() for s in self.scores]}


def _layout(model, n, warp, fix_aspect, fix_principal_point, zero_tangent, twist=False):
    return Layout(model, n, bool(fix_aspect), bool(fix_principal_point), bool(zero_tangent and model == "opencv"),
                  warp=bool(warp), twist=bool(warp and twist))


def splined_start(layout, K, dist, image_size, Nx=None, config=None):
    """(the splined layout, its intrinsics to start from) for a calibration whose lean fit
    is K (3, 3), dist (OpenCV's order, `layout.model`): the grid covers the whole image under
    the lean fit (`splined.config_covering`, Nx knots across x, default one interval per
    sixth of the image width; or the `SplineConfig` `config`) and the control points
    reproduce the lean model there (`splined.fit_correction`)."""
    from pencilcal.toolkit.camera.model import Camera

    lean_model = "pinhole" if layout.model == "pinhole" else layout.model
    lean = Camera(lean_model, int(image_size[0]), int(image_size[1]), K, dist)
    cfg = config if config is not None else _spl.config_covering(lean, Nx=Nx)
    theta = np.r_[lean.fx, lean.fy, lean.cx, lean.cy, _spl.fit_correction(cfg, lean)]
    return splined_layout(layout, cfg, theta), theta


def _score(layout, theta0, poses, objs, imgs, bases, folds, weights=None):
    """(the fit to all views (`bundle.Solution`), per-view held-out scores (V,)) of one
    candidate; weights : per view each corner's weight (None: 1), in every fit and score."""
    w = [None] * len(objs) if weights is None else list(weights)
    full = refine(layout, theta0, poses, objs, imgs, bases if layout.warp else None, weights=weights)
    scores = np.zeros(len(objs))
    for f in range(folds):
        train = [i for i in range(len(objs)) if i % folds != f]
        test = [i for i in range(len(objs)) if i % folds == f]
        sol = refine(layout, full.theta, full.poses[train], [objs[i] for i in train], [imgs[i] for i in train],
                     [bases[i] for i in train] if layout.warp else None, warp=full.warp,
                     weights=None if weights is None else [w[i] for i in train])
        for i in test:
            _, r = fit_pose(layout, sol.theta, sol.warp, full.poses[i], objs[i], imgs[i],
                            bases[i] if layout.warp else None, weights=w[i])
            r2 = np.sum(r * r, -1) if w[i] is None else np.asarray(w[i], float) * np.sum(r * r, -1)
            scores[i] = float(np.sum(r2)) / max(r.size - 6, 1)
    return full, scores


def choose_twist(layout, theta, poses, objs, imgs, board_points, folds=FOLDS):
    """Whether the board's twist (`bundle.warp_basis`'s third shape) predicts held-out views
    better than the warp's two parabolas alone, by the rule `choose_model` applies to lens
    models: the same k-fold views, each view's held-out score with and without the twist,
    and the twist kept only where its mean score is lower by more than one standard error
    of the views' paired differences (one parameter earns its place on views it was not
    fitted to). A board twisted about its axes, seen from different directions, looks like
    a focal length that changes from view to view.

    layout : the calibration's `bundle.Layout` (with the warp; its twist ignored); theta,
    poses : a fit of these views to start from; objs, imgs : per view the board points
    (N_v, 3) and corners (N_v, 2) [px]; board_points (M, 3) : the board's corners.

    Returns ``{"kept", "views", "folds", "heldout_without", "heldout_with" (mean scores,
    px^2 per axis), "difference", "difference_se", "twist" (the fit to all views [board
    unit], its sign: +corner (first, first) up), "rule"}``; None with fewer than 6 views or
    no warp.

    >>> import numpy as np
    >>> from pencilcal.toolkit.board.spec import board_from_dict
    >>> from pencilcal.toolkit.board.calibrate import synthetic_detections
    >>> from pencilcal.toolkit.board.bundle import Layout, theta_of
    >>> from pencilcal.toolkit.camera.model import Camera
    >>> board = board_from_dict({"type": "chessboard", "squares": [9, 6], "square": 25.0})
    >>> cam = Camera("opencv", 640, 480, [[530.0, 0, 320.0], [0, 530.0, 240.0], [0, 0, 1]], [-0.2, 0.05, 0, 0, 0])
    >>> dets = synthetic_detections(cam, board, views=12, noise_px=0.1, seed=3, warp=(0.0, 0.0, 0.6))
    >>> objs = [board.object_points()] * 12
    >>> lay = Layout("opencv", 5)
    >>> rec = choose_twist(lay, theta_of(cam.K, cam.dist, lay), dets.truth, objs, [d.corners for d in dets], objs[0])
    >>> rec["kept"], bool(abs(rec["twist"] - 0.6) < 0.1)
    (True, True)
    """
    from dataclasses import replace

    if not layout.warp or len(objs) < _MIN_VIEWS:
        return None
    folds = int(min(max(2, folds), len(objs)))
    got = {}
    for tw in (False, True):
        lay = replace(layout, twist=tw)
        got[tw] = _score(lay, theta, poses, objs, imgs, [warp_basis(board_points, o, tw) for o in objs], folds)
    d = got[True][1] - got[False][1]
    se = float(np.std(d, ddof=1) / math.sqrt(d.size))
    return {"kept": bool(np.mean(d) < -se), "views": int(d.size), "folds": folds,
            "heldout_without": float(np.mean(got[False][1])), "heldout_with": float(np.mean(got[True][1])),
            "difference": float(np.mean(d)), "difference_se": se, "twist": float(got[True][0].warp[2]),
            "rule": "the twist kept where it lowers the views' mean held-out score by more than one standard error"}


def choose_model(objs, imgs, bases, K, dist, poses, candidates=CANDIDATES, folds=FOLDS, warp=True,
                 fix_aspect=False, fix_principal_point=False, zero_tangent=False, image_size=None, lean=None,
                 weights=None, noise=None):
    """Compare lens models on held-out views and pick one (the module's docstring).

    Parameters
    ----------
    objs, imgs, bases : per view the board points (N_v, 3), their corners (N_v, 2) [px]
        and `bundle.warp_basis` (N_v, 2): the views and corners a calibration kept (bases of
        three columns: the board's twist estimated with its warp).
    K, dist, poses : a calibration of these views to start every candidate from (3, 3),
        its coefficients (OpenCV's order), per view (rvec, tvec).
    candidates : (model, coefficients) pairs; folds : groups of views (at most the views).
    warp, fix_aspect, fix_principal_point, zero_tangent : as `calibrate`, for every
        candidate (fisheye is skipped with fix_aspect).
    image_size : (w, h) [px], for the splined candidate's grid (skipped without it);
        lean : the (model, coefficients) of K and dist (default opencv with dist's count).
    weights : per view (N_v,) each corner's weight (the inverse of its relative variance
        under the corner-noise model, as the final fit weighs it), None: 1. Every fit,
        held-out pose and held-out score is then weighted: a held-out corner counts as
        much as its noise allows, as in the final calibration.
    noise : the `corner_noise.CornerNoise` under which each candidate's covariance is taken
        for the test of whether the views determine its coefficients (None: white errors).

    Returns
    -------
    ModelChoice
        EstimationError when fewer than 6 views are given or no candidate can be scored.
    """
    V = len(objs)
    if V < _MIN_VIEWS:
        raise EstimationError(f"choosing a lens model by held-out views needs at least {_MIN_VIEWS} views, got {V}")
    folds = int(min(max(2, folds), V))
    scores = []
    lean = lean or ("opencv" if np.size(dist) else "pinhole", int(np.size(dist)))
    twist = bool(warp) and np.shape(bases[0])[-1] == 3
    for model, n in candidates:
        layout = _layout(model, n, warp, fix_aspect, fix_principal_point, zero_tangent, twist)
        rec = ModelScore(model, n, 4 + n)
        if model == "fisheye" and fix_aspect:
            rec.status = "not with a fixed aspect ratio"
            scores.append(rec)
            continue
        if model == SPLINED:
            if image_size is None or fix_aspect:
                rec.status = "not without the image size" if image_size is None else "not with a fixed aspect ratio"
                scores.append(rec)
                continue
            layout, theta0 = splined_start(_layout(lean[0], lean[1], warp, False, fix_principal_point, False, twist), K,
                                           dist, image_size)
            rec.model, rec.coefficients, rec.parameters = layout.model, layout.n_coef, 4 + layout.n_coef
        else:
            theta0 = theta_of(K, np.zeros(n) if model == "fisheye" else dist, layout)
        try:
            rec.layout = layout
            rec.solution, rec.scores = _score(layout, theta0, poses, objs, imgs, bases, folds, weights)
            rec.fit_rms_px = _fit_rms(layout, rec.solution, objs, imgs, bases)
        except (EstimationError, np.linalg.LinAlgError) as e:
            rec.status = f"failed: {e}"
        if rec.scores is not None and not np.all(np.isfinite(rec.scores)):
            rec.status, rec.scores = "failed: a held-out view did not converge", None
        if rec.scores is not None:
            rec.linear_departure = _departure(layout, rec.solution, objs, imgs, bases, weights, image_size, noise)
            if not rec.linear_departure <= LINEAR_DEPARTURE:
                rec.status = (f"not determined by the views: a one-sigma change of its coefficients moves the "
                              f"projection {rec.linear_departure:.2g} x as far from its linear response as that "
                              "response itself")
        scores.append(rec)
    scored = [s for s in scores if s.scores is not None]
    if not scored:
        raise EstimationError("no lens model could be scored on held-out views")
    for s in scored:
        s.heldout_rms_px = math.sqrt(float(np.mean(s.scores)))
    # every candidate undetermined (not seen on real views): the comparison alone decides
    pick, best = _pick(_determined(scored) or scored)
    refused = [s for s in scored if s.status != "ok"]
    return ModelChoice(pick.model, pick.coefficients, scores, folds, _reason(pick, best, V, folds, refused))


def _determined(scored):
    return [s for s in scored if s.status == "ok"]


def _finite(x):
    return None if x is None else (float(x) if math.isfinite(x) else "inf")


def _departure(layout, solution, objs, imgs, bases, weights, image_size, noise=None):
    """`projection_uncertainty.linearity`'s departure share of a candidate's fit to all
    views under its covariance with the corner-noise model `noise` (None: white; inf where
    it is singular), over the region the views cover (the corners themselves without the
    image size)."""
    from pencilcal.toolkit.board.coverage import covered_grid
    from pencilcal.toolkit.camera.model import Camera

    cov = covariance(layout, solution, objs, imgs, bases if layout.warp else None, noise, weights).intrinsics
    if not np.all(np.isfinite(cov)):
        return math.inf
    K, dist = camera_parts(solution.theta, layout)
    if image_size is not None:
        size, region = image_size, covered_grid(imgs, image_size).pixels()
    else:
        region = np.concatenate([np.asarray(p, float).reshape(-1, 2) for p in imgs])
        size = tuple(int(v) + 1 for v in region.max(0))
    return linearity(Camera(layout.model, int(size[0]), int(size[1]), K, dist), cov, region)["departure_share"]


def _fit_rms(layout, solution, objs, imgs, bases):
    """The fit's unweighted RMS residual [px] (OpenCV's definition)."""
    res = view_residuals(layout, solution, objs, imgs, bases if layout.warp else None)
    return math.sqrt(float(sum(np.sum(r * r) for r in res)) / solution.corners)


def _pick(scored):
    """(pick, best) of the scored candidates by the one-standard-error rule; sets each one's
    excess over the best and its standard error."""
    best = min(scored, key=lambda s: float(np.mean(s.scores)))
    for s in scored:
        d = s.scores - best.scores
        s.excess = float(np.mean(d))
        s.excess_se = float(np.std(d, ddof=1) / math.sqrt(d.size)) if s is not best else 0.0
    near = [s for s in scored if s.excess <= s.excess_se]
    return min(near, key=lambda s: (s.parameters, float(np.mean(s.scores)))), best


def simpler_choice(choice, rejected, why):
    """The choice again among the candidates with fewer parameters than every one in
    `rejected` ((model, coefficients) pairs that failed a later check, `why` says which)
    whose held-out RMS is within 10 % of the best candidate's: a new ModelChoice, or None
    when no candidate is left. The scores are kept."""
    fewest = min(s.parameters for s in choice.scores if (s.model, s.coefficients) in set(rejected))
    scored = _determined([s for s in choice.scores if s.scores is not None])
    best = min(s.heldout_rms_px for s in scored)
    left = [s for s in scored if s.parameters < fewest and s.heldout_rms_px <= (1.0 + _FALLBACK_RMS) * best]
    if not left:
        return None
    pick, best = _pick(left)
    V = left[0].scores.size
    reason = (f"{', '.join(f'{m} {n}' for m, n in rejected)} failed {why}; among the simpler models: "
              + _reason(pick, best, V, choice.folds))
    return ModelChoice(pick.model, pick.coefficients, choice.scores, choice.folds, reason)


def chosen_score(choice):
    """The `ModelScore` of the candidate `choice` picked."""
    return next(s for s in choice.scores if (s.model, s.coefficients) == (choice.model, choice.coefficients))


def _reason(pick, best, views, folds, refused=()):
    name = _name(pick)
    head = f"{folds}-fold cross-validation over {views} views: "
    better = [s for s in refused if s.heldout_rms_px < best.heldout_rms_px]
    if better and best.status == "ok":
        head += (f"{', '.join(_name(s) for s in better)} predict{'s' if len(better) == 1 else ''} the held-out views "
                 f"better ({', '.join(f'{s.heldout_rms_px:.3f}' for s in better)} px per axis) but "
                 f"{'is' if len(better) == 1 else 'are'} not determined by them (the projection departs from its "
                 f"linear response to the coefficients' sigmas by "
                 f"{', '.join(f'{s.linear_departure:.2g}' for s in better)} x that response); ")
    among = " of the models they determine" if better and best.status == "ok" else ""
    if pick is best:
        return head + (f"{name} predicts the held-out views best{among} (held-out RMS {pick.heldout_rms_px:.3f} px "
                       "per axis).")
    fewer = best.parameters - pick.parameters
    return (head + f"{_name(best)} predicts the held-out views best{among} ({best.heldout_rms_px:.3f} px per axis), but "
            f"{name}, with {fewer} parameter{'s' if fewer != 1 else ''} fewer, is within one standard error of it "
            f"({pick.heldout_rms_px:.3f} px; excess {pick.excess:.2g} +- {pick.excess_se:.2g} px^2).")


def _name(s):
    if s.model == "pinhole":
        return "pinhole (no distortion)"
    if _spl.is_splined(s.model):
        cfg = _spl.splined_config(s.model)
        return f"splined stereographic ({cfg.Nx} x {cfg.Ny} knots over {cfg.fov_x_deg} deg)"
    return f"{s.model} with {s.coefficients} coefficients"

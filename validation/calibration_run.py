"""A calibration with its checks and its verdict, as `pencilcal calibrate` makes it.

`calibrate_checked` is what the command and `pencilcal.calibrate` run: the calibration with
the board's warp and the corner-noise model (`toolkit.board.calibrate`), then its checks
(`validation.calibration_checks`: two halves of the views, the projection uncertainty over
the image, how the views saw the board) and the verdict (`validation.calibration_verdict`).

With ``model="auto"`` the lens model chosen on held-out views must also pass the two-halves
check (pooled chi-square per dof and projection ratio within the verdict's consistency
bounds); one that fails gives way to the choice among the simpler models
(`model_choice.simpler_choice`), until one passes or none is left (then the first choice
stays, and the verdict says what the halves found). A model that predicts held-out views
a little better but whose two halves disagree is not a better description of the lens.

The result is the `CalibrationResult` with ``checks`` set (`CalibrationChecks`); its
``to_dict()`` is the record calib.json holds.

Example
-------
>>> from pencilcal.toolkit.board.spec import board_from_dict
>>> from pencilcal.toolkit.board.synthetic import synthetic_detections
>>> from pencilcal.toolkit.camera.model import Camera
>>> board = board_from_dict({"type": "chessboard", "squares": [9, 6], "square": 25.0})
>>> cam = Camera("opencv", 640, 480, [[530.0, 0, 320.0], [0, 530.0, 240.0], [0, 0, 1]], [-0.2, 0.05, 0, 0, 0])
>>> dets = synthetic_detections(cam, board, views=4, noise_px=0.2, seed=5)
>>> res = calibrate_checked(dets, board, (640, 480))
>>> res.checks.verdict.status, res.checks.verdict.reasons[0][:13]
('not usable', 'too few views')
"""
from __future__ import annotations

from dataclasses import dataclass, field

from pencilcal.toolkit.board.calibrate import AUTO, calibrate
from pencilcal.toolkit.board.coverage import view_geometry
from pencilcal.toolkit.board.model_choice import CANDIDATES, simpler_choice
from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.errors import EstimationError

from .calibration_report import coverage_grid
from .calibration_checks import RANDOM_HALVES, calibration_halves, uncertainty_map, used_views, view_focal_scales
from .calibration_verdict import USABLE_PX, halves_state, judge

__all__ = ["CalibrationChecks", "calibrate_checked", "run_checks"]


@dataclass
class CalibrationChecks:
    """A calibration's checks: ``halves`` (`calibration_halves`'s record or ``{"error"}``),
    ``uncertainty`` (`uncertainty_map`'s), ``geometry`` (per view tilt [deg], distance
    [board unit], board share of the image), ``verdict`` (`Verdict`) and ``models_tried``
    (with ``model="auto"``: the models that failed the halves, with their figures)."""

    halves: dict
    uncertainty: dict
    geometry: dict
    verdict: object
    models_tried: list = field(default_factory=list)
    coverage: dict | None = None

    def to_dict(self):
        return {"verdict": self.verdict.to_dict(), "cross_validation": self.halves,
                "projection_uncertainty": self.uncertainty,
                "view_geometry": {k: [round(float(x), 4) for x in v] for k, v in self.geometry.items()},
                "models_tried": list(self.models_tried), "coverage": self.coverage}


def run_checks(result, detections, board, repeats=RANDOM_HALVES, seed=0):
    """(halves, uncertainty map, view geometry, corner coverage) of a `CalibrationResult`."""
    try:
        halves = calibration_halves(result, detections, board, repeats=repeats, seed=seed)
    except EstimationError as e:
        halves = {"error": str(e)}
    if not halves.get("error"):
        # each view's own focal scale against its noise: a focus that changed between views
        halves["view_focal_scale"] = view_focal_scales(result, detections, board)
    try:
        umap = uncertainty_map(result, detections, board)
    except EstimationError as e:
        umap = {"error": str(e), "covered_fraction": 0.0, "median_covered_px": None, "max_covered_px": None}
    _, objs, imgs, _ = used_views(result, detections, board)
    poses = [p for p in result.view_poses if p is not None]
    geometry = view_geometry(poses, objs, imgs, result.camera.size)
    return halves, umap, geometry, coverage_grid(imgs, result.camera.size)


def _summary(result, halves):
    state, chi2, ratio, _, _ = halves_state(halves)
    return {"model": result.model, "coefficients": result.coefficients, "halves": state,
            "chi2_per_dof": chi2, "projection_ratio": ratio}


def calibrate_checked(detections, board, image_size, model="opencv", coefficients=None, *, checks=True,
                      repeats=RANDOM_HALVES, usable_px=USABLE_PX, candidates=CANDIDATES, warp=True, **options):
    """Calibrate (`toolkit.board.calibrate.calibrate` with the board's warp and the corner-noise
    model), check and judge; the module's docstring.

    detections, board, image_size, model ("opencv", "pinhole", "fisheye" or "auto"),
    coefficients, candidates, warp and options (fix_aspect, min_corners, ...) as `calibrate`;
    checks : run the checks and the verdict (``result.checks``); repeats : random halves
    besides odd and even; usable_px : the verdict's threshold [px].
    """
    detections = list(detections)

    def fit(m, n):
        return calibrate(detections, board, image_size, model=m, coefficients=n, corner_noise=True, warp=warp,
                         candidates=candidates, **options)

    result = fit(model, coefficients)
    if not checks:
        return result
    halves, umap, geometry, coverage = run_checks(result, detections, board, repeats)
    tried = []
    if model == AUTO and result.model_choice is not None:
        first = (result, halves, umap, geometry, coverage)
        choice = result.model_choice
        while halves_state(halves)[0] in ("loose", "disagree"):
            tried.append(_summary(result, halves))
            choice = simpler_choice(choice, [(t["model"], t["coefficients"]) for t in tried], "the two-halves check")
            if choice is None:        # no simpler model qualifies: the first stays, the verdict warns
                result, halves, umap, geometry, coverage = first
                tried = []
                break
            result = fit(choice.model, choice.coefficients)
            result.model_choice = choice
            halves, umap, geometry, coverage = run_checks(result, detections, board, repeats)
    noise = {"rms_px": result.rms_px}
    if result.corner_noise is not None:
        noise.update(ratio=result.corner_noise.ratio, length_px=result.corner_noise.length_px)
    verdict = judge(result.views_used, halves, umap, geometry, usable_px, noise)
    result.checks = CalibrationChecks(halves, umap, geometry, verdict, tried, coverage)
    cam = result.camera
    # the camera file says whether it is usable, wherever it goes
    result.camera = Camera(cam.model, cam.width, cam.height, cam.K, cam.dist,
                           meta={**(cam.meta or {}), "verdict": {"status": verdict.status,
                                                                 "headline": verdict.headline}})
    return result


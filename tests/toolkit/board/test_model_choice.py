"""The lens model chosen on held-out views: the true one, or a simpler one that predicts as well."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.board.calibrate import calibrate
from pencilcal.toolkit.board.model_choice import CANDIDATES, SPLINED, choose_twist, simpler_choice
from pencilcal.toolkit.board.spec import board_from_dict
from pencilcal.toolkit.board.synthetic import synthetic_detections
from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.camera.splined import is_splined
from pencilcal.toolkit.errors import EstimationError

BOARD = board_from_dict({"type": "chessboard", "squares": [9, 6], "square": 25.0})
K = [[600.0, 0, 480.0], [0, 600.0, 270.0], [0, 0, 1]]


@pytest.mark.parametrize("truth, expected", [
    (Camera("fisheye", 960, 540, K, [0.08, -0.03, 0.01, -0.002]), ("fisheye", 4)),
    (Camera("pinhole", 960, 540, K), ("pinhole", 0)),
    (Camera("opencv", 960, 540, K, [-0.3, 0.12, 0.0, 0.0, 0.0]), ("opencv", 4)),
])
def test_auto_finds_the_lens(truth, expected):
    dets = synthetic_detections(truth, BOARD, views=20, noise_px=0.2, seed=6, tilt_deg=50)
    r = calibrate(dets, BOARD, truth.size, model="auto", warp=True)
    choice = r.model_choice
    assert (r.model, r.coefficients) == expected, choice.reason
    assert (choice.model, choice.coefficients) == expected and "cross-validation over 20 views" in choice.reason
    scored = {(SPLINED, 0) if is_splined(s.model) else (s.model, s.coefficients): s for s in choice.scores}
    assert set(scored) == set(CANDIDATES) and scored[expected].status == "ok"
    # the rest are scored, or scored and not determined by the views (never failed)
    assert all(s.status == "ok" or s.status.startswith("not determined") for s in scored.values())
    # the chosen model's held-out score is within one standard error of the best
    pick = scored[expected]
    assert pick.excess <= pick.excess_se
    assert abs(r.camera.fx - truth.fx) < 5 * r.std_intrinsics["fx"]


def test_a_simpler_choice_when_the_first_fails_a_check():
    truth = Camera("opencv", 960, 540, K, [-0.3, 0.12, 0.0, 0.0, 0.02])
    dets = synthetic_detections(truth, BOARD, views=12, noise_px=0.2, seed=7, tilt_deg=50)
    choice = calibrate(dets, BOARD, truth.size, model="auto").model_choice
    again = simpler_choice(choice, [(choice.model, choice.coefficients)], "a test")
    first = next(s for s in choice.scores if (s.model, s.coefficients) == (choice.model, choice.coefficients))
    best = min(s.heldout_rms_px for s in choice.scores)
    simpler = [s for s in choice.scores if s.parameters < first.parameters and s.heldout_rms_px <= 1.1 * best]
    if not simpler:                        # the pinhole predicts far worse: no fallback to it
        assert again is None
    else:
        assert again is not None and again.reason.startswith(f"{choice.model} {choice.coefficients} failed a test")
        assert 4 + again.coefficients < first.parameters


def test_too_few_views_to_choose():
    dets = synthetic_detections(Camera("pinhole", 960, 540, K), BOARD, views=5, noise_px=0.2, seed=1)
    with pytest.raises(EstimationError, match="at least 6 views"):
        calibrate(dets, BOARD, (960, 540), model="auto")


def test_candidates_can_be_restricted():
    truth = Camera("fisheye", 960, 540, K, [0.08, -0.03, 0.01, -0.002])
    dets = synthetic_detections(truth, BOARD, views=10, noise_px=0.2, seed=8)
    r = calibrate(dets, BOARD, truth.size, model="auto", candidates=(("opencv", 4), ("opencv", 8)))
    assert r.model == "opencv" and [(s.model, s.coefficients) for s in r.model_choice.scores] == [("opencv", 4),
                                                                                                  ("opencv", 8)]
    assert np.isfinite(r.rms_px)


def test_auto_takes_the_splined_model_for_a_lens_no_opencv_model_holds():
    from tests.toolkit.camera.test_splined import bumped

    truth = bumped(Camera("opencv", 960, 540, K, [-0.3, 0.12, 0.0, 0.0, 0.0]), px=3.0)
    dets = synthetic_detections(truth, BOARD, views=20, noise_px=0.1, seed=6, tilt_deg=50)
    r = calibrate(dets, BOARD, truth.size, model="auto", warp=True,
                  candidates=(("opencv", 5), ("opencv", 8), (SPLINED, 0)))
    assert is_splined(r.model) and r.camera.spline is not None, r.model_choice.reason
    assert "splined stereographic" in r.model_choice.reason
    lean = next(s for s in r.model_choice.scores if s.model == "opencv" and s.coefficients == 5)
    assert lean.excess > 3 * lean.excess_se


def test_the_choice_is_weighted_as_the_final_fit():
    """With the corner-noise model the candidates are scored under its weights: unit
    weights give the unweighted scores exactly, a corner weighted 0 leaves every fit and
    score, and `calibrate(model="auto", corner_noise=True)` compares under the weights."""
    from pencilcal.toolkit.board.bundle import warp_basis
    from pencilcal.toolkit.board.model_choice import choose_model

    truth = Camera("opencv", 960, 540, K, [-0.3, 0.12, 0.0, 0.0, 0.0])
    dets = synthetic_detections(truth, BOARD, views=10, noise_px=0.2, seed=8, tilt_deg=50)
    objs = [BOARD.object_points()] * 10
    imgs = [np.array(d.corners, float) for d in dets]
    bases = [warp_basis(objs[0], o) for o in objs]
    cands = (("opencv", 4), ("opencv", 5))

    def scores(w, im=imgs):
        ch = choose_model(objs, im, bases, truth.K, truth.dist, dets.truth, candidates=cands, weights=w)
        return np.array([s.scores for s in ch.scores])

    plain = scores(None)
    assert np.allclose(scores([np.ones(54)] * 10), plain, rtol=1e-9, atol=1e-15)
    # one corner of one view thrown 40 px off: weighted 0 it moves nothing
    bad = [im.copy() for im in imgs]
    bad[3][10] += 40.0
    w = [np.ones(54) for _ in range(10)]
    w[3][10] = 0.0
    assert not np.allclose(scores(None, bad), plain, rtol=1e-3)
    assert np.allclose(scores(w, bad)[:, [0, 1, 2, 4]], plain[:, [0, 1, 2, 4]], rtol=0.05)
    r = calibrate(dets, BOARD, truth.size, model="auto", warp=True, corner_noise=True, candidates=cands)
    assert r.model_choice is not None and r.weights is not None


def test_a_model_the_views_do_not_determine_is_scored_but_not_chosen():
    # a 5-coefficient lens seen in 12 views: the rational model's numerator and denominator
    # are free to grow together, its linearised sigmas mean nothing, and however it scores
    # on held-out views it is not chosen
    from pencilcal.toolkit.board.model_choice import LINEAR_DEPARTURE

    truth = Camera("opencv", 960, 540, K, [-0.3, 0.12, 0.0, 0.0, 0.02])
    dets = synthetic_detections(truth, BOARD, views=12, noise_px=0.2, seed=7, tilt_deg=50)
    r = calibrate(dets, BOARD, truth.size, model="auto", warp=True,
                  candidates=(("opencv", 4), ("opencv", 5), ("opencv", 8), ("opencv", 14)))
    scores = {s.coefficients: s for s in r.model_choice.scores}
    assert scores[14].status.startswith("not determined") and scores[14].linear_departure > 5 * LINEAR_DEPARTURE
    assert scores[4].linear_departure < 0.1 * LINEAR_DEPARTURE and scores[5].linear_departure < 0.1 * LINEAR_DEPARTURE
    assert r.coefficients in (4, 5), r.model_choice.reason
    assert scores[14].heldout_rms_px is not None and scores[14].to_dict()["linear_departure"] > LINEAR_DEPARTURE


@pytest.mark.parametrize("twist, kept", [(0.8, True), (0.0, False)])
def test_the_boards_twist_is_kept_where_held_out_views_want_it(twist, kept):
    """A board twisted by 0.8 mm at its corners: the twist predicts held-out views better and
    is kept; a board only bowed: not kept (one-standard-error rule), and `calibrate`'s
    ``twist="auto"`` follows the choice and records it."""
    truth = Camera("opencv", 960, 540, K, [-0.3, 0.12, 0.0, 0.0, 0.0])
    dets = synthetic_detections(truth, BOARD, views=16, noise_px=0.2, seed=21, tilt_deg=50,
                                warp=(0.3, -0.2, twist))
    r = calibrate(dets, BOARD, truth.size, warp=True, twist="auto")
    rec = r.warp["twist_choice"]
    assert rec["kept"] is kept and rec["views"] == 16 and rec["folds"] == 5, rec
    assert (rec["difference"] < -rec["difference_se"]) is kept
    assert r.layout.twist is kept and len(r.warp["value"]) == (3 if kept else 2)
    if kept:
        assert abs(r.warp["value"][2] - twist) < 3 * r.warp["std"][2]
    # without the warp there is nothing to choose
    assert choose_twist(r.layout.__class__("opencv", 5, warp=False), r.solution.theta, [], [], [], None) is None


def test_twist_is_true_false_or_auto():
    from pencilcal.toolkit.errors import InputError

    dets = synthetic_detections(Camera("pinhole", 960, 540, K), BOARD, views=6, noise_px=0.2, seed=1)
    with pytest.raises(InputError, match="twist must be True, False or 'auto'"):
        calibrate(dets, BOARD, (960, 540), warp=True, twist="yes")

"""validation/pnp/: accuracy of every method, the covariance, degenerate input, poses.json."""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import stats

from pencilcal.toolkit.board.spec import board_from_dict
from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.frames import rotation_about_axis, rotation_angle, rotation_to_z, rotvec_from_rotation
from pencilcal.validation.pnp import (
    METHODS,
    POSE_KEYS,
    best_method,
    colmap_covariance_to_pencilcal,
    empty_frame_record,
    estimate_all,
    estimate_pose,
    frame_record,
    read_board_poses,
    refine_pose,
    write_board_poses,
)
from pencilcal.validation.pnp.estimate import _TWIN_RULED_OUT, _fail, _planar_twin
from pencilcal.validation.pnp.refine import normalized_points, residuals
from tests.conftest import data_dir
from tests.helpers import hd_camera

Z = np.array([0.0, 0.0, 1.0])
# the docs/formats.md example board: 18 x 25 = 450 inner corners, 5 mm squares
BIG_BOARD = board_from_dict({"type": "charuco", "squares": [19, 26], "square": 5.0, "marker": 4.0,
                             "dictionary": "DICT_4X4_250"})
SMALL_BOARD = board_from_dict({"type": "charuco", "squares": [7, 5], "square": 30.0, "marker": 22.0,
                               "dictionary": "DICT_4X4_50"})


# ---------------------------------------------------------------------------- helpers
def board_pose(camera, X, rng, tilt_deg=(25.0, 45.0), depth=None, margin=20, tries=500):
    """A random pose with the board centre on a random ray, tilted by tilt_deg from it, and
    every corner inside the image. Returns R, t, pixels (noise-free)."""
    c = X.mean(0)
    depth = 0.115 * camera.fx if depth is None else depth
    for _ in range(tries):
        px = rng.uniform([0.35 * camera.width, 0.35 * camera.height], [0.65 * camera.width, 0.65 * camera.height])
        ray = camera.rays_from_pixels(px)
        R = (rotation_to_z(ray).T @ rotation_about_axis(Z, rng.uniform(0, 2 * np.pi))
             @ rotation_about_axis([1.0, 0, 0], np.radians(rng.uniform(*tilt_deg)))
             @ rotation_about_axis(Z, rng.uniform(0, 2 * np.pi)))
        t = ray * depth / ray[2] - R @ c
        u = camera.project(X @ R.T + t)
        if (np.all(np.isfinite(u)) and u.min() > margin and u[:, 0].max() < camera.width - margin
                and u[:, 1].max() < camera.height - margin):
            return R, t, u
    raise RuntimeError("no pose keeps the board inside the image")


def pose_errors(res, R, t):
    """Rotation error [deg], translation error [% of distance], Mahalanobis^2 under res.cov."""
    e = np.concatenate([rotvec_from_rotation(R @ res.R_cam_from_target.T), t - res.t_cam_from_target])
    m2 = float(e @ np.linalg.solve(res.cov, e))
    return (float(np.degrees(rotation_angle(R, res.R_cam_from_target))),
            float(100 * np.linalg.norm(t - res.t_cam_from_target) / np.linalg.norm(t)), m2)


def planar_points(n=24):
    j, i = np.mgrid[1:5, 1:7]
    return np.stack([i.ravel() * 30.0, j.ravel() * 30.0, np.zeros(i.size)], -1)[:n]


def simple_scene(camera=None, n=24):
    cam = camera or hd_camera()
    X = planar_points(n)
    R = rotation_about_axis([1.0, 0.3, 0.0], 0.6)
    t = np.array([-100.0, -60.0, 400.0])
    return cam, X, R, t, cam.project(X @ R.T + t)


# ------------------------------------------------------------------ synthetic accuracy
@pytest.mark.parametrize("model", ["opencv", "fisheye"])
@pytest.mark.parametrize("method", METHODS)
def test_synthetic_accuracy(method, model):
    """0.15 px corner noise on the 450-corner board: < 0.02 deg and < 0.05 % of distance,
    and the error is consistent with the reported covariance."""
    cam = hd_camera(model)
    X = BIG_BOARD.object_points()
    rng = np.random.default_rng(100 + METHODS.index(method))
    for _ in range(3):
        R, t, u = board_pose(cam, X, rng)
        res = estimate_pose(X, u + 0.15 * rng.normal(size=u.shape), cam, method)
        assert res.ok, res.error
        rot, dist, m2 = pose_errors(res, R, t)
        assert rot < 0.02 and dist < 0.05, (rot, dist)
        assert m2 < stats.chi2.ppf(0.9999, 6)
        assert res.sigma_from == "residuals" and 0.1 < res.sigma_px < 0.2
        assert res.corners == X.shape[0] and res.residuals_px.shape == (X.shape[0], 2)


@pytest.mark.parametrize("model", ["opencv", "fisheye", "pinhole"])
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("refine", [True, False])
def test_noise_free_is_exact(method, model, refine):
    """Exact corners give the exact pose; unrefined colmap too, which pins COLMAP's
    +0.5 px pixel convention (a half-pixel slip would cost ~0.02 deg here)."""
    cam = hd_camera(model)
    X = SMALL_BOARD.object_points()
    R, t, u = board_pose(cam, X, np.random.default_rng(7), depth=0.3 * cam.fx)
    res = estimate_pose(X, u, cam, method, refine=refine)
    if method == "epnp" and not refine:
        # OpenCV's EPnP is not exact on planar points (opencv/opencv#22351)
        assert not res.ok or res.reproj_rms_px < 5.0
        return
    tol = 1e-6 if refine or method in ("sqpnp", "colmap") else 1e-3
    assert res.ok, res.error
    assert np.degrees(rotation_angle(R, res.R_cam_from_target)) < tol
    assert np.linalg.norm(res.t_cam_from_target - t) < tol * np.linalg.norm(t)
    assert res.refined is refine


def test_rendered_board_accuracy():
    """Corners detected in frames rendered by toolkit/synth/render.py (exact area coverage, sensor
    noise) with pinhole, opencv and fisheye lenses: every method within 0.02 deg and
    0.05 % of the distance of the true pose."""
    from pencilcal.toolkit.board.detect import detect_board
    from pencilcal.toolkit.synth.render import render_frame
    from pencilcal.toolkit.synth.sheet import layout_sheet

    board = board_from_dict({"type": "charuco", "squares": [12, 9], "square": 20.0, "marker": 15.0,
                             "dictionary": "DICT_5X5_100"})
    sheet = layout_sheet(board, paper="a3")
    X = board.object_points()
    K = [[1100.0, 0, 639.5], [0, 1100.0, 359.5], [0, 0, 1]]
    cams = [Camera("pinhole", 1280, 720, K), Camera("opencv", 1280, 720, K, [-0.25, 0.08, 5e-4, -3e-4, 0.0]),
            Camera("fisheye", 1280, 720, [[600.0, 0, 639.5], [0, 600.0, 359.5], [0, 0, 1]],
                   [0.05, -0.01, 0.003, -0.001])]
    rng = np.random.default_rng(3)
    for cam in cams:
        for k in range(2):
            R = (rotation_about_axis([np.cos(k + 1), np.sin(k + 1), 0], np.radians(38 + 5 * k))
                 @ rotation_about_axis(Z, 0.3))
            t = np.array([0.0, 0.0, 0.3 * cam.fx]) - R @ X.mean(0)
            img = render_frame(cam, R, t, sheet, background="plain", noise=1.0, rng=rng)
            det = detect_board(img, board)
            assert det.count >= 80, (cam.model, k, det.count)
            truth = cam.project(X[det.ids] @ R.T + t)
            assert np.sqrt(np.mean(np.sum((det.corners - truth) ** 2, 1))) < 0.15
            for m, res in estimate_all(X[det.ids], det.corners, cam).items():
                assert res.ok, (m, res.error)
                rot, dist, _ = pose_errors(res, R, t)
                assert rot < 0.02 and dist < 0.05, (cam.model, k, m, rot, dist)


# --------------------------------------------------------------------------- covariance
def test_covariance_coverage_monte_carlo():
    """Mahalanobis distances of the true pose: chi2(6) with the true sigma, and
    6 F(6, 2K-6) with sigma estimated from the residuals, at 50/90/99 %."""
    cam, X, R, t, u0 = simple_scene()
    rng = np.random.default_rng(2024)
    n, sig = 800, 0.2
    d_given, d_est = np.empty(n), np.empty(n)
    for k in range(n):
        res = estimate_pose(X, u0 + sig * rng.normal(size=u0.shape), cam, "sqpnp")
        e = np.concatenate([rotvec_from_rotation(R @ res.R_cam_from_target.T), t - res.t_cam_from_target])
        d_est[k] = e @ np.linalg.solve(res.cov, e)
        d_given[k] = d_est[k] * (res.sigma_px / sig) ** 2
    dof = 2 * X.shape[0] - 6
    for q, tol in ((0.5, 0.05), (0.9, 0.035), (0.99, 0.015)):
        assert abs(np.mean(d_given < stats.chi2.ppf(q, 6)) - q) < tol, q
        assert abs(np.mean(d_est / 6 < stats.f.ppf(q, 6, dof)) - q) < tol, q


def test_given_sigma_scales_covariance():
    cam, X, R, t, u = simple_scene()
    u = u + 0.3 * np.random.default_rng(1).normal(size=u.shape)
    a = estimate_pose(X, u, cam, corner_sigma_px=0.5)
    b = estimate_pose(X, u, cam, corner_sigma_px=1.0)
    c = estimate_pose(X, u, cam)
    assert a.sigma_from == "given" and a.sigma_px == 0.5 and c.sigma_from == "residuals"
    np.testing.assert_allclose(b.cov, 4 * a.cov, rtol=1e-12)
    np.testing.assert_allclose(c.cov, (c.sigma_px / 0.5) ** 2 * a.cov, rtol=1e-9)
    assert np.isclose(c.sigma_px, np.sqrt(np.sum(c.residuals_px**2) / (2 * X.shape[0] - 6)))
    # the derived uncertainties follow from cov
    np.testing.assert_allclose(np.radians(a.rotation_sigma_deg) ** 2, np.diag(a.cov)[:3])
    np.testing.assert_allclose(a.translation_sigma**2, np.diag(a.cov)[3:])


def test_covariance_agrees_with_colmap():
    """COLMAP's Ceres covariance (quaternion tangent, 1 px) converted to this convention."""
    import pycolmap

    from pencilcal.toolkit.camera.formats import camera_to_colmap

    for model in ("opencv", "fisheye"):
        cam, X, R, t, u = simple_scene(hd_camera(model))
        u = u + 0.01 * np.random.default_rng(0).normal(size=u.shape)
        ours = estimate_pose(X, u, cam, corner_sigma_px=1.0)
        ref = pycolmap.AbsolutePoseRefinementOptions()
        ref.gradient_tolerance = 1e-12
        ans = pycolmap.estimate_and_refine_absolute_pose(u + 0.5, X, camera_to_colmap(cam),
                                                         pycolmap.AbsolutePoseEstimationOptions(), ref,
                                                         return_covariance=True)
        theirs = colmap_covariance_to_pencilcal(ans["covariance"], 1.0)
        assert np.abs(theirs - ours.cov).max() < 1e-3 * np.abs(ours.cov).max()


TILTED = [-0.3, 0.12, 5e-4, 2e-4, -0.02, 0.01, 0.002, 0.001, 1e-3, -1e-3, 2e-3, 1e-4, 0.01, -0.02]


@pytest.mark.parametrize("camera", [
    hd_camera("opencv"), hd_camera("fisheye"), hd_camera("pinhole"),
    Camera("opencv", 1920, 1080, [[1500.0, 0.4, 955.0], [0, 1498.0, 545.0], [0, 0, 1]], TILTED),
    Camera("opencv", 1920, 1080, [[1500.0, 0, 955.0], [0, 1498.0, 545.0], [0, 0, 1]], TILTED),
])
def test_jacobian_matches_finite_differences(camera):
    X = planar_points()
    X[:, 2] = 5.0 * (np.arange(24) % 3)  # off the plane too
    R = rotation_about_axis([1.0, 0.3, 0.2], 0.5)
    t = np.array([-100.0, -60.0, 400.0])
    obs = camera.project(X @ R.T + t) + 1.0
    r0, J, _ = residuals(camera, X, obs, R, t)
    h = 1e-6
    for k in range(6):
        d = np.zeros(6)
        d[k] = h
        Rp = rotation_about_axis(d[:3], np.linalg.norm(d[:3])) @ R if k < 3 else R
        rp, _, _ = residuals(camera, X, obs, Rp, t + d[3:], jacobian=False)
        d[k] = -h
        Rm = rotation_about_axis(d[:3], np.linalg.norm(d[:3])) @ R if k < 3 else R
        rm, _, _ = residuals(camera, X, obs, Rm, t + d[3:], jacobian=False)
        np.testing.assert_allclose(J[:, k], ((rp - rm) / (2 * h)).ravel(), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("camera", [
    hd_camera("opencv"), hd_camera("pinhole"), hd_camera("fisheye"),
    Camera("opencv", 1920, 1080, [[1500.0, 0, 955.0], [0, 1498.0, 545.0], [0, 0, 1]], TILTED),
    Camera("opencv", 1920, 1080, [[1500.0, 0.4, 955.0], [0, 1498.0, 545.0], [0, 0, 1]], TILTED[:8]),
])
def test_residuals_are_the_camera_projection(camera):
    """The residuals (cv2.projectPoints for opencv/pinhole without skew, Camera otherwise)
    are Camera.project's; points behind the camera give NaN residuals and Jacobian rows."""
    X = planar_points()
    R = rotation_about_axis([1.0, 0.3, 0.2], 0.5)
    t = np.array([-100.0, -60.0, 400.0])
    obs = camera.project(X @ R.T + t) + 0.3
    r, J, front = residuals(camera, X, obs, R, t)
    assert front.all() and np.all(np.isfinite(J))
    np.testing.assert_allclose(r, camera.project(X @ R.T + t) - obs, rtol=0, atol=1e-9)
    t_behind = np.array([-100.0, -60.0, 0.0])  # some corners behind the camera
    r, J, front = residuals(camera, X, obs, R, t_behind)
    behind = (X @ R.T + t_behind)[:, 2] <= 0
    assert behind.any() and not behind.all() and np.array_equal(front, ~behind)
    assert np.all(np.isnan(r[behind])) and np.all(np.isnan(J.reshape(-1, 2, 6)[behind]))
    assert np.all(np.isfinite(r[~behind]))


@pytest.mark.parametrize("camera", [
    hd_camera("opencv"), hd_camera("pinhole"), hd_camera("fisheye"),
    Camera("opencv", 1280, 720, [[900.0, 0, 639.5], [0, 902.0, 359.5], [0, 0, 1]],
           [-0.12, 0.06, 4e-4, -3e-4, -0.012, 0.01, 0.002, 0.001]),
    # strong barrel distortion: OpenCV's iteration fails in the corners, Camera decides
    Camera("opencv", 1280, 720, [[600.0, 0, 639.5], [0, 600.0, 359.5], [0, 0, 1]], [-0.6, 0.2, 0, 0, 0]),
    # a model that folds inside the image: pixels beyond the fold cannot be undistorted
    Camera("opencv", 1280, 720, [[500.0, 0, 639.5], [0, 500.0, 359.5], [0, 0, 1]], [-0.35, 0.0, 0, 0, 0]),
])
def test_undistortion_is_the_cameras(camera):
    """The undistortion behind the initialisers (OpenCV's iteration, checked) gives
    Camera.normalized_from_pixels' points, NaN where it has NaN."""
    rng = np.random.default_rng(4)
    for px in (rng.uniform([0, 0], camera.size, size=(24, 2)),
               np.array([[0.0, 0.0], [camera.width - 1.0, camera.height - 1.0], [camera.cx, camera.cy]]),
               rng.uniform([0, 0], camera.size, size=(400, 2))):
        ours, ref = normalized_points(camera, px), camera.normalized_from_pixels(px)
        assert np.array_equal(np.isnan(ours), np.isnan(ref))
        np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-12)


def test_refinement_reaches_the_optimum():
    """From a start 3 deg and 5 % off, the refinement stops at the least-squares optimum:
    the gradient J^T r vanishes to round-off, and a second refinement does not move it."""
    cam, X, R, t, u = simple_scene()
    u = u + 0.3 * np.random.default_rng(8).normal(size=u.shape)
    R0 = rotation_about_axis([0.3, 1.0, 0.2], np.radians(3.0)) @ R
    R1, t1, its = refine_pose(cam, X, u, R0, 1.05 * t)
    assert 1 <= its < 20 and np.allclose(R1 @ R1.T, np.eye(3), atol=1e-15)
    r, J, _ = residuals(cam, X, u, R1, t1)
    g = J.T @ r.ravel()
    assert np.linalg.norm(g) < 1e-9 * np.linalg.norm(J) * np.linalg.norm(r)
    R2, t2, _ = refine_pose(cam, X, u, R1, t1)
    assert rotation_angle(R1, R2) < 1e-10 and np.linalg.norm(t2 - t1) < 1e-9 * np.linalg.norm(t1)


def test_a_clearly_worse_twin_is_ruled_out_at_its_start():
    """Where perspective resolves the twin (its start reprojects > 10 times worse than the
    pose) it is not refined: its start's RMS and angle are recorded, an upper bound."""
    cam, X, R, t, u = simple_scene()
    u = u + 0.2 * np.random.default_rng(6).normal(size=u.shape)
    res = estimate_pose(X, u, cam, "sqpnp")
    twin_R, twin_t = _planar_twin(X, res.R_cam_from_target, res.t_cam_from_target)
    twin_rms = np.sqrt(np.mean(np.sum((cam.project(X @ twin_R.T + twin_t) - u) ** 2, 1)))
    assert twin_rms > _TWIN_RULED_OUT * res.reproj_rms_px
    assert res.alternative_rms_px == pytest.approx(twin_rms, rel=1e-9)
    assert res.alternative_angle_deg == pytest.approx(np.degrees(rotation_angle(twin_R, res.R_cam_from_target)),
                                                      rel=1e-9)
    # refining that twin would have lowered its RMS, never below the pose's
    R2, t2, _ = refine_pose(cam, X, u, twin_R, twin_t)
    refined = np.sqrt(np.mean(np.sum((cam.project(X @ R2.T + t2) - u) ** 2, 1)))
    assert res.reproj_rms_px - 1e-9 <= refined <= res.alternative_rms_px
    assert not res.flipped


# ---------------------------------------------------------------------- method details
def test_ippe_keeps_the_better_of_its_pair_and_records_the_other():
    cam, X, R, t, u = simple_scene()
    u = u + 0.2 * np.random.default_rng(5).normal(size=u.shape)
    raw = estimate_pose(X, u, cam, "ippe", refine=False)
    assert raw.ok and raw.alternative_rms_px > raw.reproj_rms_px and raw.alternative_angle_deg > 1.0
    ref = estimate_pose(X, u, cam, "ippe")
    assert ref.ok and ref.alternative_rms_px >= ref.reproj_rms_px - 1e-12
    assert np.degrees(rotation_angle(R, ref.R_cam_from_target)) < 0.5


def test_colmap_reports_inliers_and_rejects_models_it_lacks():
    cam, X, R, t, u = simple_scene()
    res = estimate_pose(X, u, cam, "colmap")
    assert res.ok and res.extra["colmap_inliers"] == X.shape[0] and res.to_dict()["colmap_inliers"] == 24
    odd = Camera("opencv", 1920, 1080, cam.K, [-0.3, 0.12, 0, 0, 0, 0, 0, 0, 1e-3, 0, 0, 0])
    res = estimate_pose(X, odd.project(X @ R.T + t), odd, "colmap")
    assert not res.ok and "COLMAP" in res.error
    # the OpenCV methods take every lens model
    assert estimate_pose(X, odd.project(X @ R.T + t), odd, "sqpnp").ok


def test_planar_twin_check_corrects_a_wrong_twin():
    """OpenCV's EPnP returns poses far off on some planar views (opencv/opencv#22351) that
    refine to the wrong planar twin; the twin check turns every one into the right pose."""
    cam = hd_camera()
    X = SMALL_BOARD.object_points()
    rng = np.random.default_rng(11)
    flipped = 0
    for _ in range(30):
        R, t, u = board_pose(cam, X, rng, tilt_deg=(0.0, 60.0), depth=0.3 * cam.fx)
        u = u + 0.15 * rng.normal(size=u.shape)
        res = estimate_pose(X, u, cam, "epnp")
        assert res.ok, res.error
        assert pose_errors(res, R, t)[2] < stats.chi2.ppf(0.9999, 6)
        assert res.alternative_rms_px is not None and res.alternative_rms_px >= res.reproj_rms_px - 1e-9
        if res.flipped:
            flipped += 1
            raw = estimate_pose(X, u, cam, "epnp", refine=False, max_rms_px=None)
            assert np.degrees(rotation_angle(raw.R_cam_from_target, R)) > 5.0
            assert res.refine_change_deg > 5.0
    # the twin of a good pose is a different, worse pose
    res = estimate_pose(X, u, cam, "sqpnp")
    twin_R, twin_t = _planar_twin(X, res.R_cam_from_target, res.t_cam_from_target)
    assert np.degrees(rotation_angle(twin_R, res.R_cam_from_target)) > 5.0
    assert np.isclose(np.linalg.det(twin_R), 1.0) and np.allclose(twin_R @ twin_R.T, np.eye(3), atol=1e-12)
    assert not res.flipped


def test_rms_limit_rejects_a_pose_that_does_not_fit():
    cam, X, R, t, u = simple_scene()
    u = u.copy()
    u[[0, 23]] = u[[23, 0]]  # two corners mislabelled
    res = estimate_pose(X, u, cam)
    assert not res.ok and "reprojection RMS" in res.error and "local minimum" in res.error
    res = estimate_pose(X, u, cam, max_rms_px=None)
    assert res.ok and res.reproj_rms_px > 5.0


def test_best_method_prefers_sqpnp_unless_clearly_beaten():
    cam, X, R, t, u = simple_scene()
    res = estimate_all(X, u + 0.2 * np.random.default_rng(3).normal(size=u.shape), cam)
    assert best_method(res) == "sqpnp"
    bad = dict(res)
    bad["sqpnp"] = _fail("sqpnp", "x")
    assert best_method(bad) in METHODS and best_method(bad) != "sqpnp"
    assert best_method({m: _fail(m, "x") for m in METHODS}) is None


# --------------------------------------------------------------------- degenerate input
def _fails(X, u, cam, method="sqpnp", words=()):
    res = estimate_pose(X, u, cam, method)
    assert not res.ok and res.R_cam_from_target is None and res.cov is None, res
    for w in words:
        assert w in res.error, res.error
    return res


@pytest.mark.parametrize("method", METHODS)
def test_too_few_points(method):
    cam, X, R, t, u = simple_scene()
    _fails(X[:3], u[:3], cam, method, ["at least 4 points, got 3"])


def test_iterative_needs_six_points_off_a_plane():
    cam = hd_camera()
    X = np.array([[0, 0, 0], [60, 0, 10], [0, 60, 30], [60, 60, -20], [30, 10, 40.0]])
    R, t = rotation_about_axis([1.0, 0, 0], 0.3), np.array([0, 0, 400.0])
    u = cam.project(X @ R.T + t)
    _fails(X, u, cam, "iterative", ["at least 6 points off a plane"])
    _fails(X, u, cam, "ippe", ["coplanar"])
    for m in ("sqpnp", "epnp", "colmap"):
        res = estimate_pose(X, u, cam, m)
        assert res.ok and np.degrees(rotation_angle(R, res.R_cam_from_target)) < 1e-6, (m, res.error)


@pytest.mark.parametrize("method", METHODS)
def test_nan_and_collinear_points_give_no_pose(method):
    cam, X, R, t, u = simple_scene()
    bad = u.copy()
    bad[3, 1] = np.nan
    _fails(X, bad, cam, method, ["NaN"])
    line = np.stack([np.arange(8) * 20.0, np.arange(8) * 10.0, np.zeros(8)], -1)
    _fails(line, cam.project(line @ R.T + t), cam, method, ["collinear"])
    same = np.repeat(X[:1], 6, 0)
    _fails(same, np.repeat(u[:1], 6, 0), cam, method, ["collinear"])


@pytest.mark.parametrize("method", METHODS)
def test_board_seen_edge_on_gives_no_pose(method):
    """The camera in the board's plane images every corner on one line."""
    cam = hd_camera("pinhole")
    X = planar_points()
    R = rotation_about_axis([1.0, 0, 0], np.pi / 2)  # board plane contains the optical axis
    t = np.array([-75.0, 0.0, 400.0])
    u = cam.project(X @ R.T + t)
    assert np.all(np.isfinite(u))
    _fails(X, u, cam, method, ["one line"])


def test_fisheye_corners_beyond_90_degrees_are_an_error():
    cam, X, R, t, u = simple_scene(hd_camera("fisheye"))
    u = u.copy()
    u[0] = [cam.cx + 2000.0, cam.cy]  # far outside the image: beyond 90 degrees
    res = estimate_pose(X, u, cam)
    assert not res.ok and "cannot be undistorted" in res.error


def test_bad_arguments_raise_input_error():
    cam, X, R, t, u = simple_scene()
    with pytest.raises(InputError, match="unknown PnP method"):
        estimate_pose(X, u, cam, "p3p")
    with pytest.raises(InputError, match=r"\(K, 3\)"):
        estimate_pose(X[:, :2], u, cam)
    with pytest.raises(InputError, match="24 object points but 23"):
        estimate_pose(X, u[:-1], cam)
    with pytest.raises(InputError, match="corner sigma"):
        estimate_pose(X, u, cam, corner_sigma_px=0.0)
    with pytest.raises(InputError, match="RMS limit"):
        estimate_pose(X, u, cam, max_rms_px=-1.0)


# --------------------------------------------------------------------------- poses.json
def test_poses_json_round_trip(tmp_path):
    cam, X, R, t, u = simple_scene()
    u = u + 0.2 * np.random.default_rng(9).normal(size=u.shape)
    all_res = estimate_all(X, u, cam)
    one = estimate_pose(X, u, cam, "ippe")
    frames = [
        frame_record("000.png", one, ids=np.arange(24)),
        frame_record("001.png", all_res[best_method(all_res)], ids=np.arange(24), methods=all_res),
        empty_frame_record("002.png", "no board corners found"),
        frame_record("003.png", estimate_pose(X[:3], u[:3], cam)),
    ]
    p = tmp_path / "poses.json"
    write_board_poses(p, frames, camera="cam.yaml", method="all")
    raw = json.loads(p.read_text())
    assert raw["camera"] == "cam.yaml" and "left perturbation" in raw["cov_convention"]
    for f in raw["frames"]:
        assert all(k in f for k in POSE_KEYS)
    assert raw["frames"][2]["ok"] is False and raw["frames"][2]["R_cam_from_target"] is None
    assert raw["frames"][3]["error"] == "sqpnp needs at least 4 points, got 3"
    d = read_board_poses(p)
    f0, f1 = d["frames"][0], d["frames"][1]
    np.testing.assert_array_equal(f0["R_cam_from_target"], one.R_cam_from_target)
    np.testing.assert_array_equal(f0["t_cam_from_target"], one.t_cam_from_target)
    np.testing.assert_array_equal(f0["cov"], one.cov)
    np.testing.assert_array_equal(f0["rvec"], one.rvec)
    np.testing.assert_array_equal(f0["residuals_px"], one.residuals_px)
    assert f0["method"] == "ippe" and f0["corners"] == 24 and f0["reproj_rms_px"] == one.reproj_rms_px
    assert f0["alternative_rms_px"] == one.alternative_rms_px
    assert set(f1["methods"]) == set(METHODS) and f1["method"] == "sqpnp"
    for m, r in all_res.items():
        np.testing.assert_array_equal(f1["methods"][m]["R_cam_from_target"], r.R_cam_from_target)
        np.testing.assert_array_equal(f1["methods"][m]["cov"], r.cov)
    # rvec, tvec and normal agree with R and t
    np.testing.assert_allclose(rotation_about_axis(f0["rvec"], np.linalg.norm(f0["rvec"])), f0["R_cam_from_target"],
                               atol=1e-12)
    np.testing.assert_array_equal(f0["tvec"], f0["t_cam_from_target"])
    np.testing.assert_array_equal(f0["normal"], f0["R_cam_from_target"][:, 2])
    # no overwrite without force
    with pytest.raises(InputError, match="already exists"):
        write_board_poses(p, frames)
    write_board_poses(p, frames[:1], force=True)
    assert len(read_board_poses(p)["frames"]) == 1


def test_read_poses_rejects_malformed(tmp_path):
    p = tmp_path / "bad.json"
    p.write_text(json.dumps({"frames": [{"image": "a.png", "ok": True}]}))
    with pytest.raises(InputError, match="missing"):
        read_board_poses(p)
    rec = empty_frame_record("a.png", "x")
    rec.update(ok=True)
    p.write_text(json.dumps({"frames": [rec]}))
    with pytest.raises(InputError, match="finite 'R_cam_from_target'"):
        read_board_poses(p)
    rec["R_cam_from_target"], rec["t_cam_from_target"] = [[1, 0], [0, 1]], [0, 0, 1]
    p.write_text(json.dumps({"frames": [rec]}))
    with pytest.raises(InputError, match=r"shape \(3, 3\)"):
        read_board_poses(p)
    p.write_text("[]")
    with pytest.raises(InputError, match="'frames' list"):
        read_board_poses(p)


# ---------------------------------------------------------------------------- real data
def test_realsense_charuco_methods_agree():
    """28 real 1280x720 frames of a 7x5 ChArUco board (calib.io, 30 mm squares) with the
    published intrinsics: every method agrees with sqpnp within 0.1 deg / 0.5 mm (EPnP
    after the planar twin check); the RMS is below 1 px over the set and below 1.5 px on
    every frame (three frames are at 1.0-1.1 px)."""
    import cv2

    from pencilcal.toolkit.board.detect import detect_board

    d = data_dir("realsense-charuco-7x5-calibio")
    z = np.load(d / "camera_intrinsics.npz")
    cam = Camera("opencv", 1280, 720, z["cameraMatrix"], z["distCoeffs"].ravel())
    X = SMALL_BOARD.object_points()
    files = sorted((d / "intrinsics_images").glob("*.png"))
    assert len(files) == 28
    rms, full = [], 0
    for f in files:
        det = detect_board(cv2.imread(str(f)), SMALL_BOARD)
        if det.count < 24:
            continue
        full += 1
        res = estimate_all(X[det.ids], det.corners, cam)
        ref = res["sqpnp"]
        rms.append(ref.reproj_rms_px)
        for m, r in res.items():
            assert r.ok, (f.name, m, r.error)
            assert np.degrees(rotation_angle(r.R_cam_from_target, ref.R_cam_from_target)) < 0.1, (f.name, m)
            assert np.linalg.norm(r.t_cam_from_target - ref.t_cam_from_target) < 0.5, (f.name, m)
            if m != "epnp":  # EPnP returns the wrong planar twin on some of these frames
                assert not r.flipped, (f.name, m)
        assert ref.distance > 200 and ref.normal[2] > 0  # the board faces the camera
        # without refinement the closed-form methods are near the optimum already
        for m in ("sqpnp", "iterative", "colmap"):
            raw = estimate_pose(X[det.ids], det.corners, cam, m, refine=False)
            assert np.degrees(rotation_angle(raw.R_cam_from_target, ref.R_cam_from_target)) < 0.5, (f.name, m)
    assert full >= 23
    rms = np.array(rms)
    assert np.sqrt(np.mean(rms**2)) < 1.0 and rms.max() < 1.5


def test_stereo_pairs_agree_on_one_relative_rotation(tmp_path):
    """The da Vinci frames are a stereo pair: R_r R_l^T must be one rotation in every frame.

    A test of the PnP covariances on real corners without truth (`checks.rig_check`): the
    cameras verge by about 0.5 deg and the per-frame relative rotations scatter by about
    0.13 deg (median). The corner-noise covariance alone is too confident: about a third of
    the pairs fall inside its 68 % region. With the intrinsics' covariance and the
    correlated corner-noise model of the calibration (`pencilcal calibrate`, carried by the
    camera file) the totals cover 68 +- 8 %. The two halves of each calibration agree
    within their sigmas (`calibration_checks.calibration_halves`, in the report), and orient's grid
    pencil agrees with PnP within both totals."""
    from click.testing import CliRunner

    from pencilcal.cli.main import cli
    from pencilcal.validation.checks import pair_by_name, rig_check
    from pencilcal.validation.pnp import PoseResult, read_board_poses

    d = data_dir("sksurgery-davinci-charuco-stereo")
    (tmp_path / "board.yaml").write_text("type: charuco\nsquares: [19, 26]\nsquare: 5.0\nmarker: 4.0\n"
                                        "dictionary: DICT_4X4_250\nlegacy: true\n")
    poses, calib = {}, {}
    for side in ("left", "right"):
        for args in (["calibrate", d / side, "--board", tmp_path / "board.yaml", "-o", tmp_path / f"{side}.json",
                      "--report", tmp_path / f"{side}_calib.json"],
                     ["pnp", d / side, "--camera", tmp_path / f"{side}.json", "--board", tmp_path / "board.yaml",
                      "--method", "sqpnp", "-o", tmp_path / f"{side}_poses.json"]):
            r = CliRunner().invoke(cli, [str(a) for a in args] + ["-q"])
            assert r.exit_code == 0, r.output
        calib[side] = json.loads((tmp_path / f"{side}_calib.json").read_text())
        frames = read_board_poses(tmp_path / f"{side}_poses.json")["frames"]
        poses[side] = {f["image"]: PoseResult.from_record(f) for f in frames if f["ok"]}
    for side in ("left", "right"):
        halves = calib[side]["cross_validation"]["odd_even"]
        assert halves["p_value"] > 0.01, (side, halves)
        assert all(p.intrinsics_used and p.cov_total is not None for p in poses[side].values())
    names = sorted(set(poses["left"]) & set(poses["right"]))
    assert len(names) >= 40
    left, right = pair_by_name(names, [poses["left"][n] for n in names], poses["right"])
    covs = tuple(np.asarray(calib[s]["cov_intrinsics"]["cov"]) for s in ("left", "right"))
    rig = rig_check(left, right, covs)
    assert 0.3 < rig["vergence_deg"] < 0.8
    assert rig["noise"]["scatter_median_deg"] < 0.2
    lo, hi = 0.68 - 0.08, 0.68 + 0.08
    assert rig["noise"]["inside"] < lo  # the corner noise alone is too confident on real corners
    assert lo <= rig["total"]["inside"] <= hi and rig["total"]["consistent"], rig["total"]
    # orient on the board's grid lines through a corner, against PnP on the same corners: the
    # totals of both (each with the calibration's uncertainty) cover 68 +- 8 % of the tilt
    # differences, and the normal's within 8 % of the 2-D expectation
    r = CliRunner().invoke(cli, [str(a) for a in (
        "validate", d / "left", "--camera", tmp_path / "left.json", "--board", tmp_path / "board.yaml",
        "--grid-pencil", "auto", "--methods", "sqpnp", "-o", tmp_path / "grid.json", "-q")])
    assert r.exit_code == 0, r.output
    s = json.loads((tmp_path / "grid.json").read_text())["summary"]["orient:exact"]
    assert s["frames"] >= 45
    assert lo <= s["tilt_coverage"]["fraction"] <= hi, s["tilt_coverage"]
    assert abs(s["normal_coverage"]["fraction"] - s["normal_coverage"]["expected"]) <= 0.08, s["normal_coverage"]

# ------------------------------------------------------------ the board as calibrated
def _warped_views(warp, draws, noise_px, seed):
    """A 9 x 6 chessboard of 25 mm whose corners bow by `warp` (2,) [mm] at the middle, seen
    tilted 30 deg at 500 mm: (board, truth camera, R, t, noisy views (draws, K, 2))."""
    from pencilcal.toolkit.board.bundle import warp_basis

    board = board_from_dict({"type": "chessboard", "squares": [9, 6], "square": 25.0})
    cam = Camera("opencv", 640, 480, [[530.0, 0, 322.0], [0, 531.0, 238.0], [0, 0, 1]], [-0.2, 0.05, 0, 0, 0])
    X = board.object_points()
    Xw = X.copy()
    Xw[:, 2] += warp_basis(X, X) @ np.asarray(warp, float)
    R = rotation_about_axis([1.0, 0.3, 0.0], np.radians(30.0))
    t = np.array([-100.0, -60.0, 500.0]) - R @ X.mean(0)
    u = cam.project(Xw @ R.T + t)
    rng = np.random.default_rng(seed)
    return board, cam, R, t, u + rng.normal(0, noise_px, (draws,) + u.shape)


def _pose_chi2(res, R, t, cov):
    d = np.r_[rotvec_from_rotation(R @ res.R_cam_from_target.T), t - res.t_cam_from_target]
    return float(d @ np.linalg.solve(cov, d))


def test_board_poses_use_the_calibrated_warp_and_its_sigma():
    # the camera's calibration of this board measured a bow of -0.4 +- 0.05 mm along y: its
    # poses are those of the bowed board, and cov_total holds the bow's sigma; the nominal
    # flat board puts the pose off by many of its sigmas
    from pencilcal.validation.pnp import board_points

    board, truth, R, t, views = _warped_views([0.0, -0.4], 40, 0.05, 3)
    meta = {"calibration": {"board": json.loads(json.dumps(board.to_dict()))},
            "board_warp": {"value": [0.0, -0.4], "cov": [[0.05 ** 2, 0.0], [0.0, 0.05 ** 2]]}}
    cam = Camera(truth.model, 640, 480, truth.K, truth.dist, meta=meta)
    ids = np.arange(board.object_points().shape[0])
    X, warp = board_points(board, cam, ids)
    assert warp is not None and np.isclose(X[:, 2].min(), -0.4 * 0.96)  # rows at 0.4 and 0.6 of the grid
    flat, nominal = [], []
    for u in views:
        res = estimate_pose(X, u, cam, board_warp=warp, corner_noise=None, intrinsics_cov=None)
        assert res.ok and res.cov_total is not None
        # the warp's share: the total exceeds the corner term alone
        assert np.trace(res.cov_total) > np.trace(res.cov)
        flat.append(_pose_chi2(res, R, t, res.cov_total))
        plain = estimate_pose(board.object_points(), u, truth)
        nominal.append(_pose_chi2(plain, R, t, plain.cov))
    assert np.mean(flat) / 6 < 1.6
    assert np.mean(nominal) / 6 > 10.0
    # another board (or none recorded) gives the nominal points
    other = board_from_dict({"type": "chessboard", "squares": [9, 6], "square": 24.0})
    assert board_points(other, cam, ids[:5])[1] is None
    with pytest.raises(InputError, match="warp's basis"):
        estimate_pose(X, views[0], cam, board_warp=(warp[0][:5], warp[1]))


def test_board_pose_finds_corners_as_the_calibration_did():
    # a camera whose calibration refined ChArUco corners to their point of symmetry (its
    # statistics say so, and a calib.json passes that on to a camera file that lost it)
    # has them refined so in its board poses; a camera without the record, CharucoDetector's
    from pencilcal.toolkit.board.calibration_file import CalibrationFile, camera_with_report, symmetric_corners_of
    from pencilcal.toolkit.synth.render import render_frame
    from pencilcal.toolkit.synth.sheet import layout_sheet
    from pencilcal.validation.pnp import board_pose

    board = board_from_dict({"type": "charuco", "squares": [7, 5], "square": 30.0, "marker": 22.0,
                             "dictionary": "DICT_4X4_50"})
    plain = Camera("opencv", 640, 480, [[600.0, 0, 319.5], [0, 600.0, 239.5], [0, 0, 1]], [-0.05, 0.01, 0, 0])
    sym = Camera(plain.model, 640, 480, plain.K, plain.dist, meta={"calibration": {"symmetric_corners": True}})
    report = CalibrationFile(sym, None, None, None, "calib.json")
    assert symmetric_corners_of(camera_with_report(plain, report)) and not symmetric_corners_of(plain)
    R = rotation_about_axis([0.6, 0.8, 0.0], np.radians(30))
    t = np.array([5.0, -5.0, 420.0]) - R @ board.object_points().mean(0)
    img = render_frame(plain, R, t, layout_sheet(board, paper="a3"), background="plain", blur_px=1.4, noise=1.0,
                       rng=np.random.default_rng(1))
    a, b = board_pose(img, plain, board), board_pose(img, sym, board)
    assert a.ok and b.ok and a.corners == b.corners == 24
    assert b.reproj_rms_px < 0.5 * a.reproj_rms_px, (a.reproj_rms_px, b.reproj_rms_px)  # 0.066 -> 0.015 px

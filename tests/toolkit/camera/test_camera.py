"""Camera models against OpenCV and pycolmap, undistortion accuracy, Jacobians, validation."""
from __future__ import annotations

import pickle
from copy import deepcopy

import cv2
import numpy as np
import pycolmap
import pytest

from pencilcal.toolkit.camera.model import Camera, tilt_matrices
from pencilcal.toolkit.camera.formats import camera_from_colmap
from pencilcal.toolkit.errors import InputError

W, H = 1920, 1080
K0 = np.array([[1500.25, 0.0, 962.3], [0.0, 1497.75, 537.9], [0.0, 0.0, 1.0]])

# realistic coefficients for each opencv coefficient count (k1 k2 p1 p2 k3 k4 k5 k6 s1..s4 taux tauy)
COEFFS = {
    4: [-0.21, 0.07, 0.0012, -0.0008],
    5: [-0.28, 0.11, 0.0009, -0.0011, -0.025],
    8: [0.35, -0.12, 0.0011, -0.0007, 0.02, 0.62, -0.05, 0.03],
    12: [0.35, -0.12, 0.0011, -0.0007, 0.02, 0.62, -0.05, 0.03, 0.0015, -0.0003, -0.0012, 0.0002],
    14: [0.35, -0.12, 0.0011, -0.0007, 0.02, 0.62, -0.05, 0.03, 0.0015, -0.0003, -0.0012, 0.0002, 0.012, -0.008],
}
FISHEYE = [0.031, -0.012, 0.0041, -0.0007]


def _points(rng, n=400, half_angle_deg=35.0):
    """Random camera-frame points in front of the camera within a cone."""
    t = np.tan(np.radians(half_angle_deg))
    xy = rng.uniform(-t, t, (n, 2))
    z = rng.uniform(0.3, 5.0, n)
    return np.column_stack([xy * z[:, None], z])


def _cameras():
    cams = {"pinhole": Camera("pinhole", W, H, K0)}
    for n, d in COEFFS.items():
        cams[f"opencv{n}"] = Camera("opencv", W, H, K0, d)
    cams["fisheye"] = Camera("fisheye", W, H, [[700.5, 0, 958.1], [0, 701.25, 541.2], [0, 0, 1]], FISHEYE)
    cams["strong"] = Camera("opencv", W, H, [[1500.0, 0, 959.5], [0, 1500.0, 539.5], [0, 0, 1]], [-0.3, 0.12, 0.0, 0.0])
    Ks = K0.copy()
    Ks[0, 1] = 2.5
    cams["skew"] = Camera("opencv", W, H, Ks, COEFFS[5])
    return cams


CAMERAS = _cameras()


# ------------------------------------------------------------------ projection vs OpenCV
@pytest.mark.parametrize("n", sorted(COEFFS))
def test_project_matches_cv2_projectPoints(rng, n):
    cam = CAMERAS[f"opencv{n}"]
    pts = _points(rng)
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), cam.K, cam.dist)
    np.testing.assert_allclose(cam.project(pts), ref[:, 0], rtol=0, atol=1e-9)


def test_project_matches_cv2_fisheye(rng):
    cam = CAMERAS["fisheye"]
    pts = _points(rng, half_angle_deg=60.0)
    ref, _ = cv2.fisheye.projectPoints(pts[:, None], np.zeros(3), np.zeros(3), cam.K, cam.dist)
    np.testing.assert_allclose(cam.project(pts), ref[:, 0], rtol=0, atol=1e-9)


def test_project_pinhole_matches_cv2(rng):
    cam = CAMERAS["pinhole"]
    pts = _points(rng)
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), cam.K, None)
    np.testing.assert_allclose(cam.project(pts), ref[:, 0], rtol=0, atol=1e-9)


def test_skew_is_applied_through_K(rng):
    """cv2.projectPoints ignores K[0,1]; ours is K @ (x_d, y_d, 1), as cv2.fisheye's alpha."""
    cam = CAMERAS["skew"]
    pts = _points(rng)
    xd, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), np.eye(3), cam.dist)
    xd = xd[:, 0]
    expected = np.column_stack([cam.fx * xd[:, 0] + cam.skew * xd[:, 1] + cam.cx, cam.fy * xd[:, 1] + cam.cy])
    np.testing.assert_allclose(cam.project(pts), expected, rtol=0, atol=1e-9)

    fish = Camera("fisheye", W, H, [[700.0, 3.5, 958.0], [0, 702.0, 541.0], [0, 0, 1]], FISHEYE)
    ref, _ = cv2.fisheye.projectPoints(pts[:, None], np.zeros(3), np.zeros(3), fish.K, fish.dist, alpha=3.5 / 700.0)
    np.testing.assert_allclose(fish.project(pts), ref[:, 0], rtol=0, atol=1e-9)


def test_tilt_matrices_inverse():
    T, Ti = tilt_matrices(0.05, -0.03)
    np.testing.assert_allclose(T @ Ti, np.eye(3), atol=1e-15)
    T0, _ = tilt_matrices(0.0, 0.0)
    np.testing.assert_array_equal(T0, np.eye(3))


# ---------------------------------------------------------------- projection vs pycolmap
COLMAP_CASES = {
    "SIMPLE_PINHOLE": [1210.5, 962.3, 538.1],
    "PINHOLE": [1210.5, 1205.25, 962.3, 538.1],
    "SIMPLE_RADIAL": [1210.5, 962.3, 538.1, -0.12],
    "RADIAL": [1210.5, 962.3, 538.1, -0.12, 0.03],
    "OPENCV": [1210.5, 1205.25, 962.3, 538.1, -0.12, 0.03, 0.0011, -0.0009],
    "FULL_OPENCV": [1210.5, 1205.25, 962.3, 538.1, 0.31, -0.1, 0.0011, -0.0009, 0.02, 0.6, -0.04, 0.02],
    "OPENCV_FISHEYE": [700.5, 701.25, 962.3, 538.1, 0.031, -0.012, 0.0041, -0.0007],
}


@pytest.mark.parametrize("model", sorted(COLMAP_CASES))
def test_project_matches_pycolmap(rng, model):
    """COLMAP's pixel centre of the top-left pixel is (0.5, 0.5), ours (0, 0)."""
    ccam = pycolmap.Camera(model=model, width=W, height=H, params=COLMAP_CASES[model], camera_id=1)
    cam = camera_from_colmap(ccam)
    i_cx = 1 if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL") else 2
    assert (cam.cx, cam.cy) == (COLMAP_CASES[model][i_cx] - 0.5, COLMAP_CASES[model][i_cx + 1] - 0.5)
    pts = _points(rng, half_angle_deg=30.0)
    ref = ccam.img_from_cam(pts)
    np.testing.assert_allclose(cam.project(pts) + 0.5, ref, rtol=0, atol=1e-9)


# ---------------------------------------------------------------- undistortion
def _pixel_grid(cam, n=41, margin=0.0):
    u = np.linspace(-0.5 + margin, cam.width - 0.5 - margin, n)
    v = np.linspace(-0.5 + margin, cam.height - 0.5 - margin, n)
    return np.stack(np.meshgrid(u, v), -1)


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_undistort_then_distort_returns_the_pixel(name):
    cam = CAMERAS[name]
    px = _pixel_grid(cam)  # includes the image corners
    xy = cam.normalized_from_pixels(px)
    assert xy.shape == px.shape
    assert np.all(np.isfinite(xy)), f"{np.isnan(xy).any(-1).sum()} pixels failed to undistort"
    err = np.abs(cam.pixels_from_normalized(xy) - px).max()
    assert err < 1e-6, err
    # and the forward direction: normalised -> pixels -> normalised
    np.testing.assert_allclose(cam.normalized_from_pixels(cam.pixels_from_normalized(xy)), xy, rtol=0, atol=1e-12)


def test_strong_distortion_is_more_accurate_than_cv2_default():
    """k1=-0.3, k2=0.12, f=1500 on 1920x1080: cv2.undistortPoints' 5 default iterations
    leave errors far above ours at the corners."""
    cam = CAMERAS["strong"]
    px = _pixel_grid(cam, 21)
    ours = np.abs(cam.pixels_from_normalized(cam.normalized_from_pixels(px)) - px).max()
    cv = cv2.undistortPoints(px.reshape(-1, 1, 2), cam.K, cam.dist)[:, 0]
    theirs = np.abs(cam.pixels_from_normalized(cv).reshape(px.shape) - px).max()
    assert ours < 1e-8 and theirs > 1e-3


def test_undistortion_beyond_a_fold_is_nan():
    """r_d = r (1 - 0.5 r^2) peaks at r_d = 0.544 (r = 0.816): beyond, no undistorted point
    exists, and below it the root on the centre's branch must be the one returned."""
    f = 1000.0
    cam = Camera("opencv", 1920, 1080, [[f, 0, 959.5], [0, f, 539.5], [0, 0, 1]], [-0.5, 0.0, 0.0, 0.0])
    r_d = np.array([0.1, 0.3, 0.5, 0.54, 0.55, 0.8])
    px = np.column_stack([959.5 + f * r_d, np.full(r_d.size, 539.5)])
    xy = cam.normalized_from_pixels(px)
    assert np.all(np.isfinite(xy[:4])) and np.all(np.isnan(xy[4:]))
    assert np.all(xy[:4, 0] < np.sqrt(2.0 / 3.0))
    np.testing.assert_allclose(cam.pixels_from_normalized(xy[:4]), px[:4], rtol=0, atol=1e-9)

    # r_d = r - 0.5 r^3 + 0.1 r^5 rises to 0.6 (r = 1), falls to 0.566 (r = sqrt 2), rises
    # again: r_d = 0.65 .. 1.0 have roots only on the outer branch, which Newton does find
    # (r ~ 1.7) but which is not the lens; they must be NaN
    cam = Camera("opencv", 4000, 4000, [[f, 0, 1999.5], [0, f, 1999.5], [0, 0, 1]], [-0.5, 0.1, 0.0, 0.0])
    r_d = np.array([0.3, 0.55, 0.59, 0.65, 0.7, 0.8, 1.0])
    px = 1999.5 + f * r_d[:, None] * [np.cos(0.3), np.sin(0.3)]
    r = np.hypot(*cam.normalized_from_pixels(px).T)
    assert np.all(r[:3] < 1.0) and np.all(np.isnan(r[3:]))


def test_points_behind_a_pinhole_camera_are_nan():
    cam = CAMERAS["opencv5"]
    out = cam.project([[0.1, 0.2, -1.0], [0.1, 0.2, 0.0], [0.1, 0.2, 1.0]])
    assert np.all(np.isnan(out[:2])) and np.all(np.isfinite(out[2]))


def test_fisheye_rays_beyond_90_degrees():
    # theta_d(theta) must increase up to 150 deg for the pixels there to be unique
    cam = Camera("fisheye", 1600, 1600, [[300.0, 0, 799.5], [0, 300.0, 799.5], [0, 0, 1]],
                 [0.01, -0.002, 0.0003, -0.00001])
    ang = np.radians([0.0, 10.0, 60.0, 89.0, 95.0, 120.0, 150.0])
    az = np.radians([0.0, 30.0, 135.0, -60.0, 200.0, 75.0, -170.0])
    rays = np.column_stack([np.sin(ang) * np.cos(az), np.sin(ang) * np.sin(az), np.cos(ang)])
    px = cam.project(rays)
    assert np.all(np.isfinite(px))
    np.testing.assert_allclose(cam.rays_from_pixels(px), rays, rtol=0, atol=1e-12)
    xy = cam.normalized_from_pixels(px)
    assert np.all(np.isfinite(xy[:4])) and np.all(np.isnan(xy[4:]))  # z = 1 plane ends at 90 deg


@pytest.mark.parametrize("name", ["pinhole", "opencv8", "opencv14", "fisheye", "skew"])
def test_rays_from_pixels_are_unit_and_reproject(rng, name):
    cam = CAMERAS[name]
    pts = _points(rng, 200, 30.0)
    rays = cam.rays_from_pixels(cam.project(pts))
    np.testing.assert_allclose(np.linalg.norm(rays, axis=-1), 1.0, atol=1e-15)
    np.testing.assert_allclose(rays, pts / np.linalg.norm(pts, axis=-1, keepdims=True), rtol=0, atol=1e-11)


@pytest.mark.parametrize("name", ["pinhole", "opencv12", "fisheye", "skew"])
def test_undistort_and_distort_pixels(name):
    cam = CAMERAS[name]
    px = _pixel_grid(cam, 15)
    ideal = cam.undistort_pixels(px)
    np.testing.assert_allclose(ideal, cam._apply_K(cam.normalized_from_pixels(px)), rtol=0, atol=1e-12)
    np.testing.assert_allclose(cam.distort_pixels(ideal), px, rtol=0, atol=1e-7)
    if name == "pinhole":
        np.testing.assert_allclose(ideal, px, rtol=0, atol=1e-10)


def test_undistort_pixels_matches_cv2_with_tight_criteria():
    cam = CAMERAS["opencv8"]
    px = _pixel_grid(cam, 9, margin=100.0).reshape(-1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    ref = cv2.undistortPoints(px[:, None], cam.K, cam.dist, None, None, cam.K, crit)[:, 0]
    np.testing.assert_allclose(cam.undistort_pixels(px), ref, rtol=0, atol=1e-6)


# ---------------------------------------------------------------- Jacobian
@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_jacobian_matches_finite_differences(rng, name):
    cam = CAMERAS[name]
    xy = rng.uniform(-0.45, 0.45, (50, 2))
    xy[0] = 0.0  # the optical axis (fisheye special case)
    xy[1] = [3e-9, -2e-9]
    J = cam.jacobian_pixels_from_normalized(xy)
    assert J.shape == (50, 2, 2)
    h = 1e-6
    num = np.empty_like(J)
    for j in range(2):
        e = np.zeros(2)
        e[j] = h
        num[..., j] = (cam.pixels_from_normalized(xy + e) - cam.pixels_from_normalized(xy - e)) / (2 * h)
    np.testing.assert_allclose(J, num, rtol=1e-6, atol=1e-4)


def test_jacobian_broadcasts():
    cam = CAMERAS["opencv5"]
    xy = np.zeros((3, 4, 2))
    assert cam.jacobian_pixels_from_normalized(xy).shape == (3, 4, 2, 2)
    np.testing.assert_allclose(cam.jacobian_pixels_from_normalized([0.0, 0.0]), [[cam.fx, 0], [0, cam.fy]])


def test_methods_broadcast_over_leading_dims(rng):
    cam = CAMERAS["opencv8"]
    pts = _points(rng, 24).reshape(2, 3, 4, 3)
    px = cam.project(pts)
    assert px.shape == (2, 3, 4, 2)
    np.testing.assert_allclose(px.reshape(-1, 2), cam.project(pts.reshape(-1, 3)), rtol=0, atol=0)
    assert cam.normalized_from_pixels(px).shape == (2, 3, 4, 2)
    assert cam.rays_from_pixels(px).shape == (2, 3, 4, 3)
    assert CAMERAS["fisheye"].rays_from_pixels(px).shape == (2, 3, 4, 3)
    assert cam.project([0.0, 0.0, 1.0]).shape == (2,)


# ---------------------------------------------------------------- validation and equality
BAD = {
    "unknown model": dict(model="kb4", K=K0, dist=FISHEYE),
    "fx zero": dict(K=[[0.0, 0, 1], [0, 1, 1], [0, 0, 1]]),
    "fy negative": dict(K=[[1.0, 0, 1], [0, -1, 1], [0, 0, 1]]),
    "NaN in K": dict(K=[[np.nan, 0, 1], [0, 1, 1], [0, 0, 1]]),
    "inf in K": dict(K=[[1.0, 0, np.inf], [0, 1, 1], [0, 0, 1]]),
    "bottom row": dict(K=[[1.0, 0, 1], [0, 1, 1], [0, 0, 2]]),
    "lower triangle": dict(K=[[1.0, 0, 1], [0.1, 1, 1], [0, 0, 1]]),
    "K shape": dict(K=np.eye(2)),
    "K strings": dict(K=[["a", 0, 1], [0, 1, 1], [0, 0, 1]]),
    "3 coefficients": dict(model="opencv", dist=[0.1, 0.0, 0.0]),
    "6 coefficients": dict(model="opencv", dist=np.zeros(6)),
    "opencv without coefficients": dict(model="opencv", dist=[]),
    "fisheye 5": dict(model="fisheye", dist=np.zeros(5)),
    "pinhole with one": dict(model="pinhole", dist=[0.1]),
    "NaN coefficient": dict(model="opencv", dist=[0.1, np.nan, 0, 0]),
    "tilt too large": dict(model="opencv", dist=[0.0] * 12 + [2.0, 0.0]),
    "width zero": dict(width=0),
    "height negative": dict(height=-480),
    "fractional width": dict(width=640.5),
    "bool width": dict(width=True),
    "meta list": dict(meta=[1, 2]),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_invalid_cameras_raise_input_error(case):
    kw = dict(model="pinhole", width=640, height=480, K=[[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]], dist=[])
    kw.update(BAD[case])
    with pytest.raises(InputError) as e:
        Camera(**kw)
    assert "\n" not in str(e.value) and str(e.value)


def test_equality_hash_and_read_only():
    a = Camera("opencv", 640, 480, K0, [0.1, 0.0, 0.0, 0.0], meta={"rms_px": 0.3})
    b = Camera("opencv", 640.0, 480, K0.tolist(), (0.1, -0.0, 0.0, 0.0))
    assert a == b and hash(a) == hash(b)  # meta is not compared; -0.0 == 0.0
    assert a != Camera("opencv", 640, 480, K0, [0.1, 0.0, 0.0, 0.0, 0.0])
    assert a != Camera("opencv", 641, 480, K0, [0.1, 0.0, 0.0, 0.0])
    assert a != Camera("pinhole", 640, 480, K0)
    assert isinstance(b.width, int) and a.size == (640, 480)
    with pytest.raises(ValueError):
        a.K[0, 0] = 1.0
    with pytest.raises(ValueError):
        a.dist[0] = 1.0
    K = K0.copy()
    c = Camera("pinhole", 640, 480, K)
    K[0, 0] = 1.0  # the camera keeps its own copy
    assert c.fx == K0[0, 0]
    assert (a.fx, a.fy, a.cx, a.cy, a.skew) == (K0[0, 0], K0[1, 1], K0[0, 2], K0[1, 2], 0.0)
    for copy in (pickle.loads(pickle.dumps(CAMERAS["opencv14"])), deepcopy(a)):
        assert copy in (a, CAMERAS["opencv14"]) and not copy.K.flags.writeable


@pytest.mark.parametrize("dist", [[-0.2, 0.05, 0, 0, 0], [-0.45, 0.1, 0, 0, 0.02], [0.3, 0.2, 0, 0, 0],
                                  [-0.6, 0, 0, 0, 0], [-0.35, 0.12, 0, 0, -0.02]])
def test_radial_lens_undistorted_along_the_radius_as_the_general_solver(dist):
    """A k1, k2, k3 lens is inverted in one dimension (`_undistort_radial`): the same roots as
    the general 2-D solver to its tolerance, and NaN for the same pixels (beyond a fold,
    where strong barrel distortion folds the model over; the frame's corners and beyond)."""
    cam = Camera("opencv", 1920, 1080, [[1000.0, 0, 959.5], [0, 1000.0, 539.5], [0, 0, 1]], dist)
    px = np.random.default_rng(3).uniform([-500, -500], [2400, 1600], (4000, 2))
    fast = cam.normalized_from_pixels(px)
    general = cam._undistort_general(cam._distorted_from_pixels(px))
    assert np.array_equal(np.isnan(fast), np.isnan(general))
    both = np.isfinite(fast[:, 0])
    assert both.any() and np.abs(fast[both] - general[both]).max() < 1e-12

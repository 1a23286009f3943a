"""mrcal's splined stereographic model: projection, unprojection, Jacobians, files, and a
calibration on rendered views that recovers a distortion no opencv model holds."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from pencilcal.toolkit.board import bundle
from pencilcal.toolkit.camera import splined as S
from pencilcal.toolkit.camera.formats import read_camera, write_camera
from pencilcal.toolkit.camera.intrinsics import intrinsics_vector, jacobian_pixels_wrt_intrinsics, with_intrinsics
from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.errors import InputError

LEAN = Camera("opencv", 960, 540, [[760.0, 0, 483.2], [0, 760.4, 268.9], [0, 0, 1]],
              [-0.32, 0.14, 0.0006, -0.0004, -0.03])


def bumped(camera=LEAN, px=2.5, at=(0.18, -0.06), width=0.12):
    """A splined camera: `camera` plus a local bump of about `px` pixels along x centred at
    stereographic `at`: a distortion no opencv model holds."""
    cfg = S.config_covering(camera)
    c = S.fit_correction(cfg, camera).reshape(cfg.Ny, cfg.Nx, 2)
    kp = S.knot_positions(cfg)
    c[..., 0] += px / camera.fx * np.exp(-np.sum((kp - at) ** 2, -1) / (2 * width ** 2))
    return Camera(cfg.name, camera.width, camera.height, camera.K, c.ravel())


def grid(cam, n=24):
    w, h = cam.size
    return np.stack(np.meshgrid(np.linspace(0, w - 1, n), np.linspace(0, h - 1, n)), -1).reshape(-1, 2)


def test_names_parse_and_bad_ones_say_why():
    cfg = S.splined_config("LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=16_Ny=12_fov_x_deg=100")
    assert (cfg.Nx, cfg.Ny, cfg.fov_x_deg, cfg.parameters) == (16, 12, 100, 384)
    assert Camera(cfg.name.replace("splined_stereographic", S.MRCAL_PREFIX), 640, 480, np.eye(3) * [500, 500, 1]
                  + [[0, 0, 320], [0, 0, 240], [0, 0, 0]], np.zeros(384)).model == cfg.name
    for bad, why in (("splined_stereographic_order=2_Nx=8_Ny=6_fov_x_deg=90", "order=3"),
                     ("splined_stereographic_order=3_Nx=2_Ny=6_fov_x_deg=90", "Nx must be"),
                     ("splined_stereographic_order=3_Nx=8_Ny=6", "must read")):
        with pytest.raises(InputError, match=why):
            S.splined_config(bad)
    with pytest.raises(InputError, match="takes 96 distortion coefficients"):
        Camera("splined_stereographic_order=3_Nx=8_Ny=6_fov_x_deg=90", 640, 480,
               [[500.0, 0, 320], [0, 500, 240], [0, 0, 1]], np.zeros(10))


def test_a_zero_spline_is_the_stereographic_projection():
    cam = Camera(S.splined_name(8, 6, 170), 1000, 800, [[300.0, 0, 499.5], [0, 300.0, 399.5], [0, 0, 1]],
                 np.zeros(96))
    theta = np.radians([0.0, 30.0, 60.0, 89.0, 120.0])
    rays = np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], -1)
    np.testing.assert_allclose(cam.project(rays)[:, 0] - 499.5, 300.0 * 2 * np.tan(theta / 2), rtol=1e-12, atol=1e-9)


def test_projection_and_unprojection_round_trip_beyond_90_degrees():
    wide = Camera("fisheye", 1000, 800, [[280.0, 0, 499.5], [0, 280.0, 399.5], [0, 0, 1]], [0.02, -0.01, 0.0, 0.0])
    for source in (LEAN, wide):
        cam = bumped(source, px=3.0, at=(0.5, 0.3), width=0.2)
        px = grid(cam)
        px = px[np.all(np.isfinite(source.rays_from_pixels(px)), -1)]   # where the source lens is defined
        rays = cam.rays_from_pixels(px)
        assert np.all(np.isfinite(rays))
        np.testing.assert_allclose(cam.project(rays), px, atol=1e-8)
        xy = cam.normalized_from_pixels(px)
        front = np.all(np.isfinite(xy), -1)
        np.testing.assert_allclose(cam.pixels_from_normalized(xy[front]), px[front], atol=1e-8)
    assert rays[:, 2].min() < 0          # the fisheye-wide one sees beyond 90 degrees
    assert not np.all(front)             # where normalised coordinates do not exist (NaN)


def test_jacobians_match_finite_differences():
    cam = bumped()
    xy = cam.normalized_from_pixels(grid(cam, 7))
    e = 1e-7
    J = cam.jacobian_pixels_from_normalized(xy)
    Jn = np.stack([(cam.pixels_from_normalized(xy + [e, 0]) - cam.pixels_from_normalized(xy - [e, 0])) / (2 * e),
                   (cam.pixels_from_normalized(xy + [0, e]) - cam.pixels_from_normalized(xy - [0, e])) / (2 * e)], -1)
    np.testing.assert_allclose(J, Jn, atol=1e-5)
    Ji = jacobian_pixels_wrt_intrinsics(cam, xy)
    th = intrinsics_vector(cam)
    for j in (0, 1, 2, 3, 40, 41, 77, 78):
        d = np.zeros_like(th)
        d[j] = 1e-6
        num = (with_intrinsics(cam, th + d).pixels_from_normalized(xy)
               - with_intrinsics(cam, th - d).pixels_from_normalized(xy)) / 2e-6
        np.testing.assert_allclose(Ji[..., j], num, atol=1e-5)
    # the bundle's projection and pose Jacobian
    lay = bundle.splined_layout(bundle.Layout("opencv", 5), cam.spline, th)
    obj = np.c_[np.random.default_rng(1).uniform(-30, 30, (20, 2)), np.zeros(20)]
    x0 = np.r_[0.2, -0.3, 0.1, 1.0, 2.0, 120.0]
    px, _, Jp = bundle._project(lay, th, x0[:3], x0[3:], obj)
    np.testing.assert_allclose(px, cam.project(obj @ cv2.Rodrigues(x0[:3])[0].T + x0[3:]), atol=1e-9)
    for k in range(6):
        d = np.zeros(6)
        d[k] = 1e-6
        num = (bundle._project(lay, th, (x0 + d)[:3], (x0 + d)[3:], obj)[0]
               - bundle._project(lay, th, (x0 - d)[:3], (x0 - d)[3:], obj)[0]).ravel() / 2e-6
        np.testing.assert_allclose(Jp[:, k], num, atol=1e-5)


def test_files_round_trip_and_mrcal_text_reads(tmp_path):
    cam = bumped()
    for name in ("c.cameramodel", "c.json", "c.yaml"):
        write_camera(tmp_path / name, cam)
        assert read_camera(tmp_path / name) == cam
    assert "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3" in (tmp_path / "c.cameramodel").read_text()
    with pytest.raises(InputError, match="COLMAP has no splined"):
        write_camera(tmp_path / "cameras.txt", cam)
    # as mrcal writes one: its own name, %.10g numbers, extrinsics and a valid-region key
    values = [cam.fx, cam.fy, cam.cx, cam.cy] + cam.dist.tolist()
    cfg = cam.spline
    text = ("{\n 'lensmodel': '" + S.splined_name(cfg.Nx, cfg.Ny, cfg.fov_x_deg, mrcal=True) + "',\n"
            " 'intrinsics': [ " + ", ".join("%.10g" % v for v in values) + " ],\n"
            " 'valid_intrinsics_region': [ [ 0, 0 ], [ 959, 0 ], [ 959, 539 ], [ 0, 0 ] ],\n"
            " 'extrinsics': [ 0, 0, 0, 0, 0, 0 ],\n 'imagersize': [ 960, 540 ],\n}\n")
    (tmp_path / "m.cameramodel").write_text(text)
    back = read_camera(tmp_path / "m.cameramodel")
    assert back.model == cam.model
    px = grid(cam, 9)
    assert np.abs(back.project(cam.rays_from_pixels(px)) - px).max() < 1e-6
    (tmp_path / "short.cameramodel").write_text(text.replace(", ".join("%.10g" % v for v in values),
                                                             ", ".join("%.10g" % v for v in values[:-1])))
    with pytest.raises(InputError, match="short.cameramodel"):
        read_camera(tmp_path / "short.cameramodel")


def test_a_fit_on_renders_recovers_a_distortion_opencv_cannot_hold():
    from pencilcal.toolkit.board.calibrate import calibrate
    from pencilcal.toolkit.board.coverage import covered_grid
    from pencilcal.toolkit.board.detect import detect_board
    from pencilcal.toolkit.board.spec import board_from_dict
    from pencilcal.toolkit.board.synthetic import synthetic_detections
    from pencilcal.toolkit.camera.projection_uncertainty import projection_difference
    from pencilcal.toolkit.synth.chessboard import render_chessboard

    truth = bumped()
    board = board_from_dict({"type": "chessboard", "squares": [11, 8], "square": 4.77})
    poses = synthetic_detections(truth, board, views=24, noise_px=0.0, seed=3, tilt_deg=50.0, margin_px=12.0).truth
    rng = np.random.default_rng(3)
    dets = []
    for rvec, tvec in poses:
        img = render_chessboard(truth, cv2.Rodrigues(np.asarray(rvec, float))[0], tvec, board, rng, noise=3.0,
                                blur_px=1.0)
        img = cv2.imdecode(cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])[1], cv2.IMREAD_GRAYSCALE)
        dets.append(detect_board(img, board))
    assert sum(d is not None for d in dets) >= 20
    spl = calibrate(dets, board, truth.size, model=truth.model, warp=True)
    lean = calibrate(dets, board, truth.size, model="opencv", warp=True)
    region = covered_grid([d.corners for d in dets if d is not None], truth.size).pixels()

    def rms(cam):
        d = projection_difference(truth, cam, region, region)
        return float(np.sqrt(np.nanmean(np.sum(d * d, -1))))

    # measured: splined 0.023 px, opencv 5 0.32 px (RMS residual 0.036 against 0.125 px)
    assert rms(spl.camera) < 0.08
    assert rms(lean.camera) > 2.0 * rms(spl.camera)
    assert spl.rms_px < lean.rms_px


def test_colmap_takes_the_nearest_opencv_model_only_when_asked(tmp_path):
    from pencilcal.toolkit.camera.convert import convert_camera

    cam = bumped()
    with pytest.raises(InputError, match="COLMAP has no splined.*--approximate writes the best-fitting opencv"):
        convert_camera(cam, tmp_path / "cameras.txt")
    conv = convert_camera(cam, tmp_path / "cameras.txt", approximate=True)
    # the bump (2.5 px) is what no opencv model holds: measured 0.56 px at worst
    assert conv.camera.model == "opencv" and conv.fitted and 0.1 < conv.difference.max_px < 1.5


def test_calibrate_splined_places_its_grid_and_refuses_what_does_not_apply():
    from pencilcal.toolkit.board.calibrate import calibrate
    from pencilcal.toolkit.board.spec import board_from_dict
    from pencilcal.toolkit.board.synthetic import synthetic_detections

    board = board_from_dict({"type": "chessboard", "squares": [11, 8], "square": 4.77})
    truth = bumped()
    dets = synthetic_detections(truth, board, views=12, noise_px=0.1, seed=2, tilt_deg=45)
    r = calibrate(dets, board, truth.size, model="splined")
    cfg = r.camera.spline
    assert cfg is not None and r.model == r.camera.model and r.flags == []
    assert cfg.fov_x_deg >= 60 and cfg.Ny < cfg.Nx          # covers the 960 x 540 image, wider than tall
    assert r.rms_px < 0.2 and set(r.std_intrinsics) >= {"fx", "du_x[0,0]"}
    with pytest.raises(InputError, match="do not apply to the splined model"):
        calibrate(dets, board, truth.size, model="splined", fix_aspect=True)

"""toolkit/board/detect.py: ChArUco detection with the marker refinement run only when it can help,
its corners refined to their point of symmetry; chessboard corners under a falloff of light."""
from __future__ import annotations


import cv2
import numpy as np
import pytest

from pencilcal.toolkit.board import detect as detect_module
from pencilcal.toolkit.board.spec import board_from_dict
from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.board.detect import detect_board, refine_charuco_corners
from pencilcal.toolkit.geometry.frames import rotation_about_axis
from pencilcal.toolkit.synth.render import render_frame
from pencilcal.toolkit.synth.sheet import layout_sheet

BOARD = board_from_dict({"type": "charuco", "squares": [7, 5], "square": 30.0, "marker": 22.0,
                         "dictionary": "DICT_4X4_50"})


@pytest.fixture(scope="module")
def frame():
    cam = Camera("pinhole", 960, 720, [[900.0, 0, 479.5], [0, 900.0, 359.5], [0, 0, 1]])
    X = BOARD.object_points()
    R = rotation_about_axis([1.0, 0.2, 0], np.radians(25))
    t = np.array([0, 0, 520.0]) - R @ X.mean(0)
    return render_frame(cam, R, t, layout_sheet(BOARD, paper="a3"), background="plain", noise=1.0,
                        rng=np.random.default_rng(0))


def _damaged(img, marker_id):
    """The frame with a blot in one marker that makes the first detection pass miss it."""
    aruco = detect_module._charuco_detectors(BOARD)[0]
    mc, mi, _ = aruco.detectMarkers(img)
    c = mc[list(mi.ravel()).index(marker_id)].reshape(4, 2)
    p = (0.6 * c.mean(0) + 0.4 * c[0]).astype(int)
    out = img.copy()
    cv2.circle(out, (int(p[0]), int(p[1])), 4, 255 - int(img[p[1], p[0]]), -1)
    return out


def _reference(img, refine=True, symmetric=False):
    """CharucoDetector.detectBoard, markers refined inside it (tryRefineMarkers); with
    `symmetric`, its corners then refined to their point of symmetry (`refine_charuco_corners`)."""
    cp = cv2.aruco.CharucoParameters()
    cp.tryRefineMarkers = refine
    cc, ci, mc, mi = cv2.aruco.CharucoDetector(BOARD.cv2_board(), cp, cv2.aruco.DetectorParameters()).detectBoard(img)
    ids, corners = ci.ravel(), cc.reshape(-1, 2).astype(float)
    if symmetric:
        corners = refine_charuco_corners(img, corners, ids, BOARD.inner_corners[0])[0]
    order = np.argsort(ids)
    return ids[order], corners[order], mi.ravel(), np.asarray(mc, float).reshape(-1, 4, 2)


def _same(det, ref):
    ids, corners, m_ids, m_corners = ref
    return (np.array_equal(det.ids, ids) and np.array_equal(det.corners, corners)
            and np.array_equal(det.marker_ids, m_ids) and np.array_equal(det.marker_corners, m_corners))


def test_all_markers_found_needs_no_refinement(frame):
    """Every marker of the board found in the first pass: the marker refinement is skipped and
    the result is CharucoDetector's with tryRefineMarkers, exactly; asked, its corners refined
    to their point of symmetry."""
    aruco = detect_module._charuco_detectors(BOARD)[0]
    assert len(aruco.detectMarkers(frame)[1]) == 17
    det = detect_board(frame, BOARD)
    assert det.count == 24 and det.marker_ids.size == 17
    assert _same(det, _reference(frame)) and not det.symmetric
    # BGR input: the same
    assert _same(detect_board(cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR), BOARD), _reference(frame))
    sym = detect_board(frame, BOARD, symmetric=True)
    assert sym.symmetric and _same(sym, _reference(frame, symmetric=True))
    assert 0 < np.max(np.abs(sym.corners - det.corners)) < 1.0


def test_missed_marker_is_refound(frame):
    """A blotted marker the first pass misses is re-found from the board layout, as
    tryRefineMarkers does, and its four corners come back."""
    img = _damaged(frame, 2)
    aruco = detect_module._charuco_detectors(BOARD)[0]
    assert 2 not in aruco.detectMarkers(img)[1].ravel()
    without = _reference(img, refine=False)
    assert without[0].size < 24  # corners lost without the re-found marker
    det = detect_board(img, BOARD)
    assert det.count == 24 and 2 in det.marker_ids
    assert _same(det, _reference(img))
    assert _same(detect_board(img, BOARD, symmetric=True), _reference(img, symmetric=True))


def test_nothing_found():
    det = detect_board(np.full((240, 320), 255, np.uint8), BOARD)
    assert det.count == 0 and det.marker_ids.size == 0 and det.marker_corners.shape == (0, 4, 2)
    assert det.image_size == (320, 240)


DAVINCI = board_from_dict({"type": "charuco", "squares": [19, 26], "square": 5.0, "marker": 4.0,
                           "dictionary": "DICT_4X4_250", "legacy": True})


def test_charuco_corners_on_endoscope_like_renders():
    """ChArUco corners on rendered PAL endoscope views of the da Vinci board (720 x 576, fy /
    fx 1.09, barrel distortion, squares of 25-35 px with 3 px of white between marker and
    square, blur 1.4 px, vignetting falling to about a third at the image's corners, noise 5,
    JPEG 75). CharucoDetector's corners (cornerSubPix inside it) err by 0.2-0.3 px RMS per
    axis (0.29 measured); refined to their point of symmetry in a window of a fifth of the
    corner spacing, by under 0.05 px
    (0.038), and each
    view's mean error along the radius (what a vignetting's falloff would bias) by under
    0.01 px."""
    cam = Camera("opencv", 720, 576, [[833.0, 0, 300.0], [0, 909.0, 276.0], [0, 0, 1]], [-0.31, 0.4, 0, 0, 0])
    sheet = layout_sheet(DAVINCI, paper="a4")
    X = DAVINCI.object_points()
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[0:576, 0:720].astype(float)
    falloff = (1.0 + ((xx - 360.0) ** 2 + (yy - 288.0) ** 2) / 410.0 ** 2) ** -2
    before, after = [], []
    for k, (axis, deg) in enumerate([([1, 0.3, 0], 30), ([0.2, 1, 0], -35), ([1, -0.5, 0], -40), ([-0.4, 1, 0], 25)]):
        R = rotation_about_axis(np.array(axis, float), np.radians(deg))
        t = np.array([5.0 * (k - 1.5), 4.0, 130.0]) - R @ X.mean(0)
        img = render_frame(cam, R, t, sheet, background="plain", blur_px=1.4, rng=rng) * falloff
        img = np.clip(np.round(img + rng.normal(0, 5.0, img.shape)), 0, 255).astype(np.uint8)
        img = cv2.imdecode(cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 75])[1], cv2.IMREAD_GRAYSCALE)
        cc, ci, _, _ = detect_module._detect_charuco(img, DAVINCI)
        det = detect_board(img, DAVINCI, symmetric=True)
        assert det.count > 100 and np.array_equal(det.ids, np.sort(ci.ravel()))
        truth = cam.project(X @ R.T + t)[det.ids]
        radial = (truth - [cam.cx, cam.cy]) / np.linalg.norm(truth - [cam.cx, cam.cy], axis=1, keepdims=True)
        e = det.corners - truth
        assert abs(np.mean(np.sum(e * radial, 1))) < 0.01
        after.append(e)
        before.append(cc.reshape(-1, 2)[np.argsort(ci.ravel())] - truth)
    rms = [np.sqrt(np.mean(np.concatenate(e) ** 2)) for e in (before, after)]
    assert rms[0] > 0.15 and rms[1] < 0.05, rms


def test_charuco_refinement_keeps_what_it_cannot_refine():
    """A corner whose window leaves the image, or with no grid neighbour to size its window
    and no other corner to take the spacing from, keeps the detector's place."""
    img = np.full((60, 80), 128, np.uint8)
    corners = np.array([[2.0, 30.0], [40.0, 30.0]])
    out, done = refine_charuco_corners(img, corners, np.array([0, 2]), 6)
    assert np.array_equal(out, corners) and not done.any()
    out, done = refine_charuco_corners(img, corners[:1], np.array([0]), 6)
    assert np.array_equal(out, corners[:1]) and not done.any()


# ------------------------------------------------- chessboard corners under a falloff of light
def _x_junction(centre, angle, skew, blur, size=48, ss=8, square=22.0):
    """A chessboard corner at `centre` (x, y) [px], edges at `angle` and `angle + pi/2 +
    skew` [rad], area-sampled (ss x ss per pixel), blurred by `blur` [px]: (size, size)."""
    u = (np.arange(size * ss) + 0.5) / ss - 0.5
    x, y = np.meshgrid(u - centre[0], u - centre[1])
    a1 = (np.cos(angle) * x + np.sin(angle) * y) / square
    a2 = (-np.sin(angle + skew) * x + np.cos(angle + skew) * y) / square
    white = ((np.floor(a1) + np.floor(a2)) % 2 == 0).astype(float)
    return cv2.GaussianBlur(30 + 185 * white.reshape(size, ss, size, ss).mean((1, 3)), (0, 0), blur)


def test_symmetric_corner_does_not_follow_a_linear_falloff():
    """A brightness falling 0.6 % per px across the window shifts cornerSubPix's corner
    towards the brighter side (measured +0.03 to +0.12 px at blur 0.8-2.2 px); the point of
    symmetry under a linear gain and offset stays within a few thousandths of a pixel."""
    rng = np.random.default_rng(4)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 0.001)
    yy, xx = np.mgrid[0:48, 0:48].astype(float)
    sub, sym = [], []
    for _ in range(12):
        c = 24.0 + rng.uniform(-0.5, 0.5, 2)
        phi = rng.uniform(0, 2 * np.pi)
        g = np.array([np.cos(phi), np.sin(phi)])
        img = _x_junction(c, rng.uniform(0, np.pi / 2), rng.uniform(-0.3, 0.3), rng.uniform(1.5, 2.2))
        img = np.round(img * (1 + 0.006 * ((xx - c[0]) * g[0] + (yy - c[1]) * g[1]))).astype(np.float32)
        start = (c + rng.uniform(-0.6, 0.6, 2)).astype(np.float32).reshape(1, 1, 2)
        r = cv2.cornerSubPix(img, start, (7, 7), (-1, -1), crit).reshape(2).astype(float)
        q, ok = detect_module.symmetric_corners(img, r[None], 7)
        assert ok[0]
        sub.append((r - c) @ g)
        sym.append((q[0] - c) @ g)
    assert np.mean(sub) > 0.03, np.mean(sub)
    assert abs(np.mean(sym)) < 0.005 and np.max(np.abs(sym)) < 0.02, sym


def test_symmetric_corner_at_the_border_keeps_its_start():
    img = _x_junction((24.0, 24.0), 0.2, 0.0, 1.0)
    q, ok = detect_module.symmetric_corners(img, np.array([[3.0, 24.0], [24.4, 23.7]]), 6)
    assert not ok[0] and np.array_equal(q[0], [3.0, 24.0])
    assert ok[1] and np.allclose(q[1], 24.0, atol=0.01)


def test_chessboard_corners_under_vignetting():
    """Rendered endoscope chessboard views (960 x 540, barrel distortion, blur 1.8 px) lit
    by a falloff to about a third at the image's corners: the corners do not move towards
    the brighter centre (measured: each view's mean radial error -0.003 to +0.002 px,
    0.009-0.028 px RMS; cornerSubPix alone -0.02 to -0.04 px, 0.04-0.07 px RMS)."""
    from pencilcal.toolkit.board.synthetic import synthetic_detections
    from pencilcal.toolkit.synth.chessboard import render_chessboard

    cam = Camera("opencv", 960, 540, [[770.0, 0, 471.0], [0, 771.0, 281.0], [0, 0, 1]],
                 [-0.38, 0.21, 0.0008, -0.0006, -0.07])
    board = board_from_dict({"type": "chessboard", "squares": [11, 8], "square": 4.77})
    poses = synthetic_detections(cam, board, views=3, noise_px=0.0, seed=7, tilt_deg=55.0, margin_px=8.0).truth
    rng = np.random.default_rng(7)
    yy, xx = np.mgrid[0:540, 0:960].astype(float)
    falloff = (1.0 + ((xx - 480.0) ** 2 + (yy - 270.0) ** 2) / 550.0 ** 2) ** -2
    X = board.object_points()
    for rvec, tvec in poses:
        R = cv2.Rodrigues(np.asarray(rvec, float))[0]
        img = render_chessboard(cam, R, tvec, board, rng, noise=0.0, blur_px=1.8) * falloff
        img = np.clip(np.round(img + rng.normal(0, 1.0, img.shape)), 0, 255).astype(np.uint8)
        truth = cam.project(X @ R.T + np.asarray(tvec, float).ravel())
        det = detect_board(img, board)
        assert det.count == len(X)
        e = det.corners - truth[det.ids]
        if np.median(np.abs(e)) > 1:      # the board found turned by 180 deg (it is symmetric)
            e = det.corners - truth[::-1][det.ids]
        out = (truth - cam.K[:2, 2]) / np.linalg.norm(truth - cam.K[:2, 2], axis=1, keepdims=True)
        assert abs(np.mean(np.sum(e * out, 1))) < 0.01 and np.sqrt(np.mean(e ** 2)) < 0.035

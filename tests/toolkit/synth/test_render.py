"""Rendering: exact anti-aliased edges for every lens model, the printed sheet, the shaft."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from pencilcal.toolkit.board.spec import board_from_dict
from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.board.detect import detect_board
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.frames import rotation_about_axis
from pencilcal.toolkit.synth.render import (
    REFLECTANCE,
    Backdrop,
    Instrument,
    coverage,
    layout_sheet,
    polygon_coverage,
    render_frame,
    sheet_raster,
    target_coverage,
)

SHEET = layout_sheet()


def small_camera(model):
    """640x480 cameras with strong distortion (the edge tests want curved edges)."""
    if model == "fisheye":
        return Camera("fisheye", 640, 480, [[260.0, 0, 321.3], [0, 260.2, 238.2], [0, 0, 1]],
                      [0.03, -0.01, 0.002, -0.0005])
    K = [[520.0, 0, 321.3], [0, 520.4, 238.2], [0, 0, 1]]
    if model == "opencv":
        return Camera("opencv", 640, 480, K, [-0.3, 0.12, 0.0005, -0.0003, -0.02])
    return Camera("pinhole", 640, 480, K)


def board_pose(tilt_deg, distance, spin=0.2):
    R = rotation_about_axis([1.0, 0.3, 0.0], np.radians(tilt_deg)) @ rotation_about_axis([0, 0, 1.0], spin)
    return R, np.array([0.0, 0.0, distance]) - R @ np.array([87.5, 62.5, 0.0])


def true_edge_x(camera, R, t, rows, line_point, line_dir, lim_deg=None):
    """Band-averaged x of the projected target line over each pixel row [v - 0.5, v + 0.5]."""
    s = np.linspace(-3000.0, 3000.0, 600001)
    P = (np.asarray(line_point) + s[:, None] * np.asarray(line_dir)) @ R.T + t
    px = camera.project(P)
    # keep the part of the line the lens model maps faithfully (inside the image's field)
    corners = np.array([[0, 0], [camera.width - 1, 0], [0, camera.height - 1], [camera.width - 1, camera.height - 1.0]])
    max_angle = np.max(np.arccos(camera.rays_from_pixels(corners)[:, 2]))
    ang = np.arccos(P[:, 2] / np.linalg.norm(P, axis=1))
    ok = np.all(np.isfinite(px), 1) & (ang <= max_angle)
    px = px[ok][np.argsort(px[ok][:, 1])]
    out = []
    for v in rows:
        if not px[0, 1] < v - 1 < v + 1 < px[-1, 1]:
            out.append(np.nan)  # the sampled part of the line does not reach this row
            continue
        yy = np.linspace(v - 0.5, v + 0.5, 101)
        out.append(np.interp(yy, px[:, 1], px[:, 0]).mean())
    return np.array(out)


def area_edge(row_values, a):
    """Edge position along a row from the pixel-integrated profile (values 0 left of the
    edge, 1 right of it, starting at column a): the 50 % crossing of the box-filtered
    edge, exact for a straight edge whatever its angle."""
    return a - 0.5 + np.sum(1.0 - row_values)


# ------------------------------------------------------------------ the rasteriser
def test_coverage_is_exact_area_for_random_boxes(rng):
    W, H = 40, 30
    for _ in range(20):
        x0, x1 = np.sort(rng.uniform(-5, W + 5, 2))
        y0, y1 = np.sort(rng.uniform(-5, H + 5, 2))
        quad = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
        sign = rng.choice([-1, 1])
        cov = polygon_coverage([(quad if sign > 0 else quad[::-1], 1)], W, H)
        u, v = np.arange(W), np.arange(H)
        ox = np.clip(np.minimum(u + 0.5, x1) - np.maximum(u - 0.5, x0), 0, None)
        oy = np.clip(np.minimum(v + 0.5, y1) - np.maximum(v - 0.5, y0), 0, None)
        assert np.abs(cov - oy[:, None] * ox[None, :]).max() < 1e-12


def test_coverage_triangle_area_and_holes():
    tri = np.array([[1.2, 0.7], [17.9, 3.3], [6.1, 12.4]])
    cov = polygon_coverage([(tri, 1)], 20, 15)
    e1, e2 = tri[1] - tri[0], tri[2] - tri[0]
    area = 0.5 * abs(e1[0] * e2[1] - e1[1] * e2[0])
    assert cov.sum() == pytest.approx(area, abs=1e-9)
    hole = np.array([[4.0, 3.0], [8.0, 3.0], [8.0, 6.0], [4.0, 6.0]])
    cov2 = polygon_coverage([(tri, 1), (hole, -1)], 20, 15)
    assert cov2.sum() == pytest.approx(area - 12.0, abs=1e-9)
    assert cov2.min() > -1e-12 and cov2.max() < 1 + 1e-12
    # the edge list form: order does not matter
    a, b = tri, np.roll(tri, -1, 0)
    direct = coverage(a[::-1, 0], a[::-1, 1], b[::-1, 0], b[::-1, 1], np.ones(3), 20, 15)
    assert np.abs(direct - cov).max() < 1e-12


@pytest.mark.parametrize("model", ["pinhole", "opencv", "fisheye"])
@pytest.mark.parametrize("spin_deg", [0.0, 25.0, 50.0])
def test_edges_land_on_the_projected_truth(model, spin_deg):
    """A half-plane edge under a strongly distorting lens: every row's edge position (the
    50 % crossing of the pixel-integrated profile) matches the projected edge curve."""
    cam = small_camera(model)
    R = rotation_about_axis([0.2, 1.0, 0.0], np.radians(35)) @ rotation_about_axis([0, 0, 1.0], np.radians(spin_deg))
    t = np.array([20.0, 10.0, 300.0 if model != "fisheye" else 150.0])
    half = np.array([[0.0, -1e5], [1e5, -1e5], [1e5, 1e5], [0.0, 1e5]])  # x > 0 of the target
    cov = target_coverage(cam, R, t, [(half, 1)])
    rows = np.arange(12, cam.height - 12, 5)
    xt = true_edge_x(cam, R, t, rows, [0.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    slope = np.abs(np.gradient(xt, rows))
    with np.errstate(invalid="ignore"):
        keep = (xt > 20) & (xt < cam.width - 20) & (slope < 3.0)  # the row crosses the edge cleanly
    assert keep.sum() > 40
    errs = []
    for v, x in zip(rows[keep], xt[keep]):
        a = int(np.floor(x)) - 10
        row = cov[v, a:a + 21]
        if row[0] > 0.5:  # dark on the left: measure the bright side
            row = 1.0 - row
        if abs(row[0]) > 1e-9 or abs(row[-1] - 1.0) > 1e-9:
            continue  # another edge in the window: the plane's horizon, seen by the fisheye
        errs.append(area_edge(row, a) - x)
    assert len(errs) > 40
    assert np.max(np.abs(errs)) < 0.01  # measured ~1e-4 px


def test_rendered_image_edges_within_005_px():
    """The same check on the 8-bit image render_frame writes: the left edge of the board's
    first column (paper to the left, black squares to the right), opencv lens, no blur or
    noise, linear gamma."""
    cam = small_camera("opencv")
    R, t = board_pose(30.0, 330.0, spin=0.05)
    img = render_frame(cam, R, t, SHEET, background="plain").astype(float)
    white = 255 * REFLECTANCE["paper"]
    black = 255 * REFLECTANCE["ink"]
    errs = []
    for j in (0, 2, 4):  # black squares in column 0
        y0, y1 = j * 25.0 + 3.0, j * 25.0 + 22.0
        p0 = cam.project(R @ [0.0, y0, 0.0] + t)
        p1 = cam.project(R @ [0.0, y1, 0.0] + t)
        rows = np.arange(int(np.ceil(min(p0[1], p1[1]))) + 1, int(max(p0[1], p1[1])) - 1)
        xt = true_edge_x(cam, R, t, rows, [0.0, 0.0, 0.0], [0.0, 1.0, 0.0])
        for v, x in zip(rows, xt):
            a = int(np.floor(x)) - 4
            dark = np.clip((white - img[v, a:a + 9]) / (white - black), 0, 1)
            errs.append(area_edge(dark, a) - x)
    assert len(errs) > 50
    assert np.max(np.abs(errs)) < 0.05


def test_sheet_raster_matches_opencv_board_image():
    """The analytic board (black squares, marker bits and orientation) is OpenCV's board:
    at 2 px/mm every edge falls on a pixel border and the images agree exactly."""
    for squares, legacy in (([5, 4], False), ([4, 4], True)):
        board = board_from_dict({"type": "charuco", "squares": squares, "square": 14.0, "marker": 7.0,
                                 "dictionary": "DICT_5X5_100", "legacy": legacy})
        sheet = layout_sheet(board, radius=(10.0, 30.0), paper="a4")
        polys = [(p * 2.0 - 0.5, s) for p, s in sheet.ink_polygons[:len(sheet.ink_polygons) - sheet.pencil.count]]
        W, H = squares[0] * 28, squares[1] * 28
        ours = np.rint(255 * (1 - np.clip(polygon_coverage(polys, W, H), 0, 1))).astype(np.uint8)
        ref = board.cv2_board().generateImage((W, H), marginSize=0, borderBits=1)
        assert np.array_equal(ours, ref)


def test_sheet_layout_and_ink():
    s = SHEET
    x0, y0, x1, y1 = s.content_bounds
    px0, py0 = s.paper_origin
    assert px0 + s.margin <= x0 and x1 <= px0 + s.paper_size[0] - s.margin
    assert py0 + s.margin <= y0 and y1 <= py0 + s.paper_size[1] - s.margin
    # the fan sits beside the board: no bar reaches x < board width
    assert min(b[:, 0].min() for b in s.bars) >= s.board.size[0] + 7.9
    # bar k's centre line runs from radius[0] to radius[1] along (cos, sin) of its angle
    v, (r0, r1) = s.pencil.vertex, s.pencil.radius
    for th, bar in zip(s.pencil.angles, s.bars):
        d = np.array([np.cos(th), np.sin(th)])
        mid = (bar[0] + bar[3]) / 2, (bar[1] + bar[2]) / 2
        assert np.allclose(mid[0], v + r0 * d) and np.allclose(mid[1], v + r1 * d)
        assert s.ink_at(v + (r0 + r1) / 2 * d) and not s.ink_at(v + (r0 + r1) / 2 * d + 0.6 * d[::-1] * [-1, 1])
    assert s.ink_at([12.5, 12.5]) and not s.ink_at([37.5, 1.0]) and not s.ink_at(v)
    with pytest.raises(InputError, match="does not fit"):
        layout_sheet(board_from_dict({"type": "charuco", "squares": [9, 7], "square": 30.0, "marker": 22.0,
                                      "dictionary": "DICT_5X5_100"}))
    with pytest.raises(InputError, match="overlap"):
        layout_sheet(radius=(1.0, 50.0), width=2.0)
    assert sheet_raster(s, 20).shape == (165, 234)


# ------------------------------------------------------------------- the whole chain
@pytest.mark.parametrize("model", ["opencv", "fisheye"])
def test_charuco_detection_on_renders_matches_projection(model):
    """detect_board on a rendered board finds every corner where cam.project puts it
    (to the corner detector's own accuracy, ~0.05 px rms): validates the whole chain."""
    cam = small_camera(model)
    R, t = board_pose(35.0, 330.0 if model == "opencv" else 170.0)
    img = render_frame(cam, R, t, SHEET, background="plain", blur_px=0.8)
    det = detect_board(img, SHEET.board)
    assert det.count == SHEET.board.corner_count
    pred = cam.project(SHEET.board.object_points()[det.ids] @ R.T + t)
    err = np.linalg.norm(det.corners - pred, axis=1)
    assert np.sqrt(np.mean(err ** 2)) < 0.08
    assert err.max() < 0.2


def test_realistic_render_on_the_table_is_still_accurate():
    cam = small_camera("opencv")
    R, t = board_pose(25.0, 330.0)
    img = render_frame(cam, R, t, SHEET, background="table", blur_px=0.6, noise=2.0, lighting=0.3, gamma=2.2,
                       color=True, rng=5)
    assert img.shape == (480, 640, 3) and img.dtype == np.uint8
    det = detect_board(img, SHEET.board)
    assert det.count == SHEET.board.corner_count
    pred = cam.project(SHEET.board.object_points()[det.ids] @ R.T + t)
    assert np.sqrt(np.mean(np.sum((det.corners - pred) ** 2, 1))) < 0.15
    # the table is textured: plenty of features off the sheet
    gray = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    corners = cv2.goodFeaturesToTrack(gray, 500, 0.01, 5)
    assert corners is not None and len(corners) > 100


def test_determinism_with_a_seed():
    cam = small_camera("pinhole")
    R, t = board_pose(20.0, 330.0)
    kw = dict(blur_px=0.5, noise=3.0, lighting=0.3, gamma=2.2, background=Backdrop.around(SHEET, seed=2))
    a = render_frame(cam, R, t, SHEET, rng=7, **kw)
    b = render_frame(cam, R, t, SHEET, rng=np.random.default_rng(7), **kw)
    c = render_frame(cam, R, t, SHEET, rng=8, **kw)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_camera_behind_the_sheet_is_an_error():
    cam = small_camera("pinhole")
    R, t = board_pose(0.0, 330.0)
    flipped = rotation_about_axis([0, 1.0, 0], np.pi) @ R  # sees the back of the sheet
    with pytest.raises(InputError, match="behind the sheet"):
        render_frame(cam, flipped, t, SHEET)


# ------------------------------------------------------------------------ the shaft
def test_instrument_occludes_with_exact_converging_edges():
    cam = small_camera("pinhole")
    R, t = board_pose(30.0, 330.0)
    ins = Instrument.in_plane(SHEET.pencil.vertex, height=4.5, angle_deg=100.0, radius=2.5, tip=60.0, back=300.0)
    plain = render_frame(cam, R, t, SHEET, background="plain")
    with_shaft = render_frame(cam, R, t, SHEET, background="plain", instrument=ins)
    cov = np.clip(target_coverage(cam, R, t, []) + 0, 0, 1)  # nothing: sanity of the helper
    assert cov.max() == 0
    outline = ins._outline(R, t)
    from pencilcal.toolkit.synth.render import _render_coverage

    c_shaft = np.clip(_render_coverage(cam, [(outline, 1)]), 0, 1)
    # occlusion: the image changes only where the shaft is
    changed = with_shaft != plain
    assert changed.sum() > 500
    assert np.all(c_shaft[changed] > 0)
    # the silhouette: along each row the shaft's width equals the distance between the two
    # exact tangent lines (pinhole: straight lines m . (x, y, 1) = 0 in normalised coords)
    m = ins.silhouette_planes(R, t)
    K = cam.K
    lines_px = m @ np.linalg.inv(K)  # lines in pixel coordinates
    F, a = ins.axis_cam(R, t)
    tip_px, back_px = cam.project(F + 30.0 * a), cam.project(F - 80.0 * a)
    widths, truth = [], []
    for v in np.arange(int(min(tip_px[1], back_px[1])) + 2, int(max(tip_px[1], back_px[1])) - 2):
        xs = sorted(-(L[1] * v + L[2]) / L[0] for L in lines_px)
        widths.append(c_shaft[v].sum())
        truth.append(xs[1] - xs[0])
    assert len(widths) > 50
    assert np.max(np.abs(np.array(widths) - truth)) < 1e-6
    # perspective: the silhouette edges are not parallel, they meet at the axis' vanishing point
    vp = np.cross(lines_px[0], lines_px[1])
    vanish = cam.K @ a
    assert np.allclose(vp[:2] / vp[2], vanish[:2] / vanish[2], rtol=1e-6)
    # the shaft looks metallic: a bright stripe and darker flanks
    vals = with_shaft[c_shaft > 0.999].astype(float)
    assert vals.max() - vals.min() > 60

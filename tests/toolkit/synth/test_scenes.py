"""Scenarios: exact, self-consistent truth for orbit, pivot and tilt-sweep."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.board.detect import detect_board
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.frames import angle_between
from pencilcal.toolkit.pencil.spec import project_spokes
from pencilcal.toolkit.synth.scenarios import default_camera, look_at, make_scenario

SIZE = (640, 360)


def check_common(sc):
    """Truth every scenario writes must agree with the camera and the pose."""
    cam, pen = sc.camera, sc.sheet.pencil
    for f in sc.frames:
        R, t = f["R_cam_from_target"], f["t_cam_from_target"]
        assert np.allclose(R.T @ R, np.eye(3), atol=1e-12) and np.linalg.det(R) == pytest.approx(1.0)
        assert np.array_equal(f["normal"], R[:, 2])
        assert np.allclose(f["camera_center"], -R.T @ t)
        assert f["camera_center"][2] < 0  # the camera sees the printed face
        assert np.dot(f["normal"], f["vertex_cam"]) > 0  # the normal points away from the camera
        assert np.allclose(f["spokes_px"], project_spokes(cam, R, t, pen))


def inside(cam, px, margin=0.0):
    px = np.asarray(px).reshape(-1, 2)
    return bool(np.all((px >= margin) & (px <= [cam.width - 1 - margin, cam.height - 1 - margin])))


def test_orbit_is_a_smooth_overlapping_path_around_the_sheet():
    sc = make_scenario("orbit", frames=24, seed=4, size=SIZE)
    check_common(sc)
    cam, sheet = sc.camera, sc.sheet
    centre = sheet.content_center
    C = np.array([f["camera_center"] for f in sc.frames])
    dist = np.linalg.norm(C - centre, axis=1)
    assert np.all((dist > 300) & (dist < 520))
    # 30+ deg of viewpoint change over the sequence
    dirs = (C - centre) / dist[:, None]
    assert np.degrees(np.arccos(np.clip(dirs[0] @ dirs[-1], -1, 1))) > 30
    # smooth: consecutive steps are small and even
    steps = np.linalg.norm(np.diff(C, axis=0), axis=1)
    assert steps.max() < 3.0 * np.median(steps) and steps.max() < 60
    for f in sc.frames:
        R = f["R_cam_from_target"]
        # the printed area is in view: the whole board and every spoke
        assert f["board_corners_in_view"] == sheet.board.corner_count
        assert inside(cam, f["spokes_px"], 10)
        assert f["vertex_px"] == pytest.approx(cam.project(f["vertex_cam"]))
        assert f["tilt_deg"] == pytest.approx(np.degrees(angle_between(R[:, 2], f["vertex_cam"])))
        # the optical axis points at the printed area
        assert angle_between(R[2], centre - f["camera_center"]) < np.radians(5)
    # boxes stand on the table, clear of the paper
    px0, py0 = sheet.paper_origin
    pw, ph = sheet.paper_size
    assert len(sc.backdrop.boxes) >= 3
    for x0, y0, x1, y1, h in sc.backdrop.boxes:
        assert x1 < px0 - 50 or x0 > px0 + pw + 50 or y1 < py0 - 50 or y0 > py0 + ph + 50


def test_tilt_sweep_turns_about_the_vertex():
    sc = make_scenario("tilt-sweep", frames=9, seed=0, size=SIZE)
    check_common(sc)
    cam = sc.camera
    tilts = [f["tilt_deg"] for f in sc.frames]
    assert tilts == pytest.approx(np.linspace(0, 80, 9))
    for f in sc.frames:
        # tilt_deg is the angle between the normal and the vertex's viewing ray
        assert np.degrees(angle_between(f["normal"], f["vertex_cam"])) == pytest.approx(f["tilt_deg"], abs=1e-9)
        # the vertex stays on the optical axis (the principal point) and the fan stays in view
        assert f["vertex_px"] == pytest.approx(cam.K[:2, 2], abs=1e-9)
        assert inside(cam, f["spokes_px"], 5)
    # the tilt axis (target x for axis_deg = 0) is the same line in the camera in every frame
    axes = np.array([f["R_cam_from_target"][:, 0] for f in sc.frames])
    assert np.allclose(axes, axes[0], atol=1e-12)
    # another axis and an off-axis vertex
    sc2 = make_scenario("tilt-sweep", frames=3, seed=0, size=SIZE, axis_deg=90.0, vertex_px=(400.0, 150.0))
    a = np.array([f["R_cam_from_target"][:, 1] for f in sc2.frames])
    assert np.allclose(a, a[0], atol=1e-12)
    assert sc2.frames[2]["vertex_px"] == pytest.approx([400.0, 150.0], abs=1e-9)
    assert sc2.frames[2]["tilt_deg"] == pytest.approx(80.0)
    assert np.degrees(angle_between(sc2.frames[2]["normal"], sc2.frames[2]["vertex_cam"])) == pytest.approx(80.0)


@pytest.mark.parametrize("model", ["opencv", "pinhole"])
def test_pivot_shaft_lines_pass_through_the_fulcrum(model):
    sc = make_scenario("pivot", frames=7, seed=2, size=SIZE, model=model)
    check_common(sc)
    cam = sc.camera
    piv = sc.extra["pivot"]
    R0 = sc.frames[0]["R_cam_from_target"]
    assert [f["angle_deg"] for f in sc.frames] == pytest.approx(np.linspace(50, 130, 7))
    csv = sc.angles_csv().splitlines()
    assert csv[0] == "image,angle_deg" and csv[1] == "000.png,50.0" and len(csv) == 8
    for f, ins in zip(sc.frames, sc.instruments):
        R, t = f["R_cam_from_target"], f["t_cam_from_target"]
        assert np.array_equal(R, R0)  # fixed camera
        F = f["fulcrum_cam"]
        assert np.allclose(F, R @ piv["fulcrum_target"] + t)
        assert f["vertex_px"] == pytest.approx(cam.project(F))
        assert inside(cam, f["vertex_px"], 20) and inside(cam, f["tip_px"], 5)
        assert f["tilt_deg"] == pytest.approx(np.degrees(angle_between(R[:, 2], F)))
        # the shaft lies in the pivot plane, parallel to the sheet, at the stated angle
        d = f["shaft_direction_cam"]
        assert abs(d @ R[:, 2]) < 1e-12
        th = np.radians(f["angle_deg"])
        assert np.allclose(R.T @ d, [np.cos(th), np.sin(th), 0], atol=1e-12)
        # every point of the axis images onto one line through the fulcrum's image (in
        # undistorted normalised coordinates the line is straight)
        pts = cam.project(F + np.linspace(-80, 60, 8)[:, None] * d)
        xy = cam.normalized_from_pixels(np.vstack([f["vertex_px"], pts]))
        h = np.c_[xy, np.ones(len(xy))]
        assert np.linalg.svd(h, compute_uv=False)[-1] < 1e-9
        # the silhouette planes are tangent to the shaft: at distance radius from its axis
        for m in ins.silhouette_planes(R, t):
            assert abs(m @ F) == pytest.approx(ins.radius, rel=1e-12)
            assert abs(m @ d) < 1e-12
        # the two silhouette edges (normalised image lines) meet at the axis' vanishing point
        L = f["shaft_edges_normalized"]
        assert np.allclose(np.linalg.norm(L[:, :2], axis=1), 1.0)
        assert np.allclose(L @ (d / d[2]), 0.0, atol=1e-9)
    # the pivot plane's orientation is the sheet's
    assert np.allclose(piv["normal"], R0[:, 2]) and np.allclose(piv["R_cam_from_pivot"], R0)


def test_frames_render_deterministically_in_any_order():
    sc = make_scenario("pivot", frames=3, seed=9, size=(320, 240))
    a = sc.render(1)
    sc.render(0)
    b = sc.render(1)
    assert a.shape == (240, 320) and np.array_equal(a, b)
    other = make_scenario("pivot", frames=3, seed=10, size=(320, 240)).render(1)
    assert not np.array_equal(a, other)
    assert sc.render(1, color=True).shape == (240, 320, 3)


def test_orbit_frame_renders_realistically_and_detects():
    sc = make_scenario("orbit", frames=5, seed=1, size=(800, 450))
    f = sc.frames[3]
    img = sc.render(3)  # noise, blur, uneven light, gamma 2.2, textured table and boxes
    det = detect_board(img, sc.sheet.board)
    assert det.count >= sc.sheet.board.corner_count - 2
    pred = sc.camera.project(sc.sheet.board.object_points()[det.ids] @ f["R_cam_from_target"].T
                             + f["t_cam_from_target"])
    err = np.linalg.norm(det.corners - pred, axis=1)
    assert np.median(err) < 0.15 and err.max() < 0.5


def test_truth_is_json_ready():
    import json

    sc = make_scenario("pivot", frames=2, seed=0, size=SIZE)
    tr = json.loads(json.dumps(sc.truth(render={"noise": 2.0})))
    assert tr["scenario"] == "pivot" and tr["frames_count"] == 2
    f = tr["frames"][0]
    for key in ("image", "R_cam_from_target", "t_cam_from_target", "normal", "vertex_px", "tilt_deg", "angle_deg"):
        assert key in f
    assert np.asarray(f["R_cam_from_target"]).shape == (3, 3)
    assert tr["camera"]["model"] == "opencv" and tr["pencil"]["vertex"] == [179.0, 62.5]
    assert "pivot" in tr and len(tr["pivot"]["fulcrum_target"]) == 3


def test_bad_requests_are_input_errors():
    with pytest.raises(InputError, match="unknown scenario"):
        make_scenario("spin", frames=3)
    with pytest.raises(InputError, match="unknown option"):
        make_scenario("orbit", frames=3, axis_deg=10)
    with pytest.raises(InputError, match="positive integer"):
        make_scenario("orbit", frames=0)
    with pytest.raises(InputError, match="camera model"):
        default_camera("equirect")


def test_fisheye_and_custom_cameras():
    sc = make_scenario("orbit", frames=3, seed=0, size=SIZE, model="fisheye")
    check_common(sc)
    assert sc.camera.model == "fisheye"
    # the fisheye sees wider: the path moves in to keep the sheet's size in the image
    d = np.linalg.norm(sc.frames[1]["camera_center"] - sc.sheet.content_center)
    assert 150 < d < 300
    assert all(f["board_corners_in_view"] == 24 for f in sc.frames)
    R, t = look_at([0.0, 0.0, -100.0], [0.0, 0.0, 0.0])
    assert np.allclose(R, np.eye(3)) and np.allclose(t, [0, 0, 100])


def test_handheld_moves_at_the_speeds_asked_and_twice_as_fast_along_the_same_path():
    cam = default_camera("opencv", (1920, 1080))
    slow = make_scenario("handheld", frames=121, seed=2, camera=cam, distance=250.0)
    check_common(slow)
    v = np.array([f["vertex_px"] for f in slow.frames])
    roll = np.array([f["roll_deg"] for f in slow.frames])
    tilt = np.array([f["tilt_deg"] for f in slow.frames])
    # the fan's centre up to 8 px a frame, its in-plane angle 3 deg, its tilt ~1 deg
    assert np.linalg.norm(np.diff(v, axis=0), axis=1).max() == pytest.approx(8.0, rel=0.02)
    assert np.abs(np.diff(roll)).max() == pytest.approx(3.0, rel=0.02)
    assert 0.7 < np.abs(np.diff(tilt)).max() < 1.5 and 15 < tilt.min() and tilt.max() < 55
    for f in slow.frames:
        assert inside(cam, f["spokes_px"], 5)
    # speed 2: every other frame of the same path
    fast = make_scenario("handheld", frames=61, seed=2, camera=cam, distance=250.0, speed=2.0)
    assert np.allclose([f["vertex_px"] for f in fast.frames], v[::2], atol=1e-6)
    assert np.allclose([f["R_cam_from_target"] for f in fast.frames], [f["R_cam_from_target"] for f in slow.frames[::2]])

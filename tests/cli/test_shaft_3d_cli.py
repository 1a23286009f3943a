"""`lines --shaft --shaft-diameter`, `fulcrum --shaft-diameter`, `simulate --shaft-diameter`:
the 3-D axis and the 3-D fulcrum as a user gets them."""
from __future__ import annotations

import json

import cv2
import numpy as np
from click.testing import CliRunner

from pencilcal.cli.main import cli
from pencilcal.toolkit.camera.formats import write_camera
from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.geometry.frames import angle_between, normalize
from tests.toolkit.detect.shaft.test_detector import render_shaft, shaft_from
from tests.toolkit.pencil.test_cylinder import FULCRUM, HEIGHT, K, RADIUS, WIDTH, pivot_frames


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_lines_shaft_diameter_gives_the_3d_axis(tmp_path):
    cam = Camera("opencv", 640, 480, [[420.0, 0, 319.5], [0, 420.0, 239.5], [0, 0, 1]], [-0.25, 0.07, 0, 0, 0])
    write_camera(tmp_path / "camera.yaml", cam)
    truth = shaft_from([-30.0, 14.0, 22.0], [2.0, -4.0, 85.0])
    (tmp_path / "v").mkdir()
    cv2.imwrite(str(tmp_path / "v" / "a.png"), render_shaft(cam, [truth], np.random.default_rng(1)))
    r = invoke("lines", tmp_path / "v", "--camera", tmp_path / "camera.yaml", "--shaft", "--shaft-diameter", 8,
               "-o", tmp_path / "l.json", "-q")
    assert r.exit_code == 0, r.output
    sh = json.loads((tmp_path / "l.json").read_text())["frames"][0]["shafts"][0]
    d = normalize(truth["a"])
    d = d * np.sign(d[2])
    A = truth["A"] - (truth["A"] @ d) * d                               # the true axis point closest to C
    assert np.asarray(sh["edge_cov"]).shape == (2, 2, 2) and np.asarray(sh["axis_cov"]).shape == (4, 4)
    err_deg = float(np.degrees(angle_between(np.asarray(sh["axis_direction"]), d)))
    assert err_deg < 3.0 * sh["axis_direction_sigma_deg"], (err_deg, sh["axis_direction_sigma_deg"])
    assert abs(sh["axis_distance"] - np.linalg.norm(A)) < 3.0 * sh["axis_distance_sigma"]
    assert np.isclose(np.linalg.norm(sh["axis_point"]), sh["axis_distance"])
    # the diameter needs --shaft, and must be positive
    r = invoke("lines", tmp_path / "v", "--camera", tmp_path / "camera.yaml", "--shaft-diameter", 8, "-o",
               tmp_path / "m.json")
    assert r.exit_code == 2 and "--shaft" in r.output


def test_fulcrum_shaft_diameter_point_and_outlier(tmp_path):
    cam = Camera("pinhole", WIDTH, HEIGHT, K, [])
    write_camera(tmp_path / "cam.json", cam)
    segs, _ = pivot_frames(n=16)
    segs[5] = segs[5] + np.array([0.0, 50.0, 0.0, 50.0])               # a frame whose shaft misses the port
    cov = np.diag([1e-7, 0.02])
    frames = []
    for k, s in enumerate(segs):
        mid = (0.5 * (s[0] + s[1])).tolist()
        frames.append({"image": f"{k:03d}.png", "ok": True, "segments": [],
                       "shafts": [{"midline": mid, "angle_sigma_deg": 0.05, "offset_sigma_px": 0.2,
                                   "edges": s.tolist(), "edge_cov": [cov.tolist()] * 2}]})
    (tmp_path / "lines.json").write_text(json.dumps({"frames": frames}))
    r = invoke("fulcrum", "--lines", tmp_path / "lines.json", "--camera", tmp_path / "cam.json",
               "--shaft-diameter", 2 * RADIUS, "-o", tmp_path / "f.json")
    assert r.exit_code == 0, r.output
    out = json.loads((tmp_path / "f.json").read_text())
    assert np.linalg.norm(np.asarray(out["point"]) - FULCRUM) < 3 * out["point_sigma"] + 1e-6
    assert np.asarray(out["point_cov"]).shape == (3, 3) and out["point_sigma"] > 0
    assert [o["image"] for o in out["point_outliers"]] == ["005.png"]
    assert "3-D fulcrum" in r.output and "005.png" in r.output
    # a lines file without the edges' covariance: one line, exit 1
    for f in frames:
        del f["shafts"][0]["edge_cov"]
    (tmp_path / "old.json").write_text(json.dumps({"frames": frames}))
    r = invoke("fulcrum", "--lines", tmp_path / "old.json", "--camera", tmp_path / "cam.json",
               "--shaft-diameter", 8, "-o", tmp_path / "g.json", "-q")
    assert r.exit_code == 1 and "edge_cov" in r.output and len(r.output.strip().splitlines()) == 1


def test_simulate_pivot_truth_has_the_3d_axes(tmp_path):
    out = tmp_path / "p"
    r = invoke("simulate", out, "--scenario", "pivot", "--frames", 2, "--size", "320x180", "--shaft-diameter", 6,
               "--noise", 0, "-q")
    assert r.exit_code == 0, r.output
    t = json.loads((out / "truth.json").read_text())
    assert t["options"]["shaft_radius"] == 3.0
    F = np.asarray(t["pivot"]["fulcrum_cam"])
    for fr in t["frames"]:
        A, d = np.asarray(fr["axis_point_cam"]), np.asarray(fr["axis_direction_cam"])
        assert abs(A @ d) < 1e-9 and d[2] >= 0                            # the closest point, away from C
        assert np.linalg.norm(np.cross(F - A, d)) < 1e-9                   # the axis passes the fulcrum


def test_a_shaft_whose_edges_carry_no_covariance_says_why_it_has_no_3d_axis():
    """`lines --shaft-diameter` on a shaft record with edges but no edge_cov (as the 3-D
    fulcrum skips it): axis_error says so, no KeyError."""
    from pencilcal.cli.lines import with_axis

    cam = Camera("opencv", 640, 480, [[420.0, 0, 319.5], [0, 420.0, 239.5], [0, 0, 1]], [0, 0, 0, 0, 0])
    rec = with_axis(cam, {"edges": [[10.0, 10.0, 300.0, 200.0], [40.0, 10.0, 330.0, 200.0]]}, 8.0)
    assert rec["axis_error"] == "silhouette edges without their covariance" and "axis_point" not in rec

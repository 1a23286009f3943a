"""`pencilcal fulcrum --right IMAGES --camera-right CAM --right-from-left FILE`: the stereo
fulcrum from two rendered views of one pivot sequence (simulate's pivot scenario in its
port view, the second camera 10 mm to the right, turned 3 deg towards the first; OpenCV's
FileStorage R and T as cv2.stereoCalibrate writes them)."""
from __future__ import annotations

import dataclasses
import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.cli.main import cli
from pencilcal.toolkit.camera.formats import write_camera
from pencilcal.toolkit.geometry.frames import rotation_about_axis
from pencilcal.toolkit.synth.scenarios import default_camera, make_scenario

R_RL = rotation_about_axis([0.0, 1.0, 0.0], np.radians(-3.0))
T_RL = np.array([-10.0, 0.0, 0.0])


def stereo_pivot(out, frames=10, seed=0):
    """Two views of one pivot sequence written under `out` (left/, right/, left.json,
    right.json, extrinsics.yml); returns the left view's scenario (its truth)."""
    cam = default_camera("pinhole", (960, 540))
    sc = make_scenario("pivot", frames, seed, camera=cam, shaft_radius=4.0, port_view=100.0, height=150.0, tip=90.0,
                       fulcrum=(700.0, 600.0))
    right = dataclasses.replace(sc, frames=[{**f, "R_cam_from_target": R_RL @ f["R_cam_from_target"],
                                             "t_cam_from_target": R_RL @ f["t_cam_from_target"] + T_RL}
                                            for f in sc.frames])
    for name, view in (("left", sc), ("right", right)):
        (out / name).mkdir(parents=True)
        write_camera(out / f"{name}.json", cam)
        for i, f in enumerate(view.frames):
            img = view.render(i, noise=4.0, blur_px=1.2, background=0.8, gamma=1.0)
            cv2.imwrite(str(out / name / f["image"]), img)
    fs = cv2.FileStorage(str(out / "extrinsics.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("R", R_RL)
    fs.write("T", T_RL.reshape(3, 1))
    fs.release()
    return sc


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.mark.slow
def test_fulcrum_stereo_cli(tmp_path):
    sc = stereo_pivot(tmp_path)
    F = sc.extra["pivot"]["fulcrum_cam"]
    base = ["fulcrum", tmp_path / "left", "--camera", tmp_path / "left.json", "--right", tmp_path / "right",
            "--camera-right", tmp_path / "right.json", "--right-from-left", tmp_path / "extrinsics.yml"]
    r = invoke(*base, "--shaft-diameter", 8, "-o", tmp_path / "f.json")
    assert r.exit_code == 0, r.output
    out = json.loads((tmp_path / "f.json").read_text())
    st = out["stereo"]
    tri = st["triangulated"]
    err = np.asarray(tri["point"]) - F
    assert err @ np.linalg.solve(np.asarray(tri["point_cov"]), err) < 16.0, (err, tri["point_sigma"])
    assert st["right"]["frames_used"] >= 8 and np.allclose(st["R_right_from_left"], R_RL)
    a = st["agreement"]
    assert set(a) >= {"chi2", "dof", "p_value", "consistent"} and 1 <= a["dof"] <= 3
    assert st["combined"]["point_sigma"] <= min(out["point_sigma"], tri["point_sigma"]) + 1e-9
    assert "stereo fulcrum" in r.output and "chi2" in r.output
    # the axes triangulated from both views' silhouettes: as sure as the diameter's point, or surer
    ax = st["axes"]
    err = np.asarray(ax["point"]) - F
    assert ax["axes_used"] >= 8 and abs(ax["radius"] - 4.0) < 0.05 and not ax["rig_used"]
    assert err @ np.linalg.solve(np.asarray(ax["point_cov"]), err) < 16.0, (err, ax["point_sigma"])
    assert ax["point_sigma"] <= out["point_sigma"] and "stereo axes fulcrum" in r.output
    # triangulation alone, without the diameter
    r = invoke(*base, "-o", tmp_path / "g.json", "-q")
    assert r.exit_code == 0, r.output
    st = json.loads((tmp_path / "g.json").read_text())["stereo"]
    assert "agreement" not in st and np.allclose(st["triangulated"]["point"], tri["point"])


def test_fulcrum_stereo_options_go_together_and_bad_files(tmp_path):
    (tmp_path / "l.json").write_text(json.dumps({"frames": [{"image": "a.png", "segments": [[0, 0, 1, 1]]}]}))
    write_camera(tmp_path / "c.json", default_camera("pinhole", (320, 240)))
    r = invoke("fulcrum", "--lines", tmp_path / "l.json", "--camera", tmp_path / "c.json", "--right", tmp_path,
               "-o", tmp_path / "f.json")
    assert r.exit_code == 2 and "go together" in r.output
    (tmp_path / "s.yml").write_text("R: [0, 0, 0]\n")
    r = invoke("fulcrum", "--lines", tmp_path / "l.json", "--camera", tmp_path / "c.json", "--right", tmp_path,
               "--camera-right", tmp_path / "c.json", "--right-from-left", tmp_path / "s.yml", "-o",
               tmp_path / "f.json")
    assert r.exit_code == 1 and "s.yml" in r.output and "no T" in r.output
    assert len(r.output.strip().splitlines()) == 1


def test_fulcrum_stereo_from_lines_files_with_the_intrinsics(tmp_path):
    """--right as a lines file (what `pencilcal lines --shaft` writes), both camera files with
    the intrinsics' covariance: the triangulated point gains point_cov_total (noise and the
    intrinsics' term), the right record names its lines file; the exact lines of
    test_stereo_fulcrum's two views (pinhole, 20 mm baseline, the port 100 mm away)."""
    from pencilcal.toolkit.camera.intrinsics import intrinsic_names
    from pencilcal.toolkit.camera.model import Camera
    from pencilcal.toolkit.io.lines_file import write_lines
    from tests.toolkit.pencil.test_stereo_fulcrum import CAM, FULCRUM, R_RL as R2, T_RL as T2, _lens_cov, _views

    left, right = _views()
    meta = {"cov_intrinsics": {"names": intrinsic_names(CAM), "cov": _lens_cov().tolist()}}
    for name, view in (("left", left), ("right", right)):
        write_lines(tmp_path / f"{name}.json", view.frames())
        write_camera(tmp_path / f"{name}-cam.json", Camera(CAM.model, CAM.width, CAM.height, CAM.K, CAM.dist,
                                                           meta=meta))
    write_camera(tmp_path / "plain.json", CAM)
    (tmp_path / "rig.json").write_text(json.dumps({"R_right_from_left": R2.tolist(), "t_right_from_left": T2.tolist()}))
    base = ["fulcrum", "--lines", tmp_path / "left.json", "--camera", tmp_path / "left-cam.json", "--right",
            tmp_path / "right.json", "--right-from-left", tmp_path / "rig.json", "--shaft-diameter", 8]
    r = invoke(*base, "--camera-right", tmp_path / "right-cam.json", "-o", tmp_path / "f.json")
    assert r.exit_code == 0, r.output
    out = json.loads((tmp_path / "f.json").read_text())
    st, tri = out["stereo"], out["stereo"]["triangulated"]
    assert st["right"]["lines"] == str(tmp_path / "right.json") and "images" not in st["right"]
    assert np.allclose(tri["point"], FULCRUM, atol=1e-3)
    assert tri["intrinsics_views"] == ["left", "right"] and tri["point_sigma_total"] > 5 * tri["point_sigma"]
    total, noise = np.asarray(tri["point_cov_total"]), np.asarray(tri["point_cov"])
    assert np.all(np.linalg.eigvalsh(total - noise) > -1e-12) and np.trace(total) == pytest.approx(
        tri["point_sigma_total"] ** 2)
    assert out["intrinsics_used"] and np.asarray(out["ray_cov_total"]).shape == (3, 3)
    # the diameter-based point has its intrinsics' term too
    p_total, p_noise = np.asarray(out["point_cov_total"]), np.asarray(out["point_cov"])
    assert np.all(np.linalg.eigvalsh(p_total - p_noise) > -1e-12) and out["point_sigma_total"] > out["point_sigma"]
    assert st["right"]["intrinsics_used"] and "with the intrinsics of the left and right camera" in r.output
    # the right camera without a covariance: the left's term alone, the noise-only part the same
    r = invoke(*base, "--camera-right", tmp_path / "plain.json", "-o", tmp_path / "g.json", "-q")
    assert r.exit_code == 0, r.output
    tri2 = json.loads((tmp_path / "g.json").read_text())["stereo"]["triangulated"]
    assert tri2["intrinsics_views"] == ["left"] and tri2["point_sigma_total"] < tri["point_sigma_total"]
    assert np.allclose(tri2["point_cov"], noise, rtol=1e-6)
    # a right lines file that is not one: one line naming it
    (tmp_path / "bad.json").write_text('{"frames": 3}')
    r = invoke(*base[:5], "--right", tmp_path / "bad.json", "--camera-right", tmp_path / "plain.json",
               "--right-from-left", tmp_path / "rig.json", "-o", tmp_path / "h.json")
    assert r.exit_code == 1 and "bad.json" in r.output and len(r.output.strip().splitlines()) == 1, r.output


@pytest.mark.slow
def test_fulcrum_stereo_pairs_frames_by_name(tmp_path):
    """The right view's frames pair with the left's by their names, whatever their order
    (the same stereo record as in order); names that pair some frames but not all (a frame
    dropped in one eye, which in order would pair every later frame wrongly) are a one-line
    error naming the right view and the frame (the exact lines of test_stereo_fulcrum)."""
    from pencilcal.toolkit.io.lines_file import write_lines
    from tests.toolkit.pencil.test_stereo_fulcrum import CAM, R_RL as R2, T_RL as T2, _views

    left, right = _views()
    rf = right.frames(np.random.default_rng(1))
    write_lines(tmp_path / "left.json", left.frames(np.random.default_rng(0)))
    write_lines(tmp_path / "right.json", rf)
    write_lines(tmp_path / "shuffled.json", rf[::-1])
    write_lines(tmp_path / "dropped.json", [f for k, f in enumerate(rf) if k != 3])
    write_camera(tmp_path / "cam.json", CAM)
    (tmp_path / "rig.json").write_text(json.dumps({"R_right_from_left": R2.tolist(), "t_right_from_left": T2.tolist()}))
    base = ["fulcrum", "--lines", tmp_path / "left.json", "--camera", tmp_path / "cam.json", "--camera-right",
            tmp_path / "cam.json", "--right-from-left", tmp_path / "rig.json", "-q"]
    st = {}
    for name in ("right", "shuffled"):
        r = invoke(*base, "--right", tmp_path / f"{name}.json", "-o", tmp_path / f"{name}-f.json")
        assert r.exit_code == 0, r.output
        st[name] = json.loads((tmp_path / f"{name}-f.json").read_text())["stereo"]["triangulated"]
    assert st["right"]["paired_lines"] == st["shuffled"]["paired_lines"] >= 5
    assert np.allclose(st["right"]["point_cov"], st["shuffled"]["point_cov"], rtol=1e-6)
    r = invoke(*base, "--right", tmp_path / "dropped.json", "-o", tmp_path / "dropped-f.json")
    assert r.exit_code == 1 and len(r.output.strip().splitlines()) == 1, r.output
    assert "dropped.json" in r.output and "003.png" in r.output and "do not pair" in r.output

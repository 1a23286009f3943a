"""`pencilcal fulcrum --kinematics`: the hand-eye and the remote centre of motion as a user
gets them, on rendered frames with exact truth and on a lines file; every fault one line."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.cli.main import cli
from pencilcal.toolkit.camera.formats import write_camera
from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.geometry.frames import rotation_from_rotvec, rotvec_from_rotation
from tests.toolkit.pencil.test_cylinder import FULCRUM, HEIGHT, K, RADIUS, WIDTH, pivot_frames

R_TRUE = rotation_from_rotvec([0.4, -1.2, 2.0])        # R_cam_from_base
T_TRUE = np.array([30.0, -80.0, 150.0])                # t_cam_from_base [mm]
MATRIX = ",".join(f"r{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3))


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def tool_rotation(d_base):
    """An R_base_from_tool whose z axis is d_base (the roll about it arbitrary)."""
    x = np.cross([0.3, 0.5, 0.8], d_base)
    x = x / np.linalg.norm(x)
    return np.stack([x, np.cross(d_base, x), d_base], 1)


def quaternion(R):
    """(w, x, y, z) of a rotation (w > 0 branch; fine away from half turns)."""
    w = 0.5 * np.sqrt(1.0 + np.trace(R))
    return np.array([w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w)])


def kinematics_rows(names, fulcrum_cam, dirs_cam, tip, metres=False):
    """CSV rows of the tool poses: origin at the tip, z along the shaft, in the base frame."""
    head = "image,x_m,y_m,z_m,qw,qx,qy,qz" if metres else f"image,x_mm,y_mm,z_mm,{MATRIX}"
    rows = [head]
    for name, F, d in zip(names, fulcrum_cam, dirs_cam):
        origin = R_TRUE.T @ (np.asarray(F) + tip * np.asarray(d) - T_TRUE)
        Rt = tool_rotation(R_TRUE.T @ np.asarray(d))
        vals = [*(origin / 1000.0), *quaternion(Rt)] if metres else [*origin, *Rt.ravel()]
        rows.append(",".join([name] + [f"{v:.12f}" for v in vals]))
    return "\n".join(rows) + "\n"


def errors(rec):
    """(6,) the true transform against the estimate and its squared Mahalanobis distance."""
    e = np.r_[rotvec_from_rotation(R_TRUE @ np.asarray(rec["R_cam_from_base"]).T), T_TRUE - rec["t_cam_from_base_mm"]]
    return e, float(e @ np.linalg.solve(np.asarray(rec["cov_cam_from_base"]), e))


@pytest.mark.slow
def test_rendered_port_view_pivot_gives_the_hand_eye(tmp_path):
    """Rendered frames (simulate's pivot in its port view: 8 mm shaft 60-150 mm away, the
    port off the image, noise and blur) with exact tool poses in metres and quaternions: the
    transform within 3 sigma (measured: 0.23 mm, 0.003 deg; sigmas 2 mm, 0.35 deg), the
    remote centre in base exact, the mirror solution of the planar fan decided by the side
    of the tip, and the carried-over centre agreeing with the camera's fulcrum."""
    from pencilcal.toolkit.synth.scenarios import default_camera, make_scenario

    cam = default_camera("pinhole", (960, 540))
    sc = make_scenario("pivot", 12, 0, camera=cam, shaft_radius=4.0, port_view=100.0, height=150.0, tip=90.0,
                       fulcrum=(700.0, 600.0))
    write_camera(tmp_path / "camera.json", cam)
    (tmp_path / "images").mkdir()
    for i, fr in enumerate(sc.frames):
        cv2.imwrite(str(tmp_path / "images" / fr["image"]), sc.render(i, noise=5.0, blur_px=1.5, background=0.8))
    (tmp_path / "kin.csv").write_text(kinematics_rows([f["image"] for f in sc.frames],
                                                      [f["fulcrum_cam"] for f in sc.frames],
                                                      [f["shaft_direction_cam"] for f in sc.frames], 90.0, metres=True))
    r = invoke("fulcrum", tmp_path / "images", "--camera", tmp_path / "camera.json", "--shaft-diameter", 8,
               "--kinematics", tmp_path / "kin.csv", "-o", tmp_path / "f.json")
    assert r.exit_code == 0, r.output
    rob = json.loads((tmp_path / "f.json").read_text())["robot"]
    e, m2 = errors(rob)
    assert m2 < chi2_3sigma(6) and np.linalg.norm(e[3:]) < 1.0, (e, rob["translation_sigma_mm"])
    truth_base = R_TRUE.T @ (np.asarray(sc.extra["pivot"]["fulcrum_cam"]) - T_TRUE)
    assert np.allclose(rob["fulcrum_base_mm"], truth_base, atol=1e-4) and rob["fulcrum_base_cov_from"] == "scatter"
    assert rob["twin_by"] == "sides" and rob["twin_vote"] == 1.0 and rob["frames_used"] == 12
    assert rob["agreement"]["consistent"] and np.asarray(rob["cov_base_from_cam"]).shape == (6, 6)
    assert "robot: remote centre" in r.output


def chi2_3sigma(dof):
    from scipy.stats import chi2

    return chi2.ppf(0.9973, dof)


def _lines(tmp_path, n=16, seed=3):
    """A lines.json of a cone pivot (test_cylinder.pivot_frames, 1080p pinhole) with 0.1 px
    end-point noise and its edge covariance, the camera file, and the true directions."""
    cam = Camera("pinhole", WIDTH, HEIGHT, K, [])
    write_camera(tmp_path / "cam.json", cam)
    segs, D = pivot_frames(n=n, seed=seed)
    rng = np.random.default_rng(seed)
    frames = []
    for k, s in enumerate(segs):
        length = np.linalg.norm(s[:, 2:] - s[:, :2], axis=-1)
        cov = [np.diag([2 * 0.1**2 / L**2, 0.1**2 / 2]).tolist() for L in length]
        noisy = s + rng.normal(scale=0.1, size=s.shape)
        frames.append({"image": f"{k:03d}.png", "ok": True, "segments": [],
                       "shafts": [{"midline": (0.5 * (noisy[0] + noisy[1])).tolist(), "angle_sigma_deg": 0.05,
                                   "offset_sigma_px": 0.2, "edges": noisy.tolist(), "edge_cov": cov}]})
    (tmp_path / "lines.json").write_text(json.dumps({"frames": frames}))
    return [f["image"] for f in frames], D


def test_lines_file_cone_pivot_with_a_frame_index_file(tmp_path):
    names, D = _lines(tmp_path)
    text = kinematics_rows(names, [FULCRUM] * len(names), D, 95.0).replace("image,", "frame,", 1)
    text = "\n".join([text.splitlines()[0]] + [f"{k}," + row.split(",", 1)[1]
                                               for k, row in enumerate(text.splitlines()[1:])]) + "\n"
    (tmp_path / "kin.csv").write_text(text)
    r = invoke("fulcrum", "--lines", tmp_path / "lines.json", "--camera", tmp_path / "cam.json", "--shaft-diameter",
               2 * RADIUS, "--kinematics", tmp_path / "kin.csv", "-o", tmp_path / "f.json", "-q")
    assert r.exit_code == 0, r.output
    rob = json.loads((tmp_path / "f.json").read_text())["robot"]
    e, m2 = errors(rob)
    assert m2 < chi2_3sigma(6), (e, m2)
    assert rob["twin_by"] == "fit" and rob["frames_paired"] == 16 and len(rob["residuals"]) == 16
    assert rob["agreement"]["consistent"]
    # the kinematics' own sigmas: the remote centre weighted by them, and the transform wider
    lines = text.splitlines()
    (tmp_path / "kin2.csv").write_text("\n".join([lines[0] + ",sigma_deg,sigma_mm"]
                                                 + [ln + ",0.1,0.3" for ln in lines[1:]]) + "\n")
    r = invoke("fulcrum", "--lines", tmp_path / "lines.json", "--camera", tmp_path / "cam.json", "--shaft-diameter",
               2 * RADIUS, "--kinematics", tmp_path / "kin2.csv", "-o", tmp_path / "g.json", "-q")
    assert r.exit_code == 0, r.output
    noisy = json.loads((tmp_path / "g.json").read_text())["robot"]
    assert noisy["fulcrum_base_cov_from"] == "sigmas" and noisy["fulcrum_base_sigma_mm"] > 0.1
    assert noisy["translation_sigma_mm"] > rob["translation_sigma_mm"]
    assert errors(noisy)[1] < chi2_3sigma(6)


@pytest.mark.parametrize("rows, message", [
    (2, "needs 3 frames at least"),
    (0, "no frame has a tool pose"),
])
def test_too_few_poses_is_one_line(tmp_path, rows, message):
    names, D = _lines(tmp_path)
    text = kinematics_rows(names, [FULCRUM] * len(names), D, 95.0)
    lines = text.splitlines()
    body = lines[1:1 + rows] if rows else [ln.replace(".png", ".jpg", 1) for ln in lines[1:]]
    (tmp_path / "kin.csv").write_text("\n".join([lines[0], *body]) + "\n")
    r = invoke("fulcrum", "--lines", tmp_path / "lines.json", "--camera", tmp_path / "cam.json", "--shaft-diameter",
               2 * RADIUS, "--kinematics", tmp_path / "kin.csv", "-o", tmp_path / "f.json", "-q")
    assert r.exit_code == 1 and message in r.output and "kin.csv" in r.output, r.output
    assert len(r.output.strip().splitlines()) == 1


def test_faults_at_the_boundary(tmp_path):
    _lines(tmp_path)
    (tmp_path / "kin.csv").write_text("image,x_mm,y_mm,z_mm,qw,qx,qy,qz\n000.png,1,2,3,2,0,0,0\n")
    base = ["fulcrum", "--lines", tmp_path / "lines.json", "--camera", tmp_path / "cam.json"]
    r = invoke(*base, "--kinematics", tmp_path / "kin.csv", "-o", tmp_path / "f.json")
    assert r.exit_code == 2 and "--kinematics needs --shaft-diameter" in r.output
    r = invoke(*base, "--shaft-diameter", 8, "--kinematics", tmp_path / "kin.csv", "-o", tmp_path / "f.json", "-q")
    assert r.exit_code == 1 and "kin.csv:2: the quaternion" in r.output and len(r.output.strip().splitlines()) == 1
    assert not (tmp_path / "f.json").exists()
    r = invoke(*base, "--shaft-diameter", 8, "--kinematics", tmp_path / "kin.csv", "-o", tmp_path / "kin.csv",
               "--force", "-q")
    assert r.exit_code != 0 and "kin.csv" in r.output


@pytest.mark.slow
def test_simulate_pivot_with_the_fulcrum_in_view(tmp_path):
    """simulate's pivot (a planar fan, the fulcrum in view, the shaft 60 mm past it to the
    tip and 300 mm behind it across the image): the mirror solution is decided by the band's
    end inside the image, the tip's (the band's middle chose the mirror); the transform
    within 3 sigma (measured: 7.3 mm off, sigma 13 mm)."""
    out = tmp_path / "p"
    r = invoke("simulate", out, "--scenario", "pivot", "--frames", 16, "--seed", 2, "--shaft-diameter", 8, "-q")
    assert r.exit_code == 0, r.output
    truth = json.loads((out / "truth.json").read_text())
    fr = truth["frames"]
    (tmp_path / "kin.csv").write_text(kinematics_rows([f["image"] for f in fr], [f["fulcrum_cam"] for f in fr],
                                                      [f["shaft_direction_cam"] for f in fr], truth["options"]["tip"]))
    r = invoke("fulcrum", out / "images", "--camera", out / "camera.json", "--shaft-diameter", 8, "--kinematics",
               tmp_path / "kin.csv", "-o", tmp_path / "f.json", "-q")
    assert r.exit_code == 0, r.output
    rob = json.loads((tmp_path / "f.json").read_text())["robot"]
    e, m2 = errors(rob)
    assert rob["twin_by"] == "sides" and rob["twin_vote"] >= 0.5
    assert m2 < chi2_3sigma(6), (e, m2)


@pytest.mark.slow
def test_each_pivot_epoch_has_its_own_hand_eye(tmp_path):
    """simulate's pivot whose camera moves between two runs of frames, the robot's base fixed
    in the scene: each epoch's ``robot`` holds that epoch's transform (within 3 sigma) and the
    same remote centre in the base."""
    out = tmp_path / "p"
    r = invoke("simulate", out, "--scenario", "pivot", "--frames", 16, "--seed", 1, "--epochs", 2,
               "--shaft-diameter", 8, "-q")
    assert r.exit_code == 0, r.output
    truth = json.loads((out / "truth.json").read_text())
    tip = truth["options"]["tip"]
    # the base: the target frame turned and shifted (R_TRUE, T_TRUE as target-from-base)
    rows = [f"frame,x_mm,y_mm,z_mm,{MATRIX}"]
    for k, fr in enumerate(truth["frames"]):
        Rc, tc = np.asarray(fr["R_cam_from_target"]), np.asarray(fr["t_cam_from_target"])
        d_t = Rc.T @ np.asarray(fr["shaft_direction_cam"])
        tip_t = Rc.T @ (np.asarray(fr["fulcrum_cam"]) + tip * np.asarray(fr["shaft_direction_cam"]) - tc)
        vals = [*(R_TRUE.T @ (tip_t - T_TRUE)), *tool_rotation(R_TRUE.T @ d_t).ravel()]
        rows.append(",".join([str(k)] + [f"{v:.12f}" for v in vals]))
    (tmp_path / "kin.csv").write_text("\n".join(rows) + "\n")
    r = invoke("fulcrum", out / "images", "--camera", out / "camera.json", "--shaft-diameter", 8, "--kinematics",
               tmp_path / "kin.csv", "-o", tmp_path / "f.json", "-q")
    assert r.exit_code == 0, r.output
    got = json.loads((tmp_path / "f.json").read_text())
    assert len(got["epochs"]) == 2
    centre = R_TRUE.T @ (np.asarray(truth["pivot"]["fulcrum_target"]) - T_TRUE)
    for ep, te in zip(got["epochs"], truth["epochs"]):
        rob = ep["robot"]
        Rc, tc = np.asarray(te["R_cam_from_target"]), np.asarray(te["t_cam_from_target"])
        R, t = Rc @ R_TRUE, Rc @ T_TRUE + tc                                    # cam from base, this epoch
        e = np.r_[rotvec_from_rotation(R @ np.asarray(rob["R_cam_from_base"]).T), t - rob["t_cam_from_base_mm"]]
        assert e @ np.linalg.solve(np.asarray(rob["cov_cam_from_base"]), e) < chi2_3sigma(6), e
        assert np.allclose(rob["fulcrum_base_mm"], centre, atol=1e-3)


@pytest.mark.slow
def test_stereo_axes_give_a_surer_hand_eye(tmp_path):
    """The rendered stereo pivot of test_fulcrum_stereo_cli (10 frames, a 10 mm baseline)
    with exact tool poses: ``stereo.robot``, from the axes both eyes triangulate, holds the
    transform within 3 sigma with a translation sigma below the left eye's alone."""
    from tests.cli.test_fulcrum_stereo_cli import stereo_pivot

    sc = stereo_pivot(tmp_path)
    fr = sc.frames
    (tmp_path / "kin.csv").write_text(kinematics_rows([f["image"] for f in fr], [f["fulcrum_cam"] for f in fr],
                                                      [f["shaft_direction_cam"] for f in fr], 90.0))
    r = invoke("fulcrum", tmp_path / "left", "--camera", tmp_path / "left.json", "--right", tmp_path / "right",
               "--camera-right", tmp_path / "right.json", "--right-from-left", tmp_path / "extrinsics.yml",
               "--shaft-diameter", 8, "--kinematics", tmp_path / "kin.csv", "-o", tmp_path / "f.json", "-q")
    assert r.exit_code == 0, r.output
    out = json.loads((tmp_path / "f.json").read_text())
    mono, st = out["robot"], out["stereo"]["robot"]
    for rec in (mono, st):
        e, m2 = errors(rec)
        assert m2 < chi2_3sigma(6), (e, m2)
    assert st["translation_sigma_mm"] < mono["translation_sigma_mm"], (st["translation_sigma_mm"],
                                                                       mono["translation_sigma_mm"])
    assert st["frames_used"] >= 8

"""`pencilcal orient --lines`: the file contract, exit codes and messages."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.cli.main import cli
from pencilcal.toolkit.camera.formats import write_camera
from pencilcal.toolkit.pencil.spec import project_spokes
from tests.conftest import REPO
from tests.helpers import fan, frame, hd_camera, pose_facing, two_spokes_and_a_stray

KEYS = ["image", "ok", "error", "vertex_px", "vertex_cov_px2", "lines_used", "rms_residual_deg",
        "tilt_deg", "tilt_sigma_deg", "detectable", "normal", "normal_sigma_deg", "normal_twin",
        "R_cam_from_target", "R_cam_from_target_twin", "ambiguous", "model"]


@pytest.fixture
def scene(tmp_path, rng):
    cam = hd_camera()
    write_camera(tmp_path / "camera.yaml", cam)
    pen = fan(radius=None)
    (tmp_path / "pencil.yaml").write_text("start_deg: 0\nstep_deg: 20\ncount: 8\n")
    frames, truth = [], []
    for i in range(4):
        seg, R, _ = frame(cam, pen, 20 + 10 * i, 200.0, rng)
        frames.append({"image": f"{i:03d}.png", "ok": True, "segments": seg.tolist()})
        truth.append(R)
    frames.append({"image": "bad.png", "ok": True, "segments": [[0, 0, 100, 100]]})
    (tmp_path / "lines.json").write_text(json.dumps({"frames": frames}))
    return tmp_path, truth


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_orient_writes_contract(scene):
    d, truth = scene
    r = invoke("orient", "--lines", d / "lines.json", "--camera", d / "camera.yaml", "--pencil", d / "pencil.yaml",
               "-o", d / "out.json", "--quiet")
    assert r.exit_code == 0, r.output
    out = json.loads((d / "out.json").read_text())
    assert len(out["frames"]) == 5
    for fr, R in zip(out["frames"], truth):
        assert all(k in fr for k in KEYS)
        assert fr["ok"] and fr["model"] == "exact"
        err = min(np.degrees(np.arccos(np.clip((np.trace(np.asarray(Rx).T @ R) - 1) / 2, -1, 1)))
                  for Rx in (fr["R_cam_from_target"], fr["R_cam_from_target_twin"]))
        assert err < 1e-4
    bad = out["frames"][-1]
    assert bad["ok"] is False and bad["error"]
    # the failing frame is reported on stderr as one warning line
    assert "bad.png" in r.output


def test_max_segments_keeps_the_longest_and_says_so(scene):
    """A frame with more segments than --max-segments is oriented from the longest, with a
    warning naming the frame and the option; the other frames are untouched."""
    d, truth = scene
    lines = json.loads((d / "lines.json").read_text())
    short = [[100.0, 100.0 + 3 * k, 110.0, 101.0 + 3 * k] for k in range(4)]
    lines["frames"][0]["segments"] = short + lines["frames"][0]["segments"]
    (d / "lines.json").write_text(json.dumps(lines))
    r = invoke("orient", "--lines", d / "lines.json", "--camera", d / "camera.yaml", "--pencil", d / "pencil.yaml",
               "-o", d / "out.json", "--max-segments", 8)
    assert r.exit_code == 0, r.output
    assert any("warning" in ln and "000.png: 12 segments, more than --max-segments 8" in ln for ln in r.output.splitlines())
    f = json.loads((d / "out.json").read_text())["frames"][0]
    assert f["ok"] and f["lines_used"] == 8 and f["spokes"][:4] == [-1] * 4
    assert invoke("orient", "--lines", d / "lines.json", "--camera", d / "camera.yaml", "--pencil",
                  d / "pencil.yaml", "-o", d / "o2.json", "--max-segments", 2).exit_code == 2


def test_no_overwrite_without_force(scene):
    d, _ = scene
    (d / "out.json").write_text("keep me")
    args = ["orient", "--lines", d / "lines.json", "--camera", d / "camera.yaml", "--pencil", d / "pencil.yaml", "-o", d / "out.json", "-q"]
    r = invoke(*args)
    assert r.exit_code == 1 and "already exists" in r.output and "--force" in r.output
    assert (d / "out.json").read_text() == "keep me"
    assert invoke(*args, "--force").exit_code == 0


@pytest.mark.parametrize("what,content,message", [
    ("pencil", "angles_deg: [0, 20]\n", "at least three spokes"),
    ("pencil", "angles_deg: [0, 20, .nan]\n", "finite"),
    ("lines", '{"frames": [{"segments": [[1, 2, 3]]}]}', "[x1, y1, x2, y2]"),
    ("lines", "{not json", "not valid JSON"),
    ("camera", "%YAML:1.0\ncamera_matrix: !!opencv-matrix\n  rows: 3\n  cols: 3\n  dt: d\n  data: [.nan, 0, 1, 0, 1, 1, 0, 0, 1]\n", ""),
])
def test_bad_input_is_one_line_exit_1(scene, what, content, message):
    d, _ = scene
    name = {"pencil": "pencil.yaml", "lines": "lines.json", "camera": "camera.yaml"}[what]
    (d / name).write_text(content)
    r = invoke("orient", "--lines", d / "lines.json", "--camera", d / "camera.yaml", "--pencil", d / "pencil.yaml", "-o", d / "o.json", "-q")
    assert r.exit_code == 1, r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("pencilcal: error:")
    assert name in lines[0] and message in lines[0]
    assert "Traceback" not in r.output
    assert not (d / "o.json").exists()


def test_usage_error_exit_2(scene):
    d, _ = scene
    r = invoke("orient", "--camera", d / "camera.yaml")
    assert r.exit_code == 2


def test_help_has_an_example():
    r = invoke("orient", "--help")
    assert r.exit_code == 0 and "Example" in r.output and "pencilcal orient --lines" in r.output


CHECK = REPO.parent / "shared" / "checks" / "contract_orient.py"


@pytest.mark.skipif(not CHECK.is_file(), reason=f"contract check not found at {CHECK}")
@pytest.mark.skipif(shutil.which("pencilcal") is None, reason="pencilcal is not installed on PATH")
def test_shared_contract_check():
    r = subprocess.run([sys.executable, str(CHECK), shutil.which("pencilcal")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr


def test_an_ambiguous_normal_is_said_on_stderr(tmp_path, rng):
    """Two spokes and a stray edge through the vertex: three lines fit every labelling, the
    spoke radii fit none; the frame comes out with normal_ambiguous, and the run says so in a
    warning and in its summary line."""
    cam = hd_camera()
    write_camera(tmp_path / "camera.yaml", cam)
    (tmp_path / "pencil.yaml").write_text("start_deg: 0\nstep_deg: 10\ncount: 13\nradius: [15, 80]\n")
    pen = fan(radius=(15.0, 80.0), count=13, step=10.0)
    frames = []
    for i in range(12):
        seg, _, _ = two_spokes_and_a_stray(cam, pen, rng)
        frames.append({"image": f"{i:03d}.png", "ok": True, "segments": seg.tolist()})
    (tmp_path / "lines.json").write_text(json.dumps({"frames": frames}))
    r = invoke("orient", "--lines", tmp_path / "lines.json", "--camera", tmp_path / "camera.yaml", "--pencil",
               tmp_path / "pencil.yaml", "-o", tmp_path / "out.json", "--endpoint-sigma", 0.3)
    assert r.exit_code == 0, r.output
    out = json.loads((tmp_path / "out.json").read_text())
    amb = [f["image"] for f in out["frames"] if f["ok"] and f["normal_ambiguous"]]
    assert len(amb) >= 6
    for name in amb:
        assert f"{name}: the normal is ambiguous" in r.output
    assert f"({len(amb)} with an ambiguous normal)" in r.output


def test_the_noise_is_estimated_from_the_sequence(tmp_path, rng):
    """Lines with 0.15 px end point noise and no sigmas: orient does not keep the assumed
    0.5 px, it estimates the noise from the frames' residuals, and the tilt sigmas cover
    about 68 % of the errors; given --endpoint-sigma, the noise is the user's."""
    from pencilcal.toolkit.geometry.frames import angle_between

    cam = hd_camera()
    write_camera(tmp_path / "camera.yaml", cam)
    pen = fan(radius=None)
    (tmp_path / "pencil.yaml").write_text("start_deg: 0\nstep_deg: 20\ncount: 8\n")
    frames, truth = [], []
    for i in range(80):
        seg, R, t = frame(cam, pen, rng.uniform(25, 55), 250.0, rng, noise_px=0.15)
        frames.append({"image": f"{i:03d}.png", "segments": seg.tolist()})
        truth.append(np.degrees(angle_between(R[:, 2], cam.rays_from_pixels(cam.project(t)))))
    (tmp_path / "lines.json").write_text(json.dumps({"frames": frames}))
    common = ["orient", "--lines", tmp_path / "lines.json", "--camera", tmp_path / "camera.yaml", "--pencil",
              tmp_path / "pencil.yaml", "-q"]
    r = invoke(*common, "-o", tmp_path / "est.json")
    assert r.exit_code == 0, r.output
    out = json.loads((tmp_path / "est.json").read_text())
    assert out["noise"]["estimated"] and out["noise"]["sigma_scale"] == pytest.approx(0.3, rel=0.15)
    inside = [abs(f["tilt_deg"] - t) < f["tilt_sigma_deg"] for f, t in zip(out["frames"], truth) if f["ok"]]
    assert len(inside) >= 76 and 0.58 <= np.mean(inside) <= 0.78
    r = invoke(*common, "--endpoint-sigma", "0.5", "-o", tmp_path / "given.json")
    given = json.loads((tmp_path / "given.json").read_text())
    assert given["noise"] == {"estimated": False, "endpoint_sigma_px": 0.5, "angle_sigma_deg": None}
    a, b = out["frames"][0], given["frames"][0]
    assert a["tilt_sigma_deg"] == pytest.approx(b["tilt_sigma_deg"] * out["noise"]["sigma_scale"], rel=0.2)


def test_a_lines_records_error_sds_widen_the_sigmas_only(scene):
    """A lines record's `angle_sigma_error_deg` (a star's edges: docs/formats.md) is the
    covariance's: the orientation is the same as without it, bit for bit, its sigma wider."""
    d, _ = scene
    frames = json.loads((d / "lines.json").read_text())["frames"][:1]
    n = len(frames[0]["segments"])
    frames[0]["angle_sigma_deg"] = [0.05] * n
    wide = dict(frames[0], angle_sigma_error_deg=[0.05, 0.4] * (n // 2) + [0.05] * (n % 2))
    out = {}
    for name, fr in (("plain", frames[0]), ("wide", wide)):
        (d / f"{name}.json").write_text(json.dumps({"frames": [fr]}))
        r = invoke("orient", "--lines", d / f"{name}.json", "--camera", d / "camera.yaml", "--pencil",
                   d / "pencil.yaml", "-o", d / f"o_{name}.json", "--quiet")
        assert r.exit_code == 0, r.output
        out[name] = json.loads((d / f"o_{name}.json").read_text())["frames"][0]
    assert out["wide"]["normal"] == out["plain"]["normal"] and out["wide"]["spokes"] == out["plain"]["spokes"]
    assert out["wide"]["normal_sigma_deg"] > 1.2 * out["plain"]["normal_sigma_deg"]


def test_the_camera_files_readout_is_used_and_checked(scene, rng):
    # frames that move: the camera file's readout moves their lines as --readout does, and
    # one that is no fraction of the frame interval is a one-line error naming the file
    d, _ = scene
    frames = json.loads((d / "lines.json").read_text())["frames"][:4]
    for i, fr in enumerate(frames):
        # one pose turning a little a frame (the scene's own frames jump 10 deg of tilt: no
        # label would follow them, and nothing could be moved)
        fr["segments"] = (np.asarray(frames[0]["segments"] if i else fr["segments"])
                          + [3.0 * i, 0, 3.0 * i + 6.0 * i, 0]).tolist()
    (d / "lines.json").write_text(json.dumps({"frames": frames}))
    run = ("orient", "--lines", d / "lines.json", "--camera", d / "camera.yaml", "--pencil", d / "pencil.yaml",
           "--endpoint-sigma", "0.3", "-q", "--force", "-o")
    assert invoke(*run, d / "plain.json").exit_code == 0
    assert invoke(*run, d / "given.json", "--readout", "0.5").exit_code == 0
    with open(d / "camera.yaml", "a") as f:
        f.write("readout: 0.5\n")
    assert invoke(*run, d / "file.json").exit_code == 0
    tilt = {k: [f["tilt_deg"] for f in json.loads((d / f"{k}.json").read_text())["frames"]]
            for k in ("plain", "given", "file")}
    assert tilt["file"] == tilt["given"] and tilt["given"][0] == tilt["plain"][0]
    assert tilt["given"][1:] != tilt["plain"][1:]
    r = invoke(*run, d / "w.json", "--workers", "2", "--readout", "0.5")
    assert r.exit_code == 2 and "--readout" in r.output
    (d / "camera.yaml").write_text((d / "camera.yaml").read_text().replace("readout: 0.5", "readout: 1.5"))
    r = invoke(*run, d / "bad.json")
    assert r.exit_code == 1 and "camera.yaml" in r.output and "readout" in r.output


def _rolling_fan(d, rng, roll_deg, noise_px, frames=4, readout=0.6, tilt=12.0):
    """A lines file of a fan (tilt `tilt` deg, its vertex at the principal point) seen by a
    camera rolling `roll_deg` a frame about its axis through a rolling shutter: each end
    point at its row's time (`readout` of a frame from the first row to the last)."""
    cam = hd_camera("pinhole")
    write_camera(d / "camera.yaml", cam)
    (d / "pencil.yaml").write_text("start_deg: 0\nstep_deg: 20\ncount: 8\n")
    c = np.asarray(cam.K, float)[:2, 2]
    R, t = pose_facing(cam, c, tilt, 200.0, rng)
    p = project_spokes(cam, R, t, fan(radius=None), (10.0, 50.0)).reshape(-1, 2) - c
    out = []
    for i in range(frames):
        q = p
        for _ in range(8):  # a point's row sets its time, its time where it is: the fixed point
            a = np.radians(roll_deg) * (i + readout * q[:, 1] / cam.height)  # (each row's time after the vertex's)
            q = np.stack([np.cos(a) * p[:, 0] - np.sin(a) * p[:, 1], np.sin(a) * p[:, 0] + np.cos(a) * p[:, 1]], -1)
        seg = (q + c).reshape(-1, 4) + noise_px * rng.normal(size=(8, 4))
        out.append({"image": f"{i:03d}.png", "ok": True, "segments": seg.tolist()})
    (d / "lines.json").write_text(json.dumps({"frames": out}))
    run = ("orient", "--lines", d / "lines.json", "--camera", d / "camera.yaml", "--pencil", d / "pencil.yaml",
           "--endpoint-sigma", "0.3", "-q", "--force", "-o")
    res = {}
    for name, extra in (("global", ("--readout", "0")), ("unknown", ())):
        r = invoke(*run, d / f"{name}.json", *extra)
        assert r.exit_code == 0, r.output
        res[name] = json.loads((d / f"{name}.json").read_text())["frames"]
    return res


def test_an_unknown_readout_widens_a_sheared_fans_sigma_and_leaves_its_estimate(tmp_path, rng):
    # a camera rolling 5 deg a frame: the shear tilts the fit by far more than its sigma;
    # with the readout not known the sigma covers it, the estimate the same to the bit
    res = _rolling_fan(tmp_path, rng, 5.0, 0.2)
    for g, u in zip(res["global"], res["unknown"]):
        assert g["ok"] and u["ok"]
        assert u["normal"] == g["normal"] and u["tilt_deg"] == g["tilt_deg"]
    assert "tilt_sigma_shutter_deg" not in res["global"][0] and "tilt_sigma_shutter_deg" not in res["unknown"][0]
    for g, u in zip(res["global"][1:], res["unknown"][1:]):
        err = abs(g["tilt_deg"] - 12.0)
        assert err > 3 * g["tilt_sigma_deg"]  # the lines' sigma knows nothing of the shear
        assert err < 3 * u["tilt_sigma_deg"] < 10 * err
        assert u["tilt_sigma_deg"] == pytest.approx(np.hypot(g["tilt_sigma_deg"], u["tilt_sigma_shutter_deg"]))
        assert u["normal_sigma_deg"] == pytest.approx(np.hypot(g["normal_sigma_deg"], u["normal_sigma_shutter_deg"]))


def test_a_still_camera_keeps_its_sigmas_with_the_readout_not_known(tmp_path, rng):
    # lines that only jitter (0.05 px): no motion, no shear, the same record to the bit
    res = _rolling_fan(tmp_path, rng, 0.0, 0.05)
    assert res["unknown"] == res["global"]

"""`pencilcal fulcrum --lines`: contract keys and errors."""
from __future__ import annotations

import json

import numpy as np
from click.testing import CliRunner

from pencilcal.cli.main import cli
from pencilcal.toolkit.camera.formats import write_camera
from tests.helpers import hd_camera
from tests.toolkit.pencil.test_fulcrum import pivot_sequence


def test_fulcrum_cli(tmp_path, rng):
    cam = hd_camera()
    write_camera(tmp_path / "cam.json", cam)
    frames, angles, R, P = pivot_sequence(cam, rng, noise_px=0.3)
    (tmp_path / "lines.json").write_text(json.dumps({"frames": [dict(f, segments=f["segments"].tolist()) for f in frames]}))
    (tmp_path / "angles.csv").write_text("image,angle_deg\n" + "".join(f"{f['image']},{float(np.degrees(a))!r}\n" for f, a in zip(frames, angles)))
    r = CliRunner().invoke(cli, ["fulcrum", "--lines", str(tmp_path / "lines.json"), "--camera", str(tmp_path / "cam.json"),
                                 "--angles", str(tmp_path / "angles.csv"), "-o", str(tmp_path / "f.json"), "-q"])
    assert r.exit_code == 0, r.output
    out = json.loads((tmp_path / "f.json").read_text())
    for k in ("vertex_px", "vertex_cov_px2", "ray", "lines_used", "outliers", "normal", "tilt_deg", "R_cam_from_target", "ambiguous"):
        assert k in out
    assert np.linalg.norm(np.asarray(out["vertex_px"]) - cam.project(P)) < 1.0
    # too few angles: one line, exit 1
    (tmp_path / "angles.csv").write_text("1\n2\n")
    r = CliRunner().invoke(cli, ["fulcrum", "--lines", str(tmp_path / "lines.json"), "--camera", str(tmp_path / "cam.json"),
                                 "--angles", str(tmp_path / "angles.csv"), "-o", str(tmp_path / "g.json"), "-q"])
    assert r.exit_code == 1 and "angles" in r.output and len(r.output.strip().splitlines()) == 1


def test_fulcrum_estimates_the_line_noise(tmp_path, rng):
    """Segments with 1.5 px end point noise and no sigmas: the fulcrum's sigmas hold the noise
    its lines show (estimated, about 3 times the assumed 0.5 px), unless --endpoint-sigma."""
    cam = hd_camera()
    write_camera(tmp_path / "cam.json", cam)
    frames, angles, R, P = pivot_sequence(cam, rng, n=40, noise_px=1.5)
    (tmp_path / "lines.json").write_text(json.dumps({"frames": [dict(f, segments=f["segments"].tolist())
                                                                for f in frames]}))
    base = ["fulcrum", "--lines", str(tmp_path / "lines.json"), "--camera", str(tmp_path / "cam.json"), "-q"]
    r = CliRunner().invoke(cli, base + ["-o", str(tmp_path / "f.json"), "--jsonl", str(tmp_path / "s.jsonl")])
    assert r.exit_code == 0, r.output
    out = json.loads((tmp_path / "f.json").read_text())
    assert out["noise"]["estimated"] and 2.0 < out["noise"]["sigma_scale"] < 4.5
    assert len((tmp_path / "s.jsonl").read_text().splitlines()) == 40
    r = CliRunner().invoke(cli, base + ["--endpoint-sigma", "1.5", "-o", str(tmp_path / "g.json")])
    given = json.loads((tmp_path / "g.json").read_text())
    assert given["noise"] == {"estimated": False, "endpoint_sigma_px": 1.5}
    assert 0.6 < out["ray_sigma_deg"] / given["ray_sigma_deg"] < 1.6

"""The fulcrum with the sigmas `pencilcal fulcrum` writes, from Python (`validation.fulcrum_run`,
`pencilcal.fulcrum`): the same numbers as the command."""
from __future__ import annotations

import json

import numpy as np
from click.testing import CliRunner

import pencilcal
from pencilcal.cli.main import cli
from pencilcal.toolkit.camera.formats import write_camera
from pencilcal.toolkit.io.lines_file import write_lines
from pencilcal.toolkit.pencil.fulcrum import fulcrum_from_frames
from pencilcal.validation.fulcrum_run import fulcrum_with_sigmas
from tests.helpers import hd_camera
from tests.toolkit.pencil.test_sequence_noise import _pivot_frames


def test_python_and_the_command_give_the_same_fulcrum(tmp_path, rng):
    cam = hd_camera()
    _, frames = _pivot_frames(cam, rng, 1.5, n=20)
    for k, f in enumerate(frames):
        f["image"] = f"{k:03d}.png"
    write_lines(tmp_path / "lines.json", frames)
    write_camera(tmp_path / "camera.json", cam)
    r = CliRunner().invoke(cli, ["fulcrum", "--lines", str(tmp_path / "lines.json"), "--camera",
                                 str(tmp_path / "camera.json"), "-o", str(tmp_path / "f.json")])
    assert r.exit_code == 0, r.output
    written = json.loads((tmp_path / "f.json").read_text())
    api = pencilcal.fulcrum(tmp_path / "lines.json", cam)
    rec = api.to_dict()
    # the noise estimated (1.5 px lines against the assumed 0.5 px) and the jackknife run
    assert rec["noise"]["assumed_endpoint_sigma_px"] == 0.5 and 2.0 < rec["noise"]["sigma_scale"] < 5.0
    assert rec["jackknife"]["frames"] == 20
    for k in ("ray_sigma_deg", "vertex_px", "lines_used"):
        assert np.allclose(rec[k], written[k]), k
    assert written["noise"] == json.loads(json.dumps(rec["noise"]))
    # the raw fit keeps the assumed noise: what a Python user got before
    raw = fulcrum_from_frames(cam, frames)
    assert api.ray_sigma_deg > 2 * raw.ray_sigma_deg and raw.noise is None and "noise" not in raw.to_dict()
    # the noise given is kept, the warnings said
    given = fulcrum_with_sigmas(cam, frames, endpoint_sigma_px=1.5)
    assert given.noise == {"estimated": False, "endpoint_sigma_px": 1.5} and not given.warnings
    assert any("scatter" in w for w in api.warnings)

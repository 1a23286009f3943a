"""validation.json's ``fulcrum`` record and the report's fulcrum section, from a simulated
pivot folder (`pencilcal simulate --scenario pivot`, 8 frames at 640x360, an 8 mm shaft
pivoting about a port 6 mm above the printed sheet, seen with the board)."""
from __future__ import annotations

import json
import re

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.cli.main import cli
from pencilcal.validation.report.build import build_report
from pencilcal.validation.report.document import Plot
from pencilcal.validation.report.fulcrum_section import fulcrum_section
from pencilcal.validation.validation_file import load_validation


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.fixture(scope="module")
def pivot(tmp_path_factory):
    out = tmp_path_factory.mktemp("pivot")
    r = invoke("simulate", out / "p", "--scenario", "pivot", "--frames", 8, "--size", "640x360", "--shaft-diameter",
               8, "-q")
    assert r.exit_code == 0, r.output
    r = invoke("validate", out / "p", "--methods", "ippe", "-o", out / "v.json", "-q")
    assert r.exit_code == 0, r.output
    return out


def test_validate_pivot_folder_has_the_fulcrum(pivot):
    v = json.loads((pivot / "v.json").read_text())
    truth = json.loads((pivot / "p" / "truth.json").read_text())["pivot"]
    f = v["fulcrum"]
    assert f["ok"] and f["shaft_diameter"] == 8.0 and f["frames_used"] == 8
    t = f["truth"]
    # the 2-D vertex within its own 3-sigma ellipse, the 3-D point within its 3-sigma region
    assert t["vertex_chi2"] < 9.0 and t["vertex_error_px"] < 1.0, t
    assert t["point_chi2"] < 14.2 and np.allclose(t["fulcrum_cam"], truth["fulcrum_cam"]), t
    e = np.asarray(f["point"]) - truth["fulcrum_cam"]
    assert np.isclose(np.linalg.norm(e), t["point_error_norm"])
    # each frame's axis residual, 2-D and 3-D
    assert len(f["axis_residuals"]) == 8 and all(r["residual_px"] < 3 * r["sigma_px"] for r in f["axis_residuals"])
    assert len(f["point_axes"]) == 8
    # every frame's 3-D axis, as far from the point as its distance says; every midline
    P = np.asarray(f["point"])
    for a in f["point_axes"]:
        A, d = np.asarray(a["axis_point"]), np.asarray(a["axis_direction"])
        assert np.isclose(np.linalg.norm(d), 1.0) and np.isclose(np.linalg.norm(np.cross(P - A, d)), a["distance"])
    assert [m["image"] for m in f["midlines"]] == [fr["image"] for fr in v["frames"]]
    # the board frame: the PnP poses take the point to the sheet's frame, where the truth is
    b = f["board_frame"]
    assert b["frames"] >= 1 and np.asarray(b["point_cov"]).shape == (3, 3)
    assert b["error"] < 3 * np.sqrt(np.trace(np.asarray(b["point_cov"]))) + 1.0, b


def test_validate_no_fulcrum_and_report_section(pivot, tmp_path):
    r = invoke("validate", pivot / "p", "--methods", "ippe", "--no-fulcrum", "-o", tmp_path / "n.json", "-q")
    assert r.exit_code == 0, r.output
    assert "fulcrum" not in json.loads((tmp_path / "n.json").read_text())
    data = load_validation(pivot / "v.json")
    sec = fulcrum_section(data)
    plots = [b for b in sec.blocks if isinstance(b, Plot)]
    assert len(plots) == 5 and all(p.png[:8] == b"\x89PNG\r\n\x1a\n" for p in plots)
    # three sample frames spread over the sequence, the fulcrum's ellipsoid drawn on them (cyan)
    assert [p.alt for p in plots[:3]] == ["fulcrum on 000.png", "fulcrum on 004.png", "fulcrum on 007.png"]
    assert "68 % ellipsoid" in plots[0].caption and "truth" in plots[0].caption
    img = cv2.imdecode(np.frombuffer(plots[0].png, np.uint8), cv2.IMREAD_COLOR).astype(int)
    cyan = (img[..., 0] > 200) & (img[..., 1] > 200) & (img[..., 2] < 60)
    assert cyan[: int(0.8 * img.shape[0]), img.shape[1] // 2:].sum() > 100  # in the zoom, not the legend
    assert "error ellipse" in plots[3].alt and "truth" in plots[3].caption and "8 used" in plots[3].caption
    assert len([b for b in fulcrum_section(data, samples=0).blocks if isinstance(b, Plot)]) == 2
    rows = sec.blocks[0].rows
    assert [r[0] for r in rows] == ["2-D vertex", "3-D point (camera frame)", "3-D point (board frame)"]
    # a pivot's report leads with its fulcrum: right after what was validated
    assert build_report(data).sections[1].id == "fulcrum"
    assert fulcrum_section({"frames": []}) is None
    failed = fulcrum_section({"fulcrum": {"ok": False, "error": "fewer than two instrument lines"}})
    assert "fewer than two" in failed.blocks[0].text
    from tests.validation.report.figure_rules import linted_figures

    with linted_figures() as problems:  # a fixed camera: every frame at one tilt, plotted against the frame
        r = invoke("report", pivot / "v.json", "-o", tmp_path / "r.html", "-q")
    assert r.exit_code == 0, r.output
    assert problems == []
    page = (tmp_path / "r.html").read_text()
    assert "2. Fulcrum of the pivoting instrument" in page and "lengths in mm" in page


def test_validate_gamma_reaches_the_shaft_edges(pivot, tmp_path):
    """--gamma is the one the shafts' edges are located with (as in `lines --shaft` and
    `fulcrum`), and the record says which: simulate writes gamma 2.2 (the default)."""
    r = invoke("validate", pivot / "p", "--methods", "ippe", "--gamma", 1.0, "-o", tmp_path / "g.json", "-q")
    assert r.exit_code == 0, r.output
    linear = json.loads((tmp_path / "g.json").read_text())["fulcrum"]
    default = json.loads((pivot / "v.json").read_text())["fulcrum"]
    assert linear["gamma"] == 1.0 and default["gamma"] == 2.2
    # other edge locations, so another fulcrum, both ok
    assert linear["ok"] and default["ok"] and linear["vertex_px"] != default["vertex_px"]
    r = invoke("validate", pivot / "p", "--methods", "ippe", "--gamma", 0.0, "-o", tmp_path / "bad.json", "-q")
    assert r.exit_code == 2 and "--gamma" in r.output


def test_continuity_resolves_the_twin_and_rescores_the_frames(pivot, tmp_path):
    """validate carries the twin chosen in resolved frames to the ambiguous ones, as orient
    does (the camera is fixed: every frame shows the same pose): frames reported with the
    wrong twin and left ambiguous come out right, resolved by continuity, their errors
    measured again; --no-continuity leaves the frames as the spoke radii left them."""
    from pencilcal.toolkit.pencil.orientation import Orientation
    from pencilcal.validation.validate import twins_by_continuity

    frames = json.loads((pivot / "v.json").read_text())["frames"]
    estimates = []
    for i, fr in enumerate(frames):
        o = Orientation.from_dict(fr["orient"]["exact"])
        if fr["errors"]["orient:exact"]["twin"] == "wrong":
            o = o.swapped()
        # frame 0 resolved (the radii's choice, say); the others ambiguous, every other one
        # reporting the wrong twin
        o = o.replace(ambiguous=False, resolved_by="radius") if i == 0 else \
            (o.swapped() if i % 2 else o).replace(ambiguous=True, resolved_by=None)
        fr["orient"]["exact"] = o.to_dict()
        estimates.append({"orients": {"exact": o}, "R_ref": np.asarray(fr["R_ref"], float), "ray": None,
                          "ref_pose": None})
    twins_by_continuity(frames, estimates)
    for fr in frames[1:]:
        assert fr["orient"]["exact"]["resolved_by"] == "continuity" and not fr["orient"]["exact"]["ambiguous"]
        e = fr["errors"]["orient:exact"]
        assert e["twin"] == "right" and e["normal_deg"] == e["normal_closer_deg"] < 1.0
    r = invoke("validate", pivot / "p", "--methods", "ippe", "--no-fulcrum", "--no-continuity", "-o",
               tmp_path / "nc.json", "-q")
    assert r.exit_code == 0, r.output
    nc = json.loads((tmp_path / "nc.json").read_text())
    assert all(f["orient"]["exact"].get("resolved_by") != "continuity" for f in nc["frames"] if f["ok"])


def test_the_pivot_report_opens_with_the_fulcrum_in_a_browser(pivot, tmp_path):
    """The first screen (1280x900, headless Chromium) shows the verdict on the fulcrum, its
    3-D point in mm; nothing overflows, every figure's axes are labelled."""
    from tests.validation.report.browser import CHROMIUM, first_screen

    if not CHROMIUM.exists():
        pytest.skip("Chromium not installed (apt-get install chromium)")
    r = invoke("report", pivot / "v.json", "-o", tmp_path / "pivot.html", "-q")
    assert r.exit_code == 0, r.output
    verdict, problems = first_screen(tmp_path / "pivot.html", tmp_path, tmp_path / "first-screen.png")
    assert problems == []
    assert re.match(r"(PASS|FAIL) ?fulcrum of the pivoting instrument: the 3-D point \([-\d., ]+\) mm in the camera "
                    r"frame, sigma [\d.]+ mm", verdict), verdict

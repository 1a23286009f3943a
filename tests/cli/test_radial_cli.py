"""Radial targets from the command line: `target --star` at true scale, `lines --radial`, and
`orient` on a photograph-like render of the printed star."""
from __future__ import annotations

import json
import re
import zlib
from collections import Counter

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.cli.lines import lines
from pencilcal.cli.orient import orient
from pencilcal.cli.target import target
from pencilcal.toolkit.camera.formats import write_camera
from pencilcal.toolkit.pencil.spec import read_pencil


def _invoke(cmd, *args):
    return CliRunner().invoke(cmd, [str(a) for a in args])


def _pdf_subpaths(path):
    """The subpaths (lists of [x, y] [pt]) of a PDF's content streams (Flate-encoded, as
    matplotlib writes them): each `m` starts one, each `l` adds a point."""
    paths = []
    for s in re.findall(rb"stream\r?\n(.*?)\r?\nendstream", path.read_bytes(), re.S):
        try:
            toks = zlib.decompress(s).split()
        except zlib.error:
            continue
        stack, cur = [], None
        for t in toks:
            try:
                stack.append(float(t))
                continue
            except ValueError:
                pass
            if t == b"m":
                cur = [stack[-2:]]
                paths.append(cur)
            elif t == b"l" and cur is not None:
                cur.append(stack[-2:])
            stack = []
    return paths


@pytest.mark.parametrize("wedges,args,radius", [(64, (), 46.0), (32, ("--paper", "a3", "--star-radius", 70), 70.0)])
def test_star_prints_at_true_scale(tmp_path, wedges, args, radius):
    """The PDF's wedges, measured on its page: every one from the vertex the pencil file
    gives out to the radius it gives, in millimetres."""
    out = tmp_path / "star.pdf"
    r = _invoke(target, "-o", out, "--star", wedges, *args, "-q")
    assert r.exit_code == 0, r.output
    pen = read_pencil(tmp_path / "pencil.yaml")
    assert pen.shape == "wedge" and pen.count == wedges and pen.circles.tolist() == [radius]
    paths = _pdf_subpaths(out)
    apex, count = Counter(tuple(np.round(p[0], 3)) for p in paths).most_common(1)[0]
    assert count == wedges  # every wedge's outline starts at the vertex
    mm = 25.4 / 72.0
    reach = [np.max(np.hypot(*(np.array(p) - p[0]).T)) * mm for p in paths if tuple(np.round(p[0], 3)) == apex]
    assert np.allclose(reach, radius, atol=1e-3)
    # the vertex where the pencil file says, on the page (PDF y runs up from the bottom)
    m = re.search(rb"/MediaBox\s*\[\s*[-\d.]+\s+[-\d.]+\s+([-\d.]+)\s+([-\d.]+)\s*\]", out.read_bytes())
    page_h = float(m.group(2)) * mm
    from pencilcal.toolkit.synth.sheet import layout_sheet

    sheet = layout_sheet(star=wedges, star_radius=None if not args else radius, paper="a3" if args else "a4")
    x0, y0 = sheet.paper_origin
    assert apex[0] * mm == pytest.approx(pen.vertex[0] - x0, abs=1e-3)
    assert page_h - apex[1] * mm == pytest.approx(pen.vertex[1] - y0, abs=1e-3)


def test_star_options(tmp_path):
    r = _invoke(target, "-o", tmp_path / "t.pdf", "--star-radius", 40, "-q")
    assert r.exit_code != 0 and "only with --star" in r.output
    r = _invoke(target, "-o", tmp_path / "t.pdf", "--star", 32, "--spokes", 10, "-q")
    assert r.exit_code != 0 and "--spokes" in r.output and "not of --star" in r.output
    r = _invoke(target, "-o", tmp_path / "t.pdf", "--star", 32, "--star-radius", 300, "-q")
    assert r.exit_code != 0 and "does not fit" in r.output


@pytest.fixture(scope="module")
def star_photo(tmp_path_factory):
    """The printed star of `target --star 32` beside its board, rendered as a webcam sees it
    (1280x960, k1 -0.12, 1 px blur, noise, uneven light, gamma 2.2, JPEG 90), with the
    camera and pencil files and the true rotation."""
    from tests.helpers import star_sheet_view

    d = tmp_path_factory.mktemp("star")
    r = _invoke(target, "-o", d / "star.pdf", "--star", 32, "-q")
    assert r.exit_code == 0, r.output
    img, cam, _, R, _ = star_sheet_view(32, 35.0, 230.0, rng=5)
    cv2.imwrite(str(d / "frame.jpg"), img, [cv2.IMWRITE_JPEG_QUALITY, 90])
    write_camera(d / "camera.json", cam)
    return d, R


def test_orient_finds_every_spoke_of_the_printed_star(star_photo):
    d, R = star_photo
    r = _invoke(orient, d / "frame.jpg", "--camera", d / "camera.json", "--pencil", d / "pencil.yaml", "-o",
                d / "orientation.json", "-q")
    assert r.exit_code == 0, r.output
    rec = json.loads((d / "orientation.json").read_text())["frames"][0]
    assert rec["spokes_used"] == 32 and rec["lines_used"] >= 60  # every wedge, by one edge or both
    assert rec["resolved_by"] == "circle" and rec["circles_used"] >= 1 and rec["circle_consistent"]
    err = np.degrees(np.arccos(np.clip(np.dot(rec["normal"], R[:, 2]), -1, 1)))
    assert err < 3 * rec["normal_sigma_deg"] + 0.005


def test_lines_radial_writes_the_edges_and_circle_points(star_photo):
    d, _ = star_photo
    r = _invoke(lines, d / "frame.jpg", "--camera", d / "camera.json", "--radial", 64, "-o", d / "lines.json", "-q")
    assert r.exit_code == 0, r.output
    doc = json.loads((d / "lines.json").read_text())
    fr = doc["frames"][0]
    assert doc["mode"] == "radial" and doc["gamma"] == 2.2
    assert len(fr["segments"]) >= 60 and len(fr["circle_points"]) > 30
    r = _invoke(orient, "--lines", d / "lines.json", "--camera", d / "camera.json", "--pencil", d / "pencil.yaml",
                "-o", d / "o2.json", "-q")
    assert r.exit_code == 0, r.output
    rec = json.loads((d / "o2.json").read_text())["frames"][0]
    assert rec["spokes_used"] == 32 and rec["resolved_by"] == "circle"
    r = _invoke(lines, d / "frame.jpg", "--camera", d / "camera.json", "--radial", 64, "--bars", "-o", d / "x.json")
    assert r.exit_code != 0 and "--radial and --bars" in r.output
    # every edge located jointly with its neighbours, as orient IMAGES does for wedges
    r = _invoke(lines, d / "frame.jpg", "--camera", d / "camera.json", "--radial", 64, "--radial-joint", "all",
                "-o", d / "lines_all.json", "-q")
    assert r.exit_code == 0, r.output
    doc = json.loads((d / "lines_all.json").read_text())
    assert doc["radial_joint"] == "all" and len(doc["frames"][0]["segments"]) >= 60
    r = _invoke(orient, "--lines", d / "lines_all.json", "--camera", d / "camera.json", "--pencil",
                d / "pencil.yaml", "-o", d / "o_all.json", "-q")
    assert r.exit_code == 0, r.output
    assert json.loads((d / "o_all.json").read_text())["frames"][0]["spokes_used"] == 32
    r = _invoke(lines, d / "frame.jpg", "--camera", d / "camera.json", "--radial-joint", "all", "-o", d / "y.json")
    assert r.exit_code != 0 and "only with --radial" in r.output


def test_a_star_described_as_lines_is_told_so(star_photo):
    """The star's pencil file without its shape (32 rays, as for a fan of bars): its wedges
    are taken for bars, few fit, and the warning says what the file lacks."""
    d, _ = star_photo
    (d / "plain.yaml").write_text("start_deg: 0\nstep_deg: 11.25\ncount: 32\n")
    r = _invoke(orient, d / "frame.jpg", "--camera", d / "camera.json", "--pencil", d / "plain.yaml", "-o",
                d / "o3.json")
    assert "shape: wedge or edge" in r.output or "no frame gave an orientation" in r.output

"""`pencilcal target`: true scale, the files beside it, and no silent overwrite."""
from __future__ import annotations

import re

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from pencilcal.cli.target import target
from pencilcal.toolkit.board.spec import read_board
from pencilcal.toolkit.board.detect import detect_board
from pencilcal.toolkit.pencil.spec import read_pencil


def invoke(*args):
    return CliRunner().invoke(target, [str(a) for a in args])


def media_box_mm(path):
    m = re.search(rb"/MediaBox\s*\[\s*([-\d.]+)\s+([-\d.]+)\s+([-\d.]+)\s+([-\d.]+)\s*\]", path.read_bytes())
    x0, y0, x1, y1 = (float(v) for v in m.groups())
    return (x1 - x0) * 25.4 / 72.0, (y1 - y0) * 25.4 / 72.0


def test_png_is_true_scale_and_describes_itself(tmp_path):
    out = tmp_path / "target.png"
    dpi = 100.0
    r = invoke("-o", out, "--dpi", dpi, "-q")
    assert r.exit_code == 0, r.output
    im = Image.open(out)
    assert im.info["dpi"][0] == pytest.approx(dpi, abs=0.01)
    assert im.size == (round(297 / 25.4 * dpi), round(210 / 25.4 * dpi))  # A4 landscape
    img = np.asarray(im)
    board, pencil = read_board(tmp_path / "board.yaml"), read_pencil(tmp_path / "pencil.yaml")
    assert board.squares == (7, 5) and board.square == 25.0 and board.dictionary == "DICT_5X5_100"
    det = detect_board(img, board)
    assert det.count == board.corner_count
    # corner spacing is square * dpi / 25.4 px: least-squares scale of corners vs object points
    obj = board.object_points()[det.ids][:, :2]
    A = obj - obj.mean(0)
    B = det.corners - det.corners.mean(0)
    scale = np.sum(A * B) / np.sum(A * A)
    assert scale * board.square == pytest.approx(board.square * dpi / 25.4, abs=0.01)
    assert np.abs(B - scale * A).max() < 0.25  # and no rotation or shear
    # the pencil file says where the printed bars are: dark along every centre line,
    # white just beside it and at the vertex
    px = 25.4 / dpi
    origin = det.corners.mean(0) - scale * obj.mean(0)  # pixel of the board frame's origin
    v, (r0, r1), w = pencil.vertex, pencil.radius, pencil.width
    for th in pencil.angles:
        d, n = np.array([np.cos(th), np.sin(th)]), np.array([-np.sin(th), np.cos(th)])
        for rr in np.linspace(r0 + 2, r1 - 2, 5):
            on = np.rint(origin + (v + rr * d) / px).astype(int)
            off = np.rint(origin + (v + rr * d + (w / 2 + 1.0) * n) / px).astype(int)
            assert img[on[1], on[0]] < 60 and img[off[1], off[0]] > 200
    vv = np.rint(origin + v / px).astype(int)
    assert img[vv[1], vv[0]] == 255


@pytest.mark.parametrize("paper,orientation,size_mm", [
    ("a4", "landscape", (297.0, 210.0)),
    ("letter", "landscape", (279.4, 215.9)),
    ("a3", "portrait", (297.0, 420.0)),
])
def test_pdf_page_is_the_paper(tmp_path, paper, orientation, size_mm):
    out = tmp_path / "t.pdf"
    r = invoke("-o", out, "--paper", paper, "--orientation", orientation, "-q")
    assert r.exit_code == 0, r.output
    assert out.read_bytes().startswith(b"%PDF")
    w, h = media_box_mm(out)
    assert w == pytest.approx(size_mm[0], abs=0.01) and h == pytest.approx(size_mm[1], abs=0.01)


def test_options_reach_the_files(tmp_path):
    out = tmp_path / "t.pdf"
    r = invoke("-o", out, "--board-squares", "5x4", "--square", 30, "--marker", 22, "--dictionary", "DICT_4X4_50",
               "--spokes", 6, "--step-deg", 25, "--start-deg", -60, "--radius", 12, 70, "--width", 0.8, "-q")
    assert r.exit_code == 0, r.output
    board, pencil = read_board(tmp_path / "board.yaml"), read_pencil(tmp_path / "pencil.yaml")
    assert (board.squares, board.square, board.marker, board.dictionary) == ((5, 4), 30.0, 22.0, "DICT_4X4_50")
    assert np.degrees(pencil.angles) == pytest.approx([-60, -35, -10, 15, 40, 65])
    assert pencil.radius.tolist() == [12.0, 70.0] and pencil.width == 0.8
    assert pencil.vertex[0] > 5 * 30.0  # beside the board


def test_no_overwrite_without_force(tmp_path):
    out = tmp_path / "t.png"
    assert invoke("-o", out, "--dpi", 40, "-q").exit_code == 0
    before = out.read_bytes()
    r = invoke("-o", out, "--dpi", 50, "-q")
    assert r.exit_code == 1 and "already exists" in r.output and r.output.count("\n") == 1
    assert out.read_bytes() == before
    # the files beside it are protected too, before anything is written
    out2 = tmp_path / "other.pdf"
    (tmp_path / "board.yaml").write_text("mine")
    r = invoke("-o", out2, "-q")
    assert r.exit_code == 1 and "board.yaml" in r.output
    assert not out2.exists() and (tmp_path / "board.yaml").read_text() == "mine"
    assert invoke("-o", out, "--dpi", 50, "-q", "--force").exit_code == 0
    assert out.read_bytes() != before


def test_layout_that_does_not_fit_is_refused(tmp_path):
    r = invoke("-o", tmp_path / "t.pdf", "--square", 40, "--marker", 30, "-q")
    assert r.exit_code == 1 and "does not fit" in r.output
    assert list(tmp_path.iterdir()) == []
    r = invoke("-o", tmp_path / "t.pdf", "--radius", 2, 50, "--width", 2, "-q")
    assert r.exit_code == 1 and "overlap" in r.output


@pytest.mark.parametrize("args,message", [
    (["-o", "t.svg"], ".pdf or .png"),
    (["-o", "t.pdf", "--board-squares", "seven"], "NxM"),
    (["-o", "t.pdf", "--paper", "a5"], "a5"),
])
def test_usage_errors_exit_2(tmp_path, args, message):
    r = CliRunner().invoke(target, [a if a != "t.pdf" and a != "t.svg" else str(tmp_path / a) for a in args])
    assert r.exit_code == 2 and message in r.output


def test_bad_board_is_one_line_exit_1(tmp_path):
    r = invoke("-o", tmp_path / "t.pdf", "--dictionary", "DICT_NOPE")
    assert r.exit_code == 1 and "DICT_NOPE" in r.output and r.output.count("\n") == 1


def test_help_has_an_example():
    r = invoke("--help")
    assert r.exit_code == 0 and "Example" in r.output and "pencilcal target -o target.pdf" in r.output

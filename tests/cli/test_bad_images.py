"""Every command that reads images handles bad input the same way (DEVELOPERS.md):

- an unreadable or truncated image skips that frame with a one-line warning and, where
  the output has frames, a per-frame ok: false;
- an empty input folder, an image size that does not match the camera and a board with an
  unknown dictionary are one-line errors with exit code 1, and no output is written.
"""
from __future__ import annotations

import json
import shutil

import pytest
from click.testing import CliRunner

from pencilcal.cli.main import cli


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    d = tmp_path_factory.mktemp("bad")
    r = CliRunner().invoke(cli, ["simulate", str(d / "seq"), "--scenario", "tilt-sweep", "--frames", "4", "--seed", "2",
                                 "--size", "960x540", "--max-tilt", "40", "-q"])
    assert r.exit_code == 0, r.output
    return d / "seq"


def _copy(seq, tmp_path, truncate=None):
    imgs = tmp_path / "imgs"
    shutil.copytree(seq / "images", imgs)
    if truncate:
        data = (imgs / truncate).read_bytes()
        (imgs / truncate).write_bytes(data[: len(data) // 3])
    return imgs


def _commands(seq, images, out):
    cam, board, pencil = seq / "camera.json", seq / "board.yaml", seq / "pencil.yaml"
    return {
        "pnp": ["pnp", images, "--camera", cam, "--board", board, "-o", out],
        "lines": ["lines", images, "--camera", cam, "-o", out],
        "orient": ["orient", images, "--camera", cam, "--pencil", pencil, "-o", out],
        "validate": ["validate", images, "--camera", cam, "--board", board, "--pencil", pencil,
                     "--methods", "sqpnp", "--models", "exact", "-o", out],
    }


def _run(args):
    return CliRunner().invoke(cli, [str(a) for a in args] + ["-q"])


def _one_line_error(r, *words):
    assert r.exit_code == 1, r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert lines[-1].startswith("pencilcal: error:"), r.output
    assert "Traceback" not in r.output
    for w in words:
        assert w in lines[-1], lines[-1]


@pytest.mark.parametrize("cmd", ["pnp", "lines", "orient", "validate"])
def test_truncated_image_is_skipped(seq, tmp_path, cmd):
    images = _copy(seq, tmp_path, truncate="001.png")
    out = tmp_path / "out.json"
    r = _run(_commands(seq, images, out)[cmd])
    assert r.exit_code == 0, r.output
    assert "001.png" in r.output and "warning" in r.output
    frames = json.loads(out.read_text())["frames"]
    bad = [f for f in frames if f["image"] == "001.png"]
    assert len(bad) == 1 and bad[0]["ok"] is False and bad[0]["error"]


def test_calibrate_skips_truncated(seq, tmp_path):
    images = _copy(seq, tmp_path, truncate="001.png")
    r = _run(["calibrate", images, "--board", seq / "board.yaml", "-o", tmp_path / "c.json",
              "--report", tmp_path / "r.json", "--model", "pinhole"])
    # four tilt-sweep views are few; whether or not it calibrates, the truncated frame is a
    # warning, not a crash
    assert "001.png" in r.output and "Traceback" not in r.output


@pytest.mark.parametrize("cmd", ["pnp", "lines", "orient", "validate"])
def test_empty_folder(seq, tmp_path, cmd):
    (tmp_path / "empty").mkdir()
    out = tmp_path / "out.json"
    r = _run(_commands(seq, tmp_path / "empty", out)[cmd])
    _one_line_error(r, "no images")
    assert not out.exists()


@pytest.mark.parametrize("cmd", ["pnp", "lines", "orient", "validate"])
def test_size_mismatch(seq, tmp_path, cmd):
    import cv2

    images = tmp_path / "small"
    images.mkdir()
    for p in sorted((seq / "images").iterdir()):
        cv2.imwrite(str(images / p.name), cv2.resize(cv2.imread(str(p)), (320, 180)))
    out = tmp_path / "out.json"
    r = _run(_commands(seq, images, out)[cmd])
    _one_line_error(r, "320x180", "960x540")
    assert not out.exists()


@pytest.mark.parametrize("cmd", ["pnp", "validate", "calibrate"])
def test_unknown_dictionary(seq, tmp_path, cmd):
    board = tmp_path / "board.yaml"
    board.write_text((seq / "board.yaml").read_text().replace("DICT_5X5_100", "DICT_9X9_7"))
    out = tmp_path / "out.json"
    args = {"pnp": ["pnp", seq / "images", "--camera", seq / "camera.json", "--board", board, "-o", out],
            "validate": ["validate", seq / "images", "--camera", seq / "camera.json", "--board", board,
                         "--pencil", seq / "pencil.yaml", "-o", out],
            "calibrate": ["calibrate", seq / "images", "--board", board, "-o", out]}[cmd]
    r = _run(args)
    _one_line_error(r, "DICT_9X9_7")
    assert not out.exists()

"""--jsonl and --overlay: each frame's result as it is done, and the frames drawn."""
from __future__ import annotations

import json

import cv2
import pytest
from click.testing import CliRunner

from pencilcal.cli.main import cli
from pencilcal.toolkit.io.jsonl import JsonlWriter


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    d = tmp_path_factory.mktemp("live") / "sim"
    r = CliRunner().invoke(cli, ["simulate", str(d), "--scenario", "orbit", "--frames", "4", "--size", "960x540",
                                 "-q"])
    assert r.exit_code == 0, r.output
    return d


@pytest.mark.parametrize("cmd", ["lines", "pnp"])
def test_jsonl_lines_are_the_frames_records_and_the_overlay_has_every_frame(sim, tmp_path, cmd):
    extra = ["--board", str(sim / "board.yaml")] if cmd == "pnp" else []
    out, stream, video = tmp_path / "o.json", tmp_path / "s.jsonl", tmp_path / "o.avi"
    r = CliRunner().invoke(cli, [cmd, str(sim / "images"), "--camera", str(sim / "camera.json"), *extra,
                                 "-o", str(out), "--jsonl", str(stream), "--overlay", str(video), "-q"])
    assert r.exit_code == 0, r.output
    lines = [json.loads(x) for x in stream.read_text().splitlines()]
    frames = json.loads(out.read_text())["frames"]
    assert [x["image"] for x in lines] == [f["image"] for f in frames] == [f"{i:03d}.png" for i in range(4)]
    assert lines[1] == frames[1]
    cap = cv2.VideoCapture(str(video))
    assert cap.get(cv2.CAP_PROP_FRAME_COUNT) == 4 and cap.get(cv2.CAP_PROP_FRAME_WIDTH) == 960


def test_jsonl_to_stdout(sim, tmp_path):
    r = CliRunner().invoke(cli, ["lines", str(sim / "images" / "000.png"), "--camera", str(sim / "camera.json"),
                                 "-o", str(tmp_path / "o.json"), "--jsonl", "-", "-q"])
    assert r.exit_code == 0
    assert json.loads(r.output.splitlines()[0])["image"] == "000.png"


def test_a_reader_that_goes_away_ends_the_stream_not_the_run():
    class Closed:
        def write(self, s):
            raise BrokenPipeError

        def flush(self):
            pass

    w = JsonlWriter(Closed())
    w.write({"a": 1})
    w.write({"a": 2})
    assert w.lines == 0 and w.stream is None

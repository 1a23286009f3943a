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


def test_orient_streams_each_frame_and_draws_the_overlay(sim, tmp_path):
    out, stream, folder = tmp_path / "o.json", tmp_path / "s.jsonl", tmp_path / "drawn"
    r = CliRunner().invoke(cli, ["orient", str(sim / "images"), "--camera", str(sim / "camera.json"), "--pencil",
                                 str(sim / "pencil.yaml"), "-o", str(out), "--jsonl", str(stream),
                                 "--overlay", str(folder) + "/", "-q"])
    assert r.exit_code == 0, r.output
    lines = [json.loads(x) for x in stream.read_text().splitlines()]
    frames = json.loads(out.read_text())["frames"]
    assert [x["image"] for x in lines] == [f["image"] for f in frames]
    for a, b in zip(lines, frames):
        assert a["ok"] == b["ok"] and a["tilt_deg"] == b["tilt_deg"] and a["tilt_sigma_deg"] == b["tilt_sigma_deg"]
    drawn = sorted(p.name for p in folder.iterdir())
    assert drawn == [f"{i:03d}.png" for i in range(4)]
    img, raw = cv2.imread(str(folder / "001.png")), cv2.imread(str(sim / "images" / "001.png"))
    assert img.shape == raw.shape and (img != raw).any(axis=2).mean() > 0.001  # something is drawn


def test_orient_overlay_needs_frames(sim, tmp_path):
    lines = tmp_path / "lines.json"
    assert CliRunner().invoke(cli, ["lines", str(sim / "images" / "000.png"), "--camera", str(sim / "camera.json"),
                                    "--bars", "-o", str(lines), "-q"]).exit_code == 0
    r = CliRunner().invoke(cli, ["orient", "--lines", str(lines), "--camera", str(sim / "camera.json"), "--pencil",
                                 str(sim / "pencil.yaml"), "-o", str(tmp_path / "o.json"), "--overlay",
                                 str(tmp_path / "o.avi"), "--jsonl", "-", "-q"])
    assert r.exit_code == 2 and "--overlay" in r.output


def test_orient_jsonl_from_a_lines_file(sim, tmp_path):
    lines = tmp_path / "lines.json"
    assert CliRunner().invoke(cli, ["lines", str(sim / "images"), "--camera", str(sim / "camera.json"),
                                    "--bars", "-o", str(lines), "-q"]).exit_code == 0
    r = CliRunner().invoke(cli, ["orient", "--lines", str(lines), "--camera", str(sim / "camera.json"), "--pencil",
                                 str(sim / "pencil.yaml"), "-o", str(tmp_path / "o.json"), "--jsonl", "-", "-q"])
    assert r.exit_code == 0, r.output
    recs = [json.loads(x) for x in r.output.splitlines() if x.startswith("{")]
    assert [x["image"] for x in recs] == [f"{i:03d}.png" for i in range(4)] and all(x["ok"] for x in recs)
    assert all(len(x["spokes"]) > 0 for x in recs)

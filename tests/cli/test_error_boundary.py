"""The command line's one error boundary: one line for every failure, interrupts that stop
workers at once and leave nothing half-written."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.cli.main import cli
from pencilcal.toolkit.camera.formats import write_camera
from pencilcal.toolkit.camera.model import Camera
from tests.faults import wait_for


@pytest.fixture()
def frames(tmp_path):
    cam = Camera("pinhole", 320, 240, [[300.0, 0, 159.5], [0, 300.0, 119.5], [0, 0, 1]], [])
    write_camera(tmp_path / "camera.json", cam)
    d = tmp_path / "frames"
    d.mkdir()
    rng = np.random.default_rng(0)
    for i in range(60):
        assert cv2.imwrite(str(d / f"{i:03d}.png"), rng.integers(0, 255, (240, 320), np.uint8))
    return tmp_path


def test_an_unexpected_exception_is_one_line_naming_command_and_input(frames, monkeypatch):
    import pencilcal.cli.lines as lines_cli

    def boom(*a, **k):
        raise ValueError("boom\nsecond line")

    monkeypatch.setattr(lines_cli, "read_camera", boom)
    args = ["lines", str(frames / "frames"), "--camera", str(frames / "camera.json"), "-o", str(frames / "o.json")]
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 1
    out = r.output.strip().splitlines()
    assert len(out) == 1, r.output
    assert "internal error in `cli lines`" in out[0] or "internal error in `pencilcal lines`" in out[0]
    assert str(frames / "frames") in out[0] and "ValueError: boom" in out[0] and "please report" in out[0]
    # --debug: the traceback instead
    r = CliRunner().invoke(cli, ["--debug", *args])
    assert isinstance(r.exception, ValueError)


def _pencilcal(*args, **kw):
    return subprocess.Popen([sys.executable, "-c", "from pencilcal.cli.main import main; main()", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True, **kw)


@pytest.mark.slow
def test_ctrl_c_with_workers_stops_within_two_seconds(frames):
    out = frames / "o.json"
    p = _pencilcal("lines", str(frames / "frames"), "--camera", str(frames / "camera.json"), "-o", str(out),
                   "--workers", "2", "--detector", "lsd")
    # the pool is up once a worker process exists
    assert wait_for(lambda: len(subprocess.run(["pgrep", "-g", str(p.pid)], capture_output=True).stdout.split()) > 2,
                     60), "no worker started"
    time.sleep(0.5)
    t0 = time.monotonic()
    os.killpg(p.pid, signal.SIGINT)  # as the terminal sends it: to the whole process group
    try:
        _, err = p.communicate(timeout=10)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
    assert time.monotonic() - t0 < 2.0
    assert p.returncode == 130 and "interrupted" in err and "Traceback" not in err
    assert not out.exists() and not [f for f in os.listdir(frames) if f.startswith(".o.")]
    assert wait_for(lambda: subprocess.run(["pgrep", "-g", str(p.pid)], capture_output=True).stdout == b"", 5), \
        "worker processes left behind"


@pytest.mark.slow
def test_sigterm_during_simulate_leaves_no_partial_folder(tmp_path):
    out = tmp_path / "sim"
    p = _pencilcal("simulate", str(out), "--scenario", "orbit", "--frames", "200", "--size", "640x360", "-q")
    # the staging folder exists once rendering has begun
    assert wait_for(lambda: any(f.endswith(".partial") for f in os.listdir(tmp_path)), 60)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=20)
    assert p.returncode == 143 and "terminated" in err and "Traceback" not in err
    assert os.listdir(tmp_path) == []


def test_nan_and_inf_options_are_usage_errors(frames, tmp_path):
    cam = str(frames / "camera.json")
    for args in (["lines", str(frames / "frames"), "--camera", cam, "--min-length", "nan"],
                 ["orient", str(frames / "frames"), "--camera", cam, "--pencil", "p.yaml", "--endpoint-sigma", "inf"],
                 ["simulate", str(tmp_path / "s"), "--scenario", "orbit", "--blur", "inf"],
                 ["simulate", str(tmp_path / "s"), "--scenario", "orbit", "--noise", "nan"]):
        r = CliRunner().invoke(cli, [*args, "-o", str(tmp_path / "o.json")] if args[0] != "simulate" else args)
        assert r.exit_code == 2 and "finite" in r.output, (args, r.output)
    assert not (tmp_path / "s").exists()


def test_a_python_warning_is_one_pencilcal_line_once(frames, monkeypatch):
    """A floating-point warning that escapes the checks is a flaw to report: one line in
    pencilcal's words, once per place, never Python's two lines with the source."""
    import pencilcal.cli.lines as lines_cli

    real = lines_cli.read_camera

    def overflowing(*a, **k):
        for _ in range(3):
            np.float64(1e308) * 10.0  # overflow, three times from one place
        return real(*a, **k)

    monkeypatch.setattr(lines_cli, "read_camera", overflowing)
    args = ["lines", str(frames / "frames" / "000.png"), "--camera", str(frames / "camera.json"), "-o",
            str(frames / "o.json"), "-q"]
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0, r.output
    said = [ln for ln in r.output.splitlines() if "Warning" in ln]
    assert len(said) == 1 and said[0].startswith("pencilcal: warning: RuntimeWarning: overflow encountered in "
                                                 "scalar multiply (test_error_boundary.py:"), r.output
    assert said[0].endswith("; please report this)")


def _python(code):
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)


def test_a_signal_outside_a_command_ends_the_same_way():
    """While click parses or a command's module is imported (outside `run`), and while Python
    imports the command line (cli/entry.py's first handlers): one line, 128 + the signal."""
    r = _python("import signal, pencilcal.cli.main as m\n"
                "from pencilcal.cli.common import Stopped\n"
                "def parsing(**kw):\n    raise Stopped(signal.SIGTERM)\n"
                "m.cli = parsing\nm.main()")
    assert (r.returncode, r.stderr) == (143, "pencilcal: error: terminated (SIGTERM)\n")
    r = _python("import os, signal, time, pencilcal.cli.entry as e\n"
                "signal.signal(signal.SIGINT, e._before_any_work)\n"
                "os.kill(os.getpid(), signal.SIGINT)\ntime.sleep(5)")
    assert (r.returncode, r.stderr) == (130, "pencilcal: error: interrupted\n")


def test_a_stop_names_what_was_already_in_place(frames, monkeypatch):
    """Ctrl-C after the overlay video is in place but before the output: 130, the overlay
    named, the output absent."""
    import pencilcal.cli.lines as lines_cli

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(lines_cli, "write_lines", interrupted)
    ov, out = frames / "ov.avi", frames / "o.json"
    r = CliRunner().invoke(cli, ["lines", str(frames / "frames" / "000.png"), "--camera", str(frames / "camera.json"),
                                 "--overlay", str(ov), "-o", str(out), "-q"])
    assert r.exit_code == 130 and r.output == f"pencilcal: error: interrupted (SIGINT); already written: {ov}\n"
    assert ov.is_file() and not out.exists()

"""The bad-input corpus (tests/corpus/cases.yaml): every case ends in a clear message and
the documented exit code; nothing already on disk is overwritten by a failing run, and a
failing run leaves nothing that looks like a result. No case prints a Python warning or a
traceback.

Most cases run in this process (click's runner). The whole-system ones (``process: true``:
signals, a full or read-only file system, concurrent runs, hostile folders, a live source
that goes silent) run the installed `pencilcal` command in a subprocess as a user runs it,
and assert its exit status, every line it says on stderr and every file left in its
folder, byte for byte (`test_process_case`)."""
from __future__ import annotations

import importlib.util
import json
import os
import re
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

from pencilcal.cli.main import cli
from tests import faults

CORPUS = Path(__file__).resolve().parents[1] / "corpus"
ALL_CASES = yaml.safe_load((CORPUS / "cases.yaml").read_text())
CASES = [c for c in ALL_CASES if not c.get("process")]
PROCESS_CASES = [c for c in ALL_CASES if c.get("process")]
# a Python warning as Python prints it, or as pencilcal's boundary says one it caught
PYTHON_WARNING = re.compile(r"\b[A-Z]\w*Warning\b")


def _make_corpus():
    """tests/corpus/make_corpus.py, whose generators make the inputs too big (or too many)
    to keep in the repository."""
    spec = importlib.util.spec_from_file_location("make_corpus", CORPUS / "make_corpus.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _args(case, out):
    """The case's command line: corpus files and generated inputs (made in out's folder)
    by their paths."""
    made = _make_corpus().generate(case["generate"], out.parent) if case.get("generate") else {}
    args = [str(made[a]) if a in made else str(CORPUS / a) if (CORPUS / a).exists() and not a.startswith("-") else a
            for a in case["args"]]
    return args + ["-o", str(out), "-q"]


def _lines(output):
    return [ln for ln in output.splitlines() if ln.strip()]


@pytest.mark.parametrize("case", CASES, ids=[c["name"] for c in CASES])
def test_case(case, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # where a rogue .cameramodel would write its marker
    out = tmp_path / "out.json"
    r = CliRunner().invoke(cli, _args(case, out))
    assert r.exit_code == case["exit"], r.output
    assert "Traceback" not in r.output and not PYTHON_WARNING.search(r.output), r.output
    lines = _lines(r.output)
    for word in case.get("warnings", []):
        assert any("warning" in ln and word in ln for ln in lines), (word, r.output)
    if case["exit"] == 1:
        assert lines and lines[-1].startswith("pencilcal: error:"), r.output
        for word in case["message"]:
            assert word in lines[-1], (word, lines[-1])
        assert not out.exists()
    else:
        frames = json.loads(out.read_text())["frames"]
        for name in case.get("not_ok", []):
            f = [fr for fr in frames if fr["image"] == name]
            assert len(f) == 1 and f[0]["ok"] is False and f[0]["error"], name
    checks = case.get("checks", [])
    if "not_executed" in checks:
        assert not (tmp_path / "PWNED_BY_CAMERAMODEL").exists()
    if "frontal_not_detectable" in checks:
        f = json.loads(out.read_text())["frames"][0]
        assert f["ok"] is True and f["detectable"] is False and f["tilt_deg"] < 10
    if "clean_ok" in checks:  # the frame without clutter beside the refused ones: estimated, unflagged
        f = [fr for fr in json.loads(out.read_text())["frames"] if fr["image"] == "clean.png"][0]
        assert f["ok"] is True and f["lines_used"] == 8 and not f["normal_ambiguous"], f
    if "first_segment_rejected" in checks:
        f = json.loads(out.read_text())["frames"][0]
        assert f["ok"] is True and f["spokes"][0] == -1 and f["lines_used"] == 7, f


@pytest.mark.parametrize("case", [c for c in CASES if c["exit"] == 1], ids=lambda c: c["name"])
def test_failing_run_keeps_what_is_on_disk(case, tmp_path, monkeypatch):
    """Even with --force, a run that fails leaves an existing output as it was."""
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out.json"
    out.write_text("keep me\n")
    r = CliRunner().invoke(cli, _args(case, out) + ["--force"])
    assert r.exit_code == 1, r.output
    assert out.read_text() == "keep me\n"


def test_existing_output_needs_force(tmp_path):
    out = tmp_path / "out.json"
    out.write_text("keep me\n")
    r = CliRunner().invoke(cli, ["lines", str(CORPUS / "frames"), "--camera", str(CORPUS / "camera.json"), "-o", str(out), "-q"])
    assert r.exit_code == 1 and "--force" in r.output and out.read_text() == "keep me\n"


def test_calibrate_failure_leaves_no_partial_outputs(tmp_path):
    """Too few views: neither the camera, nor the report, nor the corner cache appears."""
    outs = [tmp_path / "cam.yaml", tmp_path / "calib.json", tmp_path / "corners.vnl"]
    r = CliRunner().invoke(cli, ["calibrate", str(CORPUS / "frames"), "--board", str(CORPUS / "board.yaml"),
                                 "-o", str(outs[0]), "--report", str(outs[1]), "--corners", str(outs[2]), "-q"])
    assert r.exit_code == 1 and "Traceback" not in r.output
    assert not any(p.exists() for p in outs)


# ---------------------------------------------------------------- the installed command, in a subprocess


def _default_signals():
    """In the child: the stop signals as a terminal's foreground job has them, whatever this
    test run inherited (nohup ignores SIGHUP, a background job SIGINT; the command keeps an
    ignored signal ignored)."""
    for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(s, signal.SIG_DFL)


class _Process:
    """One run of the installed command: stdout read line by line as it comes (the --jsonl
    records that say how far it got), stderr to a file."""

    def __init__(self, argv, cwd, err_path):
        self.err_path = err_path
        self.p = subprocess.Popen(argv, cwd=cwd, stdout=subprocess.PIPE, stderr=open(err_path, "wb"),
                                  start_new_session=True,  # its own process group, as a terminal's job
                                  preexec_fn=_default_signals)
        self.lines, self._cond = [], threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.p.stdout:
            with self._cond:
                self.lines.append(line)
                self._cond.notify_all()
        with self._cond:
            self.lines.append(None)  # the end
            self._cond.notify_all()

    def wait_for_records(self, k, timeout=120):
        with self._cond:
            ok = self._cond.wait_for(lambda: len([x for x in self.lines if x]) >= k or None in self.lines, timeout)
        assert ok and len([x for x in self.lines if x]) >= k, f"fewer than {k} records: {self.stderr()}"

    def finish(self, timeout=180):
        try:
            self.p.wait(timeout=timeout)
        finally:
            if self.p.poll() is None:
                os.killpg(self.p.pid, signal.SIGKILL)
        # its workers end with it: nothing of the process group is left (a zombie reaped at once aside)
        assert faults.wait_for(lambda: subprocess.run(["pgrep", "-g", str(self.p.pid)], capture_output=True).stdout == b"", 5), \
            "processes of the run left behind"
        return self.p.returncode

    def stderr(self):
        return Path(self.err_path).read_bytes().decode("utf-8", "backslashreplace")


def _workers_of(pid):
    """The worker processes of the command `pid` (its children running multiprocessing)."""
    out = subprocess.run(["pgrep", "-P", str(pid), "-f", "multiprocessing.spawn"], capture_output=True, text=True)
    return [int(x) for x in out.stdout.split()]


def _during(step, proc, run, names):
    """What happens to the run while it works (`during:` of a case): after `records` --jsonl
    records (or once a path exists), a signal to its process group as a terminal sends it,
    a worker killed, its output folder removed, input files changed."""
    if not step:
        return
    if "records" in step:
        proc.wait_for_records(step["records"])
    if "exists" in step:
        assert faults.wait_for(lambda: any(run.glob(step["exists"])), 120), step["exists"]
    for rel in step.get("remove", []):
        import shutil

        shutil.rmtree(run / rel)
    for path in step.get("delete", []):
        Path(_substitute(path, names)).unlink()
    for path in step.get("truncate", []):
        path = Path(_substitute(path, names))
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 3])
    if "kill_worker" in step:
        assert faults.wait_for(lambda: _workers_of(proc.p.pid), 60), "no worker started"
        os.kill(_workers_of(proc.p.pid)[0], getattr(signal, step["kill_worker"]))
    for name in step.get("signals", []):
        os.killpg(proc.p.pid, getattr(signal, name))
        time.sleep(0.02)


def _substitute(value, names):
    """A case's text with {corpus}, {inputs}, {run}, {url}, {e9} replaced."""
    for k, v in names.items():
        value = value.replace("{" + k + "}", str(v))
    return value


def _line_matches(expected, line, names):
    """`expected`: the exact line ({corpus} and the like replaced), or 're:' and a regex."""
    if expected.startswith("re:"):
        return re.fullmatch(_substitute(expected[3:], {k: re.escape(str(v)) for k, v in names.items()}), line)
    return _substitute(expected, names) == line


def _check_file(rel, data, want):
    """One file left behind against what the case says: its exact text, or {frames: N (or
    min_frames: N), not_ok: {image: error}} of a JSON output, or {lines: N} (or lines_whole:
    true) of a JSON Lines stream."""
    if isinstance(want, str):
        assert data == want.encode(), (rel, data[:200])
        return
    if "lines" in want or "lines_whole" in want:
        records = [json.loads(x) for x in data.decode().splitlines()]  # each line whole
        assert data.endswith(b"\n") and len(records) == want.get("lines", len(records)), (rel, len(records))
        return
    doc = json.loads(data)
    frames = doc["frames"]
    if "min_frames" in want:
        assert len(frames) >= want["min_frames"], (rel, len(frames))
    else:
        assert len(frames) == want["frames"], (rel, len(frames))
    errors = {f["image"]: f.get("error") for f in frames if not f["ok"]}
    assert errors == want.get("not_ok", {}), (rel, errors)


def _snapshot(run):
    """{path relative to the run folder: bytes} of every file left there, hidden ones too."""
    return {str(p.relative_to(run)): p.read_bytes() for p in sorted(run.rglob("*"))
            if p.is_file() and not p.is_symlink()}


@pytest.mark.slow
@pytest.mark.parametrize("case", PROCESS_CASES, ids=[c["name"] for c in PROCESS_CASES])
def test_process_case(case, tmp_path):
    import contextlib

    inputs, run = tmp_path / "inputs", tmp_path / "run"
    inputs.mkdir()
    run.mkdir()
    made = _make_corpus().generate(case.get("generate", {}), inputs)
    # {e9}: the byte 0xE9 alone, not UTF-8 (a Latin-1 e-acute), as Python holds it in a file name
    names = {"corpus": CORPUS, "inputs": inputs, "run": run, "e9": os.fsdecode(b"\xe9")}
    with contextlib.ExitStack() as stack:
        mounts = case.get("mount") or {}
        for rel, spec in mounts.items():
            stack.enter_context(faults.tmpfs(run / rel, spec["size"], readonly=spec.get("readonly", False)))
        for rel, text in (case.get("before") or {}).items():
            (run / rel).parent.mkdir(parents=True, exist_ok=True)
            (run / rel).write_text(text)
        for rel, spec in mounts.items():
            if spec.get("full"):
                faults.fill(run / rel)
        if case.get("server") == "stalled_mjpeg":
            import cv2

            jpegs = [cv2.imencode(".jpg", cv2.imread(str(CORPUS / "frames" / f"00{i % 2}.png")))[1].tobytes()
                     for i in range(5)]
            names["url"] = stack.enter_context(faults.stalled_mjpeg_server(jpegs))
        args = [str(made[a]) if a in made else str(CORPUS / a) if (CORPUS / a).exists() else _substitute(a, names)
                for a in case["args"]]
        prefix = faults.without_privileges() if case.get("unprivileged") else []
        procs = [_Process(prefix + faults.pencilcal_command() + args, run, tmp_path / f"stderr{i}")
                 for i in range(case.get("runs", 1))]
        _during(case.get("during"), procs[0], run, names)
        exits = sorted(p.finish() for p in procs)
        left = _snapshot(run)
        for rel in mounts:  # the filler of a full disk is the test's, not the run's
            left.pop(f"{rel}/filler", None)
    want_exit = case["exit"] if isinstance(case["exit"], list) else [case["exit"]]
    assert exits == sorted(want_exit), [p.stderr() for p in procs]
    said = [p.stderr() for p in procs]
    for text in said:
        assert "Traceback" not in text and not PYTHON_WARNING.search(text), text
    # the run that failed, where several ran at once
    lines = [ln for ln in max(procs, key=lambda p: p.p.returncode).stderr().splitlines() if ln.strip()]
    expected = case.get("stderr", [])
    assert len(lines) == len(expected) and all(_line_matches(e, ln, names) for e, ln in zip(expected, lines)), \
        "\n".join(lines)
    after = {_substitute(rel, names): want for rel, want in (case.get("after") or {}).items()}
    assert sorted(left) == sorted(after), sorted(left)
    for rel, want in after.items():
        _check_file(rel, left[rel], want)

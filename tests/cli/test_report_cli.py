"""`pencilcal report`: HTML and PDF from a validation.json, exit codes and messages, --force,
--quiet, and the page as headless Chromium renders it."""
from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.cli.report import report
from tests.validation.report.browser import CHROMIUM, first_screen, run
from tests.validation.report.helpers import assert_self_contained, decoded_images, pdf_pages, summary_rows, synthetic


def invoke(*args):
    return CliRunner().invoke(report, [str(a) for a in args])


@pytest.fixture(scope="module")
def vjson(tmp_path_factory):
    d = tmp_path_factory.mktemp("report_cli")
    data = synthetic(d, sfm=True, calibration=True)
    p = d / "validation.json"
    p.write_text(json.dumps(data))
    return p


@pytest.fixture(scope="module")
def page(vjson):
    out = vjson.parent / "report.html"
    r = invoke(vjson, "-o", out, "--samples", "2", "--title", "Bench 3 <check>")
    assert r.exit_code == 0, r.output
    return out


def test_html_report(page, vjson):
    html = page.read_text(encoding="utf-8")
    assert_self_contained(html)
    assert "<title>Bench 3 &lt;check&gt;</title>" in html
    data = json.loads(vjson.read_text())
    assert [r.rstrip(" †") for r in summary_rows(html)] == list(data["summary"])
    assert len(decoded_images(html)) == 3 + 2 + 1  # plots (error, sigmas, NEES), overlays, calibration
    assert f"pencilcal report {vjson} -o {page} --samples 2 --title" in html


def test_pdf_report_quiet(vjson, tmp_path):
    out = tmp_path / "report.pdf"
    r = invoke(vjson, "-o", out, "--samples", "1", "-q")
    assert r.exit_code == 0, r.output
    assert pdf_pages(out) > 1 and r.stderr == ""


def test_never_overwrites_without_force(vjson, tmp_path):
    out = tmp_path / "r.html"
    out.write_text("old")
    r = invoke(vjson, "-o", out, "--samples", "0")
    assert r.exit_code == 1
    assert r.stderr == f"pencilcal: error: {out}: already exists; pass --force to overwrite it\n"
    assert out.read_text() == "old"
    r = invoke(vjson, "-o", out, "--samples", "0", "--force")
    assert r.exit_code == 0 and out.read_text().startswith("<!DOCTYPE html>")
    assert r.stderr.strip().endswith(f"-> {out}") and len(r.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("content, message", [
    ("{oops", "not valid JSON"),
    (json.dumps({"frames": [], "hello": 1}), "not a validation file"),
    (json.dumps([1, 2, 3]), "not a validation file"),
    ("\x89PNG\r\n\x1a\n\x00\x00", "validation file"),
])
def test_bad_input_is_one_line_and_exit_1(tmp_path, content, message):
    bad = tmp_path / "v.json"
    bad.write_bytes(content.encode("latin-1"))
    out = tmp_path / "r.html"
    r = invoke(bad, "-o", out)
    assert r.exit_code == 1, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"pencilcal: error: {bad}") and message in lines[0]
    assert "Traceback" not in r.output and not out.exists()


def test_missing_files_and_usage_errors(vjson, tmp_path):
    r = invoke(tmp_path / "none.json", "-o", tmp_path / "r.html")
    assert r.exit_code == 1 and "not found" in r.stderr
    r = invoke(vjson, "-o", tmp_path / "r.html", "--sensitivity", tmp_path / "none.json")
    assert r.exit_code == 1 and "none.json: sensitivity file not found" in r.stderr
    r = invoke(vjson, "-o", tmp_path / "r.docx")
    assert r.exit_code == 2 and ".html or .pdf" in r.output
    r = invoke(vjson, "-o", tmp_path / "r.html", "--samples", "-1")
    assert r.exit_code == 2
    r = invoke(vjson)
    assert r.exit_code == 2
    r = invoke(vjson, "-o", tmp_path / "nodir" / "r.html")
    assert r.exit_code == 1 and "does not exist" in r.stderr


def test_help_has_an_example():
    r = invoke("--help")
    assert r.exit_code == 0
    assert "Example" in r.output and "pencilcal report validation.json -o report.html" in r.output
    for opt in ("--samples", "--title", "--sensitivity", "--force", "--quiet"):
        assert opt in r.output


# ---------------------------------------------------------------------------------- in a browser


@pytest.mark.skipif(not CHROMIUM.exists(), reason="Chromium not installed (apt-get install chromium)")
def test_renders_in_headless_chromium(page, tmp_path):
    dom = run(["--virtual-time-budget=3000", "--dump-dom", page.resolve().as_uri()], tmp_path)
    assert dom.returncode == 0, dom.stderr[-2000:]
    assert "2. Summary of every method" in dom.stdout
    # every figure of the page is in the rendered DOM
    assert dom.stdout.count("<img") == page.read_text().count("<img") >= 5 and "orient:exact" in dom.stdout and "pnp:ippe" in dom.stdout
    # the first screen (1280x900) opens with the verdict: the headline figure with its unit
    verdict, problems = first_screen(page, tmp_path, tmp_path / "first-screen.png")
    assert problems == []
    assert re.match(r"FAIL ?plane normal .* median error \d[\d.]* deg", verdict), verdict
    shot = tmp_path / "shot.png"
    r = run(["--window-size=1280,2400", f"--screenshot={shot}", page.resolve().as_uri()], tmp_path)
    assert r.returncode == 0 and shot.is_file(), r.stderr[-2000:]
    from matplotlib.image import imread

    img = imread(shot)[..., :3]
    assert img.shape[:2] == (2400, 1280)
    grey = img.mean(axis=2)
    # not blank: text, tables and plots cover a good part of the page, in more than one colour
    assert (grey < 0.6).mean() > 0.01 and float(grey.std()) > 0.08
    assert len(np.unique((img[::8, ::8] * 15).round().reshape(-1, 3), axis=0)) > 20
    shutil.rmtree(tmp_path / "chromium-profile", ignore_errors=True)

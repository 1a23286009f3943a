"""validation.report.build: every optional part missing or present renders, self-contained HTML,
decodable images, a multi-page PDF, atomic writes, one-line errors on malformed input."""
from __future__ import annotations

import hashlib

import pytest

from pencilcal.toolkit.errors import InputError
from pencilcal.validation import report as rp
from tests.validation.report.helpers import (
    MODELS,
    assert_self_contained,
    decoded_images,
    pdf_pages,
    summary_rows,
    synthetic,
)

BRANCHES = [
    dict(truth=True, sfm=True, calibration=True, failing=True),
    dict(truth=True, sfm=False, calibration=False, failing=False),
    dict(truth=False, sfm=False, calibration=True, failing=True, grid=True),
    dict(truth=False, sfm=True, calibration=False, failing=False, images=False),
]


@pytest.mark.parametrize("kw", BRANCHES, ids=["all", "bare", "pnp-grid-calib", "pnp-sfm-no-images"])
def test_every_branch_renders_self_contained_with_every_method(tmp_path, kw):
    data = synthetic(tmp_path, **kw)
    samples = 2 if kw is BRANCHES[0] else 1
    page = rp.render_html(rp.build_report(data, samples=samples))
    assert_self_contained(page)
    rows = summary_rows(page)
    expected = [k for k in data["summary"]]
    assert [r.rstrip(" †") for r in rows] == [rp.method_label(k) for k in expected]
    imgs = decoded_images(page)
    n_overlays = samples if kw.get("images", True) else 0
    assert len(imgs) == 3 + n_overlays + (1 if kw["calibration"] else 0)  # plots: error, sigmas, NEES
    for sec in ("verdict", "summary", "plots", "frames", "overlays", "calibration", "sfm", "sensitivity",
                "reproducibility"):
        assert f'id="{sec}"' in page
    if not kw.get("images", True):
        assert "image not found at" in page
    assert ("Not in this file: run `pencilcal validate --sfm`" in page) != kw["sfm"]
    assert ("Not in this file: validate was given no calibration report" in page) != kw["calibration"]
    if kw["calibration"]:
        assert "Rejected views and corners" in page and "outlier corner" in page


def test_no_estimate_anywhere_still_renders(tmp_path):
    data = synthetic(tmp_path)
    for f in data["frames"]:
        f.update(ok=False, error="no pencil lines in this frame", errors={})
        f.pop("reference_tilt_deg", None)
        f["orient"] = {m: {"ok": False, "error": "no pencil lines in this frame"} for m in MODELS}
    data["summary"] = {k: {"frames": 0} for k in data["summary"]}
    rep = rp.build_report(data, samples=1)
    page = rp.render_html(rep)
    assert_self_contained(page)
    assert "No frame gave an angular-variation estimate" in page
    assert "No method produced an error against the reference" in page
    assert "0 / 6" in page


def test_minimal_file_with_only_frames_and_summary(tmp_path):
    data = {"frames": [{"image": "a.png", "ok": True, "errors": {"orient:exact": {"normal_deg": 0.2,
                                                                                  "normal_closer_deg": 0.2}}}],
            "summary": {"orient:exact": {"frames": 1, "normal": {"median": 0.2}, "normal_closer": {"median": 0.2}}}}
    page = rp.render_html(rp.build_report(data, samples=1))
    assert_self_contained(page)
    assert "orient:exact" in page and "0.200" in page
    assert "image not found at None" in page


def test_pdf_has_several_pages(tmp_path):
    data = synthetic(tmp_path, sfm=True, calibration=True)
    out = tmp_path / "r.pdf"
    rp.write_report(out, data, samples=1)
    assert out.read_bytes()[:5] == b"%PDF-" and pdf_pages(out) > 1


def test_write_never_overwrites_and_is_atomic(tmp_path):
    data = synthetic(tmp_path)
    out = tmp_path / "r.html"
    out.write_text("keep me")
    with pytest.raises(InputError, match="already exists"):
        rp.write_report(out, data, samples=0)
    assert out.read_text() == "keep me"
    rp.write_report(out, data, samples=0, force=True)
    assert out.read_text().startswith("<!DOCTYPE html>")
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".r.")]  # no temporary left over
    with pytest.raises(InputError, match="unknown report format"):
        rp.write_report(tmp_path / "r.docx", data)


def test_malformed_parts_are_one_input_error(tmp_path):
    data = synthetic(tmp_path)
    data["frames"][0]["errors"]["orient:exact"] = "not a record"
    data["frames"][1]["crlb"] = [1, 2]
    data["summary"]["orient:exact"]["normal_coverage"] = {"fraction": "x"}
    page = rp.render_html(rp.build_report(data, samples=0))  # odd values are shown as missing, not fatal
    assert_self_contained(page)
    data["summary"]["pnp:ippe"] = 3
    with pytest.raises(InputError, match=r"summary\['pnp:ippe'\] is not an object"):
        rp.write_report(tmp_path / "x.html", data, source="v.json")


# ---------------------------------------------------------------------------------- a real run


@pytest.fixture(scope="module")
def real_run(tmp_path_factory):
    """A real `pencilcal simulate` + `pencilcal validate` (4 small frames, no SfM)."""
    from click.testing import CliRunner

    from pencilcal.cli.simulate import simulate
    from pencilcal.cli.validate import validate

    d = tmp_path_factory.mktemp("report_real")
    r = CliRunner().invoke(simulate, [str(d / "sim"), "--scenario", "orbit", "--frames", "4", "--seed", "3",
                                      "--size", "640x360"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(validate, [str(d / "sim"), "-o", str(d / "v.json"), "-q"])
    assert r.exit_code == 0, r.output
    return d, d / "v.json"


def test_real_validation_run_html_and_pdf(real_run):
    d, vjson = real_run
    data = rp.load_validation(vjson)
    rep = rp.write_report(d / "r.html", data, samples=2, source=vjson, report_command="pencilcal report v.json")
    page = (d / "r.html").read_text(encoding="utf-8")
    assert_self_contained(page)
    assert [r.rstrip(" †") for r in summary_rows(page)] == [rp.method_label(k) for k in rp.method_keys(data)]
    assert {"orient:exact", "orient:general", "orient:aligned", "pnp:sqpnp", "pnp:ippe", "pnp:iterative",
            "pnp:epnp", "pnp:colmap"} <= set(rp.method_keys(data))
    assert len(decoded_images(page)) == 3 + 2
    lead = next(b for b in rep.sections[0].blocks if getattr(b, "kind", None) == "lead")
    assert "ground-truth poses (truth.json)" in lead.text
    assert hashlib.sha256(vjson.read_bytes()).hexdigest() in page  # the validation file's own hash
    assert "pencilcal report v.json" in page
    rp.write_report(d / "r.pdf", data, samples=1, source=vjson)
    assert pdf_pages(d / "r.pdf") > 1

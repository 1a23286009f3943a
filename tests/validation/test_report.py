"""validation.report: content computed from the data, every optional part missing or present,
self-contained HTML, decodable images, a multi-page PDF, one-line errors on bad input."""
from __future__ import annotations

import base64
import hashlib
import io
import json
import re

import numpy as np
import pytest

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import to_jsonable
from pencilcal.toolkit.geometry.frames import rotation_about_axis
from pencilcal.validation import report as rp
from pencilcal.validation.report.sections import sensitivity_section
from pencilcal.validation.validate import frame_errors, summarise

Z = np.array([0.0, 0.0, 1.0])
MODELS = ("exact", "general", "aligned")
METHODS = ("sqpnp", "ippe")


# ---------------------------------------------------------------------------------- helpers


def _twin(R, ray=Z):
    return rotation_about_axis(ray, np.pi) @ R @ rotation_about_axis(Z, np.pi)


def _image(path, w=640, h=480):
    import cv2

    img = np.tile(np.linspace(40, 220, w, dtype=np.uint8), (h, 1))
    cv2.imwrite(str(path), img)
    return str(path)


def synthetic(tmp_path, *, truth=True, sfm=False, calibration=False, failing=True, grid=False, images=True,
              scale=1.0, n=6):
    """A small validation dict in the layout `pencilcal validate` writes (errors and summary
    made by validate's own functions)."""
    rng = np.random.default_rng(7)
    frames = []
    vertex = np.array([320.0, 240.0])
    for i in range(n):
        name = f"{i:03d}.png"
        path = _image(tmp_path / name) if images else str(tmp_path / "gone" / name)
        if failing and i == n - 1:
            frames.append({"image": name, "ok": False, "error": "no pencil lines in this frame", "path": path,
                           "pnp": {}, "pnp_best": None, "board_corners": 0,
                           "orient": {m: {"ok": False, "error": "fewer than three segments"} for m in MODELS}})
            continue
        tilt = 5.0 + 12.0 * i
        R_ref = rotation_about_axis([1.0, 0.0, 0.0], np.radians(tilt))
        t_ref = np.array([-60.0, -40.0, 400.0])
        rec = {"image": name, "ok": True, "error": None, "path": path, "board_corners": 24,
               "reference": "truth" if truth else "pnp", "R_ref": R_ref, "t_ref": t_ref,
               "reference_tilt_deg": tilt,
               "crlb": {"tilt_deg": 0.1 * scale, "normal_deg": None if i == 0 else 0.15 * scale}}
        pnp = {}
        for m in METHODS:
            if not truth and m == "sqpnp":
                Rp = R_ref
            else:
                Rp = R_ref @ rotation_about_axis(rng.normal(size=3), np.radians(0.05 * scale))
            pnp[m] = {"image": name, "ok": True, "method": m, "R_cam_from_target": Rp, "t_cam_from_target": t_ref,
                      "reproj_rms_px": 0.1, "corners": 24, "normal_sigma_deg": 0.04 * scale}
        rec["pnp"], rec["pnp_best"] = pnp, "sqpnp"
        errors, orient = {}, {}
        for m in MODELS:
            err = 0.1 * scale * (1 + i % 3) * (30.0 if m == "aligned" else 1.0)
            R = R_ref @ rotation_about_axis(rng.normal(size=3), np.radians(err))
            Rt = _twin(R)
            ambiguous = grid or i == 2
            if i == 3 and m == "exact" and not grid:  # a wrong twin
                R, Rt = Rt, R
            if grid and i % 2:  # unresolved: the fixed rule picks the other twin here
                R, Rt = Rt, R
            o = {"image": name, "ok": True, "error": None, "vertex_px": vertex,
                 "vertex_cov_px2": [[0.01, 0], [0, 0.02]], "lines_used": 7, "rms_residual_deg": 0.05,
                 "tilt_deg": tilt + 0.05 * scale, "tilt_sigma_deg": 0.1 * scale,
                 "detectable": tilt > 6, "normal": R[:, 2], "normal_sigma_deg": 0.15 * scale, "normal_twin": Rt[:, 2],
                 "R_cam_from_target": R, "R_cam_from_target_twin": Rt, "ambiguous": ambiguous, "model": m,
                 "resolved_by": None if ambiguous else "radius", "ray": Z, "tilt_threshold_deg": 3.0,
                 "labels_ambiguous": i == 1, "spokes": [0, 1, 2, 3, 4, 5, 6, -1]}
            orient[m] = o
            errors[f"orient:{m}"] = frame_errors(R, Rt, ambiguous, R_ref, Z, o["tilt_sigma_deg"], o["normal_sigma_deg"])
        for m in METHODS:
            errors[f"pnp:{m}"] = frame_errors(pnp[m]["R_cam_from_target"], None, False, R_ref, Z, None, 0.04 * scale)
        ang = np.radians(np.arange(8) * 20.0)
        rec["segments"] = [[*(vertex + 20 * np.r_[np.cos(a), np.sin(a)]), *(vertex + 120 * np.r_[np.cos(a), np.sin(a)])]
                           for a in ang]
        rec["orient"], rec["errors"] = orient, errors
        if sfm:
            Rs = R_ref @ rotation_about_axis(rng.normal(size=3), np.radians(0.03))
            rec["sfm"] = {"registered": True, "R_cam_from_target": Rs}
            errors["sfm"] = frame_errors(Rs, None, False, R_ref, Z)
        frames.append(rec)
    keys = [f"orient:{m}" for m in MODELS] + [f"pnp:{m}" for m in METHODS] + (["sfm"] if sfm else [])
    data = {"sequence": str(tmp_path / "seq"), "images": str(tmp_path), "camera_file": "camera.json",
            "camera": {"model": "pinhole", "width": 640, "height": 480,
                       "K": [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]], "dist": []},
            "board": {"type": "charuco", "squares": [7, 5], "square": 25.0, "marker": 18.0,
                      "dictionary": "DICT_5X5_100", "legacy": False},
            "pencil": ({"grid": "auto", "angles_deg": [0, 45, 90, 135, 180, -135, -90, -45]} if grid else
                       {"angles_deg": list(np.arange(8) * 20.0), "vertex": [200.0, 60.0], "radius": [15.0, 80.0]}),
            "calibration": None, "reference": "truth" if truth else "pnp", "models": list(MODELS),
            "methods": list(METHODS), "summary": summarise(frames, keys), "frames": frames,
            "reproducibility": {"versions": {"pencilcal": "0.1.0", "python": "3.11"},
                                "command": ["pencilcal", "validate", "seq", "-o", "v.json"],
                                "inputs_sha256": {"camera.json": "0" * 64}, "created": "2026-01-01T00:00:00+0000"}}
    if sfm:
        data["sfm"] = {"registered": n - 1, "frames": n, "points3D": 1234, "alignment_inliers": n - 1,
                       "alignment_frames": n - 1, "R_world_from_target": np.eye(3), "mean_reprojection_error_px": 0.4}
    if calibration:
        data["calibration"] = {
            "images": str(tmp_path), "rms_px": 0.31, "model": "pinhole",
            "std_intrinsics": {"fx": 0.5, "fy": 0.5, "cx": 0.3, "cy": 0.3},
            "counts": {"images": n, "views_used": n - 1},
            "views": [{"image": f"{i:03d}.png", "used": i != 2, "rms_px": None if i == 4 else 0.3 + 0.01 * i}
                      for i in range(n)],
            "rejected": [{"image": "002.png", "stage": "outlier", "rms_px": 0.9, "reason": "outlier view"},
                         {"image": "001.png", "stage": "outlier", "corner": 3, "residual_px": 2.1,
                          "reason": "outlier corner"}]}
    return json.loads(json.dumps(to_jsonable(data)))  # as read back from the file


_ATTR = re.compile(r"""\b(src|href)\s*=\s*["']([^"']*)["']""", re.I)


def assert_self_contained(page):
    """No resource the browser would fetch: every src is a data: URI, every href a fragment."""
    for attr, value in _ATTR.findall(page):
        if attr.lower() == "src":
            assert value.startswith("data:image/"), value[:80]
        else:
            assert value.startswith("#"), value[:80]
    low = page.lower()
    assert "<script" not in low and "<link" not in low and "<iframe" not in low
    assert "url(" not in low and "@import" not in low
    assert not re.search(r"""(src|href)\s*=\s*["']\s*(https?:)?//""", low)


def decoded_images(page):
    from matplotlib.image import imread

    out = []
    for b64 in re.findall(r'src="data:image/png;base64,([^"]+)"', page):
        raw = base64.b64decode(b64, validate=True)
        assert raw[:8] == b"\x89PNG\r\n\x1a\n"
        img = imread(io.BytesIO(raw), format="png")
        assert img.ndim == 3 and img.shape[0] > 50 and img.shape[1] > 50
        assert float(img[..., :3].std()) > 0.01  # not blank
        out.append(img)
    return out


def pdf_pages(path):
    return len(re.findall(rb"/Type\s*/Page\b", path.read_bytes()))


def summary_rows(page):
    i = page.index('id="summary"')
    table = page[i:page.index("</table>", i)]
    return [re.sub(r"<[^>]+>", "", m).strip() for m in re.findall(r"<tr>\s*<td[^>]*>(.*?)</td>", table)]


# ---------------------------------------------------------------------------------- unit tests


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
    assert len(imgs) == 2 + n_overlays + (1 if kw["calibration"] else 0)
    for sec in ("verdict", "summary", "plots", "frames", "overlays", "calibration", "sfm", "sensitivity",
                "reproducibility"):
        assert f'id="{sec}"' in page
    if not kw.get("images", True):
        assert "image not found at" in page
    assert ("Not in this file: run `pencilcal validate --sfm`" in page) != kw["sfm"]
    assert ("Not in this file: validate was given no calibration report" in page) != kw["calibration"]
    if kw["calibration"]:
        assert "Rejected views and corners" in page and "outlier corner" in page


def test_verdict_is_computed_from_the_numbers(tmp_path):
    data = synthetic(tmp_path, sfm=True, calibration=True)
    text, notes = rp.verdict(data)
    s = data["summary"]["orient:exact"]
    assert f"to {rp.num(s['normal_closer']['median'])} deg (median" in text
    assert f"on {s['frames']} of {len(data['frames'])} frames" in text
    assert f"{rp.pct(s['normal_coverage']['fraction'])} of the normal errors" in text
    assert "wrong in 1" in text and "left ambiguous in 1" in text  # frames 3 and 2
    assert "The reconstruction registered 5 of 6 frames" in text
    assert "Not covered" not in text
    assert any("1 of 6 frames were not validated" in n and "no pencil lines" in n for n in notes)
    # ten times larger errors give a ten times larger median in the words
    big = synthetic(tmp_path, sfm=True, calibration=True, scale=10.0)
    text10, _ = rp.verdict(big)
    m10 = big["summary"]["orient:exact"]["normal_closer"]["median"]
    assert m10 == pytest.approx(10 * s["normal_closer"]["median"], rel=0.05)
    assert f"to {rp.num(m10)} deg (median" in text10


def test_verdict_says_what_is_missing_and_why(tmp_path):
    data = synthetic(tmp_path, truth=False, grid=True, sfm=False, calibration=False)
    text, notes = rp.verdict(data)
    assert "Not covered by this file: ground truth, a reconstruction, calibration statistics." in text
    assert "left ambiguous in all 5 frames (the pencil has no spoke radii to choose with)" in text
    assert "agreement between PnP methods, not their accuracy" in text
    assert "combined sigma of the estimate and the PnP reference" in text
    assert any(n.startswith("No ground truth") for n in notes)
    assert any("--sfm" in n for n in notes) and any("--calibration" in n for n in notes)
    # the reference PnP method is flagged in the table, its coverage not judged
    table = rp.summary_table(data)
    names = [r[0].text for r in table.rows]
    assert "pnp:sqpnp †" in names and "pnp:ippe" in names
    sq = table.rows[names.index("pnp:sqpnp †")]
    assert sq[14].text == "– (reference)"


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


def test_coverage_judgement():
    assert rp.coverage_judgement(0.68, 0.6827, 50)[0] == "ok"
    assert rp.coverage_judgement(0.20, 0.6827, 50)[0] == "low"
    assert rp.coverage_judgement(0.98, 0.6827, 50)[0] == "high"
    assert rp.coverage_judgement(0.40, 0.6827, 4)[0] == "ok"  # four frames cannot tell
    assert rp.coverage_judgement(None, 0.68, 0)[0] is None


def test_number_format():
    assert [rp.num(v) for v in (None, float("nan"), 0, 0.12, 0.1204, 5.0, 145.24, 2.7e-8, 1234.5)] == \
        ["–", "–", "0", "0.120", "0.120", "5.00", "145", "2.7e-08", "1234"]


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


def test_load_validation_errors_name_the_file(tmp_path):
    bad = tmp_path / "v.json"
    bad.write_text("{not json")
    with pytest.raises(InputError, match=r"v\.json: not valid JSON"):
        rp.load_validation(bad)
    bad.write_text(json.dumps({"frames": []}))
    with pytest.raises(InputError, match=r"v\.json: not a validation file"):
        rp.load_validation(bad)
    bad.write_text("[1, 2]")
    with pytest.raises(InputError, match="not a validation file"):
        rp.load_validation(bad)
    with pytest.raises(InputError, match="not found"):
        rp.load_validation(tmp_path / "missing.json")
    with pytest.raises(InputError, match="is a folder"):
        rp.load_validation(tmp_path)
    sens = tmp_path / "s.json"
    sens.write_text(json.dumps({"answer": {}}))
    with pytest.raises(InputError, match="not a sensitivity file"):
        rp.load_sensitivity(sens)


def test_sensitivity_block(tmp_path):
    from pencilcal.validation.sensitivity import Setup, plan

    sens = json.loads(json.dumps(to_jsonable(
        plan(Setup(), tilts_deg="0:60:15", offaxis_deg="0,20", trials=20, accuracy_deg=0.5, seed=1,
             backend="numpy"))))
    data = synthetic(tmp_path, n=3, failing=False)
    page = rp.render_html(rp.build_report(data, samples=0, sensitivity=sens))
    assert_self_contained(page)
    assert sens["answer"]["text"].split(",")[0] in page
    i = page.index('id="sensitivity"')
    assert len(decoded_images(page[i:])) == 2  # the tilt x off-axis map and planned vs measured
    assert "could not be drawn" not in page
    # a bound-only plan (no Monte Carlo) renders too
    sens0 = json.loads(json.dumps(to_jsonable(plan(Setup(), tilts_deg="0:60:15", offaxis_deg="0", trials=0,
                                                   backend="numpy"))))
    sec = sensitivity_section(data, sens0)
    assert sum(isinstance(b, rp.Plot) for b in sec.blocks) == 2
    assert "Cramer-Rao bound" in sec.blocks[0].text
    assert not [b for b in sec.blocks if isinstance(b, rp.Para) and "could not be drawn" in b.text]


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
    assert len(decoded_images(page)) == 2 + 2
    assert "ground-truth poses (truth.json)" in rep.sections[0].blocks[1].text
    assert hashlib.sha256(vjson.read_bytes()).hexdigest() in page  # the validation file's own hash
    assert "pencilcal report v.json" in page
    rp.write_report(d / "r.pdf", data, samples=1, source=vjson)
    assert pdf_pages(d / "r.pdf") > 1


def test_ambiguous_labels_and_normals_are_told_apart(tmp_path):
    """A shifted labelling leaves the normal alone; a labelling that moves the normal does not:
    the notes say which frames are which, and the per-frame table marks the second kind."""
    data = synthetic(tmp_path)
    _, notes = rp.verdict(data)
    assert any(n.startswith("1 frame with spoke labels that could shift") for n in notes)
    assert not any("whose normal is ambiguous" in n for n in notes)
    f = data["frames"][4]["orient"]["exact"]
    f["labels_ambiguous"] = f["normal_ambiguous"] = True
    f["normal_alternatives"] = [[0.0, 0.6, 0.8]]
    _, notes = rp.verdict(data)
    assert any(n.startswith("1 frame with spoke labels that could shift") for n in notes)  # frame 1 only
    assert any(n.startswith("1 frame whose normal is ambiguous") for n in notes)
    page = rp.render_html(rp.build_report(data, samples=0))
    assert page.count("yes, normal too") == 1

"""The report's answer first: the verdict line and the numbers that matter (headline.py),
the comparison models shown as comparisons, and the page that opens with them."""
from __future__ import annotations

import copy

import numpy as np

from pencilcal.validation.report import build_report, render_html
from pencilcal.validation.report.document import Cell
from pencilcal.validation.report.gates import failed_gates_sentence, gate, gates, gates_table
from pencilcal.validation.report.headline import headline

from .helpers import synthetic


def _texts(row):
    return [c.text if isinstance(c, Cell) else str(c) for c in row]


def test_the_verdict_names_the_figure_its_sigma_and_the_twin(tmp_path):
    data = synthetic(tmp_path)  # frame 2 ambiguous, frame 3 with the wrong twin
    h = headline(data)
    assert h.status == "FAIL" and h.line.startswith("FAIL: plane normal from the fan's image angles (exact model) "
                                                    "vs the ground truth: median error ")
    # as reported, and with the closer twin where the wrong one was reported
    assert " deg as reported (0.148 deg for the closer twin), sigma 0.150 deg, 5 of 6 frames" in h.line
    assert "too few frames to judge" in h.line
    assert "left ambiguous in 1 of 5 frames" in h.line and "chosen wrong in 1" in h.line
    # what resolves the ambiguous frame is said
    assert "continuity from a resolved frame or a prior pose resolves them" in h.line
    rows = [_texts(r) for r in h.table.rows]
    assert rows[0][0] == "plane normal (exact model) vs the ground truth" and rows[0][3] == "5 / 6"
    assert rows[1][0] == "tilt vs the ground truth"
    # against PnP too (the truth is the reference here): the angle between the two estimates
    assert rows[2][0] == "plane normal vs PnP (board corners)" and rows[2][1].endswith(" median, RMS " + rows[2][1].split()[-1])
    twin = next(r for r in rows if r[0].startswith("twin"))
    assert twin[4].startswith("FAIL: left ambiguous in 1 of 5 frames")


def test_a_resolved_sequence_passes(tmp_path):
    data = synthetic(tmp_path, n=12, failing=False)
    for fr in data["frames"]:
        for m, o in fr["orient"].items():
            e = fr["errors"][f"orient:{m}"]
            if e["twin"] == "wrong":  # the right twin chosen
                o["R_cam_from_target"], o["R_cam_from_target_twin"] = o["R_cam_from_target_twin"], o["R_cam_from_target"]
                e["normal_deg"], e["twin"] = e["normal_closer_deg"], "right"
            if e["twin"] == "ambiguous":
                o["ambiguous"], o["resolved_by"], e["twin"] = False, "continuity", "right"
    for key in ("orient:exact", "orient:general", "orient:aligned"):
        data["summary"][key]["twin"] = {"right": 12}
    h = headline(data)
    assert "twin resolved in all 12 (" in h.line and "by continuity" in h.line and "by the spoke radii" in h.line
    # the sigmas of this small file judged: PASS or too few in the band, never a comparison model's FAIL
    assert h.status in ("PASS", "CHECK", "FAIL")
    assert "aligned" not in h.line


def test_comparison_models_are_shown_never_failed(tmp_path):
    data = synthetic(tmp_path, n=12, failing=False)
    # the aligned model's sigmas are far too small: a comparison, not a failed gate
    gs = gates(data)
    assert {g.status for g in gs if g.method in ("orient:general", "orient:aligned")} == {"comparison"}
    assert "aligned" not in failed_gates_sentence(gs) and "general" not in failed_gates_sentence(gs)
    table = gates_table(gs)
    comparison = [r for r in table.rows if isinstance(r[0], Cell) and r[0].text.startswith("orient:aligned")]
    assert comparison and all(c.cls == "muted" for c in comparison[0]) and comparison[0][-1].text.startswith("comparison")
    rows = [_texts(r) for r in headline(data).table.rows]
    assert ["comparison: the chapter's aligned model"] == [r[0] for r in rows if "aligned" in r[0]]
    assert all(r[4] == "comparison only, not judged" for r in rows if r[0].startswith("comparison"))


def test_gates_equal_but_for_the_method_share_a_row():
    a = gate("pnp:sqpnp", "normal", 0.6, 0.632, 16)
    same = [gate(f"pnp:{m}", "normal", 0.6, 0.632, 16) for m in ("ippe", "epnp")]
    other = gate("pnp:iterative", "normal", 0.5, 0.632, 16)
    rows = gates_table([a, *same, other]).rows
    assert [r[0] for r in rows] == ["pnp: sqpnp, ippe, epnp", "pnp:iterative"]


def _pivot(frames=4, truth=True, p=0.5):
    data = {"frames": [{"image": f"{i:03d}.png", "ok": True} for i in range(frames)], "summary": {}}
    rec = {"ok": True, "vertex_px": [100.0, 50.0], "vertex_cov_px2": [[0.04, 0.0], [0.0, 0.05]],
           "point": [20.0, -6.0, 360.0], "point_sigma": 12.0, "point_cov": np.diag([1.0, 1.0, 142.0]).tolist(),
           "outliers": [], "midlines": [{"image": f"{i:03d}.png", "shaft": 0} for i in range(frames) if i != 2]}
    if truth:
        rec["truth"] = {"vertex_error_px": 0.2, "vertex_chi2": 1.1, "point_error_norm": 4.0, "point_chi2": 2.4,
                        "point_p_value": p}
    data["fulcrum"] = rec
    return data


def test_a_pivot_leads_with_its_fulcrum_in_mm():
    h = headline(_pivot())
    assert h.status == "PASS"
    assert h.line.startswith("PASS: fulcrum of the pivoting instrument: the 3-D point (20.0, -6.0, 360.0) mm in the "
                             "camera frame, sigma 12.0 mm, 4.00 mm from the truth")
    assert "its image (100.00, 50.00) px" in h.line and "0.200 px from the truth" in h.line
    # the frame without a shaft is named, in the line and the table
    assert "shafts found in 3 of 4 frames (none in 002.png)" in h.line
    rows = [_texts(r) for r in h.table.rows]
    assert rows[1][0] == "3-D fulcrum, camera frame [mm]" and rows[1][2] == "12.0 mm" and rows[1][4].startswith("PASS")
    assert rows[-1][:2] == ["frames with a shaft", "3 of 4"] and "002.png" in rows[-1][4]
    assert headline(_pivot(p=0.001)).status == "FAIL"
    untruthed = headline(_pivot(truth=False))
    assert untruthed.status == "NOT JUDGED" and "No truth to judge it against" in untruthed.line


def test_the_page_opens_with_its_answer(tmp_path):
    data = synthetic(tmp_path)
    page = render_html(build_report(copy.deepcopy(data), samples=0))
    verdict = page.index('<p class="verdict bad" id="verdict"><b>FAIL</b>plane normal')
    assert verdict < page.index("<nav>") < page.index('<section id="verdict">')
    # the sections are numbered in reading order
    titles = [s.title for s in build_report(data, samples=0).sections]
    assert [t.split(".")[0] for t in titles] == [str(i) for i in range(1, len(titles) + 1)]

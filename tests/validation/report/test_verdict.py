"""validation.report.verdict (and the summary table it speaks for): the words are computed from
the numbers, say what is missing, and judge the coverage of the sigmas."""
from __future__ import annotations

import pytest

from pencilcal.validation import report as rp
from tests.validation.report.helpers import synthetic


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


def test_coverage_judgement():
    assert rp.coverage_judgement(0.68, 0.6827, 50)[0] == "ok"
    assert rp.coverage_judgement(0.20, 0.6827, 50)[0] == "low"
    assert rp.coverage_judgement(0.98, 0.6827, 50)[0] == "high"
    assert rp.coverage_judgement(0.40, 0.6827, 4)[0] == "ok"  # four frames cannot tell
    assert rp.coverage_judgement(None, 0.68, 0)[0] is None


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


def test_gates_pass_honest_sigmas_and_fail_small_ones():
    from pencilcal.validation.report.gates import failed_gates_sentence, gate

    honest = gate("orient:exact", "tilt", 0.70, 0.6827, 60)
    small = gate("pnp:sqpnp", "normal", 0.31, 0.632, 59)  # the da Vinci stereo figure before the fix
    few = gate("orient:exact", "normal", 0.2, 0.632, 5)
    assert (honest.status, small.status, few.status) == ("PASS", "FAIL", "too few frames")
    text = failed_gates_sentence([honest, small, few])
    assert "pnp:sqpnp normal" in text and "orient:exact" not in text and "too small" in text
    assert failed_gates_sentence([honest]) == ""

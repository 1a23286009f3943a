"""The verdict: what the numbers of a validation file say, in plain words, and what the
file does not cover.

Every sentence is computed from the file: the primary orient model's accuracy and its
twin resolution, its error against the Cramer-Rao bound, the coverage of its reported
sigmas (`coverage_judgement`), the detectability of the tilt, the other models, PnP and
the reconstruction; then the reviewer's notes (frames not validated, no ground truth, no
reconstruction, no calibration statistics, ambiguous labellings).

Example
-------
>>> coverage_judgement(0.20, 0.6827, 50)[0], coverage_judgement(0.40, 0.6827, 4)[0]
('low', 'ok')
>>> verdict({"frames": [], "summary": {}})
('The validation file holds no frames.', ['no frames'])
"""
from __future__ import annotations

import math
from collections import Counter

import numpy as np

from ..metrics import EXPECTED_COVERAGE
from .facts import (
    calibration_same_images,
    method_errors,
    method_keys,
    primary_method,
    reference_counts,
    reference_phrase,
)
from .format import finite, lookup, num, pct

__all__ = ["coverage_judgement", "verdict"]


def coverage_judgement(fraction, expected, n):
    """('ok' | 'low' | 'high' | None, words): is a coverage consistent with the expected
    rate for n frames (binomial, two standard errors)? fraction, expected: in [0, 1]."""
    fraction, expected = finite(fraction), finite(expected)
    if fraction is None or expected is None or not n:
        return None, "no sigmas to check"
    se = math.sqrt(expected * (1 - expected) / n)
    z = (fraction - expected) / se if se > 0 else 0.0
    band = f"the binomial band of +-{100 * 2 * se:.0f} points for {n} frames"
    if abs(z) <= 2:
        return "ok", f"consistent with the {pct(expected)} expected, within {band}"
    if z < 0:
        return "low", f"fewer than the {pct(expected)} expected, beyond {band}: the reported sigmas are too small"
    return "high", f"more than the {pct(expected)} expected, beyond {band}: the reported sigmas are too large"


def _combined_coverage(data, key):
    """Normal coverage against sqrt(sigma_est^2 + sigma_ref^2) when the reference is PnP:
    {fraction, expected, count}, or None without such frames."""
    pairs = []
    for _, fr, e in method_errors(data, key):
        if fr.get("reference") != "pnp":
            continue
        s_est = finite(e.get("normal_sigma_deg"))
        s_ref = finite(lookup(fr, "pnp", fr.get("pnp_best") or "", "normal_sigma_deg"))
        err = finite(e.get("normal_closer_deg") if key.startswith("orient") else e.get("normal_deg"))
        if None not in (s_est, s_ref, err):
            pairs.append((err, math.hypot(s_est, s_ref)))
    if not pairs:
        return None
    e, s = np.array(pairs).T
    return {"fraction": float(np.mean(e <= s)), "expected": float(EXPECTED_COVERAGE["normal"]), "count": len(pairs)}


def _crlb_ratio(data, key):
    """RMS error (closer twin) over the RMS per-frame Cramer-Rao bound of the normal:
    {ratio, bound_rms [deg], count}, or None without a bound."""
    pairs = [(finite(e.get("normal_closer_deg")), finite(lookup(fr, "crlb", "normal_deg")))
             for _, fr, e in method_errors(data, key)]
    pairs = [(a, b) for a, b in pairs if a is not None and b is not None and b > 0]
    if not pairs:
        return None
    e, b = np.array(pairs).T
    rms_b = float(np.sqrt(np.mean(b**2)))
    return {"ratio": float(np.sqrt(np.mean(e**2)) / rms_b), "bound_rms": rms_b, "count": len(pairs)}


def _failures(data):
    """Counter of the reasons frames were not validated."""
    return Counter(str(f.get("error") or "no estimate") for f in data["frames"] if not f.get("ok"))


def _orient_failures(data, model):
    """Counter of the reasons one orient model gave no estimate."""
    return Counter(str(lookup(f, "orient", model, "error") or "no estimate") for f in data["frames"]
                   if isinstance(lookup(f, "orient", model), dict) and not lookup(f, "orient", model, "ok"))


def _reasons(counter, limit=3):
    """The most common reasons of a Counter in words ("2 x 'why'; 1 x 'other'; 3 other")."""
    items = counter.most_common()
    txt = "; ".join(f"{n} x '{r}'" for r, n in items[:limit])
    if len(items) > limit:
        txt += f"; {sum(n for _, n in items[limit:])} other"
    return txt


# ----------------------------------------------------------------------------------------
# the verdict's sentences, in reading order


def _no_estimate_sentence(data, n):
    """No orient model gave an estimate: the sentence, with the commonest reasons."""
    models = data.get("models") or ["exact"]
    why = _orient_failures(data, models[0])
    return f"No frame gave an angular-variation estimate ({n} frames" + (f"; {_reasons(why)}" if why else "") + ")."


def _accuracy_sentences(data, prim, n):
    """The primary model's accuracy against the reference, and how its twin was resolved."""
    s = data["summary"][prim]
    model = prim.split(":", 1)[1]
    k = int(s.get("frames") or 0)
    nn, nc = s.get("normal") or {}, s.get("normal_closer") or {}
    twin = s.get("twin") or {}
    right, wrong, amb = (int(twin.get(t, 0)) for t in ("right", "wrong", "ambiguous"))
    head = (f"The angular-variation estimate of the plane normal ({model} model) agrees with the "
            f"{reference_phrase(data)} to {num(nc.get('median'))} deg (median; RMSE {num(nc.get('rmse'))}, "
            f"95th percentile {num(nc.get('p95'))} deg) on {k} of {n} frames")
    lucky = [e for _, _, e in method_errors(data, prim) if e.get("twin") == "ambiguous"
             and finite(e.get("normal_deg")) is not None and finite(e.get("normal_closer_deg")) is not None
             and abs(finite(e["normal_deg"]) - finite(e["normal_closer_deg"])) <= 1e-9]
    if wrong == 0 and amb == 0:
        return [head + (f", with the twin solution resolved in all {right}." if right else ".")]
    if wrong == 0 and len(lucky) == amb:
        rule = "the twin closer to the optical axis (a fixed rule, not an estimate)"
        return [head + (f". The twin was resolved in {right} frames; in the other {amb} it was left ambiguous "
                        f"and the reported normal, {rule}, happened to be the right one." if right else
                        f". The twin was left ambiguous in all {amb} frames; the reported normal, {rule}, "
                        f"happened to be the right one in each.")]
    why = ""
    if amb and amb == k:
        why = (" (the pencil has no spoke radii to choose with)" if not lookup(data, "pencil", "radius")
               else " (the spoke radii could not tell them apart)")
    how = (f"the twin was left ambiguous in all {k} frames{why}" if amb == k else
           f"the twin was chosen right in {right}, wrong in {wrong} and left ambiguous in {amb} "
           f"frame{'s' if amb != 1 else ''}{why}")
    return [head + " when the twin solution closer to the reference is taken.",
            f"As reported, with the twin the method chose, the median is {num(nn.get('median'))} deg "
            f"(RMSE {num(nn.get('rmse'))} deg): {how}"
            + ("; an ambiguous frame reports the twin closer to the optical axis, a fixed rule, not an estimate."
               if amb else ".")]


def _bound_sentences(data, prim):
    """The RMS error over the Cramer-Rao bound, with the spread chance alone gives it."""
    cr = _crlb_ratio(data, prim)
    if cr is None:
        return []
    return [f"Its RMS error is {cr['ratio']:.2f} times the Cramer-Rao bound of these frames "
            f"(RMS bound {num(cr['bound_rms'])} deg over {cr['count']} frames; 1 is the best any "
            f"unbiased estimator can do, and chance alone moves the ratio by about "
            f"+-{0.5 / math.sqrt(cr['count']):.2f} for {cr['count']} frames"
            + ("; the PnP reference's own error is part of every error here)." if data.get("reference") != "truth"
               else ").")]


def _sigma_sentences(data, prim):
    """How well the reported sigmas cover the errors (and, against PnP, the combined sigma)."""
    s = data["summary"][prim]
    out = []
    covs = []
    for what, c in (("normal", s.get("normal_coverage")), ("tilt", s.get("tilt_coverage"))):
        if isinstance(c, dict) and finite(c.get("fraction")) is not None:
            _, words = coverage_judgement(c.get("fraction"), c.get("expected"), c.get("count"))
            covs.append(f"{pct(c['fraction'])} of the {what} errors ({words})")
    # validate judges the coverage by the difference's sigmas where the frames carry them
    # (the estimate's totals with the PnP reference's own sigma in quadrature)
    combined = any(finite(e.get("reference_normal_sigma_deg")) is not None for _, _, e in method_errors(data, prim))
    if covs and combined:
        out.append("Its reported sigmas, combined with the PnP reference's own, cover " + " and ".join(covs) + ".")
    elif covs:
        out.append("Its reported sigmas cover " + " and ".join(covs) + ".")
    else:
        out.append("It reports no sigmas to check.")
    if data.get("reference") == "pnp" and not combined:
        cc = _combined_coverage(data, prim)
        if cc is not None:
            _, words = coverage_judgement(cc["fraction"], cc["expected"], cc["count"])
            out.append(f"Against the combined sigma of the estimate and the PnP reference, the coverage of the "
                       f"normal errors is {pct(cc['fraction'])} ({words}).")
    return out


def _detectability_sentences(data, prim):
    """In how many frames the tilt was detectable, and the reference tilts of the others."""
    s = data["summary"][prim]
    det = s.get("detectable")
    if det is None:
        return []
    model = prim.split(":", 1)[1]
    k = int(s.get("frames") or 0)
    low = [(finite(fr.get("reference_tilt_deg")), fr.get("image")) for _, fr, _ in method_errors(data, prim)
           if lookup(fr, "orient", model, "detectable") is False]
    txt = f"The tilt was detectable in {int(det)} of {k} frames"
    if low:
        tilts = ", ".join(f"{num(t)}" for t, _ in sorted(low, key=lambda x: (x[0] is None, x[0] or 0))[:6]
                          if t is not None)
        txt += (f"; in the other {len(low)}" + (f" (reference tilt {tilts} deg)" if tilts else "")
                + " it cannot be told from a frontal pencil and the reported tilt is an upper bound, "
                  "not a measurement")
    return [txt + "."]


def _other_models_sentences(data, prim):
    """The medians of the other orient models."""
    summ = data["summary"]
    others = [kk for kk in method_keys(data) if kk.startswith("orient:") and kk != prim
              and (lookup(summ, kk, "frames") or 0) > 0]
    if not others:
        return []
    parts = [f"{kk.split(':', 1)[1]} {num(lookup(summ, kk, 'normal_closer', 'median'))} deg" for kk in others]
    return ["The chapter's other models give medians (closer twin) of " + ", ".join(parts) + "."]


def _pnp_sentences(data, prim):
    """PnP against truth (how far the estimate is from it) or against itself (agreement only)."""
    summ, ref = data["summary"], data.get("reference")
    pnp = [kk for kk in method_keys(data) if kk.startswith("pnp:") and (lookup(summ, kk, "frames") or 0) > 0]
    if not pnp:
        return []
    meds = {kk: finite(lookup(summ, kk, "normal", "median")) for kk in pnp}
    meds = {kk: m for kk, m in meds.items() if m is not None}
    if ref == "truth" and meds:
        best = min(meds, key=meds.get)
        txt = (f"PnP from the board corners reaches {num(meds[best])} deg (median normal error, "
               f"{best.split(':', 1)[1]}; {len(meds)} methods, medians {num(min(meds.values()))}-"
               f"{num(max(meds.values()))} deg)")
        mine = finite(lookup(summ, prim, "normal_closer", "median")) if prim else None
        if mine is not None and meds[best] > 0:
            txt += f"; the angular-variation estimate's median is {num(mine / meds[best])} times that"
        return [txt + "."]
    if ref != "truth":
        mx = [finite(lookup(summ, kk, "normal", "max")) for kk in pnp]
        mx = [m for m in mx if m is not None]
        counts = reference_counts(data)
        who = ", ".join(f"{m} in {c}" for m, c in counts.most_common())
        return [f"The PnP methods agree with the reference (the best PnP pose per frame: {who}) to "
                f"{num(max(mx) if mx else None)} deg at most; this measures agreement between PnP methods, "
                f"not their accuracy."]
    return []


def _sfm_sentences(data):
    """What the reconstruction registered and how well its normals agree."""
    sfm = data.get("sfm")
    if not isinstance(sfm, dict):
        return []
    med = lookup(data["summary"], "sfm", "normal", "median")
    return [f"The reconstruction registered {sfm.get('registered', '?')} of {sfm.get('frames', '?')} frames "
            f"({sfm.get('points3D', '?')} points, mean reprojection error "
            f"{num(sfm.get('mean_reprojection_error_px'))} px; rotation alignment "
            f"{sfm.get('alignment_inliers', '?')} of {sfm.get('alignment_frames', '?')} frames inliers)"
            + (f"; its aligned normals agree with the reference to {num(med)} deg (median)."
               if med is not None else "; no frame has an SfM error.")]


def _not_covered_sentences(data):
    """What the file does not cover: ground truth, a reconstruction, calibration statistics."""
    cal = data.get("calibration")
    missing = [t for t, ok in (("ground truth", data.get("reference") == "truth"),
                               ("a reconstruction", isinstance(data.get("sfm"), dict)),
                               ("calibration statistics", isinstance(cal, dict) and bool(cal))) if not ok]
    return ["Not covered by this file: " + ", ".join(missing) + "."] if missing else []


# ----------------------------------------------------------------------------------------
# the reviewer's notes


def _input_notes(data):
    """What the file lacks or where its inputs are not independent."""
    frames, n = data["frames"], len(data["frames"])
    notes = []
    fails = _failures(data)
    if fails:
        notes.append(f"{sum(fails.values())} of {n} frames were not validated: {_reasons(fails, 4)}.")
    if data.get("reference") != "truth":
        sig = [finite(lookup(f, "pnp", f.get("pnp_best") or "", "normal_sigma_deg")) for f in frames
               if f.get("pnp_best")]
        sig = [v for v in sig if v is not None]
        notes.append("No ground truth: errors are measured against PnP from the board corners, whose own error is part "
                     "of every number" + (f" (median reported sigma of the reference normal {num(np.median(sig))} deg)"
                                          if sig else "") + ".")
    if not isinstance(data.get("sfm"), dict):
        notes.append("No reconstruction (run `pencilcal validate --sfm` to compare with pycolmap).")
    cal = data.get("calibration")
    if not isinstance(cal, dict) or not cal:
        notes.append("No calibration statistics (give `pencilcal validate --calibration calib.json`, the report of "
                     "`pencilcal calibrate --report`, or a camera file that carries them).")
    elif calibration_same_images(data):
        notes.append("The camera was calibrated on the same images it is validated on; the intrinsics are not "
                     "independent of the test data.")
    no_tilt = sum(1 for f in frames if f.get("ok") and finite(f.get("reference_tilt_deg")) is None)
    if no_tilt:
        notes.append(f"{no_tilt} validated frame{'s have' if no_tilt != 1 else ' has'} no reference tilt (no pencil "
                     f"vertex in the reference pose).")
    return notes


def _ambiguity_notes(data, prim):
    """Frames whose spoke labels could shift (normal unaffected) and those whose normal moves."""
    if prim is None:
        return []
    model = prim.split(":", 1)[1]
    flags = [(bool(lookup(f, "orient", model, "labels_ambiguous")),
              bool(lookup(f, "orient", model, "normal_ambiguous"))) for _, f, _ in method_errors(data, prim)]
    lab = sum(1 for la, na in flags if la and not na)
    nrm = sum(1 for _, na in flags if na)
    notes = []
    if lab:
        notes.append(f"{lab} frame{'s' if lab != 1 else ''} with spoke labels that could shift (in-plane angle "
                     f"unknown; the normal is unaffected).")
    if nrm:
        notes.append(f"{nrm} frame{'s' if nrm != 1 else ''} whose normal is ambiguous: another labelling of "
                     f"{'their' if nrm != 1 else 'its'} lines fits about as well and puts the normal elsewhere "
                     f"(normal_alternatives); the errors shown are those of the labelling reported.")
    return notes


def verdict(data):
    """(paragraph, notes): the verdict in plain words and the list of what is missing or
    worth a reviewer's attention, all computed from the numbers in `data` (a validation
    dict, `validation_file.load_validation`)."""
    n = len(data["frames"])
    prim = primary_method(data)
    if n == 0:
        return "The validation file holds no frames.", ["no frames"]
    if prim is None:
        s_out = [_no_estimate_sentence(data, n)]
    else:
        s_out = (_accuracy_sentences(data, prim, n) + _bound_sentences(data, prim) + _sigma_sentences(data, prim)
                 + _detectability_sentences(data, prim) + _other_models_sentences(data, prim))
    s_out += _pnp_sentences(data, prim) + _sfm_sentences(data) + _not_covered_sentences(data)
    return " ".join(s_out), _input_notes(data) + _ambiguity_notes(data, prim)

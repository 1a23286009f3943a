"""The single-angle experiment (the chapter's Figs. 8-9): the tilt from two spokes a known
3D angle apart, in the three cases ``on_line``, ``known`` and ``unknown``, against the
reference pose; see `pencilcal.validation.experiments`.

Example
-------
>>> import numpy as np
>>> from pencilcal.validation.experiments.synthetic import synthetic_validation
>>> r = single_angle(synthetic_validation(np.arange(0.0, 61.0, 10.0), sigma_deg=0.05, axis_deg=30.0))
>>> r["status"], r["on_line"]["counts"]["unique"], r["unknown"]["counts"]
('ok', 44, {'lower_bound': 49})
>>> round(float(np.degrees(sd_on_line(np.radians(30.0), np.radians(20.0), np.radians(0.1)))), 4)
0.6041
"""
from __future__ import annotations

import math

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.angles import wrap_line
from pencilcal.toolkit.pencil.chapter import general_parameters
from pencilcal.toolkit.pencil.estimator import detection_threshold
from pencilcal.toolkit.pencil.spec import image_angles

from .axis import adjacent_pairs, frame_axis, sequence_axis, t_plane
from .frames import frames_or_fail, sigma_line
from .sections import GROSS_Z, INSUFFICIENT, deg_or_none, finish, header, insufficient_section, rms, tilt_bins

__all__ = ["sd_on_line", "single_angle"]


def sd_on_line(gamma, theta, sigma):
    """The chapter's single-angle sd: sigma (1 + cos^2 g tan^2 theta) / (tan theta sin g).

    gamma, theta, sigma: broadcastable [rad] (theta from the axis; sigma the sd of the
    image angle between the two lines). Returns [rad]; inf at gamma = 0.
    """
    g = np.asarray(gamma, float)
    tt = np.abs(np.tan(np.asarray(theta, float)))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(np.sin(g) > 0, sigma * (1.0 + np.cos(g) ** 2 * tt * tt) / (tt * np.sin(g)), np.inf)


def _call_single(alpha, theta, case, sigma):
    """`single_angle_tilt`, or the InputError it raised (a pair that gives no information)."""
    from pencilcal.toolkit.pencil.single_angle import single_angle_tilt

    try:
        return single_angle_tilt(alpha, theta, case, sigma=sigma)
    except InputError as e:
        return e


def _pair_record(f, case, lines, theta, res, res_ref, sigma_alpha):
    """One pair's record; errors only for the values the status gives, never invented."""
    g_ref = f.tilt_ref
    rec = {"frame": f.index, "image": f.image, "reference_tilt_deg": math.degrees(g_ref), "case": case,
           "spokes": [int(f.spoke[i]) for i in lines], "lines": [int(i) for i in lines],
           "theta_deg": math.degrees(theta), "sigma_alpha_deg": math.degrees(sigma_alpha)}
    if isinstance(res, Exception):
        rec.update(status="no information", message=str(res), gamma_deg=[], sd_deg=[], error_deg=[])
        return rec
    gam = [math.degrees(g) for g in res.gamma]
    rec.update(status=res.status, message=res.message, gamma_deg=gam, sd_deg=[deg_or_none(s) for s in res.sigma])
    if res.status in ("unique", "two_roots"):
        rec["error_deg"] = [g - math.degrees(g_ref) for g in gam]
    else:
        rec["error_deg"] = []
    if res.status == "lower_bound":
        # the bound must not exceed the reference tilt (beyond noise)
        sd = res.sigma[0] if np.isfinite(res.sigma[0]) else 0.0
        rec["bound_minus_reference_deg"] = gam[0] - math.degrees(g_ref)
        rec["bound_holds"] = bool(res.gamma[0] <= g_ref + 3.0 * sd + 1e-12)
    # the sd the estimate should have, at the reference tilt (noise-free angles there)
    sd_ref = None
    if res_ref is not None and not isinstance(res_ref, Exception) and res_ref.status in ("unique", "two_roots"):
        j = int(np.argmin([abs(g - g_ref) for g in res_ref.gamma]))
        sd_ref = deg_or_none(res_ref.sigma[j])
    rec["sd_at_reference_deg"] = sd_ref
    if res.status == "unique" and sd_ref:
        rec["z"] = rec["error_deg"][0] / sd_ref
    return rec


def single_angle(v, *, pairs="adjacent", on_axis_tol_deg=0.05, cases=("on_line", "known", "unknown")):
    """The chapter's single-angle test on every frame (`pencilcal.validation.experiments`).

    v: a validation dict (`load_validation`). pairs: "adjacent" (neighbouring spokes) or
    "all" (every pair of distinct line directions) for the "known" and "unknown" cases;
    "on_line" always pairs the axis spoke with every other spoke. on_axis_tol_deg: how
    close to the tilt axis a spoke must be to count as on it (its offset is reported).
    Returns the result dict (JSON-ready).
    """
    if pairs not in ("adjacent", "all"):
        raise InputError(f"pairs must be 'adjacent' or 'all', got {pairs!r}")
    frames, skipped = frames_or_fail(v)
    out = header(v, "single-angle", frames, skipped)
    sig = sigma_line(frames)
    th_p = np.radians(np.asarray(v["pencil"]["angles_deg"], float))
    seq_axis = sequence_axis(frames)
    tol = math.radians(on_axis_tol_deg)
    if pairs == "adjacent":
        spoke_pairs = adjacent_pairs(th_p)
    else:
        spoke_pairs = [(i, j) for i in range(th_p.size) for j in range(i + 1, th_p.size)
                       if abs(math.sin(th_p[j] - th_p[i])) > 1e-6]
    records = {c: [] for c in cases}
    axis_info = []
    no_axis = []
    for f in frames:
        phi, src = frame_axis(f, seq_axis)
        p = general_parameters(f.R_ref, f.x)
        b, gain = t_plane(f.a, p)
        s_t = f.sigma * gain  # the lines' sd in T
        pred = image_angles(f.R_ref, f.x, f.th)
        b_pred, _ = t_plane(pred, p)
        info = {"frame": f.index, "image": f.image, "reference_tilt_deg": math.degrees(f.tilt_ref),
                "axis_source": src if phi is not None else None}
        if phi is None:
            no_axis.append({"image": f.image, "reason": src})
        else:
            a_ax = float(image_angles(f.R_ref, f.x, np.array([phi]))[0])
            b_ax, _ = t_plane(np.array([a_ax]), p)
            b_ax = float(b_ax[0])
            info["axis_target_deg"] = math.degrees(phi)
            if f.reference_sigma_deg is not None and math.sin(f.tilt_ref) > 0:
                info["axis_sigma_deg"] = float(np.degrees(np.radians(f.reference_sigma_deg) / math.sin(f.tilt_ref)))
        by_spoke = {}
        for i, k in enumerate(f.spoke):
            by_spoke.setdefault(int(k), []).append(i)
        # --- on_line: the measured line of a spoke on the axis is the axis image
        if "on_line" in records and phi is not None:
            off = wrap_line(f.th - phi)
            on = [i for i in range(f.a.size) if abs(off[i]) < tol]
            if on:
                info["axis_spokes"] = sorted({int(f.spoke[i]) for i in on})
                info["axis_offset_deg"] = float(np.degrees(np.max(np.abs(off[on]))))
            for i in on:
                for k in range(f.a.size):
                    if k in on or abs(math.cos(f.th[k] - f.th[i])) < 1e-6:
                        continue
                    theta = float(wrap_line(f.th[k] - f.th[i]))
                    alpha = float(wrap_line(b[k] - b[i]))
                    sa = math.hypot(s_t[k], s_t[i])
                    res = _call_single(alpha, theta, "on_line", sa)
                    res_ref = _call_single(float(wrap_line(b_pred[k] - b_pred[i])), theta, "on_line", sa)
                    records["on_line"].append(_pair_record(f, "on_line", (i, k), theta, res, res_ref, sa))
        # --- known and unknown: pairs of spokes, both measured
        for (s1, s2) in spoke_pairs:
            for i in by_spoke.get(s1, [])[:1]:
                for k in by_spoke.get(s2, [])[:1]:
                    theta = float(f.th[k] - f.th[i])
                    sa = math.sqrt(0.5 * (s_t[i] ** 2 + s_t[k] ** 2))  # one sd for both alphas
                    if "known" in records and phi is not None:
                        al = (float(wrap_line(b[i] - b_ax)), float(wrap_line(b[k] - b_ax)))
                        al_ref = (float(wrap_line(b_pred[i] - b_ax)), float(wrap_line(b_pred[k] - b_ax)))
                        res = _call_single(al, theta, "known", sa)
                        res_ref = _call_single(al_ref, theta, "known", sa)
                        records["known"].append(_pair_record(f, "known", (i, k), theta, res, res_ref, sa))
                    if "unknown" in records:
                        sa2 = math.hypot(s_t[i], s_t[k])
                        res = _call_single(float(b[k] - b[i]), theta, "unknown", sa2)
                        records["unknown"].append(_pair_record(f, "unknown", (i, k), theta, res, None, sa2))
        axis_info.append(info)
    out["pairs"] = pairs
    out["on_axis_tol_deg"] = on_axis_tol_deg
    out["sequence_axis_deg"] = deg_or_none(seq_axis)
    out["axes"] = axis_info
    if no_axis:
        out["frames_without_axis"] = no_axis
    out["theory"] = {
        "formula": "sd(g) = sigma_alpha (1 + cos^2 g tan^2 theta) / (tan theta sin g)",
        "sigma_alpha_deg": math.degrees(math.sqrt(2.0) * sig),
        "sigma_alpha_note": "sqrt(2) x the median line sigma: alpha is the difference of two measured lines",
    }
    for c in cases:
        out[c] = _single_summary(c, records[c], frames, no_axis, 2.0 * math.degrees(float(detection_threshold(sig))))
    if "on_line" in out and out["on_line"].get("status") != INSUFFICIENT:
        thetas = sorted({round(abs(r["theta_deg"]), 9) for r in records["on_line"]})
        g = np.radians(np.arange(1.0, 90.0, 1.0))
        out["theory"]["curves"] = [
            {"theta_deg": t, "tilt_deg": np.degrees(g).tolist(),
             "sd_deg": np.degrees(sd_on_line(g, math.radians(t), math.sqrt(2.0) * sig)).tolist()} for t in thetas]
    return finish(out, list(cases))


def _single_summary(case, recs, frames, no_axis, min_tilt_deg):
    """The section of one case: counts by status, and the errors of each status against the
    reference (z against the sd at the reference tilt); insufficient without pairs."""
    if not recs:
        if case == "on_line":
            why = ("no spoke lies on the tilt axis of the reference pose (within the tolerance) in any frame"
                   if len(no_axis) < len(frames) else "no frame has a defined tilt axis")
        elif case == "known":
            why = "no frame has a defined tilt axis" if no_axis else "no pair of spokes was seen together"
        else:
            why = "no pair of spokes was seen together"
        return insufficient_section(why, pairs=[])
    statuses = ("unique", "two_roots", "lower_bound", "inconsistent", "no information")
    counts = {s: sum(r["status"] == s for r in recs) for s in statuses}
    s = {"status": "ok", "counts": {k: v for k, v in counts.items() if v}, "pairs": recs}
    uni = [r for r in recs if r["status"] == "unique"]
    if uni:
        err = [r["error_deg"][0] for r in uni]
        z = [r.get("z") for r in uni if r.get("z") is not None]
        above = [r for r in uni if r["reference_tilt_deg"] >= min_tilt_deg and r.get("z") is not None]
        za = [r["z"] for r in above]
        gross = [r for r in uni if r.get("z") is not None and abs(r["z"]) > GROSS_Z]
        s["unique"] = {
            "count": len(uni),
            "error_median_abs_deg": float(np.median(np.abs(err))),
            "error_rmse_deg": rms(err),
            "z_rms": rms(z),
            "z_within_1": float(np.mean(np.abs(z) <= 1.0)) if z else None,
            "z_median_abs": float(np.median(np.abs(z))) if z else None,
            "z_count": len(z),
            "above_tilt_deg": min_tilt_deg,
            "above": {"count": len(above), "error_rmse_deg": rms([r["error_deg"][0] for r in above]),
                      "sd_rms_deg": rms([r["sd_at_reference_deg"] for r in above]), "z_rms": rms(za),
                      "z_within_1": float(np.mean(np.abs(za) <= 1.0)) if za else None,
                      "z_median_abs": float(np.median(np.abs(za))) if za else None},
            "gross": {"count": len(gross), "threshold_z": GROSS_Z,
                      "reference_tilt_deg": sorted({round(r["reference_tilt_deg"], 6) for r in gross}),
                      "note": ("'unique' results more than 5 sd off: near zero tilt the noise can push the "
                               "right root past cos(gamma) = 1, leaving only a far root, reported as unique")},
            "z_note": ("z = error / sd at the reference tilt: RMS 1, 68% within 1 and median |z| 0.67 when the sigmas "
                       "are right; "
                       "'above' keeps frames tilted at least twice the detection threshold"),
            "bins": tilt_bins([r["reference_tilt_deg"] for r in uni],
                          {"error_rms_deg": err, "sd_rms_deg": [r["sd_at_reference_deg"] for r in uni]}),
        }
    two = [r for r in recs if r["status"] == "two_roots"]
    if two:
        near = [min(abs(e) for e in r["error_deg"]) <= 3.0 * max(r["sd_at_reference_deg"] or 0.0, 1e-9) for r in two]
        s["two_roots"] = {"count": len(two), "reference_matches_a_root": int(sum(near)),
                          "note": "both roots fit exactly; the data cannot choose (a third line or a prior must)"}
    lb = [r for r in recs if r["status"] == "lower_bound"]
    if lb:
        s["lower_bound"] = {"count": len(lb), "bound_holds": int(sum(r["bound_holds"] for r in lb)),
                            "median_bound_minus_reference_deg":
                                float(np.median([r["bound_minus_reference_deg"] for r in lb])),
                            "note": "axis unknown: only gamma >= bound is known; the tilt itself is not recoverable"}
    inc = [r for r in recs if r["status"] == "inconsistent"]
    if inc:
        s["inconsistent"] = {"count": len(inc),
                             "reference_tilt_deg": {"median": float(np.median([r["reference_tilt_deg"] for r in inc])),
                                                    "max": float(np.max([r["reference_tilt_deg"] for r in inc]))},
                             "note": "the noisy angles fit no tilt (typically near zero tilt, where an image angle "
                                     "larger than the 3D angle is noise)"}
    return s

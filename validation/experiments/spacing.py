"""The distribution experiment (the chapter's Figs. 10-11): (a) every labelled spoke's image
angle against exact projection at the reference pose, and its angular variation; (b) the
orientation refitted from subsets of the spokes (every spoke, every 2nd, ...) against the
Cramer-Rao bound of each subset. See `pencilcal.validation.experiments`.

Example
-------
>>> import numpy as np
>>> from pencilcal.validation.experiments.synthetic import synthetic_validation
>>> r = distribution(synthetic_validation(np.arange(10.0, 61.0, 10.0), sigma_deg=0.05))
>>> r["status"], r["angles"]["count"], [s["stride"] for s in r["spacing"]["strides"]]
('ok', 48, [1, 2, 3])
"""
from __future__ import annotations

import math

import numpy as np

from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.geometry.angles import wrap_line
from pencilcal.toolkit.geometry.frames import angle_between
from pencilcal.toolkit.pencil.chapter import general_parameters
from pencilcal.toolkit.pencil.estimator import crlb, detection_threshold, fit_pencil, max_angular_change
from pencilcal.toolkit.pencil.spec import image_angles

from .axis import adjacent_pairs, fan_order, frame_axis, sequence_axis, t_plane
from .frames import frames_or_fail, sigma_line
from .sections import GROSS_Z, INSUFFICIENT, deg_or_none, finish, header, insufficient_section, rms, tilt_bins

__all__ = ["distribution"]


def _subsets(th_pencil, strides):
    """(stride, offset, spoke indices, spacing [rad]) of every subset with >= 3 spokes."""
    order, _ = fan_order(th_pencil)
    out = []
    for m in strides:
        for o in range(m):
            idx = order[o::m]
            if idx.size < 3:
                continue
            s = np.unwrap(np.asarray(th_pencil, float)[idx])
            spacing = float(np.median(np.abs(np.diff(s))))
            out.append((int(m), int(o), [int(i) for i in idx], spacing))
    return out


def distribution(v, *, strides=(1, 2, 3)):
    """The pencil's angular distribution and the error of spoke subsets (`pencilcal.validation.experiments`).

    v: validation dict; strides: subsets take every m-th spoke (in angle order), every
    offset, for each m. Returns the result dict (JSON-ready).
    """
    strides = tuple(int(m) for m in strides)
    if not strides or any(m < 1 for m in strides):
        raise InputError(f"strides must be positive integers, got {strides!r}")
    frames, skipped = frames_or_fail(v)
    out = header(v, "distribution", frames, skipped)
    sig = sigma_line(frames)
    th_p = np.radians(np.asarray(v["pencil"]["angles_deg"], float))
    seq_axis = sequence_axis(frames)
    # (a) every line against exact projection at the reference pose
    out["angles"] = _angles_section(frames, th_p, seq_axis)
    sigma_scale = out["angles"]["sigma_scale"]
    # (b) subsets of the spokes
    recs, too_few = _subset_fits(frames, _subsets(th_p, strides))
    g_min = 2.0 * math.degrees(float(detection_threshold(sig)))
    per = [_stride_summary(m, recs, g_min, sigma_scale) for m in strides]
    if all(p["status"] == INSUFFICIENT for p in per):
        out["spacing"] = insufficient_section("no subset of the spokes has three spokes seen in one frame",
                                              strides=per, fits=recs)
    else:
        out["spacing"] = {
            "status": "ok", "strides": per, "subsets_skipped_too_few_lines": too_few,
            "note": ("normal error of the closer twin (angles cannot choose it) and the Cramer-Rao bound at the "
                     "reference pose for the same lines; the RMS summaries use frames with reference tilt >= twice "
                     "the detection threshold of the median line sigma, where the estimator is efficient. With "
                     "the right sigmas: *_z_rms ~ 1, normal_z_median ~ 0.83 (2-D error), tilt_z_median_abs ~ 0.67; "
                     "gross: fits whose normal error exceeds 5 x the bound (a mislabelled or spurious line, which "
                     "three lines cannot reveal); normal_ratio_over_sigma_scale divides the error/bound ratio by "
                     "how much the lines actually scatter (angles.sigma_scale)"),
            "fits": recs,
        }
    return finish(out, ["angles", "spacing"])


def _frame_lines(f, th_p, seq_axis, adj):
    """(lines, neighbours) of one frame: each measured line against exact projection at the
    reference pose with its angular variation, and each pair of neighbouring spokes seen."""
    lines = []
    neighbours = []
    pred = image_angles(f.R_ref, f.x_ref, f.th)
    r = wrap_line(f.a - pred)
    phi, src = frame_axis(f, seq_axis, f.x_ref)
    p = general_parameters(f.R_ref, f.x_ref)
    if phi is None:  # frontal reference: any in-plane axis gives zero variation
        phi = float(p["theta_offset"])
    a_ax = float(image_angles(f.R_ref, f.x_ref, np.array([phi]))[0])
    b_ax = float(t_plane(np.array([a_ax]), p)[0][0])
    b_m, _ = t_plane(f.a, p)
    b_p, _ = t_plane(pred, p)
    th_ax = wrap_line(f.th - phi)
    var_m = wrap_line(wrap_line(b_m - b_ax) - th_ax)
    var_p = wrap_line(wrap_line(b_p - b_ax) - th_ax)
    for i in range(f.a.size):
        lines.append({"frame": f.index, "image": f.image, "reference_tilt_deg": math.degrees(f.tilt_ref),
                      "spoke": int(f.spoke[i]), "theta_from_axis_deg": math.degrees(float(th_ax[i])),
                      "measured_deg": math.degrees(float(f.a[i])), "predicted_deg": math.degrees(float(pred[i])),
                      "residual_deg": math.degrees(float(r[i])), "sigma_deg": math.degrees(float(f.sigma[i])),
                      "z": float(r[i] / f.sigma[i]),
                      "variation_measured_deg": math.degrees(float(var_m[i])),
                      "variation_predicted_deg": math.degrees(float(var_p[i]))})
    pos = {int(k): i for i, k in enumerate(f.spoke)}
    for s1, s2 in adj:
        if s1 in pos and s2 in pos:
            i, k = pos[s1], pos[s2]
            d3 = float(wrap_line(th_p[s2] - th_p[s1]))
            neighbours.append({"frame": f.index, "reference_tilt_deg": math.degrees(f.tilt_ref), "spokes": [s1, s2],
                               "angle_3d_deg": math.degrees(d3),
                               "measured_deg": math.degrees(float(wrap_line(f.a[k] - f.a[i]))),
                               "predicted_deg": math.degrees(float(wrap_line(pred[k] - pred[i])))})
    return lines, neighbours


def _angles_section(frames, th_p, seq_axis):
    """Section (a): every line of every frame against exact projection, with summaries."""
    lines = []
    neighbours = []
    adj = adjacent_pairs(th_p)
    for f in frames:
        ln_f, nb_f = _frame_lines(f, th_p, seq_axis, adj)
        lines += ln_f
        neighbours += nb_f
    res = np.array([ln["residual_deg"] for ln in lines])
    z = np.array([ln["z"] for ln in lines])
    tilts = np.array([ln["reference_tilt_deg"] for ln in lines])
    per_frame_max = {}
    for ln in lines:
        k = ln["frame"]
        per_frame_max[k] = max(per_frame_max.get(k, 0.0), abs(ln["variation_measured_deg"]))
    maxvar = [{"frame": f.index, "reference_tilt_deg": math.degrees(f.tilt_ref),
               "max_variation_measured_deg": per_frame_max.get(f.index),
               "max_variation_predicted_deg":
                   max(abs(ln["variation_predicted_deg"]) for ln in lines if ln["frame"] == f.index),
               "max_angular_change_deg": math.degrees(float(max_angular_change(f.tilt_ref)))} for f in frames]
    angles = {
        "status": "ok",
        "vertex_for_prediction": sorted({f.vertex_source for f in frames}),
        "sequence_axis_deg": deg_or_none(seq_axis),
        "residual_rms_deg": float(np.sqrt(np.mean(res ** 2))),
        "residual_median_abs_deg": float(np.median(np.abs(res))),
        "residual_max_abs_deg": float(np.max(np.abs(res))),
        "z_rms": float(np.sqrt(np.mean(z ** 2))),
        "sigma_scale": float(np.median(np.abs(z)) / 0.6745),
        "sigma_scale_note": ("median |z| / 0.6745: how much the lines scatter about the reference prediction "
                             "relative to their stated sigma (1: as stated; it includes the reference's error)"),
        "z_within_1": float(np.mean(np.abs(z) <= 1.0)),
        "z_within_3": float(np.mean(np.abs(z) <= 3.0)),
        "count": int(res.size),
        "note": "residual = measured - exact projection at the reference pose; z = residual / the line's sigma",
        "bins": tilt_bins(tilts, {"residual_rms_deg": res, "sigma_rms_deg": [ln["sigma_deg"] for ln in lines]}),
        "max_variation": maxvar,
        "lines": lines,
        "neighbours": neighbours,
    }
    if neighbours:
        nr = [wrap_line(math.radians(n["measured_deg"] - n["predicted_deg"])) for n in neighbours]
        angles["neighbours_summary"] = {
            "count": len(neighbours),
            "residual_rms_deg": math.degrees(float(np.sqrt(np.mean(np.square(nr))))),
            "max_change_predicted_deg": max(abs(n["predicted_deg"] - n["angle_3d_deg"]) for n in neighbours),
            "max_change_measured_deg": max(abs(n["measured_deg"] - n["angle_3d_deg"]) for n in neighbours),
            "note": "image angle between neighbouring spokes: measured vs exact projection; change = image - 3D angle",
        }
    return angles


def _subset_fits(frames, subsets):
    """(records, skipped): the orientation refitted from each subset of spokes in each frame,
    with its errors and Cramer-Rao bound at the reference; subsets with fewer than three
    spokes seen are counted in skipped."""
    recs = []
    too_few = 0
    for f in frames:
        n_ref = f.R_ref[:, 2]
        for (m, o, idx, spacing) in subsets:
            mask = np.isin(f.spoke, idx)
            if int(mask.sum()) < 3 or np.unique(f.spoke[mask]).size < 3:
                too_few += 1
                continue
            try:
                fit = fit_pencil(f.a[mask], f.th[mask], f.x, f.sigma[mask], f.vertex_cov)
            except (EstimationError, InputError) as e:
                recs.append({"frame": f.index, "stride": m, "offset": o, "ok": False, "error": str(e)})
                continue
            e_n = min(float(angle_between(fit.normal, n_ref)), float(angle_between(fit.normal_twin, n_ref)))
            _, b_tilt, b_norm = crlb(f.R_ref, f.x_ref, f.th[mask], f.sigma[mask], f.vertex_cov)
            recs.append({
                "frame": f.index, "image": f.image, "reference_tilt_deg": math.degrees(f.tilt_ref), "stride": m,
                "offset": o, "spacing_deg": math.degrees(spacing), "lines": int(mask.sum()), "ok": True,
                "tilt_deg": math.degrees(float(fit.tilt)), "tilt_error_deg": math.degrees(float(fit.tilt) - f.tilt_ref),
                "normal_error_closer_deg": math.degrees(e_n),
                "tilt_sigma_deg": deg_or_none(float(fit.tilt_sigma)), "normal_sigma_deg": deg_or_none(float(fit.normal_sigma)),
                "detectable": bool(fit.detectable),
                "crlb_tilt_deg": deg_or_none(float(b_tilt)) if np.degrees(b_tilt) < 90 else None,
                "crlb_normal_deg": deg_or_none(float(b_norm)) if np.degrees(b_norm) < 90 else None,
            })
    return recs, too_few


def _stride_summary(m, recs, g_min, sigma_scale):
    """One stride's row of the spacing section: its fits' errors against their bounds, over
    the frames tilted at least `g_min` [deg]."""
    rs = [r for r in recs if r.get("stride") == m and r.get("ok")]
    if not rs:
        return {"stride": m, "status": INSUFFICIENT,
                "reason": "no subset of this stride has three spokes seen in one frame"}
    use = [r for r in rs if r["reference_tilt_deg"] >= g_min and r["crlb_normal_deg"]]
    row = {"stride": m, "status": "ok", "spacing_deg": float(np.median([r["spacing_deg"] for r in rs])),
           "lines_median": float(np.median([r["lines"] for r in rs])), "fits": len(rs),
           "above_tilt_deg": g_min, "fits_above": len(use)}
    if use:
        en = [r["normal_error_closer_deg"] for r in use]
        bn = [r["crlb_normal_deg"] for r in use]
        et = [r["tilt_error_deg"] for r in use]
        bt = [r["crlb_tilt_deg"] for r in use]
        row.update({
            "normal_error_rms_deg": rms(en), "normal_crlb_rms_deg": rms(bn),
            "normal_ratio": rms(en) / rms(bn),
            "normal_z_rms": rms([e / b for e, b in zip(en, bn)]),
            "tilt_error_rms_deg": rms(et), "tilt_crlb_rms_deg": rms(bt),
            "tilt_ratio": rms(et) / rms(bt),
            "tilt_z_rms": rms([e / b for e, b in zip(et, bt)]),
            "normal_ratio_over_sigma_scale": rms(en) / rms(bn) / sigma_scale,
            "normal_error_median_deg": float(np.median(en)), "normal_crlb_median_deg": float(np.median(bn)),
            "normal_z_median": float(np.median([e / b for e, b in zip(en, bn)])),
            "tilt_z_median_abs": float(np.median([abs(e) / b for e, b in zip(et, bt)])),
            "gross": int(sum(e > GROSS_Z * b for e, b in zip(en, bn))),
            "bins": tilt_bins([r["reference_tilt_deg"] for r in use],
                              {"normal_error_rms_deg": en, "normal_crlb_rms_deg": bn}),
        })
    return row

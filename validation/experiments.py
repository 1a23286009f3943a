"""The book chapter's experiments, reproduced on a validation.json (synthetic or real).

Each experiment reads the per-frame records that `pencilcal validate` writes (the exact
model's labelled lines ``orient.exact.lines``, the reference pose ``R_ref``/``t_ref`` and
``reference_tilt_deg``) and compares what the lines say with what the reference pose
predicts. The reference is the exact truth for a `pencilcal simulate` folder and the best
PnP pose of the board for real images; with PnP the "errors" include the reference's own
error (a few hundredths of a degree on the da Vinci frames).

``single_angle`` (the chapter's Figs. 8-9)
    Pairs of spokes with a known 3D angle give the tilt through
    `toolkit.single_angle.single_angle_tilt`. The tilt axis is taken from the reference
    pose: the in-plane direction ``u_r = v_d x n`` (chapter.general_parameters), whose
    image through the vertex is computed by exact projection. Every measured line angle
    is first moved into the plane T orthogonal to the vertex ray
    (``aligned_angles(a - psi_i, gamma_i)``), where the chapter's eq. 6 holds exactly.
    Three cases: ``on_line`` (one spoke lies on the axis; its *measured* line is the axis
    image), ``known`` (the axis image from the reference, neither line on it: one or two
    admissible tilts) and ``unknown`` (no axis: only a lower bound on the tilt). Statuses
    other than "unique" are counted and reported as they are; a two-root or lower-bound
    result is never turned into one number.
``distribution`` (Figs. 10-11)
    (a) The image angle of every labelled spoke against exact projection at the reference
    pose, and its *angular variation*: the angle in T from the tilt axis minus the 3D
    angle from the axis (atan(tan theta cos gamma) - theta; for a vertex on the optical
    axis this is the change of the image angle from its value at zero tilt). (b) The
    orientation refitted (`estimator.fit_pencil`) from subsets of the spokes (every spoke,
    every 2nd, every 3rd, ...), with the Cramer-Rao bound of each subset at the reference.
``threshold``
    The tilt at which the estimator's ``detectable`` flag turns on for half of the frames
    (monotone regression, bootstrap interval), the tilt below which the tilt error is as
    large as half the tilt itself, and the estimated tilt of frontal-ish frames, against
    2 sqrt(sigma), `estimator.detection_threshold` and GEOMETRY.md's noise floor (median
    3.75 deg at sigma = 0.1 deg, scaled by sqrt(sigma)), each with the measured line sigma.

Each function returns a JSON-ready dict with a top-level ``status``: "ok", "partial" (some
sections lacked the data; each such section has ``status: "insufficient data"`` and a
``reason``, and keeps what the data do bound, e.g. "below the smallest tilt seen") or
"insufficient data" (every section; ``reason`` joins theirs). EstimationError is raised
only when no frame has both the exact model's lines and a reference pose. Angles in the
output are degrees; arguments and internal arrays are radians unless named ``*_deg``.

Example
-------
>>> import numpy as np
>>> v = synthetic_validation(np.arange(0.0, 61.0, 10.0), sigma_deg=0.05, axis_deg=30.0)  # or load_validation(path)
>>> r = single_angle(v)
>>> r["status"], r["on_line"]["counts"]["unique"], r["unknown"]["counts"]
('ok', 44, {'lower_bound': 49})
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pencilcal.toolkit.geometry.angles import circular_mean, wrap_line
from pencilcal.toolkit.pencil.chapter import aligned_angles, general_parameters
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.pencil.defaults import DETECTION_LEVEL
from pencilcal.toolkit.pencil.estimator import (
    crlb,
    detection_threshold,
    fit_pencil,
    frontal_fit,
    max_angular_change,
)
from pencilcal.toolkit.geometry.frames import angle_between
from pencilcal.toolkit.pencil.spec import image_angles

from .validation_file import load_pencil_validation as load_validation

__all__ = [
    "EXPERIMENTS",
    "load_validation",
    "usable_frames",
    "single_angle",
    "distribution",
    "threshold",
    "sd_on_line",
    "figure_paths",
    "write_figures",
    "synthetic_validation",
    "GEOMETRY_FRONTAL_MEDIAN_DEG",
    "GEOMETRY_FRONTAL_P95_DEG",
]

EXPERIMENTS = ("single-angle", "distribution", "threshold")

#: GEOMETRY.md: a truly frontal pencil (8 lines, sigma = 0.1 deg) is estimated at a median
#: tilt of 3.75 deg (95th percentile 5.3 deg); the floor scales with sqrt(sigma).
GEOMETRY_FRONTAL_MEDIAN_DEG = 3.75
GEOMETRY_FRONTAL_P95_DEG = 5.3
_GEOMETRY_SIGMA_DEG = 0.1

# below this reference tilt the tilt axis v_d x n is not defined by the pose
_AXIS_MIN_TILT = math.radians(1e-3)
# a sequence whose per-frame axes agree to this (circular sd, line period) has a fixed axis
_AXIS_SPREAD = math.radians(1.0)
# tilt bins of the summaries [deg]
_BIN_DEG = 10.0
# the chi-square(2) quantile of the estimator's likelihood-ratio test
_CHI2_2 = -2.0 * math.log(DETECTION_LEVEL)
_INSUFFICIENT = "insufficient data"
# a single-angle result this many sd off the reference is a gross error (a wrong root)
_GROSS_Z = 5.0


# ------------------------------------------------------------------------------ input
@dataclass
class Frame:
    """One frame's measured lines and reference pose, as the experiments use them.

    index, image: position and name in the validation file.
    a, sigma: (N,) measured image angles and their sd [rad], normalised coordinates.
    spoke: (N,) int spoke labels; th: (N,) their 3D angles [rad] in the target frame.
    x: (2,) measured vertex (normalised); vertex_cov: (2, 2) or None.
    x_ref: (2,) the vertex's image at the reference pose (x when the pencil has no vertex).
    vertex_source: "reference" or "measured" (which one x_ref is).
    R_ref, t_ref: reference pose; tilt_ref: reference tilt [rad] (the file's value).
    orient: the exact model's orientation record; crlb: the file's bound record.
    reference_sigma_deg: the PnP reference's normal sd [deg] (None for truth).
    """

    index: int
    image: str
    a: np.ndarray
    sigma: np.ndarray
    spoke: np.ndarray
    th: np.ndarray
    x: np.ndarray
    vertex_cov: np.ndarray | None
    x_ref: np.ndarray
    vertex_source: str
    R_ref: np.ndarray
    t_ref: np.ndarray | None
    tilt_ref: float
    orient: dict = field(default_factory=dict)
    crlb: dict | None = None
    reference_sigma_deg: float | None = None


def _vertex_image(R, t, vertex):
    if vertex is None or t is None:
        return None
    P = R @ np.array([vertex[0], vertex[1], 0.0]) + t
    if not P[2] > 0:
        return None
    return P[:2] / P[2]


def usable_frames(v):
    """Frames with the exact model's lines and a reference pose.

    Returns (frames: list of Frame, skipped: list of {image, reason}).
    """
    th_all = np.radians(np.asarray(v["pencil"]["angles_deg"], float))
    vertex = v["pencil"].get("vertex")
    out, skipped = [], []
    for i, f in enumerate(v["frames"]):
        if not isinstance(f, dict):
            skipped.append({"image": str(i), "reason": "not a frame record"})
            continue
        name = str(f.get("image", i))
        ex = (f.get("orient") or {}).get("exact") or {}
        if not ex.get("ok"):
            skipped.append({"image": name, "reason": ex.get("error") or f.get("error") or "no exact-model estimate"})
            continue
        ln = ex.get("lines")
        if not isinstance(ln, dict):
            skipped.append({"image": name, "reason": "no orient.exact.lines (validate with --models including exact)"})
            continue
        if ex.get("labels_ambiguous"):
            skipped.append({"image": name, "reason": "spoke labels ambiguous (another labelling fits as well: the fan "
                                                      "shifted by a spoke when no end spoke is seen, or a spurious line "
                                                      "on another labelling's prediction), so the lines' 3D angles are "
                                                      "unknown"})
            continue
        if f.get("R_ref") is None:
            skipped.append({"image": name, "reason": f.get("error") or "no reference pose"})
            continue
        try:
            a = np.asarray(ln["angle"], float)
            s = np.asarray(ln["sigma"], float)
            k = np.asarray(ln["spoke"], int)
            x = np.asarray(ln["vertex"], float).reshape(2)
            R = np.asarray(f["R_ref"], float).reshape(3, 3)
            t = None if f.get("t_ref") is None else np.asarray(f["t_ref"], float).reshape(3)
            cov = None if ln.get("vertex_cov") is None else np.asarray(ln["vertex_cov"], float).reshape(2, 2)
        except (KeyError, TypeError, ValueError) as e:
            skipped.append({"image": name, "reason": f"malformed lines or reference ({type(e).__name__})"})
            continue
        if not (a.shape == s.shape == k.shape and a.ndim == 1 and np.all((k >= 0) & (k < th_all.size))):
            skipped.append({"image": name, "reason": "malformed lines (angle, sigma, spoke differ or bad labels)"})
            continue
        xr = _vertex_image(R, t, vertex)
        src = "reference" if xr is not None else "measured"
        xr = x if xr is None else xr
        tilt = f.get("reference_tilt_deg")
        if tilt is None:
            tilt = math.degrees(float(angle_between(R[:, 2], np.r_[xr, 1.0])))
        ref_sd = None
        best = f.get("pnp_best")
        if f.get("reference") == "pnp" and best and isinstance(f.get("pnp"), dict):
            ref_sd = (f["pnp"].get(best) or {}).get("normal_sigma_deg")
        out.append(Frame(i, name, a, s, k, th_all[k], x, cov, xr, src, R, t, math.radians(float(tilt)), ex,
                         f.get("crlb"), ref_sd))
    return out, skipped


def _sigma_line(frames):
    """Median line sd [rad] over every used line of every frame."""
    return float(np.median(np.concatenate([f.sigma for f in frames])))


def _deg(x):
    return None if x is None or not np.isfinite(x) else float(np.degrees(x))


def _section_insufficient(reason, **extra):
    return {"status": _INSUFFICIENT, "reason": reason, **extra}


def _finish(out, sections):
    """Top-level status from the sections: "ok", "partial" or "insufficient data" (then
    with the reasons joined in ``reason``; what the data bound is still in the sections)."""
    bad = [(k, out[k]["reason"]) for k in sections if out[k].get("status") == _INSUFFICIENT]
    out["insufficient"] = [{"section": k, "reason": r} for k, r in bad]
    if not bad:
        out["status"] = "ok"
    elif len(bad) < len(sections):
        out["status"] = "partial"
    else:
        out["status"] = _INSUFFICIENT
        out["reason"] = "; ".join(f"{k}: {r}" for k, r in bad)
    return out


def _header(v, name, frames, skipped):
    sig = _sigma_line(frames)
    return {
        "experiment": name,
        "reference": v.get("reference"),
        "sequence": v.get("sequence"),
        "pencil": v.get("pencil"),
        "frames_used": len(frames),
        "frames_skipped": skipped,
        "sigma_line_deg": math.degrees(sig),
        "sigma_line_note": "median of orient.exact.lines.sigma (normalised image coordinates)",
    }


def _frames_or_fail(v):
    frames, skipped = usable_frames(v)
    if not frames:
        why = skipped[0]["reason"] if skipped else "the file has no frames"
        raise EstimationError(f"no frame has both the exact model's lines and a reference pose (e.g. {why})")
    return frames, skipped


def _bins(tilts_deg, values, weights=None):
    """Per tilt bin (10 deg): count, RMS (and median |.|) of each named array in `values`."""
    t = np.asarray(tilts_deg, float)
    out = []
    for lo in np.arange(0.0, 90.0, _BIN_DEG):
        m = (t >= lo) & (t < lo + _BIN_DEG)
        if not m.any():
            continue
        row = {"tilt_lo_deg": float(lo), "tilt_hi_deg": float(lo + _BIN_DEG), "count": int(m.sum())}
        for k, arr in values.items():
            a = np.asarray(arr, float)[m]
            a = a[np.isfinite(a)]
            row[k] = float(np.sqrt(np.mean(a * a))) if a.size else None
            if "_rms_" in k:  # and the median, which a single near-zero-tilt value cannot dominate
                row[k.replace("_rms_", "_median_abs_")] = float(np.median(np.abs(a))) if a.size else None
        out.append(row)
    return out


def _rms(x):
    a = np.asarray([v for v in x if v is not None], float)
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a * a))) if a.size else None


# ------------------------------------------------------------------------ single angle
def sd_on_line(gamma, theta, sigma):
    """The chapter's single-angle sd: sigma (1 + cos^2 g tan^2 theta) / (tan theta sin g).

    gamma, theta, sigma: broadcastable [rad] (theta from the axis; sigma the sd of the
    image angle between the two lines). Returns [rad]; inf at gamma = 0.
    """
    g = np.asarray(gamma, float)
    tt = np.abs(np.tan(np.asarray(theta, float)))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(np.sin(g) > 0, sigma * (1.0 + np.cos(g) ** 2 * tt * tt) / (tt * np.sin(g)), np.inf)


def _t_plane(a, p):
    """Image angles (normalised) -> angles in T from u_i, and the gain d(angle in T)/d a."""
    gi = float(p["gamma_i"])
    u = np.asarray(a, float) - float(p["psi_i"])
    b = aligned_angles(u, gi)
    gain = math.cos(gi) / (np.cos(u) ** 2 + np.sin(u) ** 2 * math.cos(gi) ** 2)
    return b, gain


def _sequence_axis(frames):
    """Target-frame tilt axis shared by the sequence (a tilt sweep), or None."""
    phis = []
    for f in frames:
        p = general_parameters(f.R_ref, f.x)
        if float(p["gamma_r"]) > math.radians(0.5):
            phis.append(float(p["theta_offset"]))
    if len(phis) < 2:
        return None
    phis = np.asarray(phis)
    m = float(circular_mean(phis, period=np.pi))
    spread = float(np.sqrt(np.mean(wrap_line(phis - m) ** 2)))
    return m if spread < _AXIS_SPREAD else None


def _frame_axis(f, seq_axis, vertex=None):
    """(phi [rad] in the target frame, source) of the tilt axis in this frame, or (None, why).

    vertex: the normalised vertex the axis u_r = v_d x n is formed with (default: measured)."""
    p = general_parameters(f.R_ref, f.x if vertex is None else vertex)
    if float(p["gamma_r"]) > _AXIS_MIN_TILT:
        return float(p["theta_offset"]), "frame"
    if seq_axis is not None:
        return seq_axis, "sequence"
    return None, "the reference pose is frontal: its tilt axis is undefined"


def _fan_order(th_pencil):
    """Spoke indices in angle order, starting after the largest gap (a fan stays contiguous
    across +-180 deg), and whether the spokes go round the full circle (no gap wider than
    the others)."""
    th = np.remainder(np.asarray(th_pencil, float), 2 * np.pi)
    order = np.argsort(th, kind="stable")
    s = th[order]
    gaps = np.diff(np.r_[s, s[0] + 2 * np.pi])  # gaps[i]: from spoke i to the next, cyclic
    big = int(np.argmax(gaps))
    order = np.roll(order, -(big + 1))
    others = np.delete(gaps, big)
    closed = bool(others.size and gaps[big] <= others.max() + 1e-9)
    return order, closed


def _adjacent_pairs(th_pencil):
    """Index pairs of spokes that are neighbours in angle (a fan's consecutive spokes)."""
    order, closed = _fan_order(th_pencil)
    pairs = [(int(order[i]), int(order[i + 1])) for i in range(len(order) - 1)]
    if closed:  # a fan round the full circle: close it
        pairs.append((int(order[-1]), int(order[0])))
    return pairs


def _call_single(alpha, theta, case, sigma):
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
    rec.update(status=res.status, message=res.message, gamma_deg=gam, sd_deg=[_deg(s) for s in res.sigma])
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
        sd_ref = _deg(res_ref.sigma[j])
    rec["sd_at_reference_deg"] = sd_ref
    if res.status == "unique" and sd_ref:
        rec["z"] = rec["error_deg"][0] / sd_ref
    return rec


def single_angle(v, *, pairs="adjacent", on_axis_tol_deg=0.05, cases=("on_line", "known", "unknown")):
    """The chapter's single-angle test on every frame (module docstring).

    v: a validation dict (`load_validation`). pairs: "adjacent" (neighbouring spokes) or
    "all" (every pair of distinct line directions) for the "known" and "unknown" cases;
    "on_line" always pairs the axis spoke with every other spoke. on_axis_tol_deg: how
    close to the tilt axis a spoke must be to count as on it (its offset is reported).
    Returns the result dict (JSON-ready).
    """
    if pairs not in ("adjacent", "all"):
        raise InputError(f"pairs must be 'adjacent' or 'all', got {pairs!r}")
    frames, skipped = _frames_or_fail(v)
    out = _header(v, "single-angle", frames, skipped)
    sig = _sigma_line(frames)
    th_p = np.radians(np.asarray(v["pencil"]["angles_deg"], float))
    seq_axis = _sequence_axis(frames)
    tol = math.radians(on_axis_tol_deg)
    if pairs == "adjacent":
        spoke_pairs = _adjacent_pairs(th_p)
    else:
        spoke_pairs = [(i, j) for i in range(th_p.size) for j in range(i + 1, th_p.size)
                       if abs(math.sin(th_p[j] - th_p[i])) > 1e-6]
    records = {c: [] for c in cases}
    axis_info = []
    no_axis = []
    for f in frames:
        phi, src = _frame_axis(f, seq_axis)
        p = general_parameters(f.R_ref, f.x)
        b, gain = _t_plane(f.a, p)
        s_t = f.sigma * gain  # the lines' sd in T
        pred = image_angles(f.R_ref, f.x, f.th)
        b_pred, _ = _t_plane(pred, p)
        info = {"frame": f.index, "image": f.image, "reference_tilt_deg": math.degrees(f.tilt_ref),
                "axis_source": src if phi is not None else None}
        if phi is None:
            no_axis.append({"image": f.image, "reason": src})
        else:
            a_ax = float(image_angles(f.R_ref, f.x, np.array([phi]))[0])
            b_ax, _ = _t_plane(np.array([a_ax]), p)
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
    out["sequence_axis_deg"] = _deg(seq_axis)
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
    if "on_line" in out and out["on_line"].get("status") != _INSUFFICIENT:
        thetas = sorted({round(abs(r["theta_deg"]), 9) for r in records["on_line"]})
        g = np.radians(np.arange(1.0, 90.0, 1.0))
        out["theory"]["curves"] = [
            {"theta_deg": t, "tilt_deg": np.degrees(g).tolist(),
             "sd_deg": np.degrees(sd_on_line(g, math.radians(t), math.sqrt(2.0) * sig)).tolist()} for t in thetas]
    return _finish(out, list(cases))


def _single_summary(case, recs, frames, no_axis, min_tilt_deg):
    if not recs:
        if case == "on_line":
            why = ("no spoke lies on the tilt axis of the reference pose (within the tolerance) in any frame"
                   if len(no_axis) < len(frames) else "no frame has a defined tilt axis")
        elif case == "known":
            why = "no frame has a defined tilt axis" if no_axis else "no pair of spokes was seen together"
        else:
            why = "no pair of spokes was seen together"
        return _section_insufficient(why, pairs=[])
    statuses = ("unique", "two_roots", "lower_bound", "inconsistent", "no information")
    counts = {s: sum(r["status"] == s for r in recs) for s in statuses}
    s = {"status": "ok", "counts": {k: v for k, v in counts.items() if v}, "pairs": recs}
    uni = [r for r in recs if r["status"] == "unique"]
    if uni:
        err = [r["error_deg"][0] for r in uni]
        z = [r.get("z") for r in uni if r.get("z") is not None]
        above = [r for r in uni if r["reference_tilt_deg"] >= min_tilt_deg and r.get("z") is not None]
        za = [r["z"] for r in above]
        gross = [r for r in uni if r.get("z") is not None and abs(r["z"]) > _GROSS_Z]
        s["unique"] = {
            "count": len(uni),
            "error_median_abs_deg": float(np.median(np.abs(err))),
            "error_rmse_deg": _rms(err),
            "z_rms": _rms(z),
            "z_within_1": float(np.mean(np.abs(z) <= 1.0)) if z else None,
            "z_median_abs": float(np.median(np.abs(z))) if z else None,
            "z_count": len(z),
            "above_tilt_deg": min_tilt_deg,
            "above": {"count": len(above), "error_rmse_deg": _rms([r["error_deg"][0] for r in above]),
                      "sd_rms_deg": _rms([r["sd_at_reference_deg"] for r in above]), "z_rms": _rms(za),
                      "z_within_1": float(np.mean(np.abs(za) <= 1.0)) if za else None,
                      "z_median_abs": float(np.median(np.abs(za))) if za else None},
            "gross": {"count": len(gross), "threshold_z": _GROSS_Z,
                      "reference_tilt_deg": sorted({round(r["reference_tilt_deg"], 6) for r in gross}),
                      "note": ("'unique' results more than 5 sd off: near zero tilt the noise can push the "
                               "right root past cos(gamma) = 1, leaving only a far root, reported as unique")},
            "z_note": ("z = error / sd at the reference tilt: RMS 1, 68% within 1 and median |z| 0.67 when the sigmas "
                       "are right; "
                       "'above' keeps frames tilted at least twice the detection threshold"),
            "bins": _bins([r["reference_tilt_deg"] for r in uni],
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


# ------------------------------------------------------------------------ distribution
def _subsets(th_pencil, strides):
    """(stride, offset, spoke indices, spacing [rad]) of every subset with >= 3 spokes."""
    order, _ = _fan_order(th_pencil)
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
    """The pencil's angular distribution and the error of spoke subsets (module docstring).

    v: validation dict; strides: subsets take every m-th spoke (in angle order), every
    offset, for each m. Returns the result dict (JSON-ready).
    """
    strides = tuple(int(m) for m in strides)
    if not strides or any(m < 1 for m in strides):
        raise InputError(f"strides must be positive integers, got {strides!r}")
    frames, skipped = _frames_or_fail(v)
    out = _header(v, "distribution", frames, skipped)
    sig = _sigma_line(frames)
    th_p = np.radians(np.asarray(v["pencil"]["angles_deg"], float))
    seq_axis = _sequence_axis(frames)
    # (a) every line against exact projection at the reference pose
    lines = []
    neighbours = []
    adj = _adjacent_pairs(th_p)
    for f in frames:
        pred = image_angles(f.R_ref, f.x_ref, f.th)
        r = wrap_line(f.a - pred)
        phi, src = _frame_axis(f, seq_axis, f.x_ref)
        p = general_parameters(f.R_ref, f.x_ref)
        if phi is None:  # frontal reference: any in-plane axis gives zero variation
            phi = float(p["theta_offset"])
        a_ax = float(image_angles(f.R_ref, f.x_ref, np.array([phi]))[0])
        b_ax = float(_t_plane(np.array([a_ax]), p)[0][0])
        b_m, _ = _t_plane(f.a, p)
        b_p, _ = _t_plane(pred, p)
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
    out["angles"] = {
        "status": "ok",
        "vertex_for_prediction": sorted({f.vertex_source for f in frames}),
        "sequence_axis_deg": _deg(seq_axis),
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
        "bins": _bins(tilts, {"residual_rms_deg": res, "sigma_rms_deg": [ln["sigma_deg"] for ln in lines]}),
        "max_variation": maxvar,
        "lines": lines,
        "neighbours": neighbours,
    }
    if neighbours:
        nr = [wrap_line(math.radians(n["measured_deg"] - n["predicted_deg"])) for n in neighbours]
        out["angles"]["neighbours_summary"] = {
            "count": len(neighbours),
            "residual_rms_deg": math.degrees(float(np.sqrt(np.mean(np.square(nr))))),
            "max_change_predicted_deg": max(abs(n["predicted_deg"] - n["angle_3d_deg"]) for n in neighbours),
            "max_change_measured_deg": max(abs(n["measured_deg"] - n["angle_3d_deg"]) for n in neighbours),
            "note": "image angle between neighbouring spokes: measured vs exact projection; change = image - 3D angle",
        }
    sigma_scale = out["angles"]["sigma_scale"]
    # (b) subsets of the spokes
    subsets = _subsets(th_p, strides)
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
                "tilt_sigma_deg": _deg(float(fit.tilt_sigma)), "normal_sigma_deg": _deg(float(fit.normal_sigma)),
                "detectable": bool(fit.detectable),
                "crlb_tilt_deg": _deg(float(b_tilt)) if np.degrees(b_tilt) < 90 else None,
                "crlb_normal_deg": _deg(float(b_norm)) if np.degrees(b_norm) < 90 else None,
            })
    g_min = 2.0 * math.degrees(float(detection_threshold(sig)))
    per = []
    for m in strides:
        rs = [r for r in recs if r.get("stride") == m and r.get("ok")]
        if not rs:
            per.append({"stride": m, "status": _INSUFFICIENT,
                        "reason": "no subset of this stride has three spokes seen in one frame"})
            continue
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
                "normal_error_rms_deg": _rms(en), "normal_crlb_rms_deg": _rms(bn),
                "normal_ratio": _rms(en) / _rms(bn),
                "normal_z_rms": _rms([e / b for e, b in zip(en, bn)]),
                "tilt_error_rms_deg": _rms(et), "tilt_crlb_rms_deg": _rms(bt),
                "tilt_ratio": _rms(et) / _rms(bt),
                "tilt_z_rms": _rms([e / b for e, b in zip(et, bt)]),
                "normal_ratio_over_sigma_scale": _rms(en) / _rms(bn) / sigma_scale,
                "normal_error_median_deg": float(np.median(en)), "normal_crlb_median_deg": float(np.median(bn)),
                "normal_z_median": float(np.median([e / b for e, b in zip(en, bn)])),
                "tilt_z_median_abs": float(np.median([abs(e) / b for e, b in zip(et, bt)])),
                "gross": int(sum(e > _GROSS_Z * b for e, b in zip(en, bn))),
                "bins": _bins([r["reference_tilt_deg"] for r in use],
                              {"normal_error_rms_deg": en, "normal_crlb_rms_deg": bn}),
            })
        per.append(row)
    if all(p["status"] == _INSUFFICIENT for p in per):
        out["spacing"] = _section_insufficient("no subset of the spokes has three spokes seen in one frame",
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
    return _finish(out, ["angles", "spacing"])


# --------------------------------------------------------------------------- threshold
def _pav(y, w=None):
    """Isotonic (non-decreasing) regression by pool-adjacent-violators."""
    y = np.asarray(y, float)
    w = np.ones_like(y) if w is None else np.asarray(w, float)
    vals, wts, lens = [], [], []
    for yi, wi in zip(y, w):
        vals.append(yi)
        wts.append(wi)
        lens.append(1)
        while len(vals) > 1 and vals[-2] > vals[-1]:
            v2, w2, l2 = vals.pop(), wts.pop(), lens.pop()
            v1, w1, l1 = vals.pop(), wts.pop(), lens.pop()
            vals.append((v1 * w1 + v2 * w2) / (w1 + w2))
            wts.append(w1 + w2)
            lens.append(l1 + l2)
    return np.repeat(vals, lens)


def _crossing(x, y, level=0.5):
    """Where the isotonic fit of indicator y (increasing in x) crosses `level`.

    Returns (crossing, bracket (lo, hi)) or (None, None) when it does not cross (all on
    one side). x need not be sorted; ties are pooled.
    """
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    order = np.argsort(x, kind="stable")
    x, y = x[order], y[order]
    ux, inv = np.unique(x, return_inverse=True)
    ym = np.bincount(inv, weights=y) / np.bincount(inv)
    wm = np.bincount(inv).astype(float)
    fit = _pav(ym, wm)
    below = np.nonzero(fit < level)[0]
    above = np.nonzero(fit >= level)[0]
    if below.size == 0 or above.size == 0:
        return None, None
    i, j = below[-1], above[0]
    if j < i:  # cannot happen for a monotone fit
        return None, None
    f0, f1 = fit[i], fit[j]
    c = ux[i] + (level - f0) * (ux[j] - ux[i]) / (f1 - f0) if f1 > f0 else 0.5 * (ux[i] + ux[j])
    return float(c), (float(ux[i]), float(ux[j]))


def _bootstrap_crossing(x, y, n_boot, rng, level=0.5):
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    vals = []
    none = 0
    for _ in range(n_boot):
        k = rng.integers(0, x.size, x.size)
        c, _ = _crossing(x[k], y[k], level)
        if c is None:
            none += 1
        else:
            vals.append(c)
    if not vals:
        return None, none
    return (float(np.percentile(vals, 2.5)), float(np.percentile(vals, 97.5))), none


def _crossing_section(x, y, n_boot, rng, what, xname="reference tilt"):
    """Crossing of an increasing indicator, with bracket and bootstrap interval."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    c, bracket = _crossing(x, y)
    if c is None:
        if np.all(y >= 0.5):
            return None, f"every frame is {what}: the crossing lies below the smallest {xname} seen ({x.min():.3g} deg)", \
                {"upper_bound_deg": float(x.min())}
        return None, f"no frame is {what}: the crossing lies above the largest {xname} seen ({x.max():.3g} deg)", \
            {"lower_bound_deg": float(x.max())}
    ci, none = _bootstrap_crossing(x, y, n_boot, rng)
    lo, hi = bracket
    interval = [lo, hi] if ci is None else [min(ci[0], lo), max(ci[1], hi)]
    return {"tilt50_deg": c, "bracket_deg": [lo, hi], "bootstrap95_deg": None if ci is None else list(ci),
            "interval_deg": interval, "bootstrap_samples": n_boot, "bootstrap_no_crossing": none,
            "interval_note": ("bootstrap 95% percentile interval over frames, widened to the neighbouring sampled "
                              "tilts (the sweep cannot resolve the crossing more finely)")}, None, {}


def _interp_crossing(x, p, level=0.5):
    """First crossing of `level` by p(x) (x sorted ascending), linear interpolation."""
    x = np.asarray(x, float)
    p = np.asarray(p, float)
    for i in range(1, x.size):
        if (p[i - 1] - level) * (p[i] - level) <= 0 and p[i] != p[i - 1]:
            return float(x[i - 1] + (level - p[i - 1]) * (x[i] - x[i - 1]) / (p[i] - p[i - 1]))
    return None


def _detect_probability(f):
    """P(detectable) at the reference pose for this frame's lines: the estimator's
    likelihood-ratio statistic is ~ noncentral chi-square(2, lambda), lambda the chi2 of the
    best frontal pencil against noise-free angles."""
    from scipy.stats import ncx2

    pred = image_angles(f.R_ref, f.x_ref, f.th)
    _, lam = frontal_fit(pred[None], f.th[None], f.x_ref[None], (1.0 / f.sigma ** 2)[None])
    lam = float(np.asarray(lam).reshape(-1)[0])
    return float(ncx2.sf(_CHI2_2, 2, max(lam, 1e-12))), lam


def _monte_carlo_tilts(f, trials, rng):
    """Estimated tilts of `trials` noisy copies of this frame's lines at its reference pose."""
    pred = image_angles(f.R_ref, f.x_ref, f.th)
    a = pred[None, :] + rng.normal(size=(trials, pred.size)) * f.sigma[None, :]
    fit = fit_pencil(a, np.broadcast_to(f.th, a.shape), np.broadcast_to(f.x_ref, (trials, 2)),
                     np.broadcast_to(f.sigma, a.shape))
    return np.degrees(np.asarray(fit.tilt, float))


def threshold(v, *, n_boot=2000, trials=500, seed=0, relative=0.5, frontal_fraction=0.5):
    """The detection threshold measured on the data against the theory (module docstring).

    v: validation dict; n_boot: bootstrap resamples of the crossings; trials: Monte Carlo
    copies per frontal-ish frame; seed: random seed; relative: a frame's tilt error is
    "noise-level" when |error| >= relative x reference tilt; frontal_fraction: frames below
    frontal_fraction x detection_threshold(sigma) are frontal-ish.
    Returns the result dict (JSON-ready).
    """
    rng = np.random.default_rng(seed)
    frames, skipped = _frames_or_fail(v)
    out = _header(v, "threshold", frames, skipped)
    sig = _sigma_line(frames)
    sig_deg = math.degrees(sig)
    dt = math.degrees(float(detection_threshold(sig)))
    scale = math.sqrt(sig_deg / _GEOMETRY_SIGMA_DEG)
    per = []
    for f in frames:
        o = f.orient
        p_det, lam = _detect_probability(f)
        est = o.get("tilt_deg")
        err = None if est is None else float(est) - math.degrees(f.tilt_ref)
        crb = (f.crlb or {}).get("tilt_deg")
        g = math.degrees(f.tilt_ref)
        if crb:
            from scipy.stats import norm

            p_noise = float(2.0 * norm.sf(relative * g / crb))
        else:
            p_noise = 1.0
        per.append({"frame": f.index, "image": f.image, "reference_tilt_deg": g, "tilt_deg": est,
                    "tilt_error_deg": err, "tilt_sigma_deg": o.get("tilt_sigma_deg"),
                    "detectable": bool(o.get("detectable")), "predicted_detect_probability": p_det,
                    "noncentrality": lam, "crlb_tilt_deg": crb,
                    "noise_level": None if err is None else bool(abs(err) >= relative * g),
                    "predicted_noise_probability": p_noise, "tilt_threshold_deg": o.get("tilt_threshold_deg"),
                    "sigma_line_deg": math.degrees(float(np.median(f.sigma))), "lines": int(f.a.size)})
    per.sort(key=lambda r: r["reference_tilt_deg"])
    x = np.array([r["reference_tilt_deg"] for r in per])
    thr = [r["tilt_threshold_deg"] for r in per if r["tilt_threshold_deg"] is not None]
    out["theory"] = {
        "two_sqrt_sigma_deg": math.degrees(2.0 * math.sqrt(sig)),
        "detection_threshold_deg": dt,
        "frame_threshold_median_deg": float(np.median(thr)) if thr else None,
        "predicted_detect50_deg": _interp_crossing(x, [r["predicted_detect_probability"] for r in per]),
        "predicted_noise50_deg": _interp_crossing(x, [1.0 - r["predicted_noise_probability"] for r in per]),
        "notes": ("two_sqrt_sigma and detection_threshold: the tilt whose largest angular change equals sigma; "
                  "frame_threshold_median: the estimator's tilt_threshold_deg; predicted_detect50: where the "
                  "likelihood-ratio test at 1% detects half the time for these frames' lines (noncentral "
                  f"chi-square); predicted_noise50: where |error| >= {relative:g} x tilt half the time for a "
                  "Gaussian error with the Cramer-Rao sd"),
    }
    # detection crossing
    det = np.array([r["detectable"] for r in per], float)
    sec, why, extra = _crossing_section(x, det, n_boot, rng, "detectable")
    if sec is None:
        out["detection"] = _section_insufficient(why, **extra, frames=len(per), detectable=int(det.sum()))
    else:
        sec.update(status="ok", frames=len(per), detectable=int(det.sum()),
                   ratio_to_two_sqrt_sigma=sec["tilt50_deg"] / out["theory"]["two_sqrt_sigma_deg"],
                   ratio_to_detection_threshold=sec["tilt50_deg"] / dt)
        out["detection"] = sec
    # noise-level errors
    rows = [r for r in per if r["noise_level"] is not None]
    if not rows:
        out["noise_level"] = _section_insufficient("no frame has a tilt estimate")
    else:
        xn = np.array([r["reference_tilt_deg"] for r in rows])
        yn = np.array([not r["noise_level"] for r in rows], float)  # increasing: measured, not noise
        sec, why, extra = _crossing_section(xn, yn, n_boot, rng, f"measured to better than {relative:g} x its tilt")
        if sec is None:
            out["noise_level"] = _section_insufficient(
                why, **extra, definition=f"|tilt error| >= {relative:g} x reference tilt")
        else:
            sec.update(status="ok", definition=f"|tilt error| >= {relative:g} x reference tilt",
                       noise_level_frames=int(sum(r["noise_level"] for r in rows)),
                       ratio_to_two_sqrt_sigma=sec["tilt50_deg"] / out["theory"]["two_sqrt_sigma_deg"])
            out["noise_level"] = sec
    # frontal-ish frames
    lim = frontal_fraction * dt
    fr = [f for f in frames if math.degrees(f.tilt_ref) < frontal_fraction * dt]
    if fr:  # the floor of these frames: scale with their own line sigma
        sig_fr = math.degrees(float(np.median(np.concatenate([f.sigma for f in fr]))))
        scale = math.sqrt(sig_fr / _GEOMETRY_SIGMA_DEG)
    else:
        sig_fr = sig_deg
    geo = {"median_deg": GEOMETRY_FRONTAL_MEDIAN_DEG * scale, "p95_deg": GEOMETRY_FRONTAL_P95_DEG * scale,
           "sigma_deg": sig_fr,
           "note": ("GEOMETRY.md: median 3.75 deg (p95 5.3) at sigma 0.1 deg for 8 lines, scaled by "
                    "sqrt(sigma / 0.1 deg) with the median line sigma of the frontal-ish frames")}
    if not fr:
        out["frontal"] = _section_insufficient(
            f"no frame has a reference tilt below {lim:.3g} deg ({frontal_fraction:g} x the detection threshold "
            f"{dt:.3g} deg); the smallest is {x.min():.3g} deg", limit_deg=lim, geometry=geo)
    else:
        est = np.array([float(f.orient["tilt_deg"]) for f in fr])
        mc_rows = []
        for f, e in zip(fr, est):
            t = _monte_carlo_tilts(f, trials, rng)
            mc_rows.append({"frame": f.index, "image": f.image, "reference_tilt_deg": math.degrees(f.tilt_ref),
                            "tilt_deg": float(e), "lines": int(f.a.size),
                            "sigma_line_deg": math.degrees(float(np.median(f.sigma))),
                            "mc_median_deg": float(np.median(t)), "mc_p95_deg": float(np.percentile(t, 95)),
                            "mc_percentile_of_measured": float(100.0 * np.mean(t <= e)),
                            "detectable": bool(f.orient.get("detectable"))})
        out["frontal"] = {
            "status": "ok", "limit_deg": lim, "count": len(fr),
            "measured_median_deg": float(np.median(est)), "measured_max_deg": float(np.max(est)),
            "geometry": geo,
            "monte_carlo": {"trials": trials, "median_deg": float(np.median([r["mc_median_deg"] for r in mc_rows])),
                            "p95_deg": float(np.median([r["mc_p95_deg"] for r in mc_rows])),
                            "note": "the exact estimator on noisy copies of each frame's lines at its reference pose"},
            "detectable": int(sum(r["detectable"] for r in mc_rows)),
            "frames": mc_rows,
        }
    out["frames"] = per
    return _finish(out, ["detection", "noise_level", "frontal"])


# --------------------------------------------------------------------- synthetic input
def synthetic_validation(tilts_deg, *, spokes_deg=tuple(range(-70, 71, 20)), sigma_deg=0.1, axis_deg=0.0,
                         offaxis_deg=0.0, seed=0):
    """A validation dict without images: exact poses, Gaussian line-angle noise, exact fits.

    One frame per tilt: the pencil (vertex at the target origin, seen `offaxis_deg` off
    the optical axis along +x) turned by the tilt about the in-plane axis at `axis_deg`
    from the target x axis, as the tilt-sweep scenario does; every spoke's image angle
    gets N(0, sigma_deg) noise and the orientation record is `estimator.fit_pencil`'s. For
    tests and for trying the experiments where images would take long (hundreds of frames
    near zero tilt). Returns the dict (numpy inside; `files.write_json` writes it).
    """
    from pencilcal.toolkit.geometry.frames import rotation_about_axis, rotation_to_z

    rng = np.random.default_rng(seed)
    th = np.radians(np.asarray(spokes_deg, float))
    sig = math.radians(sigma_deg)
    x0 = np.array([math.tan(math.radians(offaxis_deg)), 0.0])
    ray = np.r_[x0, 1.0] / math.hypot(x0[0], 1.0)
    R0 = rotation_to_z(ray).T
    a_ax = math.radians(axis_deg)
    axis = np.array([math.cos(a_ax), math.sin(a_ax), 0.0])
    thr = math.degrees(float(detection_threshold(sig)))
    frames = []
    for k, g in enumerate(np.asarray(tilts_deg, float)):
        R = R0 @ rotation_about_axis(axis, math.radians(g))
        t = ray * 400.0
        a = image_angles(R, x0, th) + rng.normal(size=th.size) * sig
        fit = fit_pencil(a, th, x0, sig)
        _, b_t, b_n = crlb(R, x0, th, sig)
        est = math.degrees(float(fit.tilt))
        frames.append({
            "image": f"{k:04d}.png", "ok": True, "error": None, "reference": "truth", "R_ref": R, "t_ref": t,
            "reference_tilt_deg": float(g),
            "crlb": {"tilt_deg": _deg(float(b_t)) if math.degrees(b_t) < 90 else None,
                     "normal_deg": _deg(float(b_n)) if math.degrees(b_n) < 90 else None},
            "orient": {"exact": {
                "ok": True, "model": "exact", "tilt_deg": est, "tilt_sigma_deg": _deg(float(fit.tilt_sigma)),
                "detectable": bool(fit.detectable), "tilt_threshold_deg": thr, "labels_ambiguous": False,
                "lines_used": int(th.size), "normal": fit.normal, "R_cam_from_target": fit.R_cam_from_target,
                "R_cam_from_target_twin": fit.R_twin, "ray": fit.ray,
                "lines": {"angle": a, "sigma": np.full(th.size, sig), "spoke": np.arange(th.size),
                          "segment": np.arange(th.size), "vertex": x0, "vertex_cov": np.zeros((2, 2))}}},
            "errors": {"orient:exact": {"tilt_deg": est - float(g)}},
        })
    return {"sequence": "synthetic", "reference": "truth", "models": ["exact"], "methods": [],
            "pencil": {"angles_deg": [float(v) for v in spokes_deg], "vertex": [0.0, 0.0]}, "frames": frames}


# ----------------------------------------------------------------------------- figures
_FIGURES = {
    "single-angle": ("single-angle",),
    "distribution": ("distribution-angles", "distribution-spacing"),
    "threshold": ("threshold",),
}


def figure_paths(experiment, prefix):
    """PNG paths an experiment writes: ``<prefix>_<name>.png``."""
    return [f"{prefix}_{n}.png" for n in _FIGURES[experiment]]


def _save(fig, path, force):
    from pencilcal.toolkit.io.files import atomic_path

    with atomic_path(path, force) as tmp:
        fig.savefig(tmp, format="png", dpi=110)


def _title(fig, r):
    fig.suptitle(f"{r['experiment']}: {r.get('sequence') or ''} (reference: {r.get('reference')}, "
                 f"{r['frames_used']} frames, line sigma {r['sigma_line_deg']:.3g} deg)", fontsize=9)


def write_figures(result, prefix, force=False):
    """Write the PNG figures of an experiment's result; returns their paths."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    name = result["experiment"]
    paths = figure_paths(name, prefix)
    if name == "single-angle":
        fig = Figure(figsize=(13, 5), layout="constrained")
        _fig_single(fig, result)
        _save(fig, paths[0], force)
    elif name == "distribution":
        fig = Figure(figsize=(13, 5), layout="constrained")
        _fig_angles(fig, result)
        _save(fig, paths[0], force)
        fig = Figure(figsize=(13, 5), layout="constrained")
        _fig_spacing(fig, result)
        _save(fig, paths[1], force)
    else:
        fig = Figure(figsize=(13, 5), layout="constrained")
        _fig_threshold(fig, result)
        _save(fig, paths[0], force)
    return paths


def _no_data(ax, text):
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, fontsize=8, wrap=True)


_CASE_STYLE = {"on_line": ("tab:blue", "o"), "known": ("tab:green", "s"), "unknown": ("tab:purple", "^")}


def _fig_single(fig, r):
    ax1, ax2 = fig.subplots(1, 2)
    _title(fig, r)
    lim = 0.0
    for case, (col, mk) in _CASE_STYLE.items():
        s = r.get(case)
        if not s or s.get("status") != "ok":
            continue
        recs = s["pairs"]
        lim = max(lim, max(p["reference_tilt_deg"] for p in recs))
        uni = [p for p in recs if p["status"] == "unique"]
        if uni:
            ax1.plot([p["reference_tilt_deg"] for p in uni], [p["gamma_deg"][0] for p in uni], mk, color=col, ms=3,
                     alpha=0.6, label=f"{case}: unique ({len(uni)})")
            ax2.semilogy([p["reference_tilt_deg"] for p in uni], [max(abs(p["error_deg"][0]), 1e-6) for p in uni], mk,
                         color=col, ms=3, alpha=0.5, label=f"{case}: |error| ({len(uni)})")
        two = [p for p in recs if p["status"] == "two_roots"]
        if two:
            for p in two:
                ax1.plot([p["reference_tilt_deg"]] * 2, p["gamma_deg"], "-", color=col, lw=0.5, alpha=0.4)
            ax1.plot([p["reference_tilt_deg"] for p in two for _ in p["gamma_deg"]],
                     [g for p in two for g in p["gamma_deg"]], mk, mfc="none", color=col, ms=4,
                     label=f"{case}: two roots, both shown ({len(two)})")
        lb = [p for p in recs if p["status"] == "lower_bound"]
        if lb:
            ax1.plot([p["reference_tilt_deg"] for p in lb], [p["gamma_deg"][0] for p in lb], "^", color=col, mfc="none",
                     ms=3, alpha=0.4, label=f"{case}: lower bound only ({len(lb)})")
        inc = [p for p in recs if p["status"] in ("inconsistent", "no information")]
        if inc:
            y0 = {"on_line": -1.5, "known": -3.0, "unknown": -4.5}[case]
            ax1.plot([p["reference_tilt_deg"] for p in inc], [y0] * len(inc), "x", color=col, ms=5,
                     label=f"{case}: inconsistent, no tilt ({len(inc)})")
        if uni and s.get("unique", {}).get("bins"):
            bins = [b for b in s["unique"]["bins"] if b.get("error_rms_deg")]
            ax2.semilogy([0.5 * (b["tilt_lo_deg"] + b["tilt_hi_deg"]) for b in bins], [b["error_rms_deg"] for b in bins],
                         mk + "-", color=col, ms=7, lw=1.5, mec="k", label=f"{case}: RMS error per 10 deg")
    hi = max(lim, 10.0) + 2
    ax1.plot([0, hi], [0, hi], "k-", lw=0.7, label="estimate = reference")
    ax1.set_xlim(-1, hi)
    ax1.set_ylim(-5, 92)
    ax1.set_xlabel("reference tilt (rotation) [deg]")
    ax1.set_ylabel("single-angle tilt [deg]")
    ax1.set_title("estimates by status (x below 0: no tilt fits)")
    ax1.legend(fontsize=6, loc="upper left")
    curves = r.get("theory", {}).get("curves", [])
    if len(curves) > 4:  # the extremes and two between
        curves = [curves[i] for i in sorted({0, len(curves) // 3, 2 * len(curves) // 3, len(curves) - 1})]
    for c, ls in zip(curves, ("-", "--", "-.", ":")):
        ax2.semilogy(c["tilt_deg"], c["sd_deg"], ls, color="k", lw=1.1,
                     label=f"theory sd, on_line, theta {c['theta_deg']:.0f} deg "
                           f"(sigma_alpha {r['theory']['sigma_alpha_deg']:.3g})")
    ax2.set_xlabel("reference tilt (rotation) [deg]")
    ax2.set_ylabel("|tilt error| [deg]")
    ax2.set_title("single-angle error vs rotation (unique results only)")
    ax2.set_xlim(-1, hi)
    ax2.legend(fontsize=6, loc="upper right")


def _fig_angles(fig, r):
    ax1, ax2, ax3 = fig.subplots(1, 3)
    _title(fig, r)
    a = r.get("angles", {})
    if a.get("status") != "ok":
        for ax in (ax1, ax2, ax3):
            _no_data(ax, a.get("reason", "no data"))
        return
    lines = a["lines"]
    spokes = sorted({ln["spoke"] for ln in lines})
    cmap = __import__("matplotlib").colormaps["tab20"]
    for j, k in enumerate(spokes):
        ls = sorted([ln for ln in lines if ln["spoke"] == k], key=lambda ln: ln["reference_tilt_deg"])
        col = cmap(j % 20)
        t = [ln["reference_tilt_deg"] for ln in ls]
        # one axis for the whole sequence (a sweep): curves; else each frame its own: ticks
        style = dict(ls="-", lw=0.8) if a.get("sequence_axis_deg") is not None else dict(ls="none", marker="_", ms=6)
        ax1.plot(t, [ln["variation_predicted_deg"] for ln in ls], color=col, **style)
        ax1.plot(t, [ln["variation_measured_deg"] for ln in ls], "o", color=col, ms=2.5, mfc="none",
                 label=f"spoke {k}" if len(spokes) <= 16 else None)
        ax2.plot(t, [ln["z"] for ln in ls], "o", color=col, ms=2.5)
    ax1.set_xlabel("reference tilt (rotation) [deg]")
    ax1.set_ylabel("angle in T from the axis minus 3D angle [deg]")
    ax1.set_title("angular variation: measured (o), exact projection ("
                  + ("lines)" if a.get("sequence_axis_deg") is not None else "ticks)"))
    ax1.legend(fontsize=6, ncol=2)
    ax2.axhspan(-1, 1, color="0.85", zorder=0)
    ax2.axhline(0, color="k", lw=0.6)
    ax2.set_xlabel("reference tilt (rotation) [deg]")
    ax2.set_ylabel("(measured - predicted) / line sigma")
    ax2.set_title(f"residuals: RMS {a['residual_rms_deg']:.3g} deg, z RMS {a['z_rms']:.2f}")
    mv = sorted(a["max_variation"], key=lambda m: m["reference_tilt_deg"])
    t = [m["reference_tilt_deg"] for m in mv]
    ax3.plot(t, [m["max_angular_change_deg"] for m in mv], "k-", lw=1, label="largest possible change (any spoke)")
    ax3.plot(t, [m["max_variation_predicted_deg"] for m in mv], "-", color="tab:orange", lw=1,
             label="predicted, these spokes")
    ax3.plot(t, [m["max_variation_measured_deg"] for m in mv], "o", color="tab:blue", ms=3, mfc="none", label="measured")
    ax3.axhline(r["sigma_line_deg"], color="tab:red", ls="--", lw=1, label="line sigma")
    ax3.set_yscale("log")
    ax3.set_xlabel("reference tilt (rotation) [deg]")
    ax3.set_ylabel("largest |variation| over the spokes [deg]")
    ax3.set_title("angular change vs tilt")
    ax3.legend(fontsize=6)


def _fig_spacing(fig, r):
    ax1, ax2 = fig.subplots(1, 2)
    _title(fig, r)
    s = r.get("spacing", {})
    if s.get("status") != "ok":
        for ax in (ax1, ax2):
            _no_data(ax, s.get("reason", "no data"))
        return
    cols = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown"]
    for j, row in enumerate(s["strides"]):
        if row.get("status") != "ok":
            continue
        m = row["stride"]
        col = cols[j % len(cols)]
        fits = sorted([f for f in s["fits"] if f.get("stride") == m and f.get("ok")],
                      key=lambda f: f["reference_tilt_deg"])
        t = [f["reference_tilt_deg"] for f in fits]
        lab = f"every {m}: {row['spacing_deg']:.0f} deg apart, ~{row['lines_median']:.0f} lines"
        ax1.semilogy(t, [max(f["normal_error_closer_deg"], 1e-5) for f in fits], "o", color=col, ms=2.5, mfc="none",
                     label=lab)
        ax2.semilogy(t, [max(abs(f["tilt_error_deg"]), 1e-5) for f in fits], "o", color=col, ms=2.5, mfc="none", label=lab)
        # the bound, averaged over the subsets of this stride in each frame
        by = {}
        for f in fits:
            if f["crlb_normal_deg"]:
                by.setdefault(f["frame"], []).append((f["reference_tilt_deg"], f["crlb_normal_deg"], f["crlb_tilt_deg"]))
        pts = sorted((v[0][0], math.sqrt(np.mean([b[1] ** 2 for b in v])), math.sqrt(np.mean([b[2] ** 2 for b in v])))
                     for v in by.values())
        if pts:
            ax1.semilogy([p[0] for p in pts], [p[1] for p in pts], "-", color=col, lw=1)
            ax2.semilogy([p[0] for p in pts], [p[2] for p in pts], "-", color=col, lw=1)
    ax1.set_xlabel("reference tilt (rotation) [deg]")
    ax1.set_ylabel("normal error, closer twin [deg]")
    ax1.set_title("orientation error by spoke spacing (o), Cramer-Rao bound (lines)")
    ax2.set_xlabel("reference tilt (rotation) [deg]")
    ax2.set_ylabel("|tilt error| [deg]")
    ax2.set_title("tilt error by spoke spacing (o), bound (lines)")
    ax1.legend(fontsize=7)


def _fig_threshold(fig, r):
    ax1, ax2 = fig.subplots(1, 2)
    _title(fig, r)
    per = r["frames"]
    x = np.array([p["reference_tilt_deg"] for p in per])
    det = np.array([p["detectable"] for p in per], float)
    th = r["theory"]
    ax1.plot(x, det + np.random.default_rng(0).uniform(-0.02, 0.02, x.size), "o", ms=3, mfc="none", color="tab:blue",
             label="detectable (1) or not (0), per frame")
    ax1.plot(x, [p["predicted_detect_probability"] for p in per], "-", color="tab:orange", lw=1,
             label="predicted P(detectable), LR test at 1%")
    d = r["detection"]
    if d.get("status") == "ok":
        ax1.axvspan(*d["interval_deg"], color="tab:blue", alpha=0.15, label="measured 50% crossing, interval")
        ax1.axvline(d["tilt50_deg"], color="tab:blue", lw=1.2, label=f"measured 50%: {d['tilt50_deg']:.2f} deg")
    ax1.axvline(th["two_sqrt_sigma_deg"], color="tab:red", ls="--", lw=1,
                label=f"2 sqrt(sigma) = {th['two_sqrt_sigma_deg']:.2f} deg")
    ax1.axvline(th["detection_threshold_deg"], color="k", ls=":", lw=1,
                label=f"detection_threshold = {th['detection_threshold_deg']:.2f} deg")
    near = 4.0 * th["two_sqrt_sigma_deg"]
    hi = max(near, d["interval_deg"][1] * 1.3) if d.get("status") == "ok" else near
    ax1.set_xlim(0, hi if x.min() < near else 1.05 * x.max())
    ax1.set_ylim(-0.1, 1.1)
    ax1.set_xlabel("reference tilt [deg]")
    ax1.set_ylabel("detectable")
    ax1.set_title("detection" + ("" if d.get("status") == "ok" else f" ({d.get('reason')})"), fontsize=8)
    ax1.legend(fontsize=6, loc="center right")
    est = [p["tilt_deg"] for p in per]
    err = [abs(p["tilt_error_deg"]) if p["tilt_error_deg"] is not None else np.nan for p in per]
    ax2.loglog(np.maximum(x, 0.05), np.maximum(err, 1e-4), "o", ms=3, mfc="none", color="tab:blue", label="|tilt error|")
    ax2.loglog(np.maximum(x, 0.05), np.maximum(np.asarray(est, float), 1e-4), ".", ms=3, color="tab:green",
               label="estimated tilt")
    crb = [p["crlb_tilt_deg"] if p["crlb_tilt_deg"] else np.nan for p in per]
    ax2.loglog(np.maximum(x, 0.05), crb, "d", color="tab:orange", ms=2.5, label="Cramer-Rao sd of the tilt")
    g = np.logspace(-1.3, math.log10(max(x.max(), 1.0)), 50)
    ax2.loglog(g, 0.5 * g, "k--", lw=0.8, label="0.5 x tilt (noise-level above it)")
    fr = r.get("frontal", {})
    geo = fr.get("geometry")
    if geo:
        ax2.axhline(geo["median_deg"], color="tab:red", ls=":", lw=1,
                    label=f"GEOMETRY frontal median, scaled: {geo['median_deg']:.2f} deg")
    ax2.axvline(th["two_sqrt_sigma_deg"], color="tab:red", ls="--", lw=1)
    ax2.set_xlabel("reference tilt [deg] (0 drawn at 0.05)")
    ax2.set_ylabel("[deg]")
    ax2.set_title("tilt error vs rotation")
    ax2.legend(fontsize=6)

"""The threshold experiment: the tilt at which the estimator's ``detectable`` flag turns on
for half of the frames (monotone regression, bootstrap interval), the tilt below which
the tilt error is as large as half the tilt itself, and the estimated tilt of frontal-ish
frames, against 2 sqrt(sigma), `estimator.detection_threshold` and the noise floor of a
frontal pencil (docs/method.md). See `pencilcal.validation.experiments`.

Example
-------
>>> crossing, bracket = _crossing([1.0, 2.0, 3.0, 4.0], [0, 0, 1, 1])
>>> crossing, bracket
(2.5, (2.0, 3.0))
"""
from __future__ import annotations

import math

import numpy as np

from pencilcal.toolkit.pencil.defaults import CHI2_2_DETECTION
from pencilcal.toolkit.pencil.estimator import detection_threshold, fit_pencil, frontal_fit
from pencilcal.toolkit.pencil.spec import image_angles

from .frames import frames_or_fail, sigma_line
from .sections import finish, header, insufficient_section

__all__ = ["GEOMETRY_FRONTAL_MEDIAN_DEG", "GEOMETRY_FRONTAL_P95_DEG", "threshold"]

#: A truly frontal pencil (8 lines, sigma = 0.1 deg) is estimated at a median tilt of
#: 3.75 deg (95th percentile 5.3 deg; docs/method.md); the floor scales with sqrt(sigma).
GEOMETRY_FRONTAL_MEDIAN_DEG = 3.75
GEOMETRY_FRONTAL_P95_DEG = 5.3
_GEOMETRY_SIGMA_DEG = 0.1


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
    """(95 % percentile interval of `_crossing` over `n_boot` resamples of the frames, or None,
    resamples without a crossing)."""
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
    return float(ncx2.sf(CHI2_2_DETECTION, 2, max(lam, 1e-12))), lam


def _monte_carlo_tilts(f, trials, rng):
    """Estimated tilts of `trials` noisy copies of this frame's lines at its reference pose."""
    pred = image_angles(f.R_ref, f.x_ref, f.th)
    a = pred[None, :] + rng.normal(size=(trials, pred.size)) * f.sigma[None, :]
    fit = fit_pencil(a, np.broadcast_to(f.th, a.shape), np.broadcast_to(f.x_ref, (trials, 2)),
                     np.broadcast_to(f.sigma, a.shape))
    return np.degrees(np.asarray(fit.tilt, float))


def threshold(v, *, n_boot=2000, trials=500, seed=0, relative=0.5, frontal_fraction=0.5):
    """The detection threshold measured on the data against the theory (`pencilcal.validation.experiments`).

    v: validation dict; n_boot: bootstrap resamples of the crossings; trials: Monte Carlo
    copies per frontal-ish frame; seed: random seed; relative: a frame's tilt error is
    "noise-level" when |error| >= relative x reference tilt; frontal_fraction: frames below
    frontal_fraction x detection_threshold(sigma) are frontal-ish.
    Returns the result dict (JSON-ready).
    """
    rng = np.random.default_rng(seed)
    frames, skipped = frames_or_fail(v)
    out = header(v, "threshold", frames, skipped)
    sig = sigma_line(frames)
    sig_deg = math.degrees(sig)
    dt = math.degrees(float(detection_threshold(sig)))
    per = sorted((_frame_row(f, relative) for f in frames), key=lambda r: r["reference_tilt_deg"])
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
        out["detection"] = insufficient_section(why, **extra, frames=len(per), detectable=int(det.sum()))
    else:
        sec.update(status="ok", frames=len(per), detectable=int(det.sum()),
                   ratio_to_two_sqrt_sigma=sec["tilt50_deg"] / out["theory"]["two_sqrt_sigma_deg"],
                   ratio_to_detection_threshold=sec["tilt50_deg"] / dt)
        out["detection"] = sec
    # noise-level errors
    rows = [r for r in per if r["noise_level"] is not None]
    if not rows:
        out["noise_level"] = insufficient_section("no frame has a tilt estimate")
    else:
        xn = np.array([r["reference_tilt_deg"] for r in rows])
        yn = np.array([not r["noise_level"] for r in rows], float)  # increasing: measured, not noise
        sec, why, extra = _crossing_section(xn, yn, n_boot, rng, f"measured to better than {relative:g} x its tilt")
        if sec is None:
            out["noise_level"] = insufficient_section(
                why, **extra, definition=f"|tilt error| >= {relative:g} x reference tilt")
        else:
            sec.update(status="ok", definition=f"|tilt error| >= {relative:g} x reference tilt",
                       noise_level_frames=int(sum(r["noise_level"] for r in rows)),
                       ratio_to_two_sqrt_sigma=sec["tilt50_deg"] / out["theory"]["two_sqrt_sigma_deg"])
            out["noise_level"] = sec
    out["frontal"] = _frontal_section(frames, x, dt, sig_deg, frontal_fraction, trials, rng)
    out["frames"] = per
    return finish(out, ["detection", "noise_level", "frontal"])


def _frame_row(f, relative):
    """One frame's record: the estimator's detection and tilt error against the reference,
    and what the theory predicts for its lines (detection and noise-level probabilities)."""
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
    return {"frame": f.index, "image": f.image, "reference_tilt_deg": g, "tilt_deg": est,
            "tilt_error_deg": err, "tilt_sigma_deg": o.get("tilt_sigma_deg"),
            "detectable": bool(o.get("detectable")), "predicted_detect_probability": p_det,
            "noncentrality": lam, "crlb_tilt_deg": crb,
            "noise_level": None if err is None else bool(abs(err) >= relative * g),
            "predicted_noise_probability": p_noise, "tilt_threshold_deg": o.get("tilt_threshold_deg"),
            "sigma_line_deg": math.degrees(float(np.median(f.sigma))), "lines": int(f.a.size)}


def _frontal_section(frames, x, dt, sig_deg, frontal_fraction, trials, rng):
    """The frontal-ish frames (reference tilt below frontal_fraction x the detection
    threshold `dt` [deg]): their estimated tilt, the noise floor of docs/method.md scaled to
    their line sigma, and a Monte Carlo of the exact estimator on each; x: the sorted
    reference tilts [deg] (for the reason when there is none)."""
    lim = frontal_fraction * dt
    fr = [f for f in frames if math.degrees(f.tilt_ref) < frontal_fraction * dt]
    # the floor of these frames: scale with their own line sigma
    sig_fr = math.degrees(float(np.median(np.concatenate([f.sigma for f in fr])))) if fr else sig_deg
    scale = math.sqrt(sig_fr / _GEOMETRY_SIGMA_DEG)
    geo = {"median_deg": GEOMETRY_FRONTAL_MEDIAN_DEG * scale, "p95_deg": GEOMETRY_FRONTAL_P95_DEG * scale,
           "sigma_deg": sig_fr,
           "note": ("noise floor of a frontal pencil: median 3.75 deg (p95 5.3) at sigma 0.1 deg for 8 lines, scaled by "
                    "sqrt(sigma / 0.1 deg) with the median line sigma of the frontal-ish frames")}
    if not fr:
        return insufficient_section(
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
        return {
            "status": "ok", "limit_deg": lim, "count": len(fr),
            "measured_median_deg": float(np.median(est)), "measured_max_deg": float(np.max(est)),
            "geometry": geo,
            "monte_carlo": {"trials": trials, "median_deg": float(np.median([r["mc_median_deg"] for r in mc_rows])),
                            "p95_deg": float(np.median([r["mc_p95_deg"] for r in mc_rows])),
                            "note": "the exact estimator on noisy copies of each frame's lines at its reference pose"},
            "detectable": int(sum(r["detectable"] for r in mc_rows)),
            "frames": mc_rows,
        }

"""A validation dict without images (exact poses, Gaussian line-angle noise, exact fits), for
tests and for trying the experiments where images would take long.

Example
-------
>>> v = synthetic_validation([0.0, 30.0], sigma_deg=0.1)
>>> v["reference"], len(v["frames"]), v["frames"][1]["reference_tilt_deg"]
('truth', 2, 30.0)
"""
from __future__ import annotations

import math

import numpy as np

from pencilcal.toolkit.geometry.frames import rotation_about_axis, rotation_to_z
from pencilcal.toolkit.pencil.estimator import crlb, detection_threshold, fit_pencil
from pencilcal.toolkit.pencil.spec import image_angles

from .sections import deg_or_none

__all__ = ["synthetic_validation"]


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
            "crlb": {"tilt_deg": deg_or_none(float(b_t)) if math.degrees(b_t) < 90 else None,
                     "normal_deg": deg_or_none(float(b_n)) if math.degrees(b_n) < 90 else None},
            "orient": {"exact": {
                "ok": True, "model": "exact", "tilt_deg": est, "tilt_sigma_deg": deg_or_none(float(fit.tilt_sigma)),
                "detectable": bool(fit.detectable), "tilt_threshold_deg": thr, "labels_ambiguous": False,
                "lines_used": int(th.size), "normal": fit.normal, "R_cam_from_target": fit.R_cam_from_target,
                "R_cam_from_target_twin": fit.R_twin, "ray": fit.ray,
                "lines": {"angle": a, "sigma": np.full(th.size, sig), "spoke": np.arange(th.size),
                          "segment": np.arange(th.size), "vertex": x0, "vertex_cov": np.zeros((2, 2))}}},
            "errors": {"orient:exact": {"tilt_deg": est - float(g)}},
        })
    return {"sequence": "synthetic", "reference": "truth", "models": ["exact"], "methods": [],
            "pencil": {"angles_deg": [float(v) for v in spokes_deg], "vertex": [0.0, 0.0]}, "frames": frames}

"""Error metrics between estimates and references, and their summaries.

All errors are angles in degrees (files and reports speak degrees). Where an estimate comes
with a twin, the *closer* twin is the fair error when the method says it is ambiguous, and
the chosen one when it claims to have resolved the twin; both are reported.

Coverage: for a 1-D error (tilt) the fraction of |error| <= sigma, 68.3% when the sigmas are
right. For the normal, `normal_sigma_deg` is the RMS angle of a 2-D error, and for an
isotropic Gaussian P(error <= sigma_rms) = 1 - exp(-1) = 63.2%.
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.geometry.frames import angle_between, rotation_angle

__all__ = ["rotation_error_deg", "normal_error_deg", "summary", "coverage", "EXPECTED_COVERAGE", "seed_list"]

EXPECTED_COVERAGE = {"tilt": 0.6827, "normal": 1.0 - np.exp(-1.0)}


def rotation_error_deg(R_est, R_ref):
    """Geodesic angle [deg] between rotations. (..., 3, 3) -> (...)."""
    return np.degrees(rotation_angle(R_est, R_ref))


def normal_error_deg(n_est, n_ref):
    """Angle [deg] between normals. (..., 3) -> (...)."""
    return np.degrees(angle_between(n_est, n_ref))


def summary(errors):
    """Median, RMSE, 95th percentile, max and count of finite errors (None when empty)."""
    e = np.asarray([x for x in np.ravel(errors) if x is not None], float)
    e = e[np.isfinite(e)]
    if e.size == 0:
        return {"count": 0, "median": None, "rmse": None, "p95": None, "max": None}
    return {"count": int(e.size), "median": float(np.median(np.abs(e))), "rmse": float(np.sqrt(np.mean(e**2))),
            "p95": float(np.percentile(np.abs(e), 95)), "max": float(np.max(np.abs(e)))}


def coverage(errors, sigmas, kind="tilt"):
    """Fraction of |error| <= sigma, with the value expected if the sigmas are right."""
    e = np.abs(np.asarray(errors, float))
    s = np.asarray(sigmas, float)
    ok = np.isfinite(e) & np.isfinite(s)
    if not ok.any():
        return {"fraction": None, "expected": EXPECTED_COVERAGE[kind], "count": 0}
    return {"fraction": float(np.mean(e[ok] <= s[ok])), "expected": float(EXPECTED_COVERAGE[kind]), "count": int(ok.sum())}


def seed_list(text):
    """The seeds a runner's ``--seeds`` names: ``"A:B"`` (A to B-1) or ``"a,b,c"``.

    >>> seed_list("3:6"), seed_list("7,9")
    ([3, 4, 5], [7, 9])
    """
    if ":" in text:
        lo, hi = (int(v) for v in text.split(":"))
        return list(range(lo, hi))
    return [int(v) for v in text.split(",")]

"""Planning maps: from which tilt on is the orientation good to X deg, for a given set-up?

A lab planning a pencil set-up (a printed fan, an instrument pivoting about a port) asks:
with my focal length, my fan (number of spokes, their spacing), my line-angle noise and
where the vertex sits in the image, how well is the plane's orientation determined, from
which tilt on is it good to X deg, and below which tilt can it not be told from a frontal
pencil at all? This module answers with two kinds of maps over the same grids:

- **Cramer-Rao bound** (`estimator.crlb`, batched): the best any unbiased estimator can do,
  averaged (RMS) over the in-plane angles psi (tilt axis) and theta0 (fan offset) on a
  regular grid. Exact, cheap, noise-free; meaningless below the detection threshold.
- **Monte Carlo**: `trials` noisy pencils per cell fitted by the exact estimator (batched
  in torch by `toolkit.torch_estimator.fit_pencils_torch`, or by the numpy estimator when
  torch is not installed). RMSE, median and 95th percentile of the tilt error and of the
  normal error (angle to the closer twin: the data never separate the twins, docs/conventions.md),
  the bias of the tilt, and the rate at which the fit is flagged ``detectable``.

Grids: tilt x vertex position (off-axis angle of the vertex ray), spokes x spacing and noise
x tilt. From each tilt curve: the *minimum tilt for an accuracy* X (the smallest tilt from
which the metric stays at or below X on the rest of the grid, interpolated linearly between
grid points) and the *measured detection threshold* (where the detectable rate crosses 50%
and 90%), next to the ``2 sqrt(sigma)`` rule of docs/method.md and its exact form
`estimator.detection_threshold`.

Simulation (as tests/toolkit/pencil/test_estimator.py): the vertex sits at off-axis angle phi
along the image x axis, normalised ``(tan phi, 0)`` (the azimuth does not matter: psi is
uniform); R = Qt Rz(psi) Rx(tilt) Rz(theta0) with Q the virtual camera along the ray; image
angles are exact (`pencil.image_angles`) plus Gaussian noise sigma on every line. Line
angles are the same in pixels and in normalised coordinates for square pixels, so the focal
length only converts vertex positions (``offaxis_px = focal * tan(phi)``).

Reproducible: every map draws its psi, theta0 and unit noise once from
``np.random.default_rng([seed, map_id])`` on the CPU and uses them in every cell (common
random numbers: curves are smooth in tilt, sigma and fan), so the numbers do not depend on
the backend, the device or on which other maps are run.

Example
-------
>>> import numpy as np
>>> m = tilt_offaxis_map(Setup(), tilts_deg=[10.0, 20.0, 40.0], offaxis_deg=[0.0], trials=400, seed=1)
>>> ratio = m["mc"]["tilt_rmse_deg"][0] / m["crb"]["tilt_deg"][0]   # efficiency, ~1 above 10 deg
>>> bool(np.all((ratio > 0.8) & (ratio < 1.25)))
True
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.pencil.estimator import crlb, detection_threshold, fit_pencil
from pencilcal.toolkit.geometry.frames import angle_between, rotation_about_axis, rotation_to_z
from pencilcal.toolkit.pencil.spec import MAX_SPOKES, image_angles

__all__ = [
    "Setup",
    "MAPS",
    "parse_range",
    "resolve_backend",
    "pose_about_ray",
    "offaxis_vertex",
    "fit_batch",
    "crb_cells",
    "monte_carlo_cells",
    "min_tilt_for_accuracy",
    "detection_crossings",
    "tilt_offaxis_map",
    "spokes_spacing_map",
    "noise_map",
    "plan",
    "validate_grids",
    "heatmap_paths",
    "write_heatmaps",
]

MAPS = ("tilt-offaxis", "spokes-spacing", "noise")
_MAP_ID = {"tilt-offaxis": 1, "spokes-spacing": 2, "noise": 3}
# pencils per fit call: bounds memory (the numpy path holds ~30 arrays of this x N)
_BATCH = 200_000


# Limits of a plan: past them a set-up is no pencil (noise of tens of degrees), the numbers
# overflow (a focal length of 1e308 px, ranges to 1e300), or the Monte Carlo outgrows memory
# (its noise draws are trials x spokes floats: 1e9 trials were 64 GB).
MAX_FOCAL_PX = 1e7
MAX_SIGMA_DEG = 30.0
MAX_TRIALS = 1_000_000
MAX_RANGE_VALUE = 1e9


@dataclass(frozen=True)
class Setup:
    """A pencil set-up to plan.

    focal_px: focal length [px] (converts off-axis angles to pixel distances from the
        principal point); spokes: number of spokes; step_deg: angle between neighbouring
        spokes [deg] (a regular fan 0, step, 2 step, ...); sigma_deg: line-angle noise,
        one standard deviation [deg].
    """

    focal_px: float = 800.0
    spokes: int = 8
    step_deg: float = 20.0
    sigma_deg: float = 0.1

    def __post_init__(self):
        if not (np.isfinite(self.focal_px) and 0 < self.focal_px <= MAX_FOCAL_PX):
            raise InputError(f"focal length must be positive and at most {MAX_FOCAL_PX:g} px, got {self.focal_px!r} px")
        if int(self.spokes) != self.spokes or not 3 <= self.spokes <= MAX_SPOKES:
            raise InputError(f"a pencil has three spokes to {MAX_SPOKES}, got {self.spokes!r}")
        if not (np.isfinite(self.step_deg) and 0 < self.step_deg <= 180):
            raise InputError(f"spoke spacing must be in (0, 180] deg, got {self.step_deg!r} deg")
        if not (np.isfinite(self.sigma_deg) and 0 < self.sigma_deg <= MAX_SIGMA_DEG):
            raise InputError(f"line noise must be in (0, {MAX_SIGMA_DEG:g}] deg, got {self.sigma_deg!r} deg")
        if _distinct_lines(self.spoke_angles()) < 3:
            raise InputError(f"{self.spokes} spokes {self.step_deg} deg apart give fewer than three distinct "
                             f"line directions (lines repeat every 180 deg)")

    def spoke_angles(self):
        """(N,) [rad] theta_k of the fan."""
        return np.radians(np.arange(int(self.spokes)) * float(self.step_deg))


def _distinct_lines(theta):
    d = np.sort(np.round(np.remainder(np.degrees(theta), 180.0), 9) % 180.0)
    return int(np.unique(d).size)


def parse_range(spec, name="range"):
    """Grid values from a range spec: ``"0:80:2"`` (start:stop:step, stop included when
    the steps land on it), ``"5,10,20"`` (a list), ``"20"`` (one value), or any mix joined
    by commas (``"0:10:2,15,20"``). Returns a sorted (K,) float array without duplicates.

    >>> parse_range("0:10:2.5").tolist(), parse_range("3,1,2").tolist()
    ([0.0, 2.5, 5.0, 7.5, 10.0], [1.0, 2.0, 3.0])
    """
    if isinstance(spec, (int, float, np.floating, np.integer)):
        return np.array([float(spec)])
    if not isinstance(spec, str):
        arr = np.asarray(spec, float).ravel()
        if arr.size == 0 or not np.all(np.isfinite(arr)):
            raise InputError(f"{name}: expected finite numbers, got {spec!r}")
        return np.unique(arr)
    vals = []
    for part in spec.replace(" ", "").split(","):
        if not part:
            continue
        bits = part.split(":")
        try:
            nums = [float(b) for b in bits]
        except ValueError:
            raise InputError(f"{name}: {spec!r} is not a range (use start:stop:step or a list a,b,c)") from None
        if not all(math.isfinite(v) for v in nums):
            raise InputError(f"{name}: {spec!r} has a non-finite value")
        if any(abs(v) > MAX_RANGE_VALUE for v in nums):
            raise InputError(f"{name}: {spec!r} has a value beyond +-{MAX_RANGE_VALUE:g}")
        if len(nums) == 1:
            vals.append(nums[0])
        elif len(nums) == 3:
            lo, hi, st = nums
            if st <= 0 or hi < lo:
                raise InputError(f"{name}: {part!r} needs start <= stop and a positive step")
            n = int(math.floor((hi - lo) / st + 1e-9)) + 1
            if n > 100_000:
                raise InputError(f"{name}: {part!r} has more than 100000 values")
            vals.extend(lo + st * np.arange(n))
        else:
            raise InputError(f"{name}: {part!r} is not start:stop:step")
    if not vals:
        raise InputError(f"{name}: {spec!r} has no values")
    return np.unique(np.round(np.asarray(vals, float), 12))


def resolve_backend(backend="auto", device="cpu"):
    """``"torch"`` or ``"numpy"``: auto picks torch when importable. A CUDA device needs
    torch (raises `toolkit.pencil.torch_backend.TorchUnavailableError` otherwise)."""
    from pencilcal.toolkit.pencil import torch_backend as te

    if backend not in ("auto", "torch", "numpy"):
        raise InputError(f"backend must be auto, torch or numpy, got {backend!r}")
    dev = str(device)
    if dev != "cpu" or backend == "torch":
        te.require_torch(dev)
        return "torch"
    if backend == "numpy":
        return "numpy"
    return "torch" if te.torch_available() else "numpy"


def offaxis_vertex(offaxis_deg):
    """Normalised vertex (tan phi, 0) for off-axis angles phi [deg]: (...,) -> (..., 2)."""
    t = np.tan(np.radians(np.asarray(offaxis_deg, float)))
    return np.stack([t, np.zeros_like(t)], -1)


def pose_about_ray(vertex, tilt, psi, theta0):
    """R_cam_from_target tilted by `tilt` [rad] against the vertex ray.

    R = Qt Rz(psi) Rx(tilt) Rz(theta0), Q the virtual camera looking along the ray of
    `vertex` (normalised, (..., 2)); psi turns the tilt axis, theta0 the fan in its plane
    (the exact estimator's parametrisation, docs/method.md). Broadcasts; returns (..., 3, 3).
    """
    vertex = np.asarray(vertex, float)
    v = np.concatenate([vertex, np.ones(vertex.shape[:-1] + (1,))], -1)
    Qt = np.swapaxes(rotation_to_z(v), -1, -2)
    n = np.broadcast_shapes(np.shape(psi), np.shape(theta0), np.shape(tilt))
    z = np.broadcast_to([0.0, 0.0, 1.0], n + (3,))
    rz = lambda a: rotation_about_axis(z, np.broadcast_to(a, n))  # noqa: E731
    rx = rotation_about_axis(np.broadcast_to([1.0, 0.0, 0.0], n + (3,)), np.broadcast_to(tilt, n))
    return Qt @ rz(psi) @ rx @ rz(theta0)


# ----------------------------------------------------------------------------------------
# fitting and statistics


def fit_batch(line_angles, spoke_angles, vertex, sigma, backend="auto", device="cpu", dtype="float64"):
    """Fit pencils with the chosen backend; returns numpy arrays.

    line_angles: (B, N) [rad]; spoke_angles: (N,) [rad]; vertex: (B, 2); sigma: scalar or
    (B, 1) [rad]. Returns dict with ``tilt`` (B,) [rad], ``normal``, ``normal_twin``
    (B, 3) and ``detectable`` (B,) bool.
    """
    backend = resolve_backend(backend, device)
    keys = ("tilt", "normal", "normal_twin", "detectable")
    if backend == "torch":
        from pencilcal.toolkit.pencil.estimator_torch import fit_pencils_torch

        f = fit_pencils_torch(line_angles, spoke_angles, vertex, sigma, device=device, dtype=dtype,
                              output="numpy", strict=False)
        return {k: np.asarray(f[k], dtype=bool if k == "detectable" else float) for k in keys}
    a = np.asarray(line_angles, float)
    x = np.broadcast_to(np.asarray(vertex, float), a.shape[:-1] + (2,))
    s = np.broadcast_to(np.asarray(sigma, float).reshape(-1, 1) if np.ndim(sigma) else sigma, a.shape)
    out = {k: [] for k in keys}
    step = 20_000
    for i in range(0, a.shape[0], step):
        f = fit_pencil(a[i:i + step], spoke_angles, x[i:i + step], sigma=s[i:i + step])
        for k in keys:
            out[k].append(getattr(f, k))
    return {k: np.concatenate(v) for k, v in out.items()}


def crb_cells(tilt_deg, offaxis_deg, spoke_angles, sigma_deg, n_inplane=24):
    """Cramer-Rao bound per cell, RMS over a regular grid of in-plane angles.

    tilt_deg, offaxis_deg, sigma_deg: (C,) broadcastable; spoke_angles: (N,) [rad].
    psi runs over [0, pi) and theta0 over [0, 2 pi) on an n_inplane x n_inplane grid.
    Returns (tilt_bound_deg (C,), normal_bound_deg (C,)); inf at tilt 0 (the tilt is not
    observable to first order there).
    """
    tilt_deg, offaxis_deg, sigma_deg = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, float))
                                                              for v in (tilt_deg, offaxis_deg, sigma_deg)))
    C = tilt_deg.size
    psi, th0 = np.meshgrid(np.linspace(0, np.pi, n_inplane, endpoint=False),
                           np.linspace(0, 2 * np.pi, n_inplane, endpoint=False))
    psi, th0 = psi.ravel(), th0.ravel()
    out_t, out_n = np.empty(C), np.empty(C)
    per = max(1, _BATCH // psi.size)
    for i in range(0, C, per):
        sl = slice(i, i + per)
        x = offaxis_vertex(offaxis_deg[sl])[:, None, :]
        R = pose_about_ray(x, np.radians(tilt_deg[sl])[:, None], psi[None, :], th0[None, :])
        _, bt, bn = crlb(R, x, spoke_angles, np.radians(sigma_deg[sl])[:, None, None])
        out_t[sl] = np.degrees(np.sqrt(np.mean(bt ** 2, -1)))
        out_n[sl] = np.degrees(np.sqrt(np.mean(bn ** 2, -1)))
    zero = tilt_deg <= 0
    out_t[zero] = np.inf
    out_n[zero] = np.inf
    return out_t, out_n


_STATS = ("tilt_rmse_deg", "tilt_median_deg", "tilt_p95_deg", "tilt_bias_deg",
          "normal_rmse_deg", "normal_median_deg", "normal_p95_deg", "detect_rate")


def monte_carlo_cells(tilt_deg, offaxis_deg, spoke_angles, sigma_deg, draws, backend="auto", device="cpu",
                      dtype="float64"):
    """Monte Carlo statistics per cell with common random numbers.

    tilt_deg, offaxis_deg, sigma_deg: (C,) broadcastable; spoke_angles (N,) [rad];
    draws: dict with ``psi`` (T,), ``theta0`` (T,) [rad] and ``z`` (T, >= N) unit normal
    noise, the same in every cell. Returns a dict of (C,) arrays: tilt_rmse_deg,
    tilt_median_deg, tilt_p95_deg (of |error|), tilt_bias_deg (mean error),
    normal_rmse_deg, normal_median_deg, normal_p95_deg (angle to the closer twin) and
    detect_rate (fraction flagged detectable).
    """
    tilt_deg, offaxis_deg, sigma_deg = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, float))
                                                              for v in (tilt_deg, offaxis_deg, sigma_deg)))
    C = tilt_deg.size
    psi, th0 = np.asarray(draws["psi"], float), np.asarray(draws["theta0"], float)
    T, N = psi.size, spoke_angles.size
    z = np.asarray(draws["z"], float)[:, :N]
    out = {k: np.empty(C) for k in _STATS}
    per = max(1, _BATCH // T)
    for i in range(0, C, per):
        sl = slice(i, i + per)
        c = tilt_deg[sl].size
        x = np.repeat(offaxis_vertex(offaxis_deg[sl]), T, axis=0)
        g = np.radians(np.repeat(tilt_deg[sl], T))
        s = np.radians(np.repeat(sigma_deg[sl], T))
        R = pose_about_ray(x, g, np.tile(psi, c), np.tile(th0, c))
        a = image_angles(R, x, spoke_angles) + s[:, None] * np.tile(z, (c, 1))
        f = fit_batch(a, spoke_angles, x, s[:, None], backend, device, dtype)
        n_true = R[:, :, 2]
        et = np.degrees(f["tilt"] - g).reshape(c, T)
        en = np.degrees(np.minimum(angle_between(f["normal"], n_true), angle_between(f["normal_twin"], n_true)))
        en = en.reshape(c, T)
        det = f["detectable"].reshape(c, T)
        out["tilt_rmse_deg"][sl] = np.sqrt(np.mean(et ** 2, -1))
        out["tilt_median_deg"][sl] = np.median(np.abs(et), -1)
        out["tilt_p95_deg"][sl] = np.percentile(np.abs(et), 95, axis=-1)
        out["tilt_bias_deg"][sl] = np.mean(et, -1)
        out["normal_rmse_deg"][sl] = np.sqrt(np.mean(en ** 2, -1))
        out["normal_median_deg"][sl] = np.median(en, -1)
        out["normal_p95_deg"][sl] = np.percentile(en, 95, axis=-1)
        out["detect_rate"][sl] = np.mean(det, -1)
    return out


def _draws(seed, map_name, trials, n_max):
    rng = np.random.default_rng([int(seed), _MAP_ID[map_name]])
    return {"psi": rng.uniform(0, 2 * np.pi, trials), "theta0": rng.uniform(0, 2 * np.pi, trials),
            "z": rng.standard_normal((trials, n_max))}


# ----------------------------------------------------------------------------------------
# reading the curves


def min_tilt_for_accuracy(tilts_deg, values, accuracy_deg):
    """Smallest tilt from which `values` stay at or below `accuracy_deg` [deg].

    tilts_deg: (K,) ascending grid; values: (..., K) an error metric on it (NaN counts as
    failing). The answer lies between the last grid tilt that fails and the next one,
    interpolated linearly in the metric; it is the first grid tilt when none fails and
    NaN when the last one fails. Monotone: a looser accuracy never asks for more tilt.
    Returns (...) [deg].

    >>> float(min_tilt_for_accuracy([0, 10, 20, 30], [5.0, 2.0, 1.0, 0.5], 1.5))
    15.0
    """
    t = np.asarray(tilts_deg, float)
    v = np.asarray(values, float)
    fail = ~(v <= accuracy_deg)
    out = np.full(v.shape[:-1], np.nan)
    for idx in np.ndindex(v.shape[:-1]):
        f = fail[idx]
        if not f.any():
            out[idx] = t[0]
            continue
        i = int(np.flatnonzero(f)[-1])
        if i == t.size - 1:
            continue
        vi, vn = v[idx][i], v[idx][i + 1]
        frac = 0.0 if not np.isfinite(vi) else float(np.clip((vi - accuracy_deg) / (vi - vn), 0.0, 1.0))
        out[idx] = t[i] + frac * (t[i + 1] - t[i])
    return out


def detection_crossings(tilts_deg, rate, levels=(0.5, 0.9)):
    """Tilt [deg] at which the detectable rate first reaches each level.

    tilts_deg: (K,) ascending; rate: (..., K) in [0, 1]. Linear interpolation between the
    grid tilts around the first crossing; the first grid tilt if it already reaches the
    level, NaN if no grid tilt does. Returns (..., len(levels)).
    """
    t = np.asarray(tilts_deg, float)
    r = np.asarray(rate, float)
    out = np.full(r.shape[:-1] + (len(levels),), np.nan)
    for idx in np.ndindex(r.shape[:-1]):
        ri = r[idx]
        for j, lev in enumerate(levels):
            hit = np.flatnonzero(ri >= lev)
            if hit.size == 0:
                continue
            k = int(hit[0])
            if k == 0:
                out[idx + (j,)] = t[0]
            else:
                r0, r1 = ri[k - 1], ri[k]
                out[idx + (j,)] = t[k - 1] + (lev - r0) / max(r1 - r0, 1e-12) * (t[k] - t[k - 1])
    return out


def _curve_answers(tilts, crb_t, crb_n, mc, accuracy):
    ans = {"crb_tilt": min_tilt_for_accuracy(tilts, crb_t, accuracy),
           "crb_normal": min_tilt_for_accuracy(tilts, crb_n, accuracy)}
    if mc is not None:
        ans["mc_tilt_rmse"] = min_tilt_for_accuracy(tilts, mc["tilt_rmse_deg"], accuracy)
        ans["mc_normal_rmse"] = min_tilt_for_accuracy(tilts, mc["normal_rmse_deg"], accuracy)
        ans["mc_normal_p95"] = min_tilt_for_accuracy(tilts, mc["normal_p95_deg"], accuracy)
    return ans


def _grid(v, name, lo=None, hi=None):
    g = parse_range(v, name)
    if lo is not None and g.min() < lo:
        raise InputError(f"{name}: values must be >= {lo:g}, got {g.min():g}")
    if hi is not None and g.max() >= hi:
        raise InputError(f"{name}: values must be < {hi:g}, got {g.max():g}")
    return g


def validate_grids(tilts_deg, offaxis_deg, spokes_grid=None, steps_grid=None, sigmas_grid=None):
    """Check range specs (and their bounds) before any work; raises InputError naming the
    option. Tilts and off-axis angles in [0, 90) deg, spokes >= 3 and whole, steps in
    (0, 360) deg, sigmas > 0 deg. None skips a grid."""
    _grid(tilts_deg, "--tilts", 0.0, 90.0)
    _grid(offaxis_deg, "--offaxis", 0.0, 90.0)
    if spokes_grid is not None:
        S = _grid(spokes_grid, "--spokes-grid", 3.0, MAX_SPOKES + 1.0)
        if np.any(S != np.round(S)):
            raise InputError("--spokes-grid: whole numbers only")
    if steps_grid is not None:
        _grid(steps_grid, "--step-grid", 1e-9, 360.0)
    if sigmas_grid is not None:
        _grid(sigmas_grid, "--sigma-grid", 1e-9, MAX_SIGMA_DEG + 1e-9)


def _one_offaxis(offaxis_deg):
    g = _grid(offaxis_deg, "offaxis", 0.0, 90.0)
    if g.size != 1:
        raise InputError(f"offaxis: this map takes one off-axis angle, got {g.size}")
    return float(g[0])


# ----------------------------------------------------------------------------------------
# the maps


def tilt_offaxis_map(setup, tilts_deg="0:80:2", offaxis_deg="0:40:10", trials=1000, seed=0,
                     accuracy_deg=None, backend="auto", device="cpu", dtype="float64", n_inplane=24):
    """Errors over tilt x off-axis angle of the vertex, for one fan and noise.

    setup: `Setup`; tilts_deg, offaxis_deg: range specs or arrays [deg] (tilt in [0, 90),
    off-axis in [0, 90)); trials: Monte Carlo pencils per cell (0: bound only).
    Returns a dict: ``tilts_deg`` (K,), ``offaxis_deg`` (O,), ``offaxis_px`` (O,),
    ``crb`` {tilt_deg, normal_deg: (O, K)}, ``mc`` {the statistics of `monte_carlo_cells`,
    each (O, K)} or None, ``ratio_tilt``/``ratio_normal`` (O, K) MC RMSE over CRB,
    ``detection`` {rate50_deg, rate90_deg: (O,)}, and with `accuracy_deg` ``min_tilt_deg``
    {crb_tilt, crb_normal, mc_tilt_rmse, mc_normal_rmse, mc_normal_p95: (O,)}.
    """
    tilts = _grid(tilts_deg, "tilts", 0.0, 90.0)
    off = _grid(offaxis_deg, "offaxis", 0.0, 90.0)
    th = setup.spoke_angles()
    T_, O_ = np.meshgrid(tilts, off)
    crb_t, crb_n = crb_cells(T_.ravel(), O_.ravel(), th, setup.sigma_deg, n_inplane)
    out = {"tilts_deg": tilts, "offaxis_deg": off, "offaxis_px": setup.focal_px * np.tan(np.radians(off)),
           "crb": {"tilt_deg": crb_t.reshape(T_.shape), "normal_deg": crb_n.reshape(T_.shape)}, "mc": None}
    if trials > 0:
        d = _draws(seed, "tilt-offaxis", trials, th.size)
        mc = monte_carlo_cells(T_.ravel(), O_.ravel(), th, setup.sigma_deg, d, backend, device, dtype)
        out["mc"] = {k: v.reshape(T_.shape) for k, v in mc.items()}
        with np.errstate(divide="ignore", invalid="ignore"):
            out["ratio_tilt"] = out["mc"]["tilt_rmse_deg"] / out["crb"]["tilt_deg"]
            out["ratio_normal"] = out["mc"]["normal_rmse_deg"] / out["crb"]["normal_deg"]
        cr = detection_crossings(tilts, out["mc"]["detect_rate"])
        out["detection"] = {"rate50_deg": cr[:, 0], "rate90_deg": cr[:, 1]}
    if accuracy_deg is not None:
        out["min_tilt_deg"] = _curve_answers(tilts, out["crb"]["tilt_deg"], out["crb"]["normal_deg"], out["mc"],
                                             accuracy_deg)
    return out


def spokes_spacing_map(setup, spokes="3,4,6,8,12,16", steps_deg="5,10,15,20,30,45", tilts_deg="0:80:2",
                       offaxis_deg=0.0, tilt_ref_deg=30.0, accuracy_deg=1.0, trials=1000, seed=0,
                       backend="auto", device="cpu", dtype="float64", n_inplane=16):
    """Minimum tilt for an accuracy and the error at a reference tilt over spokes x spacing.

    Every fan (S spokes, P deg apart: 0, P, 2P, ...) is evaluated over the tilt grid (plus
    `tilt_ref_deg`) at one off-axis angle and the set-up's noise. Fans with fewer than three
    distinct line directions are NaN. Returns a dict: ``spokes`` (S,), ``steps_deg`` (P,),
    ``tilts_deg`` (K,), ``min_tilt_deg`` {crb_normal, crb_tilt, mc_normal_rmse, mc_tilt_rmse,
    mc_normal_p95: (S, P)}, ``at_tilt_ref`` {crb_normal_deg, mc_normal_rmse_deg,
    mc_tilt_rmse_deg: (S, P)}, ``detection`` {rate50_deg, rate90_deg: (S, P)}, ``curves``
    {crb_normal_deg, mc_normal_rmse_deg, detect_rate: (S, P, K)}.
    """
    S = _grid(spokes, "spokes", 3.0)
    if np.any(S != np.round(S)):
        raise InputError("spokes: whole numbers only")
    S = S.astype(int)
    P = _grid(steps_deg, "steps", 1e-9, 360.0)
    tilts = _grid(tilts_deg, "tilts", 0.0, 90.0)
    tk = np.unique(np.concatenate([tilts, [float(tilt_ref_deg)]]))
    iref = int(np.flatnonzero(np.isclose(tk, tilt_ref_deg))[0])
    keep = np.isin(tk, tilts)
    off = _one_offaxis(offaxis_deg)
    nan = np.full((S.size, P.size), np.nan)
    res = {"min_tilt_deg": {k: nan.copy() for k in ("crb_normal", "crb_tilt", "mc_normal_rmse", "mc_tilt_rmse",
                                                    "mc_normal_p95")},
           "at_tilt_ref": {k: nan.copy() for k in ("crb_normal_deg", "mc_normal_rmse_deg", "mc_tilt_rmse_deg")},
           "detection": {k: nan.copy() for k in ("rate50_deg", "rate90_deg")},
           "curves": {k: np.full((S.size, P.size, tilts.size), np.nan)
                      for k in ("crb_normal_deg", "mc_normal_rmse_deg", "detect_rate")}}
    d = _draws(seed, "spokes-spacing", max(trials, 1), int(S.max()))
    for i, s in enumerate(S):
        for j, p in enumerate(P):
            th = np.radians(np.arange(s) * p)
            if _distinct_lines(th) < 3:
                continue
            crb_t, crb_n = crb_cells(tk, off, th, setup.sigma_deg, n_inplane)
            mc = monte_carlo_cells(tk, off, th, setup.sigma_deg, d, backend, device, dtype) if trials > 0 else None
            ans = _curve_answers(tk[keep], crb_t[keep], crb_n[keep],
                                 None if mc is None else {k: v[keep] for k, v in mc.items()}, accuracy_deg)
            for k, v in ans.items():
                res["min_tilt_deg"][k][i, j] = v
            res["at_tilt_ref"]["crb_normal_deg"][i, j] = crb_n[iref]
            res["curves"]["crb_normal_deg"][i, j] = crb_n[keep]
            if mc is not None:
                res["at_tilt_ref"]["mc_normal_rmse_deg"][i, j] = mc["normal_rmse_deg"][iref]
                res["at_tilt_ref"]["mc_tilt_rmse_deg"][i, j] = mc["tilt_rmse_deg"][iref]
                res["curves"]["mc_normal_rmse_deg"][i, j] = mc["normal_rmse_deg"][keep]
                res["curves"]["detect_rate"][i, j] = mc["detect_rate"][keep]
                cr = detection_crossings(tilts, mc["detect_rate"][keep])
                res["detection"]["rate50_deg"][i, j], res["detection"]["rate90_deg"][i, j] = cr
    return {"spokes": S, "steps_deg": P, "tilts_deg": tilts, "offaxis_deg": off, "tilt_ref_deg": float(tilt_ref_deg),
            "accuracy_deg": float(accuracy_deg), **res}


def noise_map(setup, sigmas_deg="0.02,0.05,0.1,0.2,0.5,1", tilts_deg="0:80:2", offaxis_deg=0.0, accuracy_deg=None,
              trials=1000, seed=0, backend="auto", device="cpu", dtype="float64", n_inplane=24):
    """Errors over line noise x tilt for the set-up's fan, with the detection thresholds.

    Returns a dict: ``sigmas_deg`` (S,), ``tilts_deg`` (K,), ``crb`` {tilt_deg, normal_deg:
    (S, K)}, ``mc`` {statistics: (S, K)} or None, ``detection`` {rule_deg (2 sqrt(sigma)),
    exact_deg (`estimator.detection_threshold`), rate50_deg, rate90_deg: (S,)}, and with
    `accuracy_deg` ``min_tilt_deg`` {...: (S,)}.
    """
    sig = _grid(sigmas_deg, "sigmas", 1e-9)
    tilts = _grid(tilts_deg, "tilts", 0.0, 90.0)
    off = _one_offaxis(offaxis_deg)
    th = setup.spoke_angles()
    T_, S_ = np.meshgrid(tilts, sig)
    crb_t, crb_n = crb_cells(T_.ravel(), off, th, S_.ravel(), n_inplane)
    srad = np.radians(sig)
    out = {"sigmas_deg": sig, "tilts_deg": tilts, "offaxis_deg": off,
           "crb": {"tilt_deg": crb_t.reshape(T_.shape), "normal_deg": crb_n.reshape(T_.shape)}, "mc": None,
           "detection": {"rule_deg": np.degrees(2.0 * np.sqrt(srad)), "exact_deg": np.degrees(detection_threshold(srad))}}
    if trials > 0:
        d = _draws(seed, "noise", trials, th.size)
        mc = monte_carlo_cells(T_.ravel(), off, th, S_.ravel(), d, backend, device, dtype)
        out["mc"] = {k: v.reshape(T_.shape) for k, v in mc.items()}
        cr = detection_crossings(tilts, out["mc"]["detect_rate"])
        out["detection"]["rate50_deg"], out["detection"]["rate90_deg"] = cr[:, 0], cr[:, 1]
    if accuracy_deg is not None:
        out["min_tilt_deg"] = _curve_answers(tilts, out["crb"]["tilt_deg"], out["crb"]["normal_deg"], out["mc"],
                                             accuracy_deg)
    return out


def plan(setup, tilts_deg="0:80:2", offaxis_deg="0:40:10", trials=1000, accuracy_deg=1.0, maps=("tilt-offaxis",),
         spokes_grid="3,4,6,8,12,16", steps_grid="5,10,15,20,30,45", sigmas_grid="0.02,0.05,0.1,0.2,0.5,1",
         tilt_ref_deg=30.0, backend="auto", device="cpu", dtype="float64", seed=0, log=None):
    """Everything `pencilcal sensitivity` writes: the maps asked for and the answer.

    The tilt x off-axis map is always computed (the answer comes from it); `maps` adds
    "spokes-spacing" and/or "noise" (evaluated at the largest off-axis angle of the grid,
    the worst case). `log`: callable(str) for progress lines, or None.

    The answer (``answer``) is the smallest tilt from which the RMS angle of the normal
    (closer twin, Monte Carlo) stays at or below `accuracy_deg`, per off-axis angle and
    the worst of them, with the same read from the bound and from the tilt error
    (``below_grid``: reached already at the first grid tilt, the limit lies lower); the
    detection threshold (``detection``) compares the 2 sqrt(sigma) rule, its exact form
    and the measured 50% / 90% detectable rates.
    """
    unknown = [m for m in maps if m not in MAPS]
    if unknown:
        raise InputError(f"unknown map(s) {unknown}; expected {', '.join(MAPS)} or all")
    if trials < 0 or int(trials) != trials:
        raise InputError(f"trials must be a whole number >= 0, got {trials!r}")
    if trials > MAX_TRIALS:
        raise InputError(f"trials: {trials:,} is over the limit of {MAX_TRIALS:,} Monte Carlo pencils per cell")
    if not (np.isfinite(accuracy_deg) and accuracy_deg > 0):
        raise InputError(f"accuracy must be positive, got {accuracy_deg!r} deg")
    trials = int(trials)
    backend = resolve_backend(backend, device)
    log = log or (lambda msg: None)
    kw = dict(trials=trials, seed=seed, backend=backend, device=device, dtype=dtype)
    t0 = time.perf_counter()
    tilts = _grid(tilts_deg, "tilts", 0.0, 90.0)
    off = _grid(offaxis_deg, "offaxis", 0.0, 90.0)
    log(f"tilt x off-axis map: {tilts.size} x {off.size} cells x {trials} trials ({backend})")
    base = tilt_offaxis_map(setup, tilts, off, accuracy_deg=accuracy_deg, **kw)
    result = {
        "setup": {**asdict(setup), "spoke_angles_deg": np.round(np.degrees(setup.spoke_angles()), 12), "trials": trials,
                  "seed": int(seed), "accuracy_deg": float(accuracy_deg)},
        "backend": {"name": backend, "device": str(device), "dtype": dtype if backend == "torch" else "float64"},
        "maps": {"tilt_offaxis": base},
    }
    mt = base["min_tilt_deg"]
    per = []
    for k, o in enumerate(off):
        per.append({"offaxis_deg": float(o), "offaxis_px": float(base["offaxis_px"][k]),
                    **{f"{name}_deg": float(v[k]) for name, v in mt.items()}})
    key = "mc_normal_rmse" if trials > 0 else "crb_normal"
    vals = mt[key]
    worst = float(np.max(vals)) if np.all(np.isfinite(vals)) else float("nan")
    sig = math.radians(setup.sigma_deg)
    rule = math.degrees(2.0 * math.sqrt(sig))
    exact = float(np.degrees(detection_threshold(sig)))
    below_grid = bool(np.isfinite(worst) and worst <= tilts[0])
    if np.isfinite(worst):
        when = (f"at every tilt of the grid, from {tilts[0]:g} deg on (extend --tilts downwards to find the limit)"
                if below_grid else f"from a tilt of {worst:.1f} deg on")
        text = (f"With {setup.spokes} spokes {setup.step_deg:g} deg apart and {setup.sigma_deg:g} deg of line noise, "
                f"the normal is good to {accuracy_deg:g} deg ({'RMS, Monte Carlo' if trials else 'Cramer-Rao bound'}) "
                f"{when}, with the vertex up to {off.max():.1f} deg "
                f"({setup.focal_px * math.tan(math.radians(off.max())):.0f} px at f = {setup.focal_px:g} px) off axis.")
    else:
        text = (f"With {setup.spokes} spokes {setup.step_deg:g} deg apart and {setup.sigma_deg:g} deg of line noise, "
                f"the normal is not good to {accuracy_deg:g} deg anywhere up to {tilts.max():g} deg of tilt "
                f"on the whole off-axis range (see answer.per_offaxis).")
    if trials == 0:
        text += (f" The bound ignores the detection threshold ({rule:.1f} deg by the 2 sqrt(sigma) rule, "
                 f"where the estimate turns into noise): use trials > 0 for the estimator itself.")
    result["answer"] = {"accuracy_deg": float(accuracy_deg),
                        "metric": "RMS angle of the normal to the closer twin" + (" (Monte Carlo)" if trials else
                                                                                  " (Cramer-Rao bound)"),
                        "min_tilt_deg": worst, "below_grid": below_grid, "per_offaxis": per, "text": text}
    det = {"sigma_deg": float(setup.sigma_deg), "rule_2sqrt_sigma_deg": rule, "exact_deg": exact}
    if trials > 0:
        det["measured"] = [{"offaxis_deg": float(o), "rate50_deg": float(base["detection"]["rate50_deg"][k]),
                            "rate90_deg": float(base["detection"]["rate90_deg"][k])} for k, o in enumerate(off)]
    result["detection"] = det
    log(f"  done in {time.perf_counter() - t0:.1f} s")
    if "spokes-spacing" in maps:
        t1 = time.perf_counter()
        log(f"spokes x spacing map at {off.max():.1f} deg off axis")
        result["maps"]["spokes_spacing"] = spokes_spacing_map(
            setup, spokes_grid, steps_grid, tilts, off.max(), tilt_ref_deg, accuracy_deg, **kw)
        log(f"  done in {time.perf_counter() - t1:.1f} s")
    if "noise" in maps:
        t1 = time.perf_counter()
        log(f"noise x tilt map at {off.max():.1f} deg off axis")
        result["maps"]["noise"] = noise_map(setup, sigmas_grid, tilts, off.max(), accuracy_deg, **kw)
        log(f"  done in {time.perf_counter() - t1:.1f} s")
    result["seconds"] = time.perf_counter() - t0
    return result


# ----------------------------------------------------------------------------------------
# heatmaps


def _edges(v, log=False):
    """Cell edges around grid centres (half a step beyond the ends)."""
    v = np.asarray(v, float)
    if log:
        return np.exp(_edges(np.log(v)))
    if v.size == 1:
        return np.array([v[0] - 0.5, v[0] + 0.5])
    mid = 0.5 * (v[1:] + v[:-1])
    return np.concatenate([[v[0] - (mid[0] - v[0])], mid, [v[-1] + (v[-1] - mid[-1])]])


def _lognorm(values):
    from matplotlib.colors import LogNorm

    v = np.asarray(values, float)
    ok = v[np.isfinite(v) & (v > 0)]
    if ok.size == 0:
        return None
    lo, hi = float(ok.min()), float(ok.max())
    return LogNorm(vmin=lo, vmax=max(hi, lo * 1.0001))


def _masked(v):
    return np.ma.masked_invalid(np.asarray(v, float))


def _heat_tilt_offaxis(fig, m, accuracy, sigma_deg):
    mc = m.get("mc")
    err = mc["normal_rmse_deg"] if mc is not None else m["crb"]["normal_deg"]
    t, o = m["tilts_deg"], m["offaxis_deg"]
    axes = fig.subplots(1, 2 if mc is not None else 1, squeeze=False)[0]
    ax = axes[0]
    # the bound is infinite at zero tilt: the colour scale starts at the largest finite value
    pm = ax.pcolormesh(_edges(t), _edges(o), _masked(err), norm=_lognorm(err), cmap="viridis_r", shading="flat")
    fig.colorbar(pm, ax=ax, label="normal error, RMS [deg]")
    mt = m.get("min_tilt_deg", {}).get("mc_normal_rmse" if mc is not None else "crb_normal")
    if mt is not None:
        ax.plot(mt, o, "w^-", ms=6, lw=1.5, label=f"min tilt for {accuracy:g} deg")
    rule = math.degrees(2.0 * math.sqrt(math.radians(sigma_deg)))
    ax.axvline(rule, color="tab:red", ls="--", lw=1.2, label=f"2 sqrt(sigma) = {rule:.1f} deg")
    ax.set_xlabel("tilt against the vertex ray [deg]")
    ax.set_ylabel("vertex off axis [deg]")
    ax.set_title("normal error (" + ("Monte Carlo, closer twin)" if mc is not None else "Cramer-Rao bound)"))
    _legend_under(ax)
    if mc is not None:
        ax2 = axes[1]
        pm2 = ax2.pcolormesh(_edges(t), _edges(o), _masked(mc["detect_rate"]), vmin=0, vmax=1, cmap="magma",
                             shading="flat")
        fig.colorbar(pm2, ax=ax2, label="fraction flagged detectable")
        det = m.get("detection")
        if det is not None:
            ax2.plot(det["rate50_deg"], o, "co", ms=5, label="50% detectable")
            ax2.plot(det["rate90_deg"], o, "bs", ms=5, label="90% detectable")
        ax2.axvline(rule, color="tab:red", ls="--", lw=1.2, label="2 sqrt(sigma)")
        ax2.set_xlim(max(_edges(t)[0], 0.0), min(_edges(t)[-1], max(4 * rule, t[min(3, t.size - 1)])))
        ax2.set_xlabel("tilt against the vertex ray [deg]")
        ax2.set_ylabel("vertex off axis [deg]")
        ax2.set_title("detection (likelihood-ratio test, 1%)")
        _legend_under(ax2)
    for a in axes:
        a.set_ylim(max(_edges(o)[0], 0.0), _edges(o)[-1])
    ax.set_xlim(max(_edges(t)[0], 0.0), _edges(t)[-1])


def _legend_under(ax):
    """The axes' legend below it, outside the map (never over its cells)."""
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2, fontsize=8, framealpha=0.9)


def _annotate(ax, values, fmt):
    for (i, j), v in np.ndenumerate(np.asarray(values, float)):
        ax.text(j, i, fmt(v), ha="center", va="center", fontsize=8, color="black",
                bbox=dict(boxstyle="round,pad=0.1", fc="white", ec="none", alpha=0.6))


def _heat_spokes_spacing(fig, m):
    S, P = m["spokes"], m["steps_deg"]
    key = "mc_normal_rmse" if np.isfinite(m["at_tilt_ref"]["mc_normal_rmse_deg"]).any() else "crb_normal"
    mt = m["min_tilt_deg"][key]
    ref = m["at_tilt_ref"]["mc_normal_rmse_deg" if key.startswith("mc") else "crb_normal_deg"]
    ax1, ax2 = fig.subplots(1, 2)
    top = m["tilts_deg"][-1]
    pm = ax1.imshow(_masked(mt), origin="lower", cmap="viridis_r", aspect="auto")
    fig.colorbar(pm, ax=ax1, label="minimum tilt [deg]")
    _annotate(ax1, mt, lambda v: f"{v:.1f}" if np.isfinite(v) else f">{top:g}")
    ax1.set_title(f"minimum tilt for {m['accuracy_deg']:g} deg (normal, "
                  + ("MC RMS)" if key.startswith("mc") else "bound)"))
    pm2 = ax2.imshow(_masked(ref), origin="lower", cmap="viridis_r", norm=_lognorm(ref), aspect="auto")
    fig.colorbar(pm2, ax=ax2, label="normal error, RMS [deg]")
    _annotate(ax2, ref, lambda v: f"{v:.2g}" if np.isfinite(v) else "-")
    ax2.set_title(f"normal error at {m['tilt_ref_deg']:g} deg of tilt")
    for ax in (ax1, ax2):
        ax.set_xticks(range(P.size), [f"{p:g}" for p in P])
        ax.set_yticks(range(S.size), [str(int(s)) for s in S])
        ax.set_xlabel("spacing between spokes [deg]")
        ax.set_ylabel("spokes")


def _heat_noise(fig, m, accuracy):
    mc = m.get("mc")
    err = mc["normal_rmse_deg"] if mc is not None else m["crb"]["normal_deg"]
    t, s = m["tilts_deg"], m["sigmas_deg"]
    ax = fig.subplots()
    pm = ax.pcolormesh(_edges(t), np.arange(s.size + 1) - 0.5, _masked(err), norm=_lognorm(err), cmap="viridis_r",
                       shading="flat")
    fig.colorbar(pm, ax=ax, label="normal error, RMS [deg]")
    rows = np.arange(s.size)
    det = m["detection"]
    ax.plot(det["rule_deg"], rows, "--", color="tab:red", lw=1.2, label="2 sqrt(sigma)")
    if "rate50_deg" in det:
        ax.plot(det["rate50_deg"], rows, "co:", ms=4, label="measured: 50% detectable")
    mt = m.get("min_tilt_deg", {}).get("mc_normal_rmse" if mc is not None else "crb_normal")
    if mt is not None:
        ax.plot(mt, rows, "w^-", ms=5, lw=1, label=f"min tilt for {accuracy:g} deg")
    ax.set_yticks(rows, [f"{v:g}" for v in s])
    ax.set_xlim(max(_edges(t)[0], 0.0), _edges(t)[-1])
    ax.set_xlabel("tilt against the vertex ray [deg]")
    ax.set_ylabel("line-angle noise sigma [deg]")
    ax.set_title("normal error over noise and tilt (" + ("Monte Carlo)" if mc is not None else "bound)"))
    _legend_under(ax)


def heatmap_paths(prefix, maps):
    """PNG paths `write_heatmaps` writes for these maps: ``<prefix>_<map>.png``."""
    return [f"{prefix}_{name}.png" for name in MAPS if name in maps]


def write_heatmaps(result, prefix, force=False):
    """Write one PNG per map of a `plan` result: ``<prefix>_tilt-offaxis.png``,
    ``<prefix>_spokes-spacing.png``, ``<prefix>_noise.png`` (those computed). Returns the
    paths. Files are written atomically and kept unless `force`.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    from pencilcal.toolkit.io.files import atomic_path

    maps = result["maps"]
    acc = result["setup"]["accuracy_deg"]
    present = [n for n, k in (("tilt-offaxis", "tilt_offaxis"), ("spokes-spacing", "spokes_spacing"),
                              ("noise", "noise")) if k in maps]
    paths = heatmap_paths(prefix, present)
    for name, path in zip(present, paths):
        if name == "tilt-offaxis":
            fig = Figure(figsize=(12, 4.8), layout="constrained")
            _heat_tilt_offaxis(fig, maps["tilt_offaxis"], acc, result["setup"]["sigma_deg"])
        elif name == "spokes-spacing":
            fig = Figure(figsize=(12, 4.8), layout="constrained")
            _heat_spokes_spacing(fig, maps["spokes_spacing"])
        else:
            fig = Figure(figsize=(7.5, 4.8), layout="constrained")
            _heat_noise(fig, maps["noise"], acc)
        st = result["setup"]
        fig.suptitle(f"{st['spokes']} spokes {st['step_deg']:g} deg apart, sigma {st['sigma_deg']:g} deg, "
                     f"f = {st['focal_px']:g} px, {st['trials']} trials", fontsize=9)
        with atomic_path(path, force) as tmp:
            fig.savefig(tmp, format="png", dpi=110)
    return paths

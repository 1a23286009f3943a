"""Edge-level stereo pivots: the 3-D fulcrum from one eye and from both, against the truth.

How well do `pencilcal fulcrum`'s 3-D fulcrums and their covariances hold on a stereo
endoscope? This module draws pivots like a da Vinci endoscope's at the level of the shafts'
edges (no images: each edge is the exact silhouette of the true cylinder, moved by Gaussian
noise), runs the product's estimators on them as the command does, and tabulates the errors
against the truth:

- one eye's 3-D point (`pencil.fulcrum.fulcrum_point`, the variance factor and the port's
  play read from the axes' scatter), each eye on its own frames, in its own camera frame;
- both eyes' fused point (`pencil.stereo_axes.stereo_axes_from_frames`: the shafts matched
  between the eyes, each axis from both silhouettes, the fulcrum of those with the rig's
  covariance: fulcrum.json's ``stereo.axes``), in the left camera frame.

The set-up (`SETUP`): a rectified pair, f = 520 px, 640x480, the right eye 5 mm along +x
(``p_right = R_right_from_left p_left + t_right_from_left``, t = (-5, 0, 0) mm); per pivot
the rig is drawn off its calibration by `RIG_COV` (0.5 mrad and 0.02 mm sd) and that
covariance is given to the estimator. One 8 mm shaft pivots about a fulcrum 60 mm to the
left or right, 70-110 mm deep, -20..20 mm in y (left camera frame); in each of `frames`
frames its tip is seen 40-150 mm away anywhere in the image but a 60 px border, its axis
passes within the port's play of the fulcrum (an offset orthogonal to the axis, 0-1 mm,
uniform in length: 0.41 mm sd per direction), and each eye sees the shaft from the tip back
towards the port, its axis's image 100-300 px long and 5 px inside the image (a pose that
either eye cannot see so is drawn again; the edges, the axis image's ends moved out onto
the two silhouette lines, may end a few pixels beyond the image).
Each edge is a segment whose angle and centre offset are drawn with `noise` times the
stated sd (`STATED_EDGE_SD_PX` at the centre, sqrt(12) sd / length [rad] in angle, as for
a line fitted to points spread evenly along the segment) while its ``edge_cov`` says the
stated sd: noise 2 makes the edges twice as noisy as they say, as real edges are.

Everything is seeded: ``draw_pivot(seed, noise)`` gives the same frames on every machine
with this numpy (the draws follow one `numpy.random.default_rng(seed)` in a fixed order).

Reproduce the tables of docs/uncertainty.md and docs/method.md::

    python -m pencilcal.validation.fulcrum_pivots --seeds 1040:1080 --noise 1,2,3
    python -m pencilcal.validation.fulcrum_pivots --seeds 1040:1120 --noise 2 --eyes-only

Example
-------
>>> p = draw_pivot(1040, 2.0, frames=4)          # pivot_table(seeds, noise) runs the estimators
>>> len(p.frames_left), np.round(p.fulcrum, 1).tolist()
(4, [60.0, -4.0, 90.2])
>>> np.round(p.frames_left[0]["shafts"][0]["edges"], 1).tolist()      # its two edges [px]
[[448.7, 296.1, 640.4, 246.6], [436.6, 247.2, 629.4, 202.3]]
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.camera.stereo import StereoRig
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.geometry.frames import rotation_from_rotvec
from pencilcal.toolkit.geometry.quantiles import chi2_isf
from pencilcal.toolkit.pencil.cylinder import project_cylinder
from pencilcal.toolkit.pencil.fulcrum import fulcrum_point
from pencilcal.toolkit.pencil.stereo_axes import stereo_axes_from_frames
from pencilcal.validation.metrics import seed_list

__all__ = ["SETUP", "RIG_COV", "STATED_EDGE_SD_PX", "REGION", "Pivot", "pivot_camera", "draw_pivot",
           "pivot_errors", "pivot_table", "format_table", "main"]

#: The simulated endoscope and instrument (lengths [mm], pixels [px]).
SETUP = {"focal_px": 520.0, "size": (640, 480), "baseline_mm": 5.0, "diameter_mm": 8.0, "tip_depth_mm": (40.0, 150.0),
         "play_mm": 1.0, "segment_px": (100.0, 300.0), "border_px": 60.0, "fulcrum_side_mm": 60.0,
         "fulcrum_y_mm": (-20.0, 20.0), "fulcrum_depth_mm": (70.0, 110.0)}
#: The rig's calibration error per pivot (and the covariance the estimator is given): rotation
#: vector [rad] then translation [mm].
RIG_COV = np.diag([0.5e-3**2] * 3 + [0.02**2] * 3)
#: The edges' stated sd at the segment's centre [px] (their ``edge_cov``).
STATED_EDGE_SD_PX = 0.15
#: The share of a 3-D error's chi2 (3 dof) its "68 % region" holds; 3 sigma is 99.73 %.
REGION = 0.68
_THREE_SIGMA = 0.9973
# an image point this close to the border is not seen [px]
_MARGIN_PX = 5.0
# the tip is drawn in front of the left camera at least this far [mm]; the axis is walked
# back while its points stay this far in front
_MIN_TIP_DEPTH, _MIN_AXIS_DEPTH = 20.0, 10.0
# the shaft's pose is drawn again at most this many times per frame
_TRIES = 200


class Pivot(NamedTuple):
    """One simulated stereo pivot (`draw_pivot`).

    camera: the `Camera` of both eyes (pinhole, no distortion); frames_left, frames_right:
    lines.json frames (``image``, ``ok``, ``shafts`` with ``edges`` (2, 4) [px] and
    ``edge_cov`` (2, 2, 2) of (angle [rad], offset [px])), paired by image name; rig: the
    calibrated `StereoRig` with its covariance `RIG_COV`; fulcrum: (3,) the true fulcrum in
    the left camera frame [mm]; R_right_from_left (3, 3), t_right_from_left (3,) [mm]: the
    true rig the right eye's edges were drawn with.
    """

    camera: Camera
    frames_left: list
    frames_right: list
    rig: StereoRig
    fulcrum: np.ndarray
    R_right_from_left: np.ndarray
    t_right_from_left: np.ndarray

    @property
    def fulcrum_right(self) -> np.ndarray:
        """(3,) the true fulcrum in the right camera frame [mm]."""
        return self.R_right_from_left @ self.fulcrum + self.t_right_from_left


def pivot_camera() -> Camera:
    """Both eyes' camera of `SETUP`: pinhole, principal point at the image centre."""
    w, h = SETUP["size"]
    f = SETUP["focal_px"]
    return Camera("pinhole", w, h, [[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]])


def _project(K, X):
    """(2,) pixel of the camera-frame point X (3,) [mm]."""
    x = K @ X
    return x[:2] / x[2]


def _seen(p, size):
    w, h = size
    return _MARGIN_PX <= p[0] <= w - _MARGIN_PX and _MARGIN_PX <= p[1] <= h - _MARGIN_PX


def _eye_edges(K, size, A, d, tip_s, rng, sd, R_eye_from_left=None, t_eye_from_left=None):
    """One eye's two edge segments (2, 4) [px] and their stated covariances (2, 2, 2) of the
    shaft on the axis through A (3,) along the unit d (3,) [left camera frame, mm; d from the
    fulcrum to the tip], seen from its tip A + tip_s d back towards the fulcrum over
    `segment_px`; edges drawn with sd [px] at the centre. None where that eye does not see it so."""
    R = np.eye(3) if R_eye_from_left is None else R_eye_from_left
    t = np.zeros(3) if t_eye_from_left is None else t_eye_from_left
    Ae, de = R @ A + t, R @ d
    try:
        lines = project_cylinder(K, Ae, de, 0.5 * SETUP["diameter_mm"]).lines
    except InputError:
        return None
    tip = Ae + tip_s * de
    if tip[2] < _MIN_TIP_DEPTH or not _seen(_project(K, tip), size):
        return None
    p0 = _project(K, tip)
    lo, hi = SETUP["segment_px"]
    # walk back along the axis until it leaves the view or its image is `hi` long
    s_end = None
    for s in np.linspace(0, tip_s, 400)[1:]:
        X = tip - s * de
        if X[2] < _MIN_AXIS_DEPTH or not _seen(_project(K, X), size):
            break
        s_end = s
        if np.linalg.norm(_project(K, X) - p0) >= hi:
            break
    if s_end is None:
        return None
    p1 = _project(K, tip - s_end * de)
    if np.linalg.norm(p1 - p0) < lo:
        return None
    edges, covs = [], []
    for a, b, c in lines:
        # the axis image's ends moved onto this silhouette line
        n = np.array([a, b])
        q0, q1 = p0 - (n @ p0 + c) * n, p1 - (n @ p1 + c) * n
        length = np.linalg.norm(q1 - q0)
        u = (q1 - q0) / length
        phi = np.arctan2(u[1], u[0]) + rng.normal(0, sd * np.sqrt(12.0) / length)
        u = np.array([np.cos(phi), np.sin(phi)])
        centre = 0.5 * (q0 + q1) + rng.normal(0, sd) * np.array([-u[1], u[0]])
        edges.append(np.r_[centre - 0.5 * length * u, centre + 0.5 * length * u])
        covs.append(np.diag([(STATED_EDGE_SD_PX * np.sqrt(12.0) / length) ** 2, STATED_EDGE_SD_PX**2]))
    return np.array(edges), np.array(covs)


def _frame_shaft(K, size, rng, F, sd, play, R, t):
    """One frame's shaft pivoting about F (3,) [mm]: ((edges, covs) left, (edges, covs)
    right), or None on a draw that either eye does not see."""
    border = SETUP["border_px"]
    w, h = size
    u = rng.uniform(border, w - border)
    v = rng.uniform(border, h - border)
    z = rng.uniform(*SETUP["tip_depth_mm"])
    tip = z * np.linalg.solve(K, [u, v, 1.0])
    d = tip - F
    d /= np.linalg.norm(d)
    off = rng.normal(size=3)
    off -= (off @ d) * d
    # the port's play: the axis passes beside the fulcrum, orthogonally to itself
    A = F + rng.uniform(0, play) * off / np.linalg.norm(off)
    tip_s = (tip - A) @ d
    left = _eye_edges(K, size, A, d, tip_s, rng, sd)
    right = _eye_edges(K, size, A, d, tip_s, rng, sd, R, t)
    if left is None or right is None:
        return None
    return left, right


def draw_pivot(seed, noise, frames=50, play=None) -> Pivot:
    """A stereo pivot of `SETUP` (module docstring), drawn from ``default_rng(seed)``.

    noise: the edges' sd as a multiple of the stated `STATED_EDGE_SD_PX` (0: exact edges);
    frames: how many frames; play: the port's largest play [mm] (None: `SETUP`'s 1 mm; 0:
    every axis through the fulcrum). Returns a `Pivot`.
    """
    if not (np.isfinite(noise) and noise >= 0):
        raise InputError(f"draw_pivot: the edge noise multiple must be >= 0, got {noise}")
    if frames < 2:
        raise InputError(f"draw_pivot: a pivot needs two frames at least, got {frames}")
    play = SETUP["play_mm"] if play is None else float(play)
    camera = pivot_camera()
    K, size = np.asarray(camera.K, float), camera.size
    rng = np.random.default_rng(seed)
    R0, t0 = np.eye(3), np.array([-SETUP["baseline_mm"], 0.0, 0.0])
    error = rng.multivariate_normal(np.zeros(6), RIG_COV)
    R_right_from_left = rotation_from_rotvec(error[:3]) @ R0
    t_right_from_left = t0 + error[3:]
    side = SETUP["fulcrum_side_mm"] * rng.choice([-1, 1])
    F = np.array([side, rng.uniform(*SETUP["fulcrum_y_mm"]), rng.uniform(*SETUP["fulcrum_depth_mm"])])
    sd = noise * STATED_EDGE_SD_PX
    left, right = [], []
    while len(left) < frames:
        for _ in range(_TRIES):
            shaft = _frame_shaft(K, size, rng, F, sd, play, R_right_from_left, t_right_from_left)
            if shaft is not None:
                break
        if shaft is None:
            continue
        name = f"{len(left):03d}.png"
        for out, (edges, covs) in zip((left, right), shaft):
            out.append({"image": name, "ok": True, "shafts": [{"edges": edges.tolist(), "edge_cov": covs.tolist()}]})
    rig = StereoRig(R0, t0, cov=RIG_COV)
    return Pivot(camera, left, right, rig, F, R_right_from_left, t_right_from_left)


def _judged(point, cov, truth):
    """{error (3,), error_mm, chi2 (3 dof), along_ray_mm (the error along the ray from the
    camera to the truth: < 0 nearer the camera), sigma_along_ray_mm} of an estimate."""
    e = np.asarray(point, float) - truth
    cov = np.asarray(cov, float)
    ray = truth / np.linalg.norm(truth)
    return {"error": e, "error_mm": float(np.linalg.norm(e)), "chi2": float(e @ np.linalg.solve(cov, e)),
            "along_ray_mm": float(e @ ray), "sigma_along_ray_mm": float(np.sqrt(ray @ cov @ ray))}


def pivot_errors(pivot: Pivot, stereo=True) -> dict:
    """Each estimate of one pivot judged against its truth: {"left", "right": one eye's 3-D
    point in its own camera frame (with ``play_sigma_mm``, ``variance_factor``), "stereo":
    the fused point in the left camera frame (with ``noise_factor``, ``play_sigma_mm``,
    ``axes``, ``axes_used``)}, each a `_judged` dict or None where the estimator found no
    point (its message in ``failures``). stereo=False leaves the fused point out (None)."""
    d = SETUP["diameter_mm"]
    out, failures = {}, {}
    for eye, frames, truth in (("left", pivot.frames_left, pivot.fulcrum),
                               ("right", pivot.frames_right, pivot.fulcrum_right)):
        try:
            p = fulcrum_point(pivot.camera, frames, d)
        except EstimationError as e:
            out[eye], failures[eye] = None, str(e)
            continue
        out[eye] = {**_judged(p.fit.point, p.fit.point_cov, truth), "play_sigma_mm": float(np.sqrt(p.play)),
                    "variance_factor": float(p.variance_factor)}
    out["stereo"] = None
    if stereo:
        try:
            s = stereo_axes_from_frames(pivot.camera, pivot.frames_left, pivot.camera, pivot.frames_right, pivot.rig, d)
            out["stereo"] = {**_judged(s["point"], s["point_cov"], pivot.fulcrum), "noise_factor": s["noise_factor"],
                             "play_sigma_mm": s["play_sigma"], "axes": s["axes"], "axes_used": s["axes_used"]}
        except EstimationError as e:
            failures["stereo"] = str(e)
    out["failures"] = failures
    return out


def _summary(judged):
    """The table's columns over a list of `_judged` dicts (None: no point)."""
    ok = [j for j in judged if j is not None]
    n = len(ok)
    if n == 0:
        return {"count": 0, "failed": len(judged)}
    e = np.array([j["error_mm"] for j in ok])
    c = np.array([j["chi2"] for j in ok])
    a = np.array([j["along_ray_mm"] for j in ok])
    inside = int(np.sum(c <= chi2_isf(1 - REGION, 3)))
    sd = float(np.std(a, ddof=1)) if n > 1 else 0.0
    return {"count": n, "failed": len(judged) - n, "rms_mm": float(np.sqrt(np.mean(e**2))), "max_mm": float(e.max()),
            "in_region": inside, "in_region_share": inside / n,
            "within_3_sigma_share": float(np.mean(c <= chi2_isf(1 - _THREE_SIGMA, 3))),
            "mean_chi2": float(c.mean()), "median_chi2": float(np.median(c)),
            "along_ray_mm": float(a.mean()), "along_ray_t": float(a.mean() / (sd / np.sqrt(n))) if sd > 0 else 0.0,
            "sigma_along_ray_median_mm": float(np.median([j["sigma_along_ray_mm"] for j in ok]))}


def _row(noise, pivots):
    """One multiple's row of `pivot_table` from its pivots' `pivot_errors`."""
    eyes = [p[k] for p in pivots for k in ("left", "right")]
    row = {"noise": noise, "pivots": len(pivots), "eyes": _summary(eyes),
           "left": _summary([p["left"] for p in pivots]), "right": _summary([p["right"] for p in pivots])}
    row["eyes"]["play_sigma_median_mm"] = float(np.median([j["play_sigma_mm"] for j in eyes if j is not None] or [np.nan]))
    stereo = [p["stereo"] for p in pivots]
    if any(s is not None for s in stereo) or any("stereo" in p["failures"] for p in pivots):
        s = _summary(stereo)
        # an eye without a point counts as infinitely far off
        far = [(p["stereo"]["error_mm"], *[np.inf if p[k] is None else p[k]["error_mm"] for k in ("left", "right")])
               for p in pivots if p["stereo"] is not None]
        if far:
            f, l, r = np.array(far).T
            s.update(worse_than_both_share=float(np.mean(f > np.maximum(l, r))),
                     worse_than_better_share=float(np.mean(f > np.minimum(l, r))),
                     noise_factor_median=float(np.median([p["stereo"]["noise_factor"] for p in pivots
                                                          if p["stereo"] is not None])))
        row["stereo"] = s
    return row


def pivot_table(seeds, noise=(1.0, 2.0, 3.0), frames=50, stereo=True, play=None, log=None) -> dict:
    """The table docs/uncertainty.md quotes: per edge-noise multiple, the pivots of `seeds`
    (`draw_pivot`) and their estimates (`pivot_errors`) summarised.

    seeds: iterable of ints; noise: the multiples of the stated edge sd; frames: per pivot;
    stereo: also the fused point (the costly part: ~2 s of CPU a pivot of 50 frames against
    ~0.5 s for both eyes' points); play: as `draw_pivot`; log: a callable given one line per
    pivot, or None. Returns {"setup", "seeds", "frames", "rows": [per multiple {"noise",
    "pivots", "eyes" (both eyes' points pooled: 2 per pivot), "left", "right", "stereo"
    (without stereo: absent)}], "pivots": [per multiple, per seed, `pivot_errors` without
    the error vectors]}. Each summary: count, failed, rms_mm, max_mm, in_region (of count,
    inside the `REGION` quantile of chi2 with 3 dof), in_region_share, within_3_sigma_share,
    mean_chi2, median_chi2, along_ray_mm (the mean error along the ray from the camera to
    the fulcrum: < 0 nearer the camera) and its t, sigma_along_ray_median_mm; the eyes' also
    play_sigma_median_mm; the stereo's also worse_than_both_share and
    worse_than_better_share (the fused point further off than both eyes' / the better eye's)
    and noise_factor_median.
    """
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise InputError("pivot_table: no seeds")
    rows, records = [], []
    for mult in noise:
        pivots = []
        for seed in seeds:
            res = pivot_errors(draw_pivot(seed, mult, frames, play), stereo)
            pivots.append(res)
            records.append({"noise": mult, "seed": seed, "failures": res["failures"],
                            **{k: None if res[k] is None else {a: b for a, b in res[k].items() if a != "error"}
                               for k in ("left", "right", "stereo")}})
            if log is not None:
                log(f"noise x{mult:g} seed {seed}: " + ", ".join(
                    f"{k} {'-' if res[k] is None else format(res[k]['error_mm'], '.3f')} mm"
                    for k in ("left", "right", "stereo") if stereo or k != "stereo"))
        rows.append(_row(float(mult), pivots))
    return {"setup": {**SETUP, "stated_edge_sd_px": STATED_EDGE_SD_PX, "rig_cov": RIG_COV.tolist(),
                      "region": REGION}, "seeds": seeds, "frames": int(frames), "rows": rows, "pivots": records}


def _cells(s):
    """A summary's cells: RMS, in region, within 3 sigma, mean chi2, along the ray (t)."""
    if not s.get("count"):
        return ["-"] * 5
    return [f"{s['rms_mm']:.3f}", f"{s['in_region']} of {s['count']} ({100 * s['in_region_share']:.0f} %)",
            f"{100 * s['within_3_sigma_share']:.1f} %", f"{s['mean_chi2']:.2f}",
            f"{s['along_ray_mm']:+.3f} (t {s['along_ray_t']:+.1f})"]


def format_table(table) -> str:
    """`pivot_table`'s rows as a Markdown table: per multiple the fused point and both eyes'."""
    head = ("| edges' sd / stated | estimate | RMS [mm] | in 68 % region | within 3 sigma | mean chi2 (3) "
            "| mean error along the ray [mm] | worse than both eyes | than the better eye | k (median) |")
    lines = [f"seeds {table['seeds'][0]}-{table['seeds'][-1]} ({len(table['seeds'])} pivots of "
             f"{table['frames']} frames)", "", head, "|" + "---|" * 10]
    for row in table["rows"]:
        s = row.get("stereo")
        if s is not None:
            extra = ([f"{100 * s['worse_than_both_share']:.1f} %", f"{100 * s['worse_than_better_share']:.1f} %",
                      f"{s['noise_factor_median']:.2f}"] if "worse_than_both_share" in s else ["-"] * 3)
            lines.append("| " + " | ".join([f"x{row['noise']:g}", "both eyes fused", *_cells(s), *extra]) + " |")
        e = row["eyes"]
        play = f"play sd {e['play_sigma_median_mm']:.2f} mm" if e.get("count") else "-"
        lines.append("| " + " | ".join([f"x{row['noise']:g}", "one eye (left and right)", *_cells(e), "", "", play])
                     + " |")
    return "\n".join(lines)


def main(argv=None):
    """The table of `pivot_table` on the command line (module docstring)."""
    import argparse
    import sys

    from pencilcal.toolkit.io.files import write_json

    ap = argparse.ArgumentParser(prog="python -m pencilcal.validation.fulcrum_pivots",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=seed_list, default="1040:1080",
                    help="A:B (seeds A to B-1) or a,b,c [default 1040:1080]")
    ap.add_argument("--noise", default="1,2,3", help="the edges' sd as multiples of the stated, comma-separated")
    ap.add_argument("--frames", type=int, default=50, help="frames per pivot [default 50]")
    ap.add_argument("--eyes-only", action="store_true", help="one eye's points only (no fused point: faster)")
    ap.add_argument("-o", "--output", help="also write the table and every pivot's figures as JSON here")
    ap.add_argument("-q", "--quiet", action="store_true", help="no line per pivot on stderr")
    a = ap.parse_args(argv)
    table = pivot_table(a.seeds, tuple(float(v) for v in a.noise.split(",")), a.frames,
                        stereo=not a.eyes_only, log=None if a.quiet else (lambda m: print(m, file=sys.stderr, flush=True)))
    if a.output:
        write_json(a.output, table, force=True)
    print(format_table(table))


if __name__ == "__main__":
    main()

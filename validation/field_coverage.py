"""The intrinsics' sigmas against the truth on simulated views with a corner error fixed in the image.

Each run: 24 views of a 12 x 9 chessboard of 4.77 mm (tilted up to 50 deg, bent by 0.05 mm)
through a 960x540 endoscope-like lens (opencv 5), white corner noise of 0.25 px plus, by
``kind``, one smooth error field over the image that every view sees (``"field"``: random
Fourier features of a squared exponential of ``sigma_px`` per axis at ``length_px``), each view
a field of its own of the same size (``"own"``), or nothing (``"white"``). Each seed draws its
own view geometry and errors (``numpy.random.default_rng([seed, 9, 1])``) and is calibrated as
`pencilcal calibrate` does (warp and corner-noise model, no outlier rejection). Per run: the
nine intrinsics' errors against the truth in their sigmas (z) with the calibration's
covariance and with the image-fixed field's term held out (the per-view model alone), whether
the field was kept, its score, sigma and length (`toolkit.board.image_field`).

`summary` gives per kind and size the share of runs that keep the field, the mean z^2 (1 where
the sigmas are right) and the share of z within 1 / 2 / 3 (normal: 68 / 95 / 99.7 %), with the
field's term as kept and without it; docs/calibration.md's coverage tables are this runner's:

    python -m pencilcal.validation.field_coverage --seeds 1480:1520 --kind field --sigma 0.12 --length 100

Example
-------
>>> r = run(1300, "white")
>>> r["kept"], len(r["z"])
(False, 9)
"""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

from pencilcal.toolkit.board.bundle import covariance
from pencilcal.toolkit.board.calibrate import calibrate
from pencilcal.toolkit.board.detect import BoardDetection
from pencilcal.toolkit.board.spec import board_from_dict
from pencilcal.toolkit.board.synthetic import synthetic_detections
from pencilcal.toolkit.camera.model import Camera
from pencilcal.validation.calibration_checks import used_views
from pencilcal.validation.metrics import seed_list

__all__ = ["BOARD", "LENS", "KINDS", "smooth_field", "simulated_views", "run", "summary", "format_summary", "main"]

BOARD = board_from_dict({"type": "chessboard", "squares": [12, 9], "square": 4.77})
LENS = Camera("opencv", 960, 540, [[560.0, 0, 482.0], [0, 560.0, 268.0], [0, 0, 1]],
              [-0.32, 0.12, 0.0005, -0.0003, -0.02])
KINDS = ("field", "own", "white")
# the simulation: views, their tilt [deg], the board's warp (mm), the white corner noise [px],
# the random Fourier features of a field
VIEWS = 24
TILT_DEG = 50.0
WARP = (0.0, 0.05)
WHITE_PX = 0.25
FEATURES = 300


def smooth_field(rng, sigma_px, length_px):
    """A smooth error field over the image: a function of points (N, 2) [px] giving their
    errors (N, 2) [px], ``sigma_px`` per axis, a squared-exponential kernel of ``length_px``
    (random Fourier features)."""
    W = rng.normal(size=(FEATURES, 2)) / float(length_px)
    b = rng.uniform(0, 2 * np.pi, FEATURES)
    a = rng.normal(size=(FEATURES, 2)) * float(sigma_px) * math.sqrt(2.0 / FEATURES)
    return lambda u: np.cos(u @ W.T + b) @ a


def simulated_views(seed, kind="field", sigma_px=0.2, length_px=100.0):
    """The detections (list of `BoardDetection`) of one run (module docstring)."""
    if kind not in KINDS:
        raise ValueError(f"field_coverage: kind {kind!r} is not one of {', '.join(KINDS)}")
    dets = synthetic_detections(LENS, BOARD, views=VIEWS, noise_px=0.0, seed=seed, tilt_deg=TILT_DEG, warp=WARP)
    rng = np.random.default_rng([seed, 9, 1])
    clean = [np.asarray(d.corners, float).reshape(-1, 2) for d in dets]
    if kind == "field":
        fields = [smooth_field(rng, sigma_px, length_px)] * len(clean)
    elif kind == "own":
        fields = [smooth_field(rng, sigma_px, length_px) for _ in clean]
    else:
        fields = [np.zeros_like] * len(clean)
    return [BoardDetection(d.ids, c + f(c) + rng.normal(0, WHITE_PX, c.shape), d.image_size, d.marker_ids,
                           d.marker_corners, False) for d, c, f in zip(dets, clean, fields)]


def run(seed, kind="field", sigma_px=0.2, length_px=100.0):
    """One run (module docstring): a dict of the seed, kind, size, the intrinsics' z (9,) with
    the calibration's covariance (``z``) and without the field's term (``z_without``), and the
    field (``kept``, ``score``, ``sigma_px``, ``length_px``)."""
    dets = simulated_views(seed, kind, sigma_px, length_px)
    res = calibrate(dets, BOARD, LENS.size, warp=True, corner_noise=True, outlier_view_sigma=0,
                    outlier_corner_sigma=0)
    truth = np.r_[LENS.fx, LENS.fy, LENS.cx, LENS.cy, LENS.dist]
    err = np.r_[res.camera.fx, res.camera.fy, res.camera.cx, res.camera.cy, res.camera.dist] - truth
    C = np.asarray(res.cov_intrinsics.cov, float)
    fd = res.image_field
    C0 = C
    if fd is not None and fd.kept:
        _, objs, imgs, bases = used_views(res, dets, BOARD)
        C0 = covariance(res.layout, res.solution, objs, imgs, bases, res.corner_noise, res.weights).intrinsics
    return {"seed": int(seed), "kind": kind, "sigma_px": float(sigma_px) if kind != "white" else 0.0,
            "length_px": float(length_px), "z": (err / np.sqrt(np.diag(C))).tolist(),
            "z_without": (err / np.sqrt(np.diag(C0))).tolist(),
            "kept": bool(fd is not None and fd.kept), "score": 0.0 if fd is None else float(fd.score),
            "field_sigma_px": 0.0 if fd is None else math.sqrt(fd.variance_px2),
            "field_length_px": 0.0 if fd is None else float(fd.length_px)}


def summary(rows):
    """Per (kind, sigma, length): runs, share kept, mean z^2 and the share within 1 / 2 / 3
    sigma, with the field's term as kept and without it."""
    groups = {}
    for r in rows:
        groups.setdefault((r["kind"], r["sigma_px"], r["length_px"]), []).append(r)
    out = []
    for key, rs in sorted(groups.items()):
        rec = {"kind": key[0], "sigma_px": key[1], "length_px": key[2], "runs": len(rs),
               "kept": float(np.mean([r["kept"] for r in rs]))}
        for name in ("z", "z_without"):
            a = np.abs(np.array([r[name] for r in rs]))
            rec[name] = {"mean_z2": float(np.mean(a ** 2)), "within": [float(np.mean(a < k)) for k in (1, 2, 3)]}
        out.append(rec)
    return out


def format_summary(table):
    """`summary` as text lines."""
    lines = ["kind   sigma  length  runs  kept   mean z^2 (without)  within 1/2/3 sigma (without)"]
    for r in table:
        w, o = r["z"]["within"], r["z_without"]["within"]
        lines.append(f"{r['kind']:6s} {r['sigma_px']:5.2f} {r['length_px']:6.0f} {r['runs']:5d} {r['kept'] * 100:4.0f}%"
                     f"   {r['z']['mean_z2']:5.2f} ({r['z_without']['mean_z2']:5.2f})"
                     f"      {w[0] * 100:3.0f}/{w[1] * 100:3.0f}/{w[2] * 100:3.0f}% "
                     f"({o[0] * 100:3.0f}/{o[1] * 100:3.0f}/{o[2] * 100:3.0f}%)")
    return "\n".join(lines)


def main(argv=None):
    """Run the seeds and tabulate (module docstring)."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m pencilcal.validation.field_coverage",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=seed_list, default="1400:1402", help="A:B (seeds A to B-1) or a,b,c")
    ap.add_argument("--kind", default="field", choices=KINDS,
                    help="field: one field every view sees; own: each view its own; white: none")
    ap.add_argument("--sigma", type=float, default=0.2, help="the field's sigma per axis [px]")
    ap.add_argument("--length", type=float, default=100.0, help="the field's correlation length [px]")
    ap.add_argument("--out", default=None, help="a JSON lines file the runs are appended to")
    a = ap.parse_args(argv)
    rows = []
    for seed in a.seeds:
        rows.append(run(seed, a.kind, a.sigma, a.length))
        print(json.dumps({k: rows[-1][k] for k in ("seed", "kept", "score", "field_sigma_px")}), flush=True)
        if a.out:
            with Path(a.out).open("a") as f:
                f.write(json.dumps(rows[-1]) + "\n")
    print(format_summary(summary(rows)))


if __name__ == "__main__":
    sys.exit(main())

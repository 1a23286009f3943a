"""Rendered stereo pivots, end to end: `pencilcal fulcrum` on the images, against the truth.

`validation.fulcrum_pivots` checks the 3-D fulcrum's estimators on exact edges; this module
checks the whole command line on images like a da Vinci endoscope's: a rectified pair at
640x480 (f = 520 px, the right eye 5 mm along +x), an 8 mm shaft pivoting about a port,
rendered physically (`synth.shaded`: a cylinder lit from the endoscope, diffuse plus
specular, so it darkens towards its silhouette) over a tissue backdrop
(`synth.tissue`, seen by the right eye 17 px further left, as tissue 150 mm away), with a
bright metal wrist beyond the shaft's end, uneven lighting, optical blur, sensor noise and
JPEG compression. The rig the right eye is rendered with is off its calibration by 0.5 mrad
and 0.02 mm sd (`RIG_SD`); the stereo file states the calibration and that covariance.

Per sequence (`draw_sequence(seed)`, everything from ``numpy.random.default_rng(seed)``):
the port 40-120 mm deep, in view (anywhere 40 px inside the image) or out of it
(60-400 px beyond an edge), the material one of `synth.shaded.MATERIALS`; per frame the
instrument 30-100 mm inside the port, its tip seen by both eyes 30 px inside the image, its
axis passing the port at the play (an offset across the axis, `PLAY_SD_MM` per direction),
its visible image at least 80 px long in both eyes. `write_sequence` writes what the
command takes: ``left/`` and ``right/`` (``frame_000.jpg`` ...), ``left.yaml`` and
``right.yaml`` (OpenCV camera files), ``stereo.yaml`` (OpenCV FileStorage: ``R``, ``T``
and ``cov_right_from_left``, `write_stereo`) and ``truth.json``.

`run_sequence` runs the three commands a user runs (`pencilcal fulcrum LEFT
--shaft-diameter 8`, the same on the right, and the stereo one with ``--right RIGHT
--camera-right --right-from-left``) in a child process each and tabulates each 3-D point's
error [mm] and its Mahalanobis distance by its own covariance (``sigmas``: sqrt of
e' C^-1 e): ``left`` and ``right`` (fulcrum.json's ``point``, each in its eye's frame),
``axes``, ``combined``, ``triangulated`` (its ``stereo`` record, left frame).

    python -m pencilcal.validation.pivot_renders --seeds 2600:2610 --out DIR [--edge-model limb]

Example
-------
>>> s = draw_sequence(2600, frames=2)
>>> len(s["frames"]), bool(40.0 <= s["fulcrum"][2] <= 120.0)
(2, True)
"""
from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from pencilcal.toolkit.camera.formats import write_camera
from pencilcal.toolkit.camera.stereo import StereoRig, write_stereo
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.frames import rotation_from_rotvec
from pencilcal.toolkit.synth.render import lighting_gain, sensor_image
from pencilcal.toolkit.synth.shaded import MATERIALS, shaft_light, shaft_radiance
from pencilcal.toolkit.synth.tissue import tissue_image
from pencilcal.validation.fulcrum_pivots import pivot_camera
from pencilcal.validation.metrics import seed_list

__all__ = ["RIG_SD", "PLAY_SD_MM", "DIAMETER_MM", "draw_sequence", "eye_pose", "eye_axis", "in_view", "render_pair",
           "write_sequence", "run_sequence", "format_table", "main"]

#: The rig's calibration error: rotation vector sd [rad], translation sd [mm] per axis.
RIG_SD = (0.5e-3, 0.02)
#: The port's play: the axis's offset from the fulcrum across it, sd per direction [mm].
PLAY_SD_MM = 0.35
DIAMETER_MM = 8.0
BASELINE_MM = 5.0
_TISSUE_DEPTH_MM = 150.0  # the backdrop's depth, for its disparity between the eyes
_WRIST = (2.6, 9.0)  # the wrist beyond the shaft: radius, length [mm]
_TIP_MARGIN_PX, _PORT_MARGIN_PX, _MIN_SEEN_PX = 30.0, 40.0, 80.0


def in_view(X, p, size, margin):
    """Which points X (N, 3) [mm, an eye's frame] with pixels p (N, 2) that eye sees: in front
    of it (over 5 mm deep) and at least margin [px] inside the image of size (W, H)."""
    return (X[:, 2] > 5) & (p[:, 0] >= margin) & (p[:, 0] <= size[0] - 1 - margin) & (p[:, 1] >= margin) & \
        (p[:, 1] <= size[1] - 1 - margin)


def _seen_length(cam, size, A, B, steps=200):
    """The image length [px] of the stretch A-B (3,) [mm] that lies in the image."""
    X = A + np.linspace(0, 1, steps)[:, None] * (B - A)
    p = cam.project(X)
    ok = in_view(X, p, size, 2.0)
    if ok.sum() < 2:
        return 0.0
    q = p[ok]
    return float(np.linalg.norm(q[-1] - q[0]))


def _port(rng, K, size):
    """The fulcrum (3,) [mm, left frame]: 40-120 mm deep, in view or 60-400 px beyond an edge."""
    w, h = size
    z = rng.uniform(40.0, 120.0)
    if rng.uniform() < 0.5:
        u, v = rng.uniform(_PORT_MARGIN_PX, w - _PORT_MARGIN_PX), rng.uniform(_PORT_MARGIN_PX, h - _PORT_MARGIN_PX)
    else:
        side, beyond = rng.integers(4), rng.uniform(60.0, 400.0)
        u, v = rng.uniform(0, w), rng.uniform(0, h)
        u, v = [(-beyond, v), (w + beyond, v), (u, -beyond), (u, h + beyond)][side]
    return z * np.linalg.solve(K, [u, v, 1.0])


def draw_sequence(seed, frames=50):
    """One pivot sequence's scene (module docstring): a dict with ``seed``, ``fulcrum`` (3,)
    [mm, left frame], ``R_right_from_left``, ``t_right_from_left`` (the true rig), the
    calibrated ``R_cal``, ``t_cal`` and ``cov_cal`` (6, 6), ``material``, ``sensor`` (blur,
    noise, JPEG quality, lighting) and ``frames``: per frame the axis point A (3,) (the port
    plus its play), unit d (3,) from the port to the tip, the insertion L [mm]."""
    rng = np.random.default_rng(seed)
    cam = pivot_camera()
    K, size = cam.K, (cam.width, cam.height)
    R = rotation_from_rotvec(rng.normal(0.0, RIG_SD[0], 3))
    t = np.array([-BASELINE_MM, 0.0, 0.0]) + rng.normal(0.0, RIG_SD[1], 3)
    F = _port(rng, K, size)
    out = []
    for _ in range(100000):
        if len(out) == frames:
            break
        L = rng.uniform(30.0, 100.0)
        r = np.linalg.solve(K, [rng.uniform(0, size[0]), rng.uniform(0, size[1]), 1.0])
        # the tip on this pixel's ray, L from the port: |s r - F| = L
        a, b, c = r @ r, -2 * r @ F, F @ F - L * L
        disc = b * b - 4 * a * c
        if disc <= 0:
            continue
        s = (-b + rng.choice([-1.0, 1.0]) * np.sqrt(disc)) / (2 * a)
        tip = s * r
        if tip[2] < 20.0:
            continue
        d = (tip - F) / L
        off = rng.normal(0.0, PLAY_SD_MM, 3)
        A = F + off - (off @ d) * d
        tip = A + L * d
        ok = True
        for eye in (0, 1):
            Re, te = eye_pose({"R_right_from_left": R, "t_right_from_left": t}, eye)
            Ae, tipe = Re @ A + te, Re @ tip + te
            if tipe[2] < 20.0 or not in_view(tipe[None], cam.project(tipe)[None], size, _TIP_MARGIN_PX)[0] or \
                    _seen_length(cam, size, Ae, tipe) < _MIN_SEEN_PX:
                ok = False
        if ok:
            out.append({"A": A, "d": d, "L": L})
    sensor = {"blur_px": rng.uniform(0.8, 1.5), "noise": rng.uniform(1.5, 3.0), "jpeg": int(rng.integers(80, 96)),
              "lighting": rng.uniform(0.1, 0.4), "tissue_gain": rng.uniform(0.5, 1.0)}
    return {"seed": int(seed), "fulcrum": F, "R_right_from_left": R, "t_right_from_left": t,
            "R_cal": np.eye(3), "t_cal": np.array([-BASELINE_MM, 0.0, 0.0]),
            "cov_cal": np.diag([RIG_SD[0] ** 2] * 3 + [RIG_SD[1] ** 2] * 3),
            "material": list(MATERIALS)[int(rng.integers(len(MATERIALS)))], "sensor": sensor, "frames": out}


def eye_pose(scene, eye):
    """(R (3, 3), t (3,)) of eye 0 (left: the identity) or 1 (right: the true rig,
    ``R_right_from_left``, ``t_right_from_left``) from the scene's left frame (`draw_sequence`)."""
    return (np.eye(3), np.zeros(3)) if eye == 0 else (scene["R_right_from_left"], scene["t_right_from_left"])


def eye_axis(scene, i, eye):
    """Frame i's axis in one eye's frame (`eye_pose`): its point A (3,) [mm] (the port plus its
    play) and unit direction d (3,) from the port to the tip."""
    R, t = eye_pose(scene, eye)
    f = scene["frames"][i]
    return R @ f["A"] + t, R @ f["d"]


def _over(img, light, colour):
    """img (H, W, 3) linear with one shaft's (radiance, cover) laid over it."""
    rad, cover = light
    return img * (1.0 - cover)[..., None] + rad[..., None] * np.asarray(colour, float)


def _exposure(material, level):
    """The factor on a shaft's radiance that puts its face (incidence cosine 0.8) 60 mm away
    at the linear level: one exposure for the sequence, the light's fall-off with distance
    and the specular highlights (which may clip) kept."""
    return level / float(shaft_radiance(0.8, 60.0, material))


def render_pair(scene, i, rng):
    """Frame i of the scene (`draw_sequence`) as both eyes' encoded JPEG bytes (left, right)."""
    import cv2

    cam = pivot_camera()
    W, H = cam.width, cam.height
    sen = scene["sensor"]
    disp = int(round(cam.K[0, 0] * BASELINE_MM / _TISSUE_DEPTH_MM))
    backdrop = tissue_image((H, W + disp), seed=scene["seed"]) * sen["tissue_gain"]
    gain = lighting_gain(W, H, sen["lighting"], np.random.default_rng([scene["seed"], 7]))
    f = scene["frames"][i]
    mat, wrist = MATERIALS[scene["material"]], MATERIALS["bright_metal"]
    out = []
    for eye in (0, 1):
        A, d = eye_axis(scene, i, eye)
        # the right eye sees the far backdrop `disp` px further left
        img = np.array(backdrop[:, disp:] if eye == 0 else backdrop[:, :W])
        img = img * gain[..., None]
        try:
            rad, cover = shaft_light(cam, A, d, _WRIST[0], wrist, extent=(f["L"], f["L"] + _WRIST[1]))[:2]
            img = _over(img, (rad * _exposure(wrist, 0.5), cover), wrist.colour)
        except InputError:
            pass
        rad, cover = shaft_light(cam, A, d, 0.5 * DIAMETER_MM, mat, extent=(0.0, f["L"]))[:2]
        img = _over(img, (rad * _exposure(mat, 0.3), cover), mat.colour)
        enc = sensor_image(img, 0.0, 1.0, sen["blur_px"], 2.2, sen["noise"], rng)
        ok, buf = cv2.imencode(".jpg", enc, [cv2.IMWRITE_JPEG_QUALITY, sen["jpeg"]])
        out.append(buf.tobytes())
    return tuple(out)


def write_sequence(scene, out):
    """Write the scene's images and files under the folder out (module docstring); returns out."""
    out = Path(out)
    for eye in ("left", "right"):
        (out / eye).mkdir(parents=True, exist_ok=True)
        write_camera(out / f"{eye}.yaml", pivot_camera(), force=True)
    rng = np.random.default_rng([scene["seed"], 1])
    for i in range(len(scene["frames"])):
        for eye, data in zip(("left", "right"), render_pair(scene, i, rng)):
            (out / eye / f"frame_{i:03d}.jpg").write_bytes(data)
    write_stereo(out / "stereo.yaml", StereoRig(scene["R_cal"], scene["t_cal"], cov=scene["cov_cal"]), force=True)
    R, t, F = scene["R_right_from_left"], scene["t_right_from_left"], scene["fulcrum"]
    truth = {"seed": scene["seed"], "fulcrum_left_mm": F.tolist(), "fulcrum_right_mm": (R @ F + t).tolist(),
             "R_right_from_left": R.tolist(), "t_right_from_left": t.tolist(), "material": scene["material"],
             "sensor": scene["sensor"], "fulcrum_px": pivot_camera().project(F).tolist()}
    (out / "truth.json").write_text(json.dumps(truth, indent=1))
    return out


def _figure(rec, truth):
    """{error_mm, sigmas, sigma_mm, error (3,)} of a record's point against truth (3,)."""
    if not rec or "point" not in rec:
        return None
    e = np.asarray(rec["point"], float) - truth
    C = np.asarray(rec["point_cov"], float)
    return {"error_mm": float(np.linalg.norm(e)), "sigmas": float(np.sqrt(e @ np.linalg.solve(C, e))),
            "sigma_mm": float(np.sqrt(np.trace(C))), "error": e.tolist()}


def run_sequence(folder, edge_model="step", log=None):
    """The three commands on a written sequence (module docstring); {name: figure or None}
    and each command's seconds; fulcrum.json files land in the folder."""
    folder = Path(folder)
    truth = json.loads((folder / "truth.json").read_text())
    Fl, Fr = np.asarray(truth["fulcrum_left_mm"]), np.asarray(truth["fulcrum_right_mm"])
    cmd = [sys.executable, "-c", "from pencilcal.cli.entry import main; main()", "fulcrum"]
    opts = ["--shaft-diameter", str(DIAMETER_MM), "--edge-model", edge_model, "-q", "--force"]
    runs = {"left": [folder / "left", "--camera", folder / "left.yaml"],
            "right": [folder / "right", "--camera", folder / "right.yaml"],
            "stereo": [folder / "left", "--camera", folder / "left.yaml", "--right", folder / "right",
                       "--camera-right", folder / "right.yaml", "--right-from-left", folder / "stereo.yaml"]}
    res = {"seed": truth["seed"], "seconds": {}}
    for name, args in runs.items():
        path = folder / f"fulcrum_{name}_{edge_model}.json"
        t0 = time.time()
        p = subprocess.run([*cmd, *map(str, args), *opts, "-o", str(path)], capture_output=True, text=True)
        res["seconds"][name] = round(time.time() - t0, 1)
        if p.returncode != 0:
            res[name] = None
            res.setdefault("errors", {})[name] = (p.stdout + p.stderr).strip()[-300:]
            continue
        rec = json.loads(path.read_text())
        if name == "stereo":
            st = rec.get("stereo", {})
            for key in ("axes", "combined", "triangulated"):
                res[key] = _figure(st.get(key), Fl)
            res["left_in_stereo"] = _figure(rec, Fl)
        else:
            res[name] = _figure(rec, Fl if name == "left" else Fr)
            res[name + "_frames_used"] = rec.get("frames_used")
        if log:
            log(f"seed {truth['seed']} {name}: {res['seconds'][name]} s")
    return res


_KEYS = ("left", "right", "axes", "combined", "triangulated")


def format_table(rows):
    """One line per sequence: each point's error [mm] / its sigmas."""
    head = "seed  " + "  ".join(f"{k:>16s}" for k in _KEYS)
    lines = [head]
    for r in rows:
        cells = [f"{r[k]['error_mm']:7.2f}/{r[k]['sigmas']:6.2f}s" if r.get(k) else f"{'-':>16s}" for k in _KEYS]
        lines.append(f"{r['seed']:<5d} " + "  ".join(cells))
    for stat in ("rms mm", "max sigmas", "pass"):
        cells = []
        for k in _KEYS:
            got = [r[k] for r in rows if r.get(k)]
            lim = 5.0 if k in ("left", "right") else 4.0
            if not got:
                cells.append(f"{'-':>16s}")
            elif stat == "rms mm":
                cells.append(f"{np.sqrt(np.mean([g['error_mm'] ** 2 for g in got])):16.2f}")
            elif stat == "max sigmas":
                cells.append(f"{max(g['sigmas'] for g in got):16.2f}")
            else:
                n = sum(g["error_mm"] <= lim and g["sigmas"] <= 3.0 for g in got)
                cells.append(f"{n:>13d}/{len(rows):<2d}")
        lines.append(f"{stat:<5s} " + "  ".join(cells))
    return "\n".join(lines)


def main(argv=None):
    """Write, run and tabulate seeded sequences (module docstring)."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m pencilcal.validation.pivot_renders",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=seed_list, default="2600:2610", help="A:B (seeds A to B-1) or a,b,c")
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--out", required=True, help="folder for the sequences and results")
    ap.add_argument("--edge-model", default="step", choices=("step", "limb"))
    a = ap.parse_args(argv)
    rows = []
    out = Path(a.out)
    for seed in a.seeds:
        folder = out / f"seq{seed}"
        if not (folder / "truth.json").exists():
            write_sequence(draw_sequence(seed, a.frames), folder)
        r = run_sequence(folder, a.edge_model, log=lambda m: print(m, file=sys.stderr, flush=True))
        rows.append(r)
        (out / f"results_{a.edge_model}.json").write_text(json.dumps(rows, indent=1))
        print(format_table([r]).splitlines()[1], flush=True)
    print(format_table(rows))


if __name__ == "__main__":
    main()

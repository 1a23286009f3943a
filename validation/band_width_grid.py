"""The shaft bands' width error on shaded renders, per edge model and band class.

A shaft's band width fixes one eye's 3-D fulcrum depth (the shaft's diameter is known), and
where a shaded shaft's silhouette is found depends on its material, its light and the
background beside it: error one sequence shares. This grid measures it with the detector a
user runs (`detect.shaft.detector.detect_shafts`, each edge model) on single 8 mm shafts
rendered physically (`synth.shaded`: lit from the camera, diffuse plus specular, darkening
towards the silhouette): every material of `synth.shaded.MATERIALS` over a bright and a dark
flat background and a tissue backdrop (`synth.tissue`), at each distance (20-150 mm). Per
render (``numpy.random.default_rng([seed, k])``) the axis's direction and place, the shaft's
exposure (light level 0.15-0.5, linear), a lighting ramp across the image (0-30 %), the
background's level, optical blur (0.7-1.5 px) and sensor noise (1-3 grey levels) are drawn.

``realism="endoscope"`` renders each frame as `validation.pivot_renders` renders an
endoscope's (what a user's frames look like): the shaft's light falls off with its distance
(one exposure puts its face 60 mm away at a linear level of 0.15-0.5; nearer shafts may clip),
it ends 10-40 mm beyond the axis point with a bright metal wrist (2.6 mm radius, 9 mm long)
beyond it, the lighting is uneven (`render.lighting_gain`, 0.1-0.4), the sensor noise is
1.5-3 grey levels and each frame is JPEG-compressed (quality 80-95). The default
(``"plain"``) is the grid as the class sds were first measured on (`defaults.EDGE_WIDTH_SD_PX`).
``realism="side"`` lights the shaft as `pencilcal demo`'s instrument is lit: by a lamp
beside the camera (offset sideways by 0.15-0.5 of the viewing direction), with an ambient
floor and a Phong highlight (`_side_lit_frame`), so one limb is lit and the other falls
dark before the silhouette, and a dark shaft over a bright background brightens inwards.
``--backgrounds green`` (not in the default grid) puts the shaft over a green screen whose
green channel clips over part of the frame, as a box trainer's chroma-key drape does.

Each band is classed as the detector measures it: its ``polarity`` (the shaft darker or
brighter than its surround) and its width in pixels (`band_class`); the width error is the
detected band width minus the true silhouette's width at the band's centre [px], and
relative to it. `summary` gives the RMS per edge model and class, the sd a band of each
class is given in the 3-D fulcrum's covariance (`pencil.band_width.band_width_sd`) and the
share of bands whose error lies within 1, 2 and 3 of those sds (a normal error: 68, 95,
99.7 %).

    python -m pencilcal.validation.band_width_grid --seeds 1:3 [--realism endoscope] [--out rows.json]

Example
-------
>>> r = render_band(1, 0, "matte", "bright", 80.0, edge_models=("limb",))
>>> r["material"], r["background"], r["z_mm"]
('matte', 'bright', 80.0)
>>> bool(abs(r["limb"]["error_rel"]) < 0.01)
True
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.detect.shaft.detector import EDGE_MODELS, detect_shafts
from pencilcal.toolkit.pencil.band_width import band_class, band_width_sd
from pencilcal.toolkit.synth.render import sensor_image
from pencilcal.toolkit.synth.shaded import MATERIALS, ShadedTruth, render_shaded_shaft, shaft_light, shaft_radiance
from pencilcal.toolkit.synth.tissue import tissue_image
from pencilcal.validation.metrics import seed_list

__all__ = ["BACKGROUNDS", "OTHER_BACKGROUNDS", "DISTANCES_MM", "REALISMS", "GROSS_REL", "RADIUS_MM", "grid_camera", "render_band", "run_grid", "summary",
           "format_summary", "main"]

#: The backgrounds: flat bright (a grey-blue drape), flat dark (an unlit cavity) and tissue.
BACKGROUNDS = ("bright", "dark", "tissue")
#: Backgrounds rendered on request only (``--backgrounds green``): a green screen (a box
#: trainer's chroma-key drape) whose green channel clips over part of the frame.
OTHER_BACKGROUNDS = ("green",)
DISTANCES_MM = (20.0, 40.0, 80.0, 120.0, 150.0)
RADIUS_MM = 4.0
#: How a frame is rendered (module docstring): "plain", "endoscope" or "side".
REALISMS = ("plain", "endoscope", "side")
_WRIST = (2.6, 9.0)  # the wrist beyond the shaft's end: radius, length [mm] (as `pivot_renders`)


def grid_camera():
    """The renders' pinhole camera: 640x480, f = 520 px (an endoscope's)."""
    return Camera("pinhole", 640, 480, [[520.0, 0, 319.5], [0, 520.0, 239.5], [0, 0, 1]])


def _background(name, rng, shape):
    """The linear background (3,) or (H, W, 3) of a BACKGROUNDS name."""
    if name == "bright":
        return np.array([0.5, 0.55, 0.6]) * rng.uniform(0.7, 1.2)
    if name == "dark":
        return np.array([0.10, 0.12, 0.22]) * rng.uniform(0.5, 1.5)
    if name == "tissue":
        return tissue_image(shape, seed=int(rng.integers(1 << 30))) * rng.uniform(0.4, 1.0)
    if name == "green":
        # green at 0.81-0.99 linear: with the lighting ramp (up to +-15 %) it clips over part of the frame
        return np.array([0.3, 0.9, 0.45]) * rng.uniform(0.9, 1.1)
    raise ValueError(f"background must be one of {', '.join(BACKGROUNDS + OTHER_BACKGROUNDS)}, got {name!r}")


def _endoscope_frame(cam, A, d, material, background, rng):
    """One endoscope-like frame (module docstring, ``realism="endoscope"``): (H, W, 3) uint8
    BGR decoded from its JPEG, and the shaft's `ShadedTruth`."""
    import cv2

    mat, wrist = MATERIALS[material], MATERIALS["bright_metal"]
    bg = np.asarray(_background(background, rng, (cam.height, cam.width)), float)
    img = np.array(np.broadcast_to(bg, (cam.height, cam.width, 3)))
    end = rng.uniform(10.0, 40.0)
    level = rng.uniform(0.15, 0.5)
    outline = None
    # (a bright metal shaft's wrist is its own material: the part, not the material, says which)
    for part, m, radius, extent, lev in (("wrist", wrist, _WRIST[0], (end, end + _WRIST[1]), 0.5),
                                         ("shaft", mat, RADIUS_MM, (-1e4, end), level)):
        try:
            rad, cover, _, _, seen = shaft_light(cam, A, d, radius, m, extent=extent)
        except InputError:
            if part == "shaft":
                raise
            continue  # the wrist out of view
        if part == "shaft":
            outline = seen
        # one exposure for the sequence: the face 60 mm away at the level, fall-off kept
        rad = rad * (lev / float(shaft_radiance(0.8, 60.0, m)))
        img = img * (1.0 - cover)[..., None] + rad[..., None] * np.asarray(m.colour, float)
    enc = sensor_image(img, rng.uniform(0.1, 0.4), 1.0, rng.uniform(0.7, 1.5), 2.2, rng.uniform(1.5, 3.0), rng)
    ok, buf = cv2.imencode(".jpg", enc, [cv2.IMWRITE_JPEG_QUALITY, int(rng.integers(80, 96))])
    truth = ShadedTruth(outline.lines, outline.normals, np.asarray(A, float), np.asarray(d, float) / np.linalg.norm(d),
                        RADIUS_MM, np.asarray(cam.K, float))
    return cv2.imdecode(buf, cv2.IMREAD_COLOR), truth


def _side_lit_frame(cam, A, d, material, background, rng):
    """One frame of a shaft lit by a lamp beside the camera (module docstring,
    ``realism="side"``): (H, W, 3) uint8 BGR and the shaft's `ShadedTruth`. The outline's
    pixel coverage is exact (`synth.shaded.shaft_light`); each covered pixel is shaded at its
    centre's ray (where that misses, at the ray's closest approach: the limb) as `pencilcal
    demo`'s instrument is: ``albedo (ambient + max(0, n . l)) + f0 (p + 2) / (2 pi) max(0,
    r . v)^p`` (Phong, p from the material's roughness), l the unit direction to a lamp
    offset from the camera's by 0.15-0.5 sideways in a random direction, an ambient of
    0.03-0.25."""
    mat = MATERIALS[material]
    _, cover, _, full, outline = shaft_light(cam, A, d, RADIUS_MM, mat)
    iy, ix = np.nonzero(cover > 0)
    v = np.asarray(cam.rays_from_pixels(np.stack([ix, iy], -1).astype(float)), float)
    v = v / np.linalg.norm(v, axis=-1, keepdims=True)
    # the ray's first hit of the cylinder (or its closest approach to the axis)
    A, d = np.asarray(A, float), np.asarray(d, float) / np.linalg.norm(d)
    w = v - (v @ d)[:, None] * d
    a0 = (A @ d) * d - A
    qa, qb, qc = np.sum(w * w, -1), 2.0 * (w @ a0), a0 @ a0 - RADIUS_MM ** 2
    disc = qb * qb - 4 * qa * qc
    z = (-qb - np.sqrt(np.maximum(disc, 0.0))) / (2 * qa)
    X = z[:, None] * v
    n = X - A - ((X - A) @ d)[:, None] * d
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    turn = rng.uniform(0, 2 * np.pi)
    lamp = rng.uniform(0.15, 0.5) * np.array([np.cos(turn), np.sin(turn), 0.0])
    light = lamp - v
    light = light / np.linalg.norm(light, axis=-1, keepdims=True)
    ndl = np.clip(np.sum(n * light, -1), 0.0, None)
    refl = 2.0 * ndl[:, None] * n - light
    p = max(2.0 / mat.roughness ** 2 - 2.0, 1.0)
    spec = (p + 2) / (2 * np.pi) * np.clip(-np.sum(refl * v, -1), 0.0, None) ** p
    lum = mat.albedo * (rng.uniform(0.03, 0.25) + ndl) + mat.f0 * spec
    rad = np.zeros(cover.shape)
    rad[iy, ix] = lum
    rad *= rng.uniform(0.15, 0.5) / max(float(np.median(rad[full])), 1e-300)
    bg = np.asarray(_background(background, rng, (cam.height, cam.width)), float)
    if bg.ndim == 1:
        bg = bg * (1.0 + rng.uniform(0.0, 0.3) * (np.arange(cam.width) / (cam.width - 1) - 0.5))[None, :, None]
    img = bg * (1.0 - cover)[..., None] + (cover * rad)[..., None] * np.asarray(mat.colour, float)
    enc = sensor_image(img, 0.0, 1.0, rng.uniform(0.7, 1.5), 2.2, rng.uniform(1.0, 3.0), rng)
    truth = ShadedTruth(outline.lines, outline.normals, A, d, RADIUS_MM, np.asarray(cam.K, float))
    return enc, truth


def render_band(seed, k, material, background, z_mm, edge_models=EDGE_MODELS, realism="plain"):
    """One render's bands: {seed, k, material, background, z_mm, realism, and per edge model
    in edge_models a dict (polarity, width_px, error_px, error_rel, true_width_px, class,
    sd_px) or None where the detector found no band on the shaft}; k: the render's index
    within the seed (its random settings come from default_rng([seed, k])); realism: one of
    `REALISMS` (module docstring)."""
    if realism not in REALISMS:
        raise ValueError(f"realism must be one of {', '.join(REALISMS)}, got {realism!r}")
    cam = grid_camera()
    rng = np.random.default_rng([int(seed), int(k)])
    ang = rng.uniform(0, np.pi)
    d = np.array([np.cos(ang), np.sin(ang), rng.uniform(0.2, 0.6)])
    A = [rng.uniform(-3, 3) * z_mm / 40.0, rng.uniform(-3, 3) * z_mm / 40.0, float(z_mm)]
    if realism == "endoscope":
        img, truth = _endoscope_frame(cam, A, d, material, background, rng)
    elif realism == "side":
        img, truth = _side_lit_frame(cam, A, d, material, background, rng)
    else:
        img, truth = render_shaded_shaft(cam, A, d, RADIUS_MM, MATERIALS[material],
                                         background=_background(background, rng, (cam.height, cam.width)),
                                         gradient=rng.uniform(0.0, 0.3), shaft_level=rng.uniform(0.15, 0.5),
                                         blur_px=rng.uniform(0.7, 1.5), noise=rng.uniform(1.0, 3.0), rng=rng)
    out = {"seed": int(seed), "k": int(k), "material": material, "background": background, "z_mm": float(z_mm),
           "realism": realism}
    for model in edge_models:
        best = None
        for s in detect_shafts(img, cam, edge_model=model):
            c = 0.5 * (s.ideal_midline[:2] + s.ideal_midline[2:])
            # the shaft's band: its centre within a quarter width of the true outline's middle
            dist = truth.lines[:, :2] @ c + truth.lines[:, 2]
            off = 0.5 * abs(float(dist[0] - dist[1]))
            if off < 0.25 * s.width_px and (best is None or s.score > best[0].score):
                best = (s, c)
        if best is None:
            out[model] = None
            continue
        s, c = best
        true = float(truth.width_at(c))
        rec = {"polarity": s.polarity, "width_px": float(s.width_px), "edge_model": s.edge_model}
        if s.width_sd_px is not None:
            rec["width_sd_px"] = float(s.width_sd_px)  # what the band's own fit shows (`band_width_sd`)
        rec.update(error_px=float(s.width_px - true), error_rel=float(s.width_px / true - 1.0),
                   true_width_px=true, band_class=band_class(rec), sd_px=float(band_width_sd(rec)))
        out[model] = rec
    return out


def run_grid(seeds, materials=tuple(MATERIALS), backgrounds=BACKGROUNDS, distances=DISTANCES_MM,
             edge_models=EDGE_MODELS, log=None, realism="plain"):
    """[`render_band` row] of every seed x material x background x distance."""
    rows = []
    for seed in seeds:
        k = 0
        for mat in materials:
            for bg in backgrounds:
                for z in distances:
                    rows.append(render_band(seed, k, mat, bg, z, edge_models, realism))
                    k += 1
                    if log:
                        log(_row_line(rows[-1], edge_models))
    return rows


def _row_line(r, edge_models):
    cells = []
    for m in edge_models:
        b = r.get(m)
        cells.append(f"{m} -" if b is None else
                     f"{m} {b['band_class']:>12s} {b['width_px']:6.1f}px {b['error_px']:+6.2f}px "
                     f"{100 * b['error_rel']:+6.2f}%")
    return f"{r['seed']} {r['material']:12s} {r['background']:6s} {r['z_mm']:5.0f}  " + "  ".join(cells)


#: A band read further off than this (relative) is a detection failure (the specular stripe
#: taken for the shaft, say), not a limb's shift: counted apart (``gross``), as the class sds
#: were set without them (`defaults.EDGE_WIDTH_SD_PX`).
GROSS_REL = 0.25


def summary(rows, edge_models=EDGE_MODELS):
    """{edge model: {class (and "all"): {n, rms_px, mean_px, rms_rel, sd_px (the RMS of the
    sds the class's bands are given now: `band_width_sd`), within_1, within_2, within_3
    (shares of |error| <= k sd)}; "all" also missed (no band found) and gross (bands more
    than `GROSS_REL` off, left out of the rest)}}."""
    out = {}
    for m in edge_models:
        found = [r[m] for r in rows if r.get(m) is not None]
        got = [b for b in found if abs(b["error_rel"]) <= GROSS_REL]
        per = {}
        for cls in sorted({b["band_class"] for b in got}) + ["all"]:
            sel = [b for b in got if cls == "all" or b["band_class"] == cls]
            e = np.array([b["error_px"] for b in sel])
            rel = np.array([b["error_rel"] for b in sel])
            sd = np.array([band_width_sd(b) for b in sel])
            z = np.abs(e) / sd
            per[cls] = {"n": len(sel), "rms_px": float(np.sqrt(np.mean(e ** 2))), "mean_px": float(e.mean()),
                        "rms_rel": float(np.sqrt(np.mean(rel ** 2))), "sd_px": float(np.sqrt(np.mean(sd ** 2))),
                        **{f"within_{k}": float(np.mean(z <= k)) for k in (1, 2, 3)}}
        per["all"].update(missed=sum(r.get(m) is None for r in rows), gross=len(found) - len(got))
        out[m] = per
    return out


def format_summary(summ):
    """The summary as a table: one line per edge model and class."""
    lines = [f"{'model':6s} {'class':>12s} {'n':>4s} {'rms px':>7s} {'mean px':>8s} {'rms %':>6s} {'sd px':>6s} "
             f"{'<=1sd':>6s} {'<=2sd':>6s} {'<=3sd':>6s}"]
    for m, per in summ.items():
        for cls, s in per.items():
            lines.append(f"{m:6s} {cls:>12s} {s['n']:4d} {s['rms_px']:7.2f} {s['mean_px']:+8.2f} "
                         f"{100 * s['rms_rel']:6.2f} {s['sd_px']:6.2f} {100 * s['within_1']:5.0f}% "
                         f"{100 * s['within_2']:5.0f}% {100 * s['within_3']:5.0f}%")
        lines.append(f"{m:6s} no band found on {per['all']['missed']} render(s); "
                     f"{per['all']['gross']} band(s) more than {100 * GROSS_REL:.0f} % off, left out")
    return "\n".join(lines)


def main(argv=None):
    """Render, detect and tabulate (module docstring)."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m pencilcal.validation.band_width_grid",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=seed_list, default="1:2", help="A:B (seeds A to B-1) or a,b,c")
    ap.add_argument("--materials", default=",".join(MATERIALS))
    ap.add_argument("--backgrounds", default=",".join(BACKGROUNDS),
                    help=f"of {', '.join(BACKGROUNDS + OTHER_BACKGROUNDS)} (green: a green screen that clips)")
    ap.add_argument("--distances", default=",".join(f"{z:g}" for z in DISTANCES_MM), help="mm, comma separated")
    ap.add_argument("--edge-models", default=",".join(EDGE_MODELS))
    ap.add_argument("--realism", default="plain", choices=REALISMS,
                    help="plain: flat light, no JPEG; endoscope: light fall-off, a wrist, uneven light, JPEG; "
                         "side: a lamp beside the camera, an ambient floor, a Phong highlight")
    ap.add_argument("--out", default=None, help="a JSON file for the rows")
    a = ap.parse_args(argv)
    models = tuple(a.edge_models.split(","))
    rows = run_grid(a.seeds, tuple(a.materials.split(",")), tuple(a.backgrounds.split(",")),
                    tuple(float(v) for v in a.distances.split(",")), models, log=lambda m: print(m, flush=True),
                    realism=a.realism)
    if a.out:
        Path(a.out).write_text(json.dumps(rows, indent=1))
    print(format_summary(summary(rows, models)))


if __name__ == "__main__":
    sys.exit(main())

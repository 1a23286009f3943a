"""Renders of close instruments entering the view, with exact truth: the sweep behind the
selection's rules for an instrument's bands (`shaft.distal`, docs/method.md).

Each frame (640 x 480, a tissue backdrop from `synth.tissue`) holds one instrument entering at a
random border, tilted by up to 35 deg: a shaft 80-180 px wide at the border, converging by 2-14
deg under perspective, seen along 1.2-3 of its widths to its collar, shaded darker towards its
limbs, with lengthwise streaks and, for grey and bright metal, a specular streak; beyond the
collar a paler, narrower wrist and two straight jaws opened by up to 25 deg. Every part is
composited with its exact area coverage, then blur (1-2 px), gamma, noise and JPEG 85
(`synth.render.sensor_image`). The truth is the plane bisecting the two silhouettes' planes
(a nominal pinhole of focal length the image width, as the detector's without a camera); a
detection finds it within the masked sources' tolerance for a shaft (1.5 deg, 15 px:
`validation.shaft_score.Tolerance`).

Run: ``python -m tests.toolkit.detect.shaft.close_instruments FIRST LAST [KINDS] [near|shaded]``
prints the found and false detections over seeds [FIRST, LAST) of each kind (dark, grey,
bright); near: the nearer instruments of `NEAR`; shaded: those with shaded, mirroring limbs and
a shadow beside (`SHADED`).
"""
from __future__ import annotations

import sys
import time
from types import SimpleNamespace

import cv2
import numpy as np

from pencilcal.toolkit.detect.shaft.detector import detect_shafts
from pencilcal.toolkit.synth.render import sensor_image
from pencilcal.toolkit.synth.tissue import tissue_image
from pencilcal.validation.shaft_score import score_frame

H, W = 480, 640
K = np.array([[W, 0, (W - 1) / 2], [0, W, (H - 1) / 2], [0, 0, 1.0]])


def line_through(p, d):
    """The line (3,) through p (2,) along d (2,), with a unit normal."""
    n = np.array([-d[1], d[0]]) / np.linalg.norm(d)
    return np.r_[n, -n @ p]


def scene(seed, kind, conv_deg=(2.0, 14.0), seen_widths=(1.2, 3.0), shaded=False):
    """(frame (H, W, 3) uint8 BGR, reference (kind, line, point, width_px as `mask.MaskAxis`),
    parameters) of one close instrument of kind "dark", "grey" or "bright" (module docstring);
    conv_deg, seen_widths: the ranges its convergence [deg] and its length seen to the collar
    [widths at the border] are drawn from (`NEAR`: nearer still). shaded (`SHADED`): each limb
    a strip of 5-12 % of the local width mirroring the tissue at grazing incidence (its colour
    blurred, 0.4-0.9 of its level, over a darker limb), and a shadow beside one silhouette,
    10-35 % of the width wide, the tissue at 0.2-0.5 of its level, its outer side soft: the
    silhouette is where the background begins, not the limb strip's inner side nor the
    shadow's outer one. The same seed draws the same instrument either way."""
    rng = np.random.default_rng(seed)
    back = np.array(tissue_image((H, W), seed=seed), float)
    side = rng.integers(4)
    tilt = np.radians(rng.uniform(-35, 35))
    if side == 0:
        P0, u = np.array([0.0, rng.uniform(140, 340)]), np.array([1.0, 0.0])
    elif side == 1:
        P0, u = np.array([W - 1.0, rng.uniform(140, 340)]), np.array([-1.0, 0.0])
    elif side == 2:
        P0, u = np.array([rng.uniform(180, 460), 0.0]), np.array([0.0, 1.0])
    else:
        P0, u = np.array([rng.uniform(180, 460), H - 1.0]), np.array([0.0, -1.0])
    c, s_ = np.cos(tilt), np.sin(tilt)
    u = np.array([c * u[0] - s_ * u[1], s_ * u[0] + c * u[1]])
    n = np.array([-u[1], u[0]])
    w0 = rng.uniform(80, 180)
    conv = np.radians(rng.uniform(*conv_deg))
    seen = rng.uniform(*seen_widths) * w0
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    along = (xx - P0[0]) * u[0] + (yy - P0[1]) * u[1]
    across = (xx - P0[0]) * n[0] + (yy - P0[1]) * n[1]
    half = 0.5 * w0 - along * np.tan(0.5 * conv)
    cover = np.clip(half - np.abs(across) + 0.5, 0, 1) * np.clip(seen - along + 0.5, 0, 1) * np.clip(along + 40, 0, 1)
    q = np.clip(across / np.maximum(2 * half, 1) + 0.5, 0, 1)
    # lengthwise streaks: a texture constant along the axis
    streak = np.interp(q, np.linspace(0, 1, 40), 1 + 0.18 * rng.standard_normal(40))
    limb = 0.35 + 0.65 * np.sin(np.pi * q) ** 0.6
    if kind == "dark":
        base, spec = np.array([0.07, 0.075, 0.085]) * rng.uniform(0.7, 1.5), 0.0
    elif kind == "grey":
        base, spec = np.array([0.26, 0.27, 0.30]) * rng.uniform(0.8, 1.2), 0.25
    else:  # bright metal
        base, spec = np.array([0.55, 0.57, 0.60]) * rng.uniform(0.8, 1.1), 0.9
    qs = rng.uniform(0.35, 0.7)
    shade = limb * streak + spec * np.exp(-0.5 * ((q - qs) / 0.04) ** 2)
    shaft_rgb = base[None, None, :] * shade[..., None]
    # the wrist: narrower, paler metal; then two jaws
    ww = rng.uniform(0.5, 0.75) * 2 * (0.5 * w0 - seen * np.tan(0.5 * conv))
    wl = rng.uniform(0.4, 0.9) * w0
    wrist = np.clip(0.5 * ww - np.abs(across) + 0.5, 0, 1) * np.clip(along - seen + 0.5, 0, 1) * np.clip(seen + wl - along + 0.5, 0, 1)
    jl = rng.uniform(0.4, 0.8) * w0
    jaw_open = np.radians(rng.uniform(0, 25))
    jaws = np.zeros_like(xx)
    for sgn in (-1, 1):
        d = np.array([np.cos(sgn * jaw_open) * u[0] - np.sin(sgn * jaw_open) * u[1], np.sin(sgn * jaw_open) * u[0] + np.cos(sgn * jaw_open) * u[1]])
        e = P0 + (seen + wl) * u + sgn * 0.2 * ww * n
        a2 = (xx - e[0]) * d[0] + (yy - e[1]) * d[1]
        c2 = (xx - e[0]) * -d[1] + (yy - e[1]) * d[0]
        jaws = np.maximum(jaws, np.clip(0.15 * ww - np.abs(c2) + 0.5, 0, 1) * np.clip(a2 + 0.5, 0, 1) * np.clip(jl - a2 + 0.5, 0, 1))
    metal = np.clip(wrist + jaws, 0, 1) * (1 - cover)
    mcol = np.array([0.45, 0.46, 0.48]) * (0.8 + 0.4 * rng.random())
    if shaded:
        # the limbs mirror the tissue (a blurred copy, dimmed), over the darker limb shading
        fl = rng.uniform(0.05, 0.12)
        mirror = cv2.GaussianBlur(back, (0, 0), 6.0) * rng.uniform(0.4, 0.9)
        strip = np.clip(np.minimum(q, 1 - q) / fl, 0, 1)[..., None]
        shaft_rgb = shaft_rgb * strip + mirror * (1 - strip)
        # a shadow beside one silhouette: the tissue darkened, fading out on its far side
        side_s = rng.choice([-1.0, 1.0])
        ws = rng.uniform(0.1, 0.35) * w0
        beyond = side_s * across - half
        dark = rng.uniform(0.2, 0.5)
        fall = np.clip((ws - beyond) / 4.0 + 0.5, 0, 1) * (beyond > -1) * np.clip(seen - along + 0.5, 0, 1)
        fall = cv2.GaussianBlur(fall, (0, 0), 1.5)
        back = back * (1 - (1 - dark) * fall)[..., None]
    lin = back * (1 - np.clip(cover + metal, 0, 1))[..., None] + shaft_rgb * cover[..., None] + mcol * metal[..., None]
    frame = sensor_image(lin, 0.0, 1.0, rng.uniform(1.0, 2.0), 2.2, 2.0, rng)
    _, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, 85])
    img = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    # truth: the plane bisector of the two silhouette planes (nominal pinhole, as the detector)
    e1 = line_through(P0 + 0.5 * w0 * n, u - np.tan(0.5 * conv) * n)
    e2 = line_through(P0 - 0.5 * w0 * n, u + np.tan(0.5 * conv) * n)
    n1, n2 = K.T @ e1, K.T @ e2
    n1, n2 = n1 / np.linalg.norm(n1), n2 / np.linalg.norm(n2)
    mid = P0 + 0.5 * min(seen, 400) * u
    best = None
    for cand in (n1 + n2, n1 - n2):
        l = np.linalg.inv(K).T @ cand
        l = l / np.hypot(l[0], l[1])
        r = abs(l[:2] @ mid + l[2])
        if best is None or r < best[0]:
            best = (r, l)
    l = best[1]
    pt = mid - (l[:2] @ mid + l[2]) * l[:2]
    ref = SimpleNamespace(kind="shaft", line=l, point=pt, width_px=w0)
    return img, ref, dict(side=int(side), w0=w0, conv=np.degrees(conv), seen=seen / w0, kind=kind, e1=e1, e2=e2, P0=P0, u=u)


# nearer still: converging by 14-24 deg, seen along 0.6-1.5 of its widths to the collar (the
# da Vinci frames' close shafts: 12-19 deg, 0.7-1.5 widths)
NEAR = dict(conv_deg=(14.0, 24.0), seen_widths=(0.6, 1.5))
# ... with limbs mirroring the tissue and a shadow beside the shaft (the da Vinci frames' close
# shafts: a brownish limb strip 10-18 px wide inside the silhouette, a shadow beside it)
SHADED = dict(NEAR, shaded=True)


def wedge(seed, kind):
    """(frame (H, W, 3) uint8 BGR, parameters) of a wedge of tissue entering at a random
    border as `scene`'s instrument does, 80-180 px wide there, its straight sides converging by
    14-30 deg and running on to 0.7-1.0 of the way to their apex, of kind "pale" (the tissue
    paled, as fascia or a fold lit) or "shadow" (the tissue darkened, keeping its hue): no
    instrument, so every detection is false."""
    rng = np.random.default_rng(seed)
    back = np.array(tissue_image((H, W), seed=seed), float)
    side = rng.integers(4)
    tilt = np.radians(rng.uniform(-35, 35))
    P0, u = [(np.array([0.0, rng.uniform(140, 340)]), np.array([1.0, 0.0])),
             (np.array([W - 1.0, rng.uniform(140, 340)]), np.array([-1.0, 0.0])),
             (np.array([rng.uniform(180, 460), 0.0]), np.array([0.0, 1.0])),
             (np.array([rng.uniform(180, 460), H - 1.0]), np.array([0.0, -1.0]))][side]
    c, s_ = np.cos(tilt), np.sin(tilt)
    u = np.array([c * u[0] - s_ * u[1], s_ * u[0] + c * u[1]])
    n = np.array([-u[1], u[0]])
    w0 = rng.uniform(80, 180)
    conv = np.radians(rng.uniform(14, 30))
    seen = rng.uniform(0.7, 1.0) * 0.5 * w0 / np.tan(0.5 * conv)
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    along = (xx - P0[0]) * u[0] + (yy - P0[1]) * u[1]
    across = (xx - P0[0]) * n[0] + (yy - P0[1]) * n[1]
    half = 0.5 * w0 - along * np.tan(0.5 * conv)
    cover = np.clip(half - np.abs(across) + 0.5, 0, 1) * np.clip(seen - along + 0.5, 0, 1) * np.clip(along + 40, 0, 1)
    if kind == "pale":
        inside = 0.45 * back + 0.55 * np.array([0.55, 0.58, 0.72]) * rng.uniform(0.8, 1.1)
    else:  # shadow: the tissue's own hue, darker
        inside = back * rng.uniform(0.15, 0.35)
    lin = back * (1 - cover)[..., None] + inside * cover[..., None]
    frame = sensor_image(lin, 0.0, 1.0, rng.uniform(1.0, 2.0), 2.2, 2.0, rng)
    _, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, 85])
    return cv2.imdecode(buf, cv2.IMREAD_COLOR), dict(side=int(side), w0=w0, conv=np.degrees(conv), kind=kind)


def sweep(seeds, kinds=("dark", "grey", "bright"), **ranges):
    """(found, frames, false detections) of `detect_shafts` over the scenes of seeds and kinds
    (ranges: those of `scene`)."""
    found = total = false = 0
    for kind in kinds:
        for seed in seeds:
            img, ref, _ = scene(seed, kind, **ranges)
            fs = score_frame([s.to_dict() for s in detect_shafts(img)], [ref])
            found, total, false = found + fs.found, total + 1, false + fs.false
    return found, total, false


if __name__ == "__main__":
    first, last = int(sys.argv[1]), int(sys.argv[2])
    kinds = sys.argv[3].split(",") if len(sys.argv) > 3 and sys.argv[3] not in ("near", "shaded") else ("dark", "grey", "bright")
    t0 = time.process_time()
    ranges = SHADED if "shaded" in sys.argv[3:] else NEAR if "near" in sys.argv[3:] else {}
    f, n, fa = sweep(range(first, last), kinds, **ranges)
    print(f"seeds {first}-{last - 1}: found {f}/{n}, false {fa} ({time.process_time() - t0:.1f} s CPU)")

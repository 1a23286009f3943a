"""Hard instrument frames with exact truth: the shafts a detector loses on real video.

`hard_shaft_frame` paints, over a tissue backdrop (`synth.tissue`), one or two straight
instrument shafts of one *class* of difficulty, seeded, with every shaft's exact axis:

- "thin": a distant shaft 8-20 px wide at 640x360 or 854x480, 4-15 grey levels from the
  tissue at its edges;
- "faint": a shaft seen through haze (the scene veiled towards one pale colour, which
  takes its colour contrast down too), 1.5-4 grey levels from the tissue at its edges;
  metal mirrors the tissue around it, so a shaft's colour is in part the tissue's (30-80 %
  but for the thin class's 0-40 %);
- "dark": a black shaft over tissue in a broad shadow, 2-6 grey levels below it;
- "vignette": a dark shaft (6-25 grey levels below the tissue) entering a circular field
  of view whose light falls off to black at its boundary: its edges fade into the black
  surround;
- "none": the backdrop alone (shadows, haze, vignetting at random): what a detector must
  not find a shaft in.

Every frame also carries the nuisances of real video: the backdrop's texture, pale tubular
folds (bands with two long soft edges) and fat; a specular streak along a shaft (half of
them), a cylinder's darker limbs, optical blur (1-2.5 px sd), gamma 2.2, sensor noise and
JPEG (quality 60-90). Contrast is set in encoded grey levels (luma) between the shaft
just inside its edges and the tissue just outside them, after haze and shadow, before
blur and noise.

A shaft enters the view from its border (or the field stop's) and ends inside it; its
edges converge by up to 2 deg (perspective). Its truth (`HardShaft`) is the bisector of
its two edges over the stretch in view, as `validation.shaft_score.score_frame` reads a
reference (`line`, `point`, `kind`, `width_px`).

Example
-------
>>> img, circle, truth = hard_shaft_frame("thin", 0)
>>> img.shape, img.dtype.name, len(truth) >= 1, 8.0 <= truth[0].width_px <= 20.0
((480, 854, 3), 'uint8', True, True)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.geometry.projective import line_through

__all__ = ["HARD_CLASSES", "HardShaft", "hard_shaft_frame"]

#: The classes of `hard_shaft_frame`.
HARD_CLASSES = ("thin", "faint", "dark", "vignette", "none")
_SHAPES = ((360, 640), (480, 854))
_LUMA = np.array([0.114, 0.587, 0.299])  # BGR
_GAMMA = 2.2


@dataclass(frozen=True)
class HardShaft:
    """The truth of one painted shaft.

    Attributes
    ----------
    line : (3,)
        Its axis image [px], a^2 + b^2 = 1.
    point : (2,) [px]
        The axis' point half-way along the stretch in view.
    width_px : float
        Apparent width there [px].
    edges : (2, 4) [px]
        Its two silhouette edges over the stretch in view.
    contrast : float
        Encoded grey levels between its inside and the tissue at its edges (as painted).
    kind : str
        "shaft" (what `validation.shaft_score.score_frame` reads).
    """

    line: np.ndarray
    point: np.ndarray
    width_px: float
    edges: np.ndarray
    contrast: float
    kind: str = "shaft"


def _encode(L):
    return 255.0 * np.clip(L, 0.0, 1.0) ** (1.0 / _GAMMA)


def _decode(e):
    return (np.clip(e, 0.0, 255.0) / 255.0) ** _GAMMA


def _entry(rng, H, W, circle):
    """(entry point (2,), inward unit direction (2,)) on the border of the view."""
    if circle is not None:
        cx, cy, r = circle
        for _ in range(100):
            a = rng.uniform(0, 2 * np.pi)
            p = np.array([cx + r * np.cos(a), cy + r * np.sin(a)])
            if 0.1 * W < p[0] < 0.9 * W and 0.02 * H <= p[1] <= 0.98 * H:
                break
        inward = -np.array([np.cos(a), np.sin(a)])
    else:
        side = rng.integers(4)
        t = rng.uniform(0.2, 0.8)
        p, inward = [(np.array([0.0, t * H]), np.array([1.0, 0.0])), (np.array([W - 1.0, t * H]), np.array([-1.0, 0.0])),
                     (np.array([t * W, 0.0]), np.array([0.0, 1.0])), (np.array([t * W, H - 1.0]), np.array([0.0, -1.0]))][side]
    b = rng.uniform(-50, 50) * np.pi / 180
    c, s = np.cos(b), np.sin(b)
    return p, np.array([c * inward[0] - s * inward[1], s * inward[0] + c * inward[1]])


def _band(shape, p, u, w0, w1, length):
    """(cover (H, W) area coverage, q (H, W) across from one edge (0) to the other (1),
    edges (2, 4), the bisector's line (3,) and point (2,), width at the centre): a band from
    p along u, w0 wide at p and w1 at its flat end `length` px on."""
    H, W = shape
    n = np.array([-u[1], u[0]])
    ends = p + length * u
    e1 = np.r_[p + 0.5 * w0 * n, ends + 0.5 * w1 * n]
    e2 = np.r_[p - 0.5 * w0 * n, ends - 0.5 * w1 * n]
    yy, xx = np.mgrid[0:H, 0:W].astype(float)

    def signed(e, towards):
        a, b = e[:2], e[2:]
        d = (b - a) / np.linalg.norm(b - a)
        nn = np.array([-d[1], d[0]])
        nn = nn if nn @ (towards - a) > 0 else -nn
        return (xx - a[0]) * nn[0] + (yy - a[1]) * nn[1]

    c = p + 0.5 * length * u
    d1, d2 = signed(e1, c), signed(e2, c)
    along = (xx - p[0]) * u[0] + (yy - p[1]) * u[1]
    cover = np.clip(d1 + 0.5, 0, 1) * np.clip(d2 + 0.5, 0, 1) * np.clip(length - along + 0.5, 0, 1) \
        * np.clip(along + 0.5 + 4.0, 0, 1)
    q = np.clip(d1 / np.maximum(d1 + d2, 1e-6), 0, 1)
    return cover, q, np.stack([e1, e2]), d1, d2, along


def _bisector(edges):
    """(line (3,), point (2,), width [px]) of the 2-D bisector of two edges over their span."""
    a, b = edges[:, :2], edges[:, 2:]
    mid0, mid1 = 0.5 * (a[0] + a[1]), 0.5 * (b[0] + b[1])
    ln = line_through(mid0, mid1)
    ln = ln / np.hypot(ln[0], ln[1])
    c = 0.5 * (mid0 + mid1)
    w = float(np.linalg.norm(0.5 * (a[0] + b[0]) - 0.5 * (a[1] + b[1])))
    return ln, c, w


def _clipped(edges, region_fn):
    """The edges cut to the stretch in view (where both their points pass region_fn), or
    None where it is not in view."""
    t = np.linspace(0, 1, 400)
    a, b = edges[:, None, :2], edges[:, None, 2:]
    pts = a + t[None, :, None] * (b - a)
    ok = region_fn(pts[0]) & region_fn(pts[1])
    k = np.flatnonzero(ok)
    if k.size < 2:
        return None
    t0, t1 = t[k[0]], t[k[-1]]
    return np.concatenate([a[:, 0] + t0 * (b - a)[:, 0], a[:, 0] + t1 * (b - a)[:, 0]], axis=1)


def hard_shaft_frame(kind, seed, shape=None):
    """One frame of a class (module docstring).

    Parameters
    ----------
    kind : str
        One of `HARD_CLASSES`.
    seed : int
    shape : (H, W), optional
        Default: 640x360 or 854x480 at random.

    Returns
    -------
    (frame (H, W, 3) uint8 BGR, the field stop's disc (cx, cy, r) [px] or None (the whole
    frame: `detect.region.valid.ValidRegion.from_circle` makes the valid region), list of
    `HardShaft`)
    """
    import cv2

    from pencilcal.toolkit.synth.render import sensor_image
    from pencilcal.toolkit.synth.tissue import tissue_image

    if kind not in HARD_CLASSES:
        raise ValueError(f"kind must be one of {', '.join(HARD_CLASSES)}, got {kind!r}")
    rng = np.random.default_rng([HARD_CLASSES.index(kind), int(seed)])
    H, W = _SHAPES[rng.integers(2)] if shape is None else shape
    diag = float(np.hypot(H, W))
    lin = np.array(tissue_image((H, W), seed=int(rng.integers(1 << 30))), float)
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    vignette = kind == "vignette" or (kind == "none" and rng.random() < 0.3)
    circle = None
    gain = np.ones((H, W))
    if vignette:
        circle = (W / 2 + rng.uniform(-0.03, 0.03) * W, H / 2 + rng.uniform(-0.03, 0.03) * H,
                  rng.uniform(0.55, 0.7) * max(H, W) * 0.5 + 0.25 * min(H, W))
        rr = np.hypot(xx - circle[0], yy - circle[1]) / circle[2]
        # light falls off to black over the outer third of the field, nothing outside it
        gain = np.clip((1.0 - rr) / rng.uniform(0.25, 0.4), 0, 1) ** rng.uniform(1.2, 2.0)
    shadow = np.ones((H, W))
    if kind == "dark" or (kind == "none" and rng.random() < 0.4):
        c = rng.uniform([0.2 * W, 0.2 * H], [0.8 * W, 0.8 * H])
        s = rng.uniform(0.2, 0.35) * diag
        shadow = 1.0 - rng.uniform(0.7, 0.88) * np.exp(-0.5 * ((xx - c[0]) ** 2 + (yy - c[1]) ** 2) / s**2)
    haze = rng.uniform(0.2, 0.6) if kind == "faint" or (kind == "none" and rng.random() < 0.3) else 0.0
    veil = np.array([0.55, 0.58, 0.66])
    scene = lin * (shadow * gain)[..., None]
    scene = (1 - haze) * scene + haze * veil * gain[..., None]

    def inside(P):
        P = np.asarray(P, float)
        ok = (P[..., 0] >= 0) & (P[..., 0] <= W - 1) & (P[..., 1] >= 0) & (P[..., 1] <= H - 1)
        return ok if circle is None else ok & (np.hypot(P[..., 0] - circle[0], P[..., 1] - circle[1]) <= circle[2])

    truths = []
    n_shafts = 0 if kind == "none" else (1 if rng.random() < 0.6 else 2)
    for _ in range(n_shafts):
        p, u = _entry(rng, H, W, circle)
        w0 = {"thin": rng.uniform(8, 20), "faint": rng.uniform(12, 45), "dark": rng.uniform(15, 50),
              "vignette": rng.uniform(15, 50)}[kind] * (max(H, W) / 854.0 if kind != "thin" else 1.0)
        w1 = w0 * rng.uniform(0.9, 1.0)
        length = rng.uniform(0.35, 0.6) * diag
        cover, q, edges, d1, d2, along = _band((H, W), p, u, w0, w1, length)
        if not np.any(cover > 0.5):
            continue
        # the tissue's luma in strips just outside both edges, the shaft's set from it
        strip = ((d1 < -1.5) & (d1 > -6.0) | (d2 < -1.5) & (d2 > -6.0)) & (along > 0) & (along < length)
        strip &= inside(np.stack([xx, yy], -1)) if circle is not None else True
        L_t = float(np.median(scene[strip] @ _LUMA)) if np.any(strip) else 0.1
        contrast = {"thin": rng.uniform(4, 15), "faint": rng.uniform(1.5, 4.0), "dark": rng.uniform(2.0, 6.0),
                    "vignette": rng.uniform(6.0, 25.0)}[kind]
        darker = kind in ("dark", "vignette") or rng.random() < 0.7
        e_s = _encode(L_t) + (-contrast if darker else contrast)
        L_s = max(float(_decode(e_s)), 1e-5)
        # the shaft's own light before haze, so that after it its luma is L_s
        base = (L_s - haze * float(veil @ _LUMA)) / max(1 - haze, 1e-3)
        # metal mirrors the tissue around it: part of the shaft's colour is the tissue's
        tissue_rgb = np.median(scene[strip], axis=0) if np.any(strip) else np.array([0.3, 0.3, 0.5])
        mirror = rng.uniform(0.0, 0.4) if kind == "thin" else rng.uniform(0.3, 0.8)
        tint = (1 - mirror) * np.array([1.04, 1.0, 0.96]) + mirror * tissue_rgb / max(float(tissue_rgb @ _LUMA), 1e-6)
        shade = 0.9 + 0.1 * np.sin(np.pi * q) ** 0.5  # a cylinder's darker limbs, weak
        local = shadow * gain if kind in ("dark", "vignette") else np.ones((H, W))
        # the shaft lies under the same light as the tissue beside it: its base scaled to it
        norm = float(np.median(local[strip])) if np.any(strip) else 1.0
        col = np.clip(base, 0.0, None) * tint[None, None, :] * (shade * local / max(norm, 1e-6))[..., None]
        if rng.random() < 0.5:  # a specular streak along the shaft
            q0, sq = rng.uniform(0.3, 0.7), rng.uniform(0.03, 0.08)
            col = col + rng.uniform(0.2, 1.0) * (1 - haze) * local[..., None] * np.exp(-0.5 * ((q - q0) / sq) ** 2)[..., None]
        col = (1 - haze) * col + haze * veil * gain[..., None] if haze else col
        scene = scene * (1 - cover[..., None]) + col * cover[..., None]
        edges_in = _clipped(edges, inside)
        if edges_in is None:
            continue
        line, point, width = _bisector(edges_in)
        truths.append(HardShaft(line=line, point=point, width_px=width, edges=edges_in, contrast=float(contrast)))
    if circle is not None:
        scene = scene * (np.hypot(xx - circle[0], yy - circle[1]) <= circle[2])[..., None]
    blur = rng.uniform(1.0, 2.5)
    frame = sensor_image(scene, 0.0, 1.0, blur, _GAMMA, rng.uniform(1.5, 3.0), rng)
    _, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, int(rng.integers(60, 91))])
    return cv2.imdecode(buf, cv2.IMREAD_COLOR), circle, truths

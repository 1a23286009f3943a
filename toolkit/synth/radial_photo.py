"""A webcam's photograph of a printed Siemens star, with exact truth: the star on a sheet of
paper on a desk, as hard as the world makes it.

`photo_layers` lays out the scene in the star's frame (mm, the pencil's frame, the vertex at
the origin): a desk with clutter on it (books, a pen, a keyboard's keys: other straight
edges, some long), an A4 sheet turned on it, the star printed with *dot gain* (every wedge's
edges moved out, or in, by the same distance: its dark and light widths unequal, its edges
lines that miss the vertex by that distance, its centre line still through it), an optional
grey disc at the centre where the print fills in, four ArUco markers at the sheet's corners
and lines of text beside the star. `photo_sensor` is what a webcam makes of the linear
scene: a shading gradient across the sheet and vignetting, a glossy specular patch, defocus
and motion blur, gamma 2.2, signal-dependent noise and JPEG. `photo_frame` draws one frame
from a condition dict (`validation.radial_renders.photo_conditions`).

Example
-------
>>> from pencilcal.toolkit.camera.model import Camera
>>> from pencilcal.toolkit.pencil.spec import pencil_from_dict
>>> star = pencil_from_dict({"start_deg": 0, "step_deg": 22.5, "count": 16, "shape": "wedge",
...                          "radius": [0, 40]})
>>> polys = gained_wedges(star, 0.5)
>>> len(polys), bool(abs(polys[0][0, 0] + 0.5 / np.sin(star.wedge / 2)) < 1e-9)   # apex behind the vertex
(16, True)
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.synth.polygons import arc, rect

__all__ = ["gained_wedges", "photo_layers", "photo_sensor", "aruco_cells", "A4", "curled", "paper_texture",
           "colour_photo", "banding"]

A4 = (210.0, 297.0)  # [mm]
_MARKER_MM = 30.0


def gained_wedges(pencil, gain_mm, radius=None):
    """The wedges of a star (`pencil`, shape "wedge") printed with dot gain: each wedge's two
    edges moved out (gain_mm > 0: the ink spreads) or in (< 0) by |gain_mm| [mm] along their
    normals, so each wedge is bounded by lines at that distance from the vertex and meets at
    an apex on its centre line, -gain_mm / sin(wedge / 2) from the vertex; its outer end an
    arc of `radius` (the pencil's outer radius). Returns [(K, 2) mm] polygons."""
    if pencil.shape != "wedge" or pencil.radius is None:
        raise InputError("a printed star needs a pencil of shape wedge with a radius")
    R = float(pencil.radius[1] if radius is None else radius)
    h = 0.5 * float(pencil.wedge)
    g = float(gain_mm)
    if g < 0 and -g / np.sin(h) >= R:
        raise InputError("the dot gain erodes the wedges away")
    s = np.sqrt(R * R - g * g)
    da = np.arctan2(g, s)  # the edge's far end seen from the vertex, beyond the edge's angle
    out = []
    for th in pencil.angles:
        apex = -g / np.sin(h) * np.array([np.cos(th), np.sin(th)])
        out.append(np.concatenate([apex[None], arc(R, th - h - da, th + h + da)]))
    return out


def aruco_cells(marker_id, centre, side, turn=0.0, dictionary="DICT_4X4_50"):
    """The black cells of an ArUco marker (its border and its bits) as squares [(4, 2) mm],
    the marker `side` wide, centred at `centre` (2,) and turned by `turn` [rad]."""
    import cv2

    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    bits = cv2.aruco.generateImageMarker(d, int(marker_id), d.markerSize + 2) < 128
    n = bits.shape[0]
    c = side / n
    Rt = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    cells = []
    for i, j in zip(*np.nonzero(bits)):
        sq = rect(-side / 2 + j * c, -side / 2 + i * c, -side / 2 + (j + 1) * c, -side / 2 + (i + 1) * c)
        cells.append(sq @ Rt.T + np.asarray(centre, float))
    return cells


def _turned(poly, turn, shift):
    Rt = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    return np.asarray(poly, float) @ Rt.T + np.asarray(shift, float)


def photo_layers(pencil, cond, rng):
    """The layers (`radial.render_layers`) of the photographed scene in the star's frame:
    desk, clutter, sheet, text, markers, star (gained by cond["gain_mm"]) and its grey centre
    (cond["centre_mm"] radius, 0 for none); the ink's reflectance 0.045, or the paper's times
    ((1 - c) / (1 + c))**2.2 for a print's contrast c = cond["contrast"] (Michelson, of the
    grey levels a gamma of 2.2 records).
    rng: a numpy Generator (the clutter and text)."""
    paper = float(cond.get("paper", 0.85))
    # the print's contrast as the photograph records it (gamma 2.2): grey levels (1 - c) / (1 + c) apart
    ink = paper * ((1 - cond["contrast"]) / (1 + cond["contrast"])) ** 2.2 if "contrast" in cond else 0.045
    turn = np.radians(float(cond.get("sheet_deg", 0.0)))
    w, hgt = A4
    off = np.asarray(cond.get("sheet_shift", (0.0, 0.0)), float)  # the star's place on the sheet
    sheet = _turned(rect(-w / 2, -hgt / 2, w / 2, hgt / 2) + off, turn, (0, 0))
    layers = [([rect(-3000.0, -3000.0, 3000.0, 3000.0)], float(cond.get("desk", 0.25)))]
    # clutter on the desk, outside the sheet: long straight edges of books, a pen, keys
    for _ in range(int(cond.get("clutter", 12))):
        for _try in range(20):
            c = rng.uniform(-500, 500, 2)
            if np.hypot(*c) > 260:
                break
        L, W = rng.uniform(20, 300), rng.uniform(4, 120)
        layers.append(([_turned(rect(-L / 2, -W / 2, L / 2, W / 2), rng.uniform(0, np.pi), c)],
                       float(rng.uniform(0.03, 0.8))))
    layers.append(([sheet], paper))
    printed = []
    # lines of text above and below the star: words as strokes 2.5 mm tall
    for y in (-95.0, -88.0, 88.0, 95.0, 102.0):
        x = -70.0
        while x < 70.0:
            word = rng.uniform(6, 20)
            for k in range(int(word / 1.6)):
                sw = rng.uniform(0.3, 0.6)
                xx = x + k * 1.6
                printed.append(rect(xx, y, xx + sw, y + rng.uniform(1.5, 2.6)) + off)
            x += word + 3.0
    for k, (sx, sy) in enumerate(((-1, -1), (1, -1), (1, 1), (-1, 1))):
        centre = off + np.array([sx * (w / 2 - 12 - _MARKER_MM / 2), sy * (hgt / 2 - 12 - _MARKER_MM / 2)])
        printed += aruco_cells(k, centre, _MARKER_MM)
    layers.append(([_turned(p, turn, (0, 0)) for p in printed], ink))
    light = pencil.polarity == "light"
    wedges = gained_wedges(pencil, float(cond.get("gain_mm", 0.0)) * (-1 if light else 1))  # the ink spreads
    if light:  # light wedges printed on a dark disc: the paper left unprinted
        layers.append(([arc(1.1 * float(pencil.radius[1]), 0.0, 2 * np.pi)[:-1]], ink))
        layers.append((wedges, paper))
    else:
        layers.append((wedges, ink))
    rc = float(cond.get("centre_mm", 0.0))
    if rc > 0:
        layers.append(([arc(rc, 0.0, 2 * np.pi)[:-1]], float(cond.get("centre_grey", 0.3))))
    return layers


def _disc_kernel(r):
    """A defocus kernel: a uniform disc of radius r [px], anti-aliased, sum 1."""
    n = int(np.ceil(r)) + 1
    y, x = np.mgrid[-n:n + 1, -n:n + 1].astype(float)
    k = np.clip(r + 0.5 - np.hypot(x, y), 0.0, 1.0)
    return k / k.sum()


def _motion_kernel(length, angle):
    """A motion-blur kernel: a line `length` px long at `angle` [rad], sum 1."""
    n = int(np.ceil(length / 2)) + 1
    k = np.zeros((2 * n + 1, 2 * n + 1))
    for s in np.linspace(-length / 2, length / 2, 8 * n + 1):
        x, y = n + s * np.cos(angle), n + s * np.sin(angle)
        x0, y0 = int(np.floor(x)), int(np.floor(y))
        fx, fy = x - x0, y - y0
        for dx, dy, wgt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
            if 0 <= y0 + dy < k.shape[0] and 0 <= x0 + dx < k.shape[1]:
                k[y0 + dy, x0 + dx] += wgt
    return k / k.sum()


def photo_sensor(img, cond, rng):
    """What a webcam records of the linear scene img (H, W): the light's gradient across the
    frame (cond["shading"]: its gain's range, 0.3 = +-30 %), vignetting (cond["vignette"]:
    the fall-off at the corners), a shadow's soft edge across it (cond["shadow"]: its depth,
    at cond["shadow_px"] (x, y) along cond["shadow_deg"], cond["shadow_soft"] px wide), a
    specular patch (cond["specular"]: its peak over the paper's white, at
    cond["specular_px"] (x, y, sd)), defocus (a disc of cond["defocus_px"], growing across the
    frame to cond["defocus_far_px"] where given: `_varying_defocus`) and motion blur
    (cond["motion_px"] along cond["motion_deg"]) over the optics' Gaussian
    (cond["blur_px"]), gamma 2.2, noise (cond["noise"] grey levels at mid grey, shot plus
    read), the pipeline's unsharp mask (cond["sharpen"] times the detail above a Gaussian of
    cond["sharpen_px"]: halos beside every edge) and JPEG at cond["jpeg"]; (H, W) uint8."""
    out = _recorded(_optics(img, cond), cond, rng)
    if cond.get("jpeg") is not None:
        import cv2

        ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(cond["jpeg"])])
        out = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)
    return out


def colour_photo(img, cond, rng, centre):
    """`photo_sensor` in colour with lateral chromatic aberration: the linear scene img (H, W)
    seen by the red channel magnified, and by the blue one shrunk, about `centre` (x, y) [px]
    so each lies cond["ca_px"] px from the green one at the frame's corners (bilinear
    resampling), each channel through the sensor with noise of its own, stored as a colour
    JPEG (chroma halved, as webcams store it). Returns (H, W, 3) uint8, BGR."""
    import cv2

    H, W = img.shape
    corner = np.hypot(max(centre[0], W - 1 - centre[0]), max(centre[1], H - 1 - centre[1]))
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    chans = []
    for sign in (-1.0, 0.0, 1.0):  # blue, green, red
        m = 1.0 + sign * float(cond.get("ca_px", 0.0)) / corner  # this channel's magnification
        ch = img.astype(np.float32)
        if sign:
            ch = cv2.remap(ch, (centre[0] + (xx - centre[0]) / m).astype(np.float32),
                           (centre[1] + (yy - centre[1]) / m).astype(np.float32), cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REFLECT)
        chans.append(_recorded(_optics(ch.astype(np.float64), cond), cond, rng))
    out = np.stack(chans, -1)
    if cond.get("jpeg") is not None:
        ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(cond["jpeg"])])
        out = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return out


def _optics(img, cond):
    """The linear scene img (H, W) lit and blurred as `photo_sensor` says: float32."""
    import cv2

    H, W = img.shape
    u = (np.arange(W) - (W - 1) / 2.0) / (max(W, H) / 2.0)
    v = (np.arange(H) - (H - 1) / 2.0) / (max(W, H) / 2.0)
    uu, vv = np.meshgrid(u, v)
    a = np.radians(float(cond.get("shading_deg", 0.0)))
    gain = 1.0 + float(cond.get("shading", 0.0)) * (np.cos(a) * uu + np.sin(a) * vv) / np.sqrt(2)
    gain *= 1.0 - float(cond.get("vignette", 0.0)) * (uu * uu + vv * vv) / 2.0
    if cond.get("shadow", 0) > 0:  # an object's shadow, its edge a soft line across the frame
        b = np.radians(float(cond["shadow_deg"]))
        d = (np.arange(W)[None] - cond["shadow_px"][0]) * np.cos(b) + (np.arange(H)[:, None] - cond["shadow_px"][1]) * np.sin(b)
        gain *= 1.0 - float(cond["shadow"]) / (1.0 + np.exp(-4.0 * d / float(cond["shadow_soft"])))
    out = img * np.maximum(gain, 0.05) * float(cond.get("exposure", 1.0))
    spec = float(cond.get("specular", 0.0))
    if spec > 0:
        sx, sy, sd = cond["specular_px"]
        yy, xx = np.mgrid[0:H, 0:W]
        patch = spec * np.exp(-0.5 * ((xx - sx) ** 2 + (yy - sy) ** 2) / sd**2)
        out = out + patch * img / 0.85  # glossy: the light's reflection, stronger on the paper than on the ink
    out = out.astype(np.float32)
    if cond.get("blur_px", 0) > 0:
        out = cv2.GaussianBlur(out, (0, 0), float(cond["blur_px"]), borderType=cv2.BORDER_REFLECT)
    if "defocus_far_px" in cond:  # a tilted sheet: the focus plane's distance varies across it
        out = _varying_defocus(out, cond)
    elif cond.get("defocus_px", 0) > 0.3:
        out = _defocused(out, float(cond["defocus_px"]))
    if cond.get("motion_px", 0) > 0.3:
        k = _motion_kernel(float(cond["motion_px"]), np.radians(float(cond.get("motion_deg", 0.0))))
        out = cv2.filter2D(out, -1, k.astype(np.float32), borderType=cv2.BORDER_REFLECT)
    return out


def _defocused(img, r):
    """img (H, W) float32 through a defocus disc of radius r [px] (none under 0.3 px)."""
    import cv2

    if r <= 0.3:
        return img
    return cv2.filter2D(img, -1, _disc_kernel(r).astype(np.float32), borderType=cv2.BORDER_REFLECT)


def _varying_defocus(img, cond):
    """img (H, W) float32 through a defocus that varies across the frame, as a tilted sheet's
    does: the disc's radius cond["defocus_px"] on the line through cond["focus_px"] (x, y, angle
    [deg], span [px]) across that angle, growing linearly to cond["defocus_far_px"] span px
    along it (held beyond, and before it); the images at 5 radii interpolated per pixel."""
    H, W = img.shape
    x0, y0, ang, span = (float(v) for v in cond["focus_px"])
    a = np.radians(ang)
    d = (np.arange(W)[None] - x0) * np.cos(a) + (np.arange(H)[:, None] - y0) * np.sin(a)
    f = np.clip(d / span, 0.0, 1.0) * 4.0  # the place between the 5 radii
    radii = np.linspace(float(cond.get("defocus_px", 0.0)), float(cond["defocus_far_px"]), 5)
    levels = [_defocused(img, r) for r in radii]
    k = np.minimum(np.floor(f).astype(int), 3)
    w = (f - k).astype(np.float32)
    out = np.zeros_like(img)
    for i in range(4):
        m = k == i
        out[m] = (1 - w[m]) * levels[i][m] + w[m] * levels[i + 1][m]
    return out


def _recorded(out, cond, rng):
    """The blurred linear scene `out` (H, W) as grey levels: gamma 2.2, noise, the unsharp
    mask (`photo_sensor`); (H, W) uint8."""
    import cv2

    out = 255.0 * np.clip(out.astype(np.float64), 0.0, 1.0) ** (1.0 / 2.2)
    noise = float(cond.get("noise", 0.0))
    if noise > 0:
        out = out + noise * np.sqrt(0.25 + 0.75 * out / 128.0) * rng.standard_normal(out.shape)
    if cond.get("sharpen", 0) > 0:  # the camera's sharpening: a halo on either side of every edge
        out = out + float(cond["sharpen"]) * (out - cv2.GaussianBlur(out, (0, 0), float(cond["sharpen_px"])))
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def curled(layers, R_cam_from_target, t_cam_from_target, curl_mm, curl_deg, radius=A4[1] / 2, step_mm=1.0):
    """Layers of a sheet that is not flat, as the camera sees them, drawn on the plane: the
    sheet bent into a cylinder about the vertex, z = curl_mm * (u / radius)**2 [mm] along the
    target's normal (away from the camera for curl_mm > 0), u the distance along the in-plane
    direction `curl_deg` [deg]; so at the vertex the sheet is tangent to the target plane and
    `radius` from it (half an A4 sheet's length) `curl_mm` off it. Every polygon's sides cut to `step_mm` or less, and
    each vertex moved to where its ray from the camera meets the plane: drawn flat, the
    polygons image where the bent sheet's would. Returns the layers."""
    R = np.asarray(R_cam_from_target, float)
    C = -R.T @ np.asarray(t_cam_from_target, float).reshape(3)  # the camera in the target frame
    d = np.array([np.cos(np.radians(curl_deg)), np.sin(np.radians(curl_deg))])

    def warped(poly):
        p = np.asarray(poly, float)
        q = np.roll(p, -1, 0)
        k = np.maximum(np.ceil(np.hypot(*(q - p).T) / step_mm), 1).astype(int)
        dense = np.concatenate([p[i] + np.linspace(0, 1, k[i], endpoint=False)[:, None] * (q[i] - p[i])
                                for i in range(len(p))])
        z = curl_mm * (dense @ d / radius) ** 2
        s = C[2] / (C[2] - z)  # along the ray from the camera, to the plane z = 0
        return C[:2] + (dense - C[:2]) * s[:, None]

    return [([warped(p) for p in polys], refl) for polys, refl in layers]


def paper_texture(camera, R_cam_from_target, t_cam_from_target, amplitude, rng, cell_mm=0.25, extent_mm=400.0):
    """The paper's (and desk's) texture as the camera sees it: a multiplicative gain (H, W),
    1 + amplitude * a field of unit sd on the target plane, its fibres (a noise smoothed over
    0.5 mm) and its mottle (over 4 mm) in equal parts, sampled where each pixel's ray meets
    the plane (on a grid of 8 px, interpolated)."""
    import cv2

    n = int(extent_mm / cell_mm)
    fib = cv2.GaussianBlur(rng.standard_normal((n, n)).astype(np.float32), (0, 0), 0.5 / cell_mm)
    mot = cv2.GaussianBlur(rng.standard_normal((n, n)).astype(np.float32), (0, 0), 4.0 / cell_mm)
    field = fib / fib.std() + mot / mot.std()
    field /= field.std()
    mx, my = _plane_points(camera, R_cam_from_target, t_cam_from_target)
    g = cv2.remap(field, np.clip(mx / cell_mm + n / 2, -1, n).astype(np.float32),
                  np.clip(my / cell_mm + n / 2, -1, n).astype(np.float32), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return 1.0 + float(amplitude) * g.astype(np.float64)


def _plane_points(camera, R_cam_from_target, t_cam_from_target):
    """Where each pixel's ray meets the target plane: (x, y) [mm], each (H, W) float32, on a
    grid of 8 px, interpolated; rays beyond the plane's horizon far away on it."""
    import cv2

    H, W = camera.height, camera.width
    gy, gx = np.mgrid[0:H + 8:8, 0:W + 8:8].astype(float)
    rays = camera.rays_from_pixels(np.stack([gx, gy], -1).reshape(-1, 2))
    R = np.asarray(R_cam_from_target, float)
    t = np.asarray(t_cam_from_target, float).reshape(3)
    rt = rays @ R  # the rays in the target frame, from the camera at -R^T t
    C = -R.T @ t
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -C[2] / rt[:, 2]
    s = np.where(np.isfinite(s) & (s > 0), s, 1e9)  # beyond the plane's horizon: far away on it
    P = C[None, :2] + s[:, None] * rt[:, :2]
    P = np.clip(np.where(np.isfinite(P), P, 1e5), -1e5, 1e5).reshape(gx.shape + (2,))  # rays the lens model lacks too
    mapx, mapy = np.meshgrid((np.arange(W) / 8.0).astype(np.float32), (np.arange(H) / 8.0).astype(np.float32))
    return (cv2.remap(P[..., 0].astype(np.float32), mapx, mapy, cv2.INTER_LINEAR),
            cv2.remap(P[..., 1].astype(np.float32), mapx, mapy, cv2.INTER_LINEAR))


def banding(camera, R_cam_from_target, t_cam_from_target, amplitude, period_mm, angle_deg, phase=0.0):
    """A printer's banding as the camera sees it: a multiplicative gain (H, W),
    1 + amplitude * sin(2 pi u / period_mm + phase), u [mm] the distance on the target plane
    along the direction `angle_deg` (the paper's feed): stripes across the sheet, on ink and
    paper alike."""
    mx, my = _plane_points(camera, R_cam_from_target, t_cam_from_target)
    a = np.radians(float(angle_deg))
    u = mx.astype(np.float64) * np.cos(a) + my.astype(np.float64) * np.sin(a)
    return 1.0 + float(amplitude) * np.sin(2 * np.pi * u / float(period_mm) + float(phase))

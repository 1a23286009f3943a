"""Estimates drawn on a frame with OpenCV: what `--overlay` shows, at the camera's rate.

Everything is drawn in raw pixels ((0, 0) the centre of the top-left pixel) on a BGR copy
of the frame, anti-aliased with 4 bits of sub-pixel precision, so a line lands where the
estimate puts it to 1/16 px. With ``scale`` < 1 the copy is the frame shrunk first (each
side to an even number of pixels near `scale` of it, as a video encoder wants; pixel
areas averaged) and the estimates are drawn at their places on it, lines and text at
the smaller frame's own sizes: the cheaper overlay of `--overlay-scale`, drawn sharp:

- `draw_orientation`: the pencil's segments coloured and numbered by spoke (rejected ones thin red),
  the vertex with its 3-sigma ellipse (an arrow at the border when it lies outside), the
  normal's image (from the vertex towards the normal's vanishing point), and a text box
  with tilt +- sigma, detectable, twin;
- `draw_shafts`: each shaft's two edges and its midline (the image of the axis);
- `draw_fulcrum`: the fulcrum's image and ellipse, or an arrow towards it;
- `draw_pose`: a board's axes at its pose, and its detected corners;
- `draw_frame`: any of these on one frame, as one call.

Example
-------
>>> import numpy as np
>>> img = np.zeros((120, 160), np.uint8)
>>> out = draw_frame(img, shafts=[{"midline": [10, 60, 150, 60], "edges": [[10, 50, 150, 50], [10, 70, 150, 70]]}])
>>> out.shape, out.dtype, int(out[60, 80].max()) > 0
((120, 160, 3), dtype('uint8'), True)
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["draw_frame", "draw_orientation", "draw_shafts", "draw_fulcrum", "draw_pose", "spoke_colour", "scaled_size",
           "SHIFT"]

# sub-pixel bits of cv2's drawing calls: coordinates are multiplied by 2**SHIFT
SHIFT = 4
_SCALE = 1 << SHIFT
# a palette that stays apart on grey and on tissue (BGR)
_PALETTE = [(255, 128, 0), (0, 200, 255), (80, 220, 80), (255, 0, 255), (0, 140, 255), (255, 255, 0),
            (180, 105, 255), (128, 255, 128), (255, 160, 160), (60, 180, 240)]
_RED, _WHITE, _YELLOW, _CYAN = (40, 40, 230), (255, 255, 255), (0, 230, 255), (255, 230, 0)


def spoke_colour(label):
    """BGR colour of spoke `label` (-1: rejected, red)."""
    return _RED if label < 0 else _PALETTE[int(label) % len(_PALETTE)]


def scaled_size(width, height, scale):
    """(width, height) of a frame drawn at `scale` (0 < scale <= 1): each side the even
    number of pixels nearest `scale` of it (2 at least); the frame's own at scale 1.

    >>> scaled_size(1920, 1080, 0.5), scaled_size(1918, 1082, 0.33), scaled_size(641, 481, 1.0)
    ((960, 540), (632, 358), (641, 481))
    """
    if scale == 1.0:
        return int(width), int(height)
    return max(2, 2 * int(round(width * scale / 2))), max(2, 2 * int(round(height * scale / 2)))


def _canvas(image, scale=1.0):
    """(BGR uint8 image to draw on, s): a copy of `image` at `scale` of its size
    (`scaled_size`, pixel areas averaged), and s (2,) the factors (x, y) by which `_px`
    takes the frame's raw pixels to the canvas's."""
    import cv2

    img = np.asarray(image)
    if img.dtype != np.uint8:
        k = 255.0 / max(float(np.max(img)), 1.0) if img.dtype.kind in "ui" and img.max() > 255 else 1.0
        img = np.clip(img * k, 0, 255).astype(np.uint8)
    h, w = img.shape[:2]
    size = scaled_size(w, h, float(scale))
    if size != (w, h):
        # resized before anything else: the copy, the conversion and the drawing all on
        # the smaller frame (OpenCV works without the interpreter meanwhile)
        img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
    elif img.ndim == 3:
        img = img.copy()
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    return img, np.array([size[0] / w, size[1] / h])


def _px(points, s):
    """Raw pixels (..., 2) of the frame as raw pixels of a canvas `s` times its size: pixel
    centres map to pixel centres (pixel k's area [k - 0.5, k + 0.5] scales to itself).

    >>> _px([[0.0, 0.0], [1.5, 3.0]], np.array([0.5, 0.5])).tolist()
    [[-0.25, -0.25], [0.5, 1.25]]
    """
    return (np.asarray(points, float) + 0.5) * s - 0.5


def _pt(p):
    return (int(round(float(p[0]) * _SCALE)), int(round(float(p[1]) * _SCALE)))


def _finite(*xs):
    """Whether every number is finite (math on Python floats: a frame's overlay draws dozens
    of lines, in a thread that shares the interpreter with the measurement)."""
    return all(math.isfinite(x) for x in xs)


def _line(img, p, q, colour, thickness=1):
    import cv2

    if _finite(p[0], p[1], q[0], q[1]):
        cv2.line(img, _pt(p), _pt(q), colour, thickness, cv2.LINE_AA, SHIFT)


def _thickness(img):
    return max(1, int(round(min(img.shape[:2]) / 540)))


def _ellipse(img, centre, cov, colour, n_sigma=3.0):
    """The n-sigma ellipse of a 2x2 covariance [px^2] about `centre`."""
    import cv2

    cov = np.asarray(cov, float)
    if cov.shape != (2, 2) or not np.all(np.isfinite(cov)):
        return
    w, v = np.linalg.eigh(0.5 * (cov + cov.T))
    axes = n_sigma * np.sqrt(np.clip(w, 0, None))
    angle = math.degrees(math.atan2(v[1, 1], v[0, 1]))
    size = (max(1, int(round(axes[1] * _SCALE))), max(1, int(round(axes[0] * _SCALE))))
    cv2.ellipse(img, _pt(centre), size, angle, 0, 360, colour, _thickness(img), cv2.LINE_AA, SHIFT)


def _border_arrow(img, target, colour, label):
    """An arrow from inside the border towards a point outside the frame, with a label."""
    import cv2

    h, w = img.shape[:2]
    c = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    d = np.asarray(target, float) - c
    if not np.all(np.isfinite(d)) or not np.any(d):
        return
    s = min(abs(((w - 1) * (d[0] > 0) - c[0]) / d[0]) if d[0] else np.inf,
            abs(((h - 1) * (d[1] > 0) - c[1]) / d[1]) if d[1] else np.inf) * 0.95
    tip = c + s * d
    tail = tip - 60.0 * d / np.linalg.norm(d)
    cv2.arrowedLine(img, _pt(tail), _pt(tip), colour, _thickness(img), cv2.LINE_AA, SHIFT, 0.3)
    cv2.putText(img, label, (int(tail[0]) - 40, int(tail[1]) - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1,
                cv2.LINE_AA)


def _point(img, p, cov, colour, label):
    import cv2

    h, w = img.shape[:2]
    if p is None or not np.all(np.isfinite(p)):
        return
    if -0.5 <= p[0] <= w - 0.5 and -0.5 <= p[1] <= h - 0.5:
        r = 6 * _thickness(img)
        _line(img, (p[0] - r, p[1]), (p[0] + r, p[1]), colour, _thickness(img))
        _line(img, (p[0], p[1] - r), (p[0], p[1] + r), colour, _thickness(img))
        if cov is not None:
            _ellipse(img, p, cov, colour)
    else:
        _border_arrow(img, p, colour, label)


def _text_box(img, lines, origin=(8, 8)):
    """Lines of text on a dark translucent box at the top left."""
    import cv2

    if not lines:
        return
    scale = max(0.45, min(img.shape[:2]) / 1200)
    th = max(1, int(round(scale * 2)))
    sizes = [cv2.getTextSize(t, cv2.FONT_HERSHEY_SIMPLEX, scale, th)[0] for t in lines]
    lh = max(s[1] for s in sizes) + 8
    x0, y0 = origin
    x1, y1 = x0 + max(s[0] for s in sizes) + 12, y0 + lh * len(lines) + 6
    roi = img[y0:y1, x0:x1]
    roi[:] = (roi * 0.35).astype(np.uint8)
    for k, t in enumerate(lines):
        cv2.putText(img, t, (x0 + 6, y0 + (k + 1) * lh), cv2.FONT_HERSHEY_SIMPLEX, scale, _WHITE, th, cv2.LINE_AA)


def _spoke_labels(img, seg, lab, vertex_px):
    """Each labelled segment's spoke index at its end farther from the vertex (the segment's
    second end without a vertex). seg: (M, 4) raw px; lab: (M,) spoke or -1."""
    import cv2

    v = None if vertex_px is None else [float(c) for c in np.ravel(vertex_px)]
    if v is not None and not _finite(*v):
        v = None
    scale = max(0.45, min(img.shape[:2]) / 1800)
    th = max(1, _thickness(img))
    for s, k in zip(np.asarray(seg, float).tolist(), np.asarray(lab).tolist()):
        if k < 0 or not _finite(*s):
            continue
        (px, py), (qx, qy) = s[:2], s[2:]
        if v is not None and math.hypot(px - v[0], py - v[1]) > math.hypot(qx - v[0], qy - v[1]):
            px, py, qx, qy = qx, qy, px, py
        dx, dy = qx - px, qy - py
        h = max(math.hypot(dx, dy), 1e-9)
        cv2.putText(img, str(int(k)), (int(round(qx + 12.0 * dx / h)) - 5, int(round(qy + 12.0 * dy / h)) + 5),
                    cv2.FONT_HERSHEY_SIMPLEX, scale, spoke_colour(int(k)), th, cv2.LINE_AA)


def _normal_line(img, s, orientation, camera):
    """From the vertex towards the vanishing point of the normal: the normal's image, 0.12
    of the frame's shorter side long (in the frame's pixels, then drawn on the canvas)."""
    n = np.asarray(orientation.normal, float)
    v = orientation.vertex_px
    if camera is None or v is None or not np.all(np.isfinite(n)):
        return
    length_px = 0.12 * min(img.shape[0] / s[1], img.shape[1] / s[0])
    K = np.asarray(camera.K, float)
    ray = getattr(orientation, "ray", None)
    if ray is not None and float(ray[2]) > 0:
        # the vertex's ideal pixel from its ray: no inversion of the lens model per frame
        ideal_v = K[:2, :2] @ (np.asarray(ray[:2], float) / float(ray[2])) + K[:2, 2]
    else:
        ideal_v = camera.undistort_pixels(np.asarray(v, float))
    if abs(n[2]) > 1e-9:
        vp = (K @ (n / n[2]))[:2]
        d = (vp - ideal_v) * (1 if n[2] > 0 else -1)
    else:
        d = (K[:2, :2] @ n[:2])
    if not np.any(d):
        return
    tip_ideal = ideal_v + length_px * d / np.linalg.norm(d)
    tip = camera.distort_pixels(tip_ideal)
    _line(img, _px(v, s), _px(tip, s), _YELLOW, 2 * _thickness(img))


def _value_pm(value, sigma):
    """"value +- sigma" with the sigma to two significant digits and the value to the same
    decimal place (at least two decimals), so a 0.004 deg sigma does not print as 0.00.

    >>> _value_pm(28.71342, 0.00384), _value_pm(12.3, 0.25), _value_pm(5.0, float("nan"))
    ('28.7134 +- 0.0038', '12.30 +- 0.25', '5.00 +- nan')
    """
    if not (np.isfinite(sigma) and sigma > 0):
        return f"{value:.2f} +- {sigma:.2f}"
    d = int(min(6, max(2, 1 - np.floor(np.log10(sigma)))))
    return f"{value:.{d}f} +- {sigma:.{d}f}"


def _orientation_on(img, s, orientation, segments, camera):
    """`draw_orientation` on the canvas `img` (`_canvas`), in place."""
    if segments is not None:
        seg = _px(np.asarray(segments, float).reshape(-1, 2, 2), s).reshape(-1, 4)
        lab = np.asarray(orientation.spokes if orientation.spokes is not None else np.full(len(seg), -1)).ravel()
        th = _thickness(img)
        for q, k in zip(seg.tolist(), lab.tolist()):
            _line(img, q[:2], q[2:], spoke_colour(int(k)), (2 if k >= 0 else 1) * th)
        v = orientation.vertex_px if orientation.ok else None
        _spoke_labels(img, seg, lab, None if v is None else _px(v, s))
    if orientation.ok:
        v, cov = orientation.vertex_px, orientation.vertex_cov_px2
        _point(img, None if v is None else _px(v, s), None if cov is None else s[:, None] * np.asarray(cov, float) * s,
               _CYAN, "vertex")
        _normal_line(img, s, orientation, camera)
        twin = "resolved by " + str(orientation.resolved_by) if not orientation.ambiguous else "twin: ambiguous"
        _text_box(img, [f"{orientation.image or ''}",
                        f"tilt {_value_pm(orientation.tilt_deg, orientation.tilt_sigma_deg)} deg"
                        + ("" if orientation.detectable else " (not detectable)"),
                        f"{orientation.lines_used} lines, {twin}"])
    else:
        _text_box(img, [f"{orientation.image or ''}", f"no estimate: {orientation.error}"[:80]])


def draw_orientation(image, orientation, segments=None, camera=None, scale=1.0):
    """One frame's `Orientation` drawn on `image` (a BGR copy at `scale` of its size is
    returned, module docstring).

    segments: (M, 4) raw px, the segments given to orient (coloured by
    ``orientation.spokes``); camera: for the normal's image (omitted without it).
    """
    img, s = _canvas(image, scale)
    _orientation_on(img, s, orientation, segments, camera)
    return img


def _shafts_on(img, s, shafts):
    for sh in shafts:
        for e in sh.get("edges") or []:
            e = _px(np.asarray(e, float).reshape(2, 2), s).ravel()
            _line(img, e[:2], e[2:], _CYAN, _thickness(img))
        m = _px(np.asarray(sh["midline"], float).reshape(2, 2), s).ravel()
        _line(img, m[:2], m[2:], _YELLOW, 2 * _thickness(img))


def draw_shafts(image, shafts, scale=1.0):
    """Shafts (records with ``midline`` and optionally ``edges``, raw px) drawn on `image`
    (a BGR copy at `scale` of its size)."""
    img, s = _canvas(image, scale)
    _shafts_on(img, s, shafts)
    return img


def _fulcrum_on(img, s, vertex_px, cov_px2, label):
    p = None if vertex_px is None else _px(np.asarray(vertex_px, float), s)
    _point(img, p, None if cov_px2 is None else s[:, None] * np.asarray(cov_px2, float) * s, _RED, label)


def draw_fulcrum(image, vertex_px, cov_px2=None, label="fulcrum", scale=1.0):
    """The fulcrum's image with its 3-sigma ellipse, or an arrow towards it (a BGR copy of
    `image` at `scale` of its size)."""
    img, s = _canvas(image, scale)
    _fulcrum_on(img, s, vertex_px, cov_px2, label)
    return img


def draw_pose(image, camera, R_cam_from_target, t_cam_from_target, length, corners=None, scale=1.0):
    """A target's axes at a pose (x red, y green, z blue, `length` in the target's unit)
    and its detected corners (K, 2) raw px, on a BGR copy of `image` at `scale` of its size."""
    img, s = _canvas(image, scale)
    if corners is not None:
        for c in _px(np.asarray(corners, float).reshape(-1, 2), s):
            _line(img, c - 2, c + 2, _CYAN, 1)
            _line(img, c + [-2, 2], c + [2, -2], _CYAN, 1)
    if R_cam_from_target is None or t_cam_from_target is None:
        return img
    R, t = np.asarray(R_cam_from_target, float), np.asarray(t_cam_from_target, float)
    pts = (np.vstack([np.zeros(3), length * np.eye(3)]) @ R.T) + t
    if np.any(pts[:, 2] <= 0):
        return img
    px = _px(camera.project(pts), s)
    for k, colour in enumerate(((40, 40, 230), (60, 200, 60), (230, 120, 40))):
        _line(img, px[0], px[k + 1], colour, 2 * _thickness(img))
    return img


def draw_frame(image, orientation=None, segments=None, shafts=None, fulcrum=None, camera=None, text=None,
               scale=1.0):
    """Everything known about one frame on one BGR copy of it at `scale` of its size: the
    orientation with its segments, the shafts, the fulcrum (a dict with ``vertex_px``,
    ``vertex_cov_px2``, or a Fulcrum), extra text lines."""
    img, s = _canvas(image, scale)
    if shafts:
        _shafts_on(img, s, shafts)
    if orientation is not None:
        _orientation_on(img, s, orientation, segments, camera)
    elif segments is not None:
        for q in _px(np.asarray(segments, float).reshape(-1, 2, 2), s).reshape(-1, 4):
            _line(img, q[:2], q[2:], _PALETTE[0], _thickness(img))
    if fulcrum is not None:
        v = fulcrum.get("vertex_px") if isinstance(fulcrum, dict) else fulcrum.vertex_px
        c = fulcrum.get("vertex_cov_px2") if isinstance(fulcrum, dict) else fulcrum.vertex_cov_px2
        _fulcrum_on(img, s, v, c, "fulcrum")
    if text:
        _text_box(img, list(text), origin=(8, img.shape[0] - 30 * len(text) - 8))
    return img

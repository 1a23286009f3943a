"""Overlays on sample frames: everything the estimate and the reference say about a frame,
drawn on its image (`fig_overlay`), for frames spread over the tilt range (`sample_frames`).

On the image (full view, and a zoom around the vertex): the detected pencil segments
coloured and numbered by spoke (rejected ones dashed red), the vertex with its 3-sigma
covariance ellipse, the board's outline and axes at the reference pose, and from the
vertex the reference normal, the estimated normal and its twin. Pixels are raw image
pixels (x right, y down); 3D points are in the camera frame, in the board's unit.

Example
-------
>>> import numpy as np
>>> _segment_point_at([0.0, 0.0, 10.0, 0.0], np.array([0.0, 0.0]), 4.0)
array([4., 0.])
>>> sample_frames({"frames": [{"ok": True, "reference_tilt_deg": t} for t in (30, 10, 20)]}, 2)
[1, 0]
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pencilcal.toolkit.errors import PencilcalError

from .document import Para, Plot, Section
from .figures import MAX_WIDTH_IN, MIN_FONT, legend_below, new_figure, nice_floor, png_bytes, tilt_axis
from .format import finite, lookup, num

__all__ = ["usable_camera", "field_radius", "frame_image", "project_points", "sample_frames", "fig_overlay",
           "overlay_section"]


def usable_camera(data):
    """(camera model, None) from the validation file's camera record, or (None, why not)."""
    from pencilcal.toolkit.camera.formats import camera_from_dict

    try:
        return camera_from_dict(data.get("camera"), source="validation camera"), None
    except PencilcalError as e:
        return None, str(e)


def sample_frames(data, count):
    """Indices of `count` validated frames spread evenly over the reference tilt."""
    if count <= 0:
        return []
    xs, _ = tilt_axis(data)
    cand = [i for i, f in enumerate(data["frames"]) if f.get("ok") or lookup(f, "orient", "exact", "ok")]
    if not cand:
        cand = list(range(len(data["frames"])))
    cand.sort(key=lambda i: (xs.get(i) is None, xs.get(i) or 0.0, i))
    if len(cand) <= count:
        return cand
    pick = np.unique(np.round(np.linspace(0, len(cand) - 1, count)).astype(int))
    return [cand[p] for p in pick]


def _image_path(data, fr, roots=()):
    """The frame's image: its recorded path, else that path under the validation file's
    folder, else the image name in the file's images folder."""
    path = fr.get("path")
    cands = []
    if path:
        cands.append(Path(str(path)))
        if not Path(str(path)).is_absolute():
            cands += [Path(r) / str(path) for r in roots]
    if fr.get("image") and data.get("images"):
        cands.append(Path(str(data["images"])) / str(fr["image"]))
    for c in cands:
        if c.is_file():
            return str(c)
    return path


def frame_image(data, fr, roots=()):
    """((H, W, 3) uint8 RGB image of the validation file's frame `fr`, None), or (None, why
    not); the image found as `_image_path` finds it."""
    import cv2

    path = _image_path(data, fr, roots)
    if not path or not Path(str(path)).is_file():
        return None, f"image not found at {path}"
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        return None, f"cannot decode {path}"
    return img[..., ::-1], None


def project_points(cam, P, rmax):
    """Project camera-frame points P: (N, 3) to (N, 2) raw pixels; NaN where a point is
    behind the camera or beyond the normalised radius `rmax` the lens's field reaches."""
    P = np.asarray(P, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        xy = P[:, :2] / P[:, 2:3]
        r = np.hypot(xy[:, 0], xy[:, 1])
        uv = cam.project(P)
    bad = ~(P[:, 2] > 0) | (r > rmax) | ~np.isfinite(uv).all(1)
    uv[bad] = np.nan
    return uv


def field_radius(cam):
    """Largest normalised radius (x/z, y/z) the image sees, with a margin (points beyond it
    can fold back in); 10 when the camera cannot say."""
    try:
        corners = np.array([[0, 0], [cam.width - 1, 0], [0, cam.height - 1], [cam.width - 1, cam.height - 1]], float)
        rays = cam.rays_from_pixels(corners)
        r = np.hypot(rays[:, 0] / rays[:, 2], rays[:, 1] / rays[:, 2])
        return float(np.nanmax(r)) * 1.15 if np.isfinite(r).any() else 10.0
    except Exception:  # noqa: BLE001 - a drawing aid only
        return 10.0


def _vertex_3d(fr, o, data):
    """The vertex in the camera frame at the reference pose, (3,): the vertex ray met with
    the board plane (else the pencil file's vertex, else None)."""
    R, t = fr.get("R_ref"), fr.get("t_ref")
    if R is None or t is None:
        return None
    R, t = np.asarray(R, float), np.asarray(t, float)
    n = R[:, 2]
    ray = o.get("ray")
    if ray is not None:
        ray = np.asarray(ray, float)
        d = float(n @ ray)
        if abs(d) > 1e-9:
            lam = float(n @ t) / d
            if lam > 0:
                return lam * ray
    v = lookup(data, "pencil", "vertex")
    if isinstance(v, list) and len(v) == 2:
        return R @ np.r_[np.asarray(v, float), 0.0] + t
    return None


def _segment_point_at(sgm, v, r):
    """The point (2,) of segment `sgm` (x1, y1, x2, y2) whose distance to `v` (2,) is closest
    to r (all in pixels)."""
    p, q = np.asarray(sgm[:2], float), np.asarray(sgm[2:], float)
    t = np.linspace(0, 1, 101)[:, None]
    pts = p + t * (q - p)
    return pts[np.argmin(np.abs(np.hypot(*(pts - v).T) - r))]


# ----------------------------------------------------------------------------------------
# one frame's overlay


@dataclass
class _Scene:
    """What one overlay draws. img: (H, W, 3) RGB; segs: (N, 4) pixels; labels: N spoke
    labels or None; vpx: (2,) vertex pixel or None; R_ref (3, 3), t_ref (3,): reference
    pose or None; size: board (width, height) or None; L: axis length (board units);
    P0: (3,) vertex in the camera frame or None; zoom_box: (x0, x1, y0, y1) pixels or None;
    hx, hy: the zoom's half size [px]; ell: (width, height, angle [deg]) of the magnified
    3-sigma ellipse or None; scale: its magnification."""

    o: dict
    img: np.ndarray
    segs: np.ndarray
    labels: list | None
    vpx: np.ndarray | None
    cam: object
    field_r: float
    R_ref: np.ndarray | None
    t_ref: np.ndarray | None
    size: tuple | None
    L: float | None
    P0: np.ndarray | None
    zoom_box: tuple | None = None
    hx: float = 0.0
    hy: float = 0.0
    ell: tuple | None = None
    scale: float = 1.0


def _orient_record(data, fr):
    """The frame's exact-model orientation record, else that of the first model it has."""
    o = lookup(fr, "orient", "exact") or {}
    if not o:
        for m in data.get("models") or []:
            if isinstance(lookup(fr, "orient", m), dict):
                o = fr["orient"][m]
                break
    return o


def _board_size(board):
    """(width, height) of the board's drawn outline in its unit, or None."""
    try:
        if board.get("type") == "charuco":
            return (board["squares"][0] * board["square"], board["squares"][1] * board["square"])
        if board.get("squares") and board.get("square"):
            return ((board["squares"][0] - 1) * board["square"], (board["squares"][1] - 1) * board["square"])
    except (KeyError, TypeError, IndexError):
        return None
    return None


def _set_zoom(sc, w, h):
    """The zoom window: around the vertex (else the segments), with the image's aspect."""
    pts = np.concatenate([sc.segs[:, :2], sc.segs[:, 2:]]) if sc.segs.size else sc.vpx[None]
    span = float(max(np.ptp(pts[:, 0]), np.ptp(pts[:, 1]), 40.0))
    centre = sc.vpx if sc.vpx is not None else pts.mean(0)
    half = max(0.3 * span, 30.0)
    hx, hy = (half * w / h, half) if w >= h else (half, half * h / w)
    hx, hy = min(hx, w / 2), min(hy, h / 2)
    cx = min(max(centre[0], hx - 0.5), w - 0.5 - hx)
    cy = min(max(centre[1], hy - 0.5), h - 0.5 - hy)
    sc.zoom_box, sc.hx, sc.hy = (cx - hx, cx + hx, cy + hy, cy - hy), hx, hy


def _set_ellipse(sc, w):
    """The vertex's 3-sigma ellipse, magnified by a round factor to be seen at all."""
    if sc.vpx is None or sc.o.get("vertex_cov_px2") is None:
        return
    cov = np.asarray(sc.o["vertex_cov_px2"], float)
    if cov.shape == (2, 2) and np.all(np.isfinite(cov)):
        ev, evec = np.linalg.eigh(cov)
        a3 = 3 * np.sqrt(np.clip(ev, 0, None))
        if a3.max() > 0:
            target = 0.04 * 2 * sc.hx if sc.zoom_box is not None else 0.015 * w
            sc.scale = nice_floor(target / a3.max())
            sc.ell = (2 * a3[1] * sc.scale, 2 * a3[0] * sc.scale, math.degrees(math.atan2(evec[1, 1], evec[0, 1])))


def _scene(data, fr, o, img, cam, field_r):
    """What the overlay of frame `fr` draws (_Scene), with the zoom and the ellipse set."""
    try:
        segs = np.asarray(fr.get("segments") or [], float).reshape(-1, 4)
    except ValueError:
        segs = np.zeros((0, 4))
    spokes = o.get("spokes")
    size = _board_size(data.get("board") or {})
    sc = _Scene(o=o, img=img, segs=segs,
                labels=spokes if isinstance(spokes, list) and len(spokes) == len(segs) else None,
                vpx=np.asarray(o["vertex_px"], float) if o.get("vertex_px") is not None else None,
                cam=cam, field_r=field_r,
                R_ref=np.asarray(fr["R_ref"], float) if fr.get("R_ref") is not None else None,
                t_ref=np.asarray(fr["t_ref"], float) if fr.get("t_ref") is not None else None,
                size=size, L=0.4 * min(size) if size else None,
                P0=_vertex_3d(fr, o, data) if cam is not None else None)
    h, w = img.shape[:2]
    if segs.size > 0 or sc.vpx is not None:
        _set_zoom(sc, w, h)
    _set_ellipse(sc, w)
    return sc


def _draw_board(ax, sc, keep):
    """The board's outline and axes at the reference pose."""
    s = np.linspace(0, 1, 40)[:, None]
    W, H = sc.size
    corners = np.array([[0, 0, 0], [W, 0, 0], [W, H, 0], [0, H, 0], [0, 0, 0]], float)
    outline = np.concatenate([c0 + s * (c1 - c0) for c0, c1 in zip(corners[:-1], corners[1:])])
    uv = project_points(sc.cam, (sc.R_ref @ outline.T).T + sc.t_ref, sc.field_r)
    keep("board outline (reference pose)", ax.plot(uv[:, 0], uv[:, 1], "-", color="cyan", lw=0.9)[0])
    for axis, col, name in ((0, "red", "x"), (1, "lime", "y"), (2, "blue", "z")):
        e = np.zeros(3)
        e[axis] = sc.L
        uv = project_points(sc.cam, (sc.R_ref @ (s * e).T).T + sc.t_ref, sc.field_r)
        keep(f"board {name} axis (reference pose)", ax.plot(uv[:, 0], uv[:, 1], "-", color=col, lw=2.4)[0])


def _draw_segments(ax, ai, sc, keep):
    """The pencil segments by spoke (numbered in the zoom), rejected ones dashed red."""
    import matplotlib

    cmap = matplotlib.colormaps["tab10"]
    lw = 1.0 if ai == 0 else 1.8
    for j, sgm in enumerate(sc.segs):
        k = sc.labels[j] if sc.labels is not None else None
        if k is None:
            keep("segment (no label)", ax.plot(sgm[0::2], sgm[1::2], "-", color="yellow", lw=lw)[0])
        elif int(k) < 0:
            keep("rejected segment", ax.plot(sgm[0::2], sgm[1::2], "--", color="red", lw=lw)[0])
        else:
            c = cmap(int(k) % 10)
            keep("pencil segment, numbered by spoke", ax.plot(sgm[0::2], sgm[1::2], "-", color=c, lw=lw + 0.6)[0])
            if ai == 1 and sc.vpx is not None:
                ax.annotate(str(int(k)), _segment_point_at(sgm, sc.vpx, 0.8 * min(sc.hx, sc.hy)), color="white",
                            fontsize=MIN_FONT, ha="center", va="center", annotation_clip=True,
                            bbox=dict(boxstyle="round,pad=0.15", fc=c, ec="none", alpha=0.85))


def _draw_vertex(ax, ai, sc, keep):
    """The vertex and its covariance ellipse."""
    from matplotlib.patches import Ellipse

    keep("vertex", ax.plot(*sc.vpx, "+", color="magenta", ms=12 if ai else 8, mew=1.5)[0])
    if sc.ell is not None:
        e = Ellipse(sc.vpx, sc.ell[0], sc.ell[1], angle=sc.ell[2], fill=False, color="magenta", lw=1.4)
        ax.add_patch(e)
        keep("vertex 3-sigma ellipse" + (f" x{sc.scale:g}" if sc.scale > 1 else ""), e)


def _draw_normals(ax, ai, sc, keep):
    """The estimated normal, its twin and the reference normal, from the vertex."""
    from matplotlib import patheffects

    s = np.linspace(0, 1, 20)[:, None]
    # the reference last and thinner: it shows inside an estimate that lies on it
    for vec, col, ls, name, wid in ((sc.o.get("normal"), "white", "-", "estimated normal", 3.2),
                                    (sc.o.get("normal_twin"), "white", (0, (2, 2)), "twin normal", 3.2),
                                    (sc.R_ref[:, 2] if sc.R_ref is not None else None, "blue", "-",
                                     "reference normal", 1.3)):
        if vec is None:
            continue
        uv = project_points(sc.cam, sc.P0 + s * (sc.L * np.asarray(vec, float)), sc.field_r)
        lw_n = wid if ai else wid * 0.7
        ln = ax.plot(uv[:, 0], uv[:, 1], ls=ls, color=col, lw=lw_n,
                     path_effects=[patheffects.withStroke(linewidth=lw_n + 1.6, foreground="black")])[0]
        keep(name, ln)
        if np.isfinite(uv[-1]).all():
            ax.plot(*uv[-1], "o", color=col, ms=4, mec="black")


def _draw_panel(ax, ai, sc, keep):
    """One panel (0: the whole image, 1: the zoom) with everything drawn on it."""
    h, w = sc.img.shape[:2]
    ax.imshow(sc.img, interpolation="antialiased")
    ax.set_xticks([])
    ax.set_yticks([])
    if sc.cam is not None and sc.R_ref is not None and sc.t_ref is not None and sc.size:
        _draw_board(ax, sc, keep)
    _draw_segments(ax, ai, sc, keep)
    if sc.vpx is not None:
        _draw_vertex(ax, ai, sc, keep)
    if sc.cam is not None and sc.P0 is not None and sc.L:
        _draw_normals(ax, ai, sc, keep)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)


def _overlay_title(fr, o):
    """The figure's title: reference tilt, the estimate and the normal error."""
    e = lookup(fr, "errors", "orient:exact") or {}
    title = f"{fr.get('image')}: reference tilt {num(fr.get('reference_tilt_deg'))} deg"
    if o.get("ok"):
        title += (f"; estimate {num(o.get('tilt_deg'))} +- {num(o.get('tilt_sigma_deg'))} deg"
                  + ("" if o.get("detectable", True) else " (not detectable)"))
    if e:
        title += f"; normal error {num(e.get('normal_closer_deg'))} deg (twin {e.get('twin')})"
    elif o and not o.get("ok"):
        title += f"; no estimate: {o.get('error')}"
    return title


def _overlay_caption(index, fr, sc, notes):
    """The caption: what is drawn, and what could not be."""
    cap = (f"Frame {index} ({fr.get('image')}); right: the dashed box of the left panel. Pencil segments coloured "
           f"and numbered by the spoke they were assigned to, rejected ones dashed red; the vertex with its 3-sigma "
           f"covariance ellipse" + (f" magnified {sc.scale:g} times" if sc.scale > 1 else "")
           + "; the board's x (red), y (green) and z (blue) axes and its outline (cyan) at the reference pose; "
             "from the vertex the reference normal (blue), the estimated normal (white) and its twin (white "
             "dashed), projected from where the vertex's ray meets the board plane.")
    if sc.cam is None:
        cap += " No usable camera in the file: nothing is projected."
    elif sc.R_ref is None:
        cap += " No reference pose in this frame: no board axes."
    if notes:
        cap += " Note: " + "; ".join(notes) + "."
    return cap


def fig_overlay(data, index, cam, field_r, roots=()):
    """The sample frame `index` with everything the estimate and the reference say about it.

    cam: the camera model (`usable_camera`) or None; field_r: its `field_radius`; roots:
    folders to look for a relative image path in. Returns (png bytes, caption) or (None,
    reason)."""
    from matplotlib.patches import Rectangle

    fr = data["frames"][index]
    img, why = frame_image(data, fr, roots)
    if img is None:
        return None, f"{fr.get('image')}: {why}; no overlay."
    o = _orient_record(data, fr)
    sc = _scene(data, fr, o, img, cam, field_r)
    h, w = img.shape[:2]
    zoom = sc.zoom_box is not None
    panel_w = MAX_WIDTH_IN / 2
    fig = new_figure(figsize=(2 * panel_w if zoom else panel_w + 1, panel_w * h / w + 1.7))
    axes = fig.subplots(1, 2 if zoom else 1, squeeze=False)[0]
    notes = []
    if cam is not None and (cam.width, cam.height) != (w, h):
        notes.append(f"the image is {w}x{h}, the camera {cam.width}x{cam.height}")
    handles = {}

    def keep(name, artist):
        handles.setdefault(name, artist)

    for ai, ax in enumerate(axes):
        _draw_panel(ax, ai, sc, keep)
    if zoom:
        x0, x1, y0, y1 = sc.zoom_box
        axes[1].set_xlim(x0, x1)
        axes[1].set_ylim(y0, y1)
        axes[1].set_title("around the vertex", fontsize=9)
        axes[0].add_patch(Rectangle((x0, y1), x1 - x0, y0 - y1, fill=False, ec="white", lw=0.8, ls="--"))
    if handles:
        legend_below(fig, list(handles.values()), list(handles.keys()), ncol=3)
    fig.suptitle(_overlay_title(fr, o), fontsize=9)
    return png_bytes(fig, dpi=100), _overlay_caption(index, fr, sc, notes)


def overlay_section(data, samples, source=None):
    """Section 5: `samples` frames spread over the reference tilt, each with its overlay
    (or a note saying why it has none). source: the validation file's path, whose folder
    is searched for relative image paths."""
    s5 = Section("overlays", "5. Sample frames")
    if samples <= 0:
        s5.blocks.append(Para("No sample frames asked for (--samples 0).", "note"))
        return s5
    cam, cam_err = usable_camera(data)
    if cam_err:
        s5.blocks.append(Para(f"The camera in the file cannot be used ({cam_err}); overlays show the image "
                              f"measurements only.", "note"))
    field_r = field_radius(cam) if cam is not None else 10.0
    picks = sample_frames(data, samples)
    if picks:
        _, axis = tilt_axis(data)
        over = "the reference tilt" if axis.startswith("reference tilt") else "the sequence"
        tilt = {i: finite(data["frames"][i].get("reference_tilt_deg")) for i in picks}
        s5.blocks.append(Para(f"{len(picks)} frames spread over {over}: "
                              + ", ".join(f"{data['frames'][i].get('image')}"
                                          + (f" ({num(tilt[i])} deg)" if tilt[i] is not None else "") for i in picks)
                              + "."))
    for i in picks:
        png, cap = fig_overlay(data, i, cam, field_r, [Path(source).parent] if source is not None else [])
        s5.blocks.append(Plot(png, cap, f"overlay {data['frames'][i].get('image')}", "image") if png
                         else Para(cap, "note"))
    if not picks:
        s5.blocks.append(Para("No frame to show.", "note"))
    return s5

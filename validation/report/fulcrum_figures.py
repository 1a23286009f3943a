"""The fulcrum section's figures: the fulcrum drawn on sample frames (`fulcrum_frames`) and
a top view of the 3-D fulcrum among the frames' 3-D axes (`fig_top_view`).

On a frame: its detected shaft midlines (raw pixels; those the fulcrum fit left out red),
each continued along its undistorted line towards the fulcrum (dashed, through the lens
model, so the continuation bends as the image of a straight line does); the 3-D point
projected with the outline of its 68 % ellipsoid (``point_cov``, chi2 with 3 dof: every
point of the ellipsoid's surface projected through the lens, their convex hull); the 2-D
vertex, with its 68 % ellipse (``vertex_cov_px2``, 2 dof) when there is no 3-D point;
the truth's fulcrum where known. The ellipses are drawn in a second panel that zooms on the
fulcrum, magnified by a round factor where smaller than a tenth of it (said in the legend).

The top view is the x-z plane of the camera frame (x right, z forward): the camera centre,
every frame's 3-D axis, the 3-D point with its 1- and 2-sigma ellipses (the x-z marginal
of point_cov) and the truth; a second panel zooms on the point.

Example
-------
>>> (np.round(ellipse_points([0.0, 0.0], np.diag([4.0, 1.0]), 1.0, n=5), 6) + 0.0).tolist()
[[0.0, 1.0], [2.0, 0.0], [0.0, -1.0], [-2.0, 0.0], [0.0, 1.0]]
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .document import Para, Plot
from .figures import MAX_WIDTH_IN, legend_below, new_figure, nice_floor, plot_of, png_bytes
from .format import lookup, num, vec
from .overlay import field_radius, frame_image, project_points, usable_camera

__all__ = ["ellipse_points", "ellipsoid_outline", "fig_top_view", "fulcrum_frames"]

# the probability inside the drawn regions on the frames (the 1-sigma mass of a 1-D Gaussian)
_MASS = 0.6827


def _k(dof):
    """The Mahalanobis radius holding `_MASS` of a Gaussian with `dof` dimensions."""
    from scipy.special import chdtri

    return float(np.sqrt(chdtri(dof, 1.0 - _MASS)))


def ellipse_points(centre, cov2, k, n=121):
    """(n, 2) points of the k-sigma ellipse of a 2x2 covariance about centre (2,), closed."""
    w, V = np.linalg.eigh(np.asarray(cov2, float))
    t = np.linspace(0.0, 2 * np.pi, n)
    circle = np.stack([np.cos(t), np.sin(t)], -1) * (k * np.sqrt(np.maximum(w, 0.0)))
    return np.asarray(centre, float) + circle @ V.T


def _sphere(n=600):
    """(n, 3) unit vectors spread evenly over the sphere (a Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    r = np.sqrt(1.0 - z**2)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)


def ellipsoid_outline(cam, point, cov, k, rmax):
    """(M, 2) raw pixels, closed: the image of the k-sigma ellipsoid of a 3-D point (3,) with
    covariance cov (3, 3), camera frame: its surface's points projected through the lens,
    their convex hull. None where part of it lies behind the camera or beyond the lens
    model's field (`field_radius` rmax), or it has no area in the image."""
    from scipy.spatial import ConvexHull

    w, V = np.linalg.eigh(np.asarray(cov, float))
    X = np.asarray(point, float) + k * (_sphere() * np.sqrt(np.maximum(w, 0.0))) @ V.T
    uv = project_points(cam, X, rmax)
    if not np.isfinite(uv).all():
        return None
    try:
        hull = ConvexHull(uv)
    except Exception:  # noqa: BLE001 - scipy's QhullError: a flat (degenerate) outline
        return None
    pts = uv[hull.vertices]
    return np.vstack([pts, pts[:1]])


# ----------------------------------------------------------------------------------------
# sample frames


def _frame_picks(data, rec, count):
    """Indices of up to `count` frames of data["frames"] with a detected shaft, spread evenly."""
    named = {m["image"] for m in rec.get("midlines") or []}
    cand = [i for i, f in enumerate(data["frames"]) if f.get("image") in named]
    if count <= 0 or not cand:
        return []
    if len(cand) <= count:
        return cand
    return [cand[p] for p in np.unique(np.round(np.linspace(0, len(cand) - 1, count)).astype(int))]


def _continuation(cam, midline, x, rmax):
    """(n, 2) raw pixels: the midline's undistorted line from its end nearer the fulcrum's
    normalised image x (2,) to x's foot on it, through the lens model; None when the foot
    lies on the midline itself or it cannot be drawn."""
    n = cam.normalized_from_pixels(np.asarray(midline, float).reshape(2, 2))
    d = n[1] - n[0]
    if not np.all(np.isfinite(n)) or not float(d @ d) > 0:
        return None
    t_foot = float((x - n[0]) @ d / (d @ d))
    if 0.0 <= t_foot <= 1.0:
        return None
    t_end = 0.0 if abs(t_foot) < abs(t_foot - 1.0) else 1.0
    pts = n[0] + np.linspace(t_end, t_foot, 80)[:, None] * d
    uv = cam.pixels_from_normalized(pts)
    uv[np.hypot(pts[:, 0], pts[:, 1]) > rmax] = np.nan
    return uv


def _fulcrum_marks(rec, cam, rmax):
    """What marks the fulcrum on every frame: {"point" (2,) the 3-D point's image, "outline"
    (M, 2) its 68 % ellipsoid's, "vertex" (2,), "vertex_ellipse" (n, 2), "truth" (2,),
    "x" (2,) the fulcrum's normalised image}, each None where unknown."""
    marks = dict.fromkeys(("point", "outline", "vertex", "vertex_ellipse", "truth", "x"))
    ray = np.asarray(rec.get("ray") or [np.nan] * 3, float)
    if ray[2] > 0:
        marks["x"] = ray[:2] / ray[2]
    if cam is not None and rec.get("point") is not None and rec.get("point_cov") is not None:
        P = np.asarray(rec["point"], float)
        uv = project_points(cam, P[None], rmax)[0]
        if np.isfinite(uv).all():
            marks["point"] = uv
            marks["outline"] = ellipsoid_outline(cam, P, rec["point_cov"], _k(3), rmax)
    if rec.get("vertex_px") is not None:
        marks["vertex"] = np.asarray(rec["vertex_px"], float)
        if rec.get("vertex_cov_px2") is not None and rec.get("point") is None:
            marks["vertex_ellipse"] = ellipse_points(marks["vertex"], rec["vertex_cov_px2"], _k(2))
    truth = lookup(rec, "truth", "fulcrum_px")
    marks["truth"] = None if truth is None else np.asarray(truth, float)
    return marks


def _zoom(marks, w, h):
    """(centre (2,), half width, half height, magnification) of the zoom on the fulcrum, or
    None when the fulcrum has no image."""
    centre = marks["point"] if marks["point"] is not None else marks["vertex"]
    if centre is None:
        return None
    shapes = [s for s in (marks["outline"], marks["vertex_ellipse"]) if s is not None]
    ext = max([float(np.max(np.abs(s - centre))) for s in shapes] + [0.0])
    half = max(2.5 * ext, 12.0)
    if marks["truth"] is not None:
        half = max(half, 1.3 * float(np.max(np.abs(marks["truth"] - centre))))
    scale = nice_floor(0.25 * half / ext) if 0 < ext < 0.1 * half else 1.0
    return centre, (half * w / h if w >= h else half), (half if w >= h else half * h / w), scale


def _draw_marks(ax, marks, zoom, keep):
    """The fulcrum's marks (`_fulcrum_marks`) on one panel; with `zoom` (`_zoom`'s) the
    ellipses too, magnified by its factor about its centre."""
    scale = zoom[3] if zoom else 1.0
    mag = "" if scale == 1 else f" (x{scale:g})"

    def grown(s):
        return s if scale == 1 else zoom[0] + scale * (s - zoom[0])

    if zoom and marks["vertex_ellipse"] is not None:
        keep("2-D vertex, 68 % ellipse" + mag, ax.plot(*grown(marks["vertex_ellipse"]).T, "-", color="magenta",
                                                        lw=1.2)[0])
    if marks["vertex"] is not None:
        keep("2-D vertex", ax.plot(*marks["vertex"], "+", color="magenta", ms=10, mew=1.5)[0])
    if zoom and marks["outline"] is not None:
        keep("3-D point's 68 % ellipsoid, projected" + mag, ax.plot(*grown(marks["outline"]).T, "-", color="cyan",
                                                                     lw=1.6)[0])
    if marks["point"] is not None:
        keep("3-D point, projected", ax.plot(*marks["point"], "o", color="cyan", ms=4, mec="black")[0])
    if marks["truth"] is not None:
        keep("truth", ax.plot(*marks["truth"], "x", color="red", ms=9, mew=1.6)[0])


def _draw_shafts(ax, lines, keep):
    """Each shaft's midline (green; outliers red) and its continuation towards the fulcrum."""
    for mid, cont, used in lines:
        col = "lime" if used else "red"
        keep("shaft midline" if used else "midline left out (outlier)",
             ax.plot(mid[0::2], mid[1::2], "-", color=col, lw=2.2)[0])
        if cont is not None:
            keep("midline continued towards the fulcrum", ax.plot(*cont.T, "--", color=col, lw=0.9)[0])


def _fig_frame(img, fr, lines, marks):
    """(png, the zoom's magnification) of one frame with its shafts and the fulcrum's marks."""
    h, w = img.shape[:2]
    zoom = _zoom(marks, w, h)
    fig = new_figure(figsize=(MAX_WIDTH_IN if zoom else 6.6, MAX_WIDTH_IN / 2 * h / w + 1.8))
    axes = fig.subplots(1, 2 if zoom else 1, squeeze=False)[0]
    handles = {}

    def keep(name, artist):
        handles.setdefault(name, artist)

    pts = [np.array([[0.0, 0.0], [w, h]])] + [m[None] for m in (marks["point"], marks["vertex"], marks["truth"])
                                              if m is not None]
    # the image, and around it what lies beyond it (a port off the image)
    lo, hi = np.min(np.vstack(pts), 0), np.max(np.vstack(pts), 0)
    pad = 0.03 * max(w, h) * np.array([lo[0] < 0, lo[1] < 0, hi[0] > w, hi[1] > h])
    for ai, ax in enumerate(axes):
        ax.imshow(img, interpolation="antialiased", extent=(-0.5, w - 0.5, h - 0.5, -0.5))
        ax.set_facecolor("0.85")
        _draw_shafts(ax, lines, keep)
        _draw_marks(ax, marks, zoom if ai == 1 else None, keep)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_xlim(lo[0] - 0.5 - pad[0], hi[0] - 0.5 + pad[2])
        ax.set_ylim(hi[1] - 0.5 + pad[3], lo[1] - 0.5 - pad[1])
    if zoom:
        (cx, cy), hx, hy, _ = zoom
        axes[1].set_xlim(cx - hx, cx + hx)
        axes[1].set_ylim(cy + hy, cy - hy)
        axes[1].set_title(f"around the fulcrum ({num(2 * hx)} x {num(2 * hy)} px)", fontsize=9)
    legend_below(fig, list(handles.values()), list(handles.keys()))
    fig.suptitle(f"{fr.get('image')}: {len(lines)} shaft(s)", fontsize=9)
    return png_bytes(fig), (zoom[3] if zoom else 1.0)


def fulcrum_frames(data, rec, count, source=None):
    """Blocks (Plot, or Para saying why not) of up to `count` sample frames with the fulcrum
    drawn (module docstring). data: the validation dict; rec: its ``fulcrum`` record;
    source: the validation file's path (relative image paths are looked for beside it)."""
    picks = _frame_picks(data, rec, count)
    if not picks:
        return []
    cam, why = usable_camera(data)
    if cam is None:
        return [Para(f"The camera in the file cannot be used ({why}): no fulcrum drawn on the frames.", "note")]
    rmax = field_radius(cam)
    marks = _fulcrum_marks(rec, cam, rmax)
    bad = {(o.get("image"), o.get("segment")) for o in rec.get("outliers") or []}
    roots = [Path(source).parent] if source is not None else []
    out = []
    for i in picks:
        fr = data["frames"][i]
        img, why = frame_image(data, fr, roots)
        if img is None:
            out.append(Para(f"{fr.get('image')}: {why}; no fulcrum drawn on it.", "note"))
            continue
        lines = []
        for m in rec.get("midlines") or []:
            if m["image"] == fr.get("image"):
                cont = None if marks["x"] is None else _continuation(cam, m["midline"], marks["x"], rmax)
                lines.append((np.asarray(m["midline"], float), cont, (m["image"], m["shaft"]) not in bad))
        png, scale = _fig_frame(img, fr, lines, marks)
        out.append(Plot(png, _frame_caption(fr, marks, scale), f"fulcrum on {fr.get('image')}", "image"))
    return out


def _frame_caption(fr, marks, scale):
    """The caption of one frame's figure: what is drawn, and what could not be."""
    cap = (f"{fr.get('image')}: the shaft midlines detected in this frame (green; a midline the fulcrum fit left "
           "out red), each continued along its undistorted line towards the fulcrum (dashed)")
    if marks["outline"] is not None:
        cap += ("; the 3-D fulcrum projected (cyan dot) with the outline of its 68 % ellipsoid (point_cov, chi2 "
                "3 dof = 3.53)")
    elif marks["point"] is not None:
        cap += "; the 3-D fulcrum projected (cyan dot; its ellipsoid reaches beyond the lens model's field)"
    if marks["vertex_ellipse"] is not None:
        cap += "; the 2-D vertex (magenta) with its 68 % ellipse (vertex_cov_px2, chi2 2 dof = 2.30)"
    elif marks["vertex"] is not None:
        cap += "; the 2-D vertex (magenta)"
    elif marks["point"] is None:
        cap += "; the fulcrum itself lies beyond the part of the field the lens model maps to pixels"
    if marks["truth"] is not None:
        cap += "; the truth (red cross)"
    cap += ". Right: around the fulcrum"
    cap += f", its ellipses magnified {scale:g} times about it." if scale > 1 else ", at the image's scale."
    return cap


# ----------------------------------------------------------------------------------------
# top view


def _top_axes(rec, P, reach):
    """[(x-z points (2, 2) of the axis's segment, used)] of every frame's 3-D axis: from
    its point closest to the camera centre to the fulcrum's foot on it, continued by
    `reach` [length] both ways."""
    out = []
    for a in rec.get("point_axes") or []:
        if a.get("axis_point") is None or a.get("axis_direction") is None:
            continue
        A, d = np.asarray(a["axis_point"], float), np.asarray(a["axis_direction"], float)
        s = float(d @ (P - A))
        ts = np.array([min(0.0, s) - reach, max(0.0, s) + reach])
        out.append(((A + ts[:, None] * d)[:, [0, 2]], bool(a.get("used", True))))
    return out


def _draw_top(ax, rec, P, C, axes, full, keep):
    """One top-view panel: the axes, the point and its 1- and 2-sigma ellipses, the truth;
    on the full panel also the camera centre and the fulcrum ray."""
    for seg, used in axes:
        keep("3-D axis of a frame" if used else "3-D axis left out (outlier)",
             ax.plot(seg[:, 0], seg[:, 1], "-", color="C0" if used else "C3", lw=0.8, alpha=0.6 if used else 0.9)[0])
    if full:
        keep("camera centre", ax.plot([0.0], [0.0], "ks")[0])
        ray = np.asarray(rec.get("ray") or [0, 0, 1], float)
        reach = 1.2 * float(np.linalg.norm(P))
        keep("fulcrum ray (2-D vertex)", ax.plot([0.0, reach * ray[0]], [0.0, reach * ray[2]], "C7--", lw=0.8)[0])
    keep("3-D fulcrum", ax.plot([P[0]], [P[2]], "ko", ms=4)[0])
    keep("1 sigma (x-z marginal)", ax.plot(*ellipse_points(P[[0, 2]], C, 1.0).T, "-", color="C1", lw=1.4)[0])
    keep("2 sigma", ax.plot(*ellipse_points(P[[0, 2]], C, 2.0).T, ":", color="C1", lw=1.2)[0])
    truth = lookup(rec, "truth", "fulcrum_cam")
    if truth is not None:
        keep("truth", ax.plot([truth[0]], [truth[2]], "C3x", ms=9, mew=1.6)[0])
    ax.set_xlabel("x [mm] (camera frame, right)")
    ax.set_ylabel("z [mm] (depth)")
    ax.grid(True, alpha=0.25)


def fig_top_view(rec):
    """Top view (x right, z forward) of the 3-D fulcrum among the frames' 3-D axes, with its
    ellipses, and a zoom on it; None without a 3-D point."""
    if rec.get("point") is None or rec.get("point_cov") is None:
        return None
    P = np.asarray(rec["point"], float)
    C = np.asarray(rec["point_cov"], float)[np.ix_([0, 2], [0, 2])]
    ext = 2.0 * float(np.sqrt(max(np.linalg.eigvalsh(C).max(), 0.0)))
    truth = lookup(rec, "truth", "fulcrum_cam")
    half = max(1.4 * ext, 1e-9)
    if truth is not None:
        half = max(half, 1.3 * float(np.max(np.abs(np.asarray(truth, float)[[0, 2]] - P[[0, 2]]))))
    axes = _top_axes(rec, P, max(0.1 * float(np.linalg.norm(P)), 2.0 * half))
    fig = new_figure(figsize=(MAX_WIDTH_IN, 5.0))
    ax1, ax2 = fig.subplots(1, 2)
    handles = {}

    def keep(name, artist):
        handles.setdefault(name, artist)

    _draw_top(ax1, rec, P, C, axes, True, keep)
    _draw_top(ax2, rec, P, C, axes, False, keep)
    ax1.set_aspect("equal", adjustable="datalim")
    ax2.set_xlim(P[0] - half, P[0] + half)
    ax2.set_ylim(P[2] - half, P[2] + half)
    ax2.set_aspect("equal", adjustable="box")
    ax1.set_title("the camera, the axes and the fulcrum", fontsize=9)
    ax2.set_title("around the fulcrum", fontsize=9)
    legend_below(fig, list(handles.values()), list(handles.keys()))
    used = sum(1 for _, u in axes if u)
    cap = (f"Top view (the x-z plane of the camera frame, seen from above) of the 3-D fulcrum {vec(P, ' mm')} "
           f"(point_sigma {num(rec.get('point_sigma'), ' mm')}) with its 1- and 2-sigma ellipses (the x-z marginal of "
           f"point_cov), among the 3-D axes of the frames' shafts ({used} used")
    cap += f", {len(axes) - used} left out, red)" if len(axes) > used else ")"
    if not axes:
        cap = cap.rsplit(", among", 1)[0] + " (the file holds no per-frame 3-D axes)"
    cap += "; the dashed line is the 2-D vertex's ray. Right: around the point"
    if truth is not None:
        cap += f"; the truth (red cross) is {num(lookup(rec, 'truth', 'point_error_norm'), ' mm')} away"
    return plot_of(fig, cap + ".", "top view of the 3-D fulcrum, the frames' axes and its error ellipse")

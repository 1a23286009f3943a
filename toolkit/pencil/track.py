"""Orientation from frame to frame: the previous frame's estimate as a prior.

In a video the pencil moves little between frames. `orient_tracked` labels a frame's
segments with spokes by the previous frame's orientation instead of searching all
labellings (`assign.assign_spokes`, most of `orient.orient_segments`' time), then fits as
`orient_segments` does with those labels, so a frame whose labels come out the same gets
the same estimate as a full run. The twin chosen in the previous frame is kept where this
frame alone cannot choose (`orient.resolve_twins_by_continuity` over the two frames).

The prior is checked, never trusted: the frame falls back to the full search when the
previous frame has no estimate, when fewer spokes are labelled than the previous frame
used (less one), or when a labelled line misses the spoke it was given by more than
`GATE_SIGMA` of its angle sd. The vertex is always found from this frame's lines: refined
from the lines the prior labels (`vertex.intersect_lines`' start; the search over all
pairs where one of them does not pass through it).

Labelling by the prior: each segment (undistorted, normalised) is oriented away from the
previous vertex and given the spoke whose predicted image angle (`spec.image_angles` of
the previous rotation at the previous vertex) is nearest, if within the gate: `gate_deg`,
at most 0.4 of the smallest angle between neighbouring predicted spokes (so no segment can
match two), and only if the segment's line passes the previous vertex within
`VERTEX_GATE` of its distance from it.

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.camera.model import Camera
>>> from pencilcal.toolkit.pencil.spec import Pencil
>>> cam = Camera("pinhole", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
>>> pen = Pencil(np.radians(np.arange(6) * 30.0))
>>> th = np.radians(np.arange(6) * 30.0 + 3.0)
>>> seg = np.c_[319.5 + 40 * np.cos(th), 239.5 + 40 * np.sin(th), 319.5 + 200 * np.cos(th), 239.5 + 200 * np.sin(th)]
>>> first, tracked = orient_tracked(cam, seg, pen, None)
>>> second, tracked2 = orient_tracked(cam, seg + 0.3, pen, first)
>>> tracked, tracked2, np.array_equal(second.spokes, first.spokes)
(False, True, True)
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.geometry.angles import wrap_angle
from pencilcal.toolkit.pencil.orient import orient_segments, resolve_twins_by_continuity
from pencilcal.toolkit.pencil.spec import image_angles

__all__ = ["orient_tracked", "prior_labels", "GATE_DEG", "GATE_SIGMA", "VERTEX_GATE"]

#: Largest angle [deg] between a segment and the spoke the previous frame predicts for it.
GATE_DEG = 6.0
#: A tracked fit is refused when a labelled line misses its spoke by more than this many sd.
GATE_SIGMA = 5.0
#: A segment's line must pass the previous vertex within this fraction of its distance from it.
VERTEX_GATE = 0.25


def prior_labels(camera, segments, pencil, previous, gate_deg=GATE_DEG, ideal=None):
    """Spoke label (M,) of each segment by the previous frame's orientation (-1: none); for
    wedges and sector boundaries the edge's index in the pencil's `edge_angles`.

    segments: (M, 4) raw px; previous: an `Orientation` with an estimate (``ok``);
    gate_deg [deg]: see the module docstring; ideal: (M, 4) the segments in undistorted
    pixels where known already (then not undistorted again).
    """
    seg = np.asarray(segments, float).reshape(-1, 4)
    lab = np.full(len(seg), -1)
    ray = np.asarray(previous.ray, float)
    if len(seg) == 0 or not ray[2] > 0:
        return lab
    x0 = ray[:2] / ray[2]
    pred = image_angles(np.asarray(previous.R_cam_from_target, float), x0, pencil.edge_angles()[0])  # (N,)
    gap = np.abs(wrap_angle(pred[:, None] - pred[None, :]))
    gap[np.diag_indices_from(gap)] = np.inf
    gate = min(np.radians(gate_deg), 0.4 * float(np.min(gap))) if len(pred) > 1 else np.radians(gate_deg)
    if ideal is None:
        with np.errstate(invalid="ignore"):
            p = camera.normalized_from_pixels(seg.reshape(-1, 2)).reshape(-1, 2, 2)
    else:
        K = np.asarray(camera.K, float)
        p = np.linalg.solve(K[:2, :2], (np.asarray(ideal, float).reshape(-1, 2) - K[:2, 2]).T).T.reshape(-1, 2, 2)
    d1, d2 = np.linalg.norm(p[:, 0] - x0, axis=-1), np.linalg.norm(p[:, 1] - x0, axis=-1)
    near, far = np.where((d1 <= d2)[:, None], p[:, 0], p[:, 1]), np.where((d1 <= d2)[:, None], p[:, 1], p[:, 0])
    t = far - near
    L = np.linalg.norm(t, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        perp = np.abs(t[:, 0] * (x0[1] - near[:, 1]) - t[:, 1] * (x0[0] - near[:, 0])) / L
        passes = perp <= VERTEX_GATE * np.minimum(d1, d2) + 1e-9
    a = np.arctan2(t[:, 1], t[:, 0])
    diff = np.abs(wrap_angle(a[:, None] - pred[None, :]))  # (M, N)
    best = np.argmin(diff, -1)
    ok = np.isfinite(a) & (L > 0) & passes & (diff[np.arange(len(seg)), best] <= gate)
    lab[ok] = best[ok]
    return lab


def orient_tracked(camera, segments, pencil, previous, gate_deg=GATE_DEG, keep_lines=False, prior_lab=None,
                   **orient_kwargs):
    """This frame's `Orientation` with the previous frame's as a prior: (orientation,
    tracked), tracked False when the full search was used (module docstring). Bars'
    midlines (``bar_width_px``) are moved onto their centre lines under the previous
    frame's plane and fitted once (`orient_segments`' plane_normal).

    segments: (M, 4) raw px; previous: the previous frame's `Orientation` or None;
    keep_lines: the orientation's ``lines`` kept (`orient_segments`); prior_lab: (M,) the
    segments' `prior_labels` at `gate_deg` where known already (not labelled again); orient_kwargs:
    `orient_segments`' (model, endpoint_sigma_px, angle_sigma, offset_sigma, max_segments,
    image, ideal, ...; not labels).
    """
    if previous is None or not previous.ok or previous.ray is None:
        return orient_segments(camera, segments, pencil, keep_lines=keep_lines, **orient_kwargs), False
    lab = prior_labels(camera, segments, pencil, previous, gate_deg, orient_kwargs.get("ideal")) if prior_lab is None \
        else np.array(prior_lab)  # (a copy: the fit may keep it)
    need = max(3, int(previous.lines_used or 0) - 1)
    rec, short = None, None
    if np.unique(lab[lab >= 0]).size >= 3:
        # bars' midlines moved onto their centre lines under the previous frame's plane: one fit
        plane = None if previous.ambiguous else previous.normal
        rec = orient_segments(camera, segments, pencil, labels=lab, keep_lines=True, plane_normal=plane,
                              **orient_kwargs)
        if not (rec.ok and rec.lines_used >= need and _fits_its_labels(rec)):
            # a fit true to its labels on fewer lines than the previous frame's: the full
            # search decides, unless it explains no more lines (then its labelling is one of
            # several that fit a few lines alike, often shifted by a spoke: the prior's is kept)
            short = rec if rec.ok and _fits_its_labels(rec) else None
            rec = None
    if rec is None:
        full = orient_segments(camera, segments, pencil, keep_lines=keep_lines, **orient_kwargs)
        if short is None or (full.ok and full.lines_used > short.lines_used):
            return full, False
        rec = short
    rec = rec if keep_lines else rec.replace(lines=None)
    if rec.ambiguous and not previous.ambiguous:
        rec = resolve_twins_by_continuity([previous, rec])[1]
    return rec, True


def _fits_its_labels(rec):
    """Whether every labelled line lies within GATE_SIGMA sd of its spoke's image angle
    under the fitted orientation (a wrong label misses by far more)."""
    ln = rec.lines
    # the lines' target angles as fitted (a star's wedges as wide as printed), not the file's
    pred = image_angles(np.asarray(rec.R_cam_from_target, float), np.asarray(ln["vertex"], float),
                        np.asarray(ln["theta"], float))
    res = wrap_angle(np.asarray(ln["angle"], float) - pred)
    # lines, not directions: a straddling segment's angle is known modulo pi
    res = np.minimum(np.abs(res), np.abs(wrap_angle(res + np.pi)))
    return bool(np.all(res <= GATE_SIGMA * np.asarray(ln["sigma"], float)))

"""A rolling shutter's shear, undone with the previous frame's estimate.

A rolling-shutter camera reads its rows out one after the other: row y of a frame is
exposed `readout` * y / H frame intervals after row 0. While the camera moves, each
segment's end points were therefore seen at different times, and the fan's image is bent
by the image motion times the readout; a fit takes that bend for perspective (tilts off
by degrees at a few hundredths of a degree's sigma). An even shear is not enough: a
camera that turns moves the spokes' far ends many times faster than the vertex.

`deskewed_segments` moves each end point of a segment the previous frame's orientation
labels back to the time of the row through the vertex (the time the estimate refers to),
by its own image velocity across its spoke: its distance from the spoke's line as the
previous frame fitted it, over the time between the two (1 frame plus the rows' offset).
Only the motion across a spoke matters (along it, a point stays on its line), and that is
what two frames' lines measure, at every point along the spoke. The velocity's error
(the motion changing from frame to frame) is carried into each segment's offset and
angle sds (`VELOCITY_REL_SD`, `VELOCITY_FLOOR_PX`).

Where the readout is not known, nothing is moved: the fit's tilt and normal sigmas are widened
by how far the same moves for a readout anywhere from 0 to a whole frame would take its
estimate, and the estimate is left as it is. Where the moves take it is found by one linear
step of the fit from its own solution (`sheared_linear`: every labelled line's angle and the
lines' intersection moved as a whole frame's readout moves them; `orient_video_frame`'s
widening "linear", the default) or by fitting the frame once more from the moved lines
(`shear_widened`; widening "refit": a second vertex search, several times slower, no better
against the truth).

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.camera.model import Camera
>>> from pencilcal.toolkit.pencil.spec import Pencil
>>> from pencilcal.toolkit.pencil.orient import orient_segments
>>> cam = Camera("pinhole", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
>>> pen = Pencil(np.radians(np.arange(6) * 30.0))
>>> th = np.radians(np.arange(6) * 30.0 + 3.0)
>>> seg = np.c_[319.5 + 40 * np.cos(th), 239.5 + 40 * np.sin(th), 319.5 + 200 * np.cos(th), 239.5 + 200 * np.sin(th)]
>>> prev = orient_segments(cam, seg, pen)
>>> out = deskewed_segments(cam, seg, pen, prev, 0.0)
>>> bool(np.allclose(out[0], seg)), bool(np.all(out[2] == 0))
(True, True)
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.angles import wrap_line
from pencilcal.toolkit.geometry.frames import angle_between, rotation_from_rotvec
from pencilcal.toolkit.pencil.defaults import ENDPOINT_SIGMA_PX
from pencilcal.toolkit.pencil.estimator import pencil_jacobian
from pencilcal.toolkit.pencil.orient import orient_segments
from pencilcal.toolkit.pencil.spec import image_angles
from pencilcal.toolkit.pencil.track import orient_tracked, prior_labels
from pencilcal.toolkit.pencil.vertex import segment_angle_sigma

__all__ = ["orient_video_frame", "deskewed_segments", "camera_readout", "seen_lines", "shear_widened", "sheared_linear",
           "VELOCITY_REL_SD", "VELOCITY_FLOOR_PX", "UNKNOWN_READOUTS", "WIDENINGS"]

#: The sd of a point's velocity across its spoke, relative to it (the motion changes from
#: one frame to the next: a hand's swing starts and stops).
VELOCITY_REL_SD = 0.5
#: ... and its floor [px per frame] (the previous frame's lines' own noise).
VELOCITY_FLOOR_PX = 0.3
#: A readout not known: the readouts [frames] thought equally likely (0: a global shutter,
#: 1: rows read out over the whole frame interval).
UNKNOWN_READOUTS = np.linspace(0.0, 1.0, 21)
#: How a readout not known widens the sigmas (`orient_video_frame`'s widening): "linear"
#: (`sheared_linear`: one linear step of the first fit, the default) or "refit" (the frame
#: fitted again from its sheared lines: a second vertex search, slower, no better against
#: the truth).
WIDENINGS = ("linear", "refit")


def seen_lines(camera, segments, spokes, ideal=None):
    """{spoke label: (2, 2) normalised end points} of a frame's segments as seen (before any
    move), the longest of each label; spokes: (M,) the fit's labels (-1: none)."""
    seg = np.asarray(segments, float).reshape(-1, 4)
    lab = np.asarray(spokes, int).reshape(-1)[:len(seg)]
    if ideal is None:
        with np.errstate(invalid="ignore"):
            p = camera.normalized_from_pixels(seg.reshape(-1, 2)).reshape(-1, 2, 2)
    else:
        K = np.asarray(camera.K, float)
        p = np.linalg.solve(K[:2, :2], (np.asarray(ideal, float).reshape(-1, 2) - K[:2, 2]).T).T.reshape(-1, 2, 2)
    L = np.linalg.norm(p[:, 1] - p[:, 0], axis=-1)
    out = {}
    for m in np.argsort(-np.nan_to_num(L)):
        if m < len(lab) and lab[m] >= 0 and int(lab[m]) not in out and np.all(np.isfinite(p[m])) and L[m] > 0:
            out[int(lab[m])] = p[m]
    return out


def deskewed_segments(camera, segments, pencil, previous, readout, ideal=None, seen=None, still_px=0.0, labels=None):
    """(segments, ideal, offset_sd, angle_sd): the segments moved back to the time of the
    row through the vertex (module docstring).

    segments: (M, 4) raw px; previous: the previous frame's `Orientation` (``ok``) or None
    (then nothing moves); readout: the time from the first row's exposure to the last
    row's over the frame interval (0: a global shutter); ideal: (M, 4) the segments in
    undistorted px where known. Returns the moved segments (M, 4) raw px, the moved ideal
    segments (M, 4) undistorted px (None where ideal was None), and the sd each move adds
    to a segment's perpendicular offset at its midpoint (M,) [px] and to its angle (M,)
    [rad] (0 for segments not moved: unlabelled ones, or without a previous frame).
    still_px: a motion across the spoke up to this [px per frame] is taken for the lines'
    noise, not motion (each velocity shrunk towards 0 by it): a still camera moves nothing.
    labels: (M,) the segments' labels by the previous frame (`track.prior_labels` at its
    default gate) where known already (then not labelled again).
    """
    seg = np.asarray(segments, float).reshape(-1, 4)
    M = len(seg)
    zero = np.zeros(M)
    out_ideal = None if ideal is None else np.asarray(ideal, float).reshape(-1, 4).copy()
    if M == 0 or not readout or previous is None or not previous.ok or previous.ray is None:
        return seg.copy(), out_ideal, zero, zero
    ray = np.asarray(previous.ray, float)
    if not ray[2] > 0:
        return seg.copy(), out_ideal, zero, zero
    K = np.asarray(camera.K, float)
    f = float(np.sqrt(abs(K[0, 0] * K[1, 1])))
    lab = prior_labels(camera, seg, pencil, previous, ideal=ideal) if labels is None else np.asarray(labels)
    x0 = ray[:2] / ray[2]
    pred = image_angles(np.asarray(previous.R_cam_from_target, float), x0, pencil.edge_angles()[0])  # (N,)
    if ideal is None:
        with np.errstate(invalid="ignore"):
            p = camera.normalized_from_pixels(seg.reshape(-1, 2)).reshape(-1, 2, 2)
    else:
        p = np.linalg.solve(K[:2, :2], (out_ideal.reshape(-1, 2) - K[:2, 2]).T).T.reshape(-1, 2, 2)
    yv = float(camera.pixels_from_normalized(x0)[1])  # the vertex's row (it moves a few px a frame)
    H = float(camera.height)
    use = (lab >= 0) & np.all(np.isfinite(p.reshape(-1, 4)), -1)
    ang = pred[np.where(use, lab, 0)]
    n = np.stack([-np.sin(ang), np.cos(ang)], -1)  # (M, 2) across the spoke, normalised
    d = np.einsum("mjk,mk->mj", p - x0, n)  # (M, 2) each end's distance from last frame's line
    a = readout * (seg[:, [1, 3]] - yv) / H  # (M, 2) each end's time after the vertex row [frames]
    # seen 1 + a frames after the previous estimate's time: velocity d / (1 + a), moved back by a
    a = np.clip(a, -0.9, 0.9)
    v = d / (1.0 + a)  # (M, 2) [normalised per frame]
    if seen is not None:
        # against the previous frame's lines as seen (not as corrected): a point on one and the
        # same row was seen one frame apart in both, and an error of the previous estimate
        # cannot carry on into this one
        has = np.array([int(k) in seen for k in lab.tolist()], bool).reshape(-1) & use
        m = np.flatnonzero(has)
        if len(m):
            # all at once; stacked matmuls sum as the one-line products did (the same to the bit)
            q = np.array([seen[k] for k in lab[m].tolist()], float)  # (K, 2, 2)
            dq = q[:, 1] - q[:, 0]
            t = dq / np.sqrt(np.matmul(dq[:, None, :], dq[:, :, None])[:, 0])
            nm = np.stack([-t[:, 1], t[:, 0]], -1)
            n[m] = nm
            v[m] = np.matmul(p[m] - q[:, :1], nm[:, :, None])[..., 0]
        use = has
    if still_px > 0:
        v = np.sign(v) * np.maximum(np.abs(v) - still_px / f, 0.0)
    move = np.where(use[:, None], -v * a, 0.0)
    p2 = p + move[..., None] * n[:, None, :]
    moved = use[:, None] & (move != 0)  # (a point not moved keeps its pixels to the bit)
    new_raw = camera.pixels_from_normalized(p2.reshape(-1, 2)).reshape(-1, 4)
    out = np.where(np.repeat(moved, 2, -1), new_raw, seg)
    if out_ideal is not None:
        new_ideal = (p2.reshape(-1, 2) @ K[:2, :2].T + K[:2, 2]).reshape(-1, 4)
        out_ideal = np.where(np.repeat(moved, 2, -1), new_ideal, out_ideal)
    # one velocity error across the spoke for both ends: it shifts the midpoint by its mean
    # time and turns the segment by the difference over the length
    sv = VELOCITY_REL_SD * np.mean(np.abs(v), -1) * f + VELOCITY_FLOOR_PX  # (M,) [px per frame]
    L = np.linalg.norm(p[:, 1] - p[:, 0], axis=-1) * f
    off_sd = np.where(use, np.abs(a.mean(-1)) * sv, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        ang_sd = np.where(use & (L > 0), np.abs(a[:, 1] - a[:, 0]) * sv / L, 0.0)
    return out, out_ideal, off_sd, ang_sd


def shear_widened(record, sheared, readouts=UNKNOWN_READOUTS):
    """The `Orientation` `record` (a fit of a frame's lines as seen) with its tilt and normal
    sigmas widened by what a rolling shutter of unknown readout could have done to it; the
    estimate itself is left as it is.

    sheared: the same frame fitted once more from its lines moved back by a whole frame's
    readout (`deskewed_segments` with readout 1); None or not ok where that fit failed (then
    nothing is added). The normal and the vertex ray move with the shear, from the record's
    (readout 0) to the sheared fit's (readout 1): a readout r puts them r of the way along.
    The rms over `readouts` (K,) (the readouts thought equally likely) of the change of the
    tilt and of the normal from the record's is the sd added in quadrature to
    ``tilt_sigma_deg`` and ``normal_sigma_deg`` (and the totals); the added sds [deg] are
    kept as ``tilt_sigma_shutter_deg``, ``normal_sigma_shutter_deg``. Along that path the
    tilt may change less at readout 1 than between (the shear turning the normal about the
    ray): its rms is taken along the path, not from the ends.
    """
    if not record.ok or sheared is None or not sheared.ok or record.ray is None or sheared.ray is None:
        return record
    n0 = np.asarray(record.normal, float)
    # the sheared fit may have chosen the other of the twin normals: its change is the smaller
    n1 = min((np.asarray(n, float) for n in (sheared.normal, sheared.normal_twin) if n is not None),
             key=lambda n: float(angle_between(n0, n)))
    return _widened_along(record, n1, np.asarray(sheared.ray, float), readouts)


def _widened_along(record, n1, v1, readouts=UNKNOWN_READOUTS):
    """`record` widened by the path of its normal and ray to n1, v1 (3,) at readout 1
    (`shear_widened`)."""
    n0, v0 = np.asarray(record.normal, float), np.asarray(record.ray, float)
    r = np.asarray(readouts, float)[:, None]
    n = n0 + r * (n1 - n0)
    v = v0 + r * (v1 - v0)
    tilt = angle_between(n, v)  # (K,) [rad]: the tilt is the normal's angle from the vertex's ray
    dt = float(np.degrees(np.sqrt(np.mean((tilt - angle_between(n0, v0)) ** 2))))
    dn = float(np.degrees(np.sqrt(np.mean(angle_between(n, n0) ** 2))))
    ch = {"tilt_sigma_deg": float(np.hypot(record.tilt_sigma_deg, dt)),
          "normal_sigma_deg": float(np.hypot(record.normal_sigma_deg, dn)),
          "tilt_sigma_shutter_deg": dt, "normal_sigma_shutter_deg": dn}
    if record.tilt_sigma_total_deg is not None:
        ch["tilt_sigma_total_deg"] = float(np.hypot(record.tilt_sigma_total_deg, dt))
    if record.normal_sigma_total_deg is not None:
        ch["normal_sigma_total_deg"] = float(np.hypot(record.normal_sigma_total_deg, dn))
    return record.replace(**ch)


def sheared_linear(camera, record, pencil, segments, moved, ideal=None, moved_ideal=None, angle_sigma=None,
                   endpoint_sigma_px=ENDPOINT_SIGMA_PX):
    """(normal (3,), ray (3,)) where the fit `record` goes when its lines are moved from
    `segments` to `moved` (M, 4) raw px (`ideal`, `moved_ideal`: the same in undistorted px
    where known), to first order: one Gauss-Newton step of the fit's line angle residuals
    from the record's rotation, each labelled line's angle changed by its move and the
    vertex by the moved lines' weighted intersection's move (every labelled line kept, no
    vertex search, no labelling). None where fewer than three labelled lines remain.

    angle_sigma: None, scalar or (M,) [rad] the lines' angle sds (the fit's weights; None:
    the end point model's, `vertex.segment_angle_sigma`).
    """
    seg = np.asarray(segments, float).reshape(-1, 4)
    K = np.asarray(camera.K, float)
    A = K[:2, :2]

    def px(raw, ide):  # (M, 2, 2) undistorted px
        if ide is not None:
            return np.asarray(ide, float).reshape(-1, 2, 2)
        with np.errstate(invalid="ignore"):
            nrm = camera.normalized_from_pixels(np.asarray(raw, float).reshape(-1, 2))
        return (nrm @ A.T + K[:2, 2]).reshape(-1, 2, 2)

    p, q = px(seg, ideal), px(moved, moved_ideal)
    t = p[:, 1] - p[:, 0]
    L = np.linalg.norm(t, axis=-1)
    lab = np.asarray(record.spokes, int).reshape(-1)[:len(seg)]
    use = (lab >= 0) & np.all(np.isfinite(p.reshape(-1, 4)), -1) & np.all(np.isfinite(q.reshape(-1, 4)), -1) & (L > 0)
    if use.sum() < 3 or record.ray is None or not record.ray[2] > 0:
        return None
    if angle_sigma is None:
        with np.errstate(invalid="ignore", divide="ignore"):
            s = segment_angle_sigma(p.reshape(-1, 4), endpoint_sigma_px)
    else:
        s = np.broadcast_to(np.asarray(angle_sigma, float), (len(seg),))
    with np.errstate(invalid="ignore"):
        use &= np.isfinite(s) & (s > 0)  # (a line without a weight has no say)
    if use.sum() < 3:
        return None
    p, q, t, L, lab, s = p[use], q[use], t[use], L[use], lab[use], s[use]
    R0 = np.asarray(record.R_cam_from_target, float)
    ray = np.asarray(record.ray, float)
    x0 = ray[:2] / ray[2]
    # each line's angle as the fit labelled it: of its spoke's edges, the one the fit puts nearest
    edges, edge_spoke, _ = pencil.edge_angles()
    pred = image_angles(R0, x0, edges)  # (E,)
    a_p = np.arctan2(t[:, 1], t[:, 0])
    gap = np.abs(wrap_line(a_p[:, None] - pred[None, :]))
    gap = np.where(edge_spoke[None, :] == lab[:, None], gap, np.inf)
    th = edges[np.argmin(gap, -1)]
    tq = q[:, 1] - q[:, 0]
    da = wrap_line(np.arctan2(tq[:, 1], tq[:, 0]) - a_p)  # (N,) [rad] (px angles: square pixels)
    # the vertex: the lines' intersection, each weighted by its sd at the vertex (offset and
    # angle over the distance there); the same weights before and after the move
    nrm = np.stack([-t[:, 1], t[:, 0]], -1) / L[:, None]
    v_px = x0 @ A.T + K[:2, 2]
    dist = np.linalg.norm(0.5 * (p[:, 0] + p[:, 1]) - v_px, axis=-1)
    w_off = 1.0 / (0.5 * endpoint_sigma_px ** 2 + (dist * s) ** 2)
    Hx = np.einsum("n,ni,nj->ij", w_off, nrm, nrm)
    if not np.linalg.det(Hx) > 1e-12 * np.trace(Hx) ** 2:  # (lines all parallel: no vertex)
        return None
    nq = np.stack([-tq[:, 1], tq[:, 0]], -1) / np.linalg.norm(tq, axis=-1)[:, None]
    xp = np.linalg.solve(Hx, np.einsum("n,ni,n->i", w_off, nrm, np.einsum("ni,ni->n", nrm, p[:, 0])))
    Hq = np.einsum("n,ni,nj->ij", w_off, nq, nq)
    xq = np.linalg.solve(Hq, np.einsum("n,ni,n->i", w_off, nq, np.einsum("ni,ni->n", nq, q[:, 0])))
    dx = np.linalg.solve(A, xq - xp)  # (2,) normalised
    _, J, Jx = pencil_jacobian(R0, x0, th)  # (N, 3), (N, 2)
    w = 1.0 / s ** 2
    H = J.T @ (J * w[:, None])
    H += 1e-14 * np.trace(H) * np.eye(3)  # (zero tilt: the tilt's directions unobservable)
    delta = np.linalg.solve(H, J.T @ (w * (da - Jx @ dx)))
    v1 = np.append(x0 + dx, 1.0)
    return rotation_from_rotvec(delta) @ np.asarray(record.normal, float), v1 / np.linalg.norm(v1)


def orient_video_frame(camera, segments, pencil, previous, readout=None, seen=None, widening="linear",
                       **orient_kwargs):
    """(orientation, tracked): one frame of a video fitted with the previous frame's
    `Orientation` as a prior (`track.orient_tracked`), its rolling shutter handled:

    - readout > 0 (known; frames, 0-1): the segments moved back to the time of the row through
      the vertex (`deskewed_segments`), the moves' sds added to each segment's offset and
      angle sds (from the end point noise where the frame's lines have none);
    - readout None (not known): fitted as seen, the tilt and normal sigmas widened by what a
      readout from 0 to a whole frame could have done (where the fit goes from its lines moved
      by a whole frame's readout: `sheared_linear` with widening "linear", or `shear_widened`
      with "refit" (`WIDENINGS`); the estimate itself unchanged);
    - readout 0: a global shutter, fitted as seen.

    segments: (M, 4) raw px; previous: the previous frame's `Orientation` or None (the first
    frame, or after a frame with no orientation: nothing moved or widened); seen: the
    previous frame's lines as seen (`seen_lines`), for the velocities (None: the previous
    fit's spokes); orient_kwargs: `orient_segments`' (endpoint_sigma_px, angle_sigma,
    offset_sigma, angle_sigma_error, ideal, image, keep_lines, ...).

    Example
    -------
    >>> import numpy as np
    >>> from pencilcal.toolkit.camera.model import Camera
    >>> from pencilcal.toolkit.pencil.spec import Pencil
    >>> cam = Camera("pinhole", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
    >>> pen = Pencil(np.radians(np.arange(6) * 30.0))
    >>> th = np.radians(np.arange(6) * 30.0 + 3.0)
    >>> seg = np.c_[319.5 + 40 * np.cos(th), 239.5 + 40 * np.sin(th), 319.5 + 200 * np.cos(th), 239.5 + 200 * np.sin(th)]
    >>> first, _ = orient_video_frame(cam, seg, pen, None)
    >>> rec, tracked = orient_video_frame(cam, seg, pen, first, readout=0.0)
    >>> bool(rec.ok), bool(tracked)
    (True, True)
    """
    seg = np.asarray(segments, float).reshape(-1, 4)
    kw = dict(orient_kwargs)
    moving = previous is not None and len(seg) > 0
    if readout and moving:
        seg, kw = _deskewed_inputs(camera, seg, pencil, previous, readout, kw, seen)
    lab = None
    if readout is None and moving and "gate_deg" not in kw and previous.ok and previous.ray is not None:
        # the labels by the previous frame, once for the tracked fit and the widening's moves
        lab = prior_labels(camera, seg, pencil, previous, ideal=kw.get("ideal"))
    rec, tracked = orient_tracked(camera, seg, pencil, previous, prior_lab=lab, **kw)
    if readout is None and rec.ok and moving:
        rec = _widened_by_unknown_readout(camera, seg, pencil, previous, rec, kw, seen, widening, lab)
    return rec, tracked


def _deskewed_inputs(camera, seg, pencil, previous, readout, kw, seen):
    """(segments, orient kwargs) of a known readout (`orient_video_frame`)."""
    moved, ideal, off_sd, ang_sd = deskewed_segments(camera, seg, pencil, previous, readout, ideal=kw.get("ideal"),
                                                     seen=seen)
    kw = dict(kw, ideal=ideal)
    ideal_px = seg if ideal is None else ideal
    n = (len(ideal_px),)
    endpoint_sigma = kw.get("endpoint_sigma_px", ENDPOINT_SIGMA_PX)
    with np.errstate(invalid="ignore", divide="ignore"):
        # the end point model's sds of a segment: offset sigma / sqrt(2), angle sigma sqrt(2) / L
        off0 = np.broadcast_to(kw["offset_sigma"] if kw.get("offset_sigma") is not None
                               else endpoint_sigma / np.sqrt(2.0), n)
        ang0 = np.broadcast_to(kw["angle_sigma"] if kw.get("angle_sigma") is not None
                               else segment_angle_sigma(ideal_px, endpoint_sigma), n)
    kw["offset_sigma"] = np.hypot(np.asarray(off0, float), off_sd)
    kw["angle_sigma"] = np.hypot(np.asarray(ang0, float), ang_sd)
    if kw.get("angle_sigma_error") is not None:
        kw["angle_sigma_error"] = np.hypot(np.broadcast_to(kw["angle_sigma_error"], n), ang_sd)
    return moved, kw


def _widened_by_unknown_readout(camera, seg, pencil, previous, rec, kw, seen, widening, labels=None):
    """`rec` with its sigmas widened by a readout not known (`orient_video_frame`); a frame
    whose lines did not move beyond their noise keeps its sigmas. labels: the segments'
    labels by the previous frame where known (`deskewed_segments`)."""
    moved, ideal, _, _ = deskewed_segments(camera, seg, pencil, previous, 1.0, ideal=kw.get("ideal"), seen=seen,
                                           still_px=VELOCITY_FLOOR_PX, labels=labels)
    if np.array_equal(moved, seg):
        return rec
    if widening == "linear":  # (the fit's first-order move: no second vertex search, no labelling)
        out = sheared_linear(camera, rec, pencil, seg, moved, kw.get("ideal"), ideal, kw.get("angle_sigma"),
                             kw.get("endpoint_sigma_px", ENDPOINT_SIGMA_PX))
        return rec if out is None else _widened_along(rec, *out)
    # the fit's own labels (no labelling search: the same lines, only the shear differs; the
    # vertex is searched where the moved lines no longer meet within their sds), bars'
    # midlines under the previous frame's plane as the tracked fit puts them
    plane = None if previous.ambiguous else previous.normal
    # only its normals and ray are used: no lens-uncertainty totals, no lines kept
    sheared = orient_segments(camera, moved, pencil, labels=rec.spokes, plane_normal=plane,
                              **dict(kw, ideal=ideal, intrinsics_cov=None, keep_lines=False))
    return shear_widened(rec, sheared)


def camera_readout(camera, source="camera"):
    """The camera file's rolling-shutter readout (its ``readout`` key: the time from the first
    row's exposure to the last row's over the frame interval, 0-1), None without one (not known).
    Raises InputError naming `source` for a value that is no number in [0, 1]."""
    r = (camera.meta or {}).get("readout")
    if r is None:
        return None
    if isinstance(r, bool) or not isinstance(r, (int, float)) or not 0.0 <= float(r) <= 1.0:
        raise InputError(f"{source}: 'readout' must be a number from 0 to 1 (the rows' readout over the frame "
                         f"interval), got {r!r}")
    return float(r)

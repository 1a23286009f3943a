"""Orientation of a pencil from the raw segments of one frame: the whole pipeline.

``orient_segments`` turns line segments in raw (distorted) pixels into the `Orientation`
of one frame (a record of ``orientation.json``, docs/formats.md):

1. undistort the segment end points (lines, not images);
2. find the vertex: robust weighted intersection (vertex.intersect_lines) in ideal pixels,
   rejecting segments that do not pass through it;
3. orient each segment from the vertex outwards (a segment that straddles the vertex is a
   line with no direction);
4. label the segments with spokes (assign.assign_spokes), tolerating missing spokes and
   spurious segments, and fit the pencil (the exact estimator, or the chapter's general or
   aligned model), with the vertex covariance carried into the orientation; where the
   spokes are wedges or sector boundaries (the pencil file's ``shape``) the segments are
   their edges, each labelled with an edge (`spec.Pencil.edge_angles`) of its polarity;
5. choose between the twins where extra information allows: a prior rotation (a board
   pose, the previous frame), when the pencil file gives the spoke radii, the metric
   positions of the segment end points along the spokes, or the images of circles about
   the vertex (`circle`), which also give the plane a second time;
6. report in raw pixels and degrees.

Noise model: each end point has isotropic noise `endpoint_sigma_px` per coordinate, so a
segment of length L has angle sd sqrt(2) sigma / L and offset sd sigma / sqrt(2) at its
centre; a per-segment `angle_sigma` (e.g. from a line fit to edge pixels) overrides the
angle part.
"""
from __future__ import annotations

import warnings
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from pencilcal.toolkit.geometry.angles import wrap_angle
from pencilcal.toolkit.pencil.assign import assign_spokes, grow_labels
from pencilcal.toolkit.pencil.bar_centre import centre_lines
from pencilcal.toolkit.pencil.bend import CYLINDER_SHAPE, bend_covariance, circle_bend_response
from pencilcal.toolkit.pencil.circle import circle_record
from pencilcal.toolkit.pencil.confirm import unconfirmed_labelling
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.pencil.estimator import (
    detection_threshold,
    fit_pencil,
    pencil_covariance,
    swap_twins,
    choose_by_prior,
)
from pencilcal.toolkit.geometry.frames import normalize, rotation_angle, rotation_from_rotvec, skew
from pencilcal.toolkit.geometry.quantiles import nanmedian_rows
from pencilcal.toolkit.pencil.defaults import DETECTION_LEVEL, ENDPOINT_SIGMA_PX
from pencilcal.toolkit.pencil.lens_uncertainty import orientation_totals, resolve_intrinsics_cov
from pencilcal.toolkit.pencil.orientation import Orientation
from pencilcal.toolkit.pencil.spec import image_angles
from pencilcal.toolkit.pencil.vertex import LOCAL_CANDIDATES, floored_vertex_cov, intersect_lines, lines_through

__all__ = ["orient_segments", "orientation_record", "raw_vertex", "MODELS", "MAX_SEGMENTS", "PLANE_PRIOR_DEG",
           "metric_depth", "resolve_twins_by_continuity"]

MODELS = ("exact", "general", "aligned")

# Segments shorter than this carry almost no angle information and are mostly noise.
MIN_LENGTH_PX = 8.0
#: A vertex is ambiguous when the best other vertex found (through other lines, vertex.VertexFit
#: rival_gain) has MSAC evidence within this of its own: the chi-square(2) quantile at the
#: detection level, Bonferroni-corrected for the candidate vertices compared (the rival is
#: the best of them: in clutter, random segments meet about as well in many places).
VERTEX_RIVAL_CHI2 = -2.0 * np.log(DETECTION_LEVEL / LOCAL_CANDIDATES)
#: Most segments of one frame that are used, the longest (`orient_segments`' max_segments,
#: `pencilcal orient --max-segments`). A pencil has tens of lines; a detector gives a few
#: thousand on a busy image; past this the frame is mostly other edges, the shortest of
#: which say least about any vertex, and the work (vertex hypotheses x segments) grows.
MAX_SEGMENTS = 20000
#: `orient_segments`' plane_normal is kept when the fit's normal lies within this of it [deg].
PLANE_PRIOR_DEG = 5.0


def metric_depth(R_cam_from_target, vertex, spoke_angles, inner, outer, radius):
    """Depth of the vertex and the fit of known spoke radii, for one candidate rotation.

    A point at distance r along spoke k images at signed distance
    ``t = r |w_k| / (z + r d_kz)`` from the vertex along w_k (normalised coordinates, z the
    vertex depth, d_k the spoke's camera-frame direction). With the inner and outer end of
    each spoke seen, z follows by least squares, and the residual tells the twins apart:
    they image the lines identically but foreshorten lengths differently.

    R_cam_from_target: (..., 3, 3); vertex: (2,) normalised; spoke_angles: (..., K) [rad]
    of the assigned segments; inner, outer: (K, 2) normalised image of their end points
    nearer to and farther from the vertex; radius: (2,) [inner, outer] in length units, the
    same for every spoke, or (K, 2) per segment (e.g. board corners at known distances).
    Returns (depth (...), residuals (..., 2K) in normalised units); depth is NaN and the
    residuals inf where the data do not support a positive depth.
    """
    R = np.asarray(R_cam_from_target, float)
    th = np.asarray(spoke_angles, float)
    d = np.einsum("...ij,...jk->...ki", R[..., :, :2], np.stack([np.cos(th), np.sin(th)], -2))  # (..., K, 3)
    x = np.asarray(vertex, float)
    w = d[..., :2] - x * d[..., 2:3]
    c = np.linalg.norm(w, axis=-1)
    u = w / c[..., None]
    t = np.concatenate([np.sum((inner - x) * u, -1), np.sum((outer - x) * u, -1)], -1)
    K = th.shape[-1]
    rad = np.broadcast_to(np.asarray(radius, float), (K, 2))
    r = np.concatenate([rad[:, 0], rad[:, 1]])
    cc = np.concatenate([c, c], -1)
    dz = np.concatenate([d[..., 2], d[..., 2]], -1)
    ok = t > 0
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # no positive distance: NaN, caught below
        # per-point depth estimates, then Gauss-Newton on the image distances
        z = nanmedian_rows(np.where(ok, r * (cc / np.where(ok, t, 1.0) - dz), np.nan))  # np.nanmedian's, bit for bit
        for _ in range(8):
            den = z[..., None] + r * dz
            pred = r * cc / den
            J = -r * cc / den**2
            z = z + np.sum(J * (t - pred), -1) / np.maximum(np.sum(J * J, -1), 1e-300)
        den = z[..., None] + r * dz
        res = t - r * cc / den
    bad = (ok.sum(-1) < 2) | ~np.isfinite(z) | (z <= 0) | np.any(den <= 0, -1)
    z = np.where(bad, np.nan, z)
    res = np.where(bad[..., None], np.inf, res)
    if z.ndim == 0:
        return float(z), res
    return z, res


def _segment_geometry(camera, segments, endpoint_sigma_px, ideal=None):
    """Ideal-pixel segments and the local scale raw -> ideal at each; `ideal` (M, 4): the
    segments in ideal pixels where known already (then the scale at their centres)."""
    seg = np.asarray(segments, float)
    # the local linear scale of the undistortion at each segment centre: end point noise
    # in raw pixels becomes noise in ideal pixels scaled by it (the ends and the centres
    # undistorted together: one inversion of the lens model instead of two)
    M = seg.shape[0]
    K2 = np.asarray(camera.K, float)[:2, :2]
    if ideal is None:
        centre = 0.5 * (seg[:, :2] + seg[:, 2:])
        xy_all, ideal_all = camera.normalized_and_ideal(np.concatenate([seg.reshape(-1, 2), centre]))
        ideal, xy = ideal_all[:2 * M].reshape(-1, 4), xy_all[2 * M:]
    else:  # no inversion of the lens model: the centre's ray from its ideal pixel
        ideal = np.asarray(ideal, float).reshape(-1, 4)
        xy = np.linalg.solve(K2, (0.5 * (ideal[:, :2] + ideal[:, 2:]) - np.asarray(camera.K, float)[:2, 2]).T).T
    with np.errstate(invalid="ignore"):  # NaN beyond the lens model's reach: dropped by the caller
        Jpn = camera.jacobian_pixels_from_normalized(xy)  # d raw / d normalised
        J_ideal_from_raw = K2 @ np.linalg.inv(Jpn)
        scale = np.sqrt(np.abs(np.linalg.det(J_ideal_from_raw)))
    return ideal, scale


def orient_segments(camera, segments, pencil, *, model="exact", endpoint_sigma_px=ENDPOINT_SIGMA_PX, angle_sigma=None,
                    prior=None, vertex_px=None, vertex_cov_px2=None, image=None, labels=None, keep_lines=False,
                    offset_sigma=None, spoke_radii=None, max_segments=MAX_SEGMENTS, intrinsics_cov="camera",
                    bar_width_px=None, circle_points=None, plane_normal=None, ideal=None, angle_sigma_error=None,
                    vertex_floor_px=None):
    """Orientation of a pencil seen in one frame.

    camera: a Camera; segments: (M, 4) raw pixels [x1, y1, x2, y2]; pencil: a Pencil.
    model: "exact" (default), "general" or "aligned" (the chapter's models, for comparison).
    endpoint_sigma_px: noise of each end point per coordinate [px].
    angle_sigma: None, scalar or (M,) [rad] angle sd of each segment in pixels (e.g. from
        a line fit to edge pixels; overrides the end point model for the angle).
    offset_sigma: None, scalar or (M,) [px] sd of each segment's perpendicular position at
        its midpoint (overrides the end point model for the offset).
    angle_sigma_error: None, scalar or (M,) [rad] with angle_sigma, each segment's angle sd
        with errors its angle_sigma leaves out (a star's edges turned by what they share:
        `detect.radial`'s ``angle_sigma_error``), never under angle_sigma: for the
        covariance only. The labelling, the twin and the fit keep angle_sigma's weights; the
        sigmas reported are those of that fit under errors of these sds
        (`estimator.pencil_covariance`'s sigma_error), and ``lines`` keeps them (``sigma_error``).
    vertex_floor_px: None or the sd [undistorted px] of the point the segments were located
        about (`detect.radial`'s ``vertex_sd``): edges located about a point lean towards it,
        and meet there more surely than the point was known; the vertex's covariance is
        reported no narrower than this sd (per axis, its variance halved), and the sigmas
        with it. For the covariance only: the fit and its decisions keep the intersection's.
    spoke_radii: (M, 2) distances from the vertex [length unit] of each segment's inner and
        outer end, when known per segment (board corners); else the pencil's radius.
    prior: (3, 3) R_cam_from_target known roughly (board pose, previous frame): picks the twin.
    vertex_px, vertex_cov_px2: a known vertex in raw pixels (e.g. a fulcrum) and its
        covariance, instead of intersecting the segments.
    image: name stored in the record.
    labels: (M,) spoke index of every segment when it is known (e.g. board grid lines
        through a corner), -1 to ignore one; skips the assignment. For wedges and sector
        boundaries, the index of its edge in the pencil's `edge_angles`.
    keep_lines: also return ``lines``: the used lines in normalised coordinates
        (``angle`` and ``sigma`` [rad], ``spoke`` index, ``segment`` index), for experiments;
        for wedges and sector boundaries ``spoke`` is the index of the edge in the pencil's
        `edge_angles` (as `labels` is); ``theta`` [rad] each line's target angle in the fit
        (a star's wedges as wide as the lines say they were printed: `_printed_wedge`);
        ``sigma_error`` [rad] with angle_sigma_error, the sds the covariance takes.
    intrinsics_cov: the intrinsics' covariance to propagate into the totals
        (``tilt_sigma_total_deg``, ``normal_sigma_total_deg``, ``vertex_cov_total_px2``;
        `lens_uncertainty`): "camera" (default) the one the camera file carries, if any;
        None none; or a (P, P) array / `IntrinsicsCovariance`.
    max_segments: use at most this many segments, the longest (the others get spoke -1):
        memory and time then stay bounded whatever the frame holds.
    bar_width_px: (M,) [undistorted px] when the segments are the midlines of printed bars
        (`detect.bars`' width_px; NaN for a segment that is no bar): once the frame is
        fitted and its twin chosen, the midlines are moved onto the images of the bars'
        centre lines on the fitted plane (`bar_centre.centre_lines`: under perspective a
        bar's midline sits w^2 / (4 V) off them, towards the horizon) and the frame is
        fitted again with the same labels. A frame whose twin is left open keeps its
        first fit (the two twins' horizons lie on opposite sides).
    circle_points: (K, 2) raw px edge points of which some may lie on the images of circles
        centred on the vertex (`detect.radial`'s ``circle_points``): grouped into circles
        by their radius on the plane, each fitted with an ellipse whose polar of the vertex
        gives the plane's normal (`circle.circle_estimate`). That normal chooses the twin
        (``resolved_by: "circle"``) and is reported beside the lines' (``circle_normal``,
        its sigma, and whether the two agree within them); with the circles' radii in the
        pencil file, the vertex's depth too.
    plane_normal: (3,) with bar_width_px, the plane's unit normal known already (a video's
        previous frame): the midlines are moved onto the centre lines under it and the frame
        is fitted once, kept if its normal lies within `PLANE_PRIOR_DEG` of the one given
        (the move is w^2 / (4 V), a few hundredths of a pixel: a degree off changes it by
        far less than its noise); else the two fits above.
    ideal: (M, 4) the segments in undistorted pixels where the detector has them already
        (`detect.lines`' record with ideal): not undistorted again (each segment's noise
        scale then taken at its ideal centre rather than at its raw centre's image, which
        lies off the straight segment by its curvature's sagitta).

    Returns an `Orientation` (its ``to_dict()`` is the orientation.json record) with
    ``spokes`` (label per input segment, -1 rejected; the wedge or boundary an edge belongs
    to), ``spokes_used`` (the spokes with a line in the fit), ``labels_ambiguous``,
    ``resolved_by``, ``ray``, ``tilt_threshold_deg`` and, when the spoke radii resolve the
    twin, ``vertex_cam`` (and ``t_cam_from_target`` if the pencil file gives the vertex).
    A frame with no estimate has ``ok`` false and ``error``.
    """
    kw = dict(model=model, endpoint_sigma_px=endpoint_sigma_px, angle_sigma=angle_sigma, prior=prior,
              vertex_px=vertex_px, vertex_cov_px2=vertex_cov_px2, image=image, labels=labels, keep_lines=keep_lines,
              offset_sigma=offset_sigma, spoke_radii=spoke_radii, max_segments=max_segments,
              intrinsics_cov=intrinsics_cov, circle_points=circle_points, angle_sigma_error=angle_sigma_error,
              vertex_floor_px=vertex_floor_px)

    def centred(normal):  # (raw, ideal) moved onto the centre lines
        moved = centre_lines(camera, segments, bar_width_px, normal, ideal=ideal)
        return moved if ideal is not None else (moved, None)

    if bar_width_px is not None and plane_normal is not None:
        n = np.asarray(plane_normal, float)
        rec = _orient_once(camera, *centred(n), pencil, **kw)
        if rec.ok and not rec.ambiguous and np.dot(rec.normal, n) >= np.cos(np.radians(PLANE_PRIOR_DEG)):
            return rec
    rec = _orient_once(camera, segments, ideal, pencil, **kw)
    if bar_width_px is None or not rec.ok or rec.ambiguous:
        return rec
    again = _orient_once(camera, *centred(rec.normal), pencil, **dict(kw, labels=rec.spokes))
    if not again.ok:
        return rec
    # the labelling's own ambiguities are the first fit's (the second one is given the labels)
    return again.replace(labels_ambiguous=rec.labels_ambiguous, normal_ambiguous=rec.normal_ambiguous,
                         normal_alternatives=rec.normal_alternatives)


def _orient_once(camera, segments, ideal, pencil, *, model, endpoint_sigma_px, angle_sigma, prior, vertex_px,
                 vertex_cov_px2, image, labels, keep_lines, offset_sigma, spoke_radii, max_segments, intrinsics_cov,
                 circle_points, angle_sigma_error=None, vertex_floor_px=None):
    """One fit of `orient_segments` (its arguments but bar_width_px; ideal may be None)."""
    if model not in MODELS:
        raise InputError(f"unknown model {model!r}; expected one of {', '.join(MODELS)}")
    if isinstance(max_segments, bool) or not isinstance(max_segments, (int, np.integer)) or max_segments < 3:
        raise InputError(f"max_segments must be an integer >= 3 (three lines are needed), got {max_segments!r}")
    seg = np.asarray(segments, float).reshape(-1, 4)
    labels_out = np.full(seg.shape[0], -1)
    try:
        idx, ideal, st, sc, sig_e = _usable_lines(camera, seg, endpoint_sigma_px, angle_sigma, offset_sigma,
                                                  max_segments, ideal)
        widen = _error_ratio(angle_sigma_error, seg.shape[0], idx, st)
        known = None if labels is None else np.asarray(labels, int).reshape(-1)[idx] >= 0
        v_ideal, cov_ideal, through = _vertex(camera, ideal, st, sc, pencil, vertex_px, vertex_cov_px2, known)
        idx, ideal, st = idx[through], ideal[through], st[through]
        widen = None if widen is None else widen[through]
        if idx.size < 3:
            raise EstimationError(f"only {idx.size} segments pass through the vertex; three are needed")
        ln = _normalised_lines(camera, ideal, st, v_ideal, cov_ideal)
        # end point noise in normalised units, for the metric use of the spoke radii
        A = np.linalg.inv(np.asarray(camera.K, float))[:2, :2]
        sigma_metric = np.sqrt(np.mean(sig_e[through] ** 2)) * np.sqrt(abs(np.linalg.det(A)))
        lab, fit, rivals, labels_ambiguous = _label_and_fit(ln, pencil, labels, idx, sigma_metric)
        # what the search itself labelled: growing confirms nothing, so the refusal of an
        # unconfirmed labelling counts these spokes, not the grown ones
        searched = pencil.edge_angles()[1][lab[lab >= 0]]
        if pencil.shape == "wedge":
            # a star's edges lie closer than its lines' model error allows the search to label
            # them: the labelling grows (`_grown`); then the wedges as wide as printed, and
            # labelled again (grown from the labels as they are; given labels: fitted again),
            # tracked frames too (their labels the previous frame's)
            if labels is None:
                lab, fit = _grown(ln, pencil, lab)
            for _ in range(WEDGE_ROUNDS):
                wider = _printed_wedge(ln, pencil, lab, fit)
                if wider is pencil:
                    break
                pencil = wider
                if labels is None:
                    lab, fit = _grown(ln, pencil, lab)
                else:
                    lab, fit, rivals, labels_ambiguous = _label_and_fit(ln, pencil, labels, idx, sigma_metric)
        used = lab >= 0
        edge_angles, edge_spoke, _ = pencil.edge_angles()
        th_used, a_used, s_used = edge_angles[lab[used]], ln.angle[used], ln.sigma[used]
        if model != "exact":
            fit = _chapter_fit(model, a_used, th_used, ln.vertex, s_used, ln.vertex_cov, fit)
        fit = _point_spokes_outwards(fit, ln, used, th_used, a_used)
        radius = _spoke_radius(pencil) if spoke_radii is None else \
            np.asarray(spoke_radii, float).reshape(-1, 2)[idx][used]
        fit, resolved_by, metric = _resolve_twins(fit, ln, used, th_used, s_used, prior, radius, sigma_metric)
        fit, resolved_by, circ = _resolve_by_circles(camera, fit, ln, th_used, s_used, resolved_by, circle_points,
                                                     pencil)
        s_err = None if widen is None else s_used * widen[used]
        bend, sheet = None, {}
        if pencil.shape != "line":  # a printed radial target: its sheet's bend turns every spoke alike
            bend, q, tau2, scale, M_bend = bend_covariance(fit.R_cam_from_target, ln.vertex, th_used, a_used,
                                                           s_used, ln.p1[used], ln.p2[used],
                                                           sc[through][used] * np.sqrt(abs(np.linalg.det(A))), s_err)
            bend = bend if tau2 > 0 else None
            if scale > 1.0:  # the misfit the bend leaves: the lines' errors wider than their sds
                s_err = (s_used if s_err is None else s_err) * np.sqrt(scale)
            sheet = dict(bend_chi2=q, bend_taken=tau2 > 0, misfit_scale=scale)
        own = None if circ is None else _lines_own(fit, ln, a_used, th_used, s_used, s_err)
        shared = None if circ is None or bend is None else _bend_on_circles(fit, circ, ln.vertex, tau2, M_bend)
        circles = None if circ is None else circle_record(fit, circ, own, ln.vertex_cov, shared)
        if labels is None:  # (given labels, a tracked frame's, passed the previous frame's tests)
            unconfirmed_labelling(pencil, searched, resolved_by, circle_points, circ,
                                  None if circles is None else circles["circle_consistent"],
                                  edge_spoke[lab[used]])
        # rival labellings that put the normal elsewhere make the normal itself ambiguous
        # (within the weighted fit's sigmas, as the labelling saw them)
        alt = _rival_normals(fit, rivals)
        floored = floored_vertex_cov(cov_ideal, vertex_floor_px)
        if floored is not None:  # every decision taken: the vertex no surer than the point it was found about
            cov_ideal, ln = floored, ln._replace(vertex_cov=_normalised_cov(camera, floored))
        if s_err is not None or floored is not None or bend is not None:  # the covariance under the wider errors
            cov, s_tilt, s_norm = pencil_covariance(fit.R_cam_from_target, ln.vertex, th_used, s_used, ln.vertex_cov,
                                                    sigma_error=s_err, shared_cov=bend)
            fit = replace(fit, cov=cov, tilt_sigma=s_tilt, normal_sigma=s_norm)
        labels_out[idx] = np.where(used, edge_spoke[np.maximum(lab, 0)], -1)
        s_mean = float(np.sqrt(np.mean(s_used**2)))
        rec = orientation_record(camera, fit, ln.vertex, v_ideal, cov_ideal, model=model, image=image,
                                 sigma_mean=s_mean, resolved_by=resolved_by)
        C = resolve_intrinsics_cov(camera, intrinsics_cov)
        if C is not None:
            rec = rec.replace(**orientation_totals(
                camera, C, fit.R_cam_from_target, ln.vertex, fit.cov, rec.tilt_sigma_deg, rec.vertex_cov_px2,
                seg[idx[used]], a_used, th_used, s_used, seg[idx], st, sc[through], vertex_px))
        extra = dict(sheet, labels_ambiguous=bool(labels_ambiguous), normal_ambiguous=bool(alt),
                     normal_alternatives=alt or None, spokes=labels_out,
                     spokes_used=int(np.unique(edge_spoke[lab[used]]).size))
        if keep_lines:
            extra["lines"] = {"angle": a_used, "sigma": s_used, "spoke": lab[used], "segment": idx[used],
                              "theta": th_used,
                              "vertex": ln.vertex, "vertex_cov": ln.vertex_cov}
            if s_err is not None:
                extra["lines"]["sigma_error"] = s_err
            if bend is not None:
                extra["lines"]["bend_cov"] = bend
        if metric is not None and resolved_by is not None:
            extra.update(_metric_position(fit, metric, resolved_by, ln.vertex, pencil))
        if circles is not None:
            extra.update(circles)
            if circ.depth is not None and resolved_by is not None and "vertex_cam" not in extra:
                extra.update(_vertex_position(fit, circ.depth, ln.vertex, pencil))
        return rec.replace(**extra)
    except EstimationError as e:
        return Orientation(image=image, ok=False, error=str(e), model=model, spokes=labels_out)


def _usable_lines(camera, seg, endpoint_sigma_px, angle_sigma, offset_sigma, max_segments=MAX_SEGMENTS, ideal=None):
    """The segments worth fitting, undistorted, with their noise.

    seg: (M, 4) raw px (ideal: the same in ideal px, or None). Returns idx (K,) indices
    into seg, ideal (K, 4) ideal px, angle sd st (K,) [rad] and offset sd sc (K,) [ideal
    px] of each, and sig_e (K,) the end point noise in ideal px; K <= max_segments, the
    longest. EstimationError when fewer than three remain.
    """
    M = seg.shape[0]
    finite = np.all(np.isfinite(seg), -1)
    with np.errstate(invalid="ignore"):
        length = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])
    usable = finite & (length >= MIN_LENGTH_PX)
    if usable.sum() < 3:
        bad = int((~finite).sum())
        why = f" ({bad} not finite)" if bad else ""
        raise EstimationError(f"fewer than three usable segments{why}: {int(usable.sum())} of {M}")
    idx = np.flatnonzero(usable)
    if idx.size > max_segments:
        # the longest, in their input order (a stable sort keeps ties in order)
        idx = np.sort(idx[np.argsort(-length[idx], kind="stable")[:max_segments]])
    ideal, scale = _segment_geometry(camera, seg[idx], endpoint_sigma_px,
                                     None if ideal is None else np.asarray(ideal, float).reshape(-1, 4)[idx])
    ok = np.all(np.isfinite(ideal), -1)
    idx, ideal, scale = idx[ok], ideal[ok], scale[ok]
    if idx.size < 3:
        raise EstimationError("fewer than three segments could be undistorted (outside the lens model's range)")
    L = np.hypot(ideal[:, 2] - ideal[:, 0], ideal[:, 3] - ideal[:, 1])
    sig_e = endpoint_sigma_px * scale  # end point noise in ideal pixels
    if angle_sigma is None:
        st = np.sqrt(2.0) * sig_e / L
    else:
        st = np.broadcast_to(np.asarray(angle_sigma, float), (M,))[idx]
        if np.any(~np.isfinite(st) | (st <= 0)):
            raise InputError("angle sigma must be positive and finite")
    if offset_sigma is None:
        sc = sig_e / np.sqrt(2.0)
    else:
        sc = np.broadcast_to(np.asarray(offset_sigma, float), (M,))[idx] * scale
        if np.any(~np.isfinite(sc) | (sc <= 0)):
            raise InputError("offset sigma must be positive and finite")
    return idx, ideal, st, sc, sig_e


def _error_ratio(angle_sigma_error, M, idx, st):
    """(K,) each used segment's angle_sigma_error (None, scalar or (M,) [rad]) over its angle
    sd st (K,) [rad], at least 1; None without them or where none is wider (the covariance
    then the fit's own, bit for bit)."""
    if angle_sigma_error is None:
        return None
    err = np.asarray(angle_sigma_error, float)
    if err.ndim > 1 or err.size not in (1, M):
        raise InputError(f"angle sigma error: one per segment ({M}) or one for all, got {err.size}")
    err = np.broadcast_to(err.reshape(-1), (M,))[idx]
    if np.any(~np.isfinite(err) | (err <= 0)):
        raise InputError("angle sigma error must be positive and finite")
    ratio = np.maximum(err / st, 1.0)
    return ratio if np.any(ratio > 1.0) else None


def _vertex(camera, ideal, st, sc, pencil, vertex_px, vertex_cov_px2, known=None):
    """The vertex in ideal px, its covariance, and which lines (K,) pass through it: the
    given vertex (raw px) when there is one, else the lines' robust intersection (refined
    from the lines `known` (K,) bool to be spokes, where three or more are: labelled)."""
    if vertex_px is None:
        start = known if known is not None and np.count_nonzero(known) >= 3 else None
        return _find_vertex(ideal, st, sc, _spoke_radius(pencil), start=start)
    K = np.asarray(camera.K, float)
    v_ideal = camera.undistort_pixels(np.asarray(vertex_px, float))
    J = np.linalg.inv(camera.jacobian_pixels_from_normalized(camera.normalized_from_pixels(vertex_px)))
    C = np.zeros((2, 2)) if vertex_cov_px2 is None else np.asarray(vertex_cov_px2, float)
    cov_ideal = (K[:2, :2] @ J) @ C @ (K[:2, :2] @ J).T
    # only the segments that pass through it (and, with spoke radii, reach close
    # enough to it) are the pencil's: the others are other edges of the scene
    _, through = lines_through(v_ideal, ideal, st, sc, cov_ideal)
    if _spoke_radius(pencil) is not None:
        through &= _radius_consistent(ideal, pencil.radius)(v_ideal[None])[0]
    return v_ideal, cov_ideal, through


def _spoke_radius(pencil):
    """The spokes' [inner, outer] radius where the segments run between them: a fan of
    lines or bars. A wedge's or a boundary's edge is measured where it is clear of its
    neighbours (far out on a dense star), not from the printed inner radius: None."""
    return pencil.radius if pencil.shape == "line" else None


class _Lines(NamedTuple):
    """The pencil's lines in normalised coordinates, oriented away from the vertex."""

    vertex: np.ndarray      # (2,) the vertex
    vertex_cov: np.ndarray  # (2, 2)
    p1: np.ndarray          # (K, 2) end points
    p2: np.ndarray          # (K, 2)
    angle: np.ndarray       # (K,) [rad] direction away from the vertex
    sigma: np.ndarray       # (K,) [rad] angle sd
    straddle: np.ndarray    # (K,) bool: the segment runs over the vertex (no direction)
    kind: np.ndarray        # (K,) +1 / -1: an edge segment brighter towards larger / smaller angles


def _normalised_cov(camera, cov_ideal):
    """A covariance (2, 2) of a point in undistorted px^2 -> normalised coordinates."""
    A = np.linalg.inv(np.asarray(camera.K, float))[:2, :2]
    return A @ cov_ideal @ A.T


def _normalised_lines(camera, ideal, st, v_ideal, cov_ideal):
    """Ideal-pixel lines (K, 4) with angle sd st (K,) [rad] and the vertex (2,) with its
    covariance (2, 2) [px^2] -> `_Lines` in normalised coordinates."""
    Kinv = np.linalg.inv(np.asarray(camera.K, float))
    A = Kinv[:2, :2]
    x = Kinv[:2, :2] @ v_ideal + Kinv[:2, 2]
    cov_x = _normalised_cov(camera, cov_ideal)
    p1 = ideal[:, :2] @ A.T + Kinv[:2, 2]
    p2 = ideal[:, 2:] @ A.T + Kinv[:2, 2]
    t = normalize(np.concatenate([p2 - p1, np.zeros((len(p1), 1))], -1))[:, :2]
    # angle sd in normalised coordinates: a linear map A scales angles by det(A)/|A t|^2
    t_ideal = normalize(np.concatenate([ideal[:, 2:] - ideal[:, :2], np.zeros((len(p1), 1))], -1))[:, :2]
    gain = abs(np.linalg.det(A)) / np.sum((t_ideal @ A.T) ** 2, -1)
    s_n = st * gain
    # orient each segment away from the vertex; a segment over the vertex has no direction
    s1, s2 = np.sum((p1 - x) * t, -1), np.sum((p2 - x) * t, -1)
    away = np.where(np.abs(s2) >= np.abs(s1), 1.0, -1.0)
    straddle = (s1 * s2) < 0
    a = np.arctan2(t[:, 1] * away, t[:, 0] * away)
    # an edge segment is brighter along n = (-d_y, d_x), its direction turned by +90 deg:
    # towards larger angles when it runs away from the vertex
    return _Lines(x, cov_x, p1, p2, a, s_n, straddle, away.astype(int))


#: A star's wedges are measured as printed (`_printed_wedge`) in at most this many rounds of
#: labelling again, each from the last one's fit, over widths of WEDGE_RANGE times the
#: file's (on WEDGE_GRID of them, then a parabola through the best three); a width that
#: lowers the lines' chi2 by less than WEDGE_CHI2 (3 sds of one parameter's chi2(1)) is none.
WEDGE_ROUNDS, WEDGE_RANGE, WEDGE_GRID, WEDGE_CHI2 = 2, (0.6, 1.4), 41, 9.0


def _printed_wedge(ln, pencil, lab, fit):
    """The pencil with its wedges as wide as the lines say (shape "wedge"), or `pencil`
    itself where they say nothing different.

    Ink spreads on paper (dot gain) or is eaten away: a printed star's dark wedges are wider
    or narrower than the light ones by the same distance along every edge, and its edges, as
    measured, come out turned the same way for every wedge, as a wider or narrower wedge
    would (on a photograph-like render with 0.06 mm eaten away, 2.72 deg fitted for the
    file's 2.81; exact lines of a wider or narrower wedge the rotation absorbs, so what turns
    them is in their measurement: unequal dark and light widths change how neighbouring
    blurred edges overlap). A fit at the file's width turns the rotation to absorb what it
    can; the labelling then leaves out the sectors where it cannot, and a width fitted to the
    lines it kept is the file's again. So every line through the vertex is read as the edge
    the first fit predicts nearest to it (within a quarter of the gap to the next), and the
    pencil fitted with those labels at each width of WEDGE_RANGE times the file's at once
    (one batch of the exact estimator); the width of least chi2 is kept where it lowers the
    chi2 by WEDGE_CHI2 or more."""
    if np.count_nonzero(lab >= 0) < 8:
        return pencil
    angles, _, _ = pencil.edge_angles()
    R, x = fit.R_cam_from_target, ln.vertex
    order = np.argsort(angles)
    gaps = np.diff(np.r_[angles[order], angles[order[0]] + 2 * np.pi])
    near = np.minimum(gaps, np.roll(gaps, 1))[np.argsort(order)]  # each edge's nearest neighbour [rad]
    pred = image_angles(R, x, angles)
    d = np.remainder(ln.angle[:, None] - pred[None] + 0.5 * np.pi, np.pi) - 0.5 * np.pi
    j = np.argmin(np.abs(d), 1)
    eps = 1e-4
    slope = wrap_angle(image_angles(R, x, angles + eps) - image_angles(R, x, angles - eps)) / (2 * eps)
    keep = np.abs(d[np.arange(j.size), j] / slope[j]) < 0.25 * near[j]
    if np.count_nonzero(keep) < 8:
        return pencil
    j, a, sig = j[keep], ln.angle[keep], ln.sigma[keep]
    widths = pencil.wedge * np.linspace(*WEDGE_RANGE, WEDGE_GRID)
    side = np.where(j < pencil.count, -0.5, 0.5)  # theta_k -+ wedge / 2 (`edge_angles`)
    th = pencil.angles[j % pencil.count][None] + side[None] * widths[:, None]
    oriented = not np.any(ln.straddle)
    try:
        chi2 = np.asarray(fit_pencil(np.broadcast_to(a, th.shape), th, np.broadcast_to(x, (widths.size, 2)),
                                     sigma=np.broadcast_to(sig, th.shape), vertex_cov=None, oriented=oriented).chi2)
        at_file = float(fit_pencil(a, pencil.angles[j % pencil.count] + side * pencil.wedge, x, sigma=sig,
                                   vertex_cov=None, oriented=oriented).chi2)
    except EstimationError:
        return pencil
    b = int(np.clip(np.argmin(chi2), 1, widths.size - 2))
    c0, c1, c2 = chi2[b - 1:b + 2]
    step = widths[1] - widths[0]
    curv = c0 - 2 * c1 + c2
    wedge = widths[b] + (0.5 * step * (c0 - c2) / curv if curv > 0 else 0.0)
    if at_file - float(np.min(chi2)) < WEDGE_CHI2 or not widths[0] < wedge < widths[-1]:
        return pencil
    return replace(pencil, wedge=float(wedge))


def _label_and_fit(ln, pencil, labels, idx, sigma_metric):
    """Spoke labels (K,) of the lines (-1: not the pencil's), the fit, rival labellings
    [(labels, fit)] and whether the labels are ambiguous: given `labels` (M,) or assigned."""
    oriented = not np.any(ln.straddle)
    edge_angles, _, edge_kind = pencil.edge_angles()
    if labels is None:
        kinds = dict(line_kind=ln.kind, spoke_kind=edge_kind) if edge_kind is not None and oriented else {}
        asg = assign_spokes(ln.angle, edge_angles, ln.vertex, ln.sigma, vertex_cov=ln.vertex_cov, oriented=oriented,
                            **kinds)
        if asg.clutter_ambiguous:
            # too many lines through the vertex: the labelling is one of many equally good
            raise EstimationError(
                f"clutter: {ln.angle.size} lines pass through the vertex and random ones would fit "
                f"{asg.chance_lines:.1f} of the pencil's predicted spokes; its {int(np.sum(asg.spoke >= 0))} "
                "labelled lines cannot be told from chance")
        lab, fit, rivals = asg.spoke, asg.fit, list(asg.rivals)
        if rivals and _spoke_radius(pencil) is not None:
            lab, fit, rivals = _break_label_ties(lab, fit, rivals, ln.vertex, pencil, ln.p1, ln.p2, sigma_metric)
        return lab, fit, rivals, bool(rivals)
    lab = np.asarray(labels, int).reshape(-1)[idx]
    used = lab >= 0
    if np.unique(lab[used]).size < 3:
        raise EstimationError(f"only {np.unique(lab[used]).size} labelled spokes through the vertex; three are needed")
    fit = fit_pencil(ln.angle[used], edge_angles[lab[used]], ln.vertex, sigma=ln.sigma[used],
                     vertex_cov=ln.vertex_cov, oriented=oriented)
    return lab, fit, [], False


def _grown(ln, pencil, lab):
    """The searched labelling `lab` (K,) grown to every line its fit predicts surely enough
    (`assign.grow_labels`), with its fit: (labels, fit)."""
    oriented = not np.any(ln.straddle)
    edge_angles, _, edge_kind = pencil.edge_angles()
    kinds = dict(line_kind=ln.kind, spoke_kind=edge_kind) if edge_kind is not None and oriented else {}
    return grow_labels(ln.angle, edge_angles, ln.vertex, ln.sigma, lab, vertex_cov=ln.vertex_cov, oriented=oriented,
                       **kinds)


def _point_spokes_outwards(fit, ln, used, th_used, a_used):
    """Lines fix R only up to R Rz(pi); when some segments straddle the vertex the fit
    was of lines, and the segments that do not straddle it say which way the spokes point."""
    if not np.any(ln.straddle) or not np.any(~ln.straddle[used]):
        return fit
    R = fit.R_cam_from_target
    pred = image_angles(R, ln.vertex, th_used)
    agree = np.cos(wrap_angle(a_used - pred))[~ln.straddle[used]].sum()
    if agree < 0:
        Rz = np.diag([-1.0, -1.0, 1.0])
        fit = _replace_rotation(fit, R @ Rz, fit.R_twin @ Rz)
    return fit


def _resolve_twins(fit, ln, used, th_used, s_used, prior, radius, sigma_metric):
    """Choose the twin where a prior rotation or the spoke radii tell them apart:
    (fit, resolved_by or None, the radii's comparison of the twins or None)."""
    x, cov_x = ln.vertex, ln.vertex_cov
    resolved_by = None
    if prior is not None:
        which = choose_by_prior(fit.R_cam_from_target, fit.R_twin, np.asarray(prior, float))
        fit = swap_twins(fit, which, th_used, x, s_used, cov_x, resolved_by="prior")
        resolved_by = "prior"
    metric = None
    if radius is not None:
        metric = _metric_choice(fit, x, th_used, ln.p1[used], ln.p2[used], radius, sigma_metric)
        if metric is not None and resolved_by is None and metric["decisive"]:
            fit = swap_twins(fit, metric["twin_better"], th_used, x, s_used, cov_x, resolved_by="radius")
            resolved_by = "radius"
    return fit, resolved_by, metric


def _metric_position(fit, metric, resolved_by, x, pencil):
    """vertex_cam (and t_cam_from_target when the pencil file gives the vertex) from the
    depth the spoke radii give the rotation finally chosen, if they fit it; else {}."""
    chosen_twin = resolved_by == "radius" and metric["twin_better"]
    depth = metric["depth_twin"] if chosen_twin else metric["depth"]
    chi2 = metric["chi2_twin"] if chosen_twin else metric["chi2"]
    if not (np.isfinite(depth) and chi2 / metric["points"] < 9.0):
        return {}
    return _vertex_position(fit, depth, x, pencil)


def _resolve_by_circles(camera, fit, ln, th_used, s_used, resolved_by, circle_points, pencil):
    """The circles' normal (`circle.circle_estimate`) from the edge points circle_points
    (K, 2) [raw px], and the twin it chooses where nothing chose it yet: (fit, resolved_by,
    the `CircleEstimate` or None)."""
    from pencilcal.toolkit.pencil.circle import MIN_POINTS, circle_choice, circle_estimate

    pts = None if circle_points is None else np.asarray(circle_points, float).reshape(-1, 2)
    if pts is None or pts.shape[0] < MIN_POINTS:
        return fit, resolved_by, None
    with np.errstate(invalid="ignore"):
        xn = camera.normalized_from_pixels(pts)
    xn = xn[np.all(np.isfinite(xn), -1)]
    est = circle_estimate(xn, ln.vertex, ln.vertex_cov, fit.R_cam_from_target, fit.R_twin,
                          scale=camera.f_mean, radii=pencil.circles)
    if est is None:
        return fit, resolved_by, None
    which, decisive, _, _ = circle_choice(fit, est)
    if resolved_by is None and decisive:
        fit = swap_twins(fit, which, th_used, ln.vertex, s_used, ln.vertex_cov, resolved_by="circle")
        resolved_by = "circle"
    return fit, resolved_by, est


def _bend_on_circles(fit, circ, vertex, tau2, M_bend):
    """The sheet's bend on the circles' agreement with the lines: one bend moves both normals,
    the lines' by -[n]x M_bend b (`bend.bend_covariance`) and the circles' as their images
    move (`bend.circle_bend_response`, each circle weighted by its points times its radius
    squared, as its normal's precision grows); b of covariance tau2 S. Returns (the
    difference's covariance, the circles' own share) (3, 3) [rad^2], `circle.circle_record`'s
    shared."""
    M_c = circle_bend_response(fit.R_cam_from_target, vertex, circ.radii,
                               np.asarray(circ.points, float) * np.asarray(circ.radii, float) ** 2)
    D = -skew(np.asarray(fit.normal, float)) @ M_bend - M_c
    S = tau2 * CYLINDER_SHAPE
    return D @ S @ D.T, M_c @ S @ M_c.T


def _lines_own(fit, ln, a_used, th_used, s_used, s_err=None, h=1e-6):
    """The lines' normal's covariance with the vertex held (3, 3) (their errors' sds s_err
    where given: `orient_segments`' angle_sigma_error), and how their fitted
    normal moves with the vertex's image (3, 2) (central differences, refitted from the
    solution; normalised coordinates): what `circle.circle_record` compares the circles'
    normal with, the vertex being both's."""
    from pencilcal.toolkit.pencil.circle import line_normal_cov

    n0 = np.asarray(fit.normal, float)
    own = line_normal_cov(replace(fit, cov=pencil_covariance(fit.R_cam_from_target, ln.vertex, th_used, s_used,
                                                             sigma_error=s_err)[0]))[0]
    oriented = not np.any(ln.straddle)
    cols = []
    for e in np.eye(2):
        ns = []
        for sgn in (1.0, -1.0):
            f = fit_pencil(a_used, th_used, ln.vertex + sgn * h * e, sigma=s_used, oriented=oriented)
            pair = np.stack([np.asarray(f.normal, float), np.asarray(f.normal_twin, float)])
            ns.append(pair[int(np.argmax(pair @ n0))])
        cols.append((ns[0] - ns[1]) / (2 * h))
    return own, np.stack(cols, -1)


def _vertex_position(fit, depth, x, pencil):
    """vertex_cam at `depth` along the vertex's ray x (2,), and t_cam_from_target when the
    pencil file gives the vertex."""
    P0 = depth * np.r_[x, 1.0]
    out = {"vertex_cam": P0}
    if pencil.vertex is not None:
        out["t_cam_from_target"] = P0 - fit.R_cam_from_target @ np.r_[pencil.vertex, 0.0]
    return out


def _radius_consistent(ideal, radius):
    """consistent(points) for vertex.intersect_lines: segments that can be spokes running
    from radius[0] to radius[1] of a vertex at each point.

    A spoke's near end lies at about r_in / (r_out - r_in) of its length from the vertex;
    perspective changes that ratio by well under a factor 3 at any usable tilt, while a
    stray line that only points at the vertex lies far from it.
    """
    L = np.hypot(*(ideal[:, 2:] - ideal[:, :2]).T)
    limit = np.maximum(3.0 * radius[0] / (radius[1] - radius[0]), 0.5) * L

    a, b = ideal[None, :, :2], ideal[None, :, 2:]

    def dist(q, p):  # np.linalg.norm's own sum, without its overhead (called per hypothesis)
        d = q - p
        return np.sqrt(np.add.reduce(d * d, axis=-1))

    def consistent(points):
        p = np.asarray(points, float)[:, None, :]
        return np.minimum(dist(a, p), dist(b, p)) <= limit

    return consistent


def _find_vertex(ideal, st, sc, radius, start=None):
    """Robust vertex of the segments (ideal px): (vertex, cov, inlier mask).

    With spoke radii, only lines that can be spokes of a candidate vertex count for it:
    spurious lines that happen to share a point (edges of a textured background meeting at
    the horizon) would otherwise outvote the spokes. start: (K,) bool, the lines labelled
    as spokes already (a video's tracked frame, the refit after the centre lines): the
    vertex refined from them, every line classified again, without the search over pairs
    (`vertex.intersect_lines`' start).
    """
    cons = None if radius is None else _radius_consistent(ideal, radius)
    vf = intersect_lines(ideal, angle_sigma=st, offset_sigma=sc, robust=True, consistent=cons, start=start)
    if vf.rival_vertex is not None and vf.gain - vf.rival_gain < VERTEX_RIVAL_CHI2:
        # clutter: random segments meet everywhere, and this vertex is one of many
        far = float(np.hypot(*(vf.rival_vertex - vf.vertex)))
        (x, y), (xr, yr) = vf.vertex, vf.rival_vertex
        raise EstimationError(
            f"clutter: the vertex is ambiguous: {vf.lines_used} of {len(ideal)} segments meet at ({x:.0f}, {y:.0f}) "
            f"and {vf.rival_lines} others at ({xr:.0f}, {yr:.0f}) [undistorted px], {far:.0f} px away, about as well "
            f"(evidence {vf.gain:.1f} against {vf.rival_gain:.1f}, less than {VERTEX_RIVAL_CHI2:.1f} apart)")
    return vf.vertex, vf.cov, vf.inliers


def _break_label_ties(lab, fit, rivals, x, pencil, p1, p2, sigma_metric):
    """Among labellings that explain the angles equally well, prefer the one whose spoke
    radii fit the segment end points: (labels, fit, remaining rivals).

    The radii's chi2 carries each fit's rotation uncertainty (`_radii_chi2`). When even the
    best labelling's radii misfit (chi2 per end point > 1), the others are judged against
    that scatter, and a labelling stays a rival while the ratio of the two misfits is within
    the F distribution's 99% quantile: three lines, one of them stray, fit every labelling's
    angles exactly and several labellings' radii about equally badly.
    """
    from pencilcal.toolkit.pencil.defaults import CHI2_1_99 as _CHI2_1
    from pencilcal.toolkit.pencil.defaults import CHI2_2_DETECTION as _CHI2_2

    cands = [(lab, fit)] + list(rivals)
    used = np.array([l >= 0 for l, _ in cands])
    metric_chi2 = np.empty(len(cands))
    # labellings of the same segments in one batch
    for mask in np.unique(used, axis=0):
        group = np.flatnonzero(np.all(used == mask, -1))
        R = np.stack([np.stack([cands[i][1].R_cam_from_target, cands[i][1].R_twin]) for i in group])
        cov = np.stack([cands[i][1].cov for i in group])
        th = np.stack([pencil.angles[cands[i][0][mask]] for i in group])
        metric_chi2[group] = _radii_chi2(R, cov, x, th, p1[mask], p2[mask], pencil.radius, sigma_metric)
    lines = used.sum(-1)
    points = 2 * lines
    angle_chi2 = np.array([float(f.chi2) for _, f in cands])
    per_point = metric_chi2 / np.maximum(points, 1)
    # a labelling that leaves a line out is charged for it as assign_spokes charges it, and
    # its radii are judged per end point (fewer points must not mean a smaller sum)
    angles = angle_chi2 + _CHI2_1 * (lines.max() - lines)
    if not np.any(np.isfinite(per_point)):
        return lab, fit, list(rivals)  # no labelling gives the radii a positive depth
    # Radii that no labelling fits within the end point noise (grazing views, where bar
    # ends blur; a spurious line among three, which every labelling fits exactly) cannot
    # pick one: their differences count against the best-fitting labelling's own scatter.
    scatter = max(1.0, float(np.min(per_point)))
    scores = angles + np.where(np.isfinite(per_point), per_point * max(points) / scatter, 1e12)
    best = int(np.argmin(scores))
    rival = scores - scores[best] < _CHI2_2
    if scatter > 1.0:
        # two scatters estimated from the data are told apart only by their ratio
        # the F quantile from scipy.special (scipy.stats costs a second or more to import)
        from scipy.special import fdtri

        ratio = per_point / per_point[best]
        rival |= (angles - angles[best] < _CHI2_2) & (ratio < fdtri(points, points[best], 0.99))
    rest = [c for i, c in enumerate(cands) if i != best and rival[i]]
    return cands[best][0], cands[best][1], rest


def _inner_outer(p1, p2, x):
    """Segment end points (K, 2) nearer to and farther from the vertex x (2,)."""
    near1 = (np.linalg.norm(p1 - x, axis=-1) <= np.linalg.norm(p2 - x, axis=-1))[:, None]
    return np.where(near1, p1, p2), np.where(near1, p2, p1)


def _radii_chi2(R, cov, x, th, p1, p2, radius, sigma_n):
    """How well the spoke radii fit the segment end points, for labellings of the same
    segments: chi2 (B,), the better twin's.

    R: (B, 2, 3, 3) each labelling's rotation and its twin; cov: (B, 3, 3) the rotation's
    covariance (used for the twin too: the twins are equally certain); th: (B, K) the spokes
    of the K segments p1, p2 (K, 2) (normalised); sigma_n: end point noise (normalised).
    Unlike `_metric_choice` (which compares the twins of one fit, sharing its errors) the
    residuals carry the fitted rotation's own uncertainty as well as the end point noise:
    labellings are fitted on different lines, and a fit on three lines, exact whatever the
    labels, can be far less certain than its end points.
    """
    inner, outer = _inner_outer(p1, p2, x)
    th2 = np.repeat(th[:, None], 2, 1)  # (B, 2, K)
    _, r = metric_depth(R, x, th2, inner, outer, radius)  # (B, 2, 2K)
    # residuals' sensitivity to a small left rotation of R (the depth refitted each time)
    h = 1e-6
    n = r.shape[-1]
    with np.errstate(invalid="ignore"):  # inf - inf where no depth fits: caught below
        J = np.stack([(metric_depth(rotation_from_rotvec(h * e) @ R, x, th2, inner, outer, radius)[1] - r) / h
                      for e in np.eye(3)], -1)  # (B, 2, 2K, 3)
        C = sigma_n**2 * np.eye(n) + J @ cov[:, None] @ np.swapaxes(J, -1, -2)
    good = np.all(np.isfinite(r), -1) & np.all(np.isfinite(J), (-1, -2))
    safe = np.where(good[..., None], r, 0.0)
    C = np.where(good[..., None, None], C, np.eye(n))
    chi2 = np.einsum("...i,...i->...", safe, np.linalg.solve(C, safe[..., None])[..., 0])
    return np.min(np.where(good, chi2, np.inf), -1)


def _rival_normals(fit, rivals):
    """Normals of rival labellings that differ from the fit's (closer twin compared), beyond
    three sigmas and 0.1 deg. [[x, y, z], ...] (empty when all rivals agree)."""
    n, nt = fit.normal, fit.normal_twin
    tol = max(3.0 * float(fit.normal_sigma), np.radians(0.1))
    out = []
    for _, f in rivals:
        d = min(np.arccos(np.clip(f.normal @ m, -1, 1)) for m in (n, nt))
        if d > tol:
            out.append(np.asarray(f.normal, float))
    return out


def raw_vertex(camera, vertex, vertex_ideal, cov_ideal):
    """The vertex and its covariance in raw pixels, or (None, None) where the lens model
    does not reach it.

    A vertex can lie far outside the image (an instrument's entry port usually does), where
    a polynomial lens model folds back and its "raw pixel" is no place on the sensor (a
    point 80 deg off axis came out at 4e6 px). There the vertex is given by its ray alone.
    vertex: (2,) normalised; vertex_ideal: (2,) ideal pixels; cov_ideal: (2, 2) [px^2].
    """
    v_raw = camera.distort_pixels(vertex_ideal)
    with np.errstate(all="ignore"):
        back = camera.undistort_pixels(v_raw)
        reached = bool(np.all(np.isfinite(back))
                       and np.max(np.abs(back - vertex_ideal)) <= 1e-6 * (1.0 + np.max(np.abs(vertex_ideal))))
    if not reached:
        return None, None
    A = np.linalg.inv(np.asarray(camera.K, float))[:2, :2]
    J_raw_from_ideal = camera.jacobian_pixels_from_normalized(vertex) @ A
    return v_raw, J_raw_from_ideal @ cov_ideal @ J_raw_from_ideal.T


def orientation_record(camera, fit, vertex, vertex_ideal, cov_ideal, *, model="exact", image=None,
                       sigma_mean=None, resolved_by=None):
    """The `Orientation` of a PencilFit of batch shape ().

    camera: the Camera; fit: PencilFit; vertex: (2,) normalised vertex; vertex_ideal,
    cov_ideal: the vertex in ideal (undistorted) pixels and its covariance [px^2], reported
    in raw pixels; sigma_mean: RMS line angle sd [rad] for the detection threshold.
    """
    v_raw, cov_raw = raw_vertex(camera, vertex, vertex_ideal, cov_ideal)
    return Orientation(
        image=image, ok=True, error=None, vertex_px=v_raw, vertex_cov_px2=cov_raw,
        lines_used=int(fit.lines_used), rms_residual_deg=float(np.degrees(fit.rms)),
        tilt_deg=float(np.degrees(fit.tilt)), tilt_sigma_deg=float(np.degrees(fit.tilt_sigma)),
        detectable=bool(fit.detectable), normal=fit.normal, normal_sigma_deg=float(np.degrees(fit.normal_sigma)),
        normal_twin=fit.normal_twin, R_cam_from_target=fit.R_cam_from_target, R_cam_from_target_twin=fit.R_twin,
        ambiguous=bool(fit.ambiguous), model=model, resolved_by=resolved_by, ray=fit.ray,
        tilt_threshold_deg=None if sigma_mean is None else float(np.degrees(detection_threshold(sigma_mean))),
        chi2=float(fit.chi2),
    )


def _replace_rotation(fit, R, Rt):
    return replace(fit, R_cam_from_target=R, R_twin=Rt, normal=R[:, 2], normal_twin=Rt[:, 2])


def _chapter_fit(model, a, th, x, s, cov_x, exact_fit):
    """Fit with the chapter's general or aligned model, reported like the exact estimator."""
    from pencilcal.toolkit.pencil.chapter import fit_aligned, fit_general

    if model == "general":
        res = fit_general(a, th, x, weights=1.0 / s**2)
    else:
        res = fit_aligned(a, th, weights=1.0 / s**2)
    R, Rt = np.asarray(res["R_cam_from_target"], float), np.asarray(res["R_cam_from_target_twin"], float)
    # keep the exact estimator's deterministic order (normal closer to the optical axis first)
    if Rt[2, 2] > R[2, 2]:
        R, Rt = Rt, R
    # the aligned model assumes the vertex on the optical axis: its residuals are measured
    # against exact projection so that the comparison with the exact estimator is fair
    pred = image_angles(R, x, th)
    res_exact = np.angle(np.exp(2j * (a - pred))) / 2
    cov, s_tilt, s_norm = pencil_covariance(R, x, th, s, cov_x)
    v = exact_fit.ray
    tilt = float(np.arccos(np.clip(R[:, 2] @ v, -1, 1)))
    w = 1.0 / s**2
    return replace(
        exact_fit, R_cam_from_target=R, R_twin=Rt, normal=R[:, 2], normal_twin=Rt[:, 2], tilt=np.asarray(tilt),
        tilt_sigma=s_tilt, normal_sigma=s_norm, cov=cov, residuals=res_exact,
        rms=np.sqrt(np.sum(w * res_exact**2) / np.sum(w)), chi2=np.sum(w * res_exact**2),
    )


def _metric_choice(fit, x, th, p1, p2, radius, sigma_n):
    """Compare the twins by how well the spoke radii fit the segment end points.

    sigma_n: end point noise in normalised units. Decisive when the better twin fits within
    noise (chi2 per point < 9) and the other is worse by more than 25 in chi2.
    """
    inner, outer = _inner_outer(p1, p2, x)
    # both twins in one call (every tracked frame makes this choice)
    (z, zt), (r, rt) = metric_depth(np.stack([fit.R_cam_from_target, fit.R_twin]), x, th, inner, outer, radius)
    z, zt = float(z), float(zt)
    c, ct = np.sum((r / sigma_n) ** 2), np.sum((rt / sigma_n) ** 2)
    n = r.size
    best = min(c, ct)
    decisive = bool(np.isfinite(best) and best / n < 9.0 and abs(c - ct) > 25.0)
    return {"depth": z, "depth_twin": zt, "twin_better": bool(ct < c), "decisive": decisive, "chi2": c,
            "chi2_twin": ct, "points": n}


def resolve_twins_by_continuity(orientations):
    """Choose twins over a sequence so that the orientation changes least between frames.

    orientations: [Orientation] of consecutive frames; returns new ones. Ambiguous frames
    get the twin on the cheapest path (Viterbi over the two states per frame, cost =
    rotation angle between consecutive frames). Continuity alone cannot tell the two whole
    paths apart (the twin of a smooth motion is smooth too); it carries the choice made in
    resolved frames (``ambiguous`` false: a prior, the spoke radii) to the others, which
    then get ``resolved_by: "continuity"``. With no resolved frame the twins are only made
    consistent along the sequence and stay ``ambiguous``.
    """
    out = list(orientations)
    idx = [i for i, o in enumerate(out) if o.ok]
    if len(idx) < 2:
        return out
    Rs = [np.stack([np.asarray(out[i].R_cam_from_target, float),
                    np.asarray(out[i].R_cam_from_target_twin, float)]) for i in idx]
    fixed = [not out[i].ambiguous for i in idx]
    INF = 1e9
    cost = np.array([0.0, INF if fixed[0] else 0.0])
    back = []
    for k in range(1, len(idx)):
        trans = np.array([[rotation_angle(Rs[k - 1][a], Rs[k][b]) for b in range(2)] for a in range(2)])
        tot = cost[:, None] + trans
        arg = np.argmin(tot, 0)
        cost = tot[arg, [0, 1]]
        if fixed[k]:
            cost[1] = INF
        back.append(arg)
    state = int(np.argmin(cost))
    states = [state]
    for arg in reversed(back):
        state = int(arg[state])
        states.append(state)
    states.reverse()
    anchored = any(fixed)
    for i, s in zip(idx, states):
        o = out[i]
        if o.ambiguous and s == 1:
            o = o.swapped()
        if o.ambiguous and anchored:
            o = o.replace(ambiguous=False, resolved_by="continuity")
        out[i] = o
    return out

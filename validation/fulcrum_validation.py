"""validation.json's ``fulcrum`` record: the fulcrum of a pivot sequence, against its truth.

A pivot sequence (`pencilcal simulate --scenario pivot`, or any sequence with `validate
--fulcrum`) shows an instrument pivoting about its entry port. Its shafts are detected in
every frame (`detect.shafts`), and the fulcrum found as `pencilcal fulcrum` finds it
(`pencil.fulcrum.fulcrum_from_frames`, the detector's sigmas inflated by the scatter the
lines show): the 2-D vertex and its ray, and with the shaft's diameter the 3-D point. The
record adds what validation needs:

- each frame's axis residual: in 2-D the distance of the fulcrum's (ideal) image from the
  frame's midline with the midline's sigma there, in 3-D the distance of the point from the
  frame's 3-D axis and its chi2 (2 dof); every detected shaft's midline (raw px), which
  the report draws on sample frames;
- the truth where known (a simulate folder's ``pivot``): the vertex's error [px], the 3-D
  point's error [length] and its chi2 under point_cov (3 dof);
- the fulcrum in the board frame where a board pose is known (PnP, per frame):
  ``p_board = R_cam_from_target^T (p_cam - t_cam_from_target)``, its covariance
  ``R^T point_cov R`` (the pose's own error not included), the median over the frames.
"""
from __future__ import annotations

import numpy as np
from scipy.stats import chi2 as chi2_dist

from pencilcal.toolkit.detect.edges import DEFAULT_GAMMA
from pencilcal.toolkit.errors import EstimationError
from pencilcal.toolkit.pencil.fulcrum import fulcrum_from_frames
from pencilcal.toolkit.pencil.sequence_noise import fulcrum_noise

__all__ = ["fulcrum_record", "shaft_frame"]


def shaft_frame(frame, camera, detector="lsd", valid_region=None, gamma=DEFAULT_GAMMA, masks=None):
    """The lines.json frame (image, ok, segments, shafts) of one decoded `Frame`: the shafts
    of `detect.shafts.detect_shafts` within valid_region, their edges located on levels
    linearised with `gamma` (validate calls it in its frame task, on the frame it decoded
    for everything else); with masks (`io.instrument_masks.InstrumentMasks`) the axes of
    the frame's masked instruments instead (`detect.shaft.from_mask.shafts_from_masks`)."""
    from pencilcal.toolkit.detect.lines import shaft_records

    if frame.image is None:
        return {"image": frame.name, "ok": False, "segments": np.zeros((0, 4)), "error": frame.error}
    shafts = shaft_records(frame.image, camera, valid_region, gamma, None if masks is None else masks.of(frame),
                           detector=detector)
    return {"image": frame.name, "ok": True, "segments": np.zeros((0, 4)), "shafts": shafts}


def _ideal_vertex(camera, ray):
    """The fulcrum's image in undistorted pixels (2,), or None when the ray points backwards."""
    ray = np.asarray(ray, float)
    if not ray[2] > 0:
        return None
    return (np.asarray(camera.K, float) @ (ray / ray[2]))[:2]


def _residuals_2d(camera, frames, vertex_ideal, outliers):
    """Per shaft: the fulcrum image's distance [ideal px] from its midline and the midline's
    sd there (offset sd at the centre, angle sd times the distance along it)."""
    bad = {(o["image"], o["segment"]) for o in outliers}
    rows = []
    for fr in frames:
        for j, sh in enumerate(fr.get("shafts") or []):
            ends = camera.undistort_pixels(np.asarray(sh["midline"], float).reshape(2, 2))
            if not np.all(np.isfinite(ends)) or vertex_ideal is None:
                continue
            d = ends[1] - ends[0]
            L = float(np.hypot(*d))
            if not L > 0:
                continue
            t, n = d / L, np.array([-d[1], d[0]]) / L
            centre = ends.mean(0)
            res = float(n @ (vertex_ideal - centre))
            along = float(t @ (vertex_ideal - centre))
            sa = np.radians(float(sh.get("angle_sigma_deg") or 0.0))
            so = float(sh.get("offset_sigma_px") or 0.0)
            rows.append({"image": fr["image"], "shaft": j, "residual_px": abs(res),
                         "sigma_px": float(np.hypot(so, along * sa)), "used": (fr["image"], j) not in bad})
    return rows


def _board_frame(point, cov, frames):
    """The 3-D fulcrum in the board frame from each frame's best PnP pose: the median point
    (3,), its covariance from the camera frame's, and the frames used; None without a pose."""
    pts, covs, names = [], [], []
    for f in frames:
        best = f.get("pnp_best")
        pose = (f.get("pnp") or {}).get(best) if best else None
        if not pose or not pose.get("ok", True) or pose.get("R_cam_from_target") is None:
            continue
        R = np.asarray(pose["R_cam_from_target"], float)
        t = np.asarray(pose["t_cam_from_target"], float).reshape(3)
        pts.append(R.T @ (point - t))
        covs.append(R.T @ cov @ R)
        names.append(f["image"])
    if not pts:
        return None
    pts = np.array(pts)
    k = int(np.argmin(np.linalg.norm(pts - np.median(pts, 0), axis=1)))
    return {"point": np.median(pts, 0), "point_cov": covs[k], "frames": len(pts),
            "spread": float(np.sqrt(np.mean(np.sum((pts - pts.mean(0)) ** 2, -1)))) if len(pts) > 1 else 0.0}


def fulcrum_record(camera, frames, validated=(), truth=None, shaft_diameter=None):
    """The ``fulcrum`` record of validation.json (module docstring).

    camera: Camera; frames: lines.json frames with shafts (`shaft_frame`); validated: the
    validation's frame records (their PnP poses give the board frame); truth: the truth
    file's ``pivot`` dict (``fulcrum_px``, ``fulcrum_cam``, ``fulcrum_target``) or None;
    shaft_diameter: the shafts' diameter (the 3-D point) or None. Returns a dict; ``ok``
    false with ``error`` when there is no fulcrum.
    """
    try:
        res = fulcrum_from_frames(camera, frames, shaft_diameter=shaft_diameter)
    except EstimationError as e:
        return {"ok": False, "error": str(e), "shaft_diameter": shaft_diameter}
    res, est = fulcrum_noise(res, inflate_only=True)
    rec = res.to_dict()
    rec["noise"] = None if est["vertex"] is None else est["vertex"].to_dict()
    rec["shaft_diameter"] = shaft_diameter
    rec["frames"] = len(frames)
    rec["axis_residuals"] = _residuals_2d(camera, frames, _ideal_vertex(camera, rec["ray"]), rec["outliers"])
    rec["midlines"] = [{"image": fr["image"], "shaft": j, "midline": np.asarray(sh["midline"], float).tolist()}
                       for fr in frames for j, sh in enumerate(fr.get("shafts") or [])]
    point = None if res.point is None else (np.asarray(rec["point"], float), np.asarray(rec["point_cov"], float))
    if truth:
        t = {}
        if rec["vertex_px"] is not None and truth.get("fulcrum_px") is not None:
            e = np.asarray(rec["vertex_px"], float) - np.asarray(truth["fulcrum_px"], float)
            t["vertex_error_px"] = float(np.hypot(*e))
            if rec["vertex_cov_px2"] is not None:
                t["vertex_chi2"] = float(e @ np.linalg.solve(np.asarray(rec["vertex_cov_px2"], float), e))
        if point is not None and truth.get("fulcrum_cam") is not None:
            e = point[0] - np.asarray(truth["fulcrum_cam"], float)
            c2 = float(e @ np.linalg.solve(point[1], e))
            t.update({"point_error": e, "point_error_norm": float(np.linalg.norm(e)), "point_chi2": c2,
                      "point_p_value": float(chi2_dist.sf(c2, 3))})
        t["fulcrum_px"], t["fulcrum_cam"] = truth.get("fulcrum_px"), truth.get("fulcrum_cam")
        t["fulcrum_target"] = truth.get("fulcrum_target")
        rec["truth"] = t
    if point is not None:
        board = _board_frame(point[0], point[1], validated)
        if board is not None and truth and truth.get("fulcrum_target") is not None:
            board["error"] = float(np.linalg.norm(board["point"] - np.asarray(truth["fulcrum_target"], float)))
        rec["board_frame"] = board
    return rec

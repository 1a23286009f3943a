"""Validation: the angular-variation estimate, every PnP method and a reconstruction, compared.

`validate_sequence` runs, on the same frames, each frame decoded and detected once:

- orient: lines of the pencil (the printed fan's bars, or the board's grid lines through one
  corner, `grid_pencil`) -> the exact estimator and the chapter's general and aligned
  models (`toolkit.orient.orient_segments`); the twin is chosen only by the pencil's own
  information (spoke radii, then continuity along the sequence as `pencilcal orient` has
  it by default: `orient.resolve_twins_by_continuity`), never by the board pose it is
  compared with;
- pnp: the board's corners -> every PnP method, each refined (`validation.pnp`);
- sfm (optional): a pycolmap reconstruction with the intrinsics held fixed, aligned to the
  board frame by robust rotation averaging against the PnP poses (`validation.align`).

The reference is the exact truth when there is one (a `pencilcal simulate` folder), else
the PnP pose of the best method. Per frame and per method: the normal's angular error (for
the chosen solution and for the closer twin), the full rotation error, the tilt error, how
the twin was handled, and the reported sigmas; summaries (median, RMSE, 95th percentile)
and the coverage of the reported sigmas. Angles in the output are degrees.
"""
from __future__ import annotations

import hashlib
import platform
import sys
import time
from pathlib import Path

import numpy as np

from pencilcal.toolkit.board.calibration_file import symmetric_corners_of
from pencilcal.toolkit.board.detect import detect_board
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.pencil.estimator import crlb
from pencilcal.toolkit.geometry.frames import angle_between, normalize
from pencilcal.toolkit.io.images import check_image_size
from pencilcal.toolkit.pencil.defaults import ENDPOINT_SIGMA_PX
from pencilcal.toolkit.pencil.orient import MODELS, orient_segments
from pencilcal.toolkit.io.parallel import Sized, map_frames

from .align import align_rotations
from .metrics import coverage, normal_error_deg, rotation_error_deg, summary
from .pnp import METHODS, best_method, board_points, estimate_all, frame_record

__all__ = ["validate_sequence", "validate_path", "validate_many", "find_sequences", "sequence_files", "frame_errors",
           "twins_by_continuity",
           "reference_sigmas", "summarise", "reproducibility", "FanLines", "GridLines"]


class FanLines:
    """Lines of a printed fan as `orient IMAGES` finds them (`toolkit.detect.lines.fan_line_options`):
    the midlines of its bars (`toolkit.detect.bars.detect_bars`), a star's edges all round and
    its circle points (for wedge and edge pencils: `toolkit.detect.radial.orient_radial_edges`,
    each edge trimmed at the ring the spokes end on, a dartboard's double ring), or plain
    edge segments with `edges`; within `valid_region` (a `toolkit.detect.region.ValidRegion`)
    when one is set."""

    def __init__(self, pencil, detector="auto", edges=False, valid_region=None):
        self.pencil = pencil
        self.detector = detector
        self.edges = edges
        self.valid_region = valid_region

    def __call__(self, image, camera, detection, corner_sigma_px=None):
        from pencilcal.toolkit.detect.bars import detect_bars
        from pencilcal.toolkit.detect.lines import (default_min_length, fan_line_options, radial_edge_count,
                                                    radial_joint_mode)
        from pencilcal.toolkit.detect.segments import detect_segments

        bars, polarity = fan_line_options(self.pencil.width, self.edges)
        radial = None if self.edges else radial_edge_count(self.pencil)
        if radial is not None:
            from pencilcal.toolkit.detect.radial import orient_radial_edges

            # trimmed as orient IMAGES trims them (beyond the ring other print turns an edge),
            # and with its shortest edge (an edge segment's, 20 px)
            found, _ = orient_radial_edges(image, camera, self.pencil, edges=radial, valid_region=self.valid_region,
                                           joint=radial_joint_mode(self.pencil),
                                           min_length=default_min_length(np.shape(image), bars=False))
        elif bars:
            # the bars `orient IMAGES` would find (lines_record's default shortest bar)
            found = detect_bars(image, self.detector, camera=camera, polarity=polarity, valid_region=self.valid_region,
                                min_length=default_min_length(np.shape(image), bars=True))
        else:
            found = detect_segments(image, self.detector, camera=camera, valid_region=self.valid_region)
        return {"segments": found.segments, "angle_sigma": found.angle_sigma, "offset_sigma": found.offset_sigma,
                "labels": None, "vertex_px": None, "vertex_cov_px2": None, "pencil": self.pencil,
                "width_px": found.width_px if bars and radial is None else None,
                "circle_points": getattr(found, "circle_points", None),
                "angle_sigma_error": getattr(found, "angle_sigma_error", None)}


class GridLines:
    """Lines of the board's grid through one corner (`toolkit.grid_pencil.GridPencil`).

    The corner noise is the frame's own, estimated from the PnP residuals of the same
    corners, or `corner_sigma_px` when there is no pose."""

    def __init__(self, grid, corner_sigma_px=0.2):
        self.grid = grid
        self.corner_sigma_px = corner_sigma_px

    def __call__(self, image, camera, detection, corner_sigma_px=None):
        # the frame's own corner noise (from the PnP residuals of these very corners) when
        # known: on real endoscope frames it is ~0.4 px, twice the default
        return self.grid.segments(detection, corner_sigma_px or self.corner_sigma_px)


def _tilt_deg(R, ray):
    return float(np.degrees(angle_between(np.asarray(R, float)[:, 2], ray)))


def _vertex_ray(R, t, pencil):
    """Unit ray of the pencil's vertex for a pose (None when the pencil has no vertex)."""
    if pencil is None or pencil.vertex is None or t is None:
        return None
    P0 = np.asarray(R, float) @ np.r_[pencil.vertex, 0.0] + np.asarray(t, float)
    return normalize(P0)


def frame_errors(R, R_twin, ambiguous, R_ref, ray, tilt_sigma_deg=None, normal_sigma_deg=None):
    """Errors of one estimate against the reference rotation, in degrees.

    R, R_twin: (3, 3) the chosen solution and its twin (None for methods without one);
    ambiguous: whether the twin was left unresolved; R_ref: (3, 3); ray: (3,) unit vertex
    ray. Returns normal and rotation errors for the chosen solution and the closer twin, the
    signed tilt error, the reported sigmas and the twin outcome (right, wrong, ambiguous,
    none).
    """
    R = np.asarray(R, float)
    n_ref = R_ref[:, 2]
    out = {
        "normal_deg": float(normal_error_deg(R[:, 2], n_ref)),
        "rotation_deg": float(rotation_error_deg(R, R_ref)),
        "tilt_deg": None if ray is None else _tilt_deg(R, ray) - _tilt_deg(R_ref, ray),
        "tilt_sigma_deg": tilt_sigma_deg,
        "normal_sigma_deg": normal_sigma_deg,
    }
    if R_twin is None:
        out.update(normal_closer_deg=out["normal_deg"], rotation_closer_deg=out["rotation_deg"], twin="none")
        return out
    Rt = np.asarray(R_twin, float)
    nt = float(normal_error_deg(Rt[:, 2], n_ref))
    rt = float(rotation_error_deg(Rt, R_ref))
    out["normal_closer_deg"] = min(out["normal_deg"], nt)
    out["rotation_closer_deg"] = min(out["rotation_deg"], rt)
    if ambiguous:
        out["twin"] = "ambiguous"
    else:
        out["twin"] = "right" if out["normal_deg"] <= nt else "wrong"
    return out


def summarise(frames, keys):
    """Per method: summaries of the errors, sigma coverage and twin counts."""
    out = {}
    for key in keys:
        errs = [f["errors"][key] for f in frames if f.get("errors", {}).get(key)]
        if not errs:
            out[key] = {"frames": 0}
            continue
        twins = [e.get("twin") for e in errs]
        use_closer = key.startswith("orient")
        s = {
            "frames": len(errs),
            "normal": summary([e["normal_deg"] for e in errs]),
            "normal_closer": summary([e["normal_closer_deg"] for e in errs]),
            "rotation": summary([e["rotation_deg"] for e in errs]),
            "rotation_closer": summary([e["rotation_closer_deg"] for e in errs]),
            "tilt": summary([e["tilt_deg"] for e in errs]),
            "twin": {k: twins.count(k) for k in ("right", "wrong", "ambiguous", "none") if twins.count(k)},
        }
        # judged by the sigmas of the difference where the record has them (the method's
        # totals with the reference's own sigma, `_coverage_sigmas`), else the method's own
        st = lambda e: e.get("coverage_tilt_sigma_deg") or e.get("tilt_sigma_deg")  # noqa: E731
        sn = lambda e: e.get("coverage_normal_sigma_deg") or e.get("normal_sigma_deg")  # noqa: E731
        tilt_pairs = [(e["tilt_deg"], st(e)) for e in errs if st(e) is not None and e.get("tilt_deg") is not None]
        if tilt_pairs:
            s["tilt_coverage"] = coverage(*zip(*tilt_pairs), kind="tilt")
        norm_pairs = [(e["normal_closer_deg"] if use_closer else e["normal_deg"], sn(e)) for e in errs
                      if sn(e) is not None]
        if norm_pairs:
            s["normal_coverage"] = coverage(*zip(*norm_pairs), kind="normal")
        det = [f["orient"][key.split(":", 1)[1]].get("detectable") for f in frames
               if key.startswith("orient:") and f.get("errors", {}).get(key)]
        if det:
            s["detectable"] = int(sum(bool(d) for d in det))
        out[key] = s
    return out


def _sha256(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def reproducibility(inputs, argv=None):
    """Versions, the command line and SHA-256 of the input files (path -> hash)."""
    import cv2
    import scipy

    versions = {"python": platform.python_version(), "numpy": np.__version__, "scipy": scipy.__version__,
                "opencv": cv2.__version__, "platform": platform.platform()}
    try:
        from importlib.metadata import version

        versions["pencilcal"] = version("pencilcal")
    except Exception:  # a source tree without installing
        versions["pencilcal"] = "unknown"
    try:
        from .sfm.glog import import_pycolmap

        versions["pycolmap"] = import_pycolmap().__version__
    except ImportError:
        pass
    hashes = {}
    for p in inputs:
        if p is not None and Path(p).is_file():
            hashes[str(p)] = _sha256(p)
    return {"versions": versions, "command": list(sys.argv if argv is None else argv),
            "inputs_sha256": hashes, "created": time.strftime("%Y-%m-%dT%H:%M:%S%z")}


def _pose_of(truth_frame, pnp_best):
    if truth_frame is not None:
        return "truth", np.asarray(truth_frame["R_cam_from_target"], float), np.asarray(truth_frame["t_cam_from_target"], float)
    if pnp_best is not None and pnp_best.ok:
        return "pnp", pnp_best.R_cam_from_target, pnp_best.t_cam_from_target
    return None, None, None


def reference_sigmas(pose, ray):
    """(tilt sigma, normal sigma) [deg] of a PnP reference pose (`PoseResult`) at the
    vertex ray `ray` (3,): from its total covariance when it has one, else its noise-only
    one. The tilt moves with the rotation about the axis normal x ray (left perturbation
    in the camera frame, poses.json's convention)."""
    cov = pose.cov_total if pose.cov_total is not None else pose.cov
    if cov is None:
        return None, None
    C = np.asarray(cov, float)[:3, :3]
    n = np.asarray(pose.R_cam_from_target, float)[:, 2]
    u = np.cross(n, np.asarray(ray, float))
    tilt = None
    if np.linalg.norm(u) > 1e-9:
        u = u / np.linalg.norm(u)
        tilt = float(np.degrees(np.sqrt(max(u @ C @ u, 0.0))))
    P = np.eye(3) - np.outer(n, n)
    return tilt, float(np.degrees(np.sqrt(max(np.trace(P @ C @ P), 0.0))))


def _coverage_sigmas(o, ref_pose, ray):
    """The sigmas an orientation's coverage is judged by: its total ones where the
    intrinsics' covariance was known, and against a PnP reference that pose's own sigmas
    added in quadrature (the reference errs too). Keys ``coverage_tilt_sigma_deg``,
    ``coverage_normal_sigma_deg``, ``reference_tilt_sigma_deg``,
    ``reference_normal_sigma_deg``, ``sigma_kind`` ("total" or "noise")."""
    total = o.tilt_sigma_total_deg is not None
    st = o.tilt_sigma_total_deg if total else o.tilt_sigma_deg
    sn = o.normal_sigma_total_deg if total else o.normal_sigma_deg
    rt, rn = (None, None) if ref_pose is None else reference_sigmas(ref_pose, ray)
    quad = lambda a, b: None if a is None else float(np.hypot(a, b or 0.0))  # noqa: E731
    return {"coverage_tilt_sigma_deg": quad(st, rt), "coverage_normal_sigma_deg": quad(sn, rn),
            "reference_tilt_sigma_deg": rt, "reference_normal_sigma_deg": rn,
            "sigma_kind": "total" if total else "noise"}


def _process(frame, camera, board, lines_source, models, methods, truth, keep_pixels):
    """Everything for one frame: detections, estimates, errors against the reference."""
    rec = {"image": frame.name, "ok": False, "error": None, "path": frame.path}
    if frame.image is None:
        rec["error"] = frame.error
        return rec, None, None
    check_image_size(frame, camera)
    det = detect_board(frame.image, board, symmetric_corners_of(camera))
    pnp = {}
    best = None
    if det.count >= 4:
        # the board as the camera's calibration measured it (its warp), when it was this board
        X, warp = board_points(board, camera, det.ids)
        res = estimate_all(X, det.corners, camera, methods=methods, board_warp=warp)
        name = best_method(res)
        best = res.get(name) if name else None
        rec["pnp"] = {m: frame_record(frame.name, r) for m, r in res.items()}
        rec["pnp_best"] = name
        pnp = res
    else:
        rec["pnp"] = {}
        rec["pnp_best"] = None
    rec["board_corners"] = int(det.count)
    sigma_px = getattr(best, "sigma_px", None) if best is not None and best.ok else None
    src = lines_source(frame.image, camera, det, corner_sigma_px=sigma_px)
    orients = {}
    if src is None:
        rec["orient"] = {m: {"ok": False, "error": "no pencil lines in this frame"} for m in models}
    else:
        for m in models:
            orients[m] = orient_segments(
                camera, src["segments"], src["pencil"], model=m, angle_sigma=src["angle_sigma"],
                vertex_px=src["vertex_px"], vertex_cov_px2=src["vertex_cov_px2"], labels=src["labels"],
                image=frame.name, keep_lines=(m == "exact"), offset_sigma=src.get("offset_sigma"),
                spoke_radii=src.get("radii"), endpoint_sigma_px=src.get("corner_sigma_px") or ENDPOINT_SIGMA_PX,
                bar_width_px=src.get("width_px"), circle_points=src.get("circle_points"),
                angle_sigma_error=src.get("angle_sigma_error"))
        rec["orient"] = {m: o.to_dict() for m, o in orients.items()}
        if keep_pixels:
            rec["segments"] = src["segments"]
    pencil = None if src is None else src["pencil"]
    truth_frame = None if truth is None else truth.get(frame.name)
    source, R_ref, t_ref = _pose_of(truth_frame, best)
    rec["reference"] = source
    if R_ref is None:
        rec["error"] = "no reference pose (no truth and no board pose)"
        return rec, None, None
    rec["R_ref"] = R_ref
    rec["t_ref"] = t_ref
    ray = _vertex_ray(R_ref, t_ref, pencil)
    rec["reference_tilt_deg"] = None if ray is None else _tilt_deg(R_ref, ray)
    errors = {}
    ref_pose = best if source == "pnp" else None
    for m, o in orients.items():
        if o.ok:
            errors[f"orient:{m}"] = _orient_errors(o, R_ref, ray, ref_pose)
    exact = orients.get("exact")
    if exact is not None and exact.ok and exact.lines is not None:
        ln = exact.lines
        x_ref = None
        if ray is not None:
            x_ref = ray[:2] / ray[2]
        else:
            x_ref = np.asarray(ln["vertex"], float)
        _, b_tilt, b_norm = crlb(R_ref, x_ref, pencil.angles[ln["spoke"]], ln["sigma"], ln["vertex_cov"])
        # at zero tilt the bound is infinite (the tilt is unobservable to first order)
        finite = lambda v: float(np.degrees(v)) if np.degrees(v) < 90.0 else None  # noqa: E731
        rec["crlb"] = {"tilt_deg": finite(b_tilt), "normal_deg": finite(b_norm)}
    for m, r in pnp.items():
        if r.ok:
            ray_p = _vertex_ray(r.R_cam_from_target, r.t_cam_from_target, pencil)
            ray_p = ray if ray_p is None else ray_p
            errors[f"pnp:{m}"] = frame_errors(r.R_cam_from_target, None, False, R_ref, ray_p,
                                              None, getattr(r, "normal_sigma_deg", None))
    rec["errors"] = errors
    rec["ok"] = bool(errors)
    if not errors:
        rec["error"] = "no estimate in this frame"
    return rec, best, {"orients": orients, "R_ref": R_ref, "ray": ray, "ref_pose": ref_pose}


def _orient_errors(o, R_ref, ray, ref_pose):
    """One orientation's error record against the reference (`frame_errors` with the
    sigmas its coverage is judged by); ray: the reference's vertex ray, or None for the
    estimate's own."""
    ray_m = ray if ray is not None else np.asarray(o.ray, float)
    e = frame_errors(o.R_cam_from_target, o.R_cam_from_target_twin, o.ambiguous, R_ref, ray_m,
                     o.tilt_sigma_deg, o.normal_sigma_deg)
    e.update(_coverage_sigmas(o, ref_pose, ray_m))
    return e


def twins_by_continuity(frames, estimates):
    """Resolve the twin of ambiguous frames by continuity along the sequence, per orient
    model, as `pencilcal orient` does by default (`orient.resolve_twins_by_continuity`:
    the choices of frames the spoke radii resolved carried to the others, which then say
    ``resolved_by: "continuity"``; with no resolved frame the twins are only made
    consistent and stay ambiguous). frames: the validation records, changed in place
    (their ``orient`` and ``errors``); estimates: per frame `_process`'s third value (the
    Orientations, the reference and its ray) or None."""
    from pencilcal.toolkit.pencil.orient import resolve_twins_by_continuity

    models = sorted({m for e in estimates if e for m in e["orients"]})
    for m in models:
        idx = [i for i, e in enumerate(estimates) if e and e["orients"].get(m) is not None and e["orients"][m].ok]
        done = resolve_twins_by_continuity([estimates[i]["orients"][m] for i in idx])
        for i, o in zip(idx, done):
            e = estimates[i]
            if o is e["orients"][m]:
                continue
            e["orients"][m] = o
            frames[i]["orient"][m] = o.to_dict()
            if e["R_ref"] is not None and f"orient:{m}" in frames[i].get("errors", {}):
                frames[i]["errors"][f"orient:{m}"] = _orient_errors(o, e["R_ref"], e["ray"], e["ref_pose"])


def _sfm(source, camera, frames, best_poses, workdir, warn, quiet, progress):
    """Reconstruct, align to the board frame with the PnP poses, add the sfm errors.

    best_poses: per frame (in the order of `frames`) the PoseResult of its best PnP method,
    or None."""
    from .sfm import reconstruct

    res = reconstruct(source, camera, workdir, quiet=quiet, progress=progress)
    by_name = {f.image: f for f in res.frames}
    pairs = [(by_name[f["image"]], best) for f, best in zip(frames, best_poses)
             if f["image"] in by_name and by_name[f["image"]].registered and f.get("pnp_best")]
    if len(pairs) < 2:
        raise EstimationError("the reconstruction and the board poses share fewer than two frames: cannot align them")
    Rcw = np.array([p[0].R_cam_from_world for p in pairs])
    Rct = np.array([p[1].R_cam_from_target for p in pairs])
    R_wt, inliers = align_rotations(Rcw, Rct)
    info = {"registered": int(sum(f.registered for f in res.frames)), "frames": len(res.frames),
            "points3D": int(res.n_points3D), "alignment_inliers": int(inliers.sum()),
            "alignment_frames": len(pairs), "R_world_from_target": R_wt,
            "mean_reprojection_error_px": float(res.mean_reprojection_error_px)}
    for f in frames:
        s = by_name.get(f["image"])
        if s is None or not s.registered:
            f["sfm"] = {"registered": False}
            continue
        R = s.R_cam_from_world @ R_wt
        f["sfm"] = {"registered": True, "R_cam_from_target": R}
        if f.get("R_ref") is not None:
            ray = None
            ex = f["orient"].get("exact", {})
            if ex.get("ok"):
                ray = np.asarray(ex["ray"], float)
            f.setdefault("errors", {})["sfm"] = frame_errors(R, None, False, np.asarray(f["R_ref"], float), ray)
    return info


def _frame_task(frame, ctx):
    """One frame's validation record, the PoseResult of its best PnP method (or None) and,
    with `shafts` (detector, valid region, gamma, instrument masks), its shafts as a
    lines.json frame (else None)
    (module level: runs in worker processes too)."""
    camera, board, lines_source, models, methods, truth, keep_pixels, shafts, continuity = ctx
    try:
        rec, best, est = _process(frame, camera, board, lines_source, models, methods, truth, keep_pixels)
    except EstimationError as e:
        rec, best, est = {"image": frame.name, "ok": False, "error": str(e)}, None, None
    est = est if continuity else None  # the Orientations travel back only where they are used
    if shafts is None:
        return rec, best, None, est
    from .fulcrum_validation import shaft_frame

    return rec, best, shaft_frame(frame, camera, *shafts), est


def validate_sequence(source, camera, board, lines_source, *, truth=None, models=MODELS, methods=METHODS,
                      sfm=False, sfm_workdir=None, progress=None, warn=None, quiet=True, keep_pixels=True,
                      sfm_progress=None, workers=1, right_poses=None, rig_intrinsics=(None, None), fulcrum=None,
                      continuity=True):
    """Run orient, every PnP method and optionally SfM on one sequence and compare them.

    source: an ImageSource; camera: Camera; board: Board; lines_source: FanLines or GridLines
    (a callable (image, camera, detection) -> dict of segments, labels, sigmas, pencil);
    truth: dict image name -> truth frame (R_cam_from_target, t_cam_from_target) or None;
    models: orient models; methods: PnP methods; sfm: also reconstruct with pycolmap
    (sfm_workdir: where; a temporary folder if None); progress: callable(iterable, label)
    -> iterable; warn: callable(str) for per-frame problems; sfm_progress: callable(stage,
    done, total) for the reconstruction's stages (validation.sfm.reconstruct); workers:
    frames in this many processes (toolkit.parallel.map_frames; same results);
    right_poses: the board's poses in a second camera rigidly fixed to this one (image name
    -> PoseResult, `checks.board_poses`): the rig check (`checks.rig_check`, with each
    camera's intrinsics covariance in rig_intrinsics) goes under ``checks``; fulcrum: a
    dict of detector, valid_region, truth (the pivot truth or None), shaft_diameter and
    masks (`io.instrument_masks.InstrumentMasks` or None): the instrument's shafts are
    detected in every frame as it is processed (or taken from its masks) and the ``fulcrum``
    record (`fulcrum_validation.fulcrum_record`) is made from them; continuity: resolve the
    twin of ambiguous frames along the sequence as `pencilcal orient` does
    (`twins_by_continuity`; the frames in the order given).

    Returns the validation.json dict (numpy arrays inside; write with files.write_json).
    """
    frames, best_poses, shaft_frames, estimates = [], [], [], []
    shafts = None
    if fulcrum is not None:
        from pencilcal.toolkit.detect.edges import DEFAULT_GAMMA

        gamma = DEFAULT_GAMMA if fulcrum.get("gamma") is None else float(fulcrum["gamma"])
        shafts = (fulcrum.get("detector", "auto"), fulcrum.get("valid_region"), gamma, fulcrum.get("masks"))
    ctx = (camera, board, lines_source, models, methods, truth, keep_pixels, shafts, continuity)
    results = map_frames(_frame_task, source, ctx, workers)
    it = results if progress is None else progress(Sized(results, len(source)), "validate")
    for rec, best, shaft_rec, est in it:
        if not rec["ok"] and warn is not None:
            warn(f"{rec['image']}: {rec['error']}")
        frames.append(rec)
        best_poses.append(best)
        shaft_frames.append(shaft_rec)
        estimates.append(est)
        for sh in (shaft_rec or {}).get("shafts") or []:
            if sh.get("mask_warning") and warn is not None:
                warn(f"{shaft_rec['image']}: {sh['mask_warning']}")
    if continuity:
        twins_by_continuity(frames, estimates)
    if not any(f["ok"] for f in frames):
        where = getattr(source, "description", None)
        raise EstimationError(f"{where + ': ' if where else ''}no frame could be validated (no pencil and no board "
                              f"pose in any of its {len(frames)} frames)")
    keys = [f"orient:{m}" for m in models] + [f"pnp:{m}" for m in methods]
    out = {"reference": "truth" if truth is not None else "pnp", "models": list(models), "methods": list(methods)}
    if sfm:
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            out["sfm"] = _sfm(source, camera, frames, best_poses, sfm_workdir or tmp, warn, quiet, sfm_progress)
        keys.append("sfm")
    out["summary"] = summarise(frames, keys)
    if right_poses is not None:
        from .checks import pair_by_name, rig_check

        left, right = pair_by_name([f["image"] for f in frames], best_poses, right_poses)
        out["checks"] = {"rig": rig_check(left, right, rig_intrinsics)}
    if fulcrum is not None:
        from .fulcrum_validation import fulcrum_record

        out["fulcrum"] = fulcrum_record(camera, shaft_frames, frames, truth=fulcrum.get("truth"),
                                        shaft_diameter=fulcrum.get("shaft_diameter"))
        out["fulcrum"]["gamma"] = shafts[2]
    out["frames"] = frames
    return out


# --------------------------------------------------------------------------------------
# a sequence from its paths, and many sequences (locally or on a Dask cluster)


def sequence_files(sequence):
    """(images, files): a `pencilcal simulate` folder's images/ and the camera, board, pencil
    and truth files beside it; for any other SEQUENCE (folder, glob, video, or several image
    paths: a tuple) itself and {}."""
    if isinstance(sequence, (tuple, list)):
        if len(sequence) != 1:
            return tuple(sequence), {}
        sequence = sequence[0]
    p = Path(sequence)
    if p.is_dir() and (p / "images").is_dir():
        found = {k: p / n for k, n in (("camera", "camera.json"), ("board", "board.yaml"), ("pencil", "pencil.yaml"),
                                        ("truth", "truth.json")) if (p / n).is_file()}
        return p / "images", found
    return p, {}


def read_truth(path):
    """Truth frames by image name from a truth.json (`pencilcal simulate`)."""
    from pencilcal.toolkit.io.files import load_frames

    _, frames = load_frames(path, "truth file", ("image", "R_cam_from_target", "t_cam_from_target"))
    return {str(f["image"]): f for f, _ in frames}


def _has_images(p):
    from pencilcal.toolkit.io.images import IMAGE_EXTENSIONS, VIDEO_EXTENSIONS

    return any(q.is_file() and q.suffix.lower() in IMAGE_EXTENSIONS | VIDEO_EXTENSIONS for q in p.iterdir())


def find_sequences(path):
    """The sequence folders inside `path` when it is a folder of sequences (no images of its
    own; subfolders that are simulate folders or hold images), sorted; else None."""
    if isinstance(path, (tuple, list)):
        if len(path) != 1:
            return None  # several image paths: one sequence
        path = path[0]
    p = Path(path)
    if not p.is_dir() or (p / "images").is_dir() or _has_images(p):
        return None
    subs = sorted(q for q in p.iterdir() if q.is_dir() and ((q / "images").is_dir() or _has_images(q)))
    return subs or None


def validate_path(sequence, *, camera=None, camera_id=None, board=None, pencil=None, grid_pencil=None, truth=None,
                  models=MODELS, methods=METHODS, sfm=False, sfm_dir=None, detector="auto", calibration=None,
                  workers=1, progress=None, warn=None, quiet=True, sfm_progress=None, argv=None, edges=False,
                  mask=None, right=None, right_camera=None, right_calibration=None, fulcrum=None, shaft_diameter=None,
                  gamma=None, continuity=True, instrument_mask=None, mask_labels=(), mask_instances=False):
    """Validate one sequence given by paths; returns the whole validation.json dict.

    sequence: folder, glob, video, or a `pencilcal simulate` folder (whose camera, board,
    pencil and truth files are used for the arguments left None). camera, board, pencil,
    truth, calibration: file paths; grid_pencil: None, "auto" or (i, j) to use the board's
    grid lines as the pencil. argv: the command line to record (default sys.argv; a Dask
    worker's own is meaningless). edges: the fan's plain edge segments instead of its
    spokes' midlines (`FanLines`); mask: the frames' valid region file (default: detected,
    `toolkit.detect.region.detect.sequence_region`). right, right_camera,
    right_calibration: the images, camera file and calib.json of a second camera rigidly
    fixed to the first (a stereo pair, frames paired by image name): the rig check
    (`checks`). A calibration report of this camera lends its intrinsics covariance and
    corner-noise model to the PnP poses (``cov_total``) and its two-halves
    cross-validation to ``checks``. fulcrum: also the ``fulcrum`` record
    (`fulcrum_validation.fulcrum_record`: the instrument's shafts detected in every frame,
    the fulcrum and with shaft_diameter its 3-D point, against the truth where known);
    None: when the truth is a pivot scenario's (its shaft diameter then the default); gamma:
    the frames' encoding gamma for the shafts' edges (None: `detect_shafts`' default);
    instrument_mask, mask_labels, mask_instances: the frames' instrument masks (MASKS,
    `io.instrument_masks.source_masks`): the fulcrum's shafts are their instruments' axes
    (`detect.shaft.from_mask`). The other arguments (continuity among them) as
    `validate_sequence`. Module level and paths only, so a Dask worker can run it.
    """
    from pencilcal.toolkit.board.spec import read_board
    from pencilcal.toolkit.camera.formats import camera_to_dict, read_camera
    from pencilcal.toolkit.io.files import load_structured
    from pencilcal.toolkit.pencil.grid import GridPencil
    from pencilcal.toolkit.io.images import open_images
    from pencilcal.toolkit.pencil.spec import read_pencil

    images, found = sequence_files(sequence)
    if isinstance(sequence, (tuple, list)):
        sequence = " ".join(map(str, sequence))
    camera = camera or found.get("camera")
    board = board or found.get("board")
    truth = truth or found.get("truth")
    if camera is None:
        raise InputError(f"{sequence}: no camera file (give --camera; SEQUENCE is not a simulate folder)")
    if board is None:
        raise InputError(f"{sequence}: no board file (give --board; SEQUENCE is not a simulate folder)")
    cam = read_camera(camera, camera_id=camera_id)
    brd = read_board(board)
    if grid_pencil is not None:
        grid = GridPencil(brd, None if grid_pencil == "auto" else tuple(grid_pencil))
        lines = GridLines(grid)
        pencil_desc = {"grid": "auto" if grid_pencil == "auto" else list(grid_pencil),
                       "angles_deg": [float(a) for a in np.degrees(grid.angles)]}
        pencil = None
    else:
        pencil = pencil or found.get("pencil")
        if pencil is None:
            raise InputError(f"{sequence}: no pencil (give --pencil or --grid-pencil; SEQUENCE is not a simulate folder)")
        pen = read_pencil(pencil)
        lines = FanLines(pen, detector, edges)
        pencil_desc = pen.to_dict()
    truth_frames = read_truth(truth) if truth else None
    source = open_images(images)
    if isinstance(lines, FanLines):
        from pencilcal.toolkit.detect.region.detect import sequence_region

        lines.valid_region = sequence_region(source, mask, shape=(cam.height, cam.width))
    calib = load_structured(calibration, "calibration report") if calibration else None
    from .checks import stereo_inputs

    cam, rig, checks = stereo_inputs(cam, camera, calibration, brd, methods, right, right_camera, right_calibration)
    truth_doc = load_structured(truth, "truth file") if truth else {}
    pivot_truth = truth_doc.get("pivot") if isinstance(truth_doc, dict) else None
    pivot = None
    if fulcrum or (fulcrum is None and pivot_truth):
        if shaft_diameter is None and pivot_truth:
            shaft_diameter = (truth_doc.get("options") or {}).get("shaft_diameter")
        pivot = {"detector": detector, "valid_region": getattr(lines, "valid_region", None), "truth": pivot_truth,
                 "shaft_diameter": shaft_diameter, "gamma": gamma, "masks": None}
        if instrument_mask is not None:
            from pencilcal.toolkit.io.instrument_masks import source_masks

            pivot["masks"] = source_masks(source, instrument_mask, mask_labels, mask_instances)
    elif instrument_mask is not None:
        raise InputError(f"{instrument_mask}: instrument masks are for the fulcrum (--fulcrum)")
    result = validate_sequence(source, cam, brd, lines, truth=truth_frames, models=models, methods=methods, sfm=sfm,
                               sfm_workdir=sfm_dir, progress=progress, warn=warn, quiet=quiet,
                               sfm_progress=sfm_progress, workers=workers, fulcrum=pivot, continuity=continuity,
                               **rig)
    if checks:
        result["checks"] = {**checks, **result.get("checks", {})}
    inputs = [p for p in (camera, board, pencil, truth, calibration, mask, right_camera, right_calibration) if p]
    if pivot is not None and pivot["masks"] is not None:
        result["fulcrum"]["instrument_mask"] = str(instrument_mask)
        inputs += list(pivot["masks"].paths.values())
    return {
        "sequence": str(sequence),
        "images": str(images),
        "camera_file": str(camera),
        "camera": camera_to_dict(cam),
        "board": brd.to_dict(),
        "pencil": pencil_desc,
        "calibration": calib if calib is not None else (cam.meta or None),
        **result,
        "reproducibility": reproducibility([str(p) for p in inputs] + [str(p) for p in getattr(source, "paths", [])],
                                           argv=argv),
    }


def _one(sequence, options):
    """validate_path for one of many sequences: a failure is a record, not an exception."""
    try:
        return {"name": Path(sequence).name, "ok": True, **validate_path(str(sequence), **options)}
    except (EstimationError, InputError) as e:
        return {"name": Path(sequence).name, "ok": False, "error": str(e), "sequence": str(sequence)}


def validate_many(sequences, options, dask=None, progress=None):
    """Validate several sequences, locally one after the other or each on a Dask cluster.

    sequences: paths; options: keyword arguments of `validate_path` (plain values); dask:
    None, or the address of a dask.distributed scheduler ("tcp://host:8786") to which every
    sequence is sent as one task. progress: callable(done, total). Results are identical
    either way (the same functions run, in order of `sequences`). Returns the combined
    validation.json dict: ``sequences`` (each with ``name``, ``ok`` and the validation or
    ``error``) and ``summary`` pooled over the frames of all sequences.
    """
    sequences = [str(s) for s in sequences]
    options = {"argv": list(sys.argv), **options}
    if dask is None:
        results = []
        for i, s in enumerate(sequences):
            results.append(_one(s, options))
            if progress:
                progress(i + 1, len(sequences))
    else:
        try:
            from distributed import Client, as_completed
        except ImportError:
            raise InputError('--dask needs the dask extra: pip install -e ".[dask]"') from None
        try:
            client = Client(dask, timeout="15s")
        except (OSError, TimeoutError) as e:
            raise InputError(f"{dask}: cannot reach the Dask scheduler ({str(e).splitlines()[0]})") from None
        with client:
            futures = [client.submit(_one, s, options, pure=False) for s in sequences]
            done = 0
            for _ in as_completed(futures):
                done += 1
                if progress:
                    progress(done, len(sequences))
            results = client.gather(futures)
    ok = [r for r in results if r["ok"]]
    if not ok:
        raise EstimationError("no sequence could be validated: " + "; ".join(f"{r['name']}: {r['error']}" for r in results))
    keys = []
    for r in ok:
        for k in r["summary"]:
            if k not in keys:
                keys.append(k)
    pooled = summarise([f for r in ok for f in r["frames"]], keys)
    return {"sequences": results, "summary": pooled, "reference": sorted({r["reference"] for r in ok}),
            "reproducibility": reproducibility([], argv=options["argv"])}

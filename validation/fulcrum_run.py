"""The fulcrum of a sequence with the sigmas `pencilcal fulcrum` writes.

`toolkit.pencil.fulcrum.fulcrum_from_frames` fits the lines with the noise they are given.
What the command writes holds two more steps, and a Python user gets the same from
`fulcrum_with_sigmas`:

1. the noise the lines show (`toolkit.pencil.sequence_noise.fulcrum_with_noise`): estimated
   from the residuals for segments without sigmas of their own, only ever inflated for the
   detector's sigmas (shaft midlines), kept where the user gave it;
2. with `JACKKNIFE_FRAMES` frames or more, each frame left out once
   (`checks.fulcrum_jackknife`, `checks.point_jackknife`): where the frames scatter the
   fulcrum significantly more than its sigmas say, the sigmas become the jackknife's.

Example
-------
>>> res = fulcrum_with_sigmas(camera, frames)                         # doctest: +SKIP
>>> res.noise["sigma_scale"], res.jackknife["inflated"], res.warnings  # doctest: +SKIP
"""
from __future__ import annotations

import dataclasses

from pencilcal.toolkit.errors import EstimationError
from pencilcal.toolkit.pencil.defaults import ENDPOINT_SIGMA_PX
from pencilcal.toolkit.pencil.fulcrum import fulcrum_from_frames
from pencilcal.toolkit.pencil.sequence_noise import fulcrum_with_noise

__all__ = ["fulcrum_with_sigmas", "jackknife_sigmas", "fulcrum_epochs", "epochs_record", "point_epochs_record",
           "JACKKNIFE_FRAMES"]

#: Frames with a line below which the jackknife is not run (too few to judge the spread).
JACKKNIFE_FRAMES = 8


def fulcrum_with_sigmas(camera, frames, angles=None, *, endpoint_sigma_px=None, shaft_diameter=None, where=None,
                        jackknife_frames=JACKKNIFE_FRAMES):
    """The fulcrum of lines.json `frames` with the sigmas `pencilcal fulcrum` writes (module
    docstring): a `Fulcrum` with its ``noise`` and ``jackknife`` records set.

    camera: Camera; angles: (F,) pivot angles [rad] or None; endpoint_sigma_px: the end
    point noise [px] of segments without sigmas of their own, as given by the user (kept),
    or None (`ENDPOINT_SIGMA_PX` assumed, then estimated); shaft_diameter: for the 3-D
    fulcrum; where: a name for error messages (the input's path); jackknife_frames: the
    fewest frames with a line the jackknife is run on. Its ``warnings`` say what to tell the
    user: first whether the noise or the jackknife raised the sigmas, then the fit's own.
    EstimationError when there is no fulcrum.
    """
    given = endpoint_sigma_px is not None
    sigma = float(endpoint_sigma_px) if given else ENDPOINT_SIGMA_PX

    def run(s):
        try:
            return fulcrum_from_frames(camera, frames, angles=angles, endpoint_sigma_px=s,
                                       shaft_diameter=shaft_diameter)
        except EstimationError as e:
            if where is None:
                raise
            raise EstimationError(f"{where}: {e}") from None

    res, noise, message = fulcrum_with_noise(run(sigma), run, sigma, frames, given=given)
    used = sigma * (noise.get("sigma_scale", 1.0) if "assumed_endpoint_sigma_px" in noise else 1.0)
    res, jackknife, more = jackknife_sigmas(res, camera, frames, angles, used, jackknife_frames)
    said = ([message] if message else []) + more
    return dataclasses.replace(res, noise=noise, jackknife=jackknife, warnings=(*said, *res.warnings))


def jackknife_sigmas(res, camera, frames, angles=None, endpoint_sigma_px=ENDPOINT_SIGMA_PX, min_frames=JACKKNIFE_FRAMES):
    """(Fulcrum, the fulcrum.json ``jackknife`` record or None, messages): each frame with a
    line left out once (`checks.fulcrum_jackknife`, with the noise the fit used:
    endpoint_sigma_px), and the sigmas raised to the jackknife's where the frames scatter
    the fulcrum significantly more than they say (`checks.jackknife_inflation`; the 3-D
    point's by `checks.point_jackknife`). None with fewer than `min_frames` frames."""
    from pencilcal.validation.checks import fulcrum_jackknife, jackknife_inflation, point_jackknife

    if sum(1 for f in frames if len(f.get("segments", ())) or f.get("shafts")) < min_frames:
        return res, None, []
    try:
        jk = fulcrum_jackknife(camera, frames, angles, full=res, endpoint_sigma_px=endpoint_sigma_px)
    except EstimationError:
        return res, None, []
    out, rec = jackknife_inflation(res, jk)
    messages = []
    if rec["inflated"]:
        messages.append(f"leaving one frame out at a time moves the fulcrum's ray by "
                        f"{rec['ray_sigma_jackknife_deg']:.3g} deg, {rec['ratio']:.2g} times its sigma: the lines of "
                        "different frames disagree (a fulcrum that moved, shafts misdetected in some frames); its "
                        "sigmas are the jackknife's")
    if out.point is not None:
        point, prec = point_jackknife(camera, frames, out.point.diameter, out.point)
        rec["point"] = prec
        if prec.get("reason"):
            messages.append(f"the 3-D fulcrum's jackknife is not judged: {prec['reason']}")
        if prec["inflated"]:
            messages.append(f"leaving one frame out at a time moves the 3-D fulcrum by "
                            f"{prec['point_sigma_jackknife']:.3g} (RMS), {prec['ratio']:.2g} times its sigma: its "
                            "covariance is the jackknife's")
            out = dataclasses.replace(out, point=point)
    return out, rec, messages


def fulcrum_epochs(camera, frames, angles=None, *, endpoint_sigma_px=None, shaft_diameter=None, alpha=None,
                   min_frames=None):
    """The pivot epochs of lines.json `frames` (`toolkit.pencil.epochs.frame_epochs`) and,
    when the fulcrum moved, each epoch's fulcrum with its sigmas (`fulcrum_with_sigmas` on
    its frames, the jackknife from the epoch's least number of frames on).

    Returns (`Epochs`, per epoch (Fulcrum or None, its error message or None)); with one
    epoch the list is empty (the sequence's fulcrum is the epoch's). angles: (F,) pivot
    angles [rad] or None; alpha, min_frames: the change-point test's (None: its defaults).
    """
    import numpy as np

    from pencilcal.toolkit.pencil.epochs import ALPHA, MIN_FRAMES, frame_epochs

    ep = frame_epochs(camera, frames, endpoint_sigma_px, alpha=ALPHA if alpha is None else alpha,
                      min_frames=MIN_FRAMES if min_frames is None else min_frames)
    out = []
    if len(ep.bounds) > 1:
        for a, b in ep.bounds:
            try:
                out.append((fulcrum_with_sigmas(camera, frames[a:b], None if angles is None else np.asarray(angles)[a:b],
                                                endpoint_sigma_px=endpoint_sigma_px, shaft_diameter=shaft_diameter,
                                                jackknife_frames=ep.min_frames), None))
            except EstimationError as e:
                out.append((None, str(e)))
    return ep, out


def epochs_record(ep, results, names, priors=None):
    """fulcrum.json's ``epoch_test`` record and its ``epochs`` list (docs/formats.md): the
    change-point test (alpha, min_frames, its change points, the runs it kept whole with
    the p-value of their best split, and the changes merged again), and per epoch its frames (``first``, ``last``
    indices, ``images``) with its fulcrum's record (``ok`` false and ``error`` where it has
    none) and, given, its ``axis_prior`` (priors: one `shaft.prior.AxisPrior` or None per
    epoch, `shaft.prior.prior_record`)."""
    from pencilcal.toolkit.detect.shaft.prior import prior_record

    test = _test_record(ep, names)
    epochs = []
    for e, ((a, b), (res, err)) in enumerate(zip(ep.bounds, results)):
        rec = {"first": a, "last": b - 1, "images": list(names[a:b])}
        rec.update(res.to_dict() if res is not None else {"ok": False, "error": err})
        if res is not None and res.warnings:
            rec["warnings"] = list(res.warnings)
        if priors is not None and priors[e] is not None:
            rec["axis_prior"] = prior_record(priors[e])
        epochs.append(rec)
    return test, epochs


def _test_record(ep, names):
    """The ``epoch_test`` record of `epochs.Epochs` (`epochs_record`)."""
    return {"alpha": ep.alpha, "min_frames": ep.min_frames, "epochs": len(ep.bounds),
            "change_points": [c.to_dict(names) for c in ep.changes],
            "kept": [{"frames": [a, b - 1], "p_corrected": p} for a, b, p in ep.kept],
            "merged": [{"index": k, "p_value": p} for k, p in ep.merged]}


def point_epochs_record(camera, frames, diameter, names):
    """fulcrum.json's ``point_epoch_test`` and ``point_epochs`` records of frames whose
    ``camera_pose`` carries their camera (--stabilize with poses): the change-point test on
    the 3-D axes carried into the reference camera (`toolkit.pencil.axis_epochs.point_epochs`;
    its change points' ``vertices_ideal_px`` are here ``points``, the two fits' 3-D points)
    and, where it splits, each epoch's frames (``first``, ``last``, ``images``) with its 3-D
    fulcrum's record (`fulcrum.fulcrum_point`) and ``jackknife`` (`checks.point_jackknife`:
    the covariance is the jackknife's where the frames scatter the point significantly
    more), or ``ok`` false and ``error``. (None, []) where no frame has a pose."""
    from pencilcal.toolkit.pencil.axis_epochs import point_epochs
    from pencilcal.toolkit.pencil.fulcrum import fulcrum_point
    from pencilcal.validation.checks import point_jackknife

    ep = point_epochs(camera, frames, diameter)
    if ep is None:
        return None, []
    test = _test_record(ep, names)
    for c in test["change_points"]:
        c["points"] = c.pop("vertices_ideal_px")
    out = []
    for a, b in ep.bounds if len(ep.bounds) > 1 else ():
        rec = {"first": a, "last": b - 1, "images": list(names[a:b])}
        try:
            point = fulcrum_point(camera, frames[a:b], diameter)
            point, jk = point_jackknife(camera, frames[a:b], diameter, point)
            rec.update(ok=True, **point.to_dict(), jackknife=jk)
        except EstimationError as e:
            rec.update(ok=False, error=str(e))
        out.append(rec)
    return test, out

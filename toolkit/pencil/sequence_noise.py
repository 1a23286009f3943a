"""The line noise of a sequence, estimated from its residuals: the a-posteriori variance factor.

orient assumes a line noise when none is given (0.5 px at each segment end point). The
frames' fits say how good that guess was: every frame's chi-square ``chi2_i`` (weighted
squared angle residuals at the estimate) has ``dof_i = lines - 3`` degrees of freedom, and
under the assumed noise ``E[chi2_i] = dof_i``. The pooled factor::

    s0^2 = sum chi2_i / sum dof_i

is the ratio of the true to the assumed noise variance, with ``sum dof_i`` degrees of
freedom: every frame's covariance is multiplied by it (its sigmas by s0), so the sigmas hold
the noise the sequence shows, not the one assumed.

An assumed noise far too small also truncates what the fits see: a frame's line gates
(which segments pass through the vertex, which fit a spoke) then drop the larger errors,
and the pooled factor comes out low. `estimate_sequence_noise` therefore runs the frames
again with the noise estimated so far while the factor is far from 1, until the gates fit
the noise (the factor is the product of the runs').

Outlier frames (a stray line kept, a misdetected spoke) would inflate it: frames whose
``chi2_i / dof_i`` lies beyond the 99.9 % point of chi2(dof_i) / dof_i at the current
factor are left out of the pool and the factor re-estimated, until nothing changes
(starting from the median of the frames' factors, which no minority of outliers moves far).
Their own sigmas are scaled by the pooled factor too: they are not wrong in noise, only in
model.

What a command writes comes from `orientations_with_noise` and `fulcrum_with_noise`: the
noise the user gave, estimated (lines without sigmas of their own), or only inflated (the
detector's sigmas), with the record that says which and a warning where the lines scatter
more than twice or less than half what was assumed.

The fulcrum is one fit over the whole sequence: its factor is its own intersection's
``chi2 / (lines - 2)`` (the robust fit's inliers), and the pivot plane's that of its fit
(`fulcrum_noise`). Where the lines carry the detector's own sigmas (shaft midlines, with
their measured floor) the factor only inflates: a fit that scatters less than the
detector says keeps the detector's sigmas.

Example
-------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> dof = np.full(40, 5)
>>> chi2 = 4.0 * rng.chisquare(5, 40)  # the noise is twice the assumed one
>>> chi2[3] = 500.0                     # one frame with a stray line
>>> est = variance_factor(chi2, dof)
>>> 1.6 < est.scale < 2.4, est.frames, est.rejected
(True, 39, 1)
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.geometry.quantiles import chi2_isf
from pencilcal.toolkit.pencil.defaults import MIN_ENDPOINT_SIGMA_PX

__all__ = ["NoiseEstimate", "inflation", "variance_factor", "sequence_noise", "estimate_sequence_noise", "rescale",
           "fulcrum_noise", "rescale_fulcrum", "estimate_fulcrum_noise", "orientations_with_noise",
           "fulcrum_with_noise", "MIN_DOF", "MAX_RUNS"]

#: The pooled degrees of freedom below which the factor is not estimated (too uncertain:
#: its relative sd is sqrt(2 / dof)).
MIN_DOF = 10
# a frame is an outlier beyond this point of its chi-square distribution
_OUTLIER_LEVEL = 0.999
_ITERATIONS = 20
# a first factor outside this band (sigma scale 0.9-1.1) runs the frames again with the
# estimated noise: the gates of the first run were set for another noise
_RERUN_BAND = (0.9**2, 1.1**2)
#: Runs at most of `estimate_sequence_noise` and `estimate_fulcrum_noise`.
MAX_RUNS = 5


@dataclass(frozen=True)
class NoiseEstimate:
    """The estimated noise of a sequence.

    variance_factor: s0^2, true / assumed noise variance; scale: s0 (the sigmas' factor);
    dof: pooled degrees of freedom (the factor's relative sd is sqrt(2 / dof)); frames:
    frames pooled; rejected: frames left out as outliers.
    """

    variance_factor: float
    dof: int
    frames: int
    rejected: int

    @property
    def scale(self) -> float:
        return float(np.sqrt(self.variance_factor))

    def to_dict(self) -> dict:
        """The orientation.json header record ``noise``."""
        return {"estimated": True, "variance_factor": self.variance_factor, "sigma_scale": self.scale,
                "dof": self.dof, "frames": self.frames, "rejected_frames": self.rejected}


def inflation(chi2, dof=1):
    """The a-posteriori variance factor ``chi2 / dof`` taken only to inflate: at least 1,
    and 1 where there is no redundancy (dof <= 0). dof=1 takes `chi2` as a factor already.
    The one home of the inflate-only factor every fit here takes where its inputs carry
    their own sigmas (a fit that scatters less than its inputs say keeps them).

    >>> inflation(30.0, 10), inflation(5.0, 10), inflation(5.0, 0), inflation(0.8)
    (3.0, 1.0, 1.0, 1.0)
    """
    return max(1.0, float(chi2) / dof) if dof > 0 else 1.0


def variance_factor(chi2, dof):
    """The robust pooled a-posteriori variance factor of frames' fits.

    chi2: (F,) each frame's chi-square at its estimate; dof: (F,) its degrees of freedom
    (frames with dof <= 0 carry no information and are skipped). Returns a `NoiseEstimate`,
    or None when the pooled dof is under `MIN_DOF`.
    """
    chi2 = np.asarray(chi2, float)
    dof = np.asarray(dof, float)
    use = (dof > 0) & np.isfinite(chi2)
    chi2, dof = chi2[use], dof[use]
    if dof.sum() < MIN_DOF:
        return None
    s2 = float(np.median(chi2 / dof))
    keep = np.ones(chi2.size, bool)
    limit = chi2_isf(1.0 - _OUTLIER_LEVEL, dof)
    for _ in range(_ITERATIONS):
        new = chi2 <= max(s2, 1e-300) * limit
        if dof[new].sum() < MIN_DOF:
            new = keep
        s2 = float(chi2[new].sum() / dof[new].sum())
        if np.array_equal(new, keep):
            break
        keep = new
    return NoiseEstimate(variance_factor=s2, dof=int(dof[keep].sum()), frames=int(keep.sum()),
                         rejected=int((~keep).sum()))


def rescale(record, factor):
    """The `Orientation` `record` with its noise covariances multiplied by `factor` (s0^2):
    tilt, normal and vertex sigmas, the noise-equivalent tilt, and the noise part of the
    totals (the intrinsics' part stays)."""
    if not record.ok:
        return record
    s = float(np.sqrt(factor))

    def scaled(sigma, shutter):
        # a rolling shutter's part (`shutter.shear_widened`) is no line noise: it stays
        if not shutter:
            return sigma * s
        return float(np.hypot(np.sqrt(max(sigma**2 - shutter**2, 0.0)) * s, shutter))

    ch = {"tilt_sigma_deg": scaled(record.tilt_sigma_deg, record.tilt_sigma_shutter_deg),
          "normal_sigma_deg": scaled(record.normal_sigma_deg, record.normal_sigma_shutter_deg)}
    if record.vertex_cov_px2 is not None:
        ch["vertex_cov_px2"] = np.asarray(record.vertex_cov_px2) * factor
    if record.tilt_threshold_deg is not None:
        ch["tilt_threshold_deg"] = record.tilt_threshold_deg * s
    for total, noise in (("tilt_sigma_total_deg", "tilt_sigma_deg"), ("normal_sigma_total_deg", "normal_sigma_deg")):
        t = getattr(record, total)
        if t is not None:
            lens2 = max(t**2 - getattr(record, noise) ** 2, 0.0)
            ch[total] = float(np.sqrt(lens2 + ch[noise] ** 2))
    if record.vertex_cov_total_px2 is not None and record.vertex_cov_px2 is not None:
        lens = np.asarray(record.vertex_cov_total_px2) - np.asarray(record.vertex_cov_px2)
        ch["vertex_cov_total_px2"] = lens + ch["vertex_cov_px2"]
    return record.replace(**ch)


def sequence_noise(records, inflate_only=False):
    """(records rescaled, NoiseEstimate or None): the variance factor of the ok records'
    fits (their ``chi2`` and ``lines_used``; the exact estimator's 3 parameters) applied to
    each of them. None, and the records unchanged, when the pool has under `MIN_DOF`.
    inflate_only: a factor below 1 is taken as 1 (lines with the detector's own sigmas)."""
    ok = [r for r in records if r.ok and r.chi2 is not None]
    est = _inflate_only(variance_factor([r.chi2 for r in ok], [r.lines_used - 3 for r in ok]), inflate_only)
    if est is None:
        return list(records), None
    return [rescale(r, est.variance_factor) for r in records], est


def _with_factor(est, factor):
    return None if est is None else NoiseEstimate(float(factor), est.dof, est.frames, est.rejected)


def estimate_sequence_noise(run, sigma, first=None, floor=None):
    """The frames oriented with the noise their residuals show.

    run: callable(sigma) -> list of `Orientation`, the frames oriented with the assumed
    noise `sigma` (e.g. the end point sd [px]); sigma: the assumed noise. While a run's
    factor lies outside 0.9-1.1 in sigma, the frames are run again with the noise
    estimated so far (at most `MAX_RUNS` runs), so that their gates fit the noise.
    first: the records of run(sigma) when the caller has them already (not run again).
    floor: the smallest noise to believe (in sigma's unit): a smaller estimate is raised to
    it (exact lines would otherwise get sigmas of zero).

    Returns (records, NoiseEstimate or None): the records' covariances hold the estimated
    noise; the estimate's factor is relative to `sigma` (the noise used is sigma *
    estimate.scale). None (and the first run's records unchanged) when the pool has under
    `MIN_DOF` degrees of freedom.
    """
    def estimate(records):
        scaled, est = sequence_noise(records)
        return scaled, None if est is None else est.variance_factor, est

    records, est, total, _, low = _steady_runs(run, sigma, estimate, first, floor)
    if total is None:
        return records, None
    if total < low:
        records = [rescale(r, low / total) for r in records]
        total = low
    return records, _with_factor(est, total)


def _steady_runs(run, sigma, estimate, first=None, floor=None):
    """The runs of `estimate_sequence_noise` and `estimate_fulcrum_noise`: run(sigma) with
    the noise estimated so far until a run's own factor lies within 0.9-1.1 in sigma (or the
    runs sit at the floor), at most `MAX_RUNS`. estimate(result) -> (the result rescaled,
    its factor or None when it cannot tell, its estimates). Returns (the last rescaled
    result, its estimates, the total factor relative to `sigma` or None, the last run's own
    factor, the floor's factor)."""
    low = 0.0 if floor is None else (floor / sigma) ** 2
    total, best = 1.0, None
    for i in range(MAX_RUNS):
        result = first if i == 0 and first is not None else run(sigma * np.sqrt(total))
        scaled, factor, est = estimate(result)
        if factor is None:
            return best or (scaled, est, None, None, low)
        ran_at_floor = total <= low
        total *= factor
        best = (scaled, est, total, factor, low)
        if _RERUN_BAND[0] <= factor <= _RERUN_BAND[1] or (ran_at_floor and total <= low):
            break
        # the next run's gates never below the floor
        total = max(total, low)
    return best


def _inflate_only(est, inflate_only):
    if est is None or not inflate_only or est.variance_factor >= 1.0:
        return est
    return NoiseEstimate(inflation(est.variance_factor), est.dof, est.frames, est.rejected)


def rescale_fulcrum(fulcrum, factor, pivot_factor=None):
    """The `fulcrum.Fulcrum` with its vertex's noise covariance multiplied by `factor`
    (vertex_cov_px2, ray_sigma_deg and the noise part of the totals) and its pivot plane's
    by `pivot_factor` (`rescale`; default the same factor). The 3-D point keeps its own."""
    f, s = float(factor), float(np.sqrt(factor))
    ch = {"ray_sigma_deg": fulcrum.ray_sigma_deg * s}
    if fulcrum.vertex_cov_px2 is not None:
        ch["vertex_cov_px2"] = np.asarray(fulcrum.vertex_cov_px2) * f
    if fulcrum.ray_sigma_total_deg is not None:
        lens2 = max(fulcrum.ray_sigma_total_deg**2 - fulcrum.ray_sigma_deg**2, 0.0)
        ch["ray_sigma_total_deg"] = float(np.sqrt(lens2 + ch["ray_sigma_deg"] ** 2))
    if fulcrum.vertex_cov_total_px2 is not None and fulcrum.vertex_cov_px2 is not None:
        ch["vertex_cov_total_px2"] = (np.asarray(fulcrum.vertex_cov_total_px2)
                                      - np.asarray(fulcrum.vertex_cov_px2) + ch["vertex_cov_px2"])
    if fulcrum.pivot is not None:
        ch["pivot"] = rescale(fulcrum.pivot, f if pivot_factor is None else pivot_factor)
    return dataclasses.replace(fulcrum, **ch)


def fulcrum_noise(fulcrum, inflate_only=False):
    """(Fulcrum rescaled, {"vertex": NoiseEstimate or None, "pivot": ... or None}).

    fulcrum: a `fulcrum.Fulcrum`. The vertex's factor is its intersection's chi2 / (lines
    used - 2) (chi2 = rms^2 * lines used); it scales vertex_cov_px2, ray_sigma_deg and the
    noise part of the totals. The pivot plane's is its fit's chi2 / (frames - 3) when
    that has `MIN_DOF`, else the vertex's. inflate_only: never below 1 (lines with the
    detector's own sigmas).
    """
    k = int(fulcrum.lines_used)
    est = variance_factor([fulcrum.rms**2 * k], [k - 2])
    est = _inflate_only(None if est is None else NoiseEstimate(est.variance_factor, est.dof, fulcrum.frames_used,
                                                               len(fulcrum.outliers)), inflate_only)
    pivot_est = None
    if fulcrum.pivot is not None:
        p = fulcrum.pivot
        pivot_est = None if p.chi2 is None else variance_factor([p.chi2], [p.lines_used - 3])
        pivot_est = _inflate_only(pivot_est, inflate_only) or est
    if est is None and pivot_est is None:
        return fulcrum, {"vertex": None, "pivot": None}
    out = rescale_fulcrum(fulcrum, 1.0 if est is None else est.variance_factor,
                          None if pivot_est is None else pivot_est.variance_factor)
    if fulcrum.pivot is not None and pivot_est is None:
        out = dataclasses.replace(out, pivot=fulcrum.pivot)
    return out, {"vertex": est, "pivot": pivot_est}


def estimate_fulcrum_noise(run, sigma, floor=None):
    """`fulcrum_noise` with the gates of the estimated noise (as `estimate_sequence_noise`):
    run: callable(sigma) -> Fulcrum with the assumed line noise sigma (the end point sd
    [px] of segments without their own), run again with the noise estimated so far while
    the factor lies outside 0.9-1.1 in sigma; floor: the smallest noise to believe.
    Returns (Fulcrum, estimates) as `fulcrum_noise`, the factors relative to `sigma`."""
    def estimate(f):
        out, est = fulcrum_noise(f)
        v = est["vertex"]
        return out, None if v is None else v.variance_factor, est

    f, est, total, factor, low = _steady_runs(run, sigma, estimate, floor=floor)
    if total is None:
        return f, est
    pivot = est["pivot"]
    pivot = None if pivot is None else _with_factor(pivot, pivot.variance_factor * total / factor)
    if total < low:
        f = rescale_fulcrum(f, low / total)
        total = low
    return f, {"vertex": _with_factor(est["vertex"], total), "pivot": pivot}


# ------------------------------------------------------------------ what a command writes


def orientations_with_noise(records, run, sigma, *, given=False, estimable=True, angle_sigma=None,
                            floor=MIN_ENDPOINT_SIGMA_PX, fix_hint=None):
    """(records, the orientation.json ``noise`` record, a warning or None): a sequence's
    orientations with the noise they hold, as `pencilcal orient` writes them.

    records: the frames' `Orientation` from ``run(sigma)``; run: callable(sigma) -> the
    frames oriented again with end point noise sigma [px]; given: the user gave the noise
    (nothing is estimated; `angle_sigma` [deg] is recorded beside sigma); estimable: the
    lines carry no sigmas of their own (a lines file of plain segments): the noise is
    estimated, the frames run again with it (`estimate_sequence_noise`, never below
    `floor` [px]); otherwise (the detector's own sigmas) the sigmas are only ever inflated
    (`sequence_noise`). The warning says when the lines scatter more than twice or less
    than half what was assumed; fix_hint: how to fix the noise instead, said in it.
    """
    if given:
        return records, {"estimated": False, "endpoint_sigma_px": sigma, "angle_sigma_deg": angle_sigma}, None
    if estimable:
        out, est = estimate_sequence_noise(run, sigma, first=records, floor=floor)
        kind = {"assumed_endpoint_sigma_px": sigma}
    else:
        out, est = sequence_noise(records, inflate_only=True)
        kind = {"inflate_only": True}
    if est is None:
        return records, {"estimated": False, "reason": "too few degrees of freedom to estimate the noise", **kind}, None
    message = None
    if not (0.5 < est.scale < 2.0):
        said = f"the assumed {sigma:g} px end point noise" if estimable else "their own sigmas say"
        message = (f"the lines scatter {est.scale:.2g} times as much as {said}: every sigma is scaled by that "
                   f"(from {est.frames} frames, {est.dof} degrees of freedom" + (f"; {fix_hint})" if fix_hint else ")"))
    return out, {**est.to_dict(), **kind}, message


def fulcrum_with_noise(fulcrum, run, sigma, frames, *, given=False, floor=MIN_ENDPOINT_SIGMA_PX):
    """(Fulcrum, the fulcrum.json ``noise`` record, a warning or None): the fulcrum with the
    noise its lines show, as `pencilcal fulcrum` writes it.

    fulcrum: ``run(sigma)``'s `fulcrum.Fulcrum`; run: callable(sigma) -> the fulcrum found
    again with end point noise sigma [px] for segments without their own sigmas; frames:
    the lines.json frames it came from; given: the user gave the noise (nothing
    estimated). Where its lines are segments without sigmas of their own the noise is
    estimated, the fit run again with it (`estimate_fulcrum_noise`, never below `floor`
    [px]); otherwise (shaft midlines, a lines file's angle sigmas) only ever inflated
    (`fulcrum_noise`). The warning says when the lines scatter more than twice or less
    than half what their sigmas say.
    """
    estimable = fulcrum.lines_from == "segments" and not any(f.get("angle_sigma_deg") is not None for f in frames)
    if given:
        return fulcrum, {"estimated": False, "endpoint_sigma_px": sigma}, None
    if estimable:
        out, est = estimate_fulcrum_noise(run, sigma, floor=floor)
        kind = {"assumed_endpoint_sigma_px": sigma}
    else:
        out, est = fulcrum_noise(fulcrum, inflate_only=True)
        kind = {"inflate_only": True}
    v, p = est["vertex"], est["pivot"]
    if v is None:
        return fulcrum, {"estimated": False, "reason": "too few degrees of freedom to estimate the noise", **kind}, None
    message = None
    if not (0.5 < v.scale < 2.0):
        message = (f"the fulcrum's lines scatter {v.scale:.2g} times as much as their sigmas say: its sigmas are "
                   f"scaled by that ({v.dof} degrees of freedom)")
    return out, {**v.to_dict(), **kind, "pivot": None if p is None else p.to_dict()}, message

"""The parallax term of stabilised lines: what a background homography cannot carry.

`fulcrum --stabilize` carries each frame's lines into the reference frame by the
homography of the background (`detect.background_motion`). That is exact for a camera that
turns about its centre; where the camera also translates, the homography of the background
(a surface at some depth) carries a point at another depth with a parallax error. For a
plane, ``H = K (R + t n^T / d) K^-1`` and a point at depth Z lands off ``H x`` by about::

    f |t| / d * |d / Z - d / Z_plane|        [px]

The first factor, ``f |t| / d``, is the frame's: the departure of ``K^-1 H K`` from a
rotation measures ``|t| / d`` (its singular values' ratio less 1,
``FrameMotion.non_rotation``), so `stabilize_frames` gives every mapped shaft a parallax
scale ``parallax_scale_px = f * non_rotation`` (0 for the reference frame and for a camera
that only turns). The second is the point's: the fulcrum's inverse depth off the
background's, in units of the background's, the same for every frame (the fulcrum and the
scene do not move). It is not known before the fit, and the homographies do not give it;
the lines do. Each mapped line passes the fulcrum's image off by that frame's parallax,
which for the fulcrum fit is a shift of the line at the vertex, so each line's offset
variance takes ``(kappa * parallax_scale_px)^2``, one ``kappa`` for the sequence:

- where the lines' chi2 about their common point is within its degrees of freedom
  (lines - 2), kappa is 0 and nothing changes;
- otherwise kappa is the one that brings the inliers' chi2 to its degrees of freedom (a
  variance component, taken only to inflate as the a-posteriori variance factor is, but
  added in proportion to each frame's own parallax scale instead of multiplying every
  line's covariance), the robust fit run again with it until kappa holds (`ROUNDS` at
  most). It is not gated on a significance level: each leave-one-out fit of the
  jackknife estimates its own kappa, and a gate that some of them pass and others not
  moves their points by the change of weights, not by the data (on the phantom a gate at
  99 % gave the jackknife 1.43 times the sigma, 2.80 for frames 1-14).

Where the parallax scales are nearly 0 (a still camera, or one that only turns) the term
cannot take the lines' excess scatter, which then goes to the variance factor as before
(`sequence_noise.fulcrum_noise`).

Unlike a common factor, the term weights the frames by how far the camera moved: a frame
near the reference keeps its precision, one after a long translation loses it whatever its
detection's sigma. Not modelled: the direction of the parallax (towards the epipole, so a
line along it is not moved), taken as across every line.

>>> import numpy as np
>>> segs = np.array([[0.0, 0, 100, 0], [0, 10, 100, 110], [50, -50, 50, 50], [0, 40, 100, -60]])
>>> fit, rec, sc = vertex_with_parallax(segs, np.full(4, 0.002), np.full(4, 0.3), np.zeros(4))
>>> rec is None, bool(np.allclose(sc, 0.3))
(True, True)
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.geometry.quantiles import chi2_isf, chi2_sf
from pencilcal.toolkit.pencil.vertex import intersect_lines

__all__ = ["vertex_with_parallax", "ROUNDS", "MAJORITY"]

#: Robust fits at most while kappa settles.
ROUNDS = 20
#: The least share of the lines the term settled from 0 keeps before it starts again from
#: the median (`vertex_with_parallax`'s median_start); a robust fit's breakdown point.
MAJORITY = 0.5
# kappa^2 has settled when it changes by less than this, relatively
_TOL = 1e-6


def _kappa2(e2, own, p2, dof):
    """The kappa^2 >= 0 that brings sum e2 / (own + kappa^2 p2) to dof (bisection; it
    decreases in kappa^2): e2 (n,) squared residuals [px^2], own (n,) the lines' own
    variances at the vertex, p2 (n,) squared parallax scales. 0 where the sum is within dof
    already; the largest bracket tried where lines without parallax alone exceed it."""
    def chi(k):
        return float(np.sum(e2 / (own + k * p2)))

    if chi(0.0) <= dof or not np.any(p2 > 0):
        return 0.0
    lo, hi = 0.0, float(np.sum(e2) / np.sum(p2)) + 1e-12
    for _ in range(200):
        if chi(hi) <= dof:
            break
        lo, hi = hi, 4.0 * hi
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if chi(mid) > dof else (lo, mid)
        if hi - lo <= _TOL * hi:
            break
    return hi


def _median_start(fit, own, p2):
    """A first kappa^2 >= 0 that brings the median of every line's chi2 (1 dof) at the fit's
    vertex to its own median (0.455), outliers and all (e2 from `fit` (N,), own (N,) the
    lines' own variances at the vertex, p2 (N,) squared scales), by bisection; 0 where the
    median is within it. A start that the gate of too small a noise cannot bias: that gate
    keeps only the lines that happen to pass close, whose scatter says there is none."""
    e2 = (np.asarray(fit.residuals) * np.asarray(fit.sigmas)) ** 2
    med = float(chi2_isf(0.5, 1))  # chi2(1)'s median

    def over(k):
        return float(np.median(e2 / (own + k * p2))) > med
    if not over(0.0) or not np.any(p2 > 0):
        return 0.0
    lo, hi = 0.0, float(np.max(e2 / np.maximum(p2, 1e-300))) + 1e-12
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if over(mid) else (lo, mid)
        if hi - lo <= _TOL * hi:
            break
    return hi


def _settle(segments, angle_sigma, sc, p2, fit, k2):
    """(VertexFit, kappa^2, offset sigmas used (N,)): the robust fit run again with kappa^2
    until kappa^2 holds (`ROUNDS` at most), from `fit` made with the start `k2`."""
    used = np.sqrt(sc**2 + k2 * p2)
    for _ in range(ROUNDS):
        inl = fit.inliers
        e2 = (fit.residuals * fit.sigmas)[inl] ** 2
        own = fit.sigmas[inl] ** 2 - k2 * p2[inl]  # the lines' own variance at the vertex
        new = _kappa2(e2, own, p2[inl], fit.lines_used - 2)
        done = abs(new - k2) <= _TOL * max(new, 1e-300)
        k2 = new
        used = np.sqrt(sc**2 + k2 * p2)
        fit = intersect_lines(segments, angle_sigma=angle_sigma, offset_sigma=used, robust=True)
        if done:
            break
    return fit, k2, used


def vertex_with_parallax(segments, angle_sigma, offset_sigma, parallax, median_start=False):
    """(VertexFit, the ``parallax`` record or None, offset sigmas used (N,) [px]): the robust
    common point of N lines (`vertex.intersect_lines`) with the parallax term (module
    docstring) where the lines carry parallax scales and scatter significantly more than
    their own sigmas say.

    segments: (N, 4) undistorted px; angle_sigma, offset_sigma: (N,) [rad], [px] each
    line's own; parallax: (N,) [px] each line's parallax scale, or None (no line carries
    one: the plain fit, record None). The record: ``kappa`` (the parallax per px of scale;
    0 where not called for), ``chi2_without`` and ``dof`` (the plain fit's), its
    ``p_value``, ``lines`` (lines with a scale > 0), ``sigma_px`` (the term's largest sd
    over the inliers); with median_start also ``start`` ("zero", or "median" where the term
    started again).
    median_start: where every line carries the term alike (the port's play,
    `fulcrum._vertex_fit`) and the term settled from 0 keeps fewer than `MAJORITY` of the
    lines, it starts again from the median of every line's chi2 (`_median_start`): a term
    that calls most lines outliers is one the gate of too small a noise chose (it keeps
    only the lines that happen to pass close, whose scatter then says there is little),
    not one a robust fit can claim. Started from the median every time instead, the leave-
    one-out fits of a sequence with a stray line settle some with it and some without, and
    the jackknife doubles (docs/method.md).
    """
    sc = np.asarray(offset_sigma, float)
    fit = intersect_lines(segments, angle_sigma=angle_sigma, offset_sigma=sc, robust=True)
    if parallax is None or not np.any(np.asarray(parallax) > 0):
        return fit, None, sc
    p2 = np.asarray(parallax, float) ** 2
    dof = fit.lines_used - 2
    rec = {"kappa": 0.0, "chi2_without": float(fit.chi2), "dof": int(dof),
           "p_value": float(chi2_sf(fit.chi2, dof)) if dof > 0 else None, "lines": int(np.sum(p2 > 0)),
           "sigma_px": 0.0}
    if median_start:
        rec["start"] = "zero"
    plain, k2, used = fit, 0.0, sc
    if dof > 0 and fit.chi2 > dof:
        fit, k2, used = _settle(segments, angle_sigma, sc, p2, plain, 0.0)
    # the gate's kept lines can be within their chi2 while the lines it dropped carry the
    # term: a minority kept is the sign, whether the term settled or was never called for
    if median_start and dof > 0 and fit.lines_used < MAJORITY * len(sc):
        start = _median_start(plain, np.asarray(plain.sigmas, float) ** 2, p2)
        if start > 0:
            used = np.sqrt(sc**2 + start * p2)
            first = intersect_lines(segments, angle_sigma=angle_sigma, offset_sigma=used, robust=True)
            fit, k2, used = _settle(segments, angle_sigma, sc, p2, first, start)
            rec["start"] = "median"
    if k2 == 0.0:
        return fit, rec, used
    rec.update(kappa=float(np.sqrt(k2)), sigma_px=float(np.sqrt(k2 * p2[fit.inliers].max(initial=0.0))))
    return fit, rec, used

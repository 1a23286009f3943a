"""The port's play that two views of a pivot share, in their stereo fulcrum's covariance.

An instrument pivoting in its port wanders about its fulcrum within the port's play: each
frame's shaft passes the fulcrum off by a 3-D offset, and both views of a stereo endoscope
see that one offset, so their fulcrum images move together. The two fulcrum rays' errors
are then not independent, and a point where they meet, or a fusion of it with the
diameter-based point, does not average that part (`stereo_fulcrum.stereo_fulcrum`):

- `shared_ray_cov`: the part of a view's fulcrum ray covariance beyond its lines' own sigmas;
- `play_covariance`: the two views' parts as one 3-D offset of the point, across the line of
  sight;
- `shared_offset_term`: what that offset adds to the covariance of the rays' meeting point;
- `play_cross_cov`: the two rays' cross-covariance read line by line from the frames both
  views fitted: the shaft's offset in a frame is one for both views, its edges' noise each
  view's own.
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.geometry.frames import normalize

__all__ = ["shared_ray_cov", "play_covariance", "shared_offset_term", "play_cross_cov", "cross_term", "MIN_PAIRED_LINES"]

#: The fewest frames with one line in each view for `play_cross_cov` to read the shared offset.
MIN_PAIRED_LINES = 5


def shared_ray_cov(fulcrum):
    """(3, 3) the part of the fulcrum ray's covariance (`Fulcrum.ray_covariance`) that its
    lines' own sigmas do not give: what the noise its lines' scatter showed and the
    jackknife added (they raise ray_sigma_deg and leave ray_cov, the fit's, as it was) and
    the lines' offset term (`Fulcrum.ray_cov_offset`), all of it read as the scene's."""
    C = fulcrum.ray_covariance()
    own = np.asarray(fulcrum.ray_cov, float)
    if fulcrum.ray_cov_offset is not None:
        own = own - np.asarray(fulcrum.ray_cov_offset, float)
    out = C - own
    lam, V = np.linalg.eigh(0.5 * (out + out.T))
    return (V * np.maximum(lam, 0.0)) @ V.T


def play_covariance(tri, shared_left, shared_right):
    """(3, 3) [length^2] the 3-D offset of the fulcrum that both views' fulcrum rays share
    (left camera frame), across the line of sight.

    tri: the `cylinder.RayTriangulation` of the rays (its ranges, its point); shared_left,
    shared_right: (3, 3) the shared part of each unit ray's covariance (`shared_ray_cov`;
    the right one in the left camera frame, ``R^T C R``). An instrument's shaft wanders
    about its fulcrum in its port (the play): each frame's shaft passes the fulcrum off by
    a 3-D offset, and both views see that one offset, so their fulcrum images move together
    (a rectified pair's alike); their lines scatter beyond their own sigmas by it. That
    part of each ray's covariance, times the squared range, is the offset across the line
    of sight; the two views' are two readings of it and are averaged. Scatter from edges
    noisier than their sigmas is counted as shared too: across the line of sight a
    triangulated point's sigma is then that of one view, not of two independent ones."""
    ranges = np.asarray(tri.ranges, float)
    out = 0.5 * (ranges[0] ** 2 * np.asarray(shared_left, float) + ranges[1] ** 2 * np.asarray(shared_right, float))
    out = _across(tri.point) @ out @ _across(tri.point)
    return 0.5 * (out + out.T)


def _across(x):
    """(3, 3) the projection across the line of sight of the point x (3,) (left camera frame)."""
    u = normalize(np.asarray(x, float))
    return np.eye(3) - np.outer(u, u)


def shared_offset_term(tri, common, margin=0.9):
    """(3, 3) what a 3-D offset both rays carry (`play_covariance`, covariance `common`, a
    part of each ray's covariance) adds to the covariance of their meeting point
    (`cylinder.triangulate_rays`, which takes the rays as independent): the cross terms
    ``H^-1 (I_l S I_r + I_r S I_l) H^-1`` (I_k each ray's information at the point, H their
    sum), kept across the line of sight only. Across it the two rays then no longer halve
    what they share; along it (the depth, from the rays' disparity) the point keeps the
    covariance of independent rays: on rendered pivots the disparity's errors exceed what
    the rays' own parts alone would give (edges noisier than their sigmas count in the
    shared excess too), so the shared term is not taken out of the depth.

    The term holds each ray's own part (C_k - S), which is negative where the offset read
    exceeds what a ray holds: where the term would take more than `margin` of the point's
    covariance ``tri.point_cov`` away along some direction (the sum no longer a covariance),
    its negative part is dropped (in the point's own sds), so the point keeps at least the
    covariance of independent rays there."""
    cross = _meeting_cross(tri, np.asarray(common, float))
    P = _across(tri.point)
    out = P @ cross @ P
    out = 0.5 * (out + out.T)
    L = np.linalg.cholesky(np.asarray(tri.point_cov, float))
    W = np.linalg.inv(L)
    lam, V = np.linalg.eigh(W @ out @ W.T)  # the term in the point's own sds
    if lam[0] > -margin:
        return out
    # an offset read larger than a ray holds: the term would take (nearly) all of the point's
    # covariance away along some direction; there it takes nothing (the rays as independent)
    return L @ (V * np.maximum(lam, 0.0)) @ V.T @ L.T


def play_cross_cov(left, right, R_right_from_left, pairs=None):
    """(X (3, 3), record) the cross-covariance ``E[dr_l (R^T dr_r)^T]`` of the two views'
    unit fulcrum rays' errors (left camera frame), from the lines both fitted in the same
    frames; (None, record) where it cannot be read.

    left, right: each view's `fulcrum.Fulcrum` with its ``vertex_lines`` (the inlier shaft
    midlines: frame, the ray's gain per px of the line's offset, normal, residual, sd);
    pairs: [(i, j)] the left frame i taken with the right frame j (`camera.stereo.pair_frames`),
    None: by index (the two views' frames given in the same order); only frames with one
    line in each view are pairs (at least `MIN_PAIRED_LINES`). A
    frame's shaft passes the fulcrum off by one 3-D offset (the port's play), which both
    views see as about the same image offset u (two cameras a few millimetres apart, at
    one depth): the offsets of its line along the two normals, ``n_l.u`` and ``n_r.u``,
    covary by ``tau^2 c`` (c = n_l . n_r), while the edges' noise is each view's own and
    drops out. So tau^2 [px^2], the shared offset's variance per direction, is read from
    the pairs' residuals at their vertices, ``sum r_l r_r c / sum c^2``, times N / (N - 2)
    (each vertex took two of the N residuals' degrees of freedom), held at 0 or above
    (record ``sigma_px``). What each view has alone is read from the pairs' differences,
    in which the shared offset cancels: ``beta = sum (r_l - c r_r)^2 / sum (sd_l^2 + c^2
    sd_r^2)`` times N / (N - 2) (less the little of the offset a turn between the normals
    leaves, ``tau^2 (1 - c^2)``), the edges' own variance as a share of the lines' stated
    ones; then of a line's variance as its view reports it, ``s sd^2`` (s the view's factor
    from its fit's ray covariance to the one it reports, `Fulcrum.ray_covariance`: the noise
    or the jackknife), the view's own part is ``beta sd^2`` and the rest, ``(s - beta)
    sd^2``, is shared, and where the stated sds exceed what the lines scatter, the part
    neither reading finds is split as the scatter is: a pair's covariance is ``c sqrt(s_l
    s_r) sd_l sd_r tau^2 / (tau^2 + own^2)`` (own^2 = beta times the pairs' mean sd^2),
    and ``X = sum_pairs that g_l (R^T g_r)^T``, g each line's gain. The own part is read directly, not as what is left of a
    line's stated variance once tau^2 is taken from it: where the play is most of a line's
    variance (a detector's sds that hold it), that difference of two near numbers would
    keep noise the views do not have in the rays' disparity, the point's depth (rendered
    pivots: residuals of 2.0 px in each view that differ by 0.16 px). Unlike the excess
    each view's lines read (`shared_ray_cov`), this holds the play where a detector's sds
    already covered it (its play term then reads little or none), and X counts only the
    frames both views used. record: ``pairs``, ``sigma_px`` (tau), ``own_sd_px`` (the
    edges' own sd of a paired line, ``sqrt(beta)`` times the lines' RMS sd)."""
    rec = {"pairs": 0, "sigma_px": None, "own_sd_px": None}
    if left.vertex_lines is None or right.vertex_lines is None:
        return None, rec
    fl, gl, nl, rl, sl = left.vertex_lines
    fr, gr, nr, rr, sr = right.vertex_lines
    if pairs is not None:  # the right lines' frames as their left partners' (-1: none)
        to_left = {int(j): int(i) for i, j in pairs}
        fr = np.array([to_left.get(int(j), -1) for j in fr], int)
    both = np.intersect1d(_single(fl), _single(fr))
    rec["pairs"] = int(both.size)
    if both.size < MIN_PAIRED_LINES:
        return None, rec
    a = np.intersect1d(fl, both, return_indices=True)[1]  # each pair's line in either view
    b = np.intersect1d(fr, both, return_indices=True)[1]
    c = np.sum(nl[a] * nr[b], -1)
    n = len(both)
    tau2 = max(float(np.sum(rl[a] * rr[b] * c) / max(np.sum(c * c), 1e-12)) * n / (n - 2), 0.0)
    rec["sigma_px"] = float(np.sqrt(tau2))
    # the views' own noise from the pairs' differences, where the shared offset cancels
    diff = np.sum((rl[a] - c * rr[b]) ** 2 - tau2 * (1.0 - c * c))
    beta = max(float(diff) * n / (n - 2), 0.0) / float(np.sum(sl[a] ** 2 + c * c * sr[b] ** 2))
    rec["own_sd_px"] = float(np.sqrt(beta * np.mean(0.5 * (sl[a] ** 2 + sr[b] ** 2))))
    # what the lines' reported variance holds beyond what either reading finds (stated sds
    # above the scatter) is split between shared and own as the scatter splits
    own2 = float(rec["own_sd_px"]) ** 2
    share = tau2 / (tau2 + own2) if tau2 + own2 > 0 else 0.0
    shared = share * np.sqrt(_reported_factor(left) * _reported_factor(right))
    R = np.asarray(R_right_from_left, float)
    return np.einsum("k,ki,kj->ij", shared * c * sl[a] * sr[b], gl[a], gr[b] @ R), rec


def _single(frames):
    """The frame indices that hold one line only, of the lines' frame indices (N,) int."""
    u, count = np.unique(frames, return_counts=True)
    return u[count == 1]


def _reported_factor(fulcrum):
    """The factor from the fit's ray covariance to the reported one (`Fulcrum.ray_covariance`)."""
    fit = float(np.trace(np.asarray(fulcrum.ray_cov, float)))
    return float(np.trace(fulcrum.ray_covariance())) / fit if fit > 0 else 1.0


def cross_term(tri, X):
    """(3, 3) [length^2] what the rays' cross-covariance X (3, 3) (`play_cross_cov`, unit
    rays, left camera frame) adds to the covariance of their meeting point
    (`cylinder.triangulate_rays`, which takes the rays as independent): turning ray k by d
    moves the point by ``H^-1 I_k rho_k d`` (`stereo_fulcrum.triangulation_lens_cov`), so
    the term is ``rho_l rho_r H^-1 (I_l X I_r + I_r X^T I_l) H^-1``, along the line of sight
    and across it: an offset both rays share cancels in their disparity (the depth) and
    is not halved across it."""
    out = _meeting_cross(tri, float(tri.ranges[0]) * float(tri.ranges[1]) * np.asarray(X, float))
    return 0.5 * (out + out.T)


def _meeting_cross(tri, S):
    """(3, 3) ``H^-1 (I_l S I_r + I_r S^T I_l) H^-1``: what a cross-covariance S (3, 3) of the
    two rays' offsets at the point adds to the covariance of their meeting point (I_k each
    ray's information there, `RayTriangulation.ray_information`, H their sum)."""
    info = np.asarray(tri.ray_information, float)
    H_inv = np.linalg.inv(info[0] + info[1])
    return H_inv @ (info[0] @ S @ info[1] + info[1] @ S.T @ info[0]) @ H_inv

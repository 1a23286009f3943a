"""The port's play that two views of a pivot share, in their stereo fulcrum's covariance.

An instrument pivoting in its port wanders about its fulcrum within the port's play: each
frame's shaft passes the fulcrum off by a 3-D offset, and both views of a stereo endoscope
see that one offset, so their fulcrum images move together. The two fulcrum rays' errors
are then not independent, and a point where they meet, or a fusion of it with the
diameter-based point, does not average that part (`stereo_fulcrum.stereo_fulcrum`):

- `shared_ray_cov`: the part of a view's fulcrum ray covariance beyond its lines' own sigmas;
- `play_covariance`: the two views' parts as one 3-D offset of the point, across the line of
  sight;
- `shared_offset_term`: what that offset adds to the covariance of the rays' meeting point.
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.geometry.frames import normalize

__all__ = ["shared_ray_cov", "play_covariance", "shared_offset_term"]


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
    info = np.asarray(tri.ray_information, float)
    H_inv = np.linalg.inv(info[0] + info[1])
    S = np.asarray(common, float)
    cross = H_inv @ (info[0] @ S @ info[1] + info[1] @ S @ info[0]) @ H_inv
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

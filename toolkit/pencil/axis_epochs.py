"""Pivot epochs in 3-D: where the fulcrum moves, found by a change-point test on the shafts'
3-D axes carried into the reference camera (`pencilcal fulcrum --stabilize --shaft-diameter`).

A camera that moves hides a move of the fulcrum from the image lines: once each frame's
lines are carried into the reference frame by the background's homography, the fulcrum's
image can stay put while the point moved in depth, or the camera's own translation can
look like a move. With every frame's 3-D pose (`detect.background_pose`) each shaft's
3-D axis is carried into the reference camera (`moving_fulcrum.carry_axes`), and the
epochs are tested on those axes with the image lines' engine (`epochs.segment_runs`):

1. *the cost of a run*: the fulcrum of its axes and the map unit's length fitted together
   (`moving_fulcrum.fulcrum_moving`, robust), its MSAC cost ``sum_k min(chi2_k, T^2)`` over
   the run's axes, chi2_k the axis's squared offset from the point by its perpendicular
   covariance (2 dof) and T^2 the chi-square(2) quantile at 0.999: a misdetected shaft
   costs T^2 whatever the split; a run whose axes fix no point costs T^2 an axis;
2. *the test*: the alternative (a split, or a segment and the rest) frees a second point
   and a second scale, four parameters, so ``D / 4`` over the inliers' residual variance
   ``s^2 = max(1, chi2 / nu)`` (nu: twice the inliers less 8) is F(4, nu) distributed
   (`epochs.f_sf`); the Bonferroni factors, binary segmentation and merging are the
   image lines' (`epochs` module docstring).

Each epoch's scale is its own: the map unit is one length, but an epoch's axes fix it
only together with its point, and a common scale would couple the epochs' fits.

>>> import numpy as np
>>> rng = np.random.default_rng(1)
>>> def axes(F, n):
...     d = rng.normal(size=(n, 3)) * [1, 1, 0.3]
...     d /= np.linalg.norm(d, axis=1, keepdims=True)
...     return F - 30 * d, d
>>> (A1, d1), (A2, d2) = axes(np.r_[0.0, 0, 80], 6), axes(np.r_[15.0, 0, 80], 6)
>>> A, d = np.r_[A1, A2], np.r_[d1, d2]
>>> C = np.broadcast_to(np.diag([1e-6, 1e-6, 0.01, 0.01]), (12, 4, 4))
>>> t = rng.normal(size=(12, 3)) * 0.2
>>> R = np.broadcast_to(np.eye(3), (12, 3, 3))
>>> ep = axis_epochs(A - 10 * t, d, C, R, -t, np.zeros((12, 6, 6)), np.arange(12), 12)   # centres at 10 t
>>> ep.bounds
[(0, 6), (6, 12)]
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.geometry.quantiles import chi2_isf
from pencilcal.toolkit.pencil.epochs import ALPHA, MIN_FRAMES, segment_runs
from pencilcal.toolkit.pencil.moving_fulcrum import fulcrum_moving

__all__ = ["axis_epochs", "point_epochs", "AXIS_INLIER_CONFIDENCE"]

#: The MSAC truncation's quantile of chi-square(2) (the image lines' test uses 0.999 too).
AXIS_INLIER_CONFIDENCE = 0.999


class _AxisRuns:
    """The cost of one fulcrum for sets of runs of frames' carried axes, cached (module
    docstring, step 1); scale: the factor on the axes' and the poses' sigmas."""

    params = 4

    @staticmethod
    def residuals(n):
        """Two residuals an axis."""
        return 2 * n

    def __init__(self, axes, frame_of, scale=1.0):
        self.axes, self.f, self.scale = axes, frame_of, scale
        self.t2 = chi2_isf(1.0 - AXIS_INLIER_CONFIDENCE, 2)
        self.cache = {}

    def scaled(self, scale):
        """The same runs with the axes' and the poses' sigmas times `scale`."""
        return _AxisRuns(self.axes, self.f, self.scale * scale)

    def fit(self, *runs):
        """(MSAC cost, inlier chi2, inliers, point (3,) or None) of the axes of the runs'
        frames."""
        key = tuple(runs)
        if key not in self.cache:
            sel = np.zeros(self.f.shape, bool)
            for a, b in runs:
                sel |= (self.f >= a) & (self.f < b)
            A, d, C, R, t, S = (x[sel] for x in self.axes)
            out = (sel.sum() * self.t2, 0.0, 0, None)
            if sel.sum() >= 2:
                try:
                    s2 = self.scale**2
                    mv = fulcrum_moving(A, d, C * s2, R, t, S * s2)
                    c2 = np.asarray(mv.fit.chi2, float)
                    inl = c2 < self.t2
                    out = (float(np.sum(np.minimum(c2, self.t2))), float(np.sum(c2[inl])), int(inl.sum()),
                           np.asarray(mv.fit.point, float))
                except EstimationError:
                    pass
            self.cache[key] = out
        return self.cache[key]


def axis_epochs(points, directions, covs, R, t, pose_cov, frame_of, n_frames, *, alpha=ALPHA,
                min_frames=MIN_FRAMES):
    """The pivot epochs of a sequence from its shafts' 3-D axes seen by a moving camera
    (module docstring).

    points, directions: (N, 3) the axes in their own frames' cameras; covs: (N, 4, 4) their
    chart covariances; R: (N, 3, 3) R_frame_from_ref, t: (N, 3) t_frame_from_ref [map
    unit], pose_cov: (N, 6, 6) each axis's frame's pose, as `moving_fulcrum.fulcrum_moving`
    takes them;
    frame_of: (N,) each axis's frame index in [0, n_frames), frames in their order; alpha,
    min_frames: as `epochs.split_epochs`. Returns `epochs.Epochs` (its change points'
    ``vertices`` the two fits' 3-D points in the reference camera, or None).
    """
    f = np.asarray(frame_of, int).reshape(-1)
    axes = tuple(np.asarray(x, float) for x in (points, directions, covs, R, t, pose_cov))
    if any(len(x) != f.size for x in axes) or (f.size and (f.min() < 0 or f.max() >= n_frames)):
        raise InputError(f"axis_epochs: expected {f.size} axes, poses and frame indices in [0, {n_frames})")
    if int(min_frames) < 3:
        raise InputError(f"min_frames must be at least 3, got {min_frames!r}")
    return segment_runs(_AxisRuns(axes, f), np.bincount(f, minlength=int(n_frames)), alpha=alpha,
                        min_frames=min_frames)


def point_epochs(camera, frames, diameter, *, alpha=None, min_frames=None):
    """The pivot epochs (`epochs.Epochs`) of lines.json `frames` whose ``camera_pose`` carries
    their camera (``--stabilize`` with poses) from their shafts' 3-D axes carried into the
    reference camera (`axis_epochs`), or None where no frame has a pose.
    alpha, min_frames: the test's (None: `epochs.ALPHA`, `epochs.MIN_FRAMES`)."""
    from pencilcal.toolkit.pencil.fulcrum import frame_axes, pose_arrays

    points, dirs, covs, _, _, poses, index, _ = frame_axes(camera, frames, diameter)
    if not any(p is not None for p in poses):
        return None
    R, t, S = pose_arrays(poses)
    return axis_epochs(np.array(points), np.array(dirs), np.array(covs), R, t, S, np.array(index, int), len(frames),
                       alpha=ALPHA if alpha is None else alpha,
                       min_frames=MIN_FRAMES if min_frames is None else min_frames)

"""Board detections of a known camera from random poses: for tests, examples and benchmarks.

Example
-------
>>> from pencilcal.toolkit.board.spec import board_from_dict
>>> from pencilcal.toolkit.camera.model import Camera
>>> b = board_from_dict({"type": "chessboard", "squares": [9, 6], "square": 25.0})
>>> cam = Camera("pinhole", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
>>> dets = synthetic_detections(cam, b, views=2, noise_px=0.0, seed=0, warp=(0.0, 1.0))
>>> len(dets.truth), dets[1].count
(2, 54)
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.board.bundle import warp_basis
from pencilcal.toolkit.board.detect import BoardDetection

__all__ = ["synthetic_detections", "DetectionList"]


def synthetic_detections(camera, board, views=10, noise_px=0.2, seed=0, distance=None, tilt_deg=40.0,
                         margin_px=10.0, warp=(0.0, 0.0), min_tilt=0.3, print_sigma=(0.0, 0.0)):
    """Detections of `board` seen by `camera` from random poses, with Gaussian corner noise.

    For tests and examples. Each view sees the whole board, tilted up to `tilt_deg` about a
    random in-plane axis, at `distance` (default: the board fills about half the image
    width), placed at random so that every corner lands at least `margin_px` inside the
    image. ``ids`` are the board's corner ids; `corners` raw pixels + N(0, noise_px^2) per
    axis. Also attaches the true poses as ``.truth`` = list of (rvec, tvec) on the
    returned list. `warp` (2,) [board unit] bends the board as `bundle.warp_basis` says
    (mrcal's calobject_warp), (3,) twists it too; each view's tilt is drawn from [min_tilt, 1] x `tilt_deg`.
    `print_sigma` (2,) [board unit]: each corner printed off its nominal place by
    N(0, print_sigma^2) along board x and y, the same offset in every view (the printed
    board's own errors, `print_errors`); drawn from a generator of its own, so a seed's
    views are otherwise unchanged. The offsets are ``.offsets`` (M, 2).

    Example
    -------
    >>> from pencilcal.toolkit.board.spec import board_from_dict
    >>> from pencilcal.toolkit.camera.model import Camera
    >>> b = board_from_dict({"type": "chessboard", "squares": [9, 6], "square": 25.0})
    >>> cam = Camera("pinhole", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
    >>> dets = synthetic_detections(cam, b, views=3, noise_px=0.0, seed=0)
    >>> len(dets), dets[0].count, dets[0].image_size
    (3, 54, (640, 480))
    """
    import cv2

    rng = np.random.default_rng(seed)
    flat = board.object_points()
    obj = np.array(flat, float)
    w = np.asarray(warp, float).reshape(-1)
    obj[:, 2] += warp_basis(flat, flat, twist=w.size == 3) @ w
    offsets = np.random.default_rng([int(seed), 7]).normal(size=(obj.shape[0], 2)) * np.asarray(print_sigma, float)
    obj[:, :2] += offsets
    centre = obj.mean(0)
    span = float(np.ptp(obj[:, 0]) + 1e-9)
    if distance is None:
        distance = 2.0 * camera.fx * span / camera.width
    out = DetectionList()
    out.truth = []
    out.offsets = offsets
    for _ in range(int(views)):
        for _try in range(500):
            axis = rng.normal(size=3)
            axis[2] = 0.0
            axis /= np.linalg.norm(axis)
            tilt = np.radians(rng.uniform(min_tilt, 1.0) * tilt_deg)
            spin = rng.uniform(-0.4, 0.4)
            R = cv2.Rodrigues(axis * tilt)[0] @ cv2.Rodrigues(np.array([0.0, 0.0, spin]))[0]
            depth = distance * rng.uniform(0.8, 1.3)
            target = np.array([rng.uniform(-0.35, 0.35) * camera.width / camera.fx,
                               rng.uniform(-0.3, 0.3) * camera.height / camera.fy, 1.0]) * depth
            t = target - R @ centre
            pc = obj @ R.T + t
            if np.any(pc[:, 2] <= 0):
                continue
            px = camera.project(pc)
            lo = margin_px
            hi = np.array([camera.width, camera.height]) - 1 - margin_px
            if np.all(np.isfinite(px)) and np.all(px.min(0) > lo) and np.all(px.max(0) < hi):
                break
        else:
            raise RuntimeError("no pose keeps the board inside the image; lower the distortion or move it further")
        px = px + noise_px * rng.normal(size=px.shape)
        out.append(BoardDetection(np.arange(obj.shape[0]), px, (camera.width, camera.height),
                                  np.zeros(0, int), np.zeros((0, 4, 2))))
        out.truth.append((cv2.Rodrigues(R)[0].ravel(), t))
    return out


class DetectionList(list):
    """A list that can carry the true poses of synthetic views (``.truth``) and the printed
    corners' offsets (``.offsets``)."""

"""Where a calibration's views put the board: the region of the image they cover, and how.

A lens model is measured where corners fell and extrapolated elsewhere. `covered_grid` marks
the cells of a grid over the image that lie inside at least one view's board (the convex
hull of the view's corners): the region the views cover. `view_geometry` says how the
board was seen: each view's tilt (the angle between the board's normal and the camera's
optical axis: a board parallel to the image plane shows no perspective, wherever it is in
the image), its distance, and the share of the image its corners span; a set of views
that are all nearly fronto-parallel, all at one distance, or all small leaves the focal
length and the distortion poorly separated.

Example
-------
>>> import numpy as np
>>> g = covered_grid([np.array([[0.0, 0.0], [63.0, 0.0], [63.0, 47.0], [0.0, 47.0]])], (128, 96), step_px=16)
>>> g.mask.astype(int).tolist()
[[1, 1, 1, 1, 0, 0, 0, 0], [1, 1, 1, 1, 0, 0, 0, 0], [1, 1, 1, 1, 0, 0, 0, 0], [0, 0, 0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, 0, 0, 0]]
>>> round(g.fraction, 3), g.pixels().shape
(0.25, (12, 2))
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["CoveredGrid", "covered_grid", "grid_step", "view_geometry", "GRID_CELLS"]

#: Cells along the longer side of the image in the maps of a calibration.
GRID_CELLS = 48


def grid_step(image_size, cells=GRID_CELLS):
    """The cell size [px] that puts `cells` cells along the image's longer side."""
    return max(1.0, max(image_size) / float(cells))


@dataclass(frozen=True)
class CoveredGrid:
    """A grid of cells over the image and which of them the views cover.

    image_size : (w, h) [px]; step_px : cell size [px]; mask : (ny, nx) bool, True where
    the cell's centre lies inside some view's board. The cell (j, i) is centred at pixel
    ((i + 0.5) step - 0.5, (j + 0.5) step - 0.5).
    """

    image_size: tuple
    step_px: float
    mask: np.ndarray

    @property
    def shape(self):
        return self.mask.shape

    @property
    def fraction(self):
        """The share of the image's cells covered."""
        return float(self.mask.mean())

    def centres(self):
        """(ny, nx, 2) pixel centres of every cell."""
        ny, nx = self.mask.shape
        u = (np.arange(nx) + 0.5) * self.step_px - 0.5
        v = (np.arange(ny) + 0.5) * self.step_px - 0.5
        return np.stack(np.meshgrid(u, v), -1)

    def pixels(self):
        """(M, 2) the centres of the covered cells."""
        return self.centres()[self.mask]


def covered_grid(corners, image_size, step_px=None):
    """The `CoveredGrid` of views whose corners are `corners` (sequence of (K_i, 2) raw
    pixels); step_px defaults to `grid_step`."""
    import cv2

    w, h = (int(v) for v in image_size)
    step = float(step_px) if step_px else grid_step((w, h))
    nx, ny = int(math.ceil(w / step)), int(math.ceil(h / step))
    # rasterise at 4 sub-cells per cell, then take a cell's centre sample
    sub = 4
    canvas = np.zeros((ny * sub, nx * sub), np.uint8)
    for c in corners:
        c = np.asarray(c, float).reshape(-1, 2)
        if c.shape[0] < 3:
            continue
        pts = ((c + 0.5) / step * sub - 0.5).astype(np.float32)
        hull = np.round(cv2.convexHull(pts)).astype(np.int32)
        cv2.fillConvexPoly(canvas, hull, 1)
    mask = canvas[sub // 2::sub, sub // 2::sub][:ny, :nx].astype(bool)
    return CoveredGrid((w, h), step, mask)


def view_geometry(poses, board_points, corners, image_size):
    """How each view saw the board.

    poses : per view (rvec, tvec) cam_from_target; board_points : per view (K_i, 3) the
    board points seen [board unit]; corners : per view (K_i, 2) [px]; image_size (w, h).

    Returns a dict of arrays over the views: ``tilt_deg`` (angle between the board's normal
    and the optical axis), ``distance`` (to the seen corners' centre, board unit) and
    ``area_fraction`` (the seen corners' convex hull over the image area).
    """
    import cv2

    w, h = image_size
    tilt, dist, area = [], [], []
    for (rvec, tvec), obj, px in zip(poses, board_points, corners):
        R = cv2.Rodrigues(np.asarray(rvec, float).reshape(3, 1))[0]
        centre = R @ np.asarray(obj, float).mean(0) + np.asarray(tvec, float).ravel()
        tilt.append(math.degrees(math.acos(min(1.0, abs(float(R[2, 2]))))))
        dist.append(float(np.linalg.norm(centre)))
        hull = cv2.convexHull(np.asarray(px, np.float32).reshape(-1, 1, 2))
        area.append(float(cv2.contourArea(hull)) / float(w * h))
    return {"tilt_deg": np.array(tilt), "distance": np.array(dist), "area_fraction": np.array(area)}

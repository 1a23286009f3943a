"""Views of a plain chessboard, rendered exactly through any lens model: for calibration
benchmarks and tests.

A chessboard of (cols, rows) inner corners and square s [board unit] has (cols + 1) x
(rows + 1) squares; its inner corner (i, j) sits at (i s, j s, 0) in the board frame
(`toolkit.board.spec`), so the squares span [-s, cols s] x [-s, rows s], and the square
whose top-left corner is the inner corner (0, 0) is white. Every pixel is the area
coverage of the dark squares (`raster.target_coverage`, exact for any lens), mixed between
paper and ink, then blurred and given sensor noise, as `render.render_frame` does.

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.board.spec import board_from_dict
>>> from pencilcal.toolkit.board.detect import detect_board
>>> from pencilcal.toolkit.camera.model import Camera
>>> board = board_from_dict({"type": "chessboard", "squares": [7, 6], "square": 10.0})
>>> cam = Camera("opencv", 640, 480, [[600.0, 0, 320.0], [0, 600.0, 240.0], [0, 0, 1]], [-0.1, 0, 0, 0, 0])
>>> img = render_chessboard(cam, np.eye(3), [-30.0, -25.0, 150.0], board, np.random.default_rng(0))
>>> err = detect_board(img, board).corners - cam.project(board.object_points() + [-30.0, -25.0, 150.0])
>>> err.shape, bool(np.abs(err).max() < 0.2)
((42, 2), True)
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.synth.raster import target_coverage

__all__ = ["chessboard_polygons", "render_chessboard", "PAPER", "INK"]

#: Grey levels of the paper and the ink before noise (8-bit).
PAPER, INK = 215.0, 30.0


def chessboard_polygons(board):
    """The dark squares of a chessboard `Board` as ((4, 2) vertices [board unit], +1) polygons."""
    cols, rows = board.inner_corners
    s = float(board.square)
    out = []
    for j in range(-1, rows):
        for i in range(-1, cols):
            if (i + j) % 2:
                x0, y0 = i * s, j * s
                out.append((np.array([[x0, y0], [x0 + s, y0], [x0 + s, y0 + s], [x0, y0 + s]]), 1))
    return out


def render_chessboard(camera, R_cam_from_board, t_cam_from_board, board, rng, noise=2.0, blur_px=0.7):
    """One 8-bit grey view (H, W) of the chessboard at the pose (R (3, 3), t (3,) [board
    unit]): paper `PAPER`, ink `INK`, a Gaussian blur of `blur_px` [px] sigma and Gaussian
    noise of `noise` grey levels."""
    import cv2

    cov = target_coverage(camera, R_cam_from_board, t_cam_from_board, chessboard_polygons(board))
    img = PAPER - (PAPER - INK) * cov
    if blur_px:
        img = cv2.GaussianBlur(img, (0, 0), float(blur_px))
    img = img + float(noise) * rng.normal(size=img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)

"""A pencil made of a board's own grid lines: the lines through one inner corner.

On a chessboard or ChArUco board the straight lines through one inner corner and the other
corners at grid offsets (dx, dy) (rows, columns, diagonals, ...) form a real pencil whose
spoke angles atan2(dy, dx) are known exactly in the board frame (x right, y down). The
detected corners draw those lines in every frame, so any board sequence, such as the da
Vinci endoscope frames, can be validated with the angular-variation method against the
board's own PnP pose, with no fan printed.

Each spoke k runs from the vertex corner to the farthest detected corner along its
direction (longer segments give better angles); segment labels are known, so no assignment
is needed. Noise: each corner has isotropic noise `corner_sigma_px`; the vertex corner's
noise is the vertex covariance, the far corner's gives the line's angle sd sigma / L.

Example
-------
>>> from pencilcal.toolkit.board.spec import board_from_dict
>>> b = board_from_dict({"type": "chessboard", "squares": [9, 6], "square": 25.0})
>>> g = GridPencil(b, (4, 2))
>>> len(g.directions), round(float(np.degrees(g.angles[1])), 2)
(16, 26.57)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.pencil.spec import Pencil

__all__ = ["GridPencil", "DEFAULT_DIRECTIONS"]

# the 16 primitive grid directions with |dx|, |dy| <= 2, by angle
DEFAULT_DIRECTIONS = tuple(sorted(
    {(dx, dy) for dx in range(-2, 3) for dy in range(-2, 3) if (dx, dy) != (0, 0) and np.gcd(dx, dy) == 1},
    key=lambda d: np.remainder(np.arctan2(d[1], d[0]), 2 * np.pi),
))


@dataclass(frozen=True, eq=False)
class GridPencil:
    """The board's grid lines through one inner corner.

    board: a Board; vertex: (i, j) inner-corner indices (column, row), or None to choose it
    in every frame: the detected corner whose spokes are longest in total (best angles). The
    spoke angles are the same from any corner, only the vertex's board position changes.
    directions: grid offsets (dx, dy) of the spokes.
    """

    board: object
    vertex: tuple = None
    directions: tuple = DEFAULT_DIRECTIONS

    def __post_init__(self):
        cols, rows = self.board.inner_corners
        if self.vertex is not None:
            i, j = self.vertex
            if not (0 <= i < cols and 0 <= j < rows):
                raise InputError(f"grid pencil: corner ({i}, {j}) is outside the {cols} x {rows} inner corners")
        for d in self.directions:
            if len(d) != 2 or tuple(d) == (0, 0):
                raise InputError(f"grid pencil: bad direction {d!r}")

    @property
    def angles(self):
        """(K,) [rad] spoke angles atan2(dy, dx) in the board frame."""
        return np.array([np.arctan2(dy, dx) for dx, dy in self.directions])

    def pencil(self, vertex_id):
        """The Pencil with its vertex at inner corner `vertex_id` (board frame)."""
        return Pencil(self.angles, self.board.object_points()[int(vertex_id), :2].copy(), None)

    def _spokes(self, pos, i0, j0):
        cols, rows = self.board.inner_corners
        out = []
        for k, (dx, dy) in enumerate(self.directions):
            far = None
            step = 1
            while 0 <= i0 + step * dx < cols and 0 <= j0 + step * dy < rows:
                cid = (j0 + step * dy) * cols + (i0 + step * dx)
                if cid in pos:
                    far, far_step = pos[cid], step
                step += 1
            if far is not None:
                out.append((k, far, far_step * np.hypot(dx, dy) * self.board.square))
        return out

    def segments(self, detection, corner_sigma_px=0.2):
        """Segments of one frame's detection.

        detection: a BoardDetection. Returns a dict with ``segments`` (K, 4) raw px, ``labels``
        (K,), ``angle_sigma`` (K,) [rad], ``vertex_px`` (2,), ``vertex_cov_px2`` (2, 2),
        ``pencil`` (with this frame's vertex) and ``radii`` (K, 2): each segment's ends are
        board corners at known distances from the vertex (0 and k |(dx, dy)| square), which
        tell the twins apart. None when no usable vertex corner was detected. K counts the
        directions along which some corner was detected.
        """
        cols, rows = self.board.inner_corners
        pos = {int(k): np.asarray(p, float) for k, p in zip(detection.ids, detection.corners)}
        if self.vertex is not None:
            cands = [self.vertex[1] * cols + self.vertex[0]]
        else:
            cands = list(pos)
        best, best_len = None, 0.0
        for cid in cands:
            if cid not in pos:
                continue
            i0, j0 = cid % cols, cid // cols
            spokes = self._spokes(pos, i0, j0)
            if len(spokes) < 3:
                continue
            total = sum(np.hypot(*(far - pos[cid])) for _, far, _ in spokes)
            if total > best_len:
                best, best_len = (cid, spokes), total
        if best is None:
            return None
        cid, spokes = best
        v = pos[cid]
        segs, labels, radii = [], [], []
        for k, far, dist in spokes:
            segs.append(np.r_[v, far])
            labels.append(k)
            radii.append((0.0, dist))
        seg = np.array(segs, float).reshape(-1, 4)
        L = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])
        # the far corner's noise turns the line about the vertex; the vertex's own noise is
        # the vertex covariance (not counted twice)
        sig = corner_sigma_px / np.maximum(L, 1e-9)
        return {"segments": seg, "labels": np.array(labels, int), "angle_sigma": sig, "vertex_px": v,
                "vertex_cov_px2": np.eye(2) * corner_sigma_px**2, "vertex_id": int(cid), "pencil": self.pencil(cid),
                "radii": np.array(radii, float), "corner_sigma_px": corner_sigma_px}

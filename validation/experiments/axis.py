"""The tilt axis of a frame and of a sequence, the plane T where the chapter's single-angle
equation holds, and the order of a fan's spokes: what the single-angle and distribution
experiments share. Angles [rad].

Example
-------
>>> import numpy as np
>>> order, closed = fan_order(np.radians([-70, -50, -30, -10, 10, 30, 50, 70]))
>>> order.tolist(), closed
([0, 1, 2, 3, 4, 5, 6, 7], False)
>>> adjacent_pairs(np.radians([0, 120, 240]))
[(0, 1), (1, 2), (2, 0)]
"""
from __future__ import annotations

import math

import numpy as np

from pencilcal.toolkit.geometry.angles import circular_mean, wrap_line
from pencilcal.toolkit.pencil.chapter import aligned_angles, general_parameters

__all__ = ["t_plane", "sequence_axis", "frame_axis", "fan_order", "adjacent_pairs"]

# below this reference tilt the tilt axis v_d x n is not defined by the pose
_AXIS_MIN_TILT = math.radians(1e-3)
# a sequence whose per-frame axes agree to this (circular sd, line period) has a fixed axis
_AXIS_SPREAD = math.radians(1.0)


def t_plane(a, p):
    """Image angles a (N,) [rad, normalised coordinates] -> their angles (N,) [rad] in the
    plane T (orthogonal to the vertex ray) from u_i, and the gain d(angle in T)/d a (N,).

    p: `chapter.general_parameters` of the pose and vertex (``psi_i``, ``gamma_i``)."""
    gi = float(p["gamma_i"])
    u = np.asarray(a, float) - float(p["psi_i"])
    b = aligned_angles(u, gi)
    gain = math.cos(gi) / (np.cos(u) ** 2 + np.sin(u) ** 2 * math.cos(gi) ** 2)
    return b, gain


def sequence_axis(frames):
    """Target-frame tilt axis [rad, line period] shared by the sequence (a tilt sweep), or
    None when its frames' axes do not agree to 1 deg (or fewer than two are tilted)."""
    phis = []
    for f in frames:
        p = general_parameters(f.R_ref, f.x)
        if float(p["gamma_r"]) > math.radians(0.5):
            phis.append(float(p["theta_offset"]))
    if len(phis) < 2:
        return None
    phis = np.asarray(phis)
    m = float(circular_mean(phis, period=np.pi))
    spread = float(np.sqrt(np.mean(wrap_line(phis - m) ** 2)))
    return m if spread < _AXIS_SPREAD else None


def frame_axis(f, seq_axis, vertex=None):
    """(phi [rad] in the target frame, source) of the tilt axis in this frame, or (None, why).

    vertex: the normalised vertex the axis u_r = v_d x n is formed with (default: measured)."""
    p = general_parameters(f.R_ref, f.x if vertex is None else vertex)
    if float(p["gamma_r"]) > _AXIS_MIN_TILT:
        return float(p["theta_offset"]), "frame"
    if seq_axis is not None:
        return seq_axis, "sequence"
    return None, "the reference pose is frontal: its tilt axis is undefined"


def fan_order(th_pencil):
    """Spoke indices in angle order, starting after the largest gap (a fan stays contiguous
    across +-180 deg), and whether the spokes go round the full circle (no gap wider than
    the others)."""
    th = np.remainder(np.asarray(th_pencil, float), 2 * np.pi)
    order = np.argsort(th, kind="stable")
    s = th[order]
    gaps = np.diff(np.r_[s, s[0] + 2 * np.pi])  # gaps[i]: from spoke i to the next, cyclic
    big = int(np.argmax(gaps))
    order = np.roll(order, -(big + 1))
    others = np.delete(gaps, big)
    closed = bool(others.size and gaps[big] <= others.max() + 1e-9)
    return order, closed


def adjacent_pairs(th_pencil):
    """Index pairs of spokes that are neighbours in angle (a fan's consecutive spokes)."""
    order, closed = fan_order(th_pencil)
    pairs = [(int(order[i]), int(order[i + 1])) for i in range(len(order) - 1)]
    if closed:  # a fan round the full circle: close it
        pairs.append((int(order[-1]), int(order[0])))
    return pairs

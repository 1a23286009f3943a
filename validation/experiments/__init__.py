"""The book chapter's experiments, reproduced on a validation.json (synthetic or real).

Each experiment reads the per-frame records that `pencilcal validate` writes (the exact
model's labelled lines ``orient.exact.lines``, the reference pose ``R_ref``/``t_ref`` and
``reference_tilt_deg``) and compares what the lines say with what the reference pose
predicts. The reference is the exact truth for a `pencilcal simulate` folder and the best
PnP pose of the board for real images; with PnP the "errors" include the reference's own
error (a few hundredths of a degree on the da Vinci frames).

``single_angle`` (the chapter's Figs. 8-9)
    Pairs of spokes with a known 3D angle give the tilt through
    `toolkit.pencil.single_angle.single_angle_tilt`. The tilt axis is taken from the reference
    pose: the in-plane direction ``u_r = v_d x n`` (chapter.general_parameters), whose
    image through the vertex is computed by exact projection. Every measured line angle
    is first moved into the plane T orthogonal to the vertex ray
    (``aligned_angles(a - psi_i, gamma_i)``), where the chapter's eq. 6 holds exactly.
    Three cases: ``on_line`` (one spoke lies on the axis; its *measured* line is the axis
    image), ``known`` (the axis image from the reference, neither line on it: one or two
    admissible tilts) and ``unknown`` (no axis: only a lower bound on the tilt). Statuses
    other than "unique" are counted and reported as they are; a two-root or lower-bound
    result is never turned into one number.
``distribution`` (Figs. 10-11)
    (a) The image angle of every labelled spoke against exact projection at the reference
    pose, and its *angular variation*: the angle in T from the tilt axis minus the 3D
    angle from the axis (atan(tan theta cos gamma) - theta; for a vertex on the optical
    axis this is the change of the image angle from its value at zero tilt). (b) The
    orientation refitted (`estimator.fit_pencil`) from subsets of the spokes (every spoke,
    every 2nd, every 3rd, ...), with the Cramer-Rao bound of each subset at the reference.
``threshold``
    The tilt at which the estimator's ``detectable`` flag turns on for half of the frames
    (monotone regression, bootstrap interval), the tilt below which the tilt error is as
    large as half the tilt itself, and the estimated tilt of frontal-ish frames, against
    2 sqrt(sigma), `estimator.detection_threshold` and the noise floor of a frontal pencil
    (docs/method.md: median 3.75 deg at sigma = 0.1 deg, scaled by sqrt(sigma)), each with
    the measured line sigma.

Each function returns a JSON-ready dict with a top-level ``status``: "ok", "partial" (some
sections lacked the data; each such section has ``status: "insufficient data"`` and a
``reason``, and keeps what the data do bound, e.g. "below the smallest tilt seen") or
"insufficient data" (every section; ``reason`` joins theirs). EstimationError is raised
only when no frame has both the exact model's lines and a reference pose. Angles in the
output are degrees; arguments and internal arrays are radians unless named ``*_deg``.

Modules
-------
``frames``      the usable frames of a validation dict (`usable_frames`)
``sections``    the shape results share: header, section status, tilt bins, RMS
``axis``        the tilt axis, the plane T, the order of a fan's spokes
``single``      `single_angle`
``spacing``     `distribution`
``detection``   `threshold`
``synthetic``   `synthetic_validation`
``figures``     `figure_paths`, `write_figures`

Example
-------
>>> import numpy as np
>>> v = synthetic_validation(np.arange(0.0, 61.0, 10.0), sigma_deg=0.05, axis_deg=30.0)  # or load_validation(path)
>>> r = single_angle(v)
>>> r["status"], r["on_line"]["counts"]["unique"], r["unknown"]["counts"]
('ok', 44, {'lower_bound': 49})
"""
from __future__ import annotations

from ..validation_file import load_pencil_validation as load_validation
from .detection import GEOMETRY_FRONTAL_MEDIAN_DEG, GEOMETRY_FRONTAL_P95_DEG, threshold
from .figures import figure_paths, write_figures
from .frames import usable_frames
from .single import sd_on_line, single_angle
from .spacing import distribution
from .synthetic import synthetic_validation

__all__ = [
    "EXPERIMENTS",
    "load_validation",
    "usable_frames",
    "single_angle",
    "distribution",
    "threshold",
    "sd_on_line",
    "figure_paths",
    "write_figures",
    "synthetic_validation",
    "GEOMETRY_FRONTAL_MEDIAN_DEG",
    "GEOMETRY_FRONTAL_P95_DEG",
]

#: The experiments, as the command names them.
EXPERIMENTS = ("single-angle", "distribution", "threshold")

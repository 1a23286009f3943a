"""Pencils of lines and what they tell.

- `spec`: the pencil file and exact projection of a pencil;
- `estimator` (with its one-pencil float path `scalar` and the batched `estimator_torch`):
  orientation from image line angles, with covariance, twin and detectability;
- `assign`: labelling unlabelled lines with spokes; `vertex`: their common point;
- `orient`: one frame from raw segments to an `Orientation` (`orientation`: the record
  and its file); `fulcrum`: a pivoting instrument's fulcrum over a sequence;
- `cylinder`: a shaft's 3-D axis from its silhouette and the 3-D fulcrum;
- `grid`: a pencil of a board's own grid lines; `chapter`, `single_angle`: the book
  chapter's models and its single-angle test;
- `defaults`: the defaults and thresholds shared by the estimators and detectors.
"""

from __future__ import annotations

from pencilcal.toolkit.pencil.spec import Pencil, read_pencil, write_pencil, image_angles
from pencilcal.toolkit.pencil.estimator import PencilFit, fit_pencil, crlb, detection_threshold
from pencilcal.toolkit.pencil.assign import assign_spokes
from pencilcal.toolkit.pencil.vertex import VertexFit, intersect_lines
from pencilcal.toolkit.pencil.orientation import Orientation, read_orientations, write_orientations
from pencilcal.toolkit.pencil.orient import orient_segments, resolve_twins_by_continuity
from pencilcal.toolkit.pencil.fulcrum import fulcrum_from_frames, read_angles
from pencilcal.toolkit.pencil.cylinder import shaft_axis, fulcrum_3d

__all__ = ["Pencil", "read_pencil", "write_pencil", "image_angles", "PencilFit", "fit_pencil", "crlb",
           "detection_threshold", "assign_spokes", "VertexFit", "intersect_lines", "Orientation",
           "read_orientations", "write_orientations", "orient_segments", "resolve_twins_by_continuity",
           "fulcrum_from_frames", "read_angles", "shaft_axis", "fulcrum_3d"]

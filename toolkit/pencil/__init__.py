"""Pencils of lines and what they tell.

- `spec`: the pencil file and exact projection of a pencil;
- `estimator` (with its one-pencil float path `scalar` and the batched `estimator_torch`):
  orientation from image line angles, with covariance, twin and detectability;
- `assign`: labelling unlabelled lines with spokes; `vertex`: their common point;
- `orient`: one frame from raw segments to an `Orientation` (`orientation`: the record
  and its file); `fulcrum`: a pivoting instrument's fulcrum over a sequence;
- `cylinder`: a shaft's 3-D axis from its silhouette and the 3-D fulcrum; `stereo_play`: the
  play two views of a pivot share, in their stereo fulcrum's covariance;
- `grid`: a pencil of a board's own grid lines; `chapter`, `single_angle`: the book
  chapter's models and its single-angle test;
- `defaults`: the defaults and thresholds shared by the estimators and detectors.
"""

from __future__ import annotations

from pencilcal.toolkit.lazy import lazy_exports

# each name imported from its module when first used: importing one module of this package
# does not import the others
__getattr__, __dir__ = lazy_exports(__name__, {
    "spec": ["Pencil", "read_pencil", "write_pencil", "image_angles"],
    "estimator": ["PencilFit", "fit_pencil", "crlb", "detection_threshold"],
    "assign": ["assign_spokes"],
    "vertex": ["VertexFit", "intersect_lines"],
    "orientation": ["Orientation", "read_orientations", "write_orientations"],
    "orient": ["orient_segments", "resolve_twins_by_continuity"],
    "fulcrum": ["fulcrum_from_frames", "read_angles"],
    "cylinder": ["shaft_axis", "fulcrum_3d"],
})


__all__ = ["Pencil", "read_pencil", "write_pencil", "image_angles", "PencilFit", "fit_pencil", "crlb",
           "detection_threshold", "assign_spokes", "VertexFit", "intersect_lines", "Orientation",
           "read_orientations", "write_orientations", "orient_segments", "resolve_twins_by_continuity",
           "fulcrum_from_frames", "read_angles", "shaft_axis", "fulcrum_3d"]

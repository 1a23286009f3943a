"""Calibration boards: the board file (`spec`), their detection in images (`detect`), mrcal's
corner cache (`corners_cache`), and intrinsic calibration from board views (`calibrate`)."""

from __future__ import annotations

from pencilcal.toolkit.lazy import lazy_exports

# each name imported from its module when first used: importing one module of this package
# does not import the others
__getattr__, __dir__ = lazy_exports(__name__, {
    "spec": ["Board", "read_board", "write_board"],
    "detect": ["BoardDetection", "detect_board"],
    "corners_cache": ["read_corners_vnl", "write_corners_vnl"],
    "calibrate": ["CalibrationResult", "calibrate"],
})


__all__ = ["Board", "read_board", "write_board", "BoardDetection", "detect_board", "read_corners_vnl",
           "write_corners_vnl", "CalibrationResult", "calibrate"]

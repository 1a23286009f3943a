"""Calibration boards: the board file (`spec`), their detection in images (`detect`), mrcal's
corner cache (`corners_cache`), and intrinsic calibration from board views (`calibrate`)."""

from __future__ import annotations

from pencilcal.toolkit.board.spec import Board, read_board, write_board
from pencilcal.toolkit.board.detect import BoardDetection, detect_board
from pencilcal.toolkit.board.corners_cache import read_corners_vnl, write_corners_vnl
from pencilcal.toolkit.board.calibrate import CalibrationResult, calibrate

__all__ = ["Board", "read_board", "write_board", "BoardDetection", "detect_board", "read_corners_vnl",
           "write_corners_vnl", "CalibrationResult", "calibrate"]

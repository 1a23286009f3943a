"""Calibration boards: the board file, their detection in images, mrcal's corner cache, and intrinsic calibration from board views."""

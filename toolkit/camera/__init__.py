"""Camera intrinsics: the `Camera` model (projection and undistortion, `model`), the camera
files of OpenCV, mrcal and COLMAP (`formats`), and conversion between them with the
difference it causes (`convert`)."""

from __future__ import annotations

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.camera.formats import read_camera, write_camera
from pencilcal.toolkit.camera.convert import convert_camera, projection_difference

__all__ = ["Camera", "read_camera", "write_camera", "convert_camera", "projection_difference"]

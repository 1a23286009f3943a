"""Camera intrinsics: the `Camera` model (projection and undistortion, `model`), the camera
files of OpenCV, mrcal and COLMAP (`formats`), and conversion between them with the
difference it causes (`convert`)."""

from __future__ import annotations

from pencilcal.toolkit.lazy import lazy_exports

# each name imported from its module when first used: importing one module of this package
# does not import the others
__getattr__, __dir__ = lazy_exports(__name__, {
    "model": ["Camera"],
    "formats": ["read_camera", "write_camera"],
    "convert": ["convert_camera", "projection_difference"],
})


__all__ = ["Camera", "read_camera", "write_camera", "convert_camera", "projection_difference"]

"""The valid region of a sequence's images: where the scene is (an endoscope's circular field
stop, letterbox bars, burnt-in overlays), within which every detector looks.

- `valid`: the `ValidRegion` (circle, polygon or raster; distance to its boundary, masks, its
  record in lines.json) and the mask file a user gives (`read_mask_file`);
- `detect`: the region detected from up to `MAX_FRAMES` frames of a sequence;
- `circle`: the circle step of that detection.
"""

from __future__ import annotations

from pencilcal.toolkit.lazy import lazy_exports

__getattr__, __dir__ = lazy_exports(__name__, {
    "valid": ["ValidRegion", "read_mask_file"],
    "detect": ["detect_valid_region", "sequence_region"],
})

__all__ = ["ValidRegion", "read_mask_file", "detect_valid_region", "sequence_region"]

"""Line features in images, with subpixel edges and honest uncertainties.

- `image`, `working`, `edges`, `refit`, `pairs`, `noise`: the one edge-profile engine
  (grey images, raw <-> working pixels, Gaussian-derivative profiles across a line and
  their peaks, robust line refits, pairs of edges, the image noise);
- `segments`: line segments (LSD, FLD, EDLines proposals, merged and refitted);
- `bars`: printed bars (the spokes of a fan) as their midlines;
- `shaft/`: instrument shafts and their axis images (a subpackage, one module per stage);
- `lines`, `assemble`: one frame's lines as a lines.json record, and the pencil's lines;
- `region/`: the valid region of a sequence's images
  (a field stop, letterbox bars, overlays), within which the detectors look.
"""

from __future__ import annotations

from pencilcal.toolkit.lazy import lazy_exports

# each name imported from its module when first used: importing one module of this package
# does not import the others
__getattr__, __dir__ = lazy_exports(__name__, {
    "segments": ["Segments", "detect_segments", "DETECTORS"],
    "bars": ["Bars", "detect_bars"],
    "shaft.detector": ["Shaft", "detect_shafts"],
    "lines": ["lines_record"],
})


__all__ = ["Segments", "detect_segments", "DETECTORS", "Bars", "detect_bars", "Shaft", "detect_shafts",
           "lines_record"]

"""Drawing estimates on frames, fast enough for video: labelled spokes, the vertex and its
ellipse, the normal, tilt +- sigma, shaft midlines, the fulcrum (`overlay`), and writing
the drawn frames as a video or as PNGs (`writer`)."""

from __future__ import annotations

from pencilcal.toolkit.lazy import lazy_exports

# each name imported from its module when first used: importing one module of this package
# does not import the others
__getattr__, __dir__ = lazy_exports(__name__, {
    "overlay": ["draw_frame", "draw_fulcrum", "draw_orientation", "draw_shafts"],
    "writer": ["OverlayWriter"],
})


__all__ = ["draw_frame", "draw_orientation", "draw_shafts", "draw_fulcrum", "OverlayWriter"]

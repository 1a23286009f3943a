"""Synthetic scenes with exact truth: the printed sheet (`sheet`), rendering of frames
(`render`, on `raster`, `polygons`, `texture`, `objects`), and the orbit, pivot and
tilt-sweep scenarios (`scenarios`)."""

from __future__ import annotations

from pencilcal.toolkit.lazy import lazy_exports

# each name imported from its module when first used: importing one module of this package
# does not import the others
__getattr__, __dir__ = lazy_exports(__name__, {
    "sheet": ["Sheet", "layout_sheet"],
    "render": ["render_frame"],
    "scenarios": ["Scenario", "make_scenario"],
})


__all__ = ["Sheet", "layout_sheet", "render_frame", "Scenario", "make_scenario"]

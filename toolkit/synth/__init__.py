"""Synthetic scenes with exact truth: the printed sheet (`sheet`), rendering of frames
(`render`, on `raster`, `polygons`, `texture`, `objects`), and the orbit, pivot and
tilt-sweep scenarios (`scenarios`)."""

from __future__ import annotations

from pencilcal.toolkit.synth.sheet import Sheet, layout_sheet
from pencilcal.toolkit.synth.render import render_frame
from pencilcal.toolkit.synth.scenarios import Scenario, make_scenario

__all__ = ["Sheet", "layout_sheet", "render_frame", "Scenario", "make_scenario"]

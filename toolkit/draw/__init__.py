"""Drawing estimates on frames, fast enough for video: labelled spokes, the vertex and its
ellipse, the normal, tilt +- sigma, shaft midlines, the fulcrum (`overlay`), and writing
the drawn frames as a video or as PNGs (`writer`)."""

from __future__ import annotations

from pencilcal.toolkit.draw.overlay import draw_frame, draw_fulcrum, draw_orientation, draw_shafts
from pencilcal.toolkit.draw.writer import OverlayWriter

__all__ = ["draw_frame", "draw_orientation", "draw_shafts", "draw_fulcrum", "OverlayWriter"]

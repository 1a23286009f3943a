"""Instrument shafts: the two silhouette edges of a cylinder, its axis image and width.

One module per stage:

- `detector`: `detect_shafts` (one frame), `track_shafts` and `ShaftTracker` (a video), the
  `Shaft` record; it runs the material cue on colour frames, the edge cue on grey ones;
- `work`: the reduced, undistorted work frame the material cue looks at;
- `regions`, `region_bands`, `silhouette`, `material_cue`: the material cue (instrument-like
  regions, their bands, the edges refitted at full resolution in a corridor);
- `edge_cue`, `bands`: the edge cue (bands between long edges, judged along their chord);
- `track`: the corridors a tracked shaft is looked for in;
- `axis`: the midline (the image of the axis) from the two silhouette edges, its covariance
  and the edge floor;
- `mask`, `from_mask`: instruments in a segmentation mask and the axis its outline gives;
  each masked instrument's axis refined on the image's edges (masks in);
- `parts`: the axes of the instrument regions of the learned pixel map that have no shaft, a
  distal part alone among them (kind "part").
"""

from __future__ import annotations

from pencilcal.toolkit.lazy import lazy_exports

__getattr__, __dir__ = lazy_exports(__name__, {
    "detector": ["Shaft", "ShaftOptions", "detect_shafts", "track_shafts", "ShaftTracker", "CUES"],
    "axis": ["Midline", "midline_from_edges", "plane_bisector", "EDGE_FLOOR_PX"],
    "from_mask": ["MaskShaft", "shafts_from_masks",
           "detect_parts"],
    "parts": ["detect_parts"],
})

__all__ = ["Shaft", "ShaftOptions", "detect_shafts", "track_shafts", "ShaftTracker", "CUES", "Midline",
           "midline_from_edges", "plane_bisector", "EDGE_FLOOR_PX", "MaskShaft", "shafts_from_masks",
           "detect_parts"]

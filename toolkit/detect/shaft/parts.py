"""The instrument, not only its shaft: the axis of an instrument region the shaft cues gave
no shaft, a distal part alone (jaws, a hook, a clip applier whose shaft the border cuts off)
included (`detect_parts`).

The cues of `shaft.detector` find a shaft by its two long edges. A distal part alone has no
long edge pair: its jaws are short, its slots show the tissue through them, its metal mirrors
the tissue's colour. What it has is instrument-like pixels, which the learned pixel map
(`shaft.pixels`) tells from tissue everywhere it was measured. Here:

1. *regions*: the work frame's pixels (`shaft.pixels.WORK_PX`) whose instrument probability
   exceeds `PART_PROBABILITY` (the map's own even odds: no tuned level), off the view's rim
   (`RIM_FRACTION`: a field stop's glare, a strip along the border, lights the map up but
   enters nothing), opened by 3 x 3, as connected components; a component is kept when it covers at least `MIN_PART_AREA` of
   the view (a speck of specular tissue is no instrument), touches the border of the view
   (an instrument enters from outside; its shaft, cut off by the border, is out of view) and
   touches none of the shafts already found (widened by half their width: the jaws or wrist
   beyond a found shaft belong to that instrument, which has its axis), and is not glare
   (at most `MAX_CLIPPED` of its pixels at the 8-bit ceiling: a clipped patch shows the
   light, not a material); each kept region is then grown back into the rim where the map
   holds, so that its outline there is the view's border, which the axis reading ignores
   (cut at the rim, the cut read as a straight silhouette);
2. *axis*: each region, carried to raw pixels, read as an instrument mask is
   (`shaft.from_mask.shafts_from_masks`): where its outline has two straight silhouette
   stretches, their axis refitted on the image's edges (kind "shaft", the edge fits'
   covariance); else its principal axis, kind "part", whose sigmas are the part's own
   ambiguity: the angle's sd its half-angle atan(width / length), the offset's half its width
   (`shaft.from_mask.PART_OFFSET_SIGMA_FRAC`);
3. *judged*: an axis is kept when it runs along at least `MIN_ELONGATION` of its widths
   (`MIN_PART_ELONGATION` for a principal axis: a rounder region has no direction to speak
   of) and its band keeps less of the tissue's hue than a shadow does (`shaft.tissue_colour`,
   the shafts' own `MAX_TISSUE_COLOUR`: a dark gap between tissues is as coloured as they are).
   Measured on the masked sources and the unmasked frames: docs/method.md ("distal parts").

Each is a `shaft.from_mask.MaskShaft` with cue ``"pixels"``; its score is its length along
its axis [raw px]. The regions come from a learned model: in the leave-one-source-out table
(`validation.shaft_protocol`) each source's parts come from a model that never saw it, and
the least score a part must reach (none: no parts) is chosen on the other sources; there the
detections are judged after the regions are formed, so each region is read whatever touches
it, with the detections that do (`part_axes`), and kept only where none of them is.

Example
-------
>>> import numpy as np, cv2
>>> img = np.zeros((240, 320, 3), np.uint8); img[:] = (60, 80, 170)                 # tissue
>>> _ = cv2.fillConvexPoly(img, np.array([[0, 90], [120, 95], [120, 145], [0, 140]], np.int32), (150, 150, 152))
>>> parts = detect_parts(cv2.GaussianBlur(img, (0, 0), 1.0), [])          # grey jaws from the left border
>>> len(parts), parts[0].cue, parts[0].kind in ("shaft", "part")
(1, 'pixels', True)
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from pencilcal.toolkit.detect.edges import DEFAULT_GAMMA
from pencilcal.toolkit.detect.shaft.from_mask import shafts_from_masks
from pencilcal.toolkit.detect.shaft.pixels import WORK_PX, instrument_probability
from pencilcal.toolkit.detect.shaft.tissue_colour import MAX_TISSUE_COLOUR, shaft_tissue_colour
from pencilcal.toolkit.detect.shaft.work import CLIPPED_LEVEL, MAX_CLIPPED, Validity, WorkFrame, raw_masks
from pencilcal.toolkit.detect.working import to_working

__all__ = ["detect_parts", "part_axes", "part_regions", "PART_PROBABILITY", "MIN_PART_AREA", "PART_CUE", "RIM_FRACTION",
           "MIN_ELONGATION", "MIN_PART_ELONGATION", "CLIPPED_LEVEL", "MAX_CLIPPED"]

#: A work pixel is instrument where the learned map's probability exceeds this.
PART_PROBABILITY = 0.5
#: The least area of an instrument region, as a fraction of the view's (the valid region's
#: work pixels): 1 %, a jaw 5 x 20 % of a 640 x 360 view.
MIN_PART_AREA = 0.01
#: The cue of the axes found here (`shaft.detector.Shaft.cue`).
PART_CUE = "pixels"
#: The rim of the view left out, as a fraction of the work frame's longer side (5 work px of
#: 320): not tuned, the width of a field stop's glare on the frames looked at.
RIM_FRACTION = 0.015
#: The least length of an axis read from a region, in its widths: a band shorter than wide
#: has no direction to speak of (two straight stretches shorter than the gap between them, a
#: blob's principal axis); not tuned.
MIN_ELONGATION = 1.0
#: ... and of a region read by its principal axis (kind "part"): twice its width, an angle sd
#: (atan(width / length)) of at most 27 deg; a rounder region's principal axis turns with a few
#: pixels of its outline. Set after looking at every source's regions (docs/method.md).
MIN_PART_ELONGATION = 2.0
_BORDER_WORK_PX = 2.0  # a region touches the border of the view within this beyond the rim [work px]


def _shaft_quads(work, camera, shafts):
    """Per shaft with edges, its index in shafts and its band widened by half its width
    either side, as a convex polygon (4, 2) int32 [work px]."""
    out = []
    for i, s in enumerate(shafts):
        e = np.asarray(s.edges, float).reshape(-1, 4)
        if e.shape[0] != 2:
            continue
        ideal = to_working(camera, e).reshape(2, 2, 2)
        c = ideal.reshape(-1, 2).mean(0)
        pts = np.concatenate([c + 1.5 * (p - c) for p in ideal])   # half a width beyond each edge
        out.append((i, np.rint(work.to_work(pts)).astype(np.int32)))
    return out


def part_regions(work, p, shafts=(), camera=None, min_area=MIN_PART_AREA, probability=PART_PROBABILITY):
    """The instrument regions of a work frame (module docstring, step 1): (h, w) int32 labels
    (0: none) and their count.

    work: `shaft.work.WorkFrame`; p: (h, w) its instrument probability
    (`shaft.pixels.instrument_probability`); shafts: the shafts found (`shaft.detector.Shaft`,
    raw pixels), whose instruments have their axes.
    """
    lab, touches = _regions(work, p, shafts, camera, min_area, probability)
    return _numbered(lab, [not t for t in touches])


def _regions(work, p, shafts, camera, min_area, probability):
    """Every instrument region of step 1 before the shafts are asked: (h, w) int32 labels
    1..K (0: none) and, per region, the indices into shafts (a tuple) of those whose widened
    band touches it."""
    import cv2

    # the view's rim (a field stop's glare and vignetting, a letterbox's edge) is left out:
    # a strip along the border lights the map up but enters nothing
    rim = RIM_FRACTION * max(work.shape)
    B = ((p > probability) & (work.dist > rim)).astype(np.uint8)
    B = cv2.morphologyEx(B, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, lab, stats, _ = cv2.connectedComponentsWithStats(B, connectivity=8)
    if n <= 1:
        return np.zeros(work.shape, np.int32), []
    keep = stats[:, cv2.CC_STAT_AREA] >= min_area * max(int(np.count_nonzero(work.valid)), 1)
    keep[0] = False
    border = np.zeros(n, bool)
    near = lab[(work.dist <= rim + _BORDER_WORK_PX) & work.valid]
    border[np.unique(near)] = True
    # glare: a region mostly at the 8-bit ceiling shows the light, not a material; the map's
    # colour and texture features read nothing there
    clipped = np.zeros(n, bool)
    if work.bgr.dtype == np.uint8:
        hot = (work.bgr.max(-1) >= CLIPPED_LEVEL) & (lab > 0)
        clipped = np.bincount(lab[hot], minlength=n) > MAX_CLIPPED * np.maximum(stats[:, cv2.CC_STAT_AREA], 1)
    ok = keep & border & ~clipped
    touches = [[] for _ in range(n)]
    for i, q in _shaft_quads(work, camera, shafts):
        taken = np.zeros(work.shape, np.uint8)
        cv2.fillConvexPoly(taken, cv2.convexHull(q), 1)
        for k in np.unique(lab[taken > 0]):
            touches[k].append(i)
    remap = np.zeros(n, np.int32)
    remap[ok] = np.arange(1, int(ok.sum()) + 1)
    grown = _into_rim(remap[lab], (p > probability) & work.valid & (work.dist <= rim + 1.0), rim)
    return grown, [tuple(touches[k]) for k in np.flatnonzero(ok)]


def _numbered(lab, keep):
    """The labels lab (h, w) int32 1..K of the regions keep (K bool) renumbered 1..count
    (the others 0), and count."""
    remap = np.zeros(len(keep) + 1, np.int32)
    k = np.flatnonzero(np.asarray(keep, bool)) + 1
    remap[k] = np.arange(1, k.size + 1)
    return remap[lab], int(k.size)


def _into_rim(lab, allowed, rim):
    """The labels lab (h, w) int32 grown into the rim where allowed (h, w) bool: the rim was
    left out to keep a border strip from joining regions, but a region cut there has an
    outline along the cut, a straight stretch that is no silhouette; grown back to the view's
    border, its outline there is the border's, which the axis reading ignores."""
    import cv2

    out = lab.copy()
    for _ in range(int(np.ceil(rim)) + 1):
        grown = cv2.dilate(out.astype(np.float32), np.ones((3, 3), np.uint8)).astype(np.int32)
        add = allowed & (out == 0) & (grown > 0)
        if not add.any():
            break
        out[add] = grown[add]
    return out


def detect_parts(image, shafts, camera=None, *, valid_region=None, model=None, gamma=DEFAULT_GAMMA,
                 min_area=MIN_PART_AREA, probability=PART_PROBABILITY, max_parts=4, tissue_colour=MAX_TISSUE_COLOUR):
    """The axes of the instrument regions of a colour frame that have no shaft among `shafts`
    (module docstring): a list of `shaft.from_mask.MaskShaft`, cue `PART_CUE`, kind "shaft"
    or "part", the longest first; [] on a grey frame.

    Parameters
    ----------
    image : (H, W, 3) array
        The raw BGR frame.
    shafts : list of Shaft
        The shafts found on it and kept (`shaft.detector.detect_shafts`): their instruments
        are left out. A detection not yet judged is no shaft found: a region it touches is
        that of its instrument only if the detection is kept (`part_axes`).
    camera : Camera, optional
        Lens model (as `detect_shafts`).
    valid_region : region.ValidRegion, optional
        Where the scene is; its border is where an instrument enters.
    model : shaft.pixels.PixelModel, optional
        The pixel model (default the shipped one, `shaft.pixels.default_model`).
    gamma : float
        The frame's encoding gamma (the edges' refit, `shaft.from_mask.shafts_from_masks`).
    min_area, probability : float
        `MIN_PART_AREA`, `PART_PROBABILITY`.
    max_parts : int
        At most this many.
    tissue_colour : float or None
        The most tissue colour a part's band may have (`shaft.tissue_colour`; None: not
        judged, as the leave-one-source-out protocol does, which chooses it).
    """
    found = _axes(image, shafts, camera, valid_region, model, gamma, min_area, probability, tissue_colour, True)
    return sorted((s for s, _ in found), key=lambda s: -s.score)[:max_parts]


def part_axes(image, detections, camera=None, *, valid_region=None, model=None, gamma=DEFAULT_GAMMA,
              min_area=MIN_PART_AREA, probability=PART_PROBABILITY, tissue_colour=None):
    """Every instrument region's axis, whatever shafts touch it, each with the detections
    that do: a list of (`shaft.from_mask.MaskShaft`, tuple of indices into detections),
    the longest first; [] on a grey frame.

    Where the detections are judged later (the leave-one-source-out protocol detects once
    and chooses its setting per source, `validation.shaft_protocol.filtered`), a region is
    that of a found shaft's instrument only if a detection touching it is kept: judged
    against the detections before they are, a region under a detection the setting drops
    would be lost, and what the protocol chose would turn on what was proposed, not on what
    was found. Parameters as `detect_parts` (detections: the shafts not yet judged; no most
    parts: which are kept depends on the judgement); tissue_colour None: not judged.
    """
    found = _axes(image, detections, camera, valid_region, model, gamma, min_area, probability, tissue_colour,
                  False)
    return sorted(found, key=lambda a: -a[0].score)


def _axes(image, shafts, camera, valid_region, model, gamma, min_area, probability, tissue_colour, untouched):
    """(axis, indices of the shafts touching its region) per kept region's axis (module
    docstring, steps 2-3); untouched: only the regions no shaft touches are read."""
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] < 3:
        return []
    img = img[..., :3]
    validity = Validity(valid_region, img.shape[:2])
    work = WorkFrame(img, camera, validity, WORK_PX)
    lab, touches = _regions(work, instrument_probability(work, model), shafts, camera, min_area, probability)
    if untouched:
        lab, count = _numbered(lab, [not t for t in touches])
        touches = [()] * count
    if not touches:
        return []
    masks = raw_masks(work, camera, lab, len(touches), img.shape[:2])
    read = [(m, t) for m, t in zip(masks, touches) if m.any()]
    # each axis names its region by its index among the masks read (`MaskShaft.instrument`)
    found = [(replace(a, cue=PART_CUE), read[a.instrument][1])
             for a in shafts_from_masks(img, [m for m, _ in read], camera, valid_region=valid_region, gamma=gamma)]
    found = [(s, t) for s, t in found
             if s.score >= (MIN_PART_ELONGATION if s.kind == "part" else MIN_ELONGATION) * s.width_px]
    if found and tissue_colour is not None:
        colours = shaft_tissue_colour(img, [s for s, _ in found], valid_region, validity)
        found = [a for a, c in zip(found, colours) if c <= tissue_colour]
    return found

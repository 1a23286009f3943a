"""Dark shafts in shadow: bands between edges of the tissue's colour, the material cue's
proposals where the grey levels barely step.

A grey or black shaft lying in the shadow of the frame's periphery, or on dark tissue, steps
from the tissue beside it by a few grey levels in lightness, often by none: the shadow takes
the light from both alike. Neither the region maps (`shaft.regions`) nor the grey-level edges
(`shaft.edge_pairs`) give it a side, and the learned likeness rates dark red tissue as
instrument-like as the shaft (a dark pixel's chromaticity fades in its features). What the
shadow keeps is the colour: tissue in shadow is as red as in light (its chromaticity is
unchanged by shading, `shaft.tissue_colour`), an instrument is grey. On the frame's *tissue
colour map* (`shaft.tissue_colour.tissue_colour_map`: each pixel's chromaticity along the
tissue's hue, 1 the frame's median, about 0 a grey or black instrument) such a shaft is a
valley with two clean straight sides.

1. *edges*: the straight edges of the tissue colour map, mapped to grey levels (0 for no
   colour, 255 for `_SPAN` times the frame's median: a step from tissue to grey metal is
   about 100 levels whatever the light), found as `shaft.edge_pairs.edge_segments` finds
   grey-level edges;
2. *pairs*: `shaft.edge_pairs.pair_bands` on them, its material test as it is (the inside
   one material, unlike both outsides in colour by its noise) with the instrument-likeness
   replaced by the greyness ``1 - tissue colour``: the inside less tissue-coloured than both
   outsides;
3. *in shadow*: a pair is kept where its inside is darker than the frame's median luma (a
   pale band greyer than the tissue beside it, a gallbladder's wall or a fold in light, is
   the other cues' to judge, `shaft.edge_pairs`), at most `MAX_SHADOW`.

The bands then go through the material cue as every proposal does: the band test on the
work frame, the edges refitted at full resolution (`shaft.material_cue`), the pixel
evidence, the tissue colour and the grey material (`shaft.grey_material`: a dark band
greyer than the tissue is instrument material whatever the map says).

Work pixels throughout (as `shaft.regions`).

Example
-------
>>> import numpy as np, cv2
>>> from pencilcal.toolkit.detect.shaft.work import Validity, WorkFrame
>>> img = np.zeros((240, 320, 3), np.uint8); img[:] = (120, 140, 200)          # lit tissue
>>> img[:150] = (4, 6, 36)                                                      # in shadow
>>> _ = cv2.fillConvexPoly(img, np.array([[0, 60], [319, 70], [319, 92], [0, 82]], np.int32), (9, 10, 12))
>>> img = cv2.GaussianBlur(img, (0, 0), 1.0)                    # a grey shaft in the shadow
>>> wf = WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=320)
>>> lines, pairs, maps = shadow_bands(wf, 10.0, 80.0, 20.0, 0.5, 60.0)
>>> len(pairs.i), abs(float(pairs.width[0]) - 22.0) < 2.0
(1, True)
>>> bool(maps[0][76, 160]), bool(maps[0][30, 160])
(True, False)
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.shaft.edge_pairs import MIN_CONTRAST_SD, edge_segments, pair_bands
from pencilcal.toolkit.detect.shaft.regions import RegionPairs, close_open
from pencilcal.toolkit.detect.shaft.tissue_colour import tissue_colour_map

__all__ = ["shadow_bands", "shadow_channel", "MAX_SHADOW"]

#: Bands in shadow per frame, the best first (the material cue judges each as it judges
#: a band between two grey-level edges).
MAX_SHADOW = 2
_SPAN = 3.0  # the tissue colour mapped to 255 grey levels (0: no colour)
_BLUR_PX = 1.5  # the colours' smoothing before their chromaticity [work px]
_STATIONS = 24  # samples along a pair, for its inside's and outsides' medians
_SIDE_PX = np.array([2.0, 3.5, 5.0])  # outside samples beyond each edge [work px] (as `shaft.edge_pairs`)


def shadow_channel(work):
    """((h, w) tissue colour, (h, w) float32 grey levels): the work frame's tissue colour map
    (`shaft.tissue_colour.tissue_colour_map`, its median over the valid region) and it
    mapped to grey levels (module docstring, step 1)."""
    import cv2

    # a dark pixel's colour is a few grey levels each: averaged over a few pixels first
    t = tissue_colour_map(cv2.GaussianBlur(work.colours, (0, 0), _BLUR_PX), work.valid).astype(np.float32)
    return t, np.clip(t * (255.0 / _SPAN), 0.0, 255.0)


def _cross_samples(work, lines, i, j, maps):
    """The medians of maps ((h, w) each) over one pair's inside (the middle half of its width
    between its segments i and j) and over each outside (`_SIDE_PX` beyond each segment, away
    from the other): (len(maps), 3) [inside, beyond i, beyond j], nan where unobserved."""
    h, w = work.shape
    a0, a1 = lines.p[i] + lines.lo[i] * lines.u[i], lines.p[i] + lines.hi[i] * lines.u[i]
    # segment j's points facing a0 and a1: the nearest points of its line
    pj, uj = lines.p[j], lines.u[j]
    s = np.linspace(0.0, 1.0, _STATIONS)[:, None]
    A = a0 + s * (a1 - a0)
    B = pj + ((A - pj) @ uj)[:, None] * uj
    d = B - A
    e = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
    sets = [(A[:, None, :] + np.array([0.25, 0.375, 0.5, 0.625, 0.75])[None, :, None] * d[:, None, :]),
            A[:, None, :] - _SIDE_PX[None, :, None] * e[:, None, :],
            B[:, None, :] + _SIDE_PX[None, :, None] * e[:, None, :]]
    out = np.full((len(maps), 3), np.nan)
    for c, X in enumerate(sets):
        x, y = np.rint(X[..., 0]).astype(int).ravel(), np.rint(X[..., 1]).astype(int).ravel()
        ok = (x >= 0) & (x < w) & (y >= 0) & (y < h)
        ok[ok] &= work.valid[y[ok], x[ok]]
        if ok.any():
            for m, M in enumerate(maps):
                out[m, c] = float(np.median(M[y[ok], x[ok]]))
    return out


def shadow_bands(work, wmin, wmax, conv_max_deg, noise, min_len):
    """Candidate bands of grey shafts in shadow (module docstring).

    work, wmin, wmax, conv_max_deg, noise and min_len as `shaft.edge_pairs.pair_bands` takes
    them (work a colour `shaft.work.WorkFrame`).

    Returns
    -------
    (BoundaryLines, RegionPairs, list of (h, w) uint8)
        As `shaft.edge_pairs.pair_bands` returns them, at most `MAX_SHADOW` pairs.
    """
    t, channel = shadow_channel(work)
    seg = edge_segments(work, min_len, channel)
    lines, pairs, maps = pair_bands(work, wmin, wmax, conv_max_deg, noise, min_len, 1.0 - t, segments=seg,
                                    with_maps=False)
    if not maps:
        return lines, pairs, maps
    # in shadow: darker inside than the frame's median (step 3)
    median = float(np.median(work.luma[work.valid])) if work.valid.any() else float(np.median(work.luma))
    keep, out = [], []
    for k, (i, j) in enumerate(zip(pairs.i, pairs.j)):
        (l_in, l_i, l_j), (t_in, t_i, t_j) = _cross_samples(work, lines, i, j, (work.luma, t))
        if not l_in < median or not t_in < min(t_i, t_j):
            continue
        # its edges step in lightness too, both by the edge pairs' least contrast (step 4): a
        # band of the tissue's lightness, greyer only, is a shadow on it or a blurred thing
        # behind (the hysterectomy frames' one false band), not an instrument in front
        if not min(abs(l_in - l_i), abs(l_in - l_j)) >= MIN_CONTRAST_SD * noise:
            continue
        # its map: the pixels nearer its inside's tissue colour than its outsides' (step 5)
        keep.append(k)
        out.append(close_open(((t < 0.5 * (t_in + min(t_i, t_j))) & work.valid).view(np.uint8)))
        if len(keep) == MAX_SHADOW:
            break
    keep = np.array(keep, int)
    return lines, RegionPairs(i=pairs.i[keep], j=pairs.j[keep], width=pairs.width[keep],
                              overlap=pairs.overlap[keep]), out

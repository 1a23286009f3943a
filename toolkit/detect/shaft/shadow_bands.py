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
   the other cues' to judge, `shaft.edge_pairs`), steps in lightness from both outsides by
   the edge pairs' least contrast, and is not darker than both: a dark band on lighter
   tissue both sides (a matte black shaft on lit tissue) has the grey-level outline that
   the grey-level proposals pair and judge, and its greyness alone does not overrule them;
   what this proposal adds is lit metal in the shadow, lighter than a shadowed side. At
   most `MAX_SHADOW`.

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
>>> img[:115] = (4, 6, 36)                                                      # in shadow
>>> _ = cv2.fillConvexPoly(img, np.array([[0, 60], [319, 70], [319, 92], [0, 82]], np.int32), (24, 26, 30))
>>> img = cv2.GaussianBlur(img, (0, 0), 1.0)                    # grey metal lit in the shadow
>>> wf = WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=320)
>>> lines, pairs, maps = shadow_bands(wf, 10.0, 80.0, 20.0, 0.5, 60.0)
>>> len(pairs.i), abs(float(pairs.width[0]) - 22.0) < 2.0
(1, True)
>>> bool(maps[0][76, 160]), bool(maps[0][30, 160])
(True, False)
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.shaft.edge_pairs import MIN_CONTRAST_SD, candidate_pairs, edge_segments, pair_bands
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
    t = tissue_colour_map(cv2.GaussianBlur(work.colours, (0, 0), _BLUR_PX), work.valid).astype(np.float32, copy=False)
    return t, np.clip(t * (255.0 / _SPAN), 0.0, 255.0)


def _medians(V, ok):
    """(K,) the median of each row of V (K, n) float32 over its entries where ok (K, n) bool,
    as np.median gives it (of an even count the two middle values' mean in float32), nan
    where none is."""
    n = np.count_nonzero(ok, 1)
    S = np.sort(np.where(ok, V, np.float32(np.nan)), 1)  # nan last
    rows = np.arange(len(V))
    lo, hi = S[rows, np.maximum(n - 1, 0) // 2], S[rows, np.minimum(n // 2, V.shape[1] - 1)]
    med = np.where(n % 2 == 1, lo, (lo + hi) / np.float32(2.0)).astype(float)
    return np.where(n > 0, med, np.nan)


def _cross_samples(work, lines, I, J, maps):
    """The medians of maps ((h, w) float32 each) over each pair's inside (the middle half of
    its width between its segments I[k] and J[k]) and over each outside (`_SIDE_PX` beyond
    each segment, away from the other): (K, len(maps), 3) [inside, beyond i, beyond j], nan
    where unobserved. All pairs at once; each pair's values as one pair alone gives them."""
    h, w = work.shape
    I, J = np.asarray(I, int), np.asarray(J, int)
    K = len(I)
    a0 = lines.p[I] + lines.lo[I][:, None] * lines.u[I]
    a1 = lines.p[I] + lines.hi[I][:, None] * lines.u[I]
    # segment j's points facing a0 and a1: the nearest points of its line (the projection
    # pair by pair: a batched product may round otherwise)
    pj, uj = lines.p[J][:, None, :], lines.u[J]
    s = np.linspace(0.0, 1.0, _STATIONS)[:, None]
    A = a0[:, None, :] + s[None] * (a1 - a0)[:, None, :]
    D = A - pj
    along = np.stack([D[k] @ uj[k] for k in range(K)]) if K else np.zeros((0, _STATIONS))
    B = pj + along[..., None] * uj[:, None, :]
    d = B - A
    e = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-9)
    sets = [A[:, :, None, :] + np.array([0.25, 0.375, 0.5, 0.625, 0.75])[None, None, :, None] * d[:, :, None, :],
            A[:, :, None, :] - _SIDE_PX[None, None, :, None] * e[:, :, None, :],
            B[:, :, None, :] + _SIDE_PX[None, None, :, None] * e[:, :, None, :]]
    # the three sets' points in one array, their pixels looked up in one pass
    xy = np.rint(np.concatenate([X.reshape(K, -1, 2) for X in sets], 1)).astype(np.intp)
    x, y = xy[..., 0], xy[..., 1]
    ok = (x >= 0) & (x < w) & (y >= 0) & (y < h)
    # flat indices (a take, not a 2-d gather), clipped where out of the frame
    at = np.clip(y, 0, h - 1) * w + np.clip(x, 0, w - 1)
    ok &= work.valid.ravel().take(at)
    ends = np.cumsum([0] + [X.shape[1] * X.shape[2] for X in sets])
    out = np.full((K, len(maps), 3), np.nan)
    for m, M in enumerate(maps):
        V = np.ravel(M).take(at)
        for c in range(3):
            out[:, m, c] = _medians(V[:, ends[c]:ends[c + 1]], ok[:, ends[c]:ends[c + 1]])
    return out


def _luma_median(work):
    """The median of the work frame's luma over its valid pixels (all where none is), as
    np.median gives it; from the luma's histogram where it is whole grey levels (a uint8
    frame's): one pass, no copy nor partition of the pixels."""
    import cv2

    if work.bgr.dtype != np.uint8:
        return float(np.median(work.luma[work.valid])) if work.valid.any() else float(np.median(work.luma))
    mask = work.valid.view(np.uint8) if work.valid.any() else None
    # whole grey levels 0-255: as uint8 the same values, and a faster histogram
    cum = np.cumsum(cv2.calcHist([work.luma.astype(np.uint8)], [0], mask, [256], [0, 256]).ravel().astype(np.int64))
    n = int(cum[-1])
    lo, hi = np.searchsorted(cum, [(n - 1) // 2, n // 2], side="right")
    return float((np.float32(lo) + np.float32(hi)) / np.float32(2.0))


def _in_shadow(luma, median, noise):
    """(K,) bool: the pairs in shadow whose edges step in lightness (module docstring, step
    3), of their luma samples ((K, 3) `_cross_samples`); nan fails, min as Python's min
    takes it (the second where it is less)."""
    l_in, l_i, l_j = luma.T
    # its edges step in lightness, both by the edge pairs' least contrast: a band of the
    # tissue's lightness, greyer only, is a shadow on it or a blurred thing behind (the
    # hysterectomy frames' one false band), not an instrument in front
    dl_i, dl_j = np.abs(l_in - l_i), np.abs(l_in - l_j)
    # and not darker than both: a dark band stepping down from both sides has the grey-level
    # outline that the grey-level proposals pair and judge (`shaft.edge_pairs`, the region
    # maps); what the tissue colour adds is the band the lightness does not outline so, metal
    # lit in the shadow (lighter than a shadowed side). Its greyness alone does not make a
    # dark band an instrument that those proposals refused
    return ((l_in < median) & (np.where(dl_j < dl_i, dl_j, dl_i) >= MIN_CONTRAST_SD * noise)
            & ~((l_in < l_i) & (l_in < l_j)))


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
    cand = candidate_pairs(edge_segments(work, min_len, channel), wmin, wmax, conv_max_deg, min_len)
    lines = cand[0]
    # step 3 first, on every candidate: they depend on a pair's edges only, so where no
    # candidate passes them no band is kept, and the material test (the most of the cost)
    # is skipped; the same bands as judging first. The lightness first, the tissue colour
    # on the pairs in shadow only.
    I, J = cand[1].i, cand[1].j
    shadow = np.zeros(len(I), bool)
    if len(I):
        shadow = _in_shadow(_cross_samples(work, lines, I, J, (work.luma,))[:, 0], _luma_median(work), noise)
    tc = np.full((len(I), 3), np.nan)  # [inside, beyond i, beyond j] tissue colour
    if shadow.any():
        tc[shadow] = _cross_samples(work, lines, I[shadow], J[shadow], (t,))[:, 0]
        t_in, t_i, t_j = tc[shadow].T
        shadow[shadow] = t_in < np.where(t_j < t_i, t_j, t_i)  # greyer than both sides
    if not shadow.any():
        return lines, RegionPairs(i=np.zeros(0, int), j=np.zeros(0, int), width=np.zeros(0),
                                  overlap=np.zeros(0)), []
    lines, pairs, _ = pair_bands(work, wmin, wmax, conv_max_deg, noise, min_len, 1.0 - t, with_maps=False,
                                 candidates=cand)
    at = {(int(i), int(j)): k for k, (i, j) in enumerate(zip(I, J))}
    keep, out = [], []
    for k, (i, j) in enumerate(zip(pairs.i, pairs.j)):
        q = at[int(i), int(j)]
        if not shadow[q]:
            continue
        # its map: the pixels nearer its inside's tissue colour than its outsides' (step 3)
        t_in, t_i, t_j = tc[q]
        keep.append(k)
        out.append(close_open(((t < 0.5 * (t_in + min(t_i, t_j))) & work.valid).view(np.uint8)))
        if len(keep) == MAX_SHADOW:
            break
    keep = np.array(keep, int)
    return lines, RegionPairs(i=pairs.i[keep], j=pairs.j[keep], width=pairs.width[keep],
                              overlap=pairs.overlap[keep]), out

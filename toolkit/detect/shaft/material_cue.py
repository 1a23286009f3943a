"""The material cue of the shaft detector: shafts as bands of instrument-like material, for
frames whose colour tells the materials apart (`shaft.detector`).

1. *regions* (`shaft.regions`): the frame's instrument-likeness (grey, black, white, metal
   against the dominant tissue colour), its levels, the straight boundaries of each level's
   regions and the pairs of them with region between;
2. *bands* (`shaft.region_bands`): each pair judged along its chord through the work frame;
   proposed when its run of region is at least the least length and differs in material
   from both sides, the better of overlapping ones, but an outer band before the better
   ones nested inside it, along one of its edges or its axis, where the material just
   inside both its rims is one (`_outermost_first`: the outermost edge pair, whatever lies
   inside: a shaded limb, a streak, a slot); then, from each long boundary on no
   side of these, the band on the side away from its region (a white or metal shaft
   beside a dark region: the maps give one side) to the outermost far edge a gradient
   model finds across it, with its own region map (`shaft.partner`), judged alike, where
   it overlaps none of them, and the same into its own region, converging by up to a close
   shaft's under perspective, dark or lit, with the edge pairs' colour map and only along its
   seed (`_inward_bands`: a shaft close to the lens whose far region boundary follows a
   shadow inside it); then
   the bands between two long straight grey-level edges
   whose inside is one material unlike both outsides (a dark grasper in the dark periphery,
   a grey shaft the maps do not tell from the tissue, a close shaft whose edges converge
   under perspective by up to `shaft.edge_pairs.PAIR_MAX_CONVERGENCE_DEG`), each with its
   own colour map (`shaft.edge_pairs`), and the outline of an instrument whose inside is
   not one material (its rims are: a clip applier's limbs, the slot between them), with the
   band between its edges as its map, judged alike, where they overlap none of the
   others;
3. *edges* (`shaft.silhouette`, `_band_edges`): each proposed band's two boundaries refitted at
   full resolution in a corridor (`corridor_px`) over its run; an edge found there along less
   than a quarter of it searched again in one of 3 work px (the region boundary's own
   resolution, 1.5 work px, and its offset inside a blurred silhouette; at most a fifth of the
   band's width), kept where found along half of it on the side the first fit leant to; then
   (but for a band into its own region, seen along its seed alone) grown along their own
   lines over the stretch where the band's cross-section goes on looking like the run's
   (`shaft.region_bands.band_stretch`: a shaft running into a drape of its own material, or a
   white shaft merging with white tissue, is a short band of region whose edges go on), each
   edge the best run of stations with gaps up to a width (a thread, a highlight); a band
   whose edges this fit does not find (a dark shaft fading into a vignetted periphery, its
   run the part in light; a thin one of a few grey levels) has each edge fitted along its
   whole line in the work frame by a step averaged along it, with a threshold from the
   frame's measured noise (`shaft.averaged_edges`), taken where the edges run along
   `_AVERAGED_BEYOND` times the run (a jaw's or wrist's band ends with its run) and not
   narrower than a shaft fitted per station beyond whose far end it lies, along its axis
   (its distal part, `_beyond_far_end`), its score `_AVERAGED_SCORE` of a band fitted per
   station;
   the midline is the plane bisector of the two (`shaft.axis`). It is a shaft when both edges
   are seen together along at least the least length, or 1.25 widths where that is shorter (a
   thin shaft: the length is relative to the width, `_least_seen`), and a third of the region's
   run (a run the border of the view cuts is seen up to the border, `_to_border`); when they,
   its band or its region's extension (the instrument's material, its wrist included) run along
   2.5 widths (a jaw is not elongated), or they run along 1.25 widths and the border of the view
   cuts them (a wide shaft close to the lens, entering at a corner; a wrist or jaw ends inside
   the view), its band or extension too where the border cuts its run (a shaft close to the
   lens seen from the border to its collar, its wrist beyond); when they converge by at most
   the largest convergence (a band of edge pairs or one found into its own region: up to
   `shaft.edge_pairs.PAIR_MAX_CONVERGENCE_DEG`) and meet outside the stretch (by half a width);
   and when the band's extension reaches the border of the view or the stretch ends within a
   width of it (an instrument enters from outside; its edges may fade into a dark, vignetted
   surround before the border), or it is very long (`_LONG_FRACTION` of the diagonal). It is no
   shaft when its inside differs from one side by less than `_ONE_SIDED` of its difference from
   the other (the background beside a bright instrument's edge), or when it is seen along fewer
   than `_ELONGATED_WIDTHS` widths, ends inside the view and its instrument's material runs on
   beyond it for over `_DISTAL_RUN` times its length (a distal part, open jaws or a wrist, of
   an instrument whose shaft is in view), unless its material reaches the border at one end
   only and the band lies nearer that end than the other (`_near_entry`: the shaft seen as it
   enters the view, its distal part beyond it). The score is the length of the band's run
   of region seen as a shaft [raw px] (of two readings of one instrument, the band of instrument-like
   material is the shaft, the band that takes in its shadow too is not), at most the length
   along which both edges are seen together (a long run whose edges are found together along a
   short part of it, one of them drifting onto a jaw or a shadow, claims no more), times the
   least fraction of stations where an edge was found;
4. *selection* (`select`): a shaft whose band overlaps a better one's, or that runs along a
   better one's axis (within `_COAXIAL_DEG`, its centre within half that one's width: a
   wrist, the far part of a shaft split by a highlight), is another reading of the same
   instrument; a band whose inside lies between its two sides in lightness, wholly beyond
   one edge of a better shaft and its nearer edge within its own width of that edge, is the
   tissue lit from that instrument between it and a shadow (dark | mid | white: its halo);
   a short band (its run under two widths) whose extension runs into another
   shaft's band is a wrist or jaw part continuing into that instrument's shaft, unless the
   border of the view cuts its run (a close shaft seen to its collar: what it runs into is its
   own wrist or jaws); a narrower band beyond the far end of one whose run the border cuts,
   along its axis and running into it, is that instrument's distal part (`shaft.distal`); a band nested inside one that held is structure inside that instrument.
   All are dropped.

Work pixels in the region steps, ideal pixels from the edges on.

Example
-------
>>> import numpy as np
>>> round(robust_noise(np.random.default_rng(0).normal(100, 2.0, (300, 400)).astype(np.float32)), 1)
2.0
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pencilcal.toolkit.detect.shaft.averaged_edges import band_ends, edge_line, tracked_edges
from pencilcal.toolkit.detect.shaft.axis import midline_from_edges
from pencilcal.toolkit.detect.shaft.distal import beyond_entry
from pencilcal.toolkit.detect.shaft.silhouette import fit_edges
from pencilcal.toolkit.detect.shaft.region_bands import (
    band_polygon,
    band_stretch,
    evaluate_many,
    proposed,
    suppress_overlaps,
)
from pencilcal.toolkit.detect.shaft.edge_pairs import PAIR_MAX_CONVERGENCE_DEG, colour_map, pair_bands
from pencilcal.toolkit.detect.shaft.partner import MAX_SEEDS, partner_bands, turned_round
from pencilcal.toolkit.detect.shaft.shadow_bands import MAX_SHADOW, shadow_bands
from pencilcal.toolkit.detect.shaft.regions import BoundaryLines, RegionPairs, region_pairs_many, scene_angle
from pencilcal.toolkit.geometry.projective import line_meet, line_through

__all__ = ["MaterialShaft", "material_cue", "judge_band", "select", "robust_noise"]

_MAX_PAIRS = 40  # candidate pairs per region map, the longest overlaps first
_MAX_REFINE = 6  # bands of the region maps refitted at full resolution
_MAX_PARTNER = 4  # ... and bands from a single edge (`shaft.partner`)
_MAX_PAIRED = 3  # ... and bands between two grey-level edges (`shaft.edge_pairs`)
# A band whose edges only the averaged step finds (`shaft.averaged_edges`) scores this
# fraction: its edges are an average along them, not seen station by station (on dvrk-suturing
# such a reading of a shaft, 1-2 deg off, outranked the one fitted per station: 180 against 145)
_AVERAGED_SCORE = 0.5
_AVERAGED_BEYOND = 1.5  # ... and is taken where its edges run along this many times its region's run
_TOUCH = 0.1  # ... unless it overlaps one of those by this fraction (`_touches`)
_GROUP_TOL = (3.0, 3.0)  # one boundary at two levels: offset [work px], angle [deg]
_GROW_PASSES = 3  # passes growing a band's edges along its chord
_MIN_CORRIDOR_PX = 1.5  # the narrowest corridor of a growing edge [px]
# The first fit's corridor [work px]: a region boundary lies up to ~1.5 work px inside a
# blurred silhouette (where the likeness map's level cuts it) on top of its own resolution
# (1.5 work px); measured on renders of grey shafts (tests/toolkit/detect/shaft/test_collar.py)
_FIRST_CORRIDOR_WORK_PX = 3.0
_FIRST_CORRIDOR_WIDTH = 0.2  # ... at most this fraction of the band's width (the colour strips stay on their sides)
_WEAK_FRAC = 0.25  # ... searched for an edge the fixed corridor finds along less than this fraction of its run
_FIRST_FRAC = 0.5  # ... and kept where found there along at least this fraction
_COAXIAL_DEG = 3.0  # two readings of one instrument: axes this close ...
_LONG_FRACTION = 0.25  # a run this fraction of the work frame's diagonal need not reach the border
_ELONGATED_WIDTHS = 2.5  # a shaft is seen along this many widths (a jaw is not) ...
_SHORT_WIDTHS = 1.25  # ... or along this many, cut by the border of the view (nested protocol, docs/method.md)
_DISTAL_RUN = 2.0  # a short band whose material runs on over this many times its length is a distal part
_NESTED = 0.8  # a band with this fraction of its area inside another's ...
_INNER_WIDTH = 0.6  # ... and at most this fraction of its width lies inside it (`_outermost_first`)
_RIM = 0.15  # the rims of a band: this fraction of its width inside each edge
_ONE_SIDED = 0.25  # a band whose inside differs from one side by less than this of the other's is background
# E[|z| : |z| below its 90th percentile q] / E[|z|] for z normal: (1 - exp(-q^2 / 2)) / 0.9
_TRUNCATED_MEAN = (1.0 - np.exp(-0.5 * 1.6448536269514722**2)) / 0.9
_LAPLACE_DIFF = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)


def robust_noise(channel):
    """The sd of white noise [grey levels] in one full-resolution channel (H, W):
    Immerkaer's mean-absolute estimator, sqrt(pi / 2) / 6 x mean |L|, on six bands of rows,
    over the responses below their 90th percentile (edges and texture count little; the mean
    of a half-normal's lower 90 % is `_TRUNCATED_MEAN` of its mean), and at least the
    quantisation noise 1 / sqrt(12) (the median estimator of `noise` gives 0 on dark,
    quantised frames)."""
    import cv2

    ch = np.asarray(channel)
    H = ch.shape[0]
    rows = max(8, H // 40)
    starts = np.unique(np.linspace(0, max(H - rows, 0), 6).astype(int))
    # only the bands as float32 (converting the whole channel cost more than the rest)
    r = np.concatenate([np.abs(cv2.filter2D(ch[s0:s0 + rows].astype(np.float32), cv2.CV_32F,
                                            _LAPLACE_DIFF)[1:-1, 1:-1]).ravel() for s0 in starts])
    if r.size == 0:
        return 1.0 / np.sqrt(12.0)
    # the 90th percentile from every 4th response (its sampling error is far below the
    # estimator's own; a partition of all of them is a third of the cost)
    q = r[::4]
    k = int(0.9 * (q.size - 1))
    if ch.dtype == np.uint8:  # whole responses (|r| <= 16 x 255): the same order statistic from counts
        thr = float(np.searchsorted(np.cumsum(np.bincount(q.astype(np.intp), minlength=4081)), k + 1))
    else:
        thr = np.partition(q, k)[k]
    r = r[r <= thr]
    return max(float(np.sqrt(np.pi / 2) * r.mean() / 6.0 / _TRUNCATED_MEAN), 1.0 / np.sqrt(12.0))


@dataclass(eq=False)
class MaterialShaft:
    """A shaft of the material cue (`material_cue`): its `shaft.axis.Midline`, score [raw
    px], polarity, the band that proposed it (`shaft.region_bands.RegionBand`) and its
    outline over the run and over the extension (work px), for the selection; outer: the
    band it lies inside, read before it (`_outermost_first`), or None."""

    midline: object
    score: float
    polarity: str
    band: object
    poly_run: np.ndarray
    poly_ext: np.ndarray
    outer: object = None


def _bands(work, mm, regions, o, wmin, wmax, min_len):
    """(bands, inside): the proposed bands (module docstring, steps 1-2): those of every
    region level (regions: the frame's `shaft.regions.FrameRegions`), the most region
    evidence first, an outer band ahead of those nested inside
    it (`_outermost_first`: inside maps id(inner band) to its outer), the better of
    overlapping ones, at most `_MAX_REFINE`; then
    those from a single edge (`shaft.partner`) that overlap none of them, at most
    `_MAX_PARTNER`; then those between two grey-level edges (`shaft.edge_pairs`) that overlap
    none of these, at most `_MAX_PAIRED`."""
    maps = []
    Ball = B0 = None
    for lev, kind, Bm, repeat in regions.levels:
        if kind == "all":
            Ball = Bm
            B0 = Bm if B0 is None else B0
        if not repeat:
            maps.append((lev, kind, Bm, Ball))
    if Ball is None:
        return [], {}
    # every level's boundaries, their pairs and the candidates found and judged in one batch
    # each (the same lines, pairs and bands as level by level)
    seeds = regions.lines  # each map's that is no repeat, sides at least half the least length
    pairs = region_pairs_many(seeds, wmin, wmax, np.degrees(o.region_conv_max), 0.5 * min_len, _MAX_PAIRS)
    sets = [(lines, pr, Bm, Ba, lev, kind) for lines, pr, (lev, kind, Bm, Ba) in zip(seeds, pairs, maps)]
    bands = [e for got in evaluate_many(sets, work, min_len) for e in got]
    vin = work.valid & (work.dist > 1.0)
    ang_thr = 2.0 * scene_angle(work.bgr, vin, 0.5 * wmin)
    acc = [e for e in bands if proposed(e, min_len, ang_thr)]
    acc.sort(key=lambda e: -e.shaft_len)
    acc, inside = _outermost_first(acc, work, ang_thr)
    acc = _suppressed(acc, inside)[:_MAX_REFINE]
    if o.single_edge:
        seed = _unused_seeds(seeds, acc, min_len)
        got = partner_bands(work, seed, wmin, wmax, np.degrees(o.region_conv_max), mm.luma_noise)
        acc = acc + _more_bands(got, work, B0, min_len, ang_thr, acc, "partner")[:_MAX_PARTNER]
        acc = acc + _inward_bands(work, seed, wmin, wmax, o, mm, B0, min_len, ang_thr, acc)
    if o.edge_pairs:
        got = pair_bands(work, wmin, wmax, min(np.degrees(o.conv_max), PAIR_MAX_CONVERGENCE_DEG), mm.luma_noise,
                         min_len, mm.likeness)
        acc = acc + _more_bands(got, work, B0, min_len, ang_thr, acc, "pairs")[:_MAX_PAIRED]
        if work.bgr.ndim == 3:
            # a grey shaft in shadow: edges of the tissue's colour, not of its lightness; its
            # band may overlap the others' (a reading where theirs fails the judge:
            # `material_cue` keeps it only where none of the bands it touches held up)
            got = shadow_bands(work, wmin, wmax, min(np.degrees(o.conv_max), PAIR_MAX_CONVERGENCE_DEG),
                               mm.luma_noise, min_len)
            acc = acc + _more_bands(got, work, B0, min_len, ang_thr, [], "shadow")[:MAX_SHADOW]
    return acc + _cut_bands(bands, min_len, ang_thr, acc), inside


def _cut_bands(bands, min_len, ang_thr, acc):
    """The region bands at least the least length wide whose run the border of the view cuts
    after `shaft.region_bands.CUT_RUN_WIDTHS` to under `_SHORT_WIDTHS` of their width
    (`shaft.region_bands.proposed`'s cut), as kind "cut", at most `_MAX_PAIRED`, where they
    overlap none of acc: a shaft close to the lens seen from the border to its collar is
    about as long in view as it is wide. Proposed last, so that they take no other
    proposer's place (proposed among the region bands, a short one took a partner band's);
    judged with a close shaft's convergence, without the least length and, as they reach the
    border, without the least elongation (`judge_band`)."""
    cut = [e for e in bands if e.run_len < _SHORT_WIDTHS * e.width_run and proposed(e, min_len, ang_thr, cut=True)
           and not _touches(e, acc)]
    cut.sort(key=lambda e: -e.shaft_len)
    return [replace(e, kind="cut") for e in suppress_overlaps(cut)[:_MAX_PAIRED]]


def _outermost_first(bands, work, ang_thr):
    """(bands, inside): the bands (best first) with each outer band moved ahead of the better
    bands nested inside it (`_nested`) where its rims hold (`_rims_alike`), and {id(inner
    band): its outer band} for those: of an instrument the outermost edge pair is its
    silhouette, whatever lies inside (a shaded limb, a streak, a slot between a grasper's
    jaws is a band of its own, often of more region evidence). ang_thr [deg]: the scene's
    colour variability (`shaft.regions.scene_angle`, twice)."""
    import cv2

    runs = [cv2.convexHull(band_polygon(e))[:, 0, :] for e in bands]
    exts = [cv2.convexHull(band_polygon(e, e.ext))[:, 0, :] for e in bands]
    areas = [abs(cv2.contourArea(h)) for h in runs]
    order, inside = list(range(len(bands))), {}
    for k in range(len(bands)):
        inner = [j for j in range(k) if id(bands[j]) not in inside
                 and _nested(bands[j], runs[j], areas[j], bands[k], exts[k])]
        if inner and _rims_alike(bands[k], work, ang_thr):
            order.remove(k)
            order.insert(min(order.index(j) for j in inner), k)
            inside.update({id(bands[j]): bands[k] for j in inner})
    return [bands[k] for k in order], inside


def _suppressed(bands, inside):
    """The bands (best first) that overlap no better one (`shaft.region_bands.
    suppress_overlaps`), but for an inner band its own outer band (inside: {id(inner):
    outer}, `_outermost_first`): the inner one stays, after the outer, in case the outer is
    judged no shaft (`select` drops it where the outer is held)."""
    kept = suppress_overlaps([e for e in bands if id(e) not in inside])
    for e in bands:
        outer = inside.get(id(e))
        if outer is None or not any(x is outer for x in kept):
            continue
        others = [x for x in kept if x is not outer]
        if suppress_overlaps(others + [e])[-1] is e:
            kept.insert(next(q for q, x in enumerate(kept) if x is outer) + 1, e)
    return kept


def _nested(inner, h_in, a_in, outer, h_out):
    """Whether a band (the hull of its run h_in (N, 2), area a_in) is structure inside
    another (the hull of its extension h_out), as the edge cue has it (`shaft.bands.
    nested_bands`): `_NESTED` of its area within it, at most `_INNER_WIDTH` of its width,
    along one of its edges or its axis (`_along_edge_or_axis`), and the outer band's region
    evidence at least half its own (a strip of tissue around an instrument's short band
    is no reading of it)."""
    import cv2

    if a_in <= 0 or inner.width_run > _INNER_WIDTH * outer.width_run or outer.shaft_len < 0.5 * inner.shaft_len:
        return False
    return cv2.intersectConvexConvex(h_in, h_out)[0] >= _NESTED * a_in and _along_edge_or_axis(inner, outer)


def _along_edge_or_axis(inner, outer):
    """Whether a band runs along an edge of another or along its axis: at the middle of its
    run, one of its edges within a tenth of the other's width of one of the other's edges
    (a shaded limb, a highlight along it), or its centre within a quarter of that width of
    the other's axis (a streak, a slot between two jaws) [work px]."""
    m = (inner.run[0] + inner.run[1]) // 2
    pts = inner.C[m] + np.array([inner.oi[m], inner.oj[m], 0.5 * (inner.oi[m] + inner.oj[m])])[:, None] * inner.na
    # the outer band's edges at the station nearest to that point, across its chord
    k = int(np.argmin(np.linalg.norm(outer.C - pts[2], axis=1)))
    across = (pts - outer.C[k]) @ outer.na
    w = abs(outer.oj[k] - outer.oi[k])
    on_edge = np.min(np.abs(across[:2, None] - np.array([outer.oi[k], outer.oj[k]])[None, :])) <= 0.1 * w
    return bool(on_edge or abs(across[2] - 0.5 * (outer.oi[k] + outer.oj[k])) <= 0.25 * w)


def _inner_rims(band, work):
    """The median colours (2, C) of a band's run just inside each of its two edges (at `_RIM`
    of its width from the edge), from the valid work pixels; NaN where fewer than 3 are
    valid."""
    i0, i1 = band.run
    C, oi, oj = band.C[i0:i1], band.oi[i0:i1, None], band.oj[i0:i1, None]
    img = work.colours
    h, w = work.shape
    out = []
    for t in (_RIM, 1.0 - _RIM):
        P = C + (oi + t * (oj - oi)) * band.na
        x, y = np.rint(P[:, 0]).astype(int), np.rint(P[:, 1]).astype(int)
        ok = (x >= 0) & (x < w) & (y >= 0) & (y < h)
        ok[ok] = work.valid[y[ok], x[ok]]
        out.append(np.median(img[y[ok], x[ok]], axis=0) if np.count_nonzero(ok) >= 3
                   else np.full(img.shape[-1], np.nan))
    return np.array(out)


def _rims_alike(band, work, ang_thr):
    """The rim test of an outer band: the material just inside its two edges is one, their
    median colours' spectral angle at most ang_thr [deg] (the shading of a cylinder darkens
    one limb more than the other but keeps its colour). A band that takes in an instrument
    and its shadow, or a strip of tissue beside it, has another material inside one rim;
    that the inside is unlike the outside beside both edges the band was proposed for
    (`shaft.region_bands.proposed`). Colour frames only."""
    a, b = _inner_rims(band, work)
    if a.size < 3 or not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        return False
    c = float(a @ b) / (float(np.linalg.norm(a) * np.linalg.norm(b)) + 1e-9)
    return bool(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))) <= ang_thr)


def _inward_bands(work, seed, wmin, wmax, o, mm, B0, min_len, ang_thr, acc):
    """The bands from a single edge into its own region (kind "inward", at most
    `_MAX_PARTNER`): each unused boundary (seed) taken as one silhouette edge of the region
    it bounds, its far edge the outermost a gradient model finds across the region
    (`shaft.partner.partner_bands` on the boundaries turned round), converging by up to a
    close shaft's under perspective (`shaft.edge_pairs.PAIR_MAX_CONVERGENCE_DEG`). A dark
    shaft close to the lens is a region of the maps, but its far silhouette lies on shadowed
    tissue of its own grey, so the region's far boundary follows a shadow or a streak inside
    it, converging too much to be paired (the da Vinci frames' left shaft: its two boundaries
    17-19 deg apart, its silhouette edges 12-16 deg). Only boundaries from the border of
    the view are searched (`_from_border`, within the least width), with no band where the
    far edge widens it away from the border (`partner_bands`' from_border: a fold's rim or a
    shadow's edge beyond the silhouette). Each band's own map is the edge pairs' (`shaft.
    edge_pairs.colour_map`: lightness half-weighted, as a grey shaft's streaks and sheen change
    it; the map of colours alone left half of a streaked grey shaft on a side), kept only
    across its seed's stretch (`partner_bands`' along_seed: the far edge was searched there
    alone, and beyond the seed's end, at the collar, the outline steps); its edges are fitted
    over its run and not grown beyond it (`material_cue`). Bands darker or brighter than their
    sides alike: a close grey shaft lit by the endoscope is brighter than the shadowed tissue
    beside it."""
    conv = float(np.degrees(min(o.conv_max, np.radians(PAIR_MAX_CONVERGENCE_DEG))))
    got = partner_bands(work, turned_round(_from_border(seed, work, wmin)), wmin, wmax, conv, mm.luma_noise,
                        from_border=True, colour_map=colour_map, along_seed=True)
    return _more_bands(got, work, B0, min_len, ang_thr, acc, "inward")[:_MAX_PARTNER]


def _from_border(seeds, work, reach):
    """The boundaries (`BoundaryLines`) with an end within reach [work px] of the border of
    the view: a shaft close to the lens enters the view there (and the search costs half as
    much)."""
    ends = np.concatenate([seeds.p + seeds.lo[:, None] * seeds.u, seeds.p + seeds.hi[:, None] * seeds.u])
    x = np.clip(np.rint(ends[:, 0]).astype(int), 0, work.shape[1] - 1)
    y = np.clip(np.rint(ends[:, 1]).astype(int), 0, work.shape[0] - 1)
    near = (work.dist[y, x] <= reach).reshape(2, -1).any(0)
    k = np.flatnonzero(near)
    return seeds.take(k)


def _more_bands(got, work, B0, min_len, ang_thr, acc, kind):
    """The bands of one more proposer (got: its (lines, pairs, region map per pair)) judged
    along their chords, proposed and overlapping none of acc, the better of overlapping
    ones, the most shaft evidence first."""
    lines, pairs, maps = got
    sets = [(lines, _one_pair(pairs, q), B, B0, -1, kind) for q, B in enumerate(maps)]
    more = [e for got in evaluate_many(sets, work, min_len) for e in got]
    more = [e for e in more if proposed(e, min_len, ang_thr) and not _touches(e, acc)]
    more.sort(key=lambda e: -e.shaft_len)
    return suppress_overlaps(more)


def _touches(band, bands):
    """Whether a band's extension overlaps any of bands' runs by `_TOUCH` of the smaller
    area: a single edge's band beside a region band is that instrument read again (the
    region band is the better reading: two boundaries of its material)."""
    import cv2

    P = cv2.convexHull(band_polygon(band, band.ext))[:, 0, :]
    a = abs(cv2.contourArea(P))
    for e in bands:
        Q = cv2.convexHull(band_polygon(e))[:, 0, :]
        if cv2.intersectConvexConvex(P, Q)[0] > _TOUCH * min(a, abs(cv2.contourArea(Q))):
            return True
    return False


def _one_pair(pairs, q):
    """The q-th pair of a `shaft.regions.RegionPairs` alone."""
    return RegionPairs(i=pairs.i[q:q + 1], j=pairs.j[q:q + 1], width=pairs.width[q:q + 1],
                       overlap=pairs.overlap[q:q + 1])


def _unused_seeds(seeds, bands, min_len):
    """The boundary lines of every level (list of `shaft.regions.BoundaryLines`) at least
    half the least length long, on no side of a proposed band and along no longer one
    (within `_GROUP_TOL` px and deg: the same boundary at another level), as one
    `BoundaryLines`, the longest first, at most `shaft.partner.MAX_SEEDS`."""
    P = np.concatenate([L.p for L in seeds]).reshape(-1, 2)
    U = np.concatenate([L.u for L in seeds]).reshape(-1, 2)
    N = np.concatenate([L.n for L in seeds]).reshape(-1, 2)
    lo, hi = np.concatenate([L.lo for L in seeds]), np.concatenate([L.hi for L in seeds])
    sup = np.concatenate([L.support for L in seeds])
    k = np.flatnonzero(hi - lo >= 0.5 * min_len)
    k = k[np.argsort(-(hi - lo)[k], kind="stable")]
    # the lines taken so far: the proposed bands' sides, then the seeds kept
    tp = [ln[0] for e in bands for ln in e.lines]
    tu = [ln[1] for e in bands for ln in e.lines]
    cos_tol = np.cos(np.radians(_GROUP_TOL[1]))
    keep = []
    for i in k:
        if len(keep) == MAX_SEEDS:  # all `shaft.partner` searches
            break
        c = P[i] + 0.5 * (lo[i] + hi[i]) * U[i]
        if tp:
            A, B = np.array(tp), np.array(tu)
            d = c - A
            near = (np.abs(B @ U[i]) >= cos_tol) & (np.abs(B[:, 0] * d[:, 1] - B[:, 1] * d[:, 0]) <= _GROUP_TOL[0])
            if np.any(near):
                continue
        keep.append(i)
        tp.append(P[i])
        tu.append(U[i])
    keep = np.array(keep, int)
    return BoundaryLines(p=P[keep], u=U[keep], n=N[keep], lo=lo[keep], hi=hi[keep], support=sup[keep])


def _edge_specs(band, work, ends):
    """The two proposed edges of a band in ideal px: (p0, u, n_out, s0, s1) each, over its
    stations ends [i0, i1)."""
    j0, j1 = ends
    specs = []
    for (p, u, n, _, _), off in zip(band.lines, (band.oi, band.oj)):
        pi = work.to_ideal(p)
        ui = np.asarray(u) / work.scale
        ui = ui / np.linalg.norm(ui)
        n_out = -np.array([-ui[1], ui[0]]) * np.sign(np.dot(n, [-u[1], u[0]]))
        pa = work.to_ideal(band.C[j0] + off[j0] * band.na)
        pb = work.to_ideal(band.C[j1 - 1] + off[j1 - 1] * band.na)
        s0, s1 = sorted([float((pa - pi) @ ui), float((pb - pi) @ ui)])
        specs.append((pi, ui, n_out, s0, s1))
    return specs


def _grown(fit, spec):
    """The spec of a fitted edge's next pass: its own line, over the range of spec (the
    band's chord, projected on it), at most doubled either side; and the corridor that
    holds 3 sd of the line's prediction there (plus a pixel)."""
    d = fit.u + fit.b * fit.n
    u = d / np.linalg.norm(d)
    n = np.array([-u[1], u[0]])
    n = n if n @ fit.n >= 0 else -n
    p0 = fit.point_at(fit.s_lo)
    p, v, _, s0, s1 = spec
    lo, hi = sorted([float((p + s0 * v - p0) @ u), float((p + s1 * v - p0) @ u)])
    L = fit.s_hi - fit.s_lo
    lo, hi = max(lo, -L), min(hi, 2.0 * L)
    lever = max(abs(lo - (fit.sm - fit.s_lo)), abs(hi - (fit.sm - fit.s_lo)))
    return (p0, u, n, lo, hi), 3.0 * float(np.sqrt(fit.var_t + lever**2 * fit.var_b)) + 1.0


#: The encoding gamma the material cue's edges are located with (`shaft.silhouette.fit_edges`):
#: 1, on the frames' levels as they are, whatever `detect_shafts`' gamma. Its frames are
#: real video, whose tone curve is no pure 2.2: linearised so, the black shaft's edges of the
#: dVRK phantom moved out by up to 1.7 px (widths +8 %) and 3 of the 43 shafts of the real
#: sets were lost. Until it is measured against truth, the cue keeps its measured behaviour.
_MATERIAL_GAMMA = 1.0


def _first_corridors(bands, work, corridor):
    """The first fit's corridor (2 N,) [px] of each band's two edges: `_FIRST_CORRIDOR_WORK_PX`
    work px (the region boundary's offset from a blurred silhouette and its resolution), at
    most `_FIRST_CORRIDOR_WIDTH` of the band's width (the colour strips beyond the corridor
    must stay on their sides of the edge), at least the fixed corridor."""
    s = work.mean_scale
    c = [max(corridor, min(_FIRST_CORRIDOR_WORK_PX, _FIRST_CORRIDOR_WIDTH * e.width_run) / s) for e in bands]
    return np.repeat(np.asarray(c, float), 2)


def _band_edges(image, camera, validity, noise, bands, work, corridor, stretches, gamma):
    """The two edges (`shaft.silhouette.EdgeLine`) of each band, or None: fitted over its region
    run (an edge found along less than `_WEAK_FRAC` of it, again in a corridor wide enough
    for the region boundary's offset from the silhouette, `_first_corridors`, kept where
    found along `_FIRST_FRAC` of it on the side the first fit leant to), then grown
    along their own lines over the stretch of chord where its cross-section goes on looking
    like the run's (stretches: [b0, b1) each, `shaft.region_bands.band_stretch`),
    `_GROW_PASSES` passes each at most doubling them in
    a corridor holding 3 sd of the line's prediction (a line extrapolated from a short
    region boundary would leave the fixed corridor), each the best run of stations with
    gaps up to the band's width, cut where it bends away: the edges tell how far the shaft
    goes. All bands' edges are fitted together, pass by pass; gamma: the frame's encoding
    gamma (the edges located on linear light, `shaft.silhouette.fit_edges`)."""
    gaps = np.repeat([e.width_run / work.mean_scale for e in bands], 2)
    specs = [sp for e in bands for sp in _edge_specs(e, work, e.run)]
    fits = fit_edges(image, camera, validity, noise, specs, corridor, max_gap=gaps, gamma=gamma)
    # an edge found along less than `_WEAK_FRAC` of its run, or not at all, searched again in
    # the wider corridor (the region boundary off the silhouette by more than the fixed one),
    # kept where found there along `_FIRST_FRAC` of it on the side the first fit leant to (an
    # edge across the proposed line from it is another structure's: the phantom's cavity rim)
    wide = _first_corridors(bands, work, corridor)
    weak = [m for m, f in enumerate(fits) if (f is None or f.frac < _WEAK_FRAC) and wide[m] > corridor]
    if weak:
        again = fit_edges(image, camera, validity, noise, [specs[m] for m in weak], wide[weak],
                          max_gap=gaps[weak], gamma=gamma)
        for m, f in zip(weak, again):
            if f is not None and f.frac >= _FIRST_FRAC and (fits[m] is None or f.tm * fits[m].tm > 0):
                fits[m] = f
    targets = [sp for e, st in zip(bands, stretches) for sp in _edge_specs(e, work, st)]
    alive = [k for k in range(len(bands)) if fits[2 * k] is not None and fits[2 * k + 1] is not None]
    for _ in range(_GROW_PASSES):
        todo, specs, corr = [], [], []
        for k in alive:
            grown = [_grown(fits[m], targets[m]) for m in (2 * k, 2 * k + 1)]
            if all(g[0][3] >= -1.0 and g[0][4] <= fits[m].s_hi - fits[m].s_lo + 1.0
                   for g, m in zip(grown, (2 * k, 2 * k + 1))):
                continue  # nothing left to grow into
            todo.append(k)
            specs += [g[0] for g in grown]
            corr += [min(corridor, max(_MIN_CORRIDOR_PX, max(g[1] for g in grown)))] * 2
        if not todo:
            break
        new = fit_edges(image, camera, validity, noise, specs, np.array(corr),
                        max_gap=np.repeat([gaps[2 * k] for k in todo], 2), gamma=gamma)
        for q, k in enumerate(todo):
            fits[2 * k], fits[2 * k + 1] = new[2 * q], new[2 * q + 1]
        alive = [k for k in alive if fits[2 * k] is not None and fits[2 * k + 1] is not None]
    return [(fits[2 * k], fits[2 * k + 1]) if k in alive else None for k in range(len(bands))]


def _border_distance(m, camera, validity):
    """The distance [raw px] from a midline's (ideal px) nearer end to the border of the view."""
    from pencilcal.toolkit.detect.working import to_raw_points

    return float(np.min(validity.distance(to_raw_points(camera, m.ends))))


def _beyond_far_end(m, t, camera, validity):
    """Whether midline m (ideal px) is narrower than midline t and lies beyond t's far end
    (the end farther from the border of the view, where an instrument enters), its centre
    within half t's width of t's axis: the distal part of t's instrument (`shaft.distal`).

    >>> import numpy as np
    >>> from types import SimpleNamespace as Mid
    >>> view = Mid(distance=lambda p: 960.0 - np.asarray(p)[:, 0])        # the border at x = 960
    >>> shaft = Mid(ends=np.array([[955.0, 420.0], [785.0, 432.0]]), width_px=100.0)
    >>> jaw = Mid(ends=np.array([[715.0, 435.0], [590.0, 420.0]]), width_px=29.0, centre=np.array([652.0, 428.0]))
    >>> other = Mid(ends=np.array([[700.0, 300.0], [560.0, 280.0]]), width_px=29.0, centre=np.array([630.0, 290.0]))
    >>> _beyond_far_end(jaw, shaft, None, view), _beyond_far_end(other, shaft, None, view)
    (True, False)
    """
    from pencilcal.toolkit.detect.working import to_raw_points

    if m.width_px >= t.width_px:
        return False
    near, far = (t.ends if np.argmin(validity.distance(to_raw_points(camera, t.ends))) == 0 else t.ends[::-1])
    d = (far - near) / max(float(np.linalg.norm(far - near)), 1e-9)
    c = np.asarray(m.centre, float) - far
    return float(c @ d) > 0 and abs(float(c[0] * d[1] - c[1] * d[0])) <= 0.5 * t.width_px


def _reaches_border(m, camera, validity, corridor):
    """Whether a midline (ideal px) ends within a width and a corridor of the border of the
    view (an instrument enters from outside)."""
    return _border_distance(m, camera, validity) <= m.width_px + corridor


def _to_border(m, camera, validity, corridor):
    """The distance [px] from a midline's nearer end to the border of the view, where it
    ends within a width and a corridor of it (`_reaches_border`), else 0. The edges of a band
    the border cuts are fitted on samples inside the view and fade into a dark, vignetted
    surround before it, so this stretch of a shaft entering there is the view's, not one
    where its edges were looked for and missed (the raw distance stands for the ideal one:
    the lens scales it by a few per cent at most over a width)."""
    d = _border_distance(m, camera, validity)
    return max(d, 0.0) if d <= m.width_px + corridor else 0.0


def _least_seen(width, o):
    """The least length [ideal px] along which a band's edges must be seen together: the
    least length (`ShaftOptions.region_min_length`), or where a band is narrow enough that
    this is more than `_SHORT_WIDTHS` widths, that many widths (of the band, at least the
    least width): a thin shaft entering the view is elongated over fewer pixels than a wide
    one. The least width keeps the floor at half the least length (a sliver is no shaft)."""
    return min(o.region_min_length, _SHORT_WIDTHS * max(width, o.region_wmin))


def _elongated(m, seen, along, camera, validity, corridor, cut=False):
    """Whether a band is elongated like a shaft (a jaw, a blob between two short straight
    boundaries is not): its edges, its band or its instrument-like material run along
    `_ELONGATED_WIDTHS` widths; or its edges are seen together along `_SHORT_WIDTHS` widths
    and the border of the view cuts them (a shaft close to the lens, entering the view
    obliquely at a corner, is seen over fewer widths; a wrist or jaw ends inside the view);
    or, where the border cuts the band's run itself (cut), its band or material does (a shaft
    close to the lens seen from the border to its collar, its wrist beyond: the instrument runs
    on along its axis; a blob at the border between two short edges does not).
    seen, along [ideal px]."""
    w = m.width_px
    if max(seen, along) >= _ELONGATED_WIDTHS * w:
        return True
    short = max(seen, along) if cut else seen
    return short >= _SHORT_WIDTHS * w and _reaches_border(m, camera, validity, corridor)


def material_cue(image, camera, validity, work, mm, regions, o, K, noise):
    """Shafts by the material cue (module docstring, steps 1-3): `MaterialShaft` per band
    that held up, before the selection.

    image: (H, W, 3) the raw frame; validity: `shaft.work.Validity`; work:
    `shaft.work.WorkFrame`; mm: its `shaft.regions.MaterialMap`; regions: its
    `shaft.regions.FrameRegions` (sides at least half the least length); o: the options of
    `shaft.detector.detect_shafts` (`shaft.detector.ShaftOptions`); K: (3, 3) the axis camera
    (`shaft.work.axis_matrix`); noise: the image noise sd [grey levels].
    """
    s = work.mean_scale
    wmin, wmax = o.region_wmin * s, o.region_wmax * s
    min_len = o.region_min_length * s
    long_len = _LONG_FRACTION * float(np.hypot(*work.shape)) / s
    corridor = max(o.corridor_px, 1.5 / s)
    bands, inside = _bands(work, mm, regions, o, wmin, wmax, min_len)
    # a band from one edge into its region is seen along its seed alone (`_inward_bands`):
    # its edges are fitted over its run and not grown beyond it
    stretches = [e.run if e.kind == "inward" else band_stretch(e, mm.luma_noise) for e in bands]
    # the frame as it is: each pass converts only the part its samples need (a third of a
    # 1080p frame over all passes, the median pass a tenth), not the whole frame once
    fitted = _band_edges(image, camera, validity, noise, bands, work, corridor, stretches, _MATERIAL_GAMMA)
    # a band whose edges the fit per station does not find (a shaft fading into a vignetted
    # periphery, its run the part in light; a thin one stepping by a few grey levels): each
    # edge fitted along its whole line by a step averaged along it (`shaft.averaged_edges`)
    averaged = set()
    for k, e in enumerate(bands):
        if fitted[k] is None:
            got = tracked_edges(work, band_ends(e))
            fits = None if got is None else (edge_line(work, got[0]), edge_line(work, got[1]))
            # the run is the part of the shaft in light, or under a few grey levels its region's
            # piece: the edges go on well beyond it (a jaw's or a wrist's band ends with its run)
            if fits is not None and min(f.s_hi - f.s_lo for f in fits) >= _AVERAGED_BEYOND * e.run_len / s:
                fitted[k] = fits
                averaged.add(k)
    judged = [judge_band(e, st, f, camera, validity, o, K, s, corridor, long_len)
              for e, st, f in zip(bands, stretches, fitted)]
    fitted_shafts = [sh for k, (sh, _) in enumerate(judged) if sh is not None and k not in averaged]
    held = [e for e, (sh, _) in zip(bands, judged) if sh is not None and e.kind != "shadow"]
    out = []
    for k, (e, (sh, _)) in enumerate(zip(bands, judged)):
        if sh is None or (e.kind == "shadow" and _touches(e, held)):
            continue
        if k in averaged:
            # averaged edges follow whatever edges lie along the line: a jaw's run on into its
            # wrist, another edge from its tip (on the dVRK phantom's frame 17 such a band, 10
            # deg off the shaft): a narrower band beyond the far end of a shaft fitted per
            # station, along its axis, is that instrument's distal part (`shaft.distal`)
            if any(_beyond_far_end(sh.midline, t.midline, camera, validity) for t in fitted_shafts):
                continue
            sh.score *= _AVERAGED_SCORE  # of two readings of one instrument the one fitted per station is kept
        sh.outer = inside.get(id(e))
        out.append(sh)
    return out


def judge_band(e, stretch, fits, camera, validity, o, K, s, corridor, long_len):
    """(MaterialShaft or None, why): one proposed band `e` (`shaft.region_bands.RegionBand`)
    with its stretch and its two fitted edges (or None) judged as `material_cue` judges
    it (module docstring, step 3); why names the test it failed ("" when it held).

    s: work px per ideal px; corridor [px]; long_len [ideal px]: a band this long need not
    reach the border.
    """
    if fits is None:
        return None, "no edge pair fitted"
    # the background beside one edge (a strip of tissue or shadow beside a bright instrument
    # or its jaws) is like its far side: a shaft differs from both
    cs = np.asarray(e.side_contrast, float)
    if np.all(np.isfinite(cs)) and cs.min() < _ONE_SIDED * cs.max():
        return None, "one side alike"
    m = midline_from_edges(K, fits[0], fits[1])
    if m is None:
        return None, "no midline from the edges"
    conv_max = min(o.conv_max, np.radians(PAIR_MAX_CONVERGENCE_DEG)) if e.kind in ("pairs", "shadow", "inward", "cut") else o.region_conv_max
    if m.convergence_deg > np.degrees(conv_max):
        return None, "edges converge"
    if not _meet_outside(m):
        return None, "edges meet inside the stretch"
    seen = float(np.hypot(*(m.ends[1] - m.ends[0])))
    along = max(stretch[1] - stretch[0], e.ext[1] - e.ext[0]) * e.step / s
    # a run the border of the view cuts is seen up to it (`_to_border`), but the edges must
    # confirm a good part of the run where they were looked for
    seen_b = seen + _to_border(m, camera, validity, corridor) if e.reach_run else seen
    # elongated (`_elongated`), along a good part of the region's run, entering from the
    # border of the view or very long
    # a band the border cuts short (kind "cut") was proposed from `CUT_RUN_WIDTHS` widths of
    # run: its edges need only confirm a good part of it, and reach the border
    cut = e.kind == "cut"
    if (not cut and seen_b < _least_seen(m.width_px, o)) or seen < 0.3 * e.run_len / s:
        return None, "edges seen too short"
    if not (_elongated(m, seen_b, along, camera, validity, corridor, e.reach_run)
            or (cut and _reaches_border(m, camera, validity, corridor))):
        return None, "not elongated"
    if seen < long_len and not (any(e.reach) or _reaches_border(m, camera, validity, corridor)):
        return None, "not from the border"
    # a short band inside the view whose instrument's material runs on well beyond it is a
    # distal part (open jaws, a wrist) of an instrument whose shaft is in view: its axis is
    # not the shaft's
    ext = (e.ext[1] - e.ext[0]) * e.step / s
    if (seen < _ELONGATED_WIDTHS * m.width_px and ext > _DISTAL_RUN * seen
            and not _reaches_border(m, camera, validity, corridor) and not _near_entry(e)):
        return None, "a distal part"
    # the evidence is what both edges confirm: a long run of region whose edges are found
    # together along a short part of it (one edge drifting onto a jaw, a shadow) claims no more
    return MaterialShaft(midline=m, score=min(e.shaft_len / s, seen) * min(f.frac for f in fits),
                         polarity="dark" if e.y_in < e.y_side else "bright",
                         band=e, poly_run=band_polygon(e), poly_ext=band_polygon(e, e.ext)), ""


def _near_entry(e):
    """Whether a band (`shaft.region_bands.RegionBand`) lies nearer the end of its material
    where the instrument enters the view than the other end: where the extension reaches the
    border at one end only, the instrument enters there; a band nearer that end than the
    other is the part seen as it enters (its shaft), and the material running on beyond it,
    away from the border, is its own distal part or tissue of its colour; a distal part lies
    at the far end, its shaft between it and the border. Stations of the band's chord.

    >>> from types import SimpleNamespace as Band
    >>> _near_entry(Band(run=(7, 15), ext=(4, 21), reach=(True, False)))    # 3 to the border, 6 beyond
    True
    >>> _near_entry(Band(run=(30, 40), ext=(4, 42), reach=(True, False)))   # jaws at the far end
    False
    """
    if e.reach[0] == e.reach[1]:
        return False
    gaps = (e.run[0] - e.ext[0], e.ext[1] - e.run[1])  # stations before and after the run
    entry = 0 if e.reach[0] else 1
    return gaps[entry] < gaps[1 - entry]


def _meet_outside(m):
    """The edges of a midline meet outside its stretch by half a width at least."""
    e = m.edges.reshape(2, 2, 2)
    vp = line_meet(line_through(e[0, 0], e[0, 1]), line_through(e[1, 0], e[1, 1]))
    if abs(vp[2]) < 1e-12:
        return True
    ua = (m.ends[1] - m.ends[0]) / max(np.linalg.norm(m.ends[1] - m.ends[0]), 1e-12)
    sv = float((vp[:2] / vp[2] - m.ends[0]) @ ua)
    L = float(np.linalg.norm(m.ends[1] - m.ends[0]))
    return not (-0.5 * m.width_px <= sv <= L + 0.5 * m.width_px)


def _edge_band(m):
    """The quadrilateral (4, 2) float32 [ideal px] between a midline's edges over its ends."""
    na = m.line[:2]
    pts = []
    for P in m.ends:
        for e in m.edges.reshape(2, 2, 2):
            l = line_through(e[0], e[1])
            l = l / np.hypot(l[0], l[1])
            pts.append(P - ((l[:2] @ P + l[2]) / (l[:2] @ na)) * na)
    return np.array([pts[0], pts[2], pts[3], pts[1]], np.float32)


def _overlapping(shafts):
    """Best score first, without those whose edge band overlaps a better one's by more than
    30 % of its own area."""
    import cv2

    out, polys = [], []
    for sh in sorted(shafts, key=lambda x: -x.score):
        P = _edge_band(sh.midline)
        area = abs(cv2.contourArea(P))
        if area <= 0 or any(cv2.intersectConvexConvex(P, Q)[0] > 0.3 * area for Q in polys):
            continue
        out.append(sh)
        polys.append(P)
    return out


def _coaxial(shafts):
    """Without those along a better one's axis (module docstring, step 4)."""
    out = []
    for sh in shafts:
        m = sh.midline
        if not any(np.degrees(np.arccos(np.clip(abs(m.line[:2] @ t.midline.line[:2]), -1, 1))) <= _COAXIAL_DEG
                   and abs(t.midline.line[:2] @ m.centre + t.midline.line[2]) <= 0.5 * t.midline.width_px
                   for t in out):
            out.append(sh)
    return out


def _between_sides(band):
    """Whether a band's inside lies between its two sides in lightness (a ramp from a shadow
    up to a bright edge; a shaft is darker or brighter than both)."""
    lo, hi = sorted(band.y_sides)
    return bool(lo < band.y_in < hi)


def _beside(sh, t):
    """Whether shaft sh lies beside the better shaft t (both `MaterialShaft`, ideal px):
    wholly beyond one of t's edges, its nearer edge within its own width of that edge at both
    ends, its centre alongside t's stretch."""
    mt, m = t.midline, sh.midline
    a = mt.ends[1] - mt.ends[0]
    if not 0.0 <= (m.centre - mt.ends[0]) @ a <= a @ a:
        return False
    own = m.edges.reshape(2, 2, 2)  # (edge, end, xy)
    for e in mt.edges.reshape(2, 2, 2):
        l = line_through(e[0], e[1])
        l = l / np.hypot(l[0], l[1])
        d = (own @ l[:2] + l[2]) * np.sign(l[:2] @ mt.centre + l[2])  # (edge, end) [px], > 0 on t's side
        if np.all(d < 0) and -d[np.argmax(d.mean(1))].min() <= m.width_px:
            return True
    return False


def _ramps_beside(shafts):
    """Without those whose inside lies between their sides (`_between_sides`) beside a
    better one (`_beside`): the strip of tissue lit from an instrument's edge, between it and a
    shadow, is its halo, not a second instrument (module docstring, step 4)."""
    out = []
    for sh in shafts:
        if not (_between_sides(sh.band) and any(_beside(sh, t) for t in out)):
            out.append(sh)
    return out


def _short_extensions(shafts):
    """Without the short bands whose extension runs into another's band (module docstring,
    step 4), but for a band whose run the border of the view cuts: the instrument enters
    there, so the band is its shaft seen to the collar (a close shaft, short for its width)
    and what its extension runs into beyond is its own wrist or jaws."""
    import cv2

    out = []
    for sh in shafts:
        e = sh.band
        if e.run_len < 2.0 * e.width_run and not e.reach_run:
            P = cv2.convexHull(sh.poly_ext)[:, 0, :]
            if any(cv2.intersectConvexConvex(P, Q)[0] > 0.1 * abs(cv2.contourArea(Q))
                   for Q in (cv2.convexHull(t.poly_run)[:, 0, :] for t in shafts if t is not sh)):
                continue
        out.append(sh)
    return out


def _inside_held(shafts):
    """Without those inside another's band that held (`MaterialShaft.outer`): of an
    instrument the outermost edge pair, whatever lies inside."""
    held = {id(sh.band) for sh in shafts}
    return [sh for sh in shafts if sh.outer is None or id(sh.outer) not in held]


def select(shafts, max_shafts):
    """The shafts that are not other readings of a better one (module docstring, step 4),
    best score first, at most max_shafts."""
    return beyond_entry(_short_extensions(_ramps_beside(_coaxial(_overlapping(_inside_held(shafts))))))[:max_shafts]

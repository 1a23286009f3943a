"""The edges of a radial target: every ray through one point along which the image changes
from dark to light (a Siemens star's wedges, a dartboard's sectors), and the circles about it.

A wedge's edges and the boundaries between sectors are straight lines through the vertex in
the target plane, so their images are exact rays through the vertex's image, whatever the
perspective: measured as edges, they need no model of the wedge (the image bisector of a
wedge is not the image of its centre line). `detect_radial_edges` finds them all around
the vertex, in working (undistorted) pixels:

1. *vertex*: the robust intersection of the frame's edge segments (`segments.detect_segments`,
   `pencil.vertex.intersect_lines`): the point most edges pass through;
2. *directions*: the grey levels on circles about it (an annulus where the edges are far
   apart), differentiated along each circle and summed over the radii: every edge through
   the vertex is a peak of that angular profile, its sign the edge's polarity;
3. *edges*: each direction refitted as an edge (`refit.EdgeRefit`, the edge-profile engine)
   from where it is clear of its neighbours (their profiles must not overlap: near the centre
   a star's wedges merge into grey, which is no edge) out to where it ends; the vertex is then
   intersected again from the refitted edges, and steps 2-3 repeated about it; an edge
   that is nowhere clear of its neighbours (a dense star's far side at a steep tilt) is
   then located jointly with their blurred edges (`radial_joint`, the blur fitted with them;
   where that blur is below the one the rounds read, an edge left short is located once
   more from where its neighbours lie as far apart in sds of the fitted blur);
4. *circles*: along rays between the edges, the edges across them (`radial_circles`): the
   points of closed curves about the vertex (the images of circles centred on it: a star's
   outline, a dartboard's rings), returned in raw pixels for the orientation to group by
   circle and fit (`pencil.circle`).

Conventions as in `segments`: segments ``[x1, y1, x2, y2]`` in raw pixels, oriented so that
the image is brighter along n = (-d_y, d_x); uncertainties of the undistorted lines.

Example
-------
>>> from pencilcal.toolkit.camera.model import Camera
>>> from pencilcal.toolkit.pencil.spec import pencil_from_dict
>>> from pencilcal.toolkit.synth.radial import radial_pose, render_layers, star_layers
>>> star = pencil_from_dict({"start_deg": 0, "step_deg": 22.5, "count": 16, "shape": "wedge",
...                          "radius": [0, 60]})
>>> cam = Camera("pinhole", 480, 360, [[400.0, 0, 239.5], [0, 400.0, 179.5], [0, 0, 1]])
>>> R, t = radial_pose(cam, (250, 170), 30.0, 60.0, fill=0.8)
>>> img = render_layers(cam, R, t, star_layers(star), blur_px=0.8, noise=1.0, rng=0)   # linear light
>>> found = detect_radial_edges(img, cam, edges=32, gamma=1.0)
>>> len(found), bool(np.hypot(*(found.vertex - [250, 170])) < 0.05)
(32, True)
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pencilcal.toolkit.detect.edges import DEFAULT_GAMMA, linearised
from pencilcal.toolkit.detect.image import GrayImage
from pencilcal.toolkit.detect.noise import noise_of
from pencilcal.toolkit.detect.radial_circles import circle_points, spokes_end_ring
from pencilcal.toolkit.detect.radial_joint import joint_refit
from pencilcal.toolkit.detect.radial_predicted import predicted_edges, searched_edges
from pencilcal.toolkit.detect.radial_scatter import common_offset, turned_sigma
from pencilcal.toolkit.detect.radial_vertex import better_vertex, floored_sigmas, rough_vertex, walked
from pencilcal.toolkit.detect.refit import EdgeRefit, RefitOptions
from pencilcal.toolkit.detect.segments import Segments, detect_segments, in_valid_region
from pencilcal.toolkit.detect.working import check_camera_image, to_raw_points
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.geometry.angles import angle_diff
from pencilcal.toolkit.pencil.vertex import lines_through

__all__ = ["RadialEdges", "detect_radial_edges", "orient_radial_edges", "trimmed_at_spokes_end", "CLEAR_SIGMAS",
           "CLEAR_PX", "JOINT_SIGMAS", "OFFSET_FLOOR_PX"]

#: Two neighbouring edges are measured only where they lie at least this many sds of their
#: blurred profile apart (`_edge_blur`: the sd of an edge's gradient across it as sampled,
#: blur, pixel, resampling and JPEG together: 0.91, 1.16 and 1.51 px for Gaussian blurs of
#: 0.6, 1 and 1.5 px): closer, the neighbour's blurred edge enters the profile and pulls the
#: peak, a little more on one side than the other under perspective, and the edges turn.
#: Chosen on renders (docs/method.md): 4.5 px at a 1 px blur kept the normal's error within
#: its bound; 3.5 px doubled it; fixed at 4.5 px, frames blurred by 1.5 px had errors 1.5 times
#: their sigmas. 3.9 sds of the blur as once measured (clipped, 2-9 % too large with noise);
#: 4.0 of the unbiased one (seed 7: 3.9 and 4.1 both held the normals' errors within their
#: bounds; 4.5 with JOINT_SIGMAS 3 doubled a 128-wedge star's error; at 4.1 a rendered
#: dartboard with wires, numbers and darts kept 8 of its 20 boundaries, at 4.0 all 20). That
#: cliff is not the clearance's own: the refitted edges' robust vertex
#: (`radial_vertex.vertex_of`) keeps 7-13 of that dartboard's 26 directions as inliers, and their reach (far ends' 90th
#: percentile) fell from 348 to 297 px at 4.1; the angular profile's bands, placed by the
#: reach, moved inwards and chained the numbers' edges into 9 more directions, which pulled
#: the vertex 3 px off. The reach is now taken over every refitted edge
#: (`radial_vertex.vertex_of`: 356-360 px there), and that frame keeps all 20 at 4.0, 4.1 and 4.3.
CLEAR_SIGMAS = 4.0
CLEAR_PX = 3.0  # and never closer than this [px]
#: Located jointly with their neighbours' blurred edges (`radial_joint`), the edges that are
#: nowhere CLEAR_SIGMAS sds from their neighbours are measured from where they lie this many
#: blur sds apart. Chosen on renders (seed 7, the 128-wedge stars at 55-58 deg): from 2 sds
#: their angles' errors were twice their sigmas (the positions hang on the blur's exact
#: value there), from 3 sds some had too little left to measure. 2.5 of the once biased blur;
#: 2.6 of the unbiased one (seed 7).
JOINT_SIGMAS = 2.6
_ARC_SAMPLE_PX = 0.5  # sampling along the circles of the angular profile, at its outer radius
_RADIUS_STEP_PX = 2.0  # spacing of those circles, and at most _BAND_CIRCLES of them in a band
_BAND_CIRCLES = 12
_PEAK_REL = 0.15  # an angular-profile peak: at least this fraction of the typical edge's
_BAND_RATIO = 1.3  # the angular profiles' bands of radii: from r to 1.3 r
#: A star's edges seen in at least this many directions about the segments' vertex are
#: located with their neighbours (``joint="all"``) even where none is clear of them: a
#: small star's 128 edges lie under 5 px apart at its rim
_CROWDED_DIRECTIONS = 16
_SEARCH_PX = (4.0, 2.0, 1.0)  # edge search half-width [px], round by round (the vertex sharpens)
_KERNEL_PX = 1.0  # sd of the derivative kernel across an edge
#: The least sd [px] of an edge's position across it: what the stations' scatter cannot show,
#: a gamma not quite the camera's tone curve, JPEG's blocks, bilinear interpolation across a
#: sharp edge (on renders located on linear light, a star's edges still sit 0.00-0.02 px
#: towards their bright side, the sharper the more; chosen on renders, seed 7); more where
#: the edges' own distances from their vertex say so (`radial_scatter.common_offset`).
OFFSET_FLOOR_PX = 0.02
#: An edge is trimmed at the ring where the spokes end only where its part beyond turned its
#: line by more than this many sds of the inside part's offset (`_trimmed`; the project's test
#: level, not tuned).
TURN_SIGMAS = 3.0
#: Rounds of the search for the edges a first orientation left without a line, each from the
#: orientation the last gave (`trimmed_at_spokes_end`; they stop where one adds no spoke).
PREDICTED_ROUNDS = 3
#: An edge shorter than the least length is used where this many of its angle sds lie within
#: half the angle to its nearest neighbour about the vertex (`_usable`; the project's test
#: level, not tuned).
SEPARATION_SIGMAS = 3.0
_GATE_ROUNDS = 5  # the through-vertex gate's rounds of its shared offset (`_through_vertex`)


@dataclass(frozen=True, eq=False)
class RadialEdges(Segments):
    """The edges through a radial target's vertex (`detect_radial_edges`): a `Segments`
    whose rows run outwards... or inwards, oriented by polarity as every edge segment.

    Extra attributes: ``vertex`` (2,) [working px] the
    point they were found about (the orientation intersects them again, with their own
    sigmas); ``circle_points`` (K, 2)
    [raw px]: edge points across rays between the spokes that run on from ray to ray, the
    candidates for the images of circles centred on the vertex; ``angle_sigma_error`` (M,)
    [rad]: each edge's angle sd with the error its stations' scatter does not show (a star's
    edges: `radial_scatter.turned_sigma`; else ``angle_sigma``), for the orientation's covariance only;
    ``vertex_sd`` [working px]: the sd of the point the edges were located about (the last
    round's vertex before the edges crowded by their neighbours were located with them, or
    after it where wider; where they were located once more about the point the jointly
    located edges met at, that point's): edges located about a point lean towards it and meet there more
    surely than it was known, so the orientation reports the vertex no surer than this
    (`orient_segments`' vertex_floor_px).
    """

    vertex: np.ndarray
    circle_points: np.ndarray
    angle_sigma_error: np.ndarray
    vertex_sd: float = 0.0

    @classmethod
    def empty(cls, **extra):
        return super().empty(vertex=np.full(2, np.nan), circle_points=np.zeros((0, 2)),
                             angle_sigma_error=np.zeros(0), **extra)


def detect_radial_edges(image, camera=None, *, edges=None, valid_region=None, min_length=20.0, circles=True,
                        gamma=DEFAULT_GAMMA, joint="crowded", outer=None, memo=None, predicted=None):
    """The edges through the vertex of a radial target, and the closed curves about it.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
    camera : Camera, optional
        Lens model: edges are fitted straight in undistorted pixels, returned in raw pixels.
    edges : int, optional
        How many edges the target has all around (a star of N wedges: 2N; a dartboard: 20):
        sets the finest angular detail looked for. None: whatever the profile shows.
    valid_region : region.ValidRegion, optional
        Where the scene is; see `detect_segments`.
    min_length : float
        Shortest edge returned [px]; with ``joint="all"`` a shorter one too where its angle
        sd tells it from its neighbours (`SEPARATION_SIGMAS`: a small star's edges under blur).
    circles : bool
        Also gather the edge points of circles about the vertex (`RadialEdges.circle_points`).
    gamma : float
        The frames' encoding gamma: each edge is located on its profiles linearised with it
        (`edges.edge_profiles`). Blur acts on linear light; located on encoded levels, every
        edge of a star blurred by 1 px moves ~0.5 px into its dark side, and the edges no
        longer meet in one point. 1: linear frames.
    joint : {"crowded", "all"}
        Which edges are located jointly with their neighbours' blurred edges (`radial_joint`):
        "crowded", those nowhere clear of them (a dense star's far side at a steep tilt);
        "all", every edge (where clear over at least `min_length` as before, the others
        from `JOINT_SIGMAS` sds apart).
        "all" for printed wedges (a Siemens star): at the clearance a neighbour still pulls
        an edge, a little more from one side than the other under perspective and alike
        for neighbouring edges, an error the normal does not average away (docs/method.md;
        `lines.radial_joint_mode` chooses by the pencil's shape).
        "crowded" where the target has what the model lacks beside its edges (a
        dartboard's raised wires).
    outer : (3, 3) array, optional
        The image conic [working px] of the circle where the spokes end (a dartboard's
        double ring: `radial_circles.spokes_end_ring`, about a first orientation). An edge
        that runs on past it (into a ring of numbers, a maker's print) is refitted only
        inside it, `CLEAR_SIGMAS` blur sds short of it (where the ring's own edge is no
        longer in its profiles), where what lies beyond turned its line (`TURN_SIGMAS`):
        other print does, a boundary's wire running on into the numbers' ring does not.
    memo : dict, optional
        Kept by the caller between calls on one frame (the two passes of
        `trimmed_at_spokes_end`): the edges as steps 1-3 located them, which do not depend on
        `outer`, are kept in it and reused by a call with the same image, camera and options
        (the same objects); only the trim and what follows it run again, the result the same
        as without it.
    predicted : dict, optional
        The edges a first orientation left without a line, where it predicts them
        (`radial_predicted.predicted_edges`): each searched for along its ray and added where
        its step stands out of the noise (`radial_predicted.searched_edges`).

    Returns
    -------
    RadialEdges
        Empty when no point is crossed by enough edges.
    """
    if joint not in ("crowded", "all"):
        raise InputError(f"joint must be 'crowded' or 'all', got {joint!r}")
    of, key = (image, camera, valid_region), (edges, min_length, gamma, joint)
    if memo is not None and memo.get("key") == key and all(a is b for a, b in zip(memo.get("of", ()), of)):
        located = memo["located"]
    else:
        located = _located(image, camera, edges, valid_region, min_length, gamma, joint)
        if memo is not None:
            memo.update(of=of, key=key, located=located)
    if located is None:
        return RadialEdges.empty()
    return _finished(camera, outer, min_length, circles, *located, predicted=predicted, gamma=gamma, joint=joint)


def _located(image, camera, edges, valid_region, min_length, gamma, joint):
    """Steps 1-3 of `detect_radial_edges` (its arguments), all that does not depend on
    `outer`: (img, lin, fit, v, reach, phi, rows, clear) for `_finished`, None where no
    vertex or too few edges were found."""
    img = GrayImage(image, valid_region)
    check_camera_image(camera, img)
    # edges are located on linear light, the pixels linearised before they are interpolated:
    # interpolated first, a pixel pair across a sharp edge is made darker than its linear
    # mean by the power law, and every edge sat 0.03-0.06 px towards its bright side (the
    # sharper, the more), a bias all of a star's edges share
    lin = img if gamma == 1.0 else GrayImage(linearised(img.src, gamma), valid_region)
    segs = detect_segments(image, "lsd", camera=camera, min_length=min_length, valid_region=valid_region)
    try:
        v, reach, v_sd = rough_vertex(segs)
    except EstimationError:
        return None
    fit = None
    blur = 1.16  # a 1 px blur, until the edges say
    for k, search in enumerate(_SEARCH_PX):
        clear = max(CLEAR_PX, CLEAR_SIGMAS * blur)
        phi, sign, seen = _edge_directions(img, camera, v, reach, edges, clear)
        if phi.size < 3:
            return None
        fit = _refit_edges(lin, camera, v, phi, sign, seen, search, clear)
        blur = max(CLEAR_PX / CLEAR_SIGMAS, _edge_blur(lin, camera, fit, clear))
        # no edge through the segments' vertex: no radial target; but a star's edges seen in
        # many directions and clear of their neighbours nowhere (a small star under blur) are
        # a star's, located jointly below
        if k == 0 and np.count_nonzero(fit.ok) < 3 and (joint != "all" or phi.size < _CROWDED_DIRECTIONS):
            return None
        v, reach, v_sd = better_vertex(fit, v, reach, v_sd, joint == "all")
    about_sd = v_sd  # the sd of the point the edges are located about (`RadialEdges.vertex_sd`)
    rows, fit, v1, reach1, sd1 = _jointly(lin, camera, fit, v, reach, v_sd, phi, sign, seen, blur, clear, min_length,
                                          joint)
    # a dense star's rounds each take the last round's loose intersection (within 3 of the two
    # sds added: `radial_vertex.better_vertex`) and may walk the vertex 4-5 px from the
    # segments'; the edges are then located about that point, and those the joint fit does
    # locate meet elsewhere, and more surely (a 128-wedge star 41 % high: 90 edges 0.22 px from
    # the truth at an sd of 0.07 px, the point they were located about 5.2 px off at 0.95 px).
    # Where they meet beyond 3 sds of the point they were located about and fix it better
    # (`radial_vertex.walked`), the edges are located once more about where they meet (one
    # more round, its vertex held, and the joint location), kept where that locates more
    # edges at least min_length long
    if joint == "all" and walked(v1, sd1, v, about_sd):
        again = _relocated(img, lin, camera, v1, reach1, sd1, edges, blur, min_length, joint)
        if again is not None and np.count_nonzero(_long(again[5], min_length)) > np.count_nonzero(_long(fit, min_length)):
            about_sd = sd1  # now located about the point the joint edges met at
            phi, sign, seen, clear, rows, fit, v1, reach1, sd1 = again
    v, reach, v_sd = v1, reach1, sd1
    return img, lin, fit, v, max(v_sd, about_sd), reach, phi, rows, clear


def _jointly(lin, camera, fit, v, reach, v_sd, phi, sign, seen, blur, clear, min_length, joint):
    """The edges of `fit` (EdgeFit, one row per direction phi (E,) [rad] about the vertex v
    (2,) [working px] of sd v_sd [px], sign (E,) and seen (E, 2) [px] as `_edge_directions`
    gives them) located with their neighbours (`joint_refit` from the blur sd [raw px]) as
    `_located` says: (the rows located (K,) int, the fit with them merged, and the vertex,
    reach and sd that `radial_vertex.better_vertex` takes from it)."""
    # the edges located with their neighbours (their blurred edges modelled): those that are
    # nowhere clear of them from where they lie JOINT_SIGMAS blur sds apart; with joint="all"
    # the others too, from where they are clear as before
    rows = np.flatnonzero(~fit.ok) if joint == "crowded" else np.arange(phi.size)
    if rows.size:
        ray = np.concatenate([v + 0 * phi[:, None], v + np.stack([np.cos(phi), np.sin(phi)], -1)], -1)
        r_hi = 1.25 * seen[:, 1]
        # an edge clear of its neighbours over less than min_length (a dense star's squeezed
        # side under blur) is located from JOINT_SIGMAS apart too: from where it is clear it
        # was too short to keep, and both edges of a wedge lost its spoke (128-wedge stars,
        # seed 8181: spokes used 95.7 -> 96.7 %, 64 wedges unchanged)
        clear_ok = fit.ok & (np.hypot(*(fit.p2 - fit.p1).T) >= min_length)

        def within(r):  # where an edge is measured from: inside what was seen, short of its end
            return np.minimum(np.maximum(r, 0.5 * seen[:, 0]), 0.8 * r_hi)

        r_joint = within(_clear_radius(phi, JOINT_SIGMAS * blur))
        r_lo = np.where(clear_ok, within(_clear_radius(phi, clear)), r_joint)
        lines = np.where(fit.ok[:, None], fit.lines(), ray)
        located, fitted = joint_refit(lin, camera, lines, v, sign, blur, r_lo, r_hi, rows=rows, search=_SEARCH_PX[-1])
        # the same for an edge whose clear stretch was long enough but whose joint fit kept
        # less than min_length of it (the fit drops the outer end's stations and weak steps):
        # located again from JOINT_SIGMAS apart, its neighbours at their new lines (128-wedge
        # stars, seeds 9200-9279: 84 % of the spokes lost were lost so)
        again = ~_long(located, min_length) & (r_joint[rows] < r_lo[rows])
        if again.any():
            located = _located_again(lin, camera, lines, v, sign, blur, np.where(_at(rows[again], phi.size), r_joint, r_lo),
                                     r_hi, rows, located, again)
        # a dense star's rounds read the blur with a neighbour's edge inside each profile and
        # about a vertex that may have walked: 1.5-1.95 px where the joint fit, its
        # neighbours modelled, measures 0.9, and JOINT_SIGMAS of that put the edges' joint
        # stretch at the rim, too short to keep. Where the joint fit's blur is the smaller,
        # an edge left short is located once more from JOINT_SIGMAS of it, kept where longer
        # (docs/method.md: seed 420's frame 10, a small 64-wedge star, 0.19 -> 0.03 deg off)
        if joint == "all" and fitted < blur:
            r_fitted = within(_clear_radius(phi, JOINT_SIGMAS * fitted))
            short = ~_long(located, min_length) & (r_fitted[rows] < np.minimum(r_lo, r_joint)[rows])
            if short.any():
                located = _located_again(lin, camera, lines, v, sign, fitted,
                                         np.where(_at(rows[short], phi.size), r_fitted, r_lo), r_hi, rows, located, short,
                                         longer=True)
        fit = _merged(fit, rows, located)
        v, reach, v_sd = better_vertex(fit, v, reach, v_sd, joint == "all")
    return rows, fit, v, reach, v_sd


def _relocated(img, lin, camera, v, reach, v_sd, edges, blur, min_length, joint):
    """The edges located once more about v (2,) [working px] of sd v_sd [px] (`_located`'s
    last round, its vertex held, then `_jointly`): (phi, sign, seen, clear, rows, fit,
    vertex, reach, sd), None where fewer than three directions are seen."""
    clear = max(CLEAR_PX, CLEAR_SIGMAS * blur)
    phi, sign, seen = _edge_directions(img, camera, v, reach, edges, clear)
    if phi.size < 3:
        return None
    fit = _refit_edges(lin, camera, v, phi, sign, seen, _SEARCH_PX[-1], clear)
    blur = max(CLEAR_PX / CLEAR_SIGMAS, _edge_blur(lin, camera, fit, clear))
    return (phi, sign, seen, clear) + _jointly(lin, camera, fit, v, reach, v_sd, phi, sign, seen, blur, clear, min_length,
                                               joint)


def _finished(camera, outer, min_length, circles, img, lin, fit, v, v_sd, reach, phi, rows, clear, predicted=None,
              gamma=DEFAULT_GAMMA, joint="crowded"):
    """The rest of `detect_radial_edges` from the edges `_located` found: the trim at
    `outer`, the edges searched for where `predicted` says, the edges through the vertex
    with their sigmas, the circle points."""
    if outer is not None:  # the edges located jointly keep their own model of their ends
        joint_rows = np.isin(np.arange(phi.size), rows)
        fit = _trimmed(lin, camera, fit, v, np.asarray(outer, float), clear, min_length, joint_rows)
    if predicted is not None and len(predicted["edge"]):
        # (clear is CLEAR_SIGMAS blur sds, never under CLEAR_PX: `_located`)
        # the noise in linear light where it is largest, at white (v^gamma scaled as
        # `edges.linearised` has slope gamma there), never under 8 bits' rounding (a blurred
        # JPEG's smooth areas measure 0)
        noise = gamma * max(noise_of(img), 1.0 / np.sqrt(12.0))
        new, replaced = searched_edges(lin, camera, fit, v, clear / CLEAR_SIGMAS, predicted, min_length,
                                       JOINT_SIGMAS, noise)
        kept = fit.take(np.flatnonzero(~replaced))
        fit = type(fit)(**{f: np.concatenate([getattr(kept, f), getattr(new, f)]) for f in fit.__dataclass_fields__})
    shortest = min_length
    if joint == "all":
        # every edge located jointly (a star's wedges): the shortest kept is the one its sigma
        # tells from its neighbours, not a pixel count: a small star's edges under blur are
        # clear over 10-20 px and known to 0.1-0.3 deg. Not a dartboard's: beside its wires
        # and numbers a short piece turned the right view's sector edges' plane 0.1 deg
        fit = fit.take(np.flatnonzero(_usable(fit.p1, fit.p2, fit.ok, fit.angle_sigma, v, min_length)))
        shortest = 0.0  # (the usable ones chosen)
    out = Segments.from_fit(fit, camera, shortest)
    out = out.select(in_valid_region(img, out.segments))
    out = out.select(_through_vertex(out, v))
    common = common_offset(out, v)
    # a star's edges: what they do not share beyond their sigmas (a dot gain and the vertex's
    # offset taken out) turns them about the vertex, which their stations' scatter does not
    # show; for the covariance only (`radial_scatter.turned_sigma`)
    turn = common_offset(out, v, shared=False) if joint == "all" else 0.0
    out = replace(out, offset_sigma=np.hypot(out.offset_sigma, max(OFFSET_FLOOR_PX, common)))
    err = turned_sigma(out, v, turn) if joint == "all" else out.angle_sigma
    pts = circle_points(lin, camera, v, out.ideal, reach, 1.0) if circles else np.zeros((0, 2))
    return RadialEdges(**{f: getattr(out, f) for f in out.__dataclass_fields__}, vertex=v, circle_points=pts,
                       angle_sigma_error=err, vertex_sd=v_sd)


def _usable(p1, p2, ok, angle_sigma, v, min_length):
    """(E,) bool: the fitted edges (ends p1, p2: (E, 2) [working px], ok, angle_sigma (E,)
    [rad]) an orientation can use: ok and at least `min_length` [px] long, or shorter (a
    small star's edges under blur, clear of their neighbours over 10-20 px) where their
    direction is known surely enough to tell them from their neighbours: `SEPARATION_SIGMAS`
    angle sds within half the angle, about the vertex v (2,), to the nearest other ok edge.

    >>> a = np.radians([0.0, 4.0, 8.0]); u = np.stack([np.cos(a), np.sin(a)], -1)
    >>> p1, p2 = 60 * u, np.array([90.0, 72.0, 72.0])[:, None] * u     # 30, 12 and 12 px long
    >>> _usable(p1, p2, np.ones(3, bool), np.radians([0.2, 0.5, 0.9]), np.zeros(2), 20.0).tolist()
    [True, True, False]
    """
    L = np.hypot(*(p2 - p1).T)
    long = ok & (L >= min_length)
    ok = ok & np.isfinite(angle_sigma)
    idx = np.flatnonzero(ok)
    if idx.size < 2:
        return long
    mid = 0.5 * (p1[idx] + p2[idx]) - v
    ang = np.arctan2(mid[:, 1], mid[:, 0])
    apart = np.abs(angle_diff(ang[:, None], ang[None]))  # (K, K) [rad]
    np.fill_diagonal(apart, np.inf)
    sure = np.zeros_like(long)
    sure[idx] = SEPARATION_SIGMAS * angle_sigma[idx] < 0.5 * apart.min(1)
    return long | sure


def orient_radial_edges(image, camera, pencil, **detect):
    """The edges of a radial target (`detect_radial_edges`, keywords `detect`) and the
    pencil's orientation from them (`pencil.orient.orient_segments`, with their circle
    points and ``lines`` kept), each edge trimmed at the ring the spokes end on
    (`trimmed_at_spokes_end`): (RadialEdges, Orientation).
    """
    from pencilcal.toolkit.pencil.orient import orient_segments

    def oriented(found):
        return orient_segments(camera, found.segments, pencil, angle_sigma=found.angle_sigma,
                               offset_sigma=found.offset_sigma, circle_points=found.circle_points, keep_lines=True,
                               angle_sigma_error=found.angle_sigma_error, vertex_floor_px=found.vertex_sd)

    memo = {}  # the second pass reuses the first's located edges
    return trimmed_at_spokes_end(lambda outer, predicted=None: detect_radial_edges(image, camera, **detect, outer=outer,
                                                                                  memo=memo, predicted=predicted),
                                 oriented, camera, pencil, GrayImage(image, detect.get("valid_region")),
                                 detect.get("joint", "crowded"), detect.get("gamma", DEFAULT_GAMMA))


def trimmed_at_spokes_end(detect, orient, camera, pencil, img, joint="crowded", gamma=DEFAULT_GAMMA):
    """A radial target's edges and their orientation, each edge trimmed where it runs on past
    the ring the spokes end on: (found, orientation), the one way `orient IMAGES` and
    `orient_radial_edges` detect and orient a radial target.

    The edges are detected (``detect(None)``) and oriented (``orient(found)``); with
    ``joint="all"`` (a star's wedges) the edges that orientation left without a line are
    searched for where it predicts them (``detect(None, predicted)``: `radial_predicted`)
    and the frame oriented again, kept where it uses more spokes. Where the
    pencil's spokes end on one of its circles (a dartboard's boundaries at the double ring:
    `pencil.circle.spokes_end`) and the image shows that ring about the orientation's
    plane (`radial_circles.spokes_end_ring`: its outer edge, told from its inner edge by
    their polarities), they are detected again, each trimmed where it runs on past the ring
    (``detect(outer)``: `detect_radial_edges`' ``outer``), and oriented again: beyond it a
    ring of numbers or a maker's print runs on along some boundaries and turns their lines,
    which the labelling then rejects. Not with ``joint="all"``: every edge is then located
    jointly, none trimmed; nor where
    no edge runs on past the ring (the second detection the same as the first, bit for bit:
    its orientation is too).

    detect : callable
        (outer ((3, 3) [working px] or None), predicted (dict, keyword, default None:
        `detect_radial_edges`' ``predicted``)) -> found, with ``segments`` (M, 4) [raw px]
        (a `RadialEdges`, an `io.lines_file.LineFrame`); the second call may reuse the
        first's work (`detect_radial_edges`' ``memo``).
    orient : callable
        found -> `Orientation` with ``lines`` (``keep_lines``), the ring's search needs them.
    camera : Camera or None (None: no trim); pencil : Pencil; img : `GrayImage` of the frame;
    joint : `detect_radial_edges`' joint; gamma : the frame's encoding gamma.

    The orientation kept is refused where its final labelling, once every edge was searched
    for, is still one that nothing confirms (`pencil.confirm.unconfirmed_final`), or uses too few
    of the pencil's spokes to be trusted (`pencil.confirm.few_spokes_final`).
    """
    from pencilcal.toolkit.pencil.confirm import few_spokes_final, unconfirmed_final

    found, rec = _at_spokes_end(detect, orient, camera, pencil, img, joint, gamma)
    return found, few_spokes_final(unconfirmed_final(rec, pencil), pencil)


def _at_spokes_end(detect, orient, camera, pencil, img, joint, gamma):
    """`trimmed_at_spokes_end` before its final labelling is judged (`confirm.unconfirmed_final`)."""
    from pencilcal.toolkit.pencil.circle import spokes_end

    found = detect(None)
    rec = orient(found)
    if camera is None:
        return found, rec
    if joint == "all":  # (every edge is located jointly: none is trimmed)
        return _with_predicted(detect, orient, camera, pencil, found, rec)
    end = spokes_end(camera, rec, found.segments, pencil)
    if end is None:
        return found, rec
    boundaries = _sector_boundaries(pencil)
    outer = spokes_end_ring(img, camera, np.asarray(rec.R_cam_from_target, float), np.asarray(rec.lines["vertex"], float),
                            boundaries, end[0], end[1], gamma)
    if outer is None:
        return found, rec
    trimmed = detect(outer)
    if _same(trimmed, found):  # no edge ran on past the ring: the orientation would be the same
        return found, rec
    return trimmed, orient(trimmed)


def _with_predicted(detect, orient, camera, pencil, found, rec, rounds=PREDICTED_ROUNDS):
    """(found, rec) with the edges `rec` left without a line searched for where it predicts
    them (`radial_predicted`), and oriented again where some were found, kept where it uses
    more spokes (the last kept where not, or where it fails, oriented again so that the last
    call of `orient` is the kept one's); again from the new orientation, at most `rounds`
    times (each round's prediction is closer where the last added spokes beside the missing
    ones)."""
    for _ in range(rounds):
        predicted = predicted_edges(camera, pencil, rec, found.segments)
        if predicted is None:
            break
        more = detect(None, predicted)
        if len(more.segments) == len(found.segments) and _same(more, found):
            break
        again = orient(more)
        if not (again.ok and (again.spokes_used or 0) > (rec.spokes_used or 0)):
            # oriented once more as kept: `orient` may keep state (a video's tracking, the
            # previous frame's orientation: `radial_run.radial_frame`), which the last call sets
            return found, orient(found)
        found, rec = more, again
    return found, rec


def _same(a, b):
    """Whether two detections (dataclasses: `RadialEdges`, `io.lines_file.LineFrame`) are
    the same bit for bit, every field (arrays, dicts of them) compared."""
    def equal(x, y):
        if isinstance(x, dict) or isinstance(y, dict):
            return isinstance(x, dict) and isinstance(y, dict) and x.keys() == y.keys() and all(
                equal(x[k], y[k]) for k in x)
        if isinstance(x, (np.ndarray, list, tuple)) or isinstance(y, (np.ndarray, list, tuple)):
            try:
                return bool(np.array_equal(np.asarray(x), np.asarray(y)))  # NaN never equal: orient again
            except (TypeError, ValueError):
                return False
        return x is y or x == y

    return type(a) is type(b) and all(equal(getattr(a, f), getattr(b, f)) for f in a.__dataclass_fields__)


def _sector_boundaries(pencil):
    """(B,) [rad] the directions of a sector target's boundaries all round the vertex in the
    target frame, ascending: the spokes, and where they do not go all round (lines listed
    over half a turn) each one's opposite ray too.

    >>> from pencilcal.toolkit.pencil.spec import pencil_from_dict
    >>> np.degrees(_sector_boundaries(pencil_from_dict({"start_deg": 0, "step_deg": 45, "count": 3}))).round(6).tolist()
    [0.0, 45.0, 90.0, 180.0, 225.0, 270.0]
    """
    a = np.asarray(pencil.angles, float)
    if not pencil.full_circle:
        a = np.r_[a, a + np.pi]
    return np.unique(np.round(np.remainder(a, 2 * np.pi), 12))


def _ray_conic(v, u, C):
    """Distance (E,) [px] from v (2,) along the unit directions u (E, 2) to the conic C (3, 3)
    (the larger root: v inside the ellipse), NaN where the ray misses it."""
    vh = np.r_[v, 1.0]
    uh = np.concatenate([u, np.zeros((len(u), 1))], -1)
    a = np.einsum("ei,ij,ej->e", uh, C, uh)
    b = uh @ (C @ vh)
    c = vh @ C @ vh
    disc = b * b - a * c
    with np.errstate(all="ignore"):
        rho = np.where((disc >= 0) & (a != 0), (-b + np.sign(a) * np.sqrt(np.maximum(disc, 0.0))) / a, np.nan)
    return np.where(rho > 0, rho, np.nan)


def _trimmed(img, camera, fit, v, outer, margin, min_length, joint):
    """`fit` (EdgeFit) with every edge that runs on past the conic `outer` (3, 3) [working px]
    (the circle where the spokes end) refitted from its inner end to `margin` [px] short of
    it, in the rounds of `_SEARCH_PX` (the line beyond turned the fit by more than the last
    round's search); those whose part inside is shorter than min_length [px], or whose refit
    fails or leaves less than min_length, are kept as they were, and so are those whose
    whole line lies within `TURN_SIGMAS` sds of the inside part's (what runs on beyond continues
    the edge: a dartboard's boundary wire into the ring of numbers) and those located
    jointly with their neighbours (joint (E,) bool: `radial_joint`, which models their ends)."""
    p1, p2 = fit.p1, fit.p2
    d1, d2 = np.hypot(*(p1 - v).T), np.hypot(*(p2 - v).T)
    out2 = d2 >= d1
    far = np.where(out2[:, None], p2, p1)
    u = (far - v) / np.maximum(np.maximum(d1, d2), 1e-12)[:, None]
    cut = _ray_conic(v, u, outer) - margin
    rows = np.flatnonzero(fit.ok & ~joint & np.isfinite(cut) & (np.maximum(d1, d2) > cut)
                          & (cut - np.minimum(d1, d2) >= min_length))
    if rows.size == 0:
        return fit
    end = v + cut[rows, None] * u[rows]
    q1 = np.where(out2[rows, None], p1[rows], end)
    q2 = np.where(out2[rows, None], end, p2[rows])
    for search in _SEARCH_PX:
        new = EdgeRefit(img, np.concatenate([q1, q2], -1), camera,
                        RefitOptions(search=search, extend=0.0, sigma_px=_KERNEL_PX)).fit()
        good = new.ok
        if not good.any():
            return fit
        # the next round about the refitted line, over the same stretch (the ends projected on it)
        rows, new = rows[good], new.take(np.flatnonzero(good))
        d = (new.p2 - new.p1) / np.maximum(np.hypot(*(new.p2 - new.p1).T), 1e-12)[:, None]
        q1, q2 = (new.p1 + np.sum((q[good] - new.p1) * d, -1)[:, None] * d for q in (q1, q2))
    long = np.hypot(*(new.p2 - new.p1).T) >= min_length  # a shorter piece stands for nothing: as it was
    # and only where the part beyond turned the line: the whole edge's line lies off the
    # inside part's, at its ends, by over TURN_SIGMAS sds of the inside part's offset (a
    # dartboard's boundary wires run on into the ring of numbers along the same line, numbers'
    # print does not). The two fits share the inside stations, so the sd of their difference is
    # below the inside part's alone; the two sds added (hypot) kept a print turned 2 deg that
    # biased its boundary by 0.36 deg (tests/validation/test_validate.py)
    whole = fit.take(rows)
    n = np.stack([-(whole.p2 - whole.p1)[:, 1], (whole.p2 - whole.p1)[:, 0]], -1)
    n /= np.maximum(np.hypot(*n.T), 1e-12)[:, None]
    turned = np.zeros(rows.size, bool)
    for q in (new.p1, new.p2):
        off = np.abs(np.sum((q - whole.p1) * n, -1))
        turned |= off > TURN_SIGMAS * new.offset_sigma_at(q)
    long &= turned
    return _merged(fit, rows[long], new.take(np.flatnonzero(long)))


def _through_vertex(segs, v, rounds=_GATE_ROUNDS):
    """(M,) bool: the edges `segs` (`Segments`) that pass through the vertex v (2,) within
    their sigmas (floored) and the offset they all share (`radial_scatter.common_offset`, of the edges
    passing so far: a raised wire beside a dartboard's boundary, seen obliquely, moves its
    edges 1-3 px off the vertex): from the edges passing on their own sigmas, the shared
    offset taken again from those passing with it, until the set stops changing (at most
    `rounds` times). On their own sigmas, the shared dartboard photographs' side views lost
    4 and 2 of their 20 boundaries here (edges 3.4-7 sds off, the shared offset 2.5 and 2.1
    px; docs/method.md); where the edges
    meet as their sigmas say (renders) the shared offset is 0 and the set the same.

    >>> a = np.radians(np.arange(12) * 30.0)
    >>> off = np.array([2, -2, 1.5, -1.5, 2.5, -2, 2, -1, 1.5, -2.5, 2, 12.0])  # px; the last: other print
    >>> u = np.stack([np.cos(a), np.sin(a)], -1)
    >>> n, z = np.stack([-u[:, 1], u[:, 0]], -1), np.zeros(12)
    >>> ideal = np.concatenate([20 * u + off[:, None] * n, 150 * u + off[:, None] * n], -1)
    >>> segs = Segments(segments=ideal, ideal=ideal, angle_sigma=z + 1e-4, offset_sigma=z + 0.1, length=z + 130,
    ...                 contrast=z + 50, residual_px=z, stations=z.astype(int) + 50)
    >>> plain = lines_through(np.zeros(2), ideal, np.radians(0.05), 0.5)[1]   # own sigmas, floored
    >>> int(plain.sum()), int(_through_vertex(segs, np.zeros(2)).sum())      # the shared offset allowed
    (4, 11)
    """
    ang, off = floored_sigmas(segs)
    _, through = lines_through(v, segs.ideal, ang, off)
    for _ in range(rounds):
        _, again = lines_through(v, segs.ideal, ang, np.hypot(off, common_offset(segs.select(through), v)))
        if np.array_equal(again, through):
            break
        through = again
    return through


def _long(fit, min_length):
    """(E,) bool: the rows of `fit` (EdgeFit) located and at least min_length [px] long."""
    return fit.ok & (np.hypot(*(fit.p2 - fit.p1).T) >= min_length)


def _at(rows, n):
    """(n,) bool: True at the indices rows."""
    return np.isin(np.arange(n), rows)


def _located_again(lin, camera, lines, v, sign, blur, r_lo, r_hi, rows, located, again, longer=False):
    """`located` (EdgeFit, one row per edge of `rows` (K,)) with the edges `again` (K,) bool
    located once more (`joint_refit` from blur sd [px], between r_lo and r_hi (E,) [px]),
    their neighbours at the lines `located` gave them (`lines` (E, 4) [working px] updated
    in place); with `longer`, each kept only where longer than before."""
    lines[rows] = np.where(located.ok[:, None], located.lines(), lines[rows])
    redo, _ = joint_refit(lin, camera, lines, v, sign, blur, r_lo, r_hi, rows=rows[again], search=_SEARCH_PX[-1])
    idx = np.flatnonzero(again)
    if longer:
        before = np.where(located.ok[idx], np.hypot(*(located.p2 - located.p1)[idx].T), 0.0)
        keep = np.flatnonzero(redo.ok & (np.hypot(*(redo.p2 - redo.p1).T) > before))
        idx, redo = idx[keep], redo.take(keep)
    return _merged(located, idx, redo)


def _merged(fit, rows, other):
    """`fit` (EdgeFit) with its rows `rows` replaced by those of `other` (EdgeFit, one row each)."""
    merged = {f: getattr(fit, f).copy() for f in fit.__dataclass_fields__}
    for f, a in merged.items():
        a[rows] = getattr(other, f)
    return replace(fit, **merged)


def _angular_profile(img, camera, v, r_a, r_b, n_phi):
    """phi (P,) [rad] and the tangential derivative of the grey level [levels / px] summed
    over circles of radius r_a..r_b [working px] about v: each edge through v is a peak."""
    phi = np.arange(n_phi) * (2 * np.pi / n_phi)
    radii = np.linspace(r_a, r_b, max(2, min(_BAND_CIRCLES, int((r_b - r_a) / _RADIUS_STEP_PX) + 1)))
    c, s = np.cos(phi), np.sin(phi)
    pts = v + radii[:, None, None] * np.stack([c, s], -1)[None]  # (R, P, 2)
    raw = to_raw_points(camera, pts)
    inside = img.in_region(raw[..., 0], raw[..., 1])
    vals = img.sample(np.where(inside, raw[..., 0], 0), np.where(inside, raw[..., 1], 0)).astype(float)
    # central difference along each circle [levels / px], smoothed over ~1 px of arc
    d = (np.roll(vals, -1, 1) - np.roll(vals, 1, 1)) / (2.0 * radii[:, None] * (2 * np.pi / n_phi))
    ok = inside & np.roll(inside, -1, 1) & np.roll(inside, 1, 1)
    prof = np.sum(np.where(ok, d, 0.0), 0) / np.maximum(np.sum(ok, 0), 1)
    k = max(1.0, 1.0 / _ARC_SAMPLE_PX)
    taps = np.exp(-0.5 * (np.arange(-3 * int(k), 3 * int(k) + 1) / k) ** 2)
    taps /= taps.sum()
    prof = np.real(np.fft.ifft(np.fft.fft(prof) * np.fft.fft(np.r_[taps[len(taps) // 2:], np.zeros(n_phi - len(taps)),
                                                                     taps[:len(taps) // 2]])))
    return phi, prof


def _edge_directions(img, camera, v, reach, edges, clear):
    """Directions phi (E,) [rad] of the edges through v, their sign (E,) (+1: brighter
    towards larger angles) and the radii (E, 2) [px] between which they were seen, from
    angular profiles over bands of radii out to 1.5 reach.

    An edge through the vertex shows at the same direction in neighbouring bands, its peaks
    chained from band to band; other print (a ring of numbers, a dart) shows in one. A
    tilted target's image reaches much farther from the vertex on its near side than on its
    far side: each edge's direction is taken from the outermost band of its chain (there the
    edges lie farthest apart, and an error of the vertex turns them least). A faint direction
    beside a stronger one is its companion (`_companions`: a raised wire's side), not an edge.
    """
    H, W = img.shape
    # no farther than the image's farthest corner from the vertex
    r_max = min(1.5 * reach, float(np.max(np.hypot(np.r_[0, W - 1] - v[0], np.r_[0, H - 1, 0, H - 1][:, None] - v[1]))))
    # from where the edges lie half `clear` apart on average: a tilted target's far side is
    # nearer the vertex, where they come apart at a smaller radius
    r_min = min(max(10.0, 0.5 * clear * (edges or 0) / (2 * np.pi), 0.15 * reach), 0.5 * r_max)
    bands = r_min * _BAND_RATIO ** np.arange(int(np.ceil(np.log(r_max / r_min) / np.log(_BAND_RATIO))))
    profiles = []
    for r_a in bands:
        n_phi = int(np.ceil(2 * np.pi * _BAND_RATIO * r_a / _ARC_SAMPLE_PX))
        profiles.append(_angular_profile(img, camera, v, r_a, _BAND_RATIO * r_a, n_phi))
    # the typical edge of the band that shows the edges best: bands beyond the target hold
    # only noise and other print, whose peaks must not count as edges
    typical = max(_typical_peak(prof, edges) for _, prof in profiles)
    peaks = [_profile_peaks(phi, prof, typical, r_a) for r_a, (phi, prof) in zip(bands, profiles)]
    chains = _chain_bands(peaks, bands)
    if not chains:
        return np.zeros(0), np.zeros(0), np.zeros((0, 2))
    # strongest evidence first: the most bands, then the strongest peak
    chains.sort(key=lambda c: (-len(c), -max(peaks[b][2][i] for b, i in c)))
    out = []
    for c in chains:
        b, i = c[-1]  # outermost
        ang, sgn = peaks[b][0][i], peaks[b][1][i]
        r_out = _BAND_RATIO * bands[b]
        if len(c) < 2 and peaks[b][2][i] < 0.5:
            continue  # one band, and weak: other print
        if any(sgn == o[1] and abs(np.angle(np.exp(1j * (ang - o[0])))) < 2.0 / min(r_out, o[3]) for o in out):
            continue
        out.append((ang, sgn, bands[c[0][0]], r_out, max(peaks[bb][2][ii] for bb, ii in c)))
    out.sort()
    ang, sgn, r0, r1, height = (np.array(x, float) for x in zip(*out))
    keep = ~_companions(ang, r0, r1, height, clear)
    return ang[keep], sgn[keep], np.stack([r0, r1], -1)[keep]


def _companions(ang, r0, r1, height, clear):
    """(E,) bool: the directions ang (E,) [rad], seen from r0 to r1 (E,) [px], that are a
    stronger direction's companions: weak (their peaks under half the typical edge's,
    heights (E,) relative to it, and under half that direction's), beginning to show where
    that direction runs (it was seen from farther in), within `clear` [px] of it. A raised
    wire beside a dartboard's boundary, its far side or its highlight seen obliquely, is a
    faint line 2-4 px beside the edge, parallel to it, not a second edge through the vertex:
    counted as a neighbour, it left the edge nowhere clear (`_clear_radius`) and its joint
    location (`radial_joint`, which models every neighbour as an edge of the same step)
    failed. A star's edges, and a sector target's, are alike in strength.

    >>> ang, r1, height = np.radians([10.0, 11.0, 40.0]), np.full(3, 200.0), np.array([1.0, 0.2, 1.0])
    >>> _companions(ang, np.array([20.0, 80.0, 20.0]), r1, height, 4.0).tolist()   # 1.4 px beside
    [False, True, False]
    >>> _companions(ang, np.array([80.0, 80.0, 20.0]), r1, height, 4.0).tolist()   # seen from the same band
    [False, False, False]
    """
    d = np.abs(angle_diff(ang[:, None], ang[None]))
    beside = ((d < np.pi / 2) & (r0[:, None] * np.sin(d) < clear) & (height[None] >= 2.0 * height[:, None])
              & (r0[None] < r0[:, None]) & (r0[:, None] <= r1[None]))
    return (height < 0.5) & np.any(beside, 1)


def _chain_bands(peaks, bands):
    """Chains of peaks [(band, index), ...], inner band first: a peak of band b continues the
    chain of a peak of band b - 1 of its sign within 3 px at that band's radius (the vertex's
    error turns an edge's direction by about its size over the radius), the closest pairs
    first, each peak in one chain."""
    chains, last = [], {}
    for b, (ang, sgn, _) in enumerate(peaks):
        prev = peaks[b - 1] if b else (np.zeros(0), np.zeros(0), np.zeros(0))
        here = {}
        d = np.abs(np.angle(np.exp(1j * (ang[:, None] - prev[0][None]))))
        d = np.where((sgn[:, None] == prev[1][None]) & (d <= 3.0 / bands[b - 1] if b else False), d, np.inf)
        # the closest pairs first: taken in angle order, a weak peak beside an edge (a wire's
        # side) took the edge's chain whenever it came first, and the edge began a new one
        for k in np.argsort(d, axis=None, kind="stable"):
            i, j = divmod(int(k), max(prev[0].size, 1))
            if not np.isfinite(d[i, j]):
                break
            if i not in here and j in last:
                here[i] = last.pop(j)
        for i in range(ang.size):
            if i not in here:
                here[i] = []
                chains.append(here[i])
            here[i].append((b, i))
        last = here
    return chains


def _peaks(prof):
    """Indices of the local extrema of a periodic profile (P,) (peaks of |prof| within runs
    of one sign)."""
    a = np.abs(prof)
    return np.flatnonzero((a >= np.roll(a, 1)) & (a > np.roll(a, -1)) & (np.sign(prof) == np.sign(np.roll(prof, 1))))


def _typical_peak(prof, edges):
    """The typical edge's height in an angular profile: the median of its strongest peaks
    (as many as the edges expected, or a quarter of all)."""
    a = np.abs(prof)[_peaks(prof)]
    if a.size == 0:
        return 0.0
    return float(np.median(np.sort(a)[::-1][: max(3, edges or a.size // 4)]))


def _profile_peaks(phi, prof, typical, r_a):
    """The peaks of one angular profile prof (P,) at angles phi (P,) [rad] that reach
    `_PEAK_REL` of the typical edge's height: their angles (sub-sample), signs and height
    relative to `typical`, each at least 2 px (at radius r_a) from a stronger one."""
    n_phi = phi.size
    a = np.abs(prof)
    idx = _peaks(prof)
    idx = idx[a[idx] >= _PEAK_REL * typical]
    if idx.size == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    am, a0, ap = a[(idx - 1) % n_phi], a[idx], a[(idx + 1) % n_phi]
    den = am - 2 * a0 + ap
    off = np.where(den < 0, 0.5 * (am - ap) / np.where(den < 0, den, -1.0), 0.0)
    ang = phi[idx] + np.clip(off, -0.5, 0.5) * (2 * np.pi / n_phi)
    keep = _strongest_apart(ang, a0, 2.0 / r_a)
    return ang[keep], np.sign(prof[idx][keep]), a0[keep] / max(typical, 1e-12)


def _strongest_apart(ang, strength, sep):
    """Indices (in angle order) of the directions ang (E,) [rad] that have no stronger one
    within sep [rad] (cyclic)."""
    order = np.argsort(ang)
    a, w = ang[order], strength[order]
    n = a.size
    if n < 2:
        return order
    ext = np.r_[a - 2 * np.pi, a, a + 2 * np.pi]
    wext = np.r_[w, w, w]
    lo = np.searchsorted(ext, a - sep, "left")
    hi = np.searchsorted(ext, a + sep, "right")
    keep = np.ones(n, bool)
    for k in range(1, int(np.max(hi - lo)) + 1):  # the neighbours within sep, k at a time
        for j in (n + np.arange(n) - k, n + np.arange(n) + k):
            inside = (j >= lo) & (j < hi)
            keep &= ~(inside & ((wext[j] > w) | ((wext[j] == w) & (j < n + np.arange(n)))))
    return np.sort(order[keep])


def _clear_radius(phi, clear):
    """The radius [px] (E,) from which each of the directions phi (E,) [rad] lies `clear`
    [px] from its neighbours."""
    order = np.argsort(phi)
    gaps = np.diff(np.r_[phi[order], phi[order][0] + 2 * np.pi])
    gap = np.empty_like(phi)
    gap[order] = np.minimum(gaps, np.roll(gaps, 1))
    return clear / np.maximum(np.sin(np.minimum(gap, np.pi / 2)), 1e-6)


def _edge_blur(img, camera, fit, clear, lines=24):
    """The sd [px] of the edges' gradient across them (blur and pixel together): the scale of
    the clearances, and where the joint location's own fit of the blur starts (`radial_joint`);
    the second moment of the linearised profile's derivative within 4 px of the edge, pooled
    over the stations of each of the `lines` longest refitted edges, where their neighbours
    lie at least twice `clear` away (their own profiles clean), the median over those edges;
    `clear` / CLEAR_SIGMAS when there are none to measure.

    The derivative is summed as it is, noise and all: the noise's share of the moments
    averages out over the stations. Clipped at 0 at each station (its negative samples
    dropped), it made the blur larger the noisier the frame (on a 32-wedge star at a blur of
    0.8 px: 0.99 px without noise, 1.08 px with noise 3), and the joint location, which
    models the neighbours with it, turned every edge of a dense star the same way."""
    from pencilcal.toolkit.detect.edges import derivative_kernel, edge_profiles

    ok = np.flatnonzero(fit.ok)
    if ok.size == 0:
        return clear / CLEAR_SIGMAS
    L = np.hypot(*(fit.p2[ok] - fit.p1[ok]).T)
    top = ok[np.argsort(-L)[:lines]]
    p1, p2 = fit.p1[top], fit.p2[top]
    u = (p2 - p1) / np.maximum(np.hypot(*(p2 - p1).T), 1e-12)[:, None]
    s = np.linspace(0.55, 0.95, 12)[None, :] * np.hypot(*(p2 - p1).T)[:, None]  # the outer part
    prof = edge_profiles(img, camera, p1, u, s, 4.0, derivative_kernel(0.7), 0.7)
    g = np.gradient(prof.profiles.astype(float), axis=-1)  # per sample (0.5 px), brighter along n
    t = (np.arange(g.shape[-1]) - (g.shape[-1] - 1) / 2.0) * 0.5
    d = t - np.nan_to_num(prof.t)[..., None]  # from each station's edge
    good = prof.inside & prof.found & np.isfinite(prof.t)
    g = np.where(good[..., None] & (np.abs(d) <= 4.0), g, 0.0)
    m0, m1, m2 = g.sum((-2, -1)), (g * d).sum((-2, -1)), (g * d * d).sum((-2, -1))
    with np.errstate(all="ignore"):
        var = m2 / m0 - (m1 / m0) ** 2
    use = (good.sum(-1) >= 3) & (m0 > 0) & np.isfinite(var) & (var > 0)
    if not use.any():
        return clear / CLEAR_SIGMAS
    return float(np.sqrt(np.median(var[use])))


def _refit_edges(img, camera, v, phi, sign, seen, search, clear):
    """The edges along directions phi (E,) [rad] from v, refitted (`EdgeFit`, E rows) from
    where each is `clear` [px] from its neighbours (and not much inside the radii seen
    (E, 2) [px] where its angular profile showed it) out to a quarter beyond those radii,
    oriented by their sign."""
    r_hi = 1.25 * seen[:, 1]
    r_lo = np.maximum(_clear_radius(phi, clear), 0.5 * seen[:, 0])
    r_lo = np.minimum(r_lo, 0.8 * r_hi)
    u = np.stack([np.cos(phi), np.sin(phi)], -1)
    inner, outer = v + r_lo[:, None] * u, v + r_hi[:, None] * u
    # brighter along n = (-d_y, d_x): outwards for edges brighter towards larger angles
    p1 = np.where(sign[:, None] > 0, inner, outer)
    p2 = np.where(sign[:, None] > 0, outer, inner)
    opts = RefitOptions(search=search, extend=0.0, sigma_px=_KERNEL_PX)
    return EdgeRefit(img, np.concatenate([p1, p2], -1), camera, opts).fit()

"""The lines of one frame, as the lines file holds them: the one place where `pencilcal
lines`, `orient IMAGES` and `fulcrum IMAGES` turn a decoded image into lines.

`detect_frame_lines` finds the edge segments (`segments.detect_segments`), the midlines
of the printed bars (`bars.detect_bars`) or the edges of a radial target all round its
vertex with the points of the circles about it (`radial.detect_radial_edges`) of one
image, and optionally its instrument shafts (`shaft.detector.detect_shafts`, or from an
instrument mask), and returns them as an `io.lines_file.LineFrame`: segments
``[x1, y1, x2, y2]`` in raw pixels, angle sd in degrees, offset sd in pixels;
`lines_record` is its record.

Example
-------
>>> import numpy as np
>>> img = np.full((120, 200), 220, np.uint8); img[55:61, 20:180] = 30   # a 6 px bar
>>> f = detect_frame_lines("a.png", img, bars=True)
>>> f.image, f.segments.shape, np.round(f.width_px, 2).tolist()
('a.png', (1, 4), [6.0])
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.bars import detect_bars
from pencilcal.toolkit.detect.edges import DEFAULT_GAMMA
from pencilcal.toolkit.detect.segments import MIN_LENGTH_PX, Segments, detect_segments
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.lines_file import LineFrame

__all__ = ["default_min_length", "detect_frame_lines", "lines_record", "fan_line_options", "shaft_records",
           "radial_edge_count", "radial_joint_mode"]


def default_min_length(shape, bars):
    """Shortest line [px] written by default for a frame of `shape` (H, W[, C]).

    20 px for edge segments, a radial target's edges among them (`detect_frame_lines` with
    ``radial``: only edges through the vertex are looked for there, and a small star's are
    short). For bars 20 px or 1/30 of the frame's smaller side, whichever is longer (36 px
    at 1080p): relative to the frame as OpenCV's ArUco
    ``minMarkerPerimeterRate``, since a spoke that short carries ~1/100 of the weight of
    one across a sixth of the frame (angle variance ~ 1 / length^3) and, on a busy frame,
    the shorter fragments are mostly texture.

    >>> default_min_length((1080, 1920), bars=True), default_min_length((1080, 1920), bars=False)
    (36.0, 20.0)
    """
    return max(MIN_LENGTH_PX, min(shape[0], shape[1]) / 30.0) if bars else MIN_LENGTH_PX


def fan_line_options(pencil_width, edges=False):
    """How the lines of a printed fan are found (`orient IMAGES`, `validate`): (bars,
    bar_polarity) for `detect_frame_lines`.

    The spokes' midlines (`bars.detect_bars`, at any width within its limits: 2.5 px to 1/8
    of the image) by default: dark bars when the pencil file gives the spokes' width (the
    pencil file's spokes are dark bars), else whichever polarity the frame shows (thin
    printed lines or thick bars, dark on light or light on dark). Plain edge segments only
    with `edges`.

    >>> fan_line_options(1.0), fan_line_options(None), fan_line_options(None, edges=True)
    ((True, 'dark'), (True, 'either'), (False, 'dark'))
    """
    if edges:
        return False, "dark"
    return True, ("dark" if pencil_width is not None else "either")


def radial_edge_count(pencil):
    """How many edges a pencil's target shows (`radial.detect_radial_edges`' ``edges``):
    the edges of its wedges or its sector boundaries (`spec.Pencil.edge_angles`); None for a
    fan of lines or bars, which are found as bars (`fan_line_options`).

    >>> from pencilcal.toolkit.pencil.spec import pencil_from_dict
    >>> radial_edge_count(pencil_from_dict({"start_deg": 0, "step_deg": 5.625, "count": 64, "shape": "wedge"}))
    128
    """
    return None if pencil.shape == "line" else int(pencil.edge_angles()[0].size)


def radial_joint_mode(pencil):
    """Which of a radial target's edges are located jointly with their neighbours
    (`radial.detect_radial_edges`' ``joint``): "all" for printed wedges (a Siemens star,
    whose edges are what the model holds: blurred steps), "crowded" otherwise (a dartboard's
    boundaries have raised wires beside them, which the model has not).

    >>> from pencilcal.toolkit.pencil.spec import pencil_from_dict
    >>> radial_joint_mode(pencil_from_dict({"start_deg": 0, "step_deg": 5.625, "count": 64, "shape": "wedge"}))
    'all'
    """
    return "all" if pencil.shape == "wedge" else "crowded"


def detect_frame_lines(name, image, camera=None, detector="auto", bars=False, shaft=False, min_length=None,
                       bar_width=None, proposal_scale=None, valid_region=None, bar_polarity="dark",
                       gamma=DEFAULT_GAMMA, bar_tracker=None, instrument_mask=None, radial=None, axis_prior=None,
                       shaft_tracker=None, edge_model="step", radial_joint="crowded", segments=True, parts=False,
                       radial_outer=None, ideal=False, radial_memo=None, radial_pencil=None, radial_predicted=None):
    """The lines of one decoded image, as a `LineFrame`.

    Parameters
    ----------
    name : str
        The frame's name.
    image : (H, W) or (H, W, 3) array
    camera : Camera, optional
    detector : {"auto", "lsd", "fld", "edlines"}
        The OpenCV detector proposing lines; "auto": FLD for bars on frames of 720 lines or
        more, LSD otherwise and for edge segments and shafts (`segments.proposal_detector`).
    bars : bool
        Midlines of dark bars (`detect_bars`, the printed spokes; with ``width_px``) instead
        of edge segments (`detect_segments`).
    shaft : bool
        Also the instrument shafts (`detect_shafts`), as their records.
    min_length : float, optional
        Shortest line [px]; None: `default_min_length`.
    bar_width : (2,) [px], optional
        Accepted bar widths.
    proposal_scale : float, optional
        See `detect_bars`.
    valid_region : region.ValidRegion, optional
        Where the scene is: nothing is found on its boundary (a field stop's edge); see
        `detect_segments`. None: the whole image.
    bar_polarity : {"dark", "light", "either"}
        With `bars`: dark bars on a light ground, light bars on a dark ground, or whichever
        of the two this frame shows (`detect_bars`).
    gamma : float
        With `shaft`: the frame's encoding gamma (`detect_shafts`; 1: linear frames).
    bar_tracker : bar_track.BarTracker, optional
        With `bars`, frames in order: the bars found by it (the previous frame's bars as
        this frame's proposals where it has them) instead of a full detection.
    instrument_mask : dict, optional
        With `shaft`: the shafts of the frame's instrument mask instead of the detector's
        (`shaft.from_mask.shafts_from_masks`): ``{"mask": array, "labels": ..., "instances":
        ...}``.
    radial : int, optional
        The edges of a radial target all round its vertex (`radial.detect_radial_edges`,
        located on the profiles linearised with `gamma`), so many of them (0: whatever the
        frame shows), with the points of the circles about it (``circle_points``), instead
        of bars or edge segments.
    axis_prior : shaft.prior.AxisPrior or list of them, optional
        With `shaft`: the instruments' fulcrum images (`detect_shafts`): at most one shaft
        each, through it.
    shaft_tracker : shaft.detector.ShaftTracker, optional
        With `shaft`, frames in order: the shafts found by it (where the previous frame's
        were) instead of a full detection.
    edge_model : {"step", "limb"}
        With `shaft`: how the shafts' edges are located (`detect_shafts`; a tracker has its
        own).
    radial_joint : {"crowded", "all"}
        With `radial`: which edges are located jointly with their neighbours
        (`radial.detect_radial_edges`' ``joint``; `radial_joint_mode` by the pencil's shape).
    radial_outer : (3, 3) array, optional
        With `radial`: the image conic [working px] of the circle where the spokes end, each
        edge that the print beyond it turns trimmed at it (`radial.detect_radial_edges`'
        ``outer``; `orient IMAGES` finds it about a first orientation:
        `radial.trimmed_at_spokes_end`).
    radial_memo : dict, optional
        With `radial`: kept between the calls on one frame, the edges located by the first
        reused by the next (`radial.detect_radial_edges`' ``memo``: a trim's second pass).
    radial_pencil : Pencil, optional
        With `radial` (and a camera): each edge trimmed at the ring where the pencil's spokes
        end, found from a first orientation, as `orient IMAGES` trims them
        (`radial.orient_radial_edges`); instead of `radial_outer`.
    radial_predicted : dict, optional
        With `radial`: the edges a first orientation left without a line, each searched for
        where it predicts them (`radial.detect_radial_edges`' ``predicted``).
    segments : bool
        Edge segments (`detect_segments`) where neither `bars` nor `radial` is asked for;
        False with `shaft`: the shafts alone (the segments of a textured frame cost most of
        the time, and a live shaft video does not need them).
    parts : bool
        With `shaft`: also the axes of the instrument regions with no shaft, distal parts
        alone among them (`shaft.parts.detect_parts`, cue "pixels").
    ideal : bool
        With a camera: the segments in undistorted pixels too, as the detector measured
        them, in ``extra["ideal"]`` (M, 4) (`lines_record`).
    """
    if min_length is None:
        min_length = default_min_length(np.shape(image), bars and radial is None)  # a radial target's are edges
    circle_points = None
    if radial is not None:
        from pencilcal.toolkit.detect.radial import detect_radial_edges, orient_radial_edges

        kw = dict(edges=radial or None, valid_region=valid_region, min_length=min_length, gamma=gamma,
                  joint=radial_joint)
        if radial_pencil is not None:
            if camera is None:
                raise InputError("radial_pencil needs a camera: the ring is found from an orientation")
            segs, _ = orient_radial_edges(image, camera, radial_pencil, **kw)
        else:
            segs = detect_radial_edges(image, camera, **kw, outer=radial_outer, memo=radial_memo,
                                       predicted=radial_predicted)
        circle_points = segs.circle_points
    elif bars:
        kw = dict(camera=camera, min_length=min_length, width_px_range=bar_width, proposal_scale=proposal_scale,
                  valid_region=valid_region, polarity=bar_polarity)
        segs = detect_bars(image, detector, **kw) if bar_tracker is None else bar_tracker(image, detector, **kw)[0]
    elif segments:
        segs = detect_segments(image, detector, camera=camera, min_length=min_length, valid_region=valid_region)
    else:
        segs = Segments.empty()
    return LineFrame(
        image=name,
        segments=segs.segments,
        angle_sigma_deg=np.degrees(segs.angle_sigma),
        offset_sigma_px=segs.offset_sigma,
        width_px=segs.width_px if bars and radial is None else None,
        shafts=shaft_records(image, camera, valid_region, gamma, instrument_mask, tracker=shaft_tracker,
                             axis_prior=axis_prior, edge_model=edge_model, parts=parts) if shaft else None,
        circle_points=circle_points,
        extra=_radial_extra(segs, ideal and camera is not None),
    )


def _radial_extra(segs, ideal):
    """The lines record's extra keys of `segs`: ``ideal`` (M, 4) where asked for, and a star's
    edges' ``angle_sigma_error_deg`` (M,) where wider than their ``angle_sigma_deg``
    (`radial.RadialEdges`' angle_sigma_error: the orientation's covariance takes them) and
    ``vertex_sd_px``, the sd of the point a radial target's edges were located about
    (`radial.RadialEdges`' vertex_sd: the least the orientation reports its vertex's sd)."""
    out = {"ideal": segs.ideal} if ideal else {}
    err = getattr(segs, "angle_sigma_error", None)
    if err is not None and np.any(err > segs.angle_sigma):
        out["angle_sigma_error_deg"] = np.degrees(err)
    if getattr(segs, "vertex_sd", 0.0) > 0:
        out["vertex_sd_px"] = float(segs.vertex_sd)
    return out


def shaft_records(image, camera=None, valid_region=None, gamma=DEFAULT_GAMMA, instrument_mask=None, tracker=None,
                  parts=False, **options):
    """The shaft records of one image: `shaft.detector.detect_shafts`' (options: its
    keywords, `axis_prior` among them), or with `instrument_mask` (``{"mask": array,
    "labels": ..., "instances": ...}``) those of the mask's instruments
    (`shaft.from_mask.shafts_from_masks`), or those a tracker found (frames in order:
    `shaft.detector.ShaftTracker`, its own options); parts: without a mask, also the axes of
    the instrument regions with no shaft (`shaft.parts.detect_parts`). Imported only when
    asked for: a fan's orientation does not need the shaft modules."""
    if tracker is not None and instrument_mask is None:
        found = tracker(image, camera, valid_region=valid_region)
    elif instrument_mask is not None:
        from pencilcal.toolkit.detect.shaft.detector import with_limbs
        from pencilcal.toolkit.detect.shaft.from_mask import shafts_from_masks

        found = shafts_from_masks(image, instrument_mask["mask"], camera, labels=instrument_mask.get("labels"),
                                  instances=bool(instrument_mask.get("instances")), valid_region=valid_region,
                                  gamma=gamma)
        found = with_limbs(image, camera, found, options.get("edge_model", "step"), gamma)
    else:
        from pencilcal.toolkit.detect.shaft.detector import detect_shafts

        found = detect_shafts(image, camera, valid_region=valid_region, gamma=gamma, **options)
    if parts and instrument_mask is None:
        from pencilcal.toolkit.detect.shaft.parts import detect_parts

        found = list(found) + detect_parts(image, found, camera, valid_region=valid_region, gamma=gamma)
    return [s.to_dict() for s in found]


def lines_record(name, image, camera=None, detector="auto", bars=False, shaft=False, min_length=None, bar_width=None,
                 proposal_scale=None, valid_region=None, bar_polarity="dark", gamma=DEFAULT_GAMMA, bar_tracker=None,
                 instrument_mask=None, radial=None, axis_prior=None, shaft_tracker=None, edge_model="step",
                 radial_joint="crowded", segments=True, parts=False, ideal=False, radial_pencil=None):
    """One lines.json frame record from one decoded image: ``detect_frame_lines(...).to_dict()``
    (the same arguments); ideal: with a camera, also the segments in undistorted pixels as the
    detector measured them, ``ideal`` (M, 4), for `orient_segments`' ideal (a record used in
    memory: no lines file holds them)."""
    return detect_frame_lines(name, image, camera, detector, bars, shaft, min_length, bar_width,
                              proposal_scale, valid_region, bar_polarity, gamma, bar_tracker,
                              instrument_mask, radial, axis_prior, shaft_tracker, edge_model, radial_joint,
                              segments, parts, ideal=ideal, radial_pencil=radial_pencil).to_dict()

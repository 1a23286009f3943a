"""Instrument shafts: the two long edges of a cylinder, their axis and apparent width.

A rigid instrument's shaft is a cylinder. Its image is a band bounded by two long, straight
edges (in undistorted pixels) that converge slightly under perspective towards the far end;
the image of its axis lies between them. Two cues tell a shaft from the other bands of a
scene, and `detect_shafts` takes each where the frame carries it:

- *material*: on a real endoscope frame the instrument is grey, black, white or metal
  against coloured tissue. Where the frame's colour tells the materials apart (grey is an
  outlier of the dominant colour's distribution: `shaft.regions.material_map`), shafts are
  found as long bands of instrument-like region, with straight boundaries, differing in
  material from both sides and entering the view from its border (`shaft.material_cue`);
  their edges are then refitted at full resolution in a corridor around the region's
  boundaries (`shaft.silhouette`). Folds, rims and shadows of tissue keep the tissue's colour;
  white tissue and highlights are not straight-edged;
- *edges*: a grey frame (a calibration render of a metal shaft over paper or a table) has
  no material cue. There a shaft is a band between two long edges that looks the same all
  along its length, whatever lies behind it, seen from the border to its tip
  (`shaft.edge_cue`): unsigned edges (a grey shaft is darker than white paper and brighter
  than black print), bands judged station by station along their chord (`shaft.bands`).

Both end in two silhouette edges, fitted as straight lines in undistorted pixels with
a-posteriori variances, and the midline is the image of the plane bisecting the two planes
the edges back-project to (`shaft.axis`): exact for any pose, unlike the 2-D bisector. Its
angle and offset sigmas are propagated from the edge fits, plus a measured error floor
(`shaft.axis.EDGE_FLOOR_PX`). Without a camera a nominal pinhole (focal
length the image width) stands in for the camera matrix.

On a colour frame, a band of either cue is then judged by a learned map of instrument pixels
(`shaft.pixel_evidence`): a band of tissue with two long edges is not instrument-like inside;
and by its colour (`shaft.tissue_colour`): a band more coloured in the tissue's hue than the
tissue itself is tissue in shadow (a dark gap between two tissues), not an instrument.

Nothing is detected on the valid region's boundary (`valid_region`: an endoscope's field
stop, letterbox bars): samples keep inside it, and a band stops where it leaves it.

In a video, `track_shafts` (and `ShaftTracker`, frame after frame) looks for the previous
frame's shafts in corridors around them instead of over the whole frame
(`shaft.track`), then judges and measures them as the edge cue does: the same shafts,
several times faster; a full detection where the prior fails.

Conventions: pixels with (0, 0) the centre of the top-left pixel; midlines and edges in raw
pixels, widths and uncertainties in undistorted pixels.

Example
-------
>>> import numpy as np
>>> img = np.full((240, 320), 170, np.uint8)
>>> pts = np.array([[0, 80], [0, 160], [300, 135], [300, 105]], np.int32)   # converging
>>> import cv2; _ = cv2.fillConvexPoly(img, pts, 40)
>>> sh = detect_shafts(cv2.GaussianBlur(img, (0, 0), 1.0), min_length=100, gamma=1.0)  # blurred as stored
>>> len(sh), round(float(sh[0].width_px)), sh[0].cue                 # 55 px at x = 150, plus the fill's rims
(1, 56, 'edges')
"""
from __future__ import annotations

import inspect
from dataclasses import dataclass, replace
from types import SimpleNamespace

import numpy as np

from pencilcal.toolkit.detect.edges import DEFAULT_GAMMA
from pencilcal.toolkit.detect.image import GrayImage
from pencilcal.toolkit.detect.motion import EdgeMotion, match_pairs
from pencilcal.toolkit.detect.noise import noise_of
from pencilcal.toolkit.detect.shaft.axis import midline_from_edges
from pencilcal.toolkit.detect.shaft.border_band import border_shafts
from pencilcal.toolkit.detect.shaft.silhouette import EdgeLine
from pencilcal.toolkit.detect.shaft.edge_cue import bands_from_edges, drop_repeated, edge_cue, refit_edges, unsigned_lines
from pencilcal.toolkit.detect.shaft.material_cue import material_cue, robust_noise, select
from pencilcal.toolkit.detect.shaft.grey_material import GREY_TISSUE_COLOUR, kept
from pencilcal.toolkit.detect.shaft.pencil_search import pencil_search
from pencilcal.toolkit.detect.shaft.pixel_evidence import MIN_PIXEL_EVIDENCE
from pencilcal.toolkit.detect.shaft.pixel_evidence import pixel_evidence as shaft_pixel_evidence
from pencilcal.toolkit.detect.shaft.prior import as_priors, select_through
from pencilcal.toolkit.detect.shaft.regions import frame_regions, material_map
from pencilcal.toolkit.detect.shaft.tissue_colour import MAX_TISSUE_COLOUR, shaft_flank_colour, shaft_tissue_colour
from pencilcal.toolkit.detect.shaft.track import REACH, band_colours, corridor_edges, material_edges
from pencilcal.toolkit.detect.shaft.work import Validity, WorkFrame, axis_matrix
from pencilcal.toolkit.detect.working import check_camera_image, to_raw
from pencilcal.toolkit.errors import InputError

__all__ = ["Shaft", "ShaftOptions", "detect_shafts", "detect_through", "track_shafts", "ShaftTracker", "CUES",
           "REDETECT_FRAMES", "shaft_of_midline", "EDGE_MODELS", "with_limbs"]

#: What a shaft can be found by (`Shaft.cue`): the two cues, the angle search about a
#: fulcrum's image (`detect_shafts(..., axis_prior=...)`) and a shaft the border of the view
#: cuts lengthwise (`shaft.border_band`).
CUES = ("material", "edges", "prior", "border")
#: The material cue's widths when none are given, as fractions of the image's longer side
#: (1.5 % gave many 30 px tissue bands on the in-vivo frames; the closest shafts of the real
#: sets are a quarter of the side wide).
MATERIAL_WIDTHS = (0.02, 0.30)
#: The material cue's largest convergence of a shaft's edges [deg]: the shafts of the real
#: sets converge by under 5 deg; tissue bands between unrelated boundaries converge more.
MATERIAL_MAX_CONVERGENCE_DEG = 15.0
_WORK_PX = 480.0  # the work frame's longer side [px]


@dataclass(frozen=True, eq=False)
class Shaft:
    """One instrument shaft.

    Attributes
    ----------
    midline : (4,) [px]
        Image of the axis ``[x1, y1, x2, y2]`` in raw pixels (the image of the plane
        bisecting the silhouette planes), over the stretch where both edges are seen, from
        the wide (near) end to the narrow (far) end.
    width_px : float
        Apparent width across the midline at its centre [undistorted px].
    angle_sigma : float
        sd of the midline's angle [rad] (undistorted): propagated from the two edge fits,
        plus the floor (module docstring).
    offset_sigma : float
        sd of its perpendicular position at its centre [undistorted px], likewise.
    edges : (2, 4) [px]
        The two silhouette edges in raw pixels.
    score : float
        Evidence [px]: the length along which the band is seen as a shaft.
    ideal_midline : (4,) [px]
        The midline in undistorted pixels.
    convergence_deg : float
        Angle between the two edges [deg].
    polarity : str
        "dark" (shaft darker than its surroundings along most of its length) or "bright".
    cue : str
        What found it: "material", "edges", "prior" or "border" (`CUES`).
    cov : (2, 2)
        Covariance of the midline's (angle [rad], offset [px] at its centre), floor
        included: ``cov_stat + EDGE_FLOOR_PX**2 * cov_floor`` (`shaft.axis.Midline`).
    cov_stat, cov_floor : (2, 2)
        Its part from the edge fits, and the floor's part per px^2 of
        `shaft.axis.EDGE_FLOOR_PX` (what measuring the floor needs).
    ideal_edges : (2, 4) [px]
        The two edges in undistorted pixels (`edges` is their raw image).
    edge_cov : (2, 2, 2)
        Per edge, the covariance of its (angle [rad], offset [undistorted px]) about the
        centre of its ideal segment, floor included (`shaft.axis.edge_covariance`): what
        the shaft's 3-D axis is propagated from (`pencil.cylinder.shaft_axis`).
    kind : str
        "shaft": the axis of two silhouette edges; "part": the principal axis of a distal
        part alone, with its larger sigmas (`shaft.parts`, `shaft.from_mask`).
    edge_model : str
        How its two edges were located: "step" (the gradient peak) or "limb" (the lit
        cylinder's profile, `with_limbs`); the 3-D fulcrum gives each its own width error
        (`pencil.band_width.band_width_sd`).
    width_sd_px : float or None
        The sd [px] of the band's width error that its own edge fits show (the limb model:
        `shaft.limb.width_spread`, the scatter of its bins' limbs about each edge's line),
        added to its class's in the 3-D fulcrum's covariance; None where not measured (step
        edges).
    """

    midline: np.ndarray
    width_px: float
    angle_sigma: float
    offset_sigma: float
    edges: np.ndarray
    score: float
    ideal_midline: np.ndarray
    convergence_deg: float
    polarity: str
    cue: str = "edges"
    cov: np.ndarray | None = None
    cov_stat: np.ndarray | None = None
    cov_floor: np.ndarray | None = None
    ideal_edges: np.ndarray | None = None
    edge_cov: np.ndarray | None = None
    kind: str = "shaft"
    edge_model: str = "step"
    width_sd_px: float | None = None

    def to_dict(self) -> dict:
        """The shaft's record in a lines.json frame (docs/formats.md): midline, width_px,
        angle_sigma_deg, offset_sigma_px, edges, edge_cov (when known), convergence_deg,
        polarity, score, cue, kind, edge_model, width_sd_px (when measured)."""
        out = {
            "midline": [float(v) for v in self.midline],
            "width_px": float(self.width_px),
            "angle_sigma_deg": float(np.degrees(self.angle_sigma)),
            "offset_sigma_px": float(self.offset_sigma),
            "edges": [[float(v) for v in e] for e in self.edges],
            "convergence_deg": float(self.convergence_deg),
            "polarity": self.polarity,
            "score": float(self.score),
            "cue": self.cue,
            "kind": self.kind,
            "edge_model": self.edge_model,
        }
        if self.edge_cov is not None:
            out["edge_cov"] = np.asarray(self.edge_cov, float).tolist()
        if self.width_sd_px is not None:
            out["width_sd_px"] = float(self.width_sd_px)
        return out


@dataclass(frozen=True)
class ShaftOptions:
    """The settings of one `detect_shafts` call, defaults resolved for the image: the
    keywords of `detect_shafts` (lengths [px]), with wmin, wmax [px] the accepted widths and
    conv_max [rad] the largest convergence of the edge cue, and region_wmin, region_wmax,
    region_min_length [px], region_conv_max [rad] those of the material cue."""

    detector: str
    detector_params: dict | None
    min_length: float
    wmin: float
    wmax: float
    conv_max: float
    region_wmin: float
    region_wmax: float
    region_min_length: float
    region_conv_max: float
    max_shafts: int
    scale: float
    max_gap_px: float
    search_px: float
    sigma_px: float
    min_support: float
    max_background: float
    slope_correction: bool
    from_border: bool
    border_px: float
    min_score_ratio: float
    corridor_px: float
    gamma: float
    single_edge: bool = True
    edge_model: str = "step"
    edge_pairs: bool = True
    border_bands: bool = True

    @classmethod
    def resolve(cls, shape, *, min_length, width_px_range, max_convergence_deg, scale, max_gap_px, border_px, **kw):
        """The options for an image of `shape` (H, W): the defaults of `detect_shafts` filled
        in and checked (InputError)."""
        H, W = shape
        diag = float(np.hypot(H, W))
        if width_px_range is None:
            wmin, wmax = 6.0, 0.7 * min(H, W)
            rw = (MATERIAL_WIDTHS[0] * max(H, W), MATERIAL_WIDTHS[1] * max(H, W))
        else:
            wmin, wmax = map(float, width_px_range)
            rw = (wmin, wmax)
        if kw.get("edge_model", "step") not in EDGE_MODELS:
            raise InputError(f"edge_model must be one of {', '.join(EDGE_MODELS)}, got {kw['edge_model']!r}")
        if not (0.1 <= kw["gamma"] <= 5.0):
            raise InputError(f"gamma must be in [0.1, 5], got {kw['gamma']!r}")
        if not (0 < wmin < wmax):
            raise InputError(f"width_px_range must be (min, max) with 0 < min < max, got {width_px_range!r}")
        if scale is None:
            scale = min(1.0, 640.0 / max(H, W))
        if not (0 < scale <= 1):
            raise InputError(f"scale must be in (0, 1], got {scale!r}")
        conv = np.radians(max_convergence_deg)
        return cls(min_length=diag / 8.0 if min_length is None else float(min_length), wmin=wmin, wmax=wmax,
                   conv_max=conv, region_wmin=rw[0], region_wmax=rw[1],
                   region_min_length=3.0 * rw[0] if min_length is None else float(min_length),
                   region_conv_max=min(conv, np.radians(MATERIAL_MAX_CONVERGENCE_DEG)), scale=scale,
                   max_gap_px=diag / 10.0 if max_gap_px is None else max_gap_px,
                   border_px=0.03 * diag + 8.0 if border_px is None else border_px, **kw)


def shaft_of_midline(camera, m, score, polarity, cue, cls=None, **fields):
    """The `Shaft` of a `shaft.axis.Midline` (ideal px), or None where it leaves the lens
    model's reach; cls: a subclass of `Shaft` to build instead, with its own fields."""
    ideal = m.ends.reshape(-1)
    raw = to_raw(camera, ideal)[0]
    edges = to_raw(camera, m.edges)
    if not (np.all(np.isfinite(raw)) and np.all(np.isfinite(edges))):
        return None
    return (cls or Shaft)(midline=raw, width_px=float(m.width_px), angle_sigma=float(m.angle_sigma),
                          offset_sigma=float(m.offset_sigma), edges=edges, score=float(score), ideal_midline=ideal,
                          convergence_deg=float(m.convergence_deg), polarity=polarity, cue=cue, cov=m.cov,
                          cov_stat=m.cov_stat, cov_floor=m.cov_floor, ideal_edges=np.asarray(m.edges, float),
                          edge_cov=m.edge_cov, **fields)


#: The edge models of `detect_shafts`.
EDGE_MODELS = ("step", "limb")


def _edge_line(seg, other):
    """A `shaft.silhouette.EdgeLine` of the edge segment seg (4,) [ideal px], its normal
    away from the other edge's segment (4,)."""
    p0, p1 = np.asarray(seg[:2], float), np.asarray(seg[2:], float)
    L = float(np.hypot(*(p1 - p0)))
    u = (p1 - p0) / L
    n = np.array([-u[1], u[0]])
    if n @ (0.5 * (np.asarray(other[:2], float) + np.asarray(other[2:], float)) - p0) > 0:
        n = -n
    return EdgeLine(p0=p0, u=u, n=n, sm=0.5 * L, tm=0.0, b=0.0, var_t=0.0, var_b=0.0, s_lo=0.0, s_hi=L, count=0,
                    frac=1.0, rms=0.0)


def with_limbs(image, camera, shafts, edge_model="limb", gamma=DEFAULT_GAMMA, K=None):
    """The shafts with their edges located by the limb model (`shaft.limb.limb_edges`) when
    edge_model is "limb" (else as they are): each a new `Shaft` from the refitted edges'
    midline, its score, polarity and cue kept, with the width sd its fit shows
    (``width_sd_px``, `shaft.limb.width_spread`); one whose edges give no limb as it was.
    gamma: the frame's encoding gamma; K: the camera matrix of the ideal pixels (default
    `shaft.work.axis_matrix`'s)."""
    if edge_model not in EDGE_MODELS:
        raise InputError(f"edge_model must be one of {', '.join(EDGE_MODELS)}, got {edge_model!r}")
    if edge_model != "limb" or not shafts:
        return shafts
    from pencilcal.toolkit.detect.shaft.limb import limb_edges, width_spread

    K = axis_matrix(camera, np.asarray(image).shape[:2])[0] if K is None else K
    out = []
    for s in shafts:
        new = None
        if s.ideal_edges is not None:
            e = np.asarray(s.ideal_edges, float)
            got = limb_edges(image, camera, K, _edge_line(e[0], e[1]), _edge_line(e[1], e[0]), gamma)
            m = None if got is None else midline_from_edges(K, got[0], got[1])
            new = None if m is None else shaft_of_midline(camera, m, s.score, s.polarity, s.cue)
        # the measured fields replaced, the rest kept (a mask's shaft keeps its mask's)
        out.append(s if new is None else replace(s, edge_model="limb", width_sd_px=width_spread(*got),
                                                 **{k: getattr(new, k) for k in _MEASURED}))
    return out


#: The fields of a `Shaft` its edges give (`with_limbs` replaces them).
_MEASURED = ("midline", "width_px", "angle_sigma", "offset_sigma", "edges", "ideal_midline", "convergence_deg", "cov",
             "cov_stat", "cov_floor", "ideal_edges", "edge_cov")


def _by_material(image, camera, validity, o, K, work):
    """The shafts of the material cue, or None when the frame's colour tells no material
    apart (module docstring). work: the frame's `shaft.work.WorkFrame`, or None (made here)."""
    if np.asarray(image).ndim != 3:
        return None
    work = WorkFrame(image, camera, validity, _WORK_PX) if work is None else work
    mm = material_map(work)
    if not mm.informative:
        return None
    img = np.asarray(image)
    noise = max(robust_noise(img[..., 1]), 0.5)
    # the frame's region levels and their boundaries, once: the material cue's bands and the
    # border cue's seeds read the same ones (sides at least half the least length)
    regions = frame_regions(mm, work, 0.5 * (o.region_min_length * work.mean_scale))
    found = select(material_cue(img, camera, validity, work, mm, regions, o, K, noise), o.max_shafts)
    found = [shaft_of_midline(camera, f.midline, f.score, f.polarity, "material") for f in found]
    if o.border_bands:
        # a shaft the border cuts lengthwise has one edge in view: no band of two edges
        found = [s for s in found if s is not None]
        found += [Shaft(**f) for f in border_shafts(img, camera, validity, work, mm, regions, o, found)]
    return found


def _edge_shafts(found, camera, o, K):
    """The `Shaft` of each (edges, score, polarity) the edge cue found (`shaft.edge_cue`)."""
    out = []
    for edges, score, polarity in found:
        m = midline_from_edges(K, edges[0], edges[1])
        # both edges seen together along half the least length, as the band was
        if m is not None and np.hypot(*(m.ends[1] - m.ends[0])) >= 0.5 * o.min_length:
            out.append(shaft_of_midline(camera, m, score, polarity, "edges"))
    return out


def _by_edges(image, camera, valid_region, o, K):
    """The shafts of the edge cue (module docstring)."""
    img = GrayImage(image, valid_region)
    return _edge_shafts(edge_cue(img, camera, o, noise_of(img)), camera, o, K)


def detect_shafts(image, camera=None, *, valid_region=None, detector="lsd", min_length=None, width_px_range=None,
                  max_convergence_deg=30.0, max_shafts=4, scale=None, max_gap_px=None, search_px=3.0,
                  sigma_px=1.5, min_support=0.3, max_background=0.1, slope_correction=True, from_border=True,
                  border_px=None, min_score_ratio=0.25, corridor_px=4.0, detector_params=None, gamma=DEFAULT_GAMMA,
                  axis_prior=None, single_edge=True, edge_pairs=True, border_bands=True, edge_model="step",
                  pixel_evidence=MIN_PIXEL_EVIDENCE, tissue_colour=MAX_TISSUE_COLOUR):
    """Instrument shafts in one image: midline (the axis image), width, angle uncertainty.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        Grey or BGR frame. Only a colour frame can have the material cue.
    camera : Camera, optional
        Lens model. Edges are fitted straight in undistorted pixels and the midline is the
        exact image of the axis; its image size must match. Without it a nominal pinhole
        (focal length the image width) gives the midline's plane.
    valid_region : object, optional
        Where the scene is (`region.ValidRegion`, or anything with
        ``distance_to_boundary(points (..., 2)) -> (...)`` [px], positive inside, and for
        the edge cue ``outline(shape)`` and ``covers_image(shape)``): nothing is detected on
        its boundary. Default: the whole image.
    detector : {"lsd", "fld", "edlines"}
        The edge cue's proposal detector (run on the reduced image).
    min_length : float, optional
        Shortest shaft [px]: the edge cue's least edge (default 1/8 of the image diagonal;
        the band must be seen as a shaft along at least half of it) and the material cue's
        least run (default three least widths).
    width_px_range : (2,) [px], optional
        Accepted apparent widths. Default: the edge cue 6 px to 0.7 of the image's smaller
        side, the material cue `MATERIAL_WIDTHS` of its longer side.
    max_convergence_deg : float
        Largest angle between the two edges (the material cue's at most
        `MATERIAL_MAX_CONVERGENCE_DEG`).
    max_shafts : int
        At most this many shafts, best score first.
    min_score_ratio : float
        The edge cue drops shafts whose score is below this fraction of the best one's.
    scale : float, optional
        The edge cue's reduction of the image for the proposals; default so that its larger
        side is ~640 px.
    max_gap_px : float, optional
        The edge cue's longest stretch without edge evidence inside one edge; default 1/10
        of the diagonal.
    search_px, sigma_px : float
        The edge cue's edge search half-width and Gaussian-derivative sd [px].
    min_support : float
        The edge cue's two edges must overlap along at least this fraction of the shorter
        one (occlusion allowed), and along at least half of `min_length`.
    max_background : float
        The edge cue's largest fraction of a band's stations whose inside contradicts the
        band's level, and of its cross-section that may look like the background.
    from_border : bool
        The edge cue keeps only bands that run to the border of the view (within
        `border_px`, default 3 % of the diagonal + 8 px): an instrument enters the view from
        outside, whereas the long strips of a scene end inside it. False also finds a shaft
        whose near part is hidden.
    slope_correction : bool
        The edge cue corrects each edge point for the grey-level slopes beside it (textured
        tissue), for shafts wider than twice the profile's reach (`shaft.edge_cue`).
    corridor_px : float
        Half-width of the material cue's full-resolution edge search around a region's
        boundary [px] (at least 1.5 work px, that boundary's own resolution).
    detector_params : dict, optional
        Passed to the edge cue's detector.
    gamma : float
        The frame's encoding gamma: 8-bit video and JPEG store about (linear light)^(1/2.2)
        (the default); 1 for linear frames (`pencilcal simulate --gamma 1`). The edge cue
        locates its edges on the sampled profiles linearised with it (`edges.linearised`):
        a blurred edge's gradient peak leans towards its dark side in encoded levels, so
        the band would come out narrow and the shaft too far. The material cue (real
        video) keeps the levels as they are (`shaft.material_cue._MATERIAL_GAMMA`).
    axis_prior : AxisPrior or list of AxisPrior, optional
        The image of each instrument's fulcrum (`shaft.prior.AxisPrior`: a homogeneous
        point in ideal pixels with its covariance, e.g. `AxisPrior.from_ray` of a
        fulcrum.json's ``ray`` and ``ray_cov``). Its axis passes through it: besides the
        cues, the shaft is searched by its angle about the point (`shaft.pencil_search`,
        cue "prior"), and of all the shafts found at most one per prior is returned, the
        best-scored whose midline passes through it (`shaft.prior.select_through`);
        max_shafts and min_score_ratio then do not apply.
    edge_model : {"step", "limb"}
        "limb": each shaft's two edges, once found, are located again by the profile model
        of a cylinder lit from the camera (`shaft.limb`: it darkens towards its silhouette,
        so the step edge lies inside it and the band comes out narrow); a shaft whose edges
        give no limb keeps its step edges.
    single_edge : bool
        The material cue also proposes bands from a single straight boundary, to the far
        edge a gradient model finds across it (`shaft.partner`: a white or metal shaft the
        colour does not tell from tissue, beside a dark region; and, from a boundary at the
        border of the view, into its own region: a close shaft converging under
        perspective, `shaft.material_cue`): more instruments found on
        in-vivo frames (docs/method.md), at about 8 ms more CPU per 1080p frame (39 ms
        against 31 on the hysterectomy frames, docs/performance.md).
        False: the region bands alone.
    edge_pairs : bool
        The material cue also proposes bands between two long straight grey-level edges of
        the work frame whose inside is one material, unlike both outsides and more
        instrument-like than they are (`shaft.edge_pairs`: a dark grasper in the dark
        periphery, a grey shaft the region maps do not tell from the tissue), or whose rims
        are one material unlike the outsides, whatever lies inside (an instrument's outline:
        a clip applier's limbs and the slot between them); the proposals
        cost about 7-8 ms per 1080p frame (docs/method.md). False: not proposed.
    border_bands : bool
        On a colour frame, also the axis of a shaft the border of the view cuts lengthwise,
        one silhouette edge in view and the other beyond the border: a region of one material
        from a straight boundary entering from the border out to the border, read as a mask
        (`shaft.border_band`, cue "border", kind "part" with a part's sigmas where only one
        straight silhouette stretch is seen). False: not looked for.
    pixel_evidence : float or None
        On a colour frame, a shaft of the cues is kept only where the learned instrument map
        inside its band reaches this (`shaft.pixel_evidence.MIN_PIXEL_EVIDENCE`, 0.1: a
        tissue band with two long edges is not instrument-like inside), or, with
        tissue_colour, where it is darker than its sides and its tissue colour at most
        `shaft.grey_material.GREY_TISSUE_COLOUR`, or at most
        `shaft.grey_material.GREY_FLANK_RATIO` of the tissue's right beside it (a grey
        material the map does not know: a shaft in haze, a black one on shadowed tissue);
        None: not judged.
    tissue_colour : float or None
        On a colour frame, a shaft of the cues is kept only where its inside's colour along
        the tissue's hue stays under this fraction of the frame's median
        (`shaft.tissue_colour.MAX_TISSUE_COLOUR`: an instrument is never more coloured than
        the tissue it mirrors; a dark gap between tissues keeps, and deepens, their colour);
        None: not judged.

    Returns
    -------
    list of Shaft
        Best score first (with axis_prior: one per prior that has one, in the priors'
        order); empty when none is found.

    Example
    -------
    See the module docstring.
    """
    image, o, validity, K = _prepared(image, camera, valid_region, dict(
        detector=detector, detector_params=detector_params, min_length=min_length, width_px_range=width_px_range,
        max_convergence_deg=max_convergence_deg, max_shafts=max_shafts, scale=scale, max_gap_px=max_gap_px,
        search_px=search_px, sigma_px=sigma_px, min_support=min_support, max_background=max_background,
        slope_correction=slope_correction, from_border=from_border, border_px=border_px,
        min_score_ratio=min_score_ratio, corridor_px=corridor_px, gamma=gamma, single_edge=bool(single_edge),
        edge_pairs=bool(edge_pairs), border_bands=bool(border_bands), edge_model=edge_model))
    priors = as_priors(axis_prior)
    work = WorkFrame(image, camera, validity, _WORK_PX) if priors or np.ndim(image) == 3 else None
    found = _by_material(image, camera, validity, o, K, work)
    colour = found is not None
    if found is None:
        found = _by_edges(image, camera, valid_region, o, K)
    found = [s for s in found if s is not None]
    if not priors:
        found = judged(image, camera, found, validity, work, pixel_evidence, tissue_colour)
        return with_limbs(image, camera, found, o.edge_model, o.gamma, K)
    img = np.asarray(image)
    noise = max(robust_noise(img[..., 1] if img.ndim == 3 else img), 0.5)
    # the material cue's edges keep a colour frame's levels (`shaft.material_cue`), the
    # edge cue's are located on linear light: the search's edges follow the frame's cue
    gamma_edges = 1.0 if colour else o.gamma
    for p in priors:
        for m, score, polarity in pencil_search(image, camera, validity, work, p, o, K, noise, gamma_edges):
            found.append(shaft_of_midline(camera, m, score, polarity, "prior"))
    found = judged(image, camera, [s for s in found if s is not None], validity, work, pixel_evidence,
                   tissue_colour)
    return with_limbs(image, camera, select_through(found, priors), o.edge_model, o.gamma, K)


def judged(image, camera, shafts, validity, work=None, pixel_evidence=MIN_PIXEL_EVIDENCE,
           tissue_colour=MAX_TISSUE_COLOUR, grey=GREY_TISSUE_COLOUR):
    """The shafts (list of `Shaft`) of a colour frame that are instrument-like: those whose
    pixel evidence (`shaft.pixel_evidence`) reaches pixel_evidence, or whose tissue colour is
    at most grey, or at most `shaft.grey_material.GREY_FLANK_RATIO` of its flanks', where it
    is darker than its sides (a band greyer than the tissue, `shaft.grey_material`; None: the
    evidence alone), and whose tissue colour (`shaft.tissue_colour`) stays within tissue_colour
    (either None: not judged); a grey
    frame's all. Every shaft the detector returns passes here, whichever path found it (the
    cues, the fulcrum prior's angle search, tracking): each is judged on its own, so the
    order and the others kept do not change a verdict.

    validity: the image's `work.Validity`; work: its `work.WorkFrame` (whose pass over the
    full frame the evidence shares), or None for one of its own.
    """
    if np.ndim(image) != 3 or not shafts:
        return list(shafts)
    ev = np.ones(len(shafts))
    if pixel_evidence is not None:
        ev = np.asarray(shaft_pixel_evidence(image, shafts, camera, validity=validity,
                                             reductions=None if work is None else work.reductions), float)
    tc = np.zeros(len(shafts))
    if tissue_colour is not None:
        # the colour of those the evidence keeps, and of the dark others where it may keep
        # them (a band greyer than the tissue: `shaft.grey_material`); the rest not measured
        k = np.arange(len(shafts)) if pixel_evidence is None else np.flatnonzero(
            (ev >= pixel_evidence) | ((grey is not None) & np.array([s.polarity == "dark" for s in shafts])))
        tc = np.full(len(shafts), np.nan)
        if k.size:
            tc[k] = shaft_tissue_colour(image, [shafts[i] for i in k], validity=validity)
    dark = np.array([s.polarity == "dark" for s in shafts])
    fl = None
    if pixel_evidence is not None and tissue_colour is not None and grey is not None:
        # the flanks of the dark bands only the tissue beside them may keep (`shaft.grey_material`)
        with np.errstate(invalid="ignore"):
            k = np.flatnonzero(dark & (ev < pixel_evidence) & (tc > grey) & (tc <= tissue_colour))
        fl = np.full(len(shafts), np.nan)
        if k.size:
            fl[k] = shaft_flank_colour(image, [shafts[i] for i in k], validity=validity)
    keep = kept(ev, tc, pixel_evidence, tissue_colour, np.nan if grey is None else grey, dark, fl)
    return [s for s, k in zip(shafts, keep) if k]


def detect_through(image, camera, alternatives, **options):
    """The shafts (`detect_shafts`) through the first of the `alternatives` (a list of
    `shaft.prior.AxisPrior`, or of lists of them) that gives any: a frame whose pivot epoch
    is uncertain (at a change of the fulcrum) is searched with each candidate epoch's
    prior in turn. options: the keywords of `detect_shafts`."""
    found = []
    for p in alternatives:
        found = detect_shafts(image, camera, axis_prior=p, **options)
        if found:
            break
    return found


def _prepared(image, camera, valid_region, options):
    """(image, `ShaftOptions`, `Validity`, K) of a `detect_shafts` call: the image checked
    (InputError) and reduced to grey or BGR, the options resolved (`options`: the keywords
    of `detect_shafts`)."""
    arr = np.asarray(image)
    if arr.ndim not in (2, 3) or arr.size == 0 or (arr.ndim == 3 and arr.shape[2] not in (1, 3, 4)):
        raise InputError(f"image: expected (H, W) or (H, W, 3), got shape {arr.shape}")
    if arr.ndim == 3 and arr.shape[2] != 3:
        image = arr = arr[..., 0] if arr.shape[2] == 1 else arr[..., :3]
    shape = arr.shape[:2]
    check_camera_image(camera, SimpleNamespace(shape=shape))
    o = ShaftOptions.resolve(shape, **{**_DEFAULTS, **options})
    return image, o, Validity(valid_region, shape), axis_matrix(camera, shape)[0]


#: The keywords of `detect_shafts` and their defaults (those `track_shafts` passes on).
_DEFAULTS = {k: p.default for k, p in inspect.signature(detect_shafts).parameters.items()
             if p.kind is p.KEYWORD_ONLY and k not in ("valid_region", "axis_prior", "pixel_evidence",
                                                                  "tissue_colour")}


def track_shafts(image, camera, previous, *, valid_region=None, prior=None, reach_px=None, widths=None, colours=None,
                 detect=True, **options):
    """This frame's shafts with the previous frame's as a prior: (shafts, tracked), tracked
    False where a full `detect_shafts` was run.

    Each instrument of the previous frame (its shafts, one per instrument: `_instruments`)
    is looked for around where it was, without the cues' proposals over the whole frame:
    one the edge cue found, in a corridor around it (`shaft.track.corridor_edges`), the
    bands found there judged and measured as the edge cue judges and measures its own
    (`shaft.edge_cue.bands_from_edges`); one the material cue found, on a colour frame, by
    its colour, its silhouette edges fitted as that cue fits them
    (`shaft.track.material_edges`). A shaft found again is the one a full detection finds,
    measured and judged alike (`judged`). The prior is checked, never trusted: the frame gets a full detection
    when there is no prior or when fewer instruments are found than the prior had. With an
    ``axis_prior`` in the options every frame gets a full detection.

    previous: the previous frame's list of `Shaft` (or None); prior: (K, 2, 4) [undistorted
    px], where a motion model predicts the K instruments' edges (`ShaftTracker`), and
    reach_px (K,) [px] how far each may lie from that; default the previous frame's edges
    (`_instruments(previous)`) and `shaft.track.REACH` of the image diagonal; widths (K,)
    [px] the instruments' widths a shaft found by its colour is checked against (default the
    previous frame's; `ShaftTracker` gives the last full detection's, so that no error
    builds up from frame to frame); colours (K,) the (inside, outside) colours of the
    instruments' bands (`shaft.track.band_colours`) a shaft found by its colour must keep
    (default none); detect: False returns ([], False) instead of the full detection.
    options: the keywords of `detect_shafts`.
    """
    if not previous or options.get("axis_prior") is not None or any(s.ideal_edges is None for s in previous):
        return detect_shafts(image, camera, valid_region=valid_region, **options), False
    image, o, validity, K = _prepared(image, camera, valid_region, {k: v for k, v in options.items() if k not in (
        "axis_prior", "pixel_evidence", "tissue_colour")})
    ones = _instruments(previous)
    if prior is None:
        prior = [s.ideal_edges for s in ones]
        reach_px = np.full(len(prior), REACH * float(np.hypot(*validity.shape)))
    widths = [s.width_px for s in ones] if widths is None else widths
    colour = np.asarray(image).ndim == 3
    by_colour = [k for k, s in enumerate(ones) if s.cue == "material" and colour]
    colours = [None] * len(ones) if colours is None else colours
    found = _by_colour(image, camera, validity, o, K, [ones[k] for k in by_colour], [prior[k] for k in by_colour],
                       [reach_px[k] for k in by_colour], [widths[k] for k in by_colour],
                       [colours[k] for k in by_colour])
    rest = [k for k in range(len(ones)) if k not in by_colour]
    img = GrayImage(image, valid_region) if rest else None
    sig_n = noise_of(img) if rest else None
    lines = [corridor_edges(img, camera, prior[k], o, sig_n, float(reach_px[k])) for k in rest]
    if rest and all(e is not None for e in lines):
        P, ok = refit_edges(img, camera, np.concatenate(lines), o, sig_n)
        if np.all(ok):
            E = unsigned_lines(P)
            E = E[drop_repeated(E, np.hypot(E[:, 2] - E[:, 0], E[:, 3] - E[:, 1]))]
            found += [s for s in _edge_shafts(bands_from_edges(img, camera, E, o, sig_n), camera, o, K)
                      if s is not None]
    # a shaft found again is judged as a detected one: one that lost its instrument-like
    # pixels or took the tissue's colour (the corridor slid onto tissue) is not the instrument
    found = judged(image, camera, found, validity, None, options.get("pixel_evidence", MIN_PIXEL_EVIDENCE),
                   options.get("tissue_colour", MAX_TISSUE_COLOUR))
    if len(_instruments(found)) < len(prior):
        return (detect_shafts(image, camera, valid_region=valid_region, **options) if detect else []), False
    return with_limbs(image, camera, found, o.edge_model, o.gamma, K), True


def _by_colour(image, camera, validity, o, K, shafts, prior, reach, widths, colours):
    """The material cue's shafts found again by their colour around their predicted edges
    (`shaft.track.material_edges`), each checked against its width in widths and its band's
    colours in colours; the list holds those that held."""
    if not shafts:
        return []
    img = np.ascontiguousarray(image, dtype=np.float32)
    noise = max(robust_noise(np.asarray(image)[..., 1]), 0.5)
    out = []
    for s, e, r, w, c in zip(shafts, prior, reach, widths, colours):
        fits = material_edges(img, camera, validity, noise, np.asarray(e, float), r, o.corridor_px, w, c)
        m = None if fits is None else midline_from_edges(K, fits[0], fits[1])
        if m is not None and m.convergence_deg <= np.degrees(o.region_conv_max):
            seen = float(np.hypot(*(m.ends[1] - m.ends[0])))
            out.append(shaft_of_midline(camera, m, seen * min(f.frac for f in fits), s.polarity, "material"))
    return [s for s in out if s is not None]


def _instruments(shafts, max_deg=2.0, max_offset=0.5):
    """One shaft per instrument, best score first: a shaft along another's band (within
    max_deg of its direction, each one's centre within max_offset of the other's width of
    its line) is that instrument again (the edge cue may find one band from two pairs of
    pieces of its edges)."""
    out = []
    for s in sorted(shafts, key=lambda s: -s.score):
        m = np.asarray(s.ideal_midline, float).reshape(2, 2)
        if not any(_same_band(m, s.width_px, np.asarray(q.ideal_midline, float).reshape(2, 2), q.width_px,
                              max_deg, max_offset) for q in out):
            out.append(s)
    return out


def _same_band(m1, w1, m2, w2, max_deg, max_offset):
    """Whether two midlines (2, 2) of widths w1, w2 [px] run along one band."""
    d1, d2 = m1[1] - m1[0], m2[1] - m2[0]
    d1, d2 = d1 / np.linalg.norm(d1), d2 / np.linalg.norm(d2)
    if abs(float(d1 @ d2)) < np.cos(np.radians(max_deg)):
        return False

    def off(c, m, d):
        return abs(float(d[0] * (c[1] - m[0, 1]) - d[1] * (c[0] - m[0, 0])))

    c1, c2 = m1.mean(0), m2.mean(0)
    return off(c1, m2, d2) <= max_offset * w2 and off(c2, m1, d1) <= max_offset * w1


#: A `ShaftTracker` runs a full detection at least every this many frames (a second at 30
#: fps): an instrument that enters the view is found by then.
REDETECT_FRAMES = 30


class ShaftTracker:
    """Shafts frame after frame (`track_shafts`): each frame's prior is the previous
    frame's instruments where a constant-velocity model of their edges predicts them
    (`detect.motion.EdgeMotion`, unsigned edges in undistorted px), each looked for within
    its predicted uncertainty (before its velocity is known, and where that fails for a
    shaft of the edge cue, within `shaft.track.REACH` of the image diagonal around the
    previous frame's, before a full detection); every `redetect_frames`-th frame gets a full detection whatever the prior
    (a new instrument, one the corridors lost). Call it on the frames in order;
    ``tracked`` counts the frames tracked.

    options: the keywords of `detect_shafts` (valid_region aside, given per frame).
    """

    def __init__(self, redetect_frames=REDETECT_FRAMES, **options):
        self.redetect_frames = int(redetect_frames)
        self.options = options
        self.previous = None
        self.since_full = 0
        self.tracked = 0
        self.motion = None
        self.widths = None  # the instruments' widths at the last full detection
        self.colours = None  # and their bands' colours (inside, outside), on colour frames

    def __call__(self, image, camera=None, valid_region=None):
        """This frame's shafts (list of `Shaft`)."""
        reach = REACH * float(np.hypot(*np.shape(image)[:2]))
        if self.motion is None or self.motion.prior_px != reach:  # the first frame, or another size
            self.motion, self.previous = EdgeMotion(polar=False, prior_px=reach, max_search_px=reach,
                                                    windows=False, along=False), None
        prior = self.previous if self.since_full + 1 < self.redetect_frames else None
        pred, search = self.motion.search() if prior and len(self.motion) == len(_instruments(prior)) else (None, None)
        ref = pred is not None
        kw = dict(valid_region=valid_region, widths=self.widths if ref else None,
                  colours=self.colours if ref else None, **self.options)
        found, tracked = track_shafts(image, camera, prior, prior=pred, reach_px=search, detect=not ref, **kw)
        if ref and not tracked:
            # lost where predicted: in corridors around where it was, as far as it may move
            # (the edge cue's band test judges what it finds there; a colour fit that far out
            # may take the tissue's edges), then in full
            wide = all(s.cue == "edges" for s in prior)
            found, tracked = track_shafts(image, camera, prior if wide else None, **kw)
        ones = [s for s in _instruments(found) if s.ideal_edges is not None]
        if tracked and ref and ones:  # each instrument keeps its full detection's width and colours
            m = match_pairs(pred, np.stack([s.ideal_edges for s in ones]), np.inf, max_deg=90.0)
            self.widths = [self.widths[k] if k >= 0 else s.width_px for k, s in zip(m, ones)]
            self.colours = [self.colours[k] if k >= 0 else None for k in m]
        elif not tracked:
            self.widths = [s.width_px for s in ones]
            colour = np.ndim(image) == 3
            self.colours = [band_colours(image, camera, s.ideal_edges) if colour else None for s in ones]
        if ones:
            # a tracked shaft is measured over part of its length: the next search covers
            # the whole of the last full detection's
            self.motion.update(np.stack([s.ideal_edges for s in ones]), keep_extent=tracked)
        else:
            self.motion.missed()
        self.previous = found
        self.since_full = self.since_full + 1 if tracked else 0
        self.tracked += bool(tracked)
        return found

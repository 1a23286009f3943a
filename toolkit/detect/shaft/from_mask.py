"""Instrument axes from segmentation masks, refined on the image's edges: masks in.

Every surgical-vision lab has a segmentation network; its masks say *where* each instrument
is, to a pixel or two, but not the geometry. `shafts_from_masks` adds it: for each
instrument of a mask (`mask.instruments_in_mask`)

1. the mask's own outline gives the shaft's two silhouette stretches (`mask.mask_axis`: the
   outermost pair of straight edges of its outer contour, whatever lies inside it: streaks,
   slots, a wrist; the border of the image and of the valid region is no silhouette);
2. each is found in the image within a corridor of +-`MASK_CORRIDOR_PX` (at most
   `CORRIDOR_WIDTH_FRAC` of the width) around the mask's edge by the material cue's colour
   edge fit (`shaft.silhouette.fit_edges`: colour profiles across the edge projected on its
   own colour difference, robust to tissue whose brightness matches the instrument's), then
   refined on the grey levels within `REFINE_SEARCH_PX` of that fit (`edges.edge_profiles`:
   unsigned, Gaussian-derivative sd `REFINE_SIGMA_PX`, corrected for the slopes beside the
   edge, which a shaded cylinder's falling brightness towards its rim puts there, located
   on linear light with the frame's gamma; `shaft.axis.class_edge`: one offset per
   polarity, as an edge crosses print or tissue of either brightness), with a-posteriori
   variances;
3. the axis is the plane bisector of the two edges, with the covariance propagated from
   their fits plus the detector's floor (`shaft.axis.midline_from_edges`).

The mask restricts the search and judges the result: the image's edge is taken where it
spans `MIN_FOUND_FRACTION` of the mask's stretch, is seen at `MIN_SEEN_FRACTION` of its
stations, lies within `MAX_AGREEMENT_PX` of the mask's edge all along their common stretch
and turns from it by `MAX_AGREEMENT_DEG` at most. Elsewhere (no edge in the corridor: low
contrast, a mask off by more; or an edge further off: a shadow, a tissue edge, an inner
streak, or the mask drawn wide) mask and image disagree, and it is said (`MaskShaft.
edge_from`, `mask_offset_px`, `mask_turn_deg`, `disagreement`): the mask's own edge stands
in, with the mask's error `MASK_EDGE_SIGMA_PX` at either end in place of a fit's. A mask without two
straight silhouette stretches (the distal part alone: jaws, a hook, a clip applier with the
shaft out of view) gives its principal axis, kind ``"part"``, with the larger sigmas: its
own half-angle atan(width / length) and `PART_OFFSET_SIGMA_FRAC` of its width; it has no
edges (no 3-D axis can be had from it).

How the constants were chosen and what they give: docs/method.md, masks in (renders with
exact truth; the masked real sources).

Pixels: midlines and edges in raw pixels, widths and uncertainties in undistorted pixels
(as `shaft.detector.Shaft`); (0, 0) the centre of the top-left pixel.

Example
-------
>>> import numpy as np, cv2
>>> img = np.full((240, 320, 3), (60, 90, 170), np.uint8); img[80:120, :250] = 40   # a dark shaft
>>> img = cv2.GaussianBlur(img, (0, 0), 1.2)                      # its edges at y = 79.5 and 119.5
>>> mask = np.zeros((240, 320), np.uint8); mask[82:122, :252] = 1                   # 2 px off
>>> sh = shafts_from_masks(img, mask, gamma=1.0)
>>> len(sh), sh[0].cue, sh[0].kind, sh[0].edge_from, sh[0].mask_agrees
(1, 'mask', 'shaft', ('image', 'image'), True)
>>> [round(v, 1) for v in sh[0].mask_offset_px], round(sh[0].width_px, 1)        # found where they are
([2.0, 2.1], 39.9)
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pencilcal.toolkit.detect.edges import (DEFAULT_GAMMA, MIN_STATIONS, derivative_kernel, edge_profiles,
                                            station_counts, stations)
from pencilcal.toolkit.detect.image import GrayImage
from pencilcal.toolkit.detect.noise import estimate_noise
from pencilcal.toolkit.detect.shaft.axis import class_edge, midline_from_edges
from pencilcal.toolkit.detect.shaft.detector import Shaft, shaft_of_midline
from pencilcal.toolkit.detect.shaft.mask import instruments_in_mask, mask_axis
from pencilcal.toolkit.detect.shaft.regions import Z_999
from pencilcal.toolkit.detect.shaft.silhouette import EdgeLine, fit_edges
from pencilcal.toolkit.detect.shaft.work import Validity, axis_matrix
from pencilcal.toolkit.detect.working import check_camera_image, to_working
from pencilcal.toolkit.errors import InputError

__all__ = ["MaskShaft", "shafts_from_masks", "MASK_CORRIDOR_PX", "CORRIDOR_WIDTH_FRAC", "MASK_EDGE_SIGMA_PX",
           "MAX_AGREEMENT_PX", "MAX_AGREEMENT_DEG", "MIN_FOUND_FRACTION", "MIN_SEEN_FRACTION", "REFINE_SIGMA_PX", "REFINE_SEARCH_PX", "PART_OFFSET_SIGMA_FRAC"]

#: Half-width of the search for the image's edge around the mask's [px].
MASK_CORRIDOR_PX = 5.0
#: ... at most this fraction of the mask's width: the colour strips beyond the corridor on
#: the inner side (`shaft.silhouette`: 7.5 px further) must stay inside a thin shaft.
CORRIDOR_WIDTH_FRAC = 0.2
#: The image's edge is taken where it lies within this of the mask's all along their common
#: stretch [px] and turns from it by at most `MAX_AGREEMENT_DEG`; further, it is a
#: disagreement and the mask's edge is used (the tolerances of the masked sources' score).
MAX_AGREEMENT_PX = 3.0
MAX_AGREEMENT_DEG = 1.5
#: The image shows an edge when its fit spans at least this fraction of the mask's stretch ...
MIN_FOUND_FRACTION = 0.5
#: ... and is seen at this fraction of the stations that could see it at least (texture or
#: print beside a shaft, where a mask is drawn wide of it, gives 0.14-0.19; the silhouettes of
#: the sources the constants were chosen on 0.42-0.93).
MIN_SEEN_FRACTION = 0.3
#: The error of a mask's edge at either end of its stretch [px] (sd, independent), used where
#: the mask's edge stands for the image's.
MASK_EDGE_SIGMA_PX = 2.0
#: The refinement on the grey levels: the Gaussian-derivative sd [px] and the search
#: half-width around the colour fit [px].
REFINE_SIGMA_PX = 1.0
REFINE_SEARCH_PX = 1.5
#: sd of a distal part's offset across its principal axis, as a fraction of its width; its
#: angle's sd is the part's own half-angle, atan(width / length).
PART_OFFSET_SIGMA_FRAC = 0.5
_STATION_PX = 2.0  # spacing of the refinement's stations [px]
_MAX_STATIONS = 200
_REL_STRENGTH = 0.35  # a station's edge at least this fraction of the edge's median strength


@dataclass(frozen=True, eq=False)
class MaskShaft(Shaft):
    """A `shaft.detector.Shaft` from an instrument mask (`shafts_from_masks`), cue "mask".

    Attributes (beyond `Shaft`'s)
    -----------------------------
    kind : str
        "shaft": the axis of two silhouette edges; "part": the principal axis of a distal
        part alone (no edges: `edges` is empty, `edge_cov` None).
    instrument : int
        The instrument's index in the frame's mask (`mask.instruments_in_mask`: largest
        first).
    edge_from : (2,) str
        Per edge: "image" (refitted on the image) or "mask" (the image shows no edge there,
        or one further than `MAX_AGREEMENT_PX` from the mask's: the mask's own edge, with
        `MASK_EDGE_SIGMA_PX`).
    mask_offset_px : (2,) float or None
        Per edge: the largest distance [undistorted px] between the image's edge and the
        mask's over their common stretch; None where the image shows no edge.
    mask_turn_deg : (2,) float or None
        Per edge: the angle between the image's edge and the mask's [deg]; None likewise.
    """

    kind: str = "shaft"
    instrument: int = 0
    edge_from: tuple = ()
    mask_offset_px: tuple = ()
    mask_turn_deg: tuple = ()

    @property
    def mask_agrees(self) -> bool | None:
        """Whether the image shows both of the mask's edges, within `MAX_AGREEMENT_PX` (None
        for a part, which has no edges)."""
        return None if self.kind != "shaft" else all(f == "image" for f in self.edge_from)

    def disagreement(self) -> str | None:
        """One line saying where mask and image disagree (or that this is a part alone), or
        None."""
        if self.kind == "part":
            return (f"instrument {self.instrument}: no straight silhouette edges in its mask (a distal part "
                    f"alone?): its principal axis, +-{np.degrees(self.angle_sigma):.0f} deg")
        out = [f"edge {k + 1} not seen in the image" if o is None else
               f"the image's edge {k + 1} lies {o:.1f} px from the mask's" if o > MAX_AGREEMENT_PX else
               f"the image's edge {k + 1} turns {a:.1f} deg from the mask's"
               for k, (f, o, a) in enumerate(zip(self.edge_from, self.mask_offset_px, self.mask_turn_deg))
               if f == "mask"]
        return f"instrument {self.instrument}: {'; '.join(out)} (the mask's edge used)" if out else None

    def to_dict(self) -> dict:
        """`Shaft.to_dict`'s record with kind, instrument, edge_from, mask_offset_px,
        mask_turn_deg, mask_agrees and, where they disagree, mask_warning (docs/formats.md);
        a part's without edges."""
        out = super().to_dict()
        out.update(kind=self.kind, instrument=int(self.instrument))
        if self.kind == "part":
            out.pop("edges", None)
        else:
            out.update(edge_from=list(self.edge_from),
                       mask_offset_px=[None if o is None else float(o) for o in self.mask_offset_px],
                       mask_turn_deg=[None if a is None else float(a) for a in self.mask_turn_deg],
                       mask_agrees=bool(self.mask_agrees))
        note = self.disagreement()
        if note:
            out["mask_warning"] = note
        return out


def _instrument_masks(masks, shape, labels, instances):
    """The list of (H, W) bool instrument masks of `masks` (module docstring of
    `shafts_from_masks`)."""
    if isinstance(masks, (list, tuple)):
        out = [np.asarray(m, bool) for m in masks]
    else:
        out = instruments_in_mask(masks, labels=labels, instances=instances)
        if np.asarray(masks).shape[:2] != tuple(shape):
            out = [None]  # the size check below says so
    for m in out:
        if m is None or m.shape != tuple(shape):
            got = np.asarray(masks if m is None else m).shape[:2]
            raise InputError(f"mask is {got[1]}x{got[0]} but the image is {shape[1]}x{shape[0]}")
    return out


def _mask_edge(A, B, n_out):
    """The `EdgeLine` of a mask's edge A -> B (2,) [ideal px], its normal n_out out of the
    shaft, with the mask's error (`MASK_EDGE_SIGMA_PX` at either end, independent)."""
    L = float(np.hypot(*(B - A)))
    u = (B - A) / L
    return EdgeLine(p0=A, u=u, n=n_out, sm=0.5 * L, tm=0.0, b=0.0, var_t=0.5 * MASK_EDGE_SIGMA_PX**2,
                    var_b=2.0 * MASK_EDGE_SIGMA_PX**2 / L**2, s_lo=0.0, s_hi=L, count=2, frac=1.0, rms=0.0)


def _edge_specs(camera, edges_raw):
    """(specs for `fit_edges`, mask edges as `EdgeLine`) of a mask's two edges (2, 4) [raw
    px]: each from its first end along the mask's edge in ideal px, its normal pointing out
    of the shaft (away from the other edge)."""
    ideal = to_working(camera, edges_raw).reshape(2, 2, 2)
    centre = ideal.reshape(-1, 2).mean(0)
    specs, masked = [], []
    for A, B in ideal:
        L = float(np.hypot(*(B - A)))
        u = (B - A) / L
        n = np.array([-u[1], u[0]])
        n = n if n @ (A - centre) > 0 else -n
        specs.append((A, u, n, 0.0, L))
        masked.append(_mask_edge(A, B, n))
    return specs, masked


def _grey_refit(gimg, camera, fit, spec, corridor, gamma, noise):
    """One edge refined on the grey levels (`edges.edge_profiles`: unsigned, corrected for
    the slopes beside it, located on linear light; `shaft.axis.class_edge`: one offset per
    polarity, the edge where it is best seen) within `REFINE_SEARCH_PX` of its colour fit
    (`shaft.silhouette.EdgeLine`), or within the corridor of the mask's edge (spec) where
    the colour fit found none; a station's edge above `Z_999` of the noise (sd noise [grey
    levels]) through the kernel; None where the grey levels show too little."""
    p0, u, n_out, s0, s1 = spec
    if fit is not None:
        A, B = fit.point_at(s0), fit.point_at(s1)
        search = REFINE_SEARCH_PX
    else:
        A, B = p0 + s0 * u, p0 + s1 * u
        search = corridor
    L = float(np.hypot(*(B - A)))
    U = (B - A) / L
    n_in = np.array([-U[1], U[0]])
    if n_in @ n_out > 0:  # the profiles' +t side into the shaft
        A, B, U, n_in = B, A, -U, -n_in
    cnt = station_counts(np.zeros(1), np.array([L]), _STATION_PX, _MAX_STATIONS)
    sv = stations(np.zeros(1), np.array([L]), cnt)[0]
    kern = derivative_kernel(REFINE_SIGMA_PX)
    p = edge_profiles(gimg, camera, A[None], U[None], sv, search, kern, REFINE_SIGMA_PX, unsigned=True,
                      slope_correction=True, gamma=gamma)
    a = np.abs(p.g[0])
    base = p.inside[0] & p.found[0] & (a > Z_999 * noise * float(np.sqrt(np.sum(kern[0].astype(float) ** 2))))
    if base.sum() < MIN_STATIONS:
        return None
    base &= a >= _REL_STRENGTH * np.median(a[base])
    w = a * a / np.median(a[base] ** 2)
    got = class_edge(A, U, n_in, sv[0], p.t[0], w, base, p.g[0])
    if got is None:
        return None
    # seen along this fraction of the stations that could see it (as the colour fit's frac)
    return replace(got[0], frac=got[0].count / max(int(p.inside[0].sum()), 1))


def _seen(fit, spec):
    """The stretch (lo, hi) [px along the mask's edge] where an edge fit and the mask's edge
    (spec) are both seen, when the fit spans `MIN_FOUND_FRACTION` of the mask's stretch and
    is seen at `MIN_SEEN_FRACTION` of its stations; else None."""
    if fit is None or fit.frac < MIN_SEEN_FRACTION:
        return None
    p0, u, _, s0, s1 = spec
    span = np.sort((fit.ends() - p0) @ u)
    lo, hi = max(span[0], s0), min(span[1], s1)
    return (lo, hi) if hi - lo >= MIN_FOUND_FRACTION * (s1 - s0) else None


def _judged(fit, spec):
    """(the edge to use or None, "image" | "mask", offset [px] or None, turn [deg] or None)
    of one edge: the image's fit where it is seen (`_seen`), lies within `MAX_AGREEMENT_PX` of
    the mask's edge over their common stretch (offset: the larger distance at its two ends)
    and turns from it by `MAX_AGREEMENT_DEG` at most; else None: the mask's edge stands."""
    common = _seen(fit, spec)
    if common is None:
        return None, "mask", None, None
    p0, u = spec[0], spec[1]
    ln = fit.line()
    off = max(abs(float(ln[:2] @ (p0 + s * u) + ln[2])) for s in common)
    turn = float(np.degrees(np.arcsin(min(1.0, abs(float(ln[:2] @ u))))))
    if off <= MAX_AGREEMENT_PX and turn <= MAX_AGREEMENT_DEG:
        return fit, "image", off, turn
    return None, "mask", off, turn


def _polarity(gray, m):
    """"dark" when the instrument's pixels are darker than a ring around it, else "bright"."""
    import cv2

    ring = cv2.dilate(m.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    ring &= ~m
    if not ring.any():
        return "dark"
    return "dark" if np.median(gray[m]) < np.median(gray[ring]) else "bright"


def _part(ax, m, camera, index, polarity):
    """The `MaskShaft` of a distal part alone (mask m (H, W) bool): the mask's principal axis
    (kind "part") over the mask's extent along it."""
    ys, xs = np.nonzero(m)
    d = np.array([ax.line[1], -ax.line[0]])
    along = (np.c_[xs, ys] - ax.point) @ d
    seg = np.r_[ax.point + along.min() * d, ax.point + along.max() * d]
    ideal = to_working(camera, seg).reshape(-1)
    sa = float(np.arctan2(ax.width_px, ax.length_px))
    so = PART_OFFSET_SIGMA_FRAC * ax.width_px
    cov = np.diag([sa**2, so**2])
    return MaskShaft(midline=np.asarray(seg, float), width_px=float(ax.width_px), angle_sigma=float(sa),
                     offset_sigma=float(so), edges=np.zeros((0, 4)), score=float(ax.length_px),
                     ideal_midline=np.asarray(ideal, float), convergence_deg=0.0, polarity=polarity, cue="mask",
                     cov=cov, cov_stat=cov, cov_floor=np.zeros((2, 2)), ideal_edges=None, edge_cov=None,
                     kind="part", instrument=index, edge_from=(), mask_offset_px=(), mask_turn_deg=())


def shafts_from_masks(image, masks, camera=None, *, labels=None, instances=False, valid_region=None,
                      gamma=DEFAULT_GAMMA, corridor_px=MASK_CORRIDOR_PX):
    """Each masked instrument's axis, refined on the image's edges, with its covariance
    (module docstring).

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        The raw frame (grey or BGR).
    masks : (H, W) or (H, W, 3) array, or list of (H, W) bool
        The frame's instrument mask: binary, label, colour or instance image
        (`mask.instruments_in_mask` reads it with `labels` and `instances`); or one boolean
        mask per instrument (a network's instance output).
    camera : Camera, optional
        Lens model (the edges are fitted straight in undistorted pixels); without it a
        nominal pinhole gives the axis's plane (`shaft.work.axis_matrix`).
    labels : sequence of int or of (B, G, R), optional
        The mask values (or colours) that are instrument; default every non-zero one.
    instances : bool
        Each selected value is one instrument (an instance image).
    valid_region : region.ValidRegion, optional
        Where the scene is: the mask's outline on its boundary is no silhouette, and no
        profile is sampled beyond it.
    gamma : float
        The frame's encoding gamma: the edges are located on levels linearised with it
        (`edges.linearised`; 1: linear frames).
    corridor_px : float
        Half-width of the search for each image edge around the mask's [px].

    Returns
    -------
    list of MaskShaft
        One per instrument of the mask, in its order (largest first); an instrument whose
        axis leaves the lens model's reach is left out.
    """
    img = np.asarray(image)
    if img.ndim not in (2, 3) or img.size == 0 or (img.ndim == 3 and img.shape[2] not in (1, 3, 4)):
        raise InputError(f"image: expected (H, W) or (H, W, 3), got shape {img.shape}")
    if img.ndim == 3 and img.shape[2] != 3:
        img = img[..., 0] if img.shape[2] == 1 else img[..., :3]
    shape = img.shape[:2]
    check_camera_image(camera, img)
    if not (0.1 <= gamma <= 5.0):
        raise InputError(f"gamma must be in [0.1, 5], got {gamma!r}")
    if not corridor_px > 0:
        raise InputError(f"corridor_px must be positive, got {corridor_px!r}")
    instruments = _instrument_masks(masks, shape, labels, instances)
    if not instruments:
        return []
    import cv2

    gray = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    validity = Validity(valid_region, shape)
    frame = _Frame(np.ascontiguousarray(img, dtype=np.float32), GrayImage(img, valid_region), gray, camera,
                   validity, None if validity.region is None else valid_region.mask(shape),
                   axis_matrix(camera, shape)[0], max(estimate_noise(gray), 0.5), float(gamma), float(corridor_px))
    out = [_instrument(frame, k, m) for k, m in enumerate(instruments)]
    return [sh for sh in out if sh is not None]


@dataclass(frozen=True, eq=False)
class _Frame:
    """What every instrument of one frame is measured on: the frame as float32 (colour
    fit) and grey (refinement), the camera, where samples may be taken (`Validity` and the
    valid mask), the axis camera K, the noise sd, gamma and the corridor's half-width."""

    fimg: np.ndarray
    gimg: GrayImage
    gray: np.ndarray
    camera: object
    validity: Validity
    valid: np.ndarray | None
    K: np.ndarray
    noise: float
    gamma: float
    corridor_px: float


def _instrument(fr, k, m):
    """The `MaskShaft` of instrument k, mask m (H, W) bool (module docstring, steps 1-3), or
    None (an empty mask, an axis beyond the lens model's reach)."""
    ax = mask_axis(m, fr.valid, fr.K)
    if ax is None:
        return None
    pol = _polarity(fr.gray, m)
    if ax.kind == "shaft":
        specs, masked = _edge_specs(fr.camera, ax.edges)
        corr = float(np.clip(CORRIDOR_WIDTH_FRAC * ax.width_px, 1.5, fr.corridor_px))
        fits = fit_edges(fr.fimg, fr.camera, fr.validity, fr.noise, specs, corr, gamma=fr.gamma)
        # the refinement where the grey levels show the edge, else the colour fit
        refits = [_grey_refit(fr.gimg, fr.camera, f, sp, corr, fr.gamma, fr.noise) for f, sp in zip(fits, specs)]
        fits = [r if _seen(r, sp) is not None else f for r, f, sp in zip(refits, fits, specs)]
        got = [_judged(f, sp) for f, sp in zip(fits, specs)]
        mid = midline_from_edges(fr.K, *(g[0] if g[0] is not None else mk for g, mk in zip(got, masked)))
        if mid is None:  # the image's edges bound no cylinder here: the mask's own
            got = [(None, "mask", g[2], g[3]) for g in got]
            mid = midline_from_edges(fr.K, masked[0], masked[1])
        if mid is not None:
            return shaft_of_midline(fr.camera, mid, float(np.hypot(*(mid.ends[1] - mid.ends[0]))), pol, "mask",
                                    MaskShaft, kind="shaft", instrument=k, edge_from=tuple(g[1] for g in got),
                                    mask_offset_px=tuple(g[2] for g in got), mask_turn_deg=tuple(g[3] for g in got))
    return _part(ax, m, fr.camera, k, pol)

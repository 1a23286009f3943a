"""A radial target's edges searched for where a first orientation predicts them.

On a small or steeply tilted Siemens star the angular profiles (`radial`) miss the edges
where the wedges are narrow in the image (the far side): there the edges lie a few blur sds
apart, their peaks merge, and no direction is found to refit. Once the edges that were found
have been labelled and fitted (`pencil.orient`), every edge without a line has a predicted
image, a ray from the vertex (`predicted_edges`), with its sd from the fit's lines. Each is
then searched for along that ray by the joint blurred-edge model (`radial_joint`: its
neighbours, found or predicted, modelled with it), from where its neighbours lie
`radial.JOINT_SIGMAS` blur sds apart out to the rim the found edges reach
(`searched_edges`), and kept only where its step stands out of the image's noise: the step's
z, its stations' steps pooled with their variances under the noise measured on the frame
(`noise.noise_of`), at least the one-sided normal quantile of `pencil.defaults.DETECTION_LEVEL`
shared among the edges searched (Bonferroni), and the step itself at least `STEP_FRACTION`
of the found edges' (the print's step, not a shading's slope that many stations make
significant). Where the edges merge the fitted step's variance grows and the edge is not
kept: nothing here is tuned on frames.

Example
-------
>>> from types import SimpleNamespace
>>> from pencilcal.toolkit.camera.model import Camera
>>> from pencilcal.toolkit.pencil.spec import pencil_from_dict
>>> cam = Camera("pinhole", 640, 480, [[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
>>> pen = pencil_from_dict({"start_deg": 0, "step_deg": 90, "count": 4, "shape": "wedge", "radius": [0, 50]})
>>> th, _, kind = pen.edge_angles()                   # 8 edges; the fit used all but edge 5
>>> used = np.array([0, 1, 2, 3, 4, 6, 7])
>>> a = th[used]                                      # frontal: image angles are the target's
>>> seg = np.concatenate([320 + 0 * a[:, None], 240 + 0 * a[:, None],
...                       320 + 100 * np.cos(a)[:, None], 240 + 100 * np.sin(a)[:, None]], -1)
>>> seg = np.where((kind[used] > 0)[:, None], seg, seg[:, [2, 3, 0, 1]])   # brighter along n
>>> rec = SimpleNamespace(ok=True, R_cam_from_target=np.eye(3), lines={
...     "angle": a, "sigma": np.full(7, 1e-3), "spoke": used, "segment": np.arange(7), "theta": a,
...     "vertex": np.zeros(2)})
>>> p = predicted_edges(cam, pen, rec, seg)
>>> p["edge"].tolist(), np.degrees(np.arctan2(*(p["lines"][0, 2:] - p["lines"][0, :2])[::-1])).round(3).tolist()
([5], 112.5)
>>> p["sign"].tolist() == kind[[5]].tolist(), bool(p["r"][0, 1] > 100)
(True, True)
"""
from __future__ import annotations

import numpy as np
from scipy.special import ndtri

from pencilcal.toolkit.detect.edges import SAMPLE_STEP_PX
from pencilcal.toolkit.detect.radial_joint import joint_refit
from pencilcal.toolkit.detect.working import to_working
from pencilcal.toolkit.geometry.angles import angle_diff, segment_angle
from pencilcal.toolkit.geometry.frames import rotation_from_rotvec
from pencilcal.toolkit.pencil.defaults import DETECTION_LEVEL
from pencilcal.toolkit.pencil.spec import image_angles, image_directions

__all__ = ["predicted_edges", "searched_edges", "RIM_QUANTILE", "SEARCH_SIGMAS", "STEP_FRACTION"]

#: The rim the found edges reach: this quantile of their far ends' radii on the plane (the
#: near side's edges run out to the rim; some are cut short where the fit drops their ends).
RIM_QUANTILE = 0.9
#: An edge is searched for within this many sds of its predicted position (at least 1 px, at
#: most 2 px: the joint model's reach); the project's test level, not tuned.
SEARCH_SIGMAS = 3.0
#: A searched edge's step (its stations' median, `EdgeFit.contrast`) must reach this fraction
#: of the found edges' median: the print's own step, not a shading's slope or a JPEG block's
#: step that many stations make significant; the fraction `radial_joint` asks of each of an
#: edge's stations, not tuned here.
STEP_FRACTION = 0.4
#: `_angle_sd`'s pseudo-inverse drops the rotation's directions whose weighted Jacobian's
#: singular value is under this fraction of the largest: a tilt under ~0.006 deg [rad], two
#: orders over the finite differences' second-order remainder at a frontal view (h / 2).
_RCOND = 1e-4
_RIM_MARGIN = 1.1  # the search runs this far past the rim (the joint fit drops where the step ends)


def predicted_edges(camera, pencil, rec, segments):
    """The pencil's edges that the orientation `rec` left without a line, as rays in working
    pixels where its fit predicts them.

    camera: Camera; pencil: the Pencil `rec` was fitted with (shape ``wedge``: its edges are
    `Pencil.edge_angles`); rec: an `Orientation` with ``lines`` (``keep_lines``);
    segments: (M, 4) [raw px] the segments `rec` was oriented from (``lines["segment"]``
    indexes them), each oriented brighter along n = (-d_y, d_x).

    Returns None where there is nothing to predict, else a dict: ``edge`` (K,) the edges'
    indices in `edge_angles`; ``lines`` (K, 4) [working px] from the vertex to the rim the
    found edges reach (`RIM_QUANTILE`, `_RIM_MARGIN` past it); ``sign`` (K,) each edge's
    polarity as `radial` counts it (+1 brighter towards larger image angles about the
    vertex, taken from the found edges' own); ``r`` (K, 2) [px] from the vertex: the spoke's
    inner end and the search's outer end; ``sd`` (K,) [px] the predicted line's sd at its
    far end (the fit's rotation, its covariance from the lines' sigmas and their scatter);
    ``gap`` (K,) [rad] the image angle to the nearer of its neighbours; ``phi`` (E,) [rad]
    the predicted image angles about the vertex of every edge of the pencil (working px),
    those of `edge` among them.
    """
    lines = getattr(rec, "lines", None)
    if not rec.ok or lines is None or pencil.shape != "wedge" or camera is None:
        return None
    th_all, _, kind = pencil.edge_angles()
    used = np.asarray(lines["spoke"], int)
    missing = np.setdiff1d(np.arange(th_all.size), used)
    if missing.size == 0 or used.size < 3:
        return None
    R = np.asarray(rec.R_cam_from_target, float)
    m = np.asarray(lines["vertex"], float)
    th_used = np.asarray(lines["theta"], float)
    # the wedges as wide as the fit found them printed (`orient._printed_wedge`): each edge's
    # angle moved by the same half-width change, outwards for the wedge's later edge
    side = np.where(np.arange(th_all.size) >= pencil.count, 1.0, -1.0)
    dh = float(np.median((th_used - th_all[used]) * side[used]))
    th_pred = th_all + side * dh
    th = th_pred[missing]
    K = np.asarray(camera.K, float)
    v_px = (K @ np.r_[m, 1.0])[:2]
    u_all = (K[:2, :2] @ image_directions(R, m, th_pred).T).T
    phi_all = np.arctan2(u_all[:, 1], u_all[:, 0])
    u = u_all[missing] / np.maximum(np.hypot(*u_all[missing].T), 1e-12)[:, None]
    d = np.abs(angle_diff(phi_all[missing, None], phi_all[None]))
    d[np.arange(missing.size), missing] = np.inf
    sign = _signs(camera, segments, lines, kind, v_px, missing)
    rho = _rim(camera, R, m, np.asarray(segments, float)[np.asarray(lines["segment"], int)])
    if not np.isfinite(rho) or rho <= 0:
        return None
    r_hi = _image_radius(K, R, m, th, _RIM_MARGIN * rho)
    r0 = 0.0 if pencil.radius is None else float(pencil.radius[0]) / float(pencil.radius[1])
    r_lo = _image_radius(K, R, m, th, r0 * rho)
    sd = r_hi * _angle_sd(R, m, th_used, np.asarray(lines["angle"], float), np.asarray(lines["sigma"], float), th)
    ok = np.isfinite(r_hi) & np.isfinite(sd)
    if not ok.any():
        return None
    ends = v_px + r_hi[:, None] * u
    return {"edge": missing[ok], "lines": np.concatenate([v_px + 0 * u, ends], -1)[ok], "sign": sign[ok],
            "r": np.stack([np.nan_to_num(r_lo), r_hi], -1)[ok], "sd": sd[ok], "gap": d.min(-1)[ok],
            "phi": np.delete(phi_all, missing[~ok])}


def _signs(camera, segments, lines, kind, v_px, edges):
    """The polarities (K,) of the `edges` as `radial` counts them, from `kind` (the pencil's,
    seen from the vertex in the target frame) turned as the found edges say: a found
    segment pointing away from the vertex is brighter towards larger image angles."""
    seg = to_working(camera, np.asarray(segments, float)[np.asarray(lines["segment"], int)])
    out = np.hypot(*(seg[:, 2:] - v_px).T) > np.hypot(*(seg[:, :2] - v_px).T)
    flip = np.median(np.where(out, 1.0, -1.0) * kind[np.asarray(lines["spoke"], int)])
    return np.where(flip < 0, -1.0, 1.0) * kind[edges]


def _plane_radius(R, m, x):
    """Distances (M,) on the plane from the vertex of the points whose normalised images are
    x (M, 2), in units of the vertex's depth (the plane through [m, 1] with normal R[:, 2])."""
    n = R[:, 2]
    mv = np.r_[m, 1.0]
    xh = np.concatenate([x, np.ones((len(x), 1))], -1)
    with np.errstate(all="ignore"):
        lam = (n @ mv) / (xh @ n)
    return np.where(lam > 0, np.linalg.norm(lam[:, None] * xh - mv, axis=-1), np.nan)


def _rim(camera, R, m, seg_raw):
    """The radius on the plane [vertex depths] out to which the found segments (M, 4) [raw
    px] reach: the `RIM_QUANTILE` of their far ends'."""
    if len(seg_raw) == 0:
        return np.nan
    w = to_working(camera, seg_raw).reshape(-1, 2)
    x = (np.linalg.inv(np.asarray(camera.K, float)) @ np.concatenate([w, np.ones((len(w), 1))], -1).T).T[:, :2]
    rho = _plane_radius(R, m, x).reshape(-1, 2).max(-1)
    rho = rho[np.isfinite(rho)]
    return float(np.quantile(rho, RIM_QUANTILE)) if rho.size else np.nan


def _image_radius(K, R, m, th, rho):
    """Distances (K,) [working px] from the vertex's image to the images of the points at
    radius rho [vertex depths] along the target directions th (K,)."""
    X = np.r_[m, 1.0][:, None] + rho * (R[:, :2] @ np.stack([np.cos(th), np.sin(th)]))  # (3, K)
    with np.errstate(all="ignore"):
        p = (K @ X)[:2] / (K @ X)[2]
        return np.where(X[2] > 0, np.hypot(*(p - (K @ np.r_[m, 1.0])[:2, None])), np.nan)


def _angle_sd(R, m, th_used, a_used, s_used, th, h=1e-6):
    """The sd (K,) [rad] of the image angles of the target directions th (K,) under the fit
    R, m: the rotation's covariance from the used lines (th_used, their image angles a_used
    and sds s_used), scaled up by their chi-square per degree of freedom where it exceeds 1,
    propagated to th (the vertex held: the search is about the detected one). At a frontal
    view the tilt moves no image angle to first order: the sd is the roll's alone
    (`_RCOND`).

    >>> from pencilcal.toolkit.geometry.frames import rotation_from_rotvec
    >>> th = np.radians([-22.5, 67.5, 157.5, 247.5, 22.5, 112.5, 202.5, 292.5])  # 4 wedges' edges
    >>> R = rotation_from_rotvec(np.radians([0.0, 0.0, 305.0]))                          # frontal, rolled
    >>> a = image_angles(R, np.zeros(2), np.delete(th, 1))
    >>> sd = _angle_sd(R, np.zeros(2), np.delete(th, 1), a, np.full(7, 1e-3), th[1:2])
    >>> bool(np.isfinite(sd[0])), round(float(sd[0] * np.sqrt(7) * 1e3), 3)              # the roll's: 1e-3 / sqrt(7)
    (True, 1.0)
    """
    def angles(dr, t):
        return image_angles(rotation_from_rotvec(dr) @ R, m, t)

    base_u, base = angles(np.zeros(3), th_used), angles(np.zeros(3), th)
    J_u = np.stack([np.angle(np.exp(1j * (angles(h * e, th_used) - base_u))) / h for e in np.eye(3)], -1)
    J = np.stack([np.angle(np.exp(1j * (angles(h * e, th) - base))) / h for e in np.eye(3)], -1)
    Jw = J_u / s_used[:, None]
    r = np.angle(np.exp(1j * (a_used - base_u))) / s_used
    scale = max(1.0, float(np.sum(r * r)) / max(r.size - 3, 1))
    # a pseudo-inverse: at a frontal view the image angles do not move with the tilt to first
    # order, the tilt columns are the finite differences' second-order remainder (~h), and
    # whether J^T J inverts was left to rounding (over 2000 random face-on fits: NaN once, the
    # edge dropped; elsewhere up to 20 times the roll's sd); directions the used lines do not
    # fix to `_RCOND` of the best fixed one move the predicted angles as little, and are left out
    P = np.linalg.pinv(Jw, rcond=_RCOND)
    C = (P @ P.T) * scale
    return np.sqrt(np.maximum(np.einsum("ki,ij,kj->k", J, C, J), 0.0))


def searched_edges(lin, camera, fit, v, blur, predicted, min_length, joint_sigmas, noise):
    """The predicted edges (`predicted_edges`) found along their rays: (EdgeFit of the
    edges kept, one row each, the rows of `fit` (E,) bool that they replace).

    lin: the frame's linear light (`GrayImage`); fit: the edges found (`EdgeFit`, working
    px) about the vertex v (2,); blur [raw px]: the edges' blur sd; joint_sigmas: blur sds
    between neighbours from which an edge is measured (`radial.JOINT_SIGMAS`); noise: the
    image noise's sd in linear light [grey levels] (at most: where it is largest).

    The neighbours are the found edges and the predicted ones, in angle order; a found edge
    within a third of the edges' spacing of a predicted one (an edge found but not labelled)
    is searched for again as predicted, and replaced where the search keeps it. An edge is
    kept where the joint fit gives it a line at least min_length [px] long whose step's z
    (`radial_joint.joint_refit`'s strength over the noise of `lin`, counted per pixel: its
    profiles are sampled every `edges.SAMPLE_STEP_PX`) reaches the detection level (module
    docstring).
    """
    K = len(predicted["edge"])
    ok = np.flatnonzero(fit.ok)
    pred = predicted["lines"]
    phi_p = segment_angle(pred)
    found = fit.lines()[ok]
    mid = 0.5 * (found[:, :2] + found[:, 2:])
    phi_f = np.arctan2(mid[:, 1] - v[1], mid[:, 0] - v[0])
    sign_f = np.where(np.hypot(*(fit.p2[ok] - v).T) > np.hypot(*(fit.p1[ok] - v).T), 1.0, -1.0)
    # each found edge's nearest predicted edge, within a third of the edges' spacing there:
    # one the fit labelled (a neighbour as found), one it left without a line (searched
    # for again as predicted), or none (other print: no neighbour)
    phi_e = predicted["phi"]
    d = np.abs(angle_diff(phi_f[:, None], phi_e[None]))
    near = np.argmin(d, -1) if phi_e.size else np.zeros(phi_f.size, int)
    gaps = np.sort(np.abs(angle_diff(phi_e[:, None], phi_e[None])), -1)[:, 1]
    close = d[np.arange(phi_f.size), near] < gaps[near] / 3.0
    missing_phi = np.abs(angle_diff(phi_e[near][:, None], phi_p[None])).min(-1) < 1e-9
    dup = close & missing_phi
    keep_f = close & ~missing_phi
    lines = np.concatenate([found[keep_f], pred])
    sign = np.r_[sign_f[keep_f], predicted["sign"]]
    phi = np.r_[phi_f[keep_f], phi_p]
    order = np.argsort(phi)
    inv = np.empty_like(order)
    inv[order] = np.arange(order.size)
    rows = inv[np.sum(keep_f) + np.arange(K)]
    r_lo = np.full(order.size, np.inf)
    r_hi = np.zeros(order.size)
    # from where each lies joint_sigmas blur sds from its nearer neighbour
    gap = np.diff(np.r_[phi[order], phi[order][0] + 2 * np.pi])
    gap = np.minimum(np.minimum(gap, np.roll(gap, 1)), np.pi / 2)
    r_lo[rows] = np.maximum(predicted["r"][:, 0],
                            joint_sigmas * blur / np.maximum(np.sin(gap[rows]), 1e-6))
    r_hi[rows] = predicted["r"][:, 1]
    long_enough = r_hi[rows] - r_lo[rows] >= min_length
    if not long_enough.any():
        return fit.take(np.zeros(0, int)), np.zeros(fit.ok.size, bool)
    rows = rows[long_enough]
    search = float(np.clip(SEARCH_SIGMAS * np.max(predicted["sd"][long_enough]), 1.0, 2.0))
    new, _, strength = joint_refit(lin, camera, lines[order], v, sign[order], blur, r_lo, r_hi, rows=rows,
                                   search=search, significance=True)
    noise = max(noise, 1e-6)
    z = strength / noise * np.sqrt(SAMPLE_STEP_PX)  # the profiles' samples per pixel counted once
    z_min = float(ndtri(1.0 - DETECTION_LEVEL / K))
    step = float(np.median(fit.contrast[ok])) if ok.size else 0.0
    good = (new.ok & (np.hypot(*(new.p2 - new.p1).T) >= min_length) & (z >= z_min)
            & (new.contrast >= STEP_FRACTION * step))
    kept = np.flatnonzero(long_enough)[good]
    # the found edges a kept one stands for
    replaced = np.zeros(fit.ok.size, bool)
    hit = np.abs(angle_diff(phi_e[near][:, None], phi_p[kept][None])).min(-1) < 1e-9 if kept.size \
        else np.zeros(phi_f.size, bool)
    gone = ok[dup & hit]
    replaced[gone] = True
    return new.take(np.flatnonzero(good)), replaced

"""Radial targets on rendered webcam frames, with exact truth: how many spokes the orientation
uses, whether it resolves the twin, and its normal's error against its bound and its sigma.

`radial_conditions` draws the conditions the method must hold under (Siemens stars of 16 to
128 wedges and dartboards, dark on light and the reverse, tilts 15-60 deg, a webcam's blur,
noise, uneven light, gamma 2.2 and JPEG, barrel distortion down to k1 = -0.3, the target
anywhere near the middle of a 1280x960 frame); `radial_trial` renders one
(`toolkit.synth.radial`), finds its edges and circle points (`toolkit.detect.radial`),
orients it (`toolkit.pencil.orient`) and compares with the truth; `radial_summary` gives the
figures tests/validation/test_radial_renders.py checks and docs/method.md reports.

The bound: the covariance of the normal at the *true* rotation and vertex for the lines the
fit used, with their sigmas (`estimator.pencil_covariance`): the Cramer-Rao bound of the
normal for those lines. Coverage: the fraction of frames whose normal error lies within the
68.3 % region of the covariance the fit reports (chi2 with 2 dof).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.pencil.estimator import pencil_covariance
from pencilcal.toolkit.pencil.spec import Pencil, pencil_from_dict

__all__ = ["RadialTrial", "radial_conditions", "radial_trial", "ideal_lines_trial", "radial_summary", "KINDS",
           "photo_conditions", "photographic_conditions", "real_photo_conditions", "photo_pencils", "photo_frame",
           "photo_trial", "STAR_COUNTS"]

#: What is rendered: Siemens stars of so many wedges, and a dartboard.
KINDS = ("star16", "star32", "star64", "star128", "dartboard")
_CHI2_2_68 = -2.0 * np.log(1.0 - 0.6827)  # chi-square(2) quantile of 68.27 %
_STAR_RADIUS = 70.0  # [mm]


@dataclass(frozen=True)
class RadialTrial:
    """One rendered frame and what the orientation made of it.

    spokes, spokes_used: the target's spokes and those in the fit; ok: an estimate; resolved:
    the twin chosen (any way); twin_right: it is the true one; err_deg: the chosen normal's
    angle from the truth (the closer twin's when not resolved); sigma_deg: the reported
    normal sigma; bound_deg: the normal's bound at the truth (module docstring); chi2: the
    normal error's chi2 (2 dof) with the reported covariance; circle_err_deg,
    circle_sigma_deg: the circles' normal's error and sigma (None without circles);
    conditions: the rendering's conditions; misfit_scale: the factor the lines' misfit widened
    their error variances by (the record's, `pencil.bend`; None where not measured).
    """

    kind: str
    spokes: int
    spokes_used: int
    ok: bool
    resolved: bool
    twin_right: bool
    err_deg: float
    sigma_deg: float
    bound_deg: float
    chi2: float
    circle_err_deg: float | None
    circle_sigma_deg: float | None
    conditions: dict
    misfit_scale: float | None = None


def radial_conditions(n, seed=0, kinds=KINDS):
    """n conditions drawn with `seed`, cycling through `kinds`: dicts with kind, polarity,
    tilt_deg, blur_px, noise, jpeg, k1, vertex_px, axis_deg, roll_deg, fill, seed.

    The polarity alternates from one cycle of the kinds to the next (as many dark targets as
    light), the first cycle's drawn from the seed on a stream of its own (the other draws are
    the seed's as before): a draw of one frame, or of one of each kind, is dark for some seeds
    and light for others (it was dark for every seed).

    >>> sorted({radial_conditions(1, s)[0]["polarity"] for s in range(8)})
    ['dark', 'light']
    """
    rng = np.random.default_rng(seed)
    first = int(np.random.default_rng([seed, 1]).integers(2))
    out = []
    for i in range(n):
        out.append(dict(kind=kinds[i % len(kinds)], polarity=("dark", "light")[(first + i // len(kinds)) % 2],
                        tilt_deg=float(rng.uniform(15, 60)), blur_px=float(rng.uniform(0.6, 1.5)),
                        noise=float(rng.uniform(1.0, 3.0)), jpeg=int(rng.integers(70, 96)),
                        k1=float(rng.uniform(-0.3, 0.0)), vertex_px=rng.uniform([540, 400], [740, 560]).tolist(),
                        axis_deg=float(rng.uniform(0, 360)), roll_deg=float(rng.uniform(0, 360)),
                        fill=float(rng.uniform(0.75, 0.9)), seed=int(rng.integers(1 << 30))))
    return out


def _camera(k1):
    """A webcam: 1280x960, f = 1000 px (65 deg across), barrel distortion k1."""
    return Camera("opencv", 1280, 960, [[1000.0, 0, 643.1], [0, 1000.5, 477.4], [0, 0, 1]], [k1, 0.0, 0.0, 0.0])


def _target(kind, polarity, seed):
    """(pencil, layers, radius [mm] the frame is filled to, edges all around)."""
    from pencilcal.toolkit.synth.radial import DARTBOARD, dartboard_layers, dartboard_pencil, star_layers

    if kind == "dartboard":
        pen = dartboard_pencil()
        layers = dartboard_layers(numbers=True, darts=0, rng=seed)
        if polarity == "light":  # the reverse board: black and cream swapped
            swap = {DARTBOARD["black"]: DARTBOARD["cream"], DARTBOARD["cream"]: DARTBOARD["black"]}
            layers = [(p, swap.get(r, r)) for p, r in layers]
            pen = Pencil(pen.angles, pen.vertex, pen.radius, None, "edge", None, "light", pen.circles)
        return pen, layers, DARTBOARD["board"], 20
    n = int(kind[4:])
    pen = pencil_from_dict({"start_deg": 0.0, "step_deg": 360.0 / n, "count": n, "shape": "wedge",
                            "radius": [0.0, _STAR_RADIUS], "circles": [_STAR_RADIUS], "polarity": polarity})
    return pen, star_layers(pen), _STAR_RADIUS, 2 * n


def _render_and_orient(cond):
    """Render `cond`, detect its edges and orient it: (camera, pencil, R, t, found, rec)."""
    from pencilcal.toolkit.detect.lines import radial_joint_mode
    from pencilcal.toolkit.detect.radial import orient_radial_edges
    from pencilcal.toolkit.synth.radial import radial_pose, render_layers

    cam = _camera(cond["k1"])
    pen, layers, radius, edges = _target(cond["kind"], cond["polarity"], cond["seed"])
    R, t = radial_pose(cam, cond["vertex_px"], cond["tilt_deg"], radius, fill=cond["fill"], axis_deg=cond["axis_deg"],
                       roll_deg=cond["roll_deg"])
    img = render_layers(cam, R, t, layers, blur_px=cond["blur_px"], noise=cond["noise"], gamma=2.2, lighting=0.3,
                        jpeg_quality=cond["jpeg"], rng=cond["seed"])
    found, rec = orient_radial_edges(img, cam, pen, edges=edges, joint=radial_joint_mode(pen))
    return cam, pen, R, t, found, rec


def radial_trial(cond):
    """Render, detect and orient one frame of `cond` (`radial_conditions`); a `RadialTrial`."""
    return _compared(cond["kind"], cond, *_render_and_orient(cond))


def photo_trial(cond):
    """Photograph (`photo_frame`), detect and orient one frame of `cond` (`photo_conditions`)
    with the pencil file that gives the star's shape, as `orient IMAGES` does
    (`orient_radial_edges`); a `RadialTrial` of kind "photo<wedges>"."""
    from pencilcal.toolkit.detect.lines import radial_edge_count, radial_joint_mode
    from pencilcal.toolkit.detect.radial import orient_radial_edges

    from pencilcal.toolkit.io.images import with_grey

    img, cam, R, t = photo_frame(cond)
    img = with_grey(img)[0]  # a colour photograph read as `orient IMAGES` reads it
    pen = photo_pencils(cond)[1]
    found, rec = orient_radial_edges(img, cam, pen, edges=radial_edge_count(pen), joint=radial_joint_mode(pen))
    return _compared(f"photo{cond['wedges']}", cond, cam, pen, R, t, found, rec)


def _compared(kind, cond, cam, pen, R, t, found, rec):
    """The `RadialTrial` of one oriented frame against its truth R, t."""
    if not rec.ok:
        return RadialTrial(kind, pen.count, 0, False, False, False, np.inf, np.nan, np.nan, np.inf, None, None, cond)
    n_true = R[:, 2]
    err = np.degrees(np.arccos(np.clip(np.asarray(rec.normal) @ n_true, -1, 1)))
    err_twin = np.degrees(np.arccos(np.clip(np.asarray(rec.normal_twin) @ n_true, -1, 1)))
    resolved = not rec.ambiguous
    twin_right = resolved and err < err_twin
    n_est = np.asarray(rec.normal if (twin_right or not resolved and err <= err_twin) else rec.normal_twin)
    ln = rec.lines
    th = np.asarray(ln["theta"], float)  # the edges' target angles as fitted (a star's wedges as wide as printed)
    R_est = np.asarray(rec.R_cam_from_target if n_est is rec.normal else rec.R_cam_from_target_twin, float)
    cov_est = _normal_cov(R_est, ln, th)
    x_true = t[:2] / t[2]
    cov_true = _normal_cov(R, dict(ln, vertex=x_true, sigma_error=None, bend_cov=None), th)  # the bound: the lines' own sds
    chi2 = _normal_chi2(n_est, cov_est, n_true)
    circ_err = None
    if rec.circle_normal is not None:
        circ_err = float(np.degrees(np.arccos(np.clip(np.asarray(rec.circle_normal) @ n_true, -1, 1))))
    return RadialTrial(kind, pen.count, int(rec.spokes_used), True, resolved, bool(twin_right),
                       float(min(err, err_twin) if not resolved else (err if twin_right else err_twin)),
                       float(rec.normal_sigma_deg), float(np.degrees(np.sqrt(np.trace(cov_true)))), chi2, circ_err,
                       rec.circle_normal_sigma_deg, cond, rec.misfit_scale)


def _normal_chi2(n_est, cov, n_true):
    """The chi2 (2 dof) of the normal's error n_est - n_true (3,) with its covariance (3, 3),
    in the plane normal to n_true."""
    B = np.linalg.svd(np.eye(3) - np.outer(n_true, n_true))[0][:, :2]
    e2 = B.T @ (np.asarray(n_est, float) - n_true)
    return float(e2 @ np.linalg.solve(B.T @ cov @ B, e2))


def ideal_lines_trial(cond, draws, rng=0):
    """The estimator alone on one frame of `cond`: its edges rendered and detected once, then
    replaced, `draws` times, by the exact image lines of the edges they are (each detected
    segment matched to the true edge nearest in angle about the true vertex), each given
    independent Gaussian noise at the sigmas the detector reported (its angle about its
    midpoint, its offset there), over the same extents, labelled as they are. Whatever the
    normal's chi2 then shows is the estimator's; what the detected lines show beyond it is
    the detector's (its errors not independent, or larger than its sigmas).

    Returns a dict: chi2 (draws,) of the normal against the covariance it reports (the twin
    nearer the truth), detected_chi2 (the detected lines' own), lines (how many).
    """
    from pencilcal.toolkit.pencil.orient import orient_segments

    cam, pen, R, t, found, rec = _render_and_orient(cond)
    if not rec.ok:
        return {"chi2": np.full(draws, np.inf), "detected_chi2": np.inf, "lines": 0}
    n_true = R[:, 2]
    K = np.asarray(cam.K, float)
    ea = pen.edge_angles()[0]
    xv = (K @ np.append(t[:2] / t[2], 1.0))[:2]  # the vertex [ideal px]
    P = R @ np.stack([np.cos(ea), np.sin(ea), np.zeros_like(ea)]) + t[:, None]
    U = (K @ (P / P[2]))[:2].T - xv
    U /= np.linalg.norm(U, axis=1)[:, None]  # each edge's image direction from the vertex
    used = np.asarray(rec.lines["segment"], int)
    raw = np.asarray(found.segments, float)[used]
    ideal = np.concatenate([cam.undistort_pixels(raw[:, :2]), cam.undistort_pixels(raw[:, 2:])], 1)
    mid = 0.5 * (ideal[:, :2] + ideal[:, 2:]) - xv
    gap = np.angle(np.exp(1j * (np.arctan2(mid[:, 1], mid[:, 0])[:, None] - np.arctan2(U[:, 1], U[:, 0])[None])))
    label = np.argmin(np.abs(gap), 1)
    u = U[label]
    nrm = np.stack([-u[:, 1], u[:, 0]], 1)
    s1, s2 = np.sum((ideal[:, :2] - xv) * u, 1), np.sum((ideal[:, 2:] - xv) * u, 1)  # the extents along u
    length = np.abs(s2 - s1)
    centre = xv + 0.5 * (s1 + s2)[:, None] * u
    a_sig = np.asarray(found.angle_sigma, float)[used]
    o_sig = np.asarray(found.offset_sigma, float)[used]
    scale = np.hypot(*(ideal[:, 2:] - ideal[:, :2]).T) / np.hypot(*(raw[:, 2:] - raw[:, :2]).T)  # raw -> ideal px
    rng = np.random.default_rng(rng)
    chi2 = np.empty(draws)
    for k in range(draws):
        a = rng.normal(0.0, a_sig)
        d = np.cos(a)[:, None] * u + np.sin(a)[:, None] * nrm
        c = centre + rng.normal(0.0, o_sig * scale)[:, None] * nrm
        seg = np.concatenate([cam.distort_pixels(c - 0.5 * length[:, None] * d),
                              cam.distort_pixels(c + 0.5 * length[:, None] * d)], 1)
        r = orient_segments(cam, seg, pen, angle_sigma=a_sig, offset_sigma=o_sig, labels=label, keep_lines=True)
        twins = [(r.normal, r.R_cam_from_target), (r.normal_twin, r.R_cam_from_target_twin)]
        n_est, R_est = max(twins, key=lambda q: float(np.asarray(q[0]) @ n_true))
        chi2[k] = _normal_chi2(n_est, _normal_cov(np.asarray(R_est, float), r.lines, ea[r.lines["spoke"]]), n_true)
    twins = [(rec.normal, rec.R_cam_from_target), (rec.normal_twin, rec.R_cam_from_target_twin)]
    n_est, R_est = max(twins, key=lambda q: float(np.asarray(q[0]) @ n_true))
    det = _normal_chi2(n_est, _normal_cov(np.asarray(R_est, float), rec.lines, ea[np.asarray(rec.lines["spoke"], int)]),
                       n_true)
    return {"chi2": chi2, "detected_chi2": det, "lines": int(used.size)}


def _normal_cov(R, ln, th):
    """(3, 3) covariance of the normal R[:, 2] for the lines ln (orient's ``lines``) of edge
    angles th: the rotation's (left perturbation) turned into the normal's."""
    err = ln.get("sigma_error")  # the sds of the lines' errors where wider than their weights'
    bend = ln.get("bend_cov")  # the sheet's bend (at the fit's rotation)
    cov, _, _ = pencil_covariance(R, np.asarray(ln["vertex"], float), th, np.asarray(ln["sigma"], float),
                                  np.asarray(ln["vertex_cov"], float),
                                  sigma_error=None if err is None else np.asarray(err, float),
                                  shared_cov=None if bend is None else np.asarray(bend, float))
    n = R[:, 2]
    K = np.array([[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]])
    return K @ cov @ K.T


def radial_summary(trials):
    """The figures over trials: frames, ok, spokes_used (fraction of all spokes), resolved and
    twin_right (fractions of frames), rmse_deg, bound_deg (RMS), ratio (rmse over bound),
    coverage (fraction within the reported 68.3 % region), circle_rmse_deg."""
    ok = [t for t in trials if t.ok]
    err = np.array([t.err_deg for t in ok])
    bound = np.array([t.bound_deg for t in ok])
    chi2 = np.array([t.chi2 for t in ok])
    circ = np.array([t.circle_err_deg for t in ok if t.circle_err_deg is not None])
    rmse = float(np.sqrt(np.mean(err**2))) if ok else np.nan
    rb = float(np.sqrt(np.mean(bound**2))) if ok else np.nan
    return {"frames": len(trials), "ok": len(ok),
            "spokes_used": sum(t.spokes_used for t in trials) / max(sum(t.spokes for t in trials), 1),
            "resolved": sum(t.resolved for t in trials) / max(len(trials), 1),
            "twin_right": sum(t.twin_right for t in trials) / max(len(trials), 1),
            "rmse_deg": rmse, "bound_deg": rb, "ratio": rmse / rb if ok else np.nan,
            "coverage": float(np.mean(chi2 <= _CHI2_2_68)) if ok else np.nan,
            "circle_rmse_deg": float(np.sqrt(np.mean(circ**2))) if circ.size else None}


#: The photographed star's pencil: 64 wedges, as the check's printed star.
PHOTO_WEDGES = 64


def photo_conditions(n, seed=0, wedges=(PHOTO_WEDGES,)):
    """n conditions of a webcam's photograph of a printed star (`toolkit.synth.radial_photo`)
    drawn with `seed`: dicts with wedges, polarity, tilt_deg, k1, vertex_px, axis_deg,
    roll_deg, fill (the star's diameter over the frame's height, 0.2-0.6), gain_mm (dot
    gain, -0.1..0.15 mm), centre_mm and centre_grey (a grey disc where the print filled in,
    half the frames), sheet_deg, sheet_shift, desk, clutter, paper, exposure, shading,
    shading_deg, vignette, specular (half the frames) and specular_px, blur_px, defocus_px,
    motion_px, motion_deg, noise, jpeg (60-85), seed. Polarity is drawn, not set by index."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        fill = float(rng.uniform(0.2, 0.6))
        r = fill * 480.0 * 1.15  # the star's radius in px, and room for the tilt's stretch
        c = dict(wedges=int(wedges[i % len(wedges)]), polarity=str(rng.choice(["dark", "light"], p=[0.75, 0.25])),
                 tilt_deg=float(rng.uniform(15, 60)), k1=float(rng.uniform(-0.3, 0.0)),
                 vertex_px=[float(rng.uniform(min(640, r + 60), max(640, 1220 - r))),
                            float(rng.uniform(min(480, r + 40), max(480, 920 - r)))],
                 axis_deg=float(rng.uniform(0, 360)), roll_deg=float(rng.uniform(0, 360)), fill=fill,
                 gain_mm=float(rng.uniform(-0.1, 0.15)),
                 centre_mm=float(rng.uniform(2, 9)) if rng.random() < 0.5 else 0.0,
                 centre_grey=float(rng.uniform(0.15, 0.5)), sheet_deg=float(rng.uniform(-20, 20)),
                 sheet_shift=[float(rng.uniform(-8, 8)), float(rng.uniform(-15, 15))],
                 desk=float(rng.uniform(0.06, 0.5)), clutter=int(rng.integers(6, 20)),
                 paper=float(rng.uniform(0.7, 0.9)), exposure=float(rng.uniform(0.8, 1.1)),
                 shading=float(rng.uniform(0.1, 0.6)), shading_deg=float(rng.uniform(0, 360)),
                 vignette=float(rng.uniform(0.1, 0.5)), specular=float(rng.uniform(0.1, 0.6)) * (rng.random() < 0.5),
                 blur_px=float(rng.uniform(0.5, 1.0)), defocus_px=float(rng.uniform(0.0, 2.0)),
                 motion_px=float(rng.uniform(0.0, 2.5)), motion_deg=float(rng.uniform(0, 180)),
                 noise=float(rng.uniform(1.0, 4.0)), jpeg=int(rng.integers(60, 86)), seed=int(rng.integers(1 << 30)))
        x, y = c["vertex_px"]
        c["specular_px"] = [x + float(rng.uniform(-r, r)), y + float(rng.uniform(-r, r)), float(rng.uniform(40, 160))]
        out.append(c)
    return out


def photographic_conditions(n, seed=0, wedges=(PHOTO_WEDGES,)):
    """n conditions of `photo_conditions(n, seed)`, each made as hard as a real photograph
    with draws of a stream of their own (`photo_conditions`' draws unchanged): the print's
    contrast (Michelson, of the grey levels recorded) 0.5-0.8 (0.59 in `photo_conditions`), the paper's texture (1-4 %), chromatic
    aberration (the red and blue channels 0.5-1 px from the green at the corners, either
    way; a colour JPEG), the camera's sharpening (an unsharp mask of 0.3-1.2 over 0.8-2 px:
    halos), the sheet curled (-0.5..0.5 mm off the plane at the sheet's end, 148.5 mm from
    the vertex along a direction drawn; 0.11 mm at the star's rim), and a shadow's soft edge (depth 0.3-0.6, 10-80 px wide) across the star
    in half the frames. Keys added: contrast, texture, ca_px, sharpen, sharpen_px, curl_mm,
    curl_deg, shadow, shadow_px, shadow_deg, shadow_soft. wedges: as `photo_conditions`'.

    >>> c = photographic_conditions(2, 5)
    >>> [k for k in c[0] if k not in photo_conditions(1, 5)[0]][:3], c[1]["tilt_deg"] == photo_conditions(2, 5)[1]["tilt_deg"]
    (['contrast', 'texture', 'ca_px'], True)
    """
    rng = np.random.default_rng([seed, 29])
    out = photo_conditions(n, seed, wedges)
    for c in out:
        x, y = c["vertex_px"]
        c.update(contrast=float(rng.uniform(0.5, 0.8)), texture=float(rng.uniform(0.01, 0.04)),
                 ca_px=float(rng.uniform(0.5, 1.0) * rng.choice([-1, 1])), sharpen=float(rng.uniform(0.3, 1.2)),
                 sharpen_px=float(rng.uniform(0.8, 2.0)), curl_mm=float(rng.uniform(-0.5, 0.5)),
                 curl_deg=float(rng.uniform(0, 180)), shadow=float(rng.uniform(0.3, 0.6)) * (rng.random() < 0.5),
                 shadow_px=[x + float(rng.uniform(-100, 100)), y + float(rng.uniform(-100, 100))],
                 shadow_deg=float(rng.uniform(0, 360)), shadow_soft=float(rng.uniform(10, 80)))
    return out


#: The star counts of `real_photo_conditions`: a lab's stars, coarse to fine.
STAR_COUNTS = (16, 36, 64, 128)


def real_photo_conditions(n, seed=0, wedges=STAR_COUNTS):
    """n conditions of `photographic_conditions(n, seed, wedges)` with what the shared real
    photographs of radial targets show beyond them (their edges' blur measured as a Gaussian's
    sd: medians 1.7-2.0 px, a quarter of the edges over 4 px; the blur not the same across the
    target), drawn on a stream of their own: a defocus that grows across the star as a tilted
    sheet's does (the disc's radius from defocus_px on a line through the star to 1-3.5 px
    more one star diameter along a direction drawn: defocus_far_px, focus_px), and a
    printer's banding (stripes of 1-5 % in ink and paper, 2-12 mm apart, along the sheet's
    feed: banding, banding_mm, banding_deg, banding_phase), and the light's gradient and
    vignetting of `photo_conditions` drawn up to half again as strong.

    >>> c = real_photo_conditions(4, 5)
    >>> [x["wedges"] for x in c], c[0]["tilt_deg"] == photographic_conditions(4, 5, STAR_COUNTS)[0]["tilt_deg"]
    ([16, 36, 64, 128], True)
    """
    rng = np.random.default_rng([seed, 2929])
    out = photographic_conditions(n, seed, wedges)
    for c in out:
        x, y = c["vertex_px"]
        r = c["fill"] * 480.0  # the star's radius [px]
        ang = float(rng.uniform(0, 360))
        c.update(defocus_far_px=c["defocus_px"] + float(rng.uniform(1.0, 3.5)),
                 focus_px=[x - r * np.cos(np.radians(ang)), y - r * np.sin(np.radians(ang)), ang, 2 * r],
                 banding=float(rng.uniform(0.01, 0.05)), banding_mm=float(rng.uniform(2, 12)),
                 banding_deg=c["sheet_deg"] + 90.0 * int(rng.integers(2)), banding_phase=float(rng.uniform(0, 2 * np.pi)),
                 shading=c["shading"] * float(rng.uniform(1.0, 1.5)), vignette=c["vignette"] * float(rng.uniform(1.0, 1.5)))
    return out


def photo_pencils(cond):
    """(the star as printed: shape wedge from the vertex, the pencil file with its shape:
    radius [12, 70] mm, the plain pencil file: rays along the wedges' centre lines, radius
    [12, 70] mm, no shape) of a `photo_conditions` condition."""
    n = cond["wedges"]
    base = {"start_deg": 0.0, "step_deg": 360.0 / n, "count": n}
    printed = pencil_from_dict(dict(base, shape="wedge", radius=[0.0, _STAR_RADIUS], polarity=cond["polarity"]))
    shaped = pencil_from_dict(dict(base, shape="wedge", radius=[12.0, _STAR_RADIUS], polarity=cond["polarity"]))
    return printed, shaped, pencil_from_dict(dict(base, radius=[12.0, _STAR_RADIUS]))


def photo_frame(cond):
    """The photograph of `cond` (`photo_conditions`, `photographic_conditions`,
    `real_photo_conditions`): (image
    (960, 1280) uint8, or (960, 1280, 3) BGR with chromatic aberration, camera, R, t), the
    star's vertex at the target frame's origin (where a curled sheet touches the plane)."""
    from pencilcal.toolkit.synth.radial import linear_layers, radial_pose
    from pencilcal.toolkit.synth.radial_photo import banding, colour_photo, curled, paper_texture, photo_layers, photo_sensor

    cam = _camera(cond["k1"])
    printed, _, _ = photo_pencils(cond)
    R, t = radial_pose(cam, cond["vertex_px"], cond["tilt_deg"], _STAR_RADIUS, fill=cond["fill"],
                       axis_deg=cond["axis_deg"], roll_deg=cond["roll_deg"])
    rng = np.random.default_rng(cond["seed"])
    layers = photo_layers(printed, cond, rng)
    if cond.get("curl_mm"):  # the sheet bent, the desk and its clutter (the first layers) flat
        k = 1 + int(cond.get("clutter", 12))
        layers = layers[:k] + curled(layers[k:], R, t, cond["curl_mm"], cond["curl_deg"])
    lin = linear_layers(cam, R, t, layers, 0.25)
    if cond.get("texture"):
        lin = lin * paper_texture(cam, R, t, cond["texture"], np.random.default_rng([cond["seed"], 3]))
    if cond.get("banding"):
        lin = lin * banding(cam, R, t, cond["banding"], cond["banding_mm"], cond["banding_deg"], cond["banding_phase"])
    if "ca_px" in cond:
        return colour_photo(lin, cond, rng, np.asarray(cam.K, float)[:2, 2]), cam, R, t
    return photo_sensor(lin, cond, rng), cam, R, t

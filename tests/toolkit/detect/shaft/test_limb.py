"""The limb model of a lit shaft's edges (`detect.shaft.limb`) on physically shaded renders
with exact truth (`synth.shaded`): the band's width without the step edge's bias."""
import numpy as np
import pytest

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.detect.shaft.axis import midline_from_edges
from pencilcal.toolkit.detect.shaft.detector import detect_shafts
from pencilcal.toolkit.detect.shaft.limb import fit_limb_profile, limb_design, limb_edges
from pencilcal.toolkit.detect.shaft.silhouette import fit_edges
from pencilcal.toolkit.detect.shaft.work import Validity
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.synth.shaded import MATERIALS, render_shaded_shaft

CAM = Camera("pinhole", 640, 480, [[520.0, 0, 319.5], [0, 520.0, 239.5], [0, 0, 1]])
BRIGHT, DARK = (0.5, 0.55, 0.6), (0.10, 0.12, 0.22)


def _specs(lines, rng, shape, proposal_sd=0.7):
    """fit_edges specs along the true silhouette lines, each shifted as a proposal is."""
    H, W = shape
    out = []
    for l in lines:
        n, u = -l[:2], np.array([l[1], -l[0]])
        p0 = -l[2] * l[:2]
        p0 = p0 + ((np.array([319.5, 239.5]) - p0) @ u) * u
        s = np.arange(-800.0, 800.0)
        P = p0 + s[:, None] * u
        ok = (P[:, 0] > 15) & (P[:, 0] < W - 16) & (P[:, 1] > 15) & (P[:, 1] < H - 16)
        out.append((p0 + rng.normal(0, proposal_sd) * n, u, n, s[ok].min(), s[ok].max()))
    return out


def _widths(material, z, background, seed):
    """(step bias, limb bias) of the band's width [fraction] on one render."""
    rng = np.random.default_rng(seed)
    ang = rng.uniform(0, np.pi)
    d = np.array([np.cos(ang), np.sin(ang), rng.uniform(0.2, 0.6)])
    img, truth = render_shaded_shaft(CAM, [rng.uniform(-3, 3), rng.uniform(-3, 3), z], d, 4.0, MATERIALS[material],
                                     background=background, blur_px=rng.uniform(0.7, 1.5), noise=1.5, rng=rng)
    e = fit_edges(img.astype(np.float32), None, Validity(None, img.shape[:2]), 1.5, _specs(truth.lines, rng, img.shape[:2]),
                  4.0, gamma=2.2)
    step = midline_from_edges(CAM.K, e[0], e[1], floor_px=0.0)
    limb = limb_edges(img, None, CAM.K, e[0], e[1], gamma=2.2)
    m = midline_from_edges(CAM.K, limb[0], limb[1], floor_px=0.0)
    return step.width_px / truth.width_at(step.centre) - 1, m.width_px / truth.width_at(m.centre) - 1


def test_profile_fit_recovers_its_own_model():
    t = np.arange(-8.0, 6.0, 0.25)
    y = limb_design(t, 0.3, 1.0, 12.0, 0.2, 0.9, 0.05) @ [40.0, 0.5, 20.0, 200.0]
    fit = fit_limb_profile(t, y, 12.0, 0.0, 1.2, sin_view=0.9, q=0.05)
    assert fit.ok and abs(fit.edge - 0.3) < 1e-4 and abs(fit.sigma - 1.0) < 1e-4


@pytest.mark.parametrize("material,z,background", [
    ("matte", 120, BRIGHT), ("glossy", 120, BRIGHT), ("dark_metal", 120, BRIGHT), ("bright_metal", 40, BRIGHT),
    ("matte", 40, DARK), ("glossy", 40, DARK), ("dark_metal", 20, DARK),
])
def test_band_width_unbiased_on_shaded_renders(material, z, background):
    # measured on these settings (seeds 1-2): the limb within 0.3 % where the step edge is
    # off by up to 2.3 % on narrow bands (docs/method.md, the limb model)
    biases = [_widths(material, z, background, seed) for seed in (1, 2)]
    limb = np.array([b[1] for b in biases])
    assert np.all(np.abs(limb) < 0.003), limb


def test_step_edge_is_biased_where_the_limb_darkens():
    step, limb = _widths("matte", 150, DARK, 3)
    assert step < -0.01 and abs(limb) < abs(step) / 5


def test_detect_shafts_with_the_limb_model():
    img, truth = render_shaded_shaft(CAM, [0, 0, 120], [1.0, 0.35, 0.5], 4.0, MATERIALS["glossy"],
                                     background=(0.35, 0.3, 0.5), blur_px=1.0, noise=1.5, rng=3)
    for model, tol in (("step", None), ("limb", 0.003)):
        sh = detect_shafts(img, CAM, edge_model=model)
        c = 0.5 * (sh[0].ideal_midline[:2] + sh[0].ideal_midline[2:])
        bias = sh[0].width_px / truth.width_at(c) - 1
        if tol is None:
            assert bias > 0.005  # the material cue's step edges, on encoded levels: narrow far bands come out wide
        else:
            assert abs(bias) < tol
    with pytest.raises(InputError, match="edge_model"):
        detect_shafts(img, CAM, edge_model="ramp")


def _pivot_axes(rng, F, material, background, frames):
    """Each frame's shaft (from the fulcrum F through the view, 25-100 mm away) rendered,
    its edges fitted (step) and located by the limb model: the 3-D axes of both, the edge
    floor set to 0.1 px (what the renders' limb fits keep of systematic error; module
    test of the pivot)."""
    from pencilcal.toolkit.pencil.cylinder import shaft_axis

    K = CAM.K
    out = {"step": [], "limb": []}
    while len(out["limb"]) < frames:
        tgt = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.25), 1.0]) * rng.uniform(25, 100)
        d = (tgt - F) / np.linalg.norm(tgt - F)
        L = np.linalg.norm(tgt - F) + 15
        img, truth = render_shaded_shaft(CAM, F, d, 4.0, MATERIALS[material], extent=(0, L), background=background,
                                         blur_px=rng.uniform(0.7, 1.5), noise=1.5, rng=rng)
        ends = np.array([K @ F, K @ (F + L * d)])
        ends = ends[:, :2] / ends[:, 2:]
        specs = []
        for sp in _specs(truth.lines, rng, img.shape[:2]):
            lo, hi = sorted(((ends - sp[0]) @ sp[1]).tolist())
            specs.append((*sp[:3], max(sp[3], lo + 10), min(sp[4], hi - 10)))
        if any(s[4] - s[3] < 60 for s in specs):
            continue
        e = fit_edges(img.astype(np.float32), None, Validity(None, img.shape[:2]), 1.5, specs, 4.0, gamma=2.2)
        limb = None if None in e else limb_edges(img, None, K, e[0], e[1], gamma=2.2)
        if limb is None:
            continue
        for name, ee in (("step", e), ("limb", limb)):
            m = midline_from_edges(K, ee[0], ee[1], floor_px=0.1)
            out[name].append(shaft_axis(K, m.edges.reshape(2, 4), 4.0, edge_cov=m.edge_cov))
    return out


def test_pivot_fulcrum_within_a_millimetre():
    # an 8 mm matte shaft pivoting about a port 140 mm away against a dark background, where
    # the step edges put the fulcrum millimetres off (docs/method.md, the limb model)
    from pencilcal.toolkit.pencil.cylinder import fulcrum_3d

    rng = np.random.default_rng(0)
    F = np.array([5.0, -55.0, 140.0])
    axes = _pivot_axes(rng, F, "matte", DARK, 6)
    err = {}
    for name, ax in axes.items():
        f = fulcrum_3d(np.stack([a.axis_point for a in ax]), np.stack([a.axis_direction for a in ax]),
                       np.stack([a.axis_cov for a in ax]))
        err[name] = np.linalg.norm(f.point - F)
    assert err["limb"] < 1.0 and err["step"] > 2.0 * err["limb"], err

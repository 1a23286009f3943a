"""Where the limb model is used (`detect.shaft.limb`): the shading it fits is light, never
negative, and an edge keeps its step edge unless the lit cylinder explains its profiles
significantly better than a blurred step (docs/method.md, the limb model on real frames)."""
import numpy as np
import pytest

from pencilcal.toolkit.detect.shaft.limb import (fit_limb_profile, fit_step_profile, limb_design, limb_explains,
                                                 shading_lstsq, step_design)


def _sharpened_dark_step(t, rng, noise=0.15):
    """A black shaft's edge as the phantom's camera gives it (linear light): a blurred step
    from 0 up to a sloping background, an unsharp mask's undershoot inside and overshoot
    outside, and noise: no shading to model."""
    y = step_design(t, 0.0, 0.8) @ [36.0, -0.3, 0.0, 0.0]
    halo = np.gradient(np.gradient(step_design(t, 0.0, 1.6) @ [36.0, 0.0, 0.0, 0.0], t), t)
    return y - 0.8 * halo + rng.normal(0, noise, t.size)


def _light_rss(t, y, fit, half_width):
    """The residual sum of squares of the limb fit with its shading held non-negative."""
    A = limb_design(t, fit.edge, fit.sigma, half_width, fit.roughness)
    r = A @ shading_lstsq(A, y) - y
    return float(r @ r)


def test_shading_is_never_negative():
    from scipy.optimize import lsq_linear

    t = np.arange(-12.0, 7.0, 0.25)
    A = limb_design(t, 0.2, 0.8, 40.0, 0.3)
    rng = np.random.default_rng(0)
    # a shaft darker at its rim than a lit cylinder can be: unbounded, negative diffuse light
    y = A @ [36.0, -0.3, -20.0, 120.0] + rng.normal(0, 0.2, t.size)
    assert np.linalg.lstsq(A, y, rcond=None)[0][2] < 0
    c = shading_lstsq(A, y)
    best = lsq_linear(A, y, bounds=([-np.inf, -np.inf, 0, 0], np.inf), tol=1e-12).x
    assert c[2] >= 0 and c[3] >= 0 and np.allclose(c, best, atol=1e-6)
    # where the unbounded solution is light already it is the one
    good = A @ [40.0, 0.5, 20.0, 200.0]
    assert np.allclose(shading_lstsq(A, good), [40.0, 0.5, 20.0, 200.0], atol=1e-6)


def test_a_step_profile_keeps_its_step_edge():
    rng = np.random.default_rng(1)
    t = np.arange(-12.0, 7.0, 0.25)
    y = _sharpened_dark_step(t, rng)
    fit = fit_limb_profile(t, y, 40.0, 0.0, 1.2)
    step = fit_step_profile(t, y, 0.0, 1.2)
    assert step is not None and abs(step[0]) < 0.1
    assert not limb_explains(_light_rss(t, y, fit, 40.0), step[2], t.size)


@pytest.mark.parametrize("coef,half_width", [([40.0, 0.0, 60.0, 0.0], 40.0), ([40.0, 0.3, 10.0, 150.0], 15.0)])
def test_a_shaded_profile_takes_the_limb(coef, half_width):
    # a matte and a glossy shaft over a brighter background, the noise of a 12 px bin's mean
    # profile (the renders' 1.5 grey levels a station, averaged)
    rng = np.random.default_rng(2)
    t = np.arange(-12.0, 7.0, 0.25)
    t = t[t > -0.7 * half_width]  # the window's reach inside (`refine_edge`)
    y = limb_design(t, 0.3, 1.0, half_width, 0.2) @ coef + rng.normal(0, 0.1, t.size)
    fit = fit_limb_profile(t, y, half_width, 0.0, 1.2)
    step = fit_step_profile(t, y, 0.0, 1.2)
    assert fit.ok and abs(fit.edge - 0.3) < 0.05
    assert limb_explains(_light_rss(t, y, fit, half_width), step[2], t.size)
    assert abs(step[0] - 0.3) > 0.1  # the step misplaces the limb: what the limb model is for


def test_phantom_band_keeps_its_step_edges():
    """The phantom's black shaft (dvrk-lnd-phantom-sequence frame 5): its profiles hold no
    shading a step does not explain (a flat black inside, the camera's sharpening halo), so
    `with_limbs` keeps the step band, edges and class, where the limb model unchosen moved
    the phantom's bands by up to pixels and its 3-D fulcrum's jackknife from 1.4 to 3.8 times
    its sigma."""
    from pencilcal.toolkit.detect.region.detect import detect_valid_region
    from pencilcal.toolkit.detect.shaft.detector import detect_shafts, with_limbs
    from tests.conftest import data_dir
    from tests.toolkit.detect.shaft.test_real import _phantom_camera, _read

    root = data_dir("real-instruments") / "dvrk-lnd-phantom-sequence"
    img = _read(root / "5.png")
    cam = _phantom_camera(root)
    step = detect_shafts(img, cam, valid_region=detect_valid_region([img]))
    assert step
    limb = with_limbs(img, cam, step)
    for a, b in zip(step, limb):
        assert b.edge_model == "step" and np.array_equal(a.ideal_edges, b.ideal_edges)

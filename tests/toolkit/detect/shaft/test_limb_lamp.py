"""A shaft lit by a lamp beside the camera (`detect.shaft.limb`, `LATERAL`): one limb lit, the
other dark before the silhouette, an ambient floor. The limb model with the lamp's sideways
term places the limb within a few hundredths of a pixel on such profiles, where the model of
a light at the camera is off by up to a tenth and fits them worse than a step."""
import numpy as np
import pytest

from pencilcal.toolkit.detect.shaft.limb import (fit_limb_profile, fit_step_profile, is_light, limb_design,
                                                 limb_explains, shading_lstsq)

_W, _K = 7.5, 0.83  # the band's half-width [px], the sine of the view's angle with the axis


def _lamp_profile(t, lamp, ambient, background=0.77, kd=0.6, blur=0.6):
    """(T,) the profile [grey levels of linear light] across a limb at t = 0 (t (T,) [px],
    outwards): ``ambient + kd max(0, k sin psi + lamp cos psi)`` on the shaft (a lamp's
    sideways component lamp along the edge's outward normal), the background level beyond,
    integrated over 1 px pixels and blurred by a Gaussian of sd blur [px]."""
    fine = np.arange(-14.0, 12.0, 0.01)
    psi = np.arccos(np.clip(1.0 + fine / _W, -1.0, 1.0))
    shaft = ambient + kd * np.clip(_K * np.sin(psi) + lamp * np.cos(psi), 0.0, None)
    y = np.convolve(np.where(fine > 0, background, shaft), np.ones(100) / 100, mode="same")
    g = np.exp(-0.5 * (np.arange(-400, 401) * 0.01 / blur) ** 2)
    y = np.convolve(y, g / g.sum(), mode="same")
    return 255.0 * np.interp(t, fine, y)


def _best(t, y, lateral):
    fits = [fit_limb_profile(t, y, _W, e0, 1.0, sin_view=_K, lateral=lateral) for e0 in (0.0, 1.5)]
    return min((f for f in fits if f.ok), key=lambda f: f.rms)


@pytest.mark.parametrize("lamp,ambient", [(0.3, 0.1), (0.3, 0.0), (-0.3, 0.04), (0.0, 0.1)])
def test_a_lamp_beside_the_camera_is_modelled(lamp, ambient):
    t = np.arange(-0.7 * _W, 7.0, 0.25)
    y = _lamp_profile(t, lamp, ambient)
    side = _best(t, y, True)
    assert abs(side.edge) < 0.03 and side.coef.shape == (5,), side
    assert side.rms < 0.1
    # judged as light, it explains the profile better than a step
    A = limb_design(t, side.edge, side.sigma, _W, side.roughness, _K, 0.0, True)
    c = side.coef if is_light(A, side.coef) else shading_lstsq(A, y)
    r = A @ c - y
    assert limb_explains(float(r @ r), fit_step_profile(t, y, 0.0, 1.0)[2], t.size)


def test_the_light_at_the_camera_misses_a_lit_side():
    """The model without the lamp's term: a limb lit from the side with an ambient floor is
    placed 0.08 px in and fitted 15 times worse."""
    t = np.arange(-0.7 * _W, 7.0, 0.25)
    y = _lamp_profile(t, 0.3, 0.1)
    at, side = _best(t, y, False), _best(t, y, True)
    assert abs(at.edge) > 0.05 and at.rms > 5 * side.rms, (at, side)


def test_the_sideways_term_keeps_shading_light():
    """`shading_lstsq` with the lamp's term: the diffuse and specular terms held non-negative,
    the sideways one of either sign."""
    from scipy.optimize import lsq_linear

    t = np.arange(-12.0, 7.0, 0.25)
    A = limb_design(t, 0.2, 0.8, 40.0, 0.3, lateral=True)
    rng = np.random.default_rng(0)
    y = A @ [36.0, -0.3, -20.0, 120.0, -15.0] + rng.normal(0, 0.2, t.size)
    c = shading_lstsq(A, y)
    best = lsq_linear(A, y, bounds=([-np.inf, -np.inf, 0, 0, -np.inf], np.inf), tol=1e-12).x
    assert c.shape == (5,) and c[2] >= 0 and c[3] >= 0 and np.allclose(c, best, atol=1e-6)

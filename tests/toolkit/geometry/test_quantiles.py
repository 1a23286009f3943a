"""The chi-square tails and quantiles of the gates agree with scipy's to 1e-10 relative,
over the degrees of freedom and probabilities the gates use and far beyond them."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.special import chdtrc, chdtri

from pencilcal.toolkit.geometry.quantiles import chi2_isf, chi2_sf, median

DOFS = [0.1, 0.5, 1, 2, 2.5, 3, 4, 5, 7, 10, 17, 30, 61, 150, 1000, 20000]
PROBS = [1e-300, 1e-100, 1e-12, 1e-6, 0.001, 0.01, 0.05, 0.3173, 0.5, 0.7, 0.9, 0.999, 1 - 1e-9]


@pytest.mark.parametrize("dof", DOFS)
def test_quantiles_and_tails_agree_with_scipy(dof):
    for p in PROBS:
        x = chdtri(dof, p)
        assert chi2_isf(p, dof) == pytest.approx(x, rel=1e-10), (dof, p)
        assert chi2_sf(x, dof) == pytest.approx(chdtrc(dof, x), rel=1e-10), (dof, x)


def test_arrays_broadcast_and_the_ends():
    dof = np.array([1.0, 3.0, 12.0])
    assert np.allclose(chi2_isf(0.01, dof), chdtri(dof, 0.01), rtol=1e-10)
    assert np.allclose(chi2_sf([[1.0], [9.0]], dof), chdtrc(dof, np.array([[1.0], [9.0]])), rtol=1e-10)
    assert chi2_isf(0.0, 3) == np.inf and chi2_isf(1.0, 3) == 0.0
    assert chi2_sf(0.0, 3) == 1.0 and chi2_sf(np.inf, 3) == 0.0


def test_no_scipy_for_one_and_two_degrees_of_freedom():
    # the per-frame gates must not import scipy.special (half a second of start-up)
    import subprocess
    import sys

    code = ("import sys; from pencilcal.toolkit.geometry.quantiles import chi2_isf, chi2_sf; "
            "chi2_isf(0.01, 1); chi2_isf(0.01, 2); chi2_sf(3.0, 2); chi2_isf(0.01, 5); chi2_sf(4.0, 7); "
            "print('scipy.special' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_median_is_numpys_bit_for_bit():
    rng = np.random.default_rng(5)
    for trial in range(3000):
        n = int(rng.integers(1, 2000)) if trial % 2 else int(rng.integers(1, 30))
        kind = trial % 4
        x = {0: rng.normal(size=n), 1: rng.integers(0, 5, n).astype(float), 2: rng.standard_cauchy(n) + 1e5,
             3: np.where(rng.random(n) < 0.02, np.nan, rng.normal(size=n))}[kind]
        x = x.astype((np.float32, np.float64)[trial % 3 == 0])
        got, want = median(x), np.median(x)
        assert type(got) is type(want) and (got.tobytes() == want.tobytes() or (np.isnan(got) and np.isnan(want)))
    assert median(np.arange(7)) == 3.0 and np.isnan(median(np.zeros(0, np.float32)))


def test_nanmedian_rows_is_numpys_bit_for_bit():
    # rows of a few to 40 values with NaNs (none to all), infinities and ties, in batches
    import warnings

    from pencilcal.toolkit.geometry.quantiles import nanmedian_rows

    rng = np.random.default_rng(6)
    for _ in range(3000):
        shape = tuple(rng.integers(1, 4, rng.integers(0, 3))) + (int(rng.integers(1, 40)),)
        a = rng.normal(size=shape) * 10 ** rng.uniform(-5, 5)
        a[rng.random(shape) < rng.uniform(0, 1)] = np.nan
        a[rng.random(shape) < 0.03] = np.inf
        a[rng.random(shape) < 0.03] = -np.inf
        if rng.random() < 0.3:
            a = np.round(a)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows
            want = np.nanmedian(a, -1)
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # no warning of its own
            got = nanmedian_rows(a)
        assert got.shape == want.shape and np.array_equal(got, want, equal_nan=True)

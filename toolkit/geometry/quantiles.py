"""Chi-square tails and quantiles for the gates, with the standard library alone; and the
median of a sample, as np.median gives it, at a fraction of its cost.

Every gate of pencilcal is a chi-square quantile or tail: a squared z (1 dof), a 2-D
point's Mahalanobis distance (2 dof), a fit's residual sum. scipy's `scipy.special.chdtri`
and `chdtrc` give them, but importing scipy.special costs a command half a second or more
(it pulls numpy.f2py and scipy's array-API layer): most of a live run's first frame. One and
two degrees of freedom have closed forms; any other count is the regularised incomplete
gamma function (series below a + 1, Lentz's continued fraction above, as in Numerical
Recipes), inverted by safeguarded Newton steps from the Wilson-Hilferty guess. Agreement
with scipy: 1e-10 relative or better (tests/toolkit/geometry/test_quantiles.py).

`median` is np.median's value of a float sample, bit for bit (the same two middle order
statistics, averaged in the sample's precision as np.median does), from one partition where
np.median makes three (its middle two and the largest, for its NaN check), and from a sort
for the small samples whose cost np.median's overhead is: the shaft detector takes dozens of
medians a frame, of a few to 60 thousand values. `nanmedian_rows` is np.nanmedian's along the
last axis of small float64 arrays, bit for bit, from one sort: np.nanmedian takes small
arrays through masked arrays, ~40 numpy calls (a tenth of a millisecond and more) a call.

Example
-------
>>> round(chi2_isf(0.05, 1), 4), round(chi2_isf(0.05, 2), 4), round(chi2_isf(0.05, 3), 4)
(3.8415, 5.9915, 7.8147)
>>> round(chi2_sf(7.8147, 3), 4)
0.05
"""
from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np

__all__ = ["chi2_isf", "chi2_sf", "median", "nanmedian_rows"]

_NORMAL = NormalDist()
_SORT_BELOW = 256  # samples up to this size are sorted (`median`)
_EPS = 1e-15
_TINY = 1e-300


def _gamma_log_tails(a, x):
    """The logarithms (ln P(a, x), ln Q(a, x)) of the regularised incomplete gamma
    functions, a > 0, x > 0: the one that is computed (the series of P below a + 1, the
    continued fraction of Q above) is accurate to its own last digits however small it is,
    the other comes from its complement."""
    log_front = -x + a * math.log(x) - math.lgamma(a)
    if x < a + 1.0:  # the series of P converges fast here
        term = total = 1.0 / a
        n = a
        for _ in range(10000):
            n += 1.0
            term *= x / n
            total += term
            if abs(term) < abs(total) * _EPS:
                break
        lp = min(0.0, log_front + math.log(total))
        return lp, math.log1p(-math.exp(lp)) if lp < 0.0 else -math.inf
    # Lentz's continued fraction of Q
    b = x + 1.0 - a
    c = 1.0 / _TINY
    d = 1.0 / b
    h = d
    for i in range(1, 10000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = _TINY if abs(d) < _TINY else d
        c = b + an / c
        c = _TINY if abs(c) < _TINY else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < _EPS:
            break
    lq = min(0.0, log_front + math.log(h))
    return (math.log1p(-math.exp(lq)) if lq < 0.0 else -math.inf), lq


def _elementwise(fn):
    """fn of scalars, applied element by element to arrays (broadcast), a float for scalars."""
    vec = np.vectorize(fn, otypes=[float])

    def apply(u, dof):
        if np.ndim(u) == 0 and np.ndim(dof) == 0:
            return fn(float(u), float(dof))
        return vec(np.asarray(u, float), np.asarray(dof, float))

    apply.__name__, apply.__doc__ = fn.__name__.lstrip("_"), fn.__doc__
    return apply


def _chi2_sf(x, dof):
    """The probability that a chi-square variable with `dof` (> 0) degrees of freedom exceeds
    x (upper tail), as `scipy.special.chdtrc(dof, x)`.

    Arrays broadcast (a float for scalars).

    >>> abs(chi2_sf(3.841458820694124, 1) - 0.05) < 1e-12, chi2_sf(0.0, 4)
    (True, 1.0)
    """
    x, dof = float(x), float(dof)
    if not x > 0.0:
        return 1.0
    if math.isinf(x):
        return 0.0
    if dof == 2.0:
        return math.exp(-0.5 * x)
    return math.exp(_gamma_log_tails(0.5 * dof, 0.5 * x)[1])


def _chi2_isf(p, dof):
    """The value a chi-square variable with `dof` (> 0) degrees of freedom exceeds with
    probability p (upper tail), as `scipy.special.chdtri(dof, p)`.

    dof 1: z^2 with z the normal quantile of 1 - p / 2 (Wichura's algorithm); dof 2: -2 ln p
    (the exponential law); otherwise Newton steps on `chi2_sf`, kept inside a bracket.

    Arrays broadcast (a float for scalars).

    >>> abs(chi2_isf(0.01, 1) - 6.634896601021214) < 1e-10, chi2_isf(0.05, [1, 2]).round(4).tolist()
    (True, [3.8415, 5.9915])
    """
    p, dof = float(p), float(dof)
    if not 0.0 < p < 1.0:
        return math.inf if p <= 0.0 else 0.0
    if dof == 1.0:
        return _NORMAL.inv_cdf(0.5 * p) ** 2  # the lower tail's z: exact for small p
    if dof == 2.0:
        return -2.0 * math.log(p)
    a = 0.5 * dof
    upper = p <= 0.5  # Newton on the log of the smaller tail, computed to its last digits
    log_target = math.log(p) if upper else math.log1p(-p)
    if upper:
        z = -_NORMAL.inv_cdf(p)
        k = 2.0 / (9.0 * dof)
        x = dof * max(1.0 - k + z * math.sqrt(k), 0.1) ** 3  # Wilson-Hilferty
    else:  # P(a, x / 2) ~ (x / 2)^a / Gamma(a + 1) for small x
        x = 2.0 * math.exp((log_target + math.lgamma(a + 1.0)) / a)
    lo, hi = 0.0, math.inf
    log_norm = a * math.log(2.0) + math.lgamma(a)
    for _ in range(200):
        lp, lq = _gamma_log_tails(a, 0.5 * x)
        g = (lq if upper else lp) - log_target
        below = g > 0 if upper else g < 0  # x lies below the quantile
        if below:
            lo = x
        else:
            hi = x
        log_pdf = (a - 1.0) * math.log(x) - 0.5 * x - log_norm
        # d ln Q / dx = -pdf / Q, d ln P / dx = pdf / P
        new = x + g * math.exp(lq - log_pdf) if upper else x - g * math.exp(lp - log_pdf)
        if not lo < new < hi:  # Newton left the bracket: bisect (in logs), or grow
            if lo > 0 and math.isfinite(hi):
                new = math.exp(0.5 * (math.log(lo) + math.log(hi)))
            else:
                new = 0.5 * hi if math.isfinite(hi) else 2.0 * x
        if abs(new - x) <= 1e-14 * x:
            return new
        x = new
    return x


chi2_sf = _elementwise(_chi2_sf)
chi2_isf = _elementwise(_chi2_isf)


def median(a):
    """np.median(a) (all elements) of a float32 or float64 array: the same value and type
    (module docstring); NaN where a holds one. Other dtypes, and an empty a, go to np.median.

    >>> x = np.random.default_rng(0).normal(size=1001).astype(np.float32)
    >>> [bool(median(v) == np.median(v)) for v in (x, x[:1000], x[:9], x[:8])], float(median(np.array([1.0, np.nan])))
    ([True, True, True, True], nan)
    """
    a = np.asarray(a).reshape(-1)
    n = a.size
    if n == 0 or a.dtype not in (np.float32, np.float64):
        return np.median(a)
    h = n // 2
    if n <= _SORT_BELOW:
        srt = np.sort(a)
        hi, top = srt[h], srt[-1]
        lo = srt[h - 1] if n % 2 == 0 else hi
    else:  # NaN sorts last: any lies among the upper part
        part = np.partition(a, h)
        hi, top = part[h], part[h:].max()
        lo = part[:h].max() if n % 2 == 0 else hi
    if np.isnan(top):
        return a.dtype.type(np.nan)
    # np.median's mean of its middle ones: their sum in the sample's precision, over the count
    return hi if n % 2 else (lo + hi) / a.dtype.type(2)


def nanmedian_rows(a):
    """np.nanmedian(a, axis=-1) of a float64 array (..., n), n >= 1: the same values (the
    median of each row's non-NaN values, the mean of its middle two in float64 as
    np.nanmedian's small-array path takes it; NaN for a row of NaNs), from one sort. Meant
    for small rows: every row is sorted whole.

    >>> a = np.array([[3.0, np.nan, 1.0, 2.0], [np.nan] * 4, [4.0, 1.0, 3.0, 2.0]])
    >>> nanmedian_rows(a).tolist()
    [2.0, nan, 2.5]
    """
    a = np.asarray(a, float)
    srt = np.sort(a, -1)  # NaN sorts last
    k = np.count_nonzero(~np.isnan(a), -1)[..., None]
    h = k // 2
    lo = np.take_along_axis(srt, np.maximum(np.where(k % 2 == 1, h, h - 1), 0), -1)[..., 0]
    hi = np.take_along_axis(srt, np.minimum(h, a.shape[-1] - 1), -1)[..., 0]
    with np.errstate(invalid="ignore"):  # inf + -inf in a row: NaN, as np.nanmedian's
        return np.where(k[..., 0] > 0, (lo + hi) / 2.0, np.nan)

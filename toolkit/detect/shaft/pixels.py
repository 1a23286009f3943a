"""How instrument-like each pixel of a colour frame is: a small learned model of colour and
local texture, the shaft detector's pixel cue.

Hand-made colour cues break on the next hospital's video: measured on the masked real sources,
the direction in which a single cue (darkness, texture, uniformity along the band) tells
instruments from tissue flips from one source to the next. What holds everywhere is a
combination: instruments are achromatic relative to the scene (grey metal, black plastic),
smooth where tissue is textured or specular where it is matte, and unlike the frame's dominant
colour. `PixelModel` learns that combination from masked frames: a one-hidden-layer perceptron
(tanh) on `FEATURES`, each measured relative to the frame's own median so that white balance,
exposure and the tissue's hue drop out:

- the opponent chromaticity ``x = (R - G) / S``, ``y = (R + G - 2 B) / (sqrt(3) S)``, ``S = R + G
  + B + 3 eps`` (eps = 10 % of the median brightness: black pixels keep little colour), as its
  magnitude over the median magnitude (`chroma`), and along and across the frame's median
  chromaticity (`along`, `across`);
- the log brightness over the median's (`log_luma`);
- the local spread of log brightness and of chroma, and the local mean chroma, over 5 and 15
  work pixels;
- the gradient magnitude of log brightness; the density of specular pixels (the brightest 2 %).

The model runs on the work frame (`shaft.work.WorkFrame`) of `WORK_PX` on its longer side, the
scale its texture features were learned at. `default_model` is the one the package ships
(trained on every masked real source the project has; how, and its leave-one-source-out scores,
in docs/method.md); a lab can train its own on its own annotated frames
(`validation.shaft_training`) and pass it in.

Example
-------
>>> import numpy as np
>>> img = np.zeros((90, 160, 3), np.uint8); img[:] = (60, 80, 170); img[40:50] = 90   # grey band on red
>>> F = pixel_features(img, np.ones(img.shape[:2], bool))
>>> F.shape, [round(float(v), 1) for v in F[20, 80, :2]], [round(float(v), 1) for v in F[45, 80, :2]]
((90, 160, 12), [1.0, 1.0], [0.0, 0.0])
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.quantiles import median

__all__ = ["FEATURES", "WORK_PX", "pixel_features", "pixel_features_at", "expanded_inputs", "PixelModel", "default_model",
           "instrument_probability", "instrument_probability_at"]

#: The pixel features, in the order `pixel_features` stacks them (module docstring).
FEATURES = ("chroma", "along", "across", "log_luma", "luma_sd5", "chroma_mean5", "chroma_sd5", "luma_sd15",
            "chroma_mean15", "chroma_sd15", "luma_gradient", "specular")
#: The work frame's longer side the model runs at [px].
WORK_PX = 320.0
_DARK_EPS = 0.1  # eps of the chromaticity as a fraction of the median brightness
_SPECULAR_PCT = 98.0  # specular: brighter than this percentile of the valid pixels
_MODEL_FILE = Path(__file__).with_name("instrument_pixels.json")


def _local_sd(a, k):
    import cv2

    m = cv2.blur(a, (k, k))
    return np.sqrt(np.maximum(cv2.blur(a * a, (k, k)) - m * m, 0.0)), m


def _hist_quantiles(hist, qs):
    """np.percentile's quantiles qs (in [0, 1], linear interpolation) of the non-negative
    integers whose histogram is hist (the same values, from the counts)."""
    cum = np.cumsum(np.asarray(hist, np.float64).reshape(-1))
    n = int(round(cum[-1]))
    vi = (n - 1) * np.asarray(qs, float)
    lo = np.floor(vi)
    k = np.stack([lo, np.minimum(lo + 1, n - 1)])
    a, b = np.searchsorted(cum, k + 1, side="left").astype(float)  # the k-th smallest: cum first exceeds k
    return a, b, vi - lo


def _lerp(a, b, t):
    """np.percentile's interpolation between neighbouring order statistics."""
    return np.where(t >= 0.5, b - (b - a) * (1 - t), a + (b - a) * t)


def _frame_levels(F, Y3, v, levels8, u8=None):
    """The median (3,) of each channel of F (h, w, 3) float32 over the pixels v, and the
    median and `_SPECULAR_PCT` percentile there of the mean Y = Y3 / 3 (Y3 = B + G + R;
    float32, as the features compute it): from histograms where the channels hold 8-bit
    levels (levels8; the same values at a fraction of the cost of partitions; u8: the 8-bit
    frame F is the float copy of, whose histograms are the same at a quarter of the cost),
    else by np.percentile."""
    import cv2

    third = np.float32(1.0 / 3.0)
    if not levels8:
        Y = Y3 * third
        return (np.array([np.median(F[..., ch][v]) for ch in range(F.shape[-1])], np.float32),
                *(float(q) for q in np.percentile(Y[v], [50.0, _SPECULAR_PCT])))
    mask = v.astype(np.uint8)
    src = F if u8 is None else u8
    med = []
    for ch in range(F.shape[-1]):
        a, b, t = _hist_quantiles(cv2.calcHist([src], [ch], mask, [256], [0, 256]), [0.5])
        med.append(_lerp(a, b, t)[0])
    # Y3 sums three 8-bit levels, exactly in float32; its quantiles are mapped to Y as Y is
    # computed, so that a threshold on an order statistic is that value itself
    a, b, t = _hist_quantiles(cv2.calcHist([Y3], [0], mask, [766], [0, 766]), [0.5, _SPECULAR_PCT / 100.0])
    qa, qb = ((x.astype(np.float32) * third).astype(float) for x in (a, b))
    y_med, y_spec = _lerp(qa, qb, t)
    return np.array(med, np.float32), float(y_med), float(y_spec)


def _features(bgr, valid, at=None):
    """The pixel features (module docstring) of a BGR image (h, w, 3) (or grey (h, w)):
    of every pixel (h, w, F), or only of the pixels at = (rows, cols) (M,) each (M, F), F =
    len(FEATURES): the frame's medians and the local windows are the same either way, the
    per-pixel terms are computed where asked."""
    import cv2

    levels8 = np.asarray(bgr).dtype == np.uint8
    F = np.array(bgr, np.float32)
    v = np.asarray(valid, bool)
    if np.count_nonzero(v) < 16:
        v = np.ones(v.shape, bool)
    if F.ndim == 2:
        F = np.repeat(F[..., None], 3, -1)
    # outside the valid region (a field stop's black, letterbox bars) the frame's median
    # colour: the local windows near the boundary see the scene, not the black around it
    B, G, R = F[..., 0], F[..., 1], F[..., 2]
    fill, y_med, y_spec = _frame_levels(F, B + G + R, v, levels8, bgr if levels8 and np.ndim(bgr) == 3 else None)
    F[~v] = fill
    Y = (B + G + R) * np.float32(1.0 / 3.0)
    y_med = max(y_med, 1.0)
    S = R + G + B + np.float32(3.0 * max(_DARK_EPS * y_med, 1.0))
    x = (R - G) / S
    y = (R + G - 2.0 * B) / (np.float32(np.sqrt(3.0)) * S)
    mx, my = float(median(x[v])), float(median(y[v]))
    cm = float(np.hypot(mx, my)) + 1e-3
    u = np.array([mx, my]) / cm
    c = (np.hypot(x, y) / cm).astype(np.float32)
    ly = (np.log1p(Y) - np.float32(np.log1p(y_med))).astype(np.float32)

    def pick(a):
        return a if at is None else a[at]

    xa, ya = pick(x), pick(y)
    along = ((xa * u[0] + ya * u[1]) / cm).astype(np.float32)
    across = ((-xa * u[1] + ya * u[0]) / cm).astype(np.float32)
    feats = [pick(c), along, across, pick(ly)]
    for k in (5, 15):
        ls, _ = _local_sd(ly, k)
        cs, cmean = _local_sd(c, k)
        feats += [pick(ls), pick(cmean), pick(cs)]
    gx = cv2.Sobel(ly, cv2.CV_32F, 1, 0)
    gy = cv2.Sobel(ly, cv2.CV_32F, 0, 1)
    feats.append(np.hypot(pick(gx), pick(gy)))
    spec = (Y > y_spec).astype(np.float32)
    feats.append(pick(cv2.blur(spec, (9, 9))))
    return np.stack(feats, -1)


def pixel_features(bgr, valid):
    """The pixel features (module docstring) of a BGR image.

    bgr: (h, w, 3) uint8 or float; valid: (h, w) bool, the pixels the frame's medians are taken
    over. Returns (h, w, len(FEATURES)) float32.
    """
    return _features(bgr, valid)


def pixel_features_at(bgr, valid, rows, cols):
    """`pixel_features` (M, len(FEATURES)) float32 of the pixels (rows, cols) (M,) int only:
    the same values (the frame's medians and local windows as for the whole image), without
    the per-pixel terms of the pixels not asked for."""
    return _features(bgr, valid, (np.asarray(rows, np.intp), np.asarray(cols, np.intp)))


def expanded_inputs(X):
    """The model's inputs (N, F + 5): the features, the squares of the first four and the
    chroma-brightness product (the curvature one hidden layer of a few units lacks)."""
    return np.concatenate([X, X[:, :4] ** 2, X[:, [0]] * X[:, [3]]], 1)


@dataclass(frozen=True, eq=False)
class PixelModel:
    """A one-hidden-layer perceptron on the pixel features: p = sigmoid(w2 . tanh(W1^T z + b1)
    + b2), z the standardised expanded features ((x - mu) / sd).

    Attributes
    ----------
    mu, sd : (D,)
        Standardisation of the expanded features.
    W1 : (D, H); b1 : (H,); w2 : (H,); b2 : float
        The weights.
    trained_on : tuple of str
        The sources it was trained on (names, for the record).
    """

    mu: np.ndarray
    sd: np.ndarray
    W1: np.ndarray
    b1: np.ndarray
    w2: np.ndarray
    b2: float
    trained_on: tuple = ()

    def probability(self, features):
        """p (...,) in [0, 1] of features (..., len(FEATURES))."""
        X = np.asarray(features, np.float32)
        shape = X.shape[:-1]
        Z = (expanded_inputs(X.reshape(-1, X.shape[-1])) - self.mu) / self.sd
        z = np.tanh(Z @ self.W1 + self.b1) @ self.w2 + self.b2
        return (1.0 / (1.0 + np.exp(-np.clip(z, -40, 40)))).astype(np.float32).reshape(shape)

    def to_dict(self) -> dict:
        return {"kind": "pencilcal instrument pixel model", "version": 1, "features": list(FEATURES),
                "trained_on": list(self.trained_on), "mu": self.mu.tolist(), "sd": self.sd.tolist(),
                "W1": self.W1.tolist(), "b1": self.b1.tolist(), "w2": self.w2.tolist(), "b2": float(self.b2)}

    @classmethod
    def from_dict(cls, d, where="pixel model"):
        """The model of a `to_dict` record (InputError naming `where` when it is not one)."""
        try:
            if list(d["features"]) != list(FEATURES):
                raise InputError(f"{where}: made for features {d['features']}, this pencilcal uses {list(FEATURES)}")
            m = cls(mu=np.asarray(d["mu"], float), sd=np.asarray(d["sd"], float), W1=np.asarray(d["W1"], float),
                    b1=np.asarray(d["b1"], float), w2=np.asarray(d["w2"], float), b2=float(d["b2"]),
                    trained_on=tuple(d.get("trained_on", ())))
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"{where}: not a pencilcal pixel model ({e})") from None
        D, H = m.W1.shape if m.W1.ndim == 2 else (-1, -1)
        if not (m.mu.shape == m.sd.shape == (D,) and m.b1.shape == m.w2.shape == (H,) and D == len(FEATURES) + 5):
            raise InputError(f"{where}: inconsistent weight shapes")
        if not all(np.all(np.isfinite(a)) for a in (m.mu, m.sd, m.W1, m.b1, m.w2)) or np.any(m.sd <= 0):
            raise InputError(f"{where}: weights must be finite and sd positive")
        return m


_DEFAULT = None


def default_model() -> PixelModel:
    """The model the package ships (module docstring)."""
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = PixelModel.from_dict(json.loads(_MODEL_FILE.read_text()), str(_MODEL_FILE))
    return _DEFAULT


def instrument_probability(work, model=None):
    """p (h, w) float32 of each pixel of a work frame (`shaft.work.WorkFrame`, BGR) being
    instrument; 0 outside its valid region. model: a `PixelModel` (default `default_model`)."""
    model = default_model() if model is None else model
    valid = work.valid & (work.dist > 1.0)
    p = model.probability(pixel_features(work.bgr, valid))
    return np.where(work.valid, p, 0.0).astype(np.float32)


def instrument_probability_at(work, rows, cols, model=None):
    """`instrument_probability` (M,) float32 of the work frame's pixels (rows, cols) (M,)
    int only: the same values, the model evaluated at those pixels alone."""
    model = default_model() if model is None else model
    valid = work.valid & (work.dist > 1.0)
    rows, cols = np.asarray(rows, np.intp), np.asarray(cols, np.intp)
    p = model.probability(pixel_features_at(work.bgr, valid, rows, cols))
    return np.where(work.valid[rows, cols], p, 0.0).astype(np.float32)

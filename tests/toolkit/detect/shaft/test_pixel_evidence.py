"""The pixel evidence of detected bands (toolkit/detect/shaft/pixel_evidence.py) and its hook
in detect_shafts; the per-fold training (validation/shaft_training.py)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from pencilcal.toolkit.detect.shaft.detector import detect_shafts
from pencilcal.toolkit.detect.shaft.pixel_evidence import MIN_PIXEL_EVIDENCE, pixel_evidence
from pencilcal.toolkit.errors import InputError


def _frame(seed=0):
    """A grey shaft from the left border over textured red tissue, 640x360."""
    rng = np.random.default_rng(seed)
    img = np.zeros((360, 640, 3), np.float32)
    img[:] = (60, 80, 170)
    img += cv2.GaussianBlur(rng.normal(0, 12, img.shape).astype(np.float32), (0, 0), 3.0)
    cv2.fillConvexPoly(img, np.array([[0, 150], [430, 160], [430, 205], [0, 215]]), (92, 95, 98))
    img = cv2.GaussianBlur(img, (0, 0), 1.0) + rng.normal(0, 2, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def test_instrument_band_above_tissue_band():
    img = _frame()
    on = {"midline": [0.0, 182.0, 420.0, 182.0], "width_px": 50.0}
    off = {"midline": [0.0, 60.0, 420.0, 60.0], "width_px": 50.0}
    ev = pixel_evidence(img, [on, off])
    assert ev[0] >= MIN_PIXEL_EVIDENCE > ev[1], ev


def test_records_and_shafts_alike_and_grey_refused():
    img = _frame()
    shafts = detect_shafts(img, pixel_evidence=None)
    assert shafts
    ev = pixel_evidence(img, shafts)
    np.testing.assert_allclose(ev, pixel_evidence(img, [s.to_dict() for s in shafts]))
    assert pixel_evidence(img, []).shape == (0,)
    with pytest.raises(InputError, match="colour"):
        pixel_evidence(img[..., 0], shafts)


def test_detect_shafts_hook():
    img = _frame()
    kept = detect_shafts(img)                                    # the shipped least evidence
    assert len(kept) == len(detect_shafts(img, pixel_evidence=None)) >= 1
    assert detect_shafts(img, pixel_evidence=1.01) == []        # none can reach it
    grey = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)                  # a grey frame is not judged
    assert len(detect_shafts(grey, pixel_evidence=1.01)) == len(detect_shafts(grey, pixel_evidence=None))


def test_fold_models_leave_out_each_source_and_pair():
    from pencilcal.validation.shaft_training import fold_models, pixel_samples

    img = _frame()
    m = np.zeros(img.shape[:2], bool)
    cv2.fillConvexPoly(m.view(np.uint8), np.array([[0, 150], [430, 160], [430, 205], [0, 215]]), 1)
    X, y = pixel_samples(img, m, samples_per_frame=200)
    samples = {k: [(X, y)] for k in "abcd"}
    models = fold_models(samples, hidden=2, maxiter=20)
    assert len(models) == 4 + 6
    assert set(models[frozenset("ab")].trained_on) == {"c", "d"}
    assert set(models[frozenset("c")].trained_on) == {"a", "b", "d"}

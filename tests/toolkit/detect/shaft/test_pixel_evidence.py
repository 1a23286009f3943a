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
    # none can reach it: without the tissue colour, the evidence alone decides; with it, a
    # dark band greyer than the tissue is kept whatever its evidence (`shaft.grey_material`)
    assert detect_shafts(img, pixel_evidence=1.01, tissue_colour=None) == []
    assert len(detect_shafts(img, pixel_evidence=1.01)) == sum(s.polarity == "dark" for s in kept)
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


def _whole_map_evidence(img, shafts, region=None):
    """The evidence as first computed: the map over the whole work frame, then its samples."""
    from pencilcal.toolkit.detect.shaft.pixel_evidence import band_evidence
    from pencilcal.toolkit.detect.shaft.pixels import WORK_PX, instrument_probability
    from pencilcal.toolkit.detect.shaft.work import Validity, WorkFrame

    work = WorkFrame(img, None, Validity(region, img.shape[:2]), WORK_PX)
    return band_evidence(instrument_probability(work), work, None, np.array([s.midline for s in shafts]),
                         np.array([s.width_px for s in shafts]))


def test_evidence_at_the_samples_equals_the_whole_map():
    """The map evaluated only where the bands' samples read it gives the evidence of the
    whole map (synthetic bands across the frame, some leaving it, and the detected ones)."""
    from pencilcal.toolkit.detect.shaft.detector import Shaft

    img = _frame(3)
    shafts = detect_shafts(img, pixel_evidence=None)
    rng = np.random.default_rng(1)
    for _ in range(12):  # bands anywhere, of any width, partly outside the frame
        a, b = rng.uniform([-100, -60], [740, 420], (2, 2))
        shafts.append(Shaft(midline=np.r_[a, b], width_px=float(rng.uniform(4, 120)), angle_sigma=0.0,
                            offset_sigma=0.0, edges=np.zeros((2, 4)), score=1.0, ideal_midline=np.r_[a, b],
                            convergence_deg=0.0, polarity="dark"))
    np.testing.assert_allclose(pixel_evidence(img, shafts), _whole_map_evidence(img, shafts), atol=1e-6)


def test_features_at_pixels_and_frame_levels():
    """pixel_features_at is pixel_features at those pixels, and the frame's medians and
    specular threshold from histograms are np.percentile's, for 8-bit and float frames (a
    valid region that leaves part of the frame out, odd and even pixel counts)."""
    from pencilcal.toolkit.detect.shaft.pixels import pixel_features, pixel_features_at

    img = _frame(4)[:180, :320]
    valid = np.ones(img.shape[:2], bool)
    valid[:, :20] = False
    rows, cols = np.nonzero(np.random.default_rng(2).random(valid.shape) < 0.1)
    for frame in (img, img.astype(np.float32) + 0.25):
        for v in (valid, valid & (np.arange(320) != 300)[None, :], np.ones_like(valid)):
            whole = pixel_features(frame, v)
            np.testing.assert_array_equal(pixel_features_at(frame, v, rows, cols), whole[rows, cols])
    # the histogram route (8-bit) against the partition route on the same levels
    v = valid & (np.arange(320) != 300)[None, :]
    np.testing.assert_allclose(pixel_features(img, v), pixel_features(img.astype(np.float32), v), atol=1e-5)


def test_evidence_equals_the_whole_map_on_real_frames():
    """On the real hysterectomy frames (every detection, before judging), the evidence at the
    samples is the whole map's to 1e-6 (the shipped least evidence keeps the same bands)."""
    from pencilcal.toolkit.detect.region.detect import detect_valid_region
    from tests.conftest import data_dir

    root = data_dir("real-instruments") / "laparoscopy-hysterectomy-frames"
    n = 0
    for path in sorted(root.glob("*.jpg"))[::3]:
        img = cv2.imread(str(path))
        region = detect_valid_region([img])
        shafts = detect_shafts(img, valid_region=region, pixel_evidence=None)
        if shafts:
            n += len(shafts)
            np.testing.assert_allclose(pixel_evidence(img, shafts, valid_region=region),
                                       _whole_map_evidence(img, shafts, region), atol=1e-6)
    assert n >= 3

"""The tissue colour of detected bands (toolkit/detect/shaft/tissue_colour.py) and its hook in
detect_shafts: a dark gap between two tissues keeps their colour, an instrument does not."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from pencilcal.toolkit.detect.shaft.detector import detect_shafts
from pencilcal.toolkit.detect.shaft.tissue_colour import MAX_TISSUE_COLOUR, shaft_tissue_colour, tissue_colour
from pencilcal.toolkit.errors import InputError

_FAT, _BOWEL = np.array([40.0, 150.0, 190.0]), np.array([120.0, 130.0, 200.0])  # BGR


def _shade(bgr, k):
    """BGR values of a surface k times as lit, through a 2.2 power law (as stored)."""
    return 255.0 * (k * (np.asarray(bgr) / 255.0) ** 2.2) ** (1 / 2.2)


def _frame(gap=True, seed=0):
    """Fat above, bowel below (most of the view), 640x360, textured, blurred and JPEG-compressed; between them a
    dark gap whose colour is the bowel's deepened (gap=True) or a black shaft (gap=False), from
    the left border."""
    rng = np.random.default_rng(seed)
    img = np.zeros((360, 640, 3), np.float32)
    img[:120], img[120:] = _FAT, _BOWEL
    img *= 1 + cv2.GaussianBlur(rng.normal(0, 0.15, img.shape[:2]).astype(np.float32), (0, 0), 2.0)[..., None]
    if gap:  # the cavity's colour: the bowel's chromaticity twice as saturated, at a tenth of its light
        deep = np.array([70.0, 110.0, 235.0])
        inside = _shade(deep, 0.02)
    else:
        inside = np.array([22.0, 22.0, 23.0])
    cv2.fillConvexPoly(img, np.array([[0, 110], [600, 120], [600, 160], [0, 166]]), tuple(float(v) for v in inside))
    img = cv2.GaussianBlur(img, (0, 0), 1.2) + rng.normal(0, 1.5, img.shape)
    ok, buf = cv2.imencode(".jpg", np.clip(img, 0, 255).astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 85])
    return cv2.imdecode(buf, cv2.IMREAD_COLOR)


def test_gap_over_the_bound_instruments_under_it():
    band = np.array([[0.0, 138.0, 580.0, 140.0]])
    gap = tissue_colour(_frame(gap=True), band, [44.0])[0]
    black = tissue_colour(_frame(gap=False), band, [44.0])[0]
    assert gap > 1.5 * MAX_TISSUE_COLOUR and black < 0.5, (gap, black)
    # a metal shaft mirroring the bowel: half grey, half the bowel's light
    img = _frame(gap=False)
    img[120:160, :600] = np.clip(0.5 * np.array([150.0, 150.0, 150.0]) + 0.5 * _BOWEL, 0, 255).astype(np.uint8)
    assert tissue_colour(img, band, [30.0])[0] < 1.0


def test_shading_does_not_change_it():
    """The chromaticity of a power-law image is that of the light: the gap as dark as it is or
    five times as lit measures alike."""
    img = np.zeros((100, 200, 3), np.uint8)
    img[:] = _BOWEL
    mid = np.array([[0.0, 50.0, 199.0, 50.0]])
    vals = []
    for k in (0.02, 0.1):
        img[40:60] = np.round(_shade([90.0, 125.0, 230.0], k)).astype(np.uint8)
        vals.append(tissue_colour(img, mid, [20.0])[0])
    assert vals[0] == pytest.approx(vals[1], rel=0.1) and vals[0] > MAX_TISSUE_COLOUR


def test_records_shafts_and_refusals():
    img = _frame(gap=False)
    shafts = detect_shafts(img, pixel_evidence=None, tissue_colour=None)
    assert shafts
    np.testing.assert_allclose(shaft_tissue_colour(img, shafts), shaft_tissue_colour(img, [s.to_dict() for s in shafts]))
    assert shaft_tissue_colour(img, []).shape == (0,)
    grey = np.full((50, 80, 3), 120, np.uint8)                    # no tissue hue: no evidence either way
    assert tissue_colour(grey, [[0.0, 25.0, 79.0, 25.0]], [10.0]).tolist() == [0.0]
    with pytest.raises(InputError, match="colour"):
        tissue_colour(img[..., 0], [[0.0, 25.0, 79.0, 25.0]], [10.0])
    with pytest.raises(InputError, match="widths"):
        tissue_colour(img, [[0.0, 25.0, 79.0, 25.0]], [10.0, 3.0])


def test_detect_shafts_hook():
    """The gap is found as a band by the cues, and dropped by its colour; the black shaft in its
    place is kept."""
    gap = _frame(gap=True)
    assert detect_shafts(gap, pixel_evidence=None, tissue_colour=None)
    assert detect_shafts(gap, pixel_evidence=None) == []
    shaft = _frame(gap=False)
    assert len(detect_shafts(shaft, pixel_evidence=None)) == len(detect_shafts(shaft, pixel_evidence=None,
                                                                               tissue_colour=None)) >= 1

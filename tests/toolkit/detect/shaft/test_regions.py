"""The material map's colour (`shaft.regions.material_map`) on a red frame a bright instrument
close to the lens fills a third of: its grey outnumbers any one tissue hue.

The tissue's pixels spread over several hues (red muscle, yellow fat, pink serosa, in patches),
the instrument's sit in one narrow peak near grey, faintly blue (the metal mirrors a cold light):
the chromaticity histogram's mode is the instrument's. The frame still has a colour, and the
instrument is what is least like it.
"""
from __future__ import annotations

import cv2
import numpy as np

from pencilcal.toolkit.detect.shaft.regions import material_map
from pencilcal.toolkit.detect.shaft.work import Validity, WorkFrame

H, W = 360, 640


def _close_instrument_frame(seed, grey=False):
    """(frame (H, W, 3) uint8 BGR, instrument mask (H, W) bool): tissue patches of three hues,
    a bright bluish-grey band across 35 % of the height, blur, noise, JPEG; grey: every
    tissue patch grey too (a colourless scene)."""
    rng = np.random.default_rng(seed)
    hues = np.array([[60, 70, 170], [70, 140, 190], [110, 110, 175]], float)  # BGR: red, fat, pink
    if grey:
        hues = hues.mean(1, keepdims=True).repeat(3, 1)
    labels = cv2.resize(rng.integers(0, 3, (9, 16)).astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST)
    img = hues[labels] * rng.uniform(0.7, 1.2, (H, W, 1))
    img = cv2.GaussianBlur(img, (0, 0), 3.0)
    yy, xx = np.mgrid[0:H, 0:W]
    band = np.abs(yy - 0.5 * H - 0.04 * (xx - 0.5 * W)) < 0.175 * H
    metal = np.array([205.0, 200.0, 198.0]) if not grey else np.full(3, 201.0)
    img[band] = metal * (0.92 + 0.08 * np.sin(xx[band] / 9.0))[:, None]
    img = cv2.GaussianBlur(img, (0, 0), 1.0) + rng.normal(0, 2.0, img.shape)
    _, buf = cv2.imencode(".jpg", np.clip(img, 0, 255).astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 85])
    return cv2.imdecode(buf, cv2.IMREAD_COLOR), band


def test_close_grey_instrument_leaves_the_frame_its_colour():
    for seed in range(3):
        img, band = _close_instrument_frame(seed)
        wf = WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=W)
        mm = material_map(wf)
        assert mm.informative, (seed, mm.tissue, mm.p_med)
        # the tissue's colour is red-orange, not the instrument's grey
        assert np.hypot(*mm.tissue) > 0.1 and mm.tissue[0] > 0 and mm.tissue[1] > 0, mm.tissue
        inner = cv2.erode(band.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
        outer = ~cv2.dilate(band.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
        # the instrument the least like it: its least likeness above the tissue's most (the
        # scale is the tissue's spread of hues, so the levels split them apart)
        assert np.percentile(mm.likeness[inner], 5) > 3.0 * np.percentile(mm.likeness[outer], 99)


def test_grey_scene_stays_without_colour():
    """The coloured pixels' mode is sought only to find the tissue's colour: a grey scene, whose
    few coloured pixels are noise, has none along it."""
    img, _ = _close_instrument_frame(0, grey=True)
    mm = material_map(WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=W))
    assert not mm.informative

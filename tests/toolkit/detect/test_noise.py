"""The noise estimates (toolkit/detect/noise.py): an 8-bit image's from a histogram of its
integer responses, the same value as the float route's."""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.image import GrayImage
from pencilcal.toolkit.detect.noise import estimate_noise, noise_of


def test_eight_bit_route_equals_float_route():
    rng = np.random.default_rng(7)
    for shape, sd in (((120, 200), 3.0), ((121, 201), 0.7), ((700, 900), 5.0)):
        img = np.clip(100 + 40 * np.sin(np.arange(shape[1]) / 17.0)[None, :] + rng.normal(0, sd, shape), 0, 255)
        u8 = img.astype(np.uint8)
        assert estimate_noise(u8) == estimate_noise(u8.astype(np.float32))
        assert abs(estimate_noise(u8) - sd) < 0.25 * sd + 0.3
        # the banded estimate of a large image, 8-bit and float alike
        assert noise_of(GrayImage(u8)) == noise_of(GrayImage(u8.astype(np.float32)))


def test_shaft_robust_noise_eight_bit_equals_float():
    """The material cue's robust noise (toolkit/detect/shaft/material_cue.py) of an 8-bit
    channel: its 90th percentile from counts, the same value as the float route's."""
    from pencilcal.toolkit.detect.shaft.material_cue import robust_noise

    rng = np.random.default_rng(3)
    for shape, sd in (((1080, 1920), 2.0), ((360, 640), 0.5), ((50, 80), 6.0)):
        img = np.clip(90 + 30 * np.cos(np.arange(shape[0]) / 23.0)[:, None] + rng.normal(0, sd, shape), 0, 255)
        u8 = img.astype(np.uint8)
        assert robust_noise(u8) == robust_noise(u8.astype(np.float32))
        assert abs(robust_noise(u8) - max(sd, 0.3)) < 0.3 * sd + 0.3

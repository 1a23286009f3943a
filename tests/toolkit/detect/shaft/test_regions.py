"""The material map's tissue colour (`toolkit.detect.shaft.regions.material_map`) on a frame
that a white shaft close to the lens dominates.

A white or metal shaft near the lens fills a quarter of the view or more with one grey
chromaticity, a sharper peak than the tissue's, whose hues spread over pink, fat and blood:
the mode of the chromaticities was the shaft's. Its faint sheen (here a little blue) then
gave the projection on the "tissue's" direction a negative median, the frame was judged to
have no colour and the material cue was not run (cholecystectomy VID03_000180: the hook's
shaft, 0.3 of the view, none of its three instruments proposed). The tissue's colour is then
sought among the coloured pixels.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from pencilcal.toolkit.detect.shaft.detector import detect_shafts
from pencilcal.toolkit.detect.shaft.regions import material_map
from pencilcal.toolkit.detect.shaft.work import Validity, WorkFrame
from pencilcal.toolkit.synth.tissue import tissue_image

_H, _W = 360, 640
_SLOPE, _Y0 = 0.08, 170.0  # the shaft's axis: y = _Y0 + _SLOPE (x - 320)


def _frame(half_width, seed=0):
    """A frame (H, W, 3) uint8 of tissue whose hue varies over the view (pink, fat, blood,
    with a fine texture), a white shaft 2 x half_width px wide entering from the right with
    a faint blue sheen, blur and noise; and the tissue's own mean chromaticity (2,)."""
    rng = np.random.default_rng(seed)
    lum = np.asarray(tissue_image((_H, _W), seed=seed + 3, color=False), float)[..., 0]
    f = cv2.resize(rng.uniform(0, 1, (2, 6, 2)), (_W, _H), interpolation=cv2.INTER_LINEAR)
    pink, fat, red = np.array([0.30, 0.28, 0.70]), np.array([0.10, 0.45, 0.75]), np.array([0.10, 0.10, 0.55])
    t = (f[..., :1] * pink + (1 - f[..., :1]) * fat) * (0.5 + f[..., 1:]) + 0.3 * (1 - f[..., 1:]) * red
    t *= (lum / lum.mean())[..., None]
    t *= np.exp(0.6 * cv2.GaussianBlur(rng.normal(0, 1, (_H, _W, 3)), (0, 0), 1.0))
    img = 255 * np.clip(t, 0, 1) ** (1 / 2.2)
    B, G, R = img[..., 0], img[..., 1], img[..., 2]
    S = B + G + R + 1e-9
    tissue = np.array([np.median((R - G) / S), np.median((R + G - 2 * B) / (np.sqrt(3) * S))])
    yy, xx = np.mgrid[0:_H, 0:_W].astype(float)
    d = np.abs((yy - _Y0) - _SLOPE * (xx - 320))
    inside = (d < half_width) & (xx > 150)
    level = 225 - 50 * np.clip(d / half_width, 0, 1) ** 2  # shaded across its width
    img = np.where(inside[..., None], np.stack([level + 5, level + 1, level - 3], -1), img)
    img = cv2.GaussianBlur(img, (0, 0), 1.0) + rng.normal(0, 1.5, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8), tissue


@pytest.mark.parametrize("half_width", [60, 80])
def test_tissue_colour_under_a_close_white_shaft(half_width):
    img, tissue = _frame(half_width)
    work = WorkFrame(img, None, Validity(None, img.shape[:2]), 480.0)
    mm = material_map(work)
    # the frame has a colour, the tissue's: its hue within 10 deg of the tissue's mean
    assert mm.informative
    cos = float(mm.tissue @ tissue) / (np.linalg.norm(mm.tissue) * np.linalg.norm(tissue))
    assert np.degrees(np.arccos(min(1.0, cos))) < 10.0
    # and the shaft is a material band along all of its length in view (the edge cue alone,
    # without the colour, read a part of it), on its axis
    shafts = detect_shafts(img)
    assert shafts and shafts[0].cue == "material"
    m = np.asarray(shafts[0].to_dict()["midline"], float)
    ang = np.degrees(np.arctan2(m[3] - m[1], m[2] - m[0]))
    assert min(abs(ang - np.degrees(np.arctan(_SLOPE))) % 180, 180 - abs(ang - np.degrees(np.arctan(_SLOPE))) % 180) < 1.0
    assert abs(m[0] - m[2]) > 400


def test_grey_scene_stays_without_colour():
    """A grey scene has no tissue colour to find, with or without a coloured object in it (a
    lab's paper, table or box trainer's floor; here a fifth of the view a pink patch): the map
    stays uninformative, and the shaft is left to the edge cue."""
    img, _ = _frame(80)
    grey = np.repeat(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)[..., None], 3, -1)
    assert not material_map(WorkFrame(grey, None, Validity(None, grey.shape[:2]), 480.0)).informative
    patch = grey.copy()
    patch[:, :128] = np.clip(patch[:, :128] * np.array([0.7, 0.75, 1.3]), 0, 255).astype(np.uint8)
    assert not material_map(WorkFrame(patch, None, Validity(None, patch.shape[:2]), 480.0)).informative

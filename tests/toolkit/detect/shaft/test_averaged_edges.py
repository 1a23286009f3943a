"""A band's edges fitted along the whole line by a step averaged along it
(`shaft.averaged_edges`): faint edges the fit per station does not find, tracked from a short
run over the whole line and into a vignetted fall-off, and nothing tracked on noise."""
from __future__ import annotations

import cv2
import numpy as np

from pencilcal.toolkit.detect.shaft.averaged_edges import edge_line, tracked_edges
from pencilcal.toolkit.detect.shaft.work import Validity, WorkFrame


def _frame(step, noise, seed, fall=None):
    """A 240 x 320 frame of tissue colour with a vertical shaft at x in [150, 164) from the top
    to y = 170, `step` grey levels darker (times `fall` (240,) along y), blurred, with noise."""
    rng = np.random.default_rng(seed)
    img = np.full((240, 320, 3), (70.0, 80.0, 120.0))
    g = np.ones(240) if fall is None else fall
    img[:170, 150:164] -= step * g[:170, None, None]
    img *= (g[:, None, None] if fall is not None else 1.0)
    img = cv2.GaussianBlur(img, (0, 0), 1.2) + rng.normal(0, noise, img.shape)
    img = np.clip(img, 0, 255).astype(np.uint8)
    return WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=320)


def _run(x):
    return [(np.array([x, 100.0]), np.array([x, 130.0])) for x in (150.0, 164.0)] if x is None else x


def test_faint_edges_tracked_over_their_length():
    """2.5 grey levels in noise 2 (under the noise per pixel): from a 30-px run, both edges
    are found within 0.5 px of the truth (x = 149.5 and 163.5: the steps between pixel
    centres) and along at least 130 of their 170 px."""
    for seed in range(4):
        wf = _frame(2.5, 2.0, seed)
        got = tracked_edges(wf, _run(None))
        assert got is not None
        for e, x in zip((edge_line(wf, got[0]), edge_line(wf, got[1])), (149.5, 163.5)):
            assert abs(e.point_at(e.sm)[0] - x) < 0.5 and abs(e.point_at(e.s_lo)[0] - x) < 1.0
            assert e.s_hi - e.s_lo >= 130.0
            assert np.all(e.ends()[:, 1] <= 175.0)  # not beyond the shaft's end


def test_tracked_into_the_dark():
    """A shaft 12 levels darker in light that falls off to a tenth over the top of the frame:
    from a run in the light (y 130-165) it is followed up to where the step is a third of it."""
    y = np.arange(240.0)
    fall = np.clip(0.1 + 0.9 * y / 160.0, 0.1, 1.0)
    wf = _frame(12.0, 1.5, 0, fall)
    got = tracked_edges(wf, [(np.array([x, 130.0]), np.array([x, 165.0])) for x in (150.0, 164.0)])
    assert got is not None
    for e in (edge_line(wf, got[0]), edge_line(wf, got[1])):
        assert e.ends()[:, 1].min() <= 50.0


def test_nothing_on_noise():
    """No shaft: the run's step is not significant, no edges."""
    for seed in range(4):
        wf = _frame(0.0, 2.0, seed)
        assert tracked_edges(wf, _run(None)) is None

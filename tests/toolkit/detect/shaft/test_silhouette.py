"""The silhouette edge fit samples an 8-bit frame through crops of it (one per group of
nearby edges): the fits equal those on the whole frame converted to float32, bit for bit,
for edges spread over the frame, crossing each other and running off its border."""
from __future__ import annotations

import cv2
import numpy as np

from pencilcal.toolkit.detect.shaft.silhouette import fit_edges
from pencilcal.toolkit.detect.shaft.work import Validity


def _frame():
    rng = np.random.default_rng(3)
    img = np.zeros((360, 640, 3), np.uint8)
    img[:] = (70, 90, 180)
    for (x0, y0, x1, y1, w, c) in [(0, 40, 639, 90, 30, 40), (100, 359, 300, 0, 24, 200), (500, 0, 639, 300, 40, 90)]:
        cv2.line(img, (x0, y0), (x1, y1), (c, c, c + 5), w, cv2.LINE_AA)
    img = cv2.GaussianBlur(img, (0, 0), 1.2)
    return np.clip(img + rng.normal(0, 2.0, img.shape), 0, 255).astype(np.uint8)


def _specs():
    out = []
    for p0, p1 in [((0, 25), (639, 75)), ((0, 55), (639, 105)), ((112, 359), (312, 0)), ((88, 359), (288, 0)),
                   ((480, 0), (639, 290)), ((520, 0), (639, 260)), ((-20, 5), (300, -10))]:
        p0, p1 = np.array(p0, float), np.array(p1, float)
        L = float(np.hypot(*(p1 - p0)))
        u = (p1 - p0) / L
        out.append((p0, u, np.array([-u[1], u[0]]), 15.0, L - 15.0))
    return out


def test_fits_through_crops_equal_the_whole_frame():
    img = _frame()
    val = Validity(None, img.shape[:2])
    specs = _specs()
    for gamma in (1.0, 2.2):
        a = fit_edges(img, None, val, 2.0, specs, 6.0, gamma=gamma)
        b = fit_edges(np.ascontiguousarray(img, np.float32), None, val, 2.0, specs, 6.0, gamma=gamma)
        assert sum(e is not None for e in a) >= 4
        for ea, eb in zip(a, b):
            assert (ea is None) == (eb is None)
            if ea is not None:
                for k, v in vars(ea).items():
                    assert np.array_equal(v, getattr(eb, k)), k

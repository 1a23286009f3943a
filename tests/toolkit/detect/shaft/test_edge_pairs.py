"""Bands between two grey-level edges (`shaft.edge_pairs`): on renders, a dark grey shaft on
dark reddish tissue, blurred, noisy and JPEG-compressed, its edges converging as a close
cylinder's do, is proposed with both edges on its silhouette, and so is a clip applier's outline
(two thin metal limbs, the tissue seen between them: its inside is not one material), its map
the whole band; a band of tissue between two edges (redder inside than its sides: no
instrument) and a band whose far side is outside the view are not."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from pencilcal.toolkit.detect.shaft.edge_pairs import PAIR_MAX_CONVERGENCE_DEG, pair_bands
from pencilcal.toolkit.detect.shaft.regions import material_map
from pencilcal.toolkit.detect.shaft.work import Validity, WorkFrame


class _Disc:
    """A circular field stop of radius r around the image centre (`region.ValidRegion`'s
    interface)."""

    def __init__(self, centre, r):
        self.c, self.r = np.asarray(centre, float), float(r)

    def distance_to_boundary(self, pts):
        return self.r - np.linalg.norm(np.asarray(pts, float) - self.c, axis=-1)

    def covers_image(self, shape):
        return False


def _render(conv_deg, w_mid, inside=(30, 32, 36), seed=0, shape=(240, 320)):
    """A (H, W, 3) frame: dark reddish tissue textured, a band across it along x whose edges
    converge by conv_deg (w_mid px wide at the centre) filled with `inside` (BGR); blurred,
    noisy, JPEG-compressed. Returns the frame and the band's two edges' lines (3,) each
    (a x + b y + c = 0, unit normal)."""
    rng = np.random.default_rng(seed)
    H, W = shape
    img = np.empty((H, W, 3))
    img[:] = (38, 45, 85)
    img += rng.normal(0, 4, (H, W, 1)) * np.array([1, 1, 1.5])
    img = cv2.GaussianBlur(img, (0, 0), 3.0)
    h = np.radians(conv_deg / 2)
    cx, cy = W / 2 - 0.5, H / 2 - 0.5
    lines = []
    for s in (-1, 1):  # y = cy + s (w_mid / 2 + tan(h) (x - cx))
        a, b = s * np.tan(h), -1.0
        c = cy + s * w_mid / 2 - a * cx
        lines.append(np.array([a, b, c]) / np.hypot(a, b))
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    half = w_mid / 2 + np.tan(h) * (xx - cx)
    img[np.abs(yy - cy) <= half] = inside
    img = cv2.GaussianBlur(img, (0, 0), 1.2) + rng.normal(0, 1.5, (H, W, 3))
    _, buf = cv2.imencode(".jpg", np.clip(img, 0, 255).astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 85])
    return cv2.imdecode(buf, cv2.IMREAD_COLOR), lines


def _pairs(img, region=None):
    wf = WorkFrame(img, None, Validity(region, img.shape[:2]), target_px=320)
    mm = material_map(wf)
    lines, pairs, _ = pair_bands(wf, 10.0, 120.0, PAIR_MAX_CONVERGENCE_DEG, mm.luma_noise, 60.0, mm.likeness)
    return lines, pairs


@pytest.mark.parametrize("conv_deg, w_mid, seed", [(0.0, 40.0, 0), (18.0, 80.0, 1), (22.0, 90.0, 2)])
def test_converging_dark_shaft_is_proposed(conv_deg, w_mid, seed):
    img, truth = _render(conv_deg, w_mid, seed=seed)
    lines, pairs = _pairs(img)
    assert len(pairs.i) >= 1

    def on(k, ln):  # both ends of line k within 2 px of the true edge ln
        ends = [lines.p[k] + t * lines.u[k] for t in (lines.lo[k], lines.hi[k])]
        return all(abs(ln[:2] @ e + ln[2]) <= 2.0 for e in ends)

    # the best pair is the silhouette: one line on each true edge
    i, j = pairs.i[0], pairs.j[0]
    assert (on(i, truth[0]) and on(j, truth[1])) or (on(i, truth[1]) and on(j, truth[0]))


def test_tissue_band_is_not_proposed():
    # a redder band than the tissue around it: two long edges, but tissue inside
    img, _ = _render(0.0, 40.0, inside=(30, 40, 120))
    _, pairs = _pairs(img)
    assert len(pairs.i) == 0


def test_band_beside_the_field_stop_is_not_proposed():
    # the shaft runs along the field stop: the strip beyond its far edge is outside the view
    img, truth = _render(0.0, 40.0, shape=(240, 320))
    stop = _Disc((159.5, 119.5 + 20.0 + 400.0), 400.0)  # its boundary runs along the lower edge
    img[stop.distance_to_boundary(np.stack(np.mgrid[0:240, 0:320][::-1], -1).astype(float)) < 0] = 0
    _, pairs = _pairs(img, stop)
    assert len(pairs.i) == 0


@pytest.mark.parametrize("seed", [0, 1])
def test_outline_of_two_limbs_is_proposed(seed):
    # a clip applier: two bright metal limbs 7 px wide, 44 px apart outside, the tissue seen
    # through the slot between them; the inside is tissue, the rims metal
    img, truth = _render(0.0, 44.0, inside=(200, 205, 210), seed=seed)
    slot, _ = _render(0.0, 30.0, inside=(38, 45, 85), seed=seed)  # the tissue alone
    H, W = img.shape[:2]
    yy = np.mgrid[0:H, 0:W][0]
    middle = np.abs(yy - (H / 2 - 0.5)) <= 12
    img[middle] = slot[middle]
    wf = WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=320)
    mm = material_map(wf)
    lines, pairs, maps = pair_bands(wf, 10.0, 120.0, PAIR_MAX_CONVERGENCE_DEG, mm.luma_noise, 60.0, mm.likeness)

    def on(k, ln):
        ends = [lines.p[k] + t * lines.u[k] for t in (lines.lo[k], lines.hi[k])]
        return all(abs(ln[:2] @ e + ln[2]) <= 2.0 for e in ends)

    outer = [q for q in range(len(pairs.i)) if (on(pairs.i[q], truth[0]) and on(pairs.j[q], truth[1]))
             or (on(pairs.i[q], truth[1]) and on(pairs.j[q], truth[0]))]
    assert outer, "no pair on the outline"
    # its map is the band between the outer edges, the slot included, nothing beyond
    B = maps[outer[0]]
    assert B[H // 2, W // 2] and B[H // 2 - 18, W // 2] and B[H // 2 + 18, W // 2]
    assert not B[H // 2 - 30, W // 2] and not B[H // 2 + 30, W // 2]


def test_given_candidates_give_the_same_bands():
    """pair_bands on the candidates the caller made (`candidate_pairs` of the same segments)
    returns what it returns from the segments: the same lines, pairs and maps."""
    from pencilcal.toolkit.detect.shaft.edge_pairs import candidate_pairs, edge_segments

    img, _ = _render(18.0, 80.0, seed=1)
    wf = WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=320)
    mm = material_map(wf)
    args = (wf, 10.0, 120.0, PAIR_MAX_CONVERGENCE_DEG, mm.luma_noise, 60.0, mm.likeness)
    seg = edge_segments(wf, 60.0)
    a = pair_bands(*args, segments=seg)
    b = pair_bands(*args, candidates=candidate_pairs(seg, 10.0, 120.0, PAIR_MAX_CONVERGENCE_DEG, 60.0))
    assert len(a[1].i) >= 1
    for f in ("p", "u", "lo", "hi"):
        assert np.array_equal(getattr(a[0], f), getattr(b[0], f))
    for f in ("i", "j", "width", "overlap"):
        assert np.array_equal(getattr(a[1], f), getattr(b[1], f))
    assert all(np.array_equal(x, y) for x, y in zip(a[2], b[2])) and len(a[2]) == len(b[2])

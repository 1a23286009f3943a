"""The shaft detector's work frame: its shared reductions are OpenCV's INTER_AREA bit for bit."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.detect.shaft.work import Reductions, Validity, WorkFrame, grid_map


@pytest.mark.parametrize("factor", range(1, 19))
@pytest.mark.parametrize("channels", [None, 1, 3])
def test_reductions_equal_inter_area(factor, channels):
    # every factor, the exact-sum path (even factors 4-16) and cv2.resize itself (the rest);
    # uniform noise over all 256 levels makes every rounding tie occur
    rng = np.random.default_rng(factor)
    shape = (factor * 13, factor * 17) + (() if channels is None else (channels,))
    img = rng.integers(0, 256, shape, dtype=np.uint8)
    got = Reductions(img).to(17, 13)
    ref = img if factor == 1 else cv2.resize(img, (17, 13), interpolation=cv2.INTER_AREA)
    assert got.dtype == ref.dtype and np.array_equal(got, ref)


def test_reductions_shared_and_other_sizes():
    """One image's reductions to several sizes, in any order, each as cv2.resize gives it;
    sizes that are no even multiple (and float images) go to cv2.resize."""
    rng = np.random.default_rng(7)
    img = rng.integers(0, 256, (1080, 1920, 3), dtype=np.uint8)
    r = Reductions(img)
    for w, h in ((320, 180), (480, 270), (640, 360), (240, 135), (500, 281)):
        assert np.array_equal(r.to(w, h), cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)), (w, h)
    f = img[:64, :96].astype(np.float32) / 3
    assert np.array_equal(Reductions(f).to(24, 16), cv2.resize(f, (24, 16), interpolation=cv2.INTER_AREA))


def test_work_frames_sharing_reductions_are_the_same():
    rng = np.random.default_rng(3)
    img = cv2.GaussianBlur(rng.integers(0, 256, (540, 960, 3), dtype=np.uint8), (0, 0), 2.0)
    v = Validity(None, img.shape[:2])
    a = WorkFrame(img, None, v, 480)
    b = WorkFrame(img, None, v, 320, reductions=a.reductions)
    c = WorkFrame(img, None, v, 320)
    assert np.array_equal(b.bgr, c.bgr) and np.array_equal(b.dist, c.dist) and b.reductions is a.reductions


def test_grid_distance_is_the_points_distance():
    # a work frame without a lens takes its distances from the grid, separably where there
    # is no region: the same values as of every point
    from pencilcal.toolkit.detect.region.valid import ValidRegion

    xs, ys = np.linspace(-3.0, 643.0, 57), np.linspace(-2.0, 361.0, 31)
    pts = np.stack(np.broadcast_arrays(xs[None, :], ys[:, None]), -1)
    for region in (None, ValidRegion.from_circle(320.0, 180.0, 170.0, 640, 360)):
        v = Validity(region, (360, 640))
        assert np.array_equal(v.grid_distance(xs, ys), v.distance(pts))


def test_grid_map_reads_each_pixel_at_its_own_point():
    """A map sampled on a coarse grid is read at every pixel's own position: exact for an
    affine map, within 0.01 px of a barrel lens's own at every pixel (a resize of the node
    grid reads pixel x at (x + 0.5) / step - 0.5 of the grid: 1.5 px off at step 4); NaN
    exactly where a lost node has weight."""
    H, W = 483, 857                                                    # no multiple of the step
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    px = np.stack([xx, yy], -1)
    affine = np.array([[0.37, 0.02], [-0.01, 0.375]])
    for step in (4.0, 8.0):
        got = grid_map(lambda p: p @ affine.T + [3.0, -2.0], (H, W), step)
        np.testing.assert_allclose(got, px @ affine.T + [3.0, -2.0], atol=1e-4)
    cam = Camera("opencv", W, H, [[770.0, 0, 428.0], [0, 770.0, 241.0], [0, 0, 1]], [-0.25, 0.08, 0.001, -0.001, 0.0])
    got = grid_map(cam.undistort_pixels, (H, W), 4.0)
    assert np.max(np.abs(got - cam.undistort_pixels(px))) < 0.01
    # a node lost (beyond a model's reach): NaN over the pixels it weighs on, none beyond
    lost = lambda p: np.where(((p[..., :1] == 40) & (p[..., 1:] == 20)), np.nan, p)
    nan = np.isnan(grid_map(lost, (H, W), 4.0)[..., 0])
    assert np.array_equal(nan, (np.abs(xx - 40) < 4) & (np.abs(yy - 20) < 4))


@pytest.mark.parametrize("size", [(1080, 1920), (360, 640), (481, 853), (100, 37)])
@pytest.mark.parametrize("target", [480.0, 320.0, 97.0])
def test_work_frame_distance_from_the_border_factors(size, target):
    """Without a lens or a region a work frame's distance map is formed from the border's two
    factors (`Validity.border_distances`) in one pass: the same float32 values as the grid's
    distance scaled and converted (what it was formed from before)."""
    img = np.zeros(size + (3,), np.uint8)
    v = Validity(None, size)
    wf = WorkFrame(img, None, v, target)
    h, w = wf.shape
    xs = wf.to_ideal(np.stack([np.arange(w), np.zeros(w)], -1))[:, 0]
    ys = wf.to_ideal(np.stack([np.zeros(h), np.arange(h)], -1))[:, 1]
    dx, dy = v.border_distances(xs, ys)
    assert np.array_equal(np.minimum(dx[None, :], dy[:, None]), v.grid_distance(xs, ys))
    d = v.grid_distance(xs, ys) * float(np.mean(wf.scale))
    assert wf.dist.dtype == np.float32 and np.array_equal(wf.dist, np.where(np.isfinite(d), d, -1.0).astype(np.float32))
    assert v.border_distances(np.r_[xs, np.nan], ys) is None

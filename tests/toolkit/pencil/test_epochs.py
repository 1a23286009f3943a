"""Pivot epochs (toolkit/pencil/epochs.py): the change-point test on a sequence's lines.

Lines are drawn with the fulcrum's noise model (an angle error about the segment's centre
and an offset across it), through one point per epoch; the Monte Carlo tests measure the
false split rate without a move (sigmas right, and 1.5x too small as the detector's are on
real frames) and the moves found.
"""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.pencil.epochs import ALPHA, distinct_lines, f2_sf, split_epochs

SD_DEG, OFF_PX = 0.5, 0.5


def fan(rng, vertex, n, spread_deg=30.0, sd_deg=SD_DEG, off_px=OFF_PX, near=(200.0, 600.0), outliers=0,
        direction=None):
    """(n, 4) segments [px] through `vertex`, 100-300 px long, starting 200-600 px from it,
    within spread_deg of one direction (random, or `direction` [rad]), with angle noise
    sd_deg about their centre and offset noise off_px across; the last `outliers` of them
    random lines instead."""
    a0 = rng.uniform(0, np.pi) if direction is None else direction
    a = np.radians(rng.uniform(-spread_deg / 2, spread_deg / 2, n)) + a0
    r0, L = rng.uniform(*near, n)[:, None], rng.uniform(100.0, 300.0, n)[:, None]
    d = np.stack([np.cos(a), np.sin(a)], -1)
    c = np.asarray(vertex, float) + (r0 + 0.5 * L) * d
    da = np.radians(sd_deg) * rng.standard_normal(n)
    u = np.stack([np.cos(a + da), np.sin(a + da)], -1)
    c = c + off_px * rng.standard_normal(n)[:, None] * np.stack([-u[:, 1], u[:, 0]], -1)
    s = np.concatenate([c - 0.5 * L * u, c + 0.5 * L * u], -1)
    if outliers:
        p = rng.uniform(-800, 800, (outliers, 2))
        q = p + rng.uniform(100, 300, (outliers, 1)) * np.stack([np.cos(t := rng.uniform(0, np.pi, outliers)),
                                                                  np.sin(t)], -1)
        s[-outliers:] = np.concatenate([p, q], -1)
    return s


def split(segs, scale=1.0):
    n = segs.shape[0]
    return split_epochs(segs, np.radians(SD_DEG) * scale, OFF_PX * scale, np.arange(n), n)


def test_f2_sf_is_the_f_distribution():
    from scipy.stats import f

    for F, nu in [(0.5, 3), (4.2, 12), (20.0, 40)]:
        assert f2_sf(F, nu) == pytest.approx(f.sf(F, 2, nu), rel=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("true_scale,near", [(1.0, (200.0, 600.0)), (1.5, (200.0, 600.0)), (1.5, (1000.0, 1500.0))])
def test_no_move_no_split(true_scale, near):
    """One fulcrum, 20 frames: the false split rate is at most alpha (0.01) with the lines'
    sigmas right and 1.5x too small (the test then takes the noise the residuals show), and
    with the point far off the lines (nearly parallel ones). Measured: 0 of 150 each."""
    rng = np.random.default_rng(int(10 * true_scale + near[0]))
    n_trials, splits = 60, 0
    for _ in range(n_trials):
        segs = fan(rng, (0.0, 0.0), 20, spread_deg=30.0 if near[0] < 1000 else 8.0, sd_deg=SD_DEG * true_scale,
                   off_px=OFF_PX * true_scale, near=near)
        splits += len(split(segs).bounds) > 1
    print(f"false splits {splits}/{n_trials}")
    assert splits <= 1  # P(>= 2 of 60 | rate 0.01) = 0.12: a rate above alpha shows as more


@pytest.mark.slow
def test_a_moved_fulcrum_is_found():
    """20 frames, the fulcrum moved by 60 px after the 10th, in a random direction: each
    epoch's point has sd 1.3 px across its lines and 9 px along them (10 lines within 30
    deg), so the move is 4.7 sd of the two points' difference (RMS). Measured: found in
    32 of 40 trials, 27 at the right frame (the others within a frame or two); 40 px (3.1
    sd): about half (the price of the robust cost and of trying every frame)."""
    rng = np.random.default_rng(3)
    found, at = 0, 0
    for _ in range(40):
        a = rng.uniform(0, 2 * np.pi)
        segs = np.concatenate([fan(rng, (0.0, 0.0), 10), fan(rng, (60.0 * np.cos(a), 60.0 * np.sin(a)), 10)])
        ep = split(segs)
        found += len(ep.bounds) == 2
        at += len(ep.bounds) == 2 and ep.changes[0].index == 10
    print(f"found {found}/40, {at} at the right frame")
    assert found >= 30
    assert at >= 25


def test_moved_and_back_with_outliers():
    """An arm re-set and set back (three epochs, the first and last with one fulcrum, 150 px
    from the second across the lines) and a sixth of the lines random: the segment is found
    (the circular alternative), the outliers make no epoch."""
    rng = np.random.default_rng(7)
    A, B = (0.0, 0.0), (0.0, 150.0)
    order = np.r_[0:5, 10:12, 5:10]  # the random lines inside each epoch, not at its ends
    segs = np.concatenate([fan(rng, p, 12, outliers=2, direction=0.0)[order] for p in (A, B, A)])
    ep = split(segs)
    assert ep.bounds == [(0, 12), (12, 24), (24, 36)]
    assert {c.partner for c in ep.changes} == {12, 24}
    assert all(c.p_corrected < ALPHA for c in ep.changes)


def test_frames_without_lines_stay_with_the_frames_before():
    """Frames 8, 9 have no line: the new epoch starts at the first frame with one (10). (The
    lines point along x, the fulcrum moves 150 px across them.)"""
    rng = np.random.default_rng(1)
    segs = np.concatenate([fan(rng, (0.0, 0.0), 8, direction=0.0), fan(rng, (0.0, 150.0), 10, direction=0.0)])
    frame_of = np.r_[np.arange(8), np.arange(10, 20)]
    ep = split_epochs(segs, np.radians(SD_DEG), OFF_PX, frame_of, 20)
    assert ep.bounds == [(0, 10), (10, 20)]
    assert ep.epoch_of(9) == 0 and ep.epoch_of(10) == 1


def test_too_few_frames_are_one_epoch():
    """Fewer than twice min_frames frames with a line: nothing to test, one epoch, the run
    kept with no p-value."""
    rng = np.random.default_rng(2)
    segs = np.concatenate([fan(rng, (0.0, 0.0), 3), fan(rng, (150.0, 0.0), 4)])
    ep = split(segs)
    assert ep.bounds == [(0, 7)] and ep.kept == [(0, 7, None)]


def test_a_move_at_infinity():
    """Parallel lines (a port at infinity) turning by 3 deg: one epoch each side."""
    rng = np.random.default_rng(5)
    segs = []
    for k, ang in enumerate([0.0] * 10 + [3.0] * 10):
        a = np.radians(ang + SD_DEG * rng.standard_normal())
        u = np.array([np.cos(a), np.sin(a)])
        c = np.array([0.0, 40.0 * k])
        segs.append(np.r_[c - 100 * u, c + 100 * u])
    assert split(np.array(segs)).bounds == [(0, 10), (10, 20)]


def test_distinct_lines_keeps_one_of_a_repeated_line():
    """A band of tissue found in five frames is one line; lines of different frames that
    differ beyond their noise all stay."""
    rng = np.random.default_rng(4)
    segs = fan(rng, (0.0, 0.0), 6)
    band = np.repeat([[300.0, 500.0, 600.0, 520.0]], 5, 0) + rng.normal(0, 0.2, (5, 4))
    allsegs = np.concatenate([segs, band])
    keep = distinct_lines(allsegs, np.radians(SD_DEG), OFF_PX, np.r_[np.arange(6), np.arange(6, 11)])
    assert keep[:6].all() and keep[6:].sum() == 1


def test_bad_inputs():
    segs = np.zeros((3, 4))
    with pytest.raises(InputError, match="frame_of"):
        split_epochs(segs, 0.01, 0.5, [0, 1, 5], 3)
    with pytest.raises(InputError, match="min_frames"):
        split_epochs(segs, 0.01, 0.5, [0, 1, 2], 3, min_frames=2)
    with pytest.raises(InputError, match="alpha"):
        split_epochs(segs, 0.01, 0.5, [0, 1, 2], 3, alpha=1.5)

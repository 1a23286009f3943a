"""Printed bars from frame to frame: `bars.find_bars` with a prior and `bar_track.BarTracker`."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.detect.bar_track import BarTracker
from pencilcal.toolkit.detect.bars import find_bars
from pencilcal.toolkit.errors import InputError


@pytest.fixture(scope="module")
def sweep():
    """Rendered frames of a tilt sweep at 1280x720, 2 deg a frame (the bars move by up to
    ~5 px), and a frame far along it (30 deg on: every bar elsewhere)."""
    from pencilcal.toolkit.synth.scenarios import make_scenario

    sc = make_scenario("tilt-sweep", frames=40, seed=3, size=(1280, 720))
    return sc.camera, [sc.render(i) for i in range(12, 18)], sc.render(30)


def _angle_z(a, b):
    """|angle difference| of each of a's midlines and the one of b's nearest to it over a's
    angle sd (lines, so modulo pi), and how far a's centre lies off b's line [px] (their
    extents may differ: the ends are located on their own)."""
    ca = 0.5 * (a.ideal[:, :2] + a.ideal[:, 2:])
    cb = 0.5 * (b.ideal[:, :2] + b.ideal[:, 2:])
    j = np.argmin(np.linalg.norm(ca[:, None] - cb[None], axis=-1), 1)
    d = (a.angle - b.angle[j] + np.pi / 2) % np.pi - np.pi / 2
    u = np.stack([np.cos(b.angle[j]), np.sin(b.angle[j])], -1)
    r = ca - b.ideal[j, :2]
    off = np.abs(u[:, 0] * r[:, 1] - u[:, 1] * r[:, 0])
    return np.abs(d) / a.angle_sigma, off


def _spokes(camera, bars):
    """The bars that are the fan's spokes (as `orient` keeps them for the next frame)."""
    from pencilcal.toolkit.pencil.orient import orient_segments
    from pencilcal.toolkit.synth.scenarios import make_scenario

    pencil = make_scenario("tilt-sweep", frames=2, seed=3, size=(1280, 720)).sheet.pencil
    rec = orient_segments(camera, bars.segments, pencil, bar_width_px=bars.width_px)
    return bars.select(np.asarray(rec.spokes) >= 0)


def test_a_prior_finds_the_same_bars_measured_alike(sweep):
    camera, frames, _ = sweep
    prev, polarity = find_bars(frames[0], camera=camera, polarity="either")
    prev = _spokes(camera, prev)
    assert polarity == "dark" and len(prev) == 8
    for img in frames[1:]:
        full, _ = find_bars(img, camera=camera, polarity="dark")
        tracked, pol = find_bars(img, camera=camera, polarity="dark", prior=prev.edges)
        assert pol == "dark" and len(tracked) == len(prev)
        # the same edges from other stations along them: measurement noise, no more
        z, dist = _angle_z(tracked, full)
        assert np.all(dist < 0.5) and np.all(z < 2.5) and np.sqrt(np.mean(z**2)) < 1.0, z
        prev = tracked


def test_bars_that_moved_far_are_not_found_from_the_prior(sweep):
    camera, frames, far = sweep
    prev, _ = find_bars(frames[0], camera=camera, polarity="dark")
    assert len(find_bars(far, camera=camera, polarity="dark", prior=prev.edges)[0]) < len(prev) // 2


def test_a_prior_needs_its_polarity(sweep):
    camera, frames, _ = sweep
    with pytest.raises(InputError, match="polarity"):
        find_bars(frames[0], camera=camera, polarity="either", prior=np.zeros((2, 2, 4)))


def test_the_tracker_detects_in_full_first_when_lost_and_every_nth_frame(sweep):
    camera, frames, far = sweep
    tracker = BarTracker(redetect_frames=3)
    seen = []
    for img in frames:
        bars, tracked = tracker(img, camera=camera, polarity="either")
        seen.append(tracked)
        if not tracked:
            tracker.keep(np.ones(len(bars), bool), used=len(bars))
    # full, tracked, tracked, full, ...: the polarity found in full is kept
    assert seen == [False, True, True, False, True, True] and tracker.tracked == 4
    assert tracker.full_used >= 8
    tracker.lost()
    assert tracker.tracked == 3
    bars, tracked = tracker(far, camera=camera, polarity="either")
    assert tracked is False
    # another frame size: in full
    tracker.keep(np.ones(len(bars), bool))
    small = frames[0][::2, ::2]
    assert tracker(small, polarity="either")[1] is False

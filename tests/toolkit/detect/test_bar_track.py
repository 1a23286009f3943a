"""Printed bars from frame to frame: `bars.find_bars` with a prior and `bar_track.BarTracker`."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.detect.bar_track import BarTracker, region_of
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


def test_the_tracker_detects_first_then_tracks_and_falls_back_region_then_whole_frame(sweep):
    camera, frames, far = sweep
    tracker = BarTracker(redetect_frames=4)
    seen = []
    for img in frames:
        bars, tracked = tracker(img, camera=camera, polarity="either")
        seen.append(tracker.last_mode)
        tracker.keep(np.ones(len(bars), bool), used=len(bars))
    # a whole-frame detection first, then one in the region around it (no velocity known
    # yet), and every 4th frame one in the region around the prediction
    assert seen == ["full", "region", "track", "track", "track", "region"]
    assert tracker.tracked == 3 and tracker.regional == 2 and tracker.full_used >= 8
    # a frame the prediction misses: the region around it first, then the whole frame
    bars, tracked = tracker(far, camera=camera, polarity="either")
    assert tracked is True and tracker.lost() is True
    tracker(far, camera=camera, polarity="either")
    assert tracker.last_mode == "region" and tracker.lost() is True
    bars, tracked = tracker(far, camera=camera, polarity="either")
    assert tracker.last_mode == "full" and not tracked and len(bars) >= 8
    assert tracker.lost() is False  # nothing more to try on this frame
    # another frame size: in full
    small = frames[0][::2, ::2]
    tracker(small, polarity="either")
    assert tracker.last_mode == "full"


def test_the_region_proposes_in_part_of_the_frame_and_measures_alike(sweep):
    camera, frames, _ = sweep
    spokes = _spokes(camera, find_bars(frames[1], camera=camera, polarity="dark")[0])
    roi = region_of(spokes.edges, frames[1].shape, pad_px=8.0)
    assert (roi[2] - roi[0]) * (roi[3] - roi[1]) < 0.5 * frames[1].size
    part, _ = find_bars(frames[1], camera=camera, polarity="dark", roi=roi)
    # every spoke found again, measured alike (the refit sees the whole frame either way; its
    # stations start from other proposals: measurement noise, no more)
    z, dist = _angle_z(spokes, part)
    assert len(spokes) == 8 and np.all(dist < 0.05) and np.all(z < 2.5) and np.sqrt(np.mean(z**2)) < 1.0
    # nothing in a corner of the frame
    assert len(find_bars(frames[1], camera=camera, polarity="dark", roi=(0, 0, 200, 150))[0]) == 0


def test_the_tracker_follows_a_hand_held_target_at_twice_the_issue_speed():
    """A hand-held camera (1280x720, the fan's centre up to 11 px a frame, its in-plane
    angle 6 deg, its tilt 2 deg a frame): after the first two frames, every one tracked,
    its tilt within 0.1 deg of the truth."""
    from pencilcal.toolkit.pencil.orient import orient_segments
    from pencilcal.toolkit.synth.scenarios import make_scenario

    sc = make_scenario("handheld", frames=10, seed=5, size=(1280, 720), speed=2.0, distance=250.0)
    tracker = BarTracker()
    modes = []
    for i in range(len(sc)):
        img = sc.render(i, background="plain", blur_px=1.0)
        bars, _ = tracker(img, camera=sc.camera, polarity="dark")
        rec = orient_segments(sc.camera, bars.segments, sc.sheet.pencil, bar_width_px=bars.width_px)
        assert rec.ok and rec.lines_used >= 6 and abs(rec.tilt_deg - sc.frames[i]["tilt_deg"]) < 0.1
        modes.append(tracker.last_mode)
        tracker.keep(np.asarray(rec.spokes) >= 0, used=rec.lines_used)
    assert modes == ["full", "region"] + ["track"] * 8

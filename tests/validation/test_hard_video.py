"""The hard hand-held video (`bench_video.hard_handheld_frames`): seeded, and as hard as promised."""
from __future__ import annotations

import numpy as np

from pencilcal.validation.bench_video import hard_handheld_frames


def test_hard_video_is_seeded_frame_by_frame():
    # a frame rendered alone is the same frame as in the whole video (the draws of the frames
    # skipped are still made), and another seed is another video
    cam, pencil, full, tilts, info = hard_handheld_frames(3, seed=5, size=(480, 270))
    _, _, one, tilts1, info1 = hard_handheld_frames(3, seed=5, size=(480, 270), only={2})
    assert one[0] is None and np.array_equal(one[2], full[2])
    assert tilts1 == tilts and info1 == info
    other = hard_handheld_frames(3, seed=6, size=(480, 270), only={2})[2][2]
    assert not np.array_equal(other, full[2])
    assert full[2].shape == (270, 480) and full[2].dtype == np.uint8


def test_hard_video_has_what_it_promises():
    # over 120 frames: 2-3x swings, a hand, auto-exposure steps, defocus drift, JPEG 50-75
    _, _, images, tilts, info = hard_handheld_frames(120, seed=1, size=(480, 270), only=set())
    speed = np.array([f["speed"] for f in info])
    gain = np.array([f["exposure"] for f in info])
    blur = np.array([f["blur_px"] for f in info])
    q = np.array([f["jpeg_quality"] for f in info])
    assert all(im is None for im in images) and len(tilts) == 120
    assert np.any((speed >= 2.0) & (speed <= 3.0)) and np.mean(speed > 1.0) < 0.4
    assert sum(f["hand"] is not None for f in info) >= 4
    assert np.ptp(gain) > 0.05 and np.all((blur >= 1.0 - 1e-9) & (blur <= 2.5 + 1e-9)) and np.ptp(blur) > 0.5
    assert np.all((q >= 50) & (q <= 75)) and 150.0 <= info[0]["distance_mm"] <= 400.0
    assert 3.0 <= info[0]["noise"] <= 6.0 and 0.5 <= info[0]["exposure_time"] <= 1.0
    assert 5.0 < min(tilts) and max(tilts) < 65.0

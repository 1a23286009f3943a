"""orient_video_frame: a video frame's fit with its rolling shutter handled, as orient's CLI does it."""
import numpy as np

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.pencil.shutter import deskewed_segments, orient_video_frame, seen_lines
from pencilcal.toolkit.pencil.spec import Pencil
from pencilcal.toolkit.pencil.track import orient_tracked, prior_labels

CAM = Camera("pinhole", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
PEN = Pencil(np.radians(np.arange(6) * 30.0))


def _fan(turn_deg, squash=0.8):
    # a tilted fan (squashed along y) turning about its vertex: its lines move across their spokes
    th = np.radians(np.arange(6) * 30.0 + turn_deg)
    c, s = np.cos(th), squash * np.sin(th)
    n = np.hypot(c, s)
    c, s = c / n, s / n
    return np.c_[319.5 + 40 * c, 239.5 + 40 * s, 319.5 + 200 * c, 239.5 + 200 * s]


def test_the_readout_decides_what_is_done_to_a_moving_frame():
    first, _ = orient_video_frame(CAM, _fan(3.0), PEN, None, readout=None)
    assert first.ok and first.tilt_sigma_shutter_deg is None  # no previous frame: nothing widened
    seg = _fan(7.0)
    still, _ = orient_video_frame(CAM, seg, PEN, first, readout=0.0)
    unknown, _ = orient_video_frame(CAM, seg, PEN, first, readout=None)
    known, _ = orient_video_frame(CAM, seg, PEN, first, readout=0.6)
    assert still.ok and unknown.ok and known.ok
    # not known: the global shutter's estimate, its sigmas widened by the shear's rms
    np.testing.assert_array_equal(unknown.normal, still.normal)
    assert unknown.tilt_sigma_shutter_deg > 0
    assert unknown.tilt_sigma_deg > still.tilt_sigma_deg
    # known: the lines moved back to the vertex's row, so the estimate itself changes
    assert not np.allclose(known.normal, still.normal, atol=1e-9, rtol=0)


def test_a_frame_that_did_not_move_keeps_its_sigmas():
    first, _ = orient_video_frame(CAM, _fan(3.0), PEN, None)
    again, _ = orient_video_frame(CAM, _fan(3.0), PEN, first, readout=None)
    still, _ = orient_video_frame(CAM, _fan(3.0), PEN, first, readout=0.0)
    assert again.tilt_sigma_deg == still.tilt_sigma_deg


def test_the_linear_step_widens_as_the_second_fit_where_the_lines_agree():
    # a clean turning fan: every moved line still meets the others, so one linear step of the
    # first fit goes where the second fit goes; the estimate is the plain fit's either way
    first, _ = orient_video_frame(CAM, _fan(3.0), PEN, None)
    out = {}
    for mode in ("refit", "linear"):
        out[mode], _ = orient_video_frame(CAM, _fan(7.0), PEN, first, readout=None, widening=mode)
    refit, linear = out["refit"], out["linear"]
    np.testing.assert_array_equal(linear.normal, refit.normal)
    assert linear.tilt_deg == refit.tilt_deg
    assert linear.normal_sigma_shutter_deg > 0.5
    assert abs(linear.normal_sigma_shutter_deg / refit.normal_sigma_shutter_deg - 1) < 0.05
    # a frame whose lines did not move keeps its sigmas
    again, _ = orient_video_frame(CAM, _fan(3.0), PEN, first, readout=None)
    assert again.tilt_sigma_shutter_deg is None


def test_labels_given_move_and_fit_as_labels_found():
    # a video frame labels its segments by the previous frame once, for the tracked fit and
    # for the widening's moves: the same moves and the same fit to the bit as labelling twice
    first, _ = orient_video_frame(CAM, _fan(3.0), PEN, None)
    seg = _fan(7.0)
    lab = prior_labels(CAM, seg, PEN, first)
    assert np.count_nonzero(lab >= 0) == 6
    seen = seen_lines(CAM, _fan(3.0), first.spokes)
    for kw in ({}, {"seen": seen}):
        found = deskewed_segments(CAM, seg, PEN, first, 0.6, **kw)
        given = deskewed_segments(CAM, seg, PEN, first, 0.6, labels=lab.copy(), **kw)
        for a, b in zip(found, given):
            np.testing.assert_array_equal(a, b)
        assert np.all(found[2] > 0)  # (every labelled line moved, its offset sd widened)
    rec, tracked = orient_tracked(CAM, seg, PEN, first)
    rec2, tracked2 = orient_tracked(CAM, seg, PEN, first, prior_lab=lab)
    assert tracked and tracked2
    np.testing.assert_equal(rec.to_dict(), rec2.to_dict())

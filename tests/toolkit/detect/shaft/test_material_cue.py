"""The material cue's choice of a band among those nested in one instrument: the outermost
edge pair, whatever lies inside (`shaft.material_cue._outermost_first`); and a wide shaft
the border of the view cuts, seen short of its collar (`shaft.material_cue.judge_band`).

A wide grey shaft close to the lens enters the view from its border and is seen along less
than two of its widths. Lit from beside the lens, one limb falls dark (a band of dark grey
along one silhouette) and a specular streak runs along the other half: both limb and streak
bound bands of their own inside the shaft, the dark limb's often with more region evidence
than the whole shaft's. The frame: a tissue backdrop (`synth.tissue`), the shaft composited
with its exact area coverage, then blur, gamma, noise and JPEG (`synth.render.sensor_image`).
The truth is the band's own midline: both silhouettes are straight and parallel.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from pencilcal.toolkit.detect.shaft.detector import detect_shafts
from pencilcal.toolkit.synth.render import sensor_image
from pencilcal.toolkit.synth.tissue import tissue_image

H, W = 480, 640
WIDTH = 120.0  # the shaft's width [px]
TIP_X = 430.0  # where its flat end lies: seen along (640 - 430) / 120 = 1.75 widths
AXIS_Y = 200.0  # the axis' height at the right border [px]
TILT_DEG = -3.0


def short_wide_shaft(seed):
    """(frame (H, W, 3) uint8 BGR, axis line (3,) with unit normal): the shaft over tissue
    (module docstring). Its cross-section from one silhouette (q = 0) to the other (q = 1):
    dark at q = 0 (8 % of its grey) rising to its grey by q = 0.3, a specular streak at
    q = 0.62, 25 % darker towards q = 1."""
    rng = np.random.default_rng(seed)
    backdrop = np.array(tissue_image((H, W), seed=seed), float)
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    t = np.radians(TILT_DEG)
    u, n = np.array([np.cos(t), np.sin(t)]), np.array([-np.sin(t), np.cos(t)])
    along = (xx - W) * u[0] + (yy - AXIS_Y) * u[1]
    across = (xx - W) * n[0] + (yy - AXIS_Y) * n[1]
    cover = np.clip(0.5 * WIDTH - np.abs(across) + 0.5, 0, 1) * np.clip(along - (TIP_X - W) + 0.5, 0, 1)
    q = across / WIDTH + 0.5
    shade = np.where(q < 0.3, 0.08 + 0.92 * np.clip(q / 0.3, 0, 1) ** 2, 1.0)
    shade = shade * (1.0 - 0.25 * np.clip((q - 0.8) / 0.2, 0, 1)) + 1.2 * np.exp(-0.5 * ((q - 0.62) / 0.03) ** 2)
    shaft = np.array([0.35, 0.36, 0.40])[None, None, :] * shade[..., None]
    linear = backdrop * (1 - cover[..., None]) + shaft * cover[..., None]
    frame = sensor_image(linear, 0.0, 1.0, 1.5, 2.2, 2.0, rng)
    _, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, 85])
    return cv2.imdecode(buf, cv2.IMREAD_COLOR), np.r_[n, -n @ np.array([W, AXIS_Y])]


def assert_read_once(found, axis, width):
    """One detection, within 1 deg and 2 px of the axis (3,), its width within 4 % of width."""
    assert len(found) == 1, [s.to_dict()["midline"] for s in found]
    d = found[0].to_dict()
    m = np.asarray(d["midline"], float).reshape(2, 2)
    v = (m[1] - m[0]) / np.linalg.norm(m[1] - m[0])
    assert np.degrees(np.arcsin(min(1.0, abs(float(axis[:2] @ v))))) < 1.0
    assert np.max(np.abs(m @ axis[:2] + axis[2])) < 2.0, m
    assert abs(d["width_px"] - width) < 0.04 * width, d["width_px"]


@pytest.mark.parametrize("seed", range(6))
def test_short_wide_shaft_read_between_its_silhouettes(seed):
    """The shaft is read between its two silhouettes, not along its dark limb or its streak:
    one detection, its width within 4 % of the shaft's, its midline within 1 deg and 2 px of
    the axis. Without the outermost pair first the dark limb's band (26 px wide, 47 px off
    the axis) was the reading in 4 of these 6 frames."""
    img, axis = short_wide_shaft(seed)
    assert_read_once(detect_shafts(img), axis, WIDTH)


STUB_WIDTH = 120.0  # a dark shaft entering at the left border [px] ...
STUB_SEEN = 0.8  # ... seen along this many widths to its collar ...
WRIST = (0.6, 1.0)  # ... where a paler wrist of this fraction of its width runs on this many widths
STUB_Y, STUB_TILT_DEG = 260.0, -4.0  # its axis' height at the border [px], its tilt


def border_stub(seed, wrist=True):
    """(frame (H, W, 3) uint8 BGR, axis line (3,) with unit normal): a dark shaft close to
    the lens entering at the left border of the view, seen along `STUB_SEEN` of its widths
    before its collar, with or without the paler, narrower wrist beyond it (the da Vinci's
    left instrument in the endovis17 frames); rendered as `short_wide_shaft` is."""
    rng = np.random.default_rng(seed)
    backdrop = np.array(tissue_image((H, W), seed=seed), float)
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    t = np.radians(STUB_TILT_DEG)
    u, n = np.array([np.cos(t), np.sin(t)]), np.array([-np.sin(t), np.cos(t)])
    along, across = xx * u[0] + (yy - STUB_Y) * u[1], xx * n[0] + (yy - STUB_Y) * n[1]
    end = STUB_SEEN * STUB_WIDTH
    shaft = np.clip(0.5 * STUB_WIDTH - np.abs(across) + 0.5, 0, 1) * np.clip(end - along + 0.5, 0, 1)
    w, run = WRIST[0] * STUB_WIDTH, WRIST[1] * STUB_WIDTH
    beyond = (np.clip(0.5 * w - np.abs(across) + 0.5, 0, 1) * np.clip(along - end + 0.5, 0, 1)
              * np.clip(end + run - along + 0.5, 0, 1)) if wrist else np.zeros_like(xx)
    shade = 0.6 + 0.4 * np.sin(np.pi * np.clip(across / STUB_WIDTH + 0.5, 0, 1))
    linear = (backdrop * (1 - np.clip(shaft + beyond, 0, 1))[..., None]
              + np.array([0.30, 0.31, 0.34]) * (shade * shaft)[..., None] + np.array([0.45, 0.46, 0.48]) * beyond[..., None])
    frame = sensor_image(linear, 0.0, 1.0, 1.5, 2.2, 2.0, rng)
    _, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, 85])
    return cv2.imdecode(buf, cv2.IMREAD_COLOR), np.r_[n, -n @ np.array([0.0, STUB_Y])]


@pytest.mark.parametrize("seed", range(3))
def test_shaft_cut_by_the_border_seen_short_of_its_collar(seed):
    """Seen along 0.7 of its widths from the border (its edges' samples keep inside the view,
    `_to_border`), the shaft is one (its instrument's material runs on along its axis beyond
    the collar, `_elongated`): one detection, its width within 4 % of the shaft's, within 1 deg
    and 2 px of the axis. Before, it was missed (edges seen too short), the wrist read as a
    72 px shaft in 3 of 6 seeds. Without the wrist (a blob at the border: nothing beyond two
    short edges) nothing is found."""
    img, axis = border_stub(seed)
    assert_read_once(detect_shafts(img), axis, STUB_WIDTH)
    assert detect_shafts(border_stub(seed, wrist=False)[0]) == []


def test_distal_part_not_near_where_the_instrument_enters():
    """A short band lies near where its instrument enters the view when its material reaches
    the border at one end only and the band is nearer that end than the other: the shaft
    seen as it enters (000150's thin instrument: 3 stations from the border, 6 to the far
    end), not a distal part at the far end of its material (open jaws, a wrist: the border
    stub's wrist above, 14 stations from the border, 1 to the far end)."""
    from types import SimpleNamespace

    from pencilcal.toolkit.detect.shaft.material_cue import _near_entry

    def band(run, ext, reach):
        return SimpleNamespace(run=run, ext=ext, reach=reach)

    assert _near_entry(band((7, 15), (4, 21), (True, False)))
    assert _near_entry(band((10, 18), (4, 21), (False, True)))  # mirrored
    assert not _near_entry(band((64, 81), (63, 95), (False, True)))  # the wrist at the far end
    assert not _near_entry(band((14, 18), (4, 21), (True, False)))  # nearer the far end
    assert not _near_entry(band((7, 15), (4, 21), (False, False)))  # no end at the border
    assert not _near_entry(band((7, 15), (4, 21), (True, True)))  # both


def test_band_cut_short_by_the_border_proposed_as_a_close_shaft():
    """A region band at least the least length wide whose run the border of the view cuts is
    a close shaft's candidate from 0.75 of its width (`region_bands.proposed`'s cut: endovis17's
    left shaft in frame001, 132 px wide, a run of 101 px under the least length of 115 px);
    a narrower band, one whose run ends inside the view, or a shorter run is not. Without cut,
    the least length alone."""
    from types import SimpleNamespace

    from pencilcal.toolkit.detect.shaft.region_bands import CUT_RUN_WIDTHS, proposed

    def band(run, width, reach_run=True):
        return SimpleNamespace(fall=(0.0, 0.0), ang=(20.0, 20.0), run_len=run, shaft_len=run, reach_run=reach_run,
                               width_run=width)

    min_len, ang = 115.0, 10.0
    assert CUT_RUN_WIDTHS == 0.75
    assert proposed(band(101.0, 132.0), min_len, ang, cut=True)
    assert not proposed(band(101.0, 132.0), min_len, ang)  # under the least length
    assert not proposed(band(101.0, 132.0, reach_run=False), min_len, ang, cut=True)  # ends inside the view
    assert not proposed(band(90.0, 132.0), min_len, ang, cut=True)  # 0.68 widths
    assert not proposed(band(101.0, 110.0), min_len, ang, cut=True)  # narrower than the least length
    assert proposed(band(120.0, 60.0), min_len, ang) and not proposed(band(120.0, 60.0), min_len, ang, cut=True)

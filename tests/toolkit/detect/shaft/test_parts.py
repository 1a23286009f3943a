"""The axes of instrument regions with no shaft (`toolkit.detect.shaft.parts`)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from pencilcal.toolkit.detect.shaft.detector import Shaft
from pencilcal.toolkit.detect.shaft.parts import MIN_PART_AREA, PART_CUE, detect_parts, part_regions
from pencilcal.toolkit.detect.shaft.pixels import WORK_PX
from pencilcal.toolkit.detect.shaft.work import Validity, WorkFrame


def _frame(poly, seed=0):
    """A tissue-coloured 480 x 640 frame with textured noise and a grey metal polygon."""
    rng = np.random.default_rng(seed)
    img = np.zeros((480, 640, 3), np.float32)
    img[:] = (60, 80, 170)
    img += cv2.GaussianBlur(rng.normal(0, 12, img.shape).astype(np.float32), (0, 0), 3.0)
    cv2.fillConvexPoly(img, np.array(poly, np.int32), (150, 150, 152))
    img = cv2.GaussianBlur(img, (0, 0), 1.2) + rng.normal(0, 2, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


JAW = [[0, 180], [200, 200], [200, 290], [0, 280]]  # 100 px wide, 200 long, from the left border


def test_a_jaw_from_the_border_gets_an_axis():
    parts = detect_parts(_frame(JAW), [])
    assert len(parts) == 1
    p = parts[0]
    assert p.cue == PART_CUE and p.kind in ("shaft", "part")
    # the axis along the jaw: the line from (0, 230) to (200, 245)
    m = np.asarray(p.midline, float)
    ang = np.degrees(np.arctan2(m[3] - m[1], m[2] - m[0]))
    assert abs(((ang - np.degrees(np.arctan2(15, 200))) + 90) % 180 - 90) < 4.0, ang
    # the line passes within a few px of the jaw's middle
    d = np.array([m[2] - m[0], m[3] - m[1]]) / np.hypot(m[2] - m[0], m[3] - m[1])
    r = np.array([100.0, 237.5]) - m[:2]
    off = abs(float(d[0] * r[1] - d[1] * r[0]))
    assert off < 8.0
    if p.kind == "part":  # a part's sigmas are its own half-angle and half its width
        assert p.angle_sigma == pytest.approx(np.arctan2(p.width_px, np.hypot(*(m[2:] - m[:2]))), rel=0.3)
    rec = p.to_dict()
    assert rec["cue"] == PART_CUE and rec["kind"] == p.kind


def test_a_region_inside_the_view_is_no_part():
    # the same jaw, clear of the border: an instrument enters the view from outside
    assert detect_parts(_frame([[p[0] + 150, p[1]] for p in JAW]), []) == []


def test_the_instrument_of_a_found_shaft_is_left_out():
    img = _frame(JAW)
    shaft = Shaft(midline=np.array([0.0, 230, 200, 245]), width_px=100.0, angle_sigma=0.01, offset_sigma=1.0,
                  edges=np.array([[0.0, 180, 200, 200], [0.0, 280, 200, 290]]), score=200.0,
                  ideal_midline=np.array([0.0, 230, 200, 245]), convergence_deg=1.0, polarity="bright")
    assert detect_parts(img, [shaft]) == []


def test_grey_frames_and_specks():
    img = _frame(JAW)
    assert detect_parts(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), []) == []
    # a region smaller than the least area is a speck
    work = WorkFrame(img, None, Validity(None, img.shape[:2]), WORK_PX)
    p = np.zeros(work.shape, np.float32)
    p[:3, :3] = 1.0   # 9 work px in the corner: far below MIN_PART_AREA of the view
    assert 9 < MIN_PART_AREA * p.size
    lab, n = part_regions(work, p)
    assert n == 0 and not lab.any()
    p[:, :40] = 1.0   # a band from the left border
    lab, n = part_regions(work, p)
    assert n == 1 and lab[5, 10] == 1


def test_shaft_records_carry_kind():
    s = Shaft(midline=np.zeros(4), width_px=1.0, angle_sigma=0.0, offset_sigma=0.0, edges=np.zeros((2, 4)),
              score=1.0, ideal_midline=np.zeros(4), convergence_deg=0.0, polarity="dark")
    assert s.to_dict()["kind"] == "shaft"


@pytest.mark.parametrize("lens", [False, True])
def test_raw_masks_window_is_the_whole_frame_map(lens):
    """Only the raw pixels near the regions are mapped, and each is mapped as in the whole
    frame: the masks are those of the whole frame's map (`grid_map`) bit for bit, for small
    regions anywhere (a corner, the edge, a speck), with and without a strong barrel lens."""
    from pencilcal.toolkit.camera.model import Camera
    from pencilcal.toolkit.detect.shaft.work import RAW_STEP_PX, grid_map, raw_masks
    from pencilcal.toolkit.detect.working import to_working_points

    H, W = 270, 481
    cam = Camera("opencv", W, H, [[300.0, 0, 240.0], [0, 300.0, 134.5], [0, 0, 1]],
                 [-0.45, 0.2, 0.001, -0.001, 0.0]) if lens else None
    work = WorkFrame(np.zeros((H, W, 3), np.uint8), cam, Validity(None, (H, W)), 200)
    q = grid_map(lambda g: work.to_work(to_working_points(cam, g)), (H, W), RAW_STEP_PX)
    q = np.nan_to_num(q, nan=-1.0).astype(np.float32)
    rng = np.random.default_rng(3)
    h, w = work.shape
    for trial in range(12):
        lab = np.zeros(work.shape, np.int32)
        for k in (1, 2, 3):
            r, c = int(rng.integers(0, h)), int(rng.integers(0, w))
            lab[r:r + int(rng.integers(1, 30)), c:c + int(rng.integers(1, 30))] = k
        lab[0:5, 0:4] = 2 if trial % 2 else lab[0:5, 0:4]
        want = cv2.remap(lab.astype(np.float32), q[..., 0], q[..., 1], cv2.INTER_NEAREST,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        for k, got in enumerate(raw_masks(work, cam, lab, 3, (H, W)), 1):
            assert got.shape == (H, W) and np.array_equal(got, want == k), (trial, k)
    assert not any(m.any() for m in raw_masks(work, cam, np.zeros(work.shape, np.int32), 2, (H, W)))


@pytest.mark.parametrize("lens", [False, True])
def test_raw_masks_are_the_regions_where_they_are(lens):
    """A region of the work frame carried to raw pixels covers the raw pixels whose own work
    point falls in it, each evaluated exactly: the same pixels without a lens (where a resize
    of the 4 px raw grid shifted every mask 1.5 px right and down), to within a pixel of its
    outline and a centroid 0.02 px off with a barrel lens."""
    from pencilcal.toolkit.camera.model import Camera
    from pencilcal.toolkit.detect.shaft.work import raw_masks
    from pencilcal.toolkit.detect.working import to_working_points

    H, W = 480, 854
    cam = Camera("opencv", W, H, [[770.0, 0, 426.5], [0, 770.0, 239.5], [0, 0, 1]],
                 [-0.25, 0.08, 0.001, -0.001, 0.0]) if lens else None
    work = WorkFrame(np.zeros((H, W, 3), np.uint8), cam, Validity(None, (H, W)), WORK_PX)
    lab = np.zeros(work.shape, np.int32)
    lab[30:110, 50:200] = 1
    lab[140:, :40] = 2                                                 # one at the frame's corner
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    q = np.rint(work.to_work(to_working_points(cam, np.stack([xx, yy], -1)))).astype(int)
    inside = (q[..., 0] >= 0) & (q[..., 0] < lab.shape[1]) & (q[..., 1] >= 0) & (q[..., 1] < lab.shape[0])
    exact = np.where(inside, lab[np.clip(q[..., 1], 0, lab.shape[0] - 1), np.clip(q[..., 0], 0, lab.shape[1] - 1)], 0)
    for k, got in enumerate(raw_masks(work, cam, lab, 2, (H, W)), 1):
        want = exact == k
        assert got.sum() > 2000
        if not lens:
            assert np.array_equal(got, want), k
        ys, xs = np.nonzero(got)
        ey, ex = np.nonzero(want)
        assert abs(xs.mean() - ex.mean()) < 0.02 and abs(ys.mean() - ey.mean()) < 0.02, k
        off = got != want                                              # only on the outline
        assert cv2.dilate(want.astype(np.uint8), np.ones((3, 3), np.uint8))[off].all()
        assert not cv2.erode(want.astype(np.uint8), np.ones((3, 3), np.uint8))[off].any()



def test_a_region_reaches_the_border_of_the_view():
    """The rim is left out when regions are formed (a strip along the border joins nothing)
    but a region is grown back into it: its outline there is the view's border, which the
    axis reading ignores, not a cut 5 work px inside that would read as a straight silhouette."""
    img = _frame(JAW)
    work = WorkFrame(img, None, Validity(None, img.shape[:2]), WORK_PX)
    p = np.zeros(work.shape, np.float32)
    p[60:100, :120] = 1.0                                               # a band from the left border
    lab, n = part_regions(work, p)
    assert n == 1
    assert (lab[60:100, 0] == 1).all() and (lab[60:100, :120] == 1).all()
    assert not lab[:58].any() and not lab[102:].any()                   # grown only where the map is


def test_glare_is_no_part():
    """A region mostly clipped (a field of glare at the border, as bright a white as the
    sensor gives) shows the light, not a material: no part, where the same region in grey
    metal gets its axis."""
    img = _frame(JAW)
    assert len(detect_parts(img, [])) == 1
    glare = img.copy()
    cv2.fillConvexPoly(glare, np.array(JAW, np.int32), (255, 255, 255))
    glare = cv2.GaussianBlur(glare, (0, 0), 1.2)
    work = WorkFrame(glare, None, Validity(None, glare.shape[:2]), WORK_PX)
    p = np.zeros(work.shape, np.float32)
    p[:, :] = 0.0
    jaw = np.zeros(glare.shape[:2], np.uint8)
    cv2.fillConvexPoly(jaw, np.array(JAW, np.int32), 1)
    p[cv2.resize(jaw, (work.shape[1], work.shape[0]), interpolation=cv2.INTER_NEAREST) > 0] = 1.0
    assert part_regions(work, p)[1] == 0
    # the same map over the grey jaw gives the region
    work = WorkFrame(img, None, Validity(None, img.shape[:2]), WORK_PX)
    assert part_regions(work, p)[1] == 1


def test_a_blob_and_a_shadow_are_no_part():
    """A grey region as long as wide (no direction to speak of), and a dark band that keeps
    the tissue's hue (a shadow, `shaft.tissue_colour`), give no axis; the grey jaw does."""
    blob = [[0, 150], [150, 150], [150, 330], [0, 330]]                 # 150 long, 180 wide
    assert detect_parts(_frame(blob), []) == []
    rng = np.random.default_rng(1)
    img = np.zeros((480, 640, 3), np.float32)
    img[:] = (60, 80, 170)
    img += cv2.GaussianBlur(rng.normal(0, 12, img.shape).astype(np.float32), (0, 0), 3.0)
    cv2.fillConvexPoly(img, np.array(JAW, np.int32), (2, 4, 24))     # dark, deeper in the tissue's hue (a cavity)
    img = np.clip(cv2.GaussianBlur(img, (0, 0), 1.2) + rng.normal(0, 2, img.shape), 0, 255).astype(np.uint8)
    from pencilcal.toolkit.detect.shaft.tissue_colour import shaft_tissue_colour
    loose = detect_parts(img, [], tissue_colour=None)                   # the map takes it for metal
    assert len(loose) == 1 and shaft_tissue_colour(img, loose)[0] > 1.25
    assert detect_parts(img, []) == []


def test_a_region_is_judged_with_the_detections_touching_it():
    """Where the detections are judged after the regions are formed (the leave-one-source-out
    protocol detects once and chooses its setting per source), a region is its shaft's
    instrument only where a detection touching it is kept: a weak band over the jaw, which
    the setting drops, takes nothing from it, whatever else was proposed; kept, the jaw is that
    shaft's instrument. Formed against the detections before they were judged, the jaw was lost
    with the weak band proposed and found without it."""
    from pencilcal.validation.shaft_protocol import filtered, part_records

    img = _frame(JAW)
    weak = Shaft(midline=np.array([0.0, 230, 120, 239]), width_px=60.0, angle_sigma=0.01, offset_sigma=1.0,
                 edges=np.array([[0.0, 200, 120, 209], [0.0, 260, 120, 269]]), score=60.0,
                 ideal_midline=np.array([0.0, 230, 120, 239]), convergence_deg=1.0, polarity="bright")
    diagonal = float(np.hypot(*img.shape[:2]))                          # 800 px: 0.1 of it is 80 > 60
    alone = part_records(img, [])
    proposed = [weak.to_dict()] + part_records(img, [weak])
    assert len(alone) == 1 and [r["touches"] for r in proposed[1:]] == [[0]]
    for setting in (0.1, 0.2):                                          # the weak band dropped
        got = filtered(proposed, setting, diagonal, part=0.0)
        assert [d["cue"] for d in got] == [PART_CUE]
        assert [d["midline"] for d in got] == [d["midline"] for d in filtered(alone, setting, diagonal, part=0.0)]
    assert filtered(proposed, 0.05, diagonal, part=0.0) == [proposed[0]]          # kept: the jaw is its instrument
    # the product's, which gets the shafts found (judged): the same
    assert detect_parts(img, [weak]) == [] and len(detect_parts(img, [])) == 1

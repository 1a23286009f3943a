"""The valid region (toolkit.detect.region, region.detect): synthetic fields (circle,
clipped circle, letterbox, logo, black shaft, ordinary image), the ValidRegion API, mask
files, and real image sets where they are present."""
from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from pencilcal.toolkit.detect.region.valid import ValidRegion, read_mask_file
from pencilcal.toolkit.detect.region.detect import detect_valid_region, sequence_region
from pencilcal.toolkit.errors import InputError
from tests.conftest import data_dir


# ----------------------------------------------------------------------------
# synthetic images
# ----------------------------------------------------------------------------
def tissue(h, w, seed, dark_patches=True):
    """Smooth, textured, reddish 'tissue' (BGR uint8), values ~40..230."""
    rng = np.random.default_rng(seed)
    small = cv2.GaussianBlur(rng.normal(0, 1, (h // 8 + 1, w // 8 + 1)).astype(np.float32), (0, 0), 3)
    base = cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
    base = (base - base.min()) / (np.ptp(base) + 1e-9)
    fine = cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), 2)
    fine /= np.abs(fine).max() + 1e-9
    v = 90 + 120 * base + 18 * fine
    if dark_patches:
        yy, xx = np.mgrid[0:h, 0:w]
        for _ in range(3):
            cy, cx, rr = rng.uniform(0.2, 0.8) * h, rng.uniform(0.2, 0.8) * w, rng.uniform(0.05, 0.12) * min(h, w)
            v = np.where((yy - cy) ** 2 + (xx - cx) ** 2 < rr ** 2, v * 0.45, v)
    img = np.stack([0.45 * v, 0.6 * v, v], axis=2)
    return np.clip(img, 0, 255)


def field(h, w, cx, cy, r, seed=0, blur=1.5, black=8.0, noise=2.0, content=None):
    """Circular field of view (un-blurred 50 % boundary exactly at radius r)."""
    rng = np.random.default_rng(seed + 100)
    yy, xx = np.mgrid[0:h, 0:w]
    # anti-aliased disc (pixel coverage, linear in the distance to the circle)
    inside = np.clip(r - np.hypot(xx - cx, yy - cy) + 0.5, 0.0, 1.0).astype(np.float32)
    if blur > 0:
        inside = cv2.GaussianBlur(inside, (0, 0), blur)
    c = tissue(h, w, seed) if content is None else content
    img = black + inside[..., None] * (c - black)
    img = img + rng.normal(0, noise, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def letterbox(h, w, top, bottom, left=0, right=0, seed=0, noise=1.5):
    rng = np.random.default_rng(seed + 7)
    img = tissue(h, w, seed)
    img[:top] = 3
    img[h - bottom:] = 3
    if left:
        img[:, :left] = 3
    if right:
        img[:, w - right:] = 3
    img = img + rng.normal(0, noise, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def draw_shaft(img, p0, p1, width, value=12):
    out = img.copy()
    cv2.line(out, tuple(map(int, p0)), tuple(map(int, p1)), (value, value, value), width, cv2.LINE_AA)
    return out


# ----------------------------------------------------------------------------
# detection on synthetic data
# ----------------------------------------------------------------------------
def _detected_circle(h, w, cx, cy, r, **field_options):
    """The region detected in one synthetic circular field: (region, its 50 % circle)."""
    reg = detect_valid_region([field(h, w, cx, cy, r, **field_options)])
    assert reg.kind == "circle", reg.info.get("circle_diag")
    return reg, reg.info["circle_50"]


def test_circle_field_centre_radius():
    h, w, cx, cy, r = 720, 1280, 652.3, 371.8, 318.4
    reg, c50 = _detected_circle(h, w, cx, cy, r, seed=1)
    assert abs(c50[0] - cx) < 1.0 and abs(c50[1] - cy) < 1.0, c50
    assert abs(c50[2] - r) < 1.0, c50
    # conservative: the returned circle lies inside, by ~ the blur (2 sigma + 1)
    m = c50[2] - reg.circle[2]
    assert 2.0 <= m <= 8.0, m
    assert reg.to_dict() == {"circle": list(reg.circle)}
    # the ramp is outside; the surround is outside; content is inside
    assert not reg.contains([cx + r, cy]) and reg.contains([cx + r - 10, cy])
    assert not reg.mask()[5, 5]


def test_circle_clipped_by_image_top_bottom():
    h, w, cx, cy, r = 1080, 1920, 955.0, 548.0, 700.0
    reg, c50 = _detected_circle(h, w, cx, cy, r, seed=2, blur=2.0)
    assert np.hypot(c50[0] - cx, c50[1] - cy) < 2.0 and abs(c50[2] - r) < 2.0, c50
    # the image rectangle clips it: the top-centre pixel is valid, the corners are not
    m = reg.mask()
    assert m[0, int(cx)] and m[h - 1, int(cx)] and not m[0, 0] and not m[h - 1, w - 1]


def test_circle_only_corners_clipped():
    h, w, cx, cy, r = 720, 1280, 640.0, 360.0, 700.0
    reg, c50 = _detected_circle(h, w, cx, cy, r, seed=3)
    assert np.hypot(c50[0] - cx, c50[1] - cy) < 2.0 and abs(c50[2] - r) < 2.0, c50


def test_letterbox():
    h, w = 720, 1280
    img = letterbox(h, w, top=60, bottom=60, seed=4)
    reg = detect_valid_region([img])
    assert reg.kind == "letterbox", reg.info.get("bars_diag")
    poly = np.array(reg.to_dict()["polygon"])
    x0, y0 = poly.min(0)
    x1, y1 = poly.max(0)
    assert x0 == 0 and x1 == w - 1
    # bar rows 0..59 dark, content from row 60: 50 % edge at 59.5, then a small margin
    assert 60.0 <= y0 <= 63.5 and h - 64.5 <= y1 <= h - 61.0, (y0, y1)
    assert not reg.contains([100, 59]) and reg.contains([100, 64])


def test_pillarbox_with_text_in_bar():
    h, w = 720, 1280
    img = letterbox(h, w, top=0, bottom=0, left=160, right=160, seed=5)
    cv2.putText(img, "12:34:56", (10, 300), cv2.FONT_HERSHEY_SIMPLEX, 1.0, (230, 230, 230), 2)
    reg = detect_valid_region([img])
    assert reg.kind == "letterbox", reg.info.get("bars_diag")
    poly = np.array(reg.to_dict()["polygon"])
    assert 160.0 <= poly[:, 0].min() <= 164.0 and w - 165.0 <= poly[:, 0].max() <= w - 161.0


def test_ordinary_image_is_full():
    img = np.clip(tissue(480, 640, 6) * 0.9 + 10, 0, 255).astype(np.uint8)
    # a dark, smooth object in one corner (not a surround)
    yy, xx = np.mgrid[0:480, 0:640]
    blob = np.hypot(xx, yy) < 120
    img[blob] = (img[blob] * 0.15).astype(np.uint8)
    reg = detect_valid_region([img])
    assert reg.kind == "full", (reg.kind, reg.info.get("circle_diag"))
    assert reg.to_dict() == {"polygon": [[0.0, 0.0], [639.0, 0.0], [639.0, 479.0], [0.0, 479.0]]}
    assert reg.mask().all()


def test_black_shaft_touching_border_not_excluded():
    h, w = 720, 1280
    base = np.clip(np.rint(tissue(h, w, 7) + np.random.default_rng(1).normal(0, 2, (h, w, 3))), 0, 255).astype(np.uint8)
    img = draw_shaft(base, (0, 250), (700, 420), 70)
    reg = detect_valid_region([img])
    assert reg.kind == "full", (reg.kind, reg.info.get("bars_diag"), reg.info.get("circle_diag"))
    assert reg.contains([5, 255]) and reg.contains([300, 320])


def test_black_shaft_across_circle_boundary():
    h, w, cx, cy, r = 720, 1280, 640.0, 360.0, 330.0
    img = field(h, w, cx, cy, r, seed=8)
    img = draw_shaft(img, (1280, 100), (700, 330), 60, value=10)   # enters from outside the field
    reg = detect_valid_region([img])
    assert reg.kind == "circle", reg.info.get("circle_diag")
    c50 = reg.info["circle_50"]
    assert np.hypot(c50[0] - cx, c50[1] - cy) < 2.0 and abs(c50[2] - r) < 2.0, c50
    # a shaft point inside the field stays valid
    t = 0.8
    p = (1280 + t * (700 - 1280), 100 + t * (330 - 100))
    assert np.hypot(p[0] - cx, p[1] - cy) < r - 20
    assert reg.contains(p)


def test_sequence_with_moving_black_shaft():
    h, w, cx, cy, r = 540, 960, 480.0, 270.0, 300.0      # clipped top and bottom
    frames = []
    for k in range(8):
        img = field(h, w, cx, cy, r, seed=20 + k)
        a = math.radians(200 + 12 * k)
        frames.append(draw_shaft(img, (cx + 600 * math.cos(a), cy + 600 * math.sin(a)), (cx, cy), 50, value=8))
    reg = detect_valid_region(frames)
    assert reg.kind == "circle", reg.info.get("circle_diag")
    c50 = reg.info["circle_50"]
    assert np.hypot(c50[0] - cx, c50[1] - cy) < 1.5 and abs(c50[2] - r) < 1.5, c50
    assert reg.mask()[int(cy), int(cx) - 150]


def test_static_logo_in_corner_becomes_hole():
    h, w = 540, 960
    frames = []
    for k in range(6):
        img = np.clip(np.rint(tissue(h, w, 30 + k) + np.random.default_rng(k).normal(0, 2, (h, w, 3))), 0, 255)
        img = img.astype(np.uint8)
        cv2.putText(img, "LOGO", (820, 520), cv2.FONT_HERSHEY_SIMPLEX, 1.0, (255, 255, 255), 3)
        cv2.rectangle(img, (812, 488), (940, 530), (40, 200, 40), 2)
        frames.append(img)
    reg = detect_valid_region(frames)
    assert reg.holes, reg.info.get("overlay_diag")
    m = reg.mask()
    assert not m[510, 850] and not m[489, 900]          # logo text / frame
    assert m[270, 480] and m[100, 100]                   # content elsewhere
    assert reg.kind == "full" and "holes" not in reg.to_dict()
    assert "holes" in reg.to_dict(include_holes=True)
    # single frame: an overlay cannot be told from content (documented limitation)
    assert not detect_valid_region(frames[:1]).holes


@pytest.mark.slow
def test_speed_10_frames_1080p():
    import time
    frames = [field(1080, 1920, 960, 540, 620, seed=40 + k) for k in range(10)]
    t = time.process_time()
    reg = detect_valid_region(frames)
    dt = time.process_time() - t
    assert reg.kind == "circle"
    assert dt < 1.0, dt


# ----------------------------------------------------------------------------
# ValidRegion API
# ----------------------------------------------------------------------------
def test_dict_roundtrip_and_conventions():
    c = ValidRegion.from_circle(100.5, 80.25, 60.0, 200, 160)
    assert c.to_dict() == {"circle": [100.5, 80.25, 60.0]}
    c2 = ValidRegion.from_dict(json.loads(json.dumps(c.to_dict())), shape=(160, 200))
    assert c2 == c
    full = ValidRegion.full(200, 160)
    assert full.to_dict() == {"polygon": [[0.0, 0.0], [199.0, 0.0], [199.0, 159.0], [0.0, 159.0]]}
    assert full.mask().all()
    # a pixel on the image border is on the boundary (distance 0), inside
    assert full.distance_to_boundary([0, 50]) == 0 and full.contains([0, 50])
    assert full.distance_to_boundary([100, 80]) == pytest.approx(79.0)
    assert full.distance_to_boundary([-3, 50]) == pytest.approx(-3.0)
    assert ValidRegion.from_dict(full.to_dict(), shape=(160, 200)).kind == "full"


def test_mask_contains_distance_consistent():
    regs = [ValidRegion.from_circle(100.3, 70.7, 90.0, 200, 150),
            ValidRegion.from_rect(10.5, 5.0, 180.2, 140.0, 200, 150),
            ValidRegion.from_dict({"polygon": [[10, 10], [190, 20], [150, 140], [100, 60], [20, 130]]},
                                  shape=(150, 200)),
            ValidRegion(200, 150, circle=(100.0, 75.0, 70.0), holes=((150.0, 60.0, 190.0, 90.0),), kind="circle")]
    yy, xx = np.mgrid[0:150, 0:200]
    pts = np.stack([xx, yy], axis=-1).astype(float)
    for reg in regs:
        m = reg.mask()
        assert m.shape == (150, 200) and m.dtype == bool
        assert np.array_equal(m, reg.contains(pts)), reg
        d = reg.distance_to_boundary(pts)
        assert np.array_equal(m, d >= -1e-7)
    # signed distance of a circle
    c = regs[0]
    assert c.distance_to_boundary([100.3 + 50, 70.7]) == pytest.approx(40.0)
    assert c.distance_to_boundary([100.3, 70.7 - 50]) == pytest.approx(20.7)   # image top edge nearer
    # holes: outside the hole is valid, inside not; distance positive outside the hole
    hreg = regs[3]
    assert not hreg.contains([160, 75]) and hreg.contains([140, 75])
    assert hreg.distance_to_boundary([140, 75]) == pytest.approx(10.0)


def test_eroded():
    c = ValidRegion.from_circle(100, 80, 60, 200, 160)
    e = c.eroded(5)
    assert e.circle == (100.0, 80.0, 55.0)
    lb = ValidRegion.from_rect(0, 20, 199, 139, 200, 160)
    e = lb.eroded(3)
    p = np.array(e.to_dict()["polygon"])
    # bar edges move inward, edges on the image border stay
    assert p[:, 1].min() == pytest.approx(23) and p[:, 1].max() == pytest.approx(136)
    assert p[:, 0].min() == pytest.approx(0) and p[:, 0].max() == pytest.approx(199)
    with pytest.raises(InputError):
        c.eroded(-1)
    with pytest.raises(InputError):
        c.eroded(100)


@pytest.mark.parametrize("d, msg", [
    ({}, "exactly one"),
    ({"circle": [1, 2, 3], "polygon": [[0, 0], [1, 0], [0, 1]]}, "exactly one"),
    ({"circle": [1, 2]}, "3 numbers"),
    ({"circle": [1, 2, -3]}, "radius"),
    ({"circle": [1, float("nan"), 3]}, "finite"),
    ({"circle": "1,2,3"}, "list"),
    ({"polygon": [[0, 0], [1, 1]]}, "at least 3"),
    ({"polygon": [[0, 0], [1, 1], [2, 2]]}, "zero area"),
    ({"polygon": [[0, 0], [10, 0], [0, 10], [10, 10]]}, "self-intersecting"),
    ({"polygon": [[0, 0], [1, "a"], [0, 1]]}, "numbers"),
    ({"circle": [1, 2, 3], "extra": 1}, "unknown"),
    ([1, 2, 3], "mapping"),
])
def test_from_dict_errors(d, msg):
    with pytest.raises(InputError) as e:
        ValidRegion.from_dict(d)
    assert msg in str(e.value) and "\n" not in str(e.value)


def test_read_mask_file(tmp_path):
    shape = (120, 160)
    m = np.zeros(shape, np.uint8)
    cv2.circle(m, (80, 60), 50, 255, -1)
    p = tmp_path / "mask.png"
    cv2.imwrite(str(p), m)
    reg = read_mask_file(p, shape)
    assert np.array_equal(reg.mask(), m > 0)
    assert reg.contains([80, 60]) and not reg.contains([2, 2])
    assert reg.distance_to_boundary([80, 60]) > 45
    assert "polygon" in reg.to_dict()
    j = tmp_path / "r.json"
    j.write_text(json.dumps({"circle": [80, 60, 50]}))
    assert read_mask_file(j, shape).circle == (80.0, 60.0, 50.0)
    y = tmp_path / "r.yaml"
    y.write_text("polygon:\n  - [10, 10]\n  - [150, 10]\n  - [150, 110]\n  - [10, 110]\n")
    ry = read_mask_file(y, shape)
    assert ry.kind == "letterbox" and ry.mask().sum() == 141 * 101
    # errors name the file
    cv2.imwrite(str(tmp_path / "small.png"), np.full((10, 10), 255, np.uint8))
    with pytest.raises(InputError, match="small.png.*10x10"):
        read_mask_file(tmp_path / "small.png", shape)
    cv2.imwrite(str(tmp_path / "empty.png"), np.zeros(shape, np.uint8))
    with pytest.raises(InputError, match="empty.png"):
        read_mask_file(tmp_path / "empty.png", shape)
    (tmp_path / "bad.json").write_text("{circle: 1")
    with pytest.raises(InputError, match="bad.json"):
        read_mask_file(tmp_path / "bad.json", shape)
    (tmp_path / "neg.json").write_text(json.dumps({"circle": [1, 2, -1]}))
    with pytest.raises(InputError, match="neg.json.*radius"):
        read_mask_file(tmp_path / "neg.json", shape)
    (tmp_path / "out.json").write_text(json.dumps({"circle": [-500, -500, 10]}))
    with pytest.raises(InputError, match="out.json.*no pixel"):
        read_mask_file(tmp_path / "out.json", shape)
    with pytest.raises(InputError, match="nope.png"):
        read_mask_file(tmp_path / "nope.png", shape)


def test_bad_frames():
    with pytest.raises(InputError):
        detect_valid_region([])
    with pytest.raises(InputError, match="dtype"):
        detect_valid_region([np.zeros((10, 10), np.float32)])
    with pytest.raises(InputError, match="frame 1"):
        detect_valid_region([np.zeros((40, 40), np.uint8), np.zeros((41, 40), np.uint8)])


# ----------------------------------------------------------------------------
# real data (skipped when absent)
# ----------------------------------------------------------------------------
def _imgs(set_name, pattern):
    return [cv2.imread(str(f)) for f in sorted(data_dir(set_name).glob(pattern))]


@pytest.mark.slow
@pytest.mark.parametrize("set_name, pattern", [("opencv-charuco-tutorial", "*.jpg"),
                                               ("realsense-charuco-7x5-calibio", "intrinsics_images/*.png"),
                                               ("real-instruments/dvrk-suturing-masks", "*_img.png")])
def test_real_ordinary_sets_full(set_name, pattern):
    ims = _imgs(set_name, pattern)
    if not ims:
        pytest.skip("set absent")
    assert detect_valid_region(ims).kind == "full"
    for im in ims:
        assert detect_valid_region([im]).kind == "full"


@pytest.mark.slow
def test_real_davinci_sequence_bars():
    ims = _imgs("sksurgery-davinci-charuco-stereo", "left/*.jpg")
    if not ims:
        pytest.skip("set absent")
    reg = detect_valid_region(ims)
    assert reg.kind == "letterbox"
    p = np.array(reg.to_dict()["polygon"])
    # 12 dark columns at the left, a blue line + dark columns at the right, ~4 dark rows on top
    assert 12 <= p[:, 0].min() <= 16 and 705 <= p[:, 0].max() <= 712 and 4 <= p[:, 1].min() <= 7
    assert p[:, 1].max() == 575


def test_real_box_trainer_circle():
    ims = _imgs("real-instruments/box-trainer-and-greenscreen", "box_trainer.jpg")
    if not ims:
        pytest.skip("set absent")
    reg = detect_valid_region(ims)
    assert reg.kind == "circle"
    cx, cy, r = reg.info["circle_50"]
    assert abs(cx - 490) < 4 and abs(cy - 494) < 4 and abs(r - 490) < 5


# ----------------------------------------------------------------------------
# the detectors within a region
# ----------------------------------------------------------------------------
FIELD = (320.0, 240.0, 220.0)  # the field stop of field_with_shaft: centre, radius [px]


def field_with_shaft(seed=0):
    """A 640x480 circular field (radius 220, dark surround) over smooth shading, and a dark
    50 px shaft entering it from the upper right to its centre."""
    h, w = 480, 640
    cx, cy, r = FIELD
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    base = 150 + 30 * np.sin(xx / 37.0) * np.cos(yy / 53.0)
    inside = np.clip(r - np.hypot(xx - cx, yy - cy) + 0.5, 0, 1).astype(np.float32)
    img = 10 + inside * (base - 10)
    sh = np.zeros((h, w), np.float32)
    cv2.line(sh, (700, -60), (330, 250), 1.0, 50, cv2.LINE_AA)
    img = img * (1 - sh) + 35 * sh * inside + 10 * sh * (1 - inside)
    img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), 1.2) + rng.normal(0, 1.5, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def _near_field_edge(seg, tol=4.0):
    """(M,) bool: segments (M, 4) whose midpoint lies within tol of the field's circle."""
    cx, cy, r = FIELD
    mid = 0.5 * (seg[:, :2] + seg[:, 2:])
    return np.abs(np.hypot(mid[:, 0] - cx, mid[:, 1] - cy) - r) < tol


def test_no_segment_on_the_field_edge():
    from pencilcal.toolkit.detect.segments import detect_segments

    img = field_with_shaft()
    reg = detect_valid_region([img])
    assert reg.kind == "circle"
    plain = detect_segments(img)
    assert _near_field_edge(plain.segments).sum() >= 10  # the field stop's edge, without a region
    segs = detect_segments(img, valid_region=reg)
    assert not _near_field_edge(segs.segments).any()
    # the shaft's two edges are still there, along its direction
    d = segs.segments[:, 2:] - segs.segments[:, :2]
    ang = np.degrees(np.arctan2(d[:, 1], d[:, 0])) % 180
    along = np.abs(ang - (np.degrees(np.arctan2(310, -370)) % 180)) < 2
    assert (along & (np.hypot(d[:, 0], d[:, 1]) > 100)).sum() >= 2
    assert np.all(reg.contains(segs.segments[:, :2]) & reg.contains(segs.segments[:, 2:]))


def test_no_region_or_a_full_one_changes_nothing():
    from pencilcal.toolkit.detect.segments import detect_segments

    img = field_with_shaft()
    a = detect_segments(img)
    b = detect_segments(img, valid_region=ValidRegion.full(640, 480))
    assert np.array_equal(a.segments, b.segments) and np.array_equal(a.angle_sigma, b.angle_sigma)


def test_bars_inside_a_letterbox():
    from pencilcal.toolkit.detect.bars import detect_bars

    img = np.full((240, 320), 210, np.uint8)
    img[:40] = 3
    img[-40:] = 3
    img[120:127, 20:300] = 30  # a bar between the bars
    img = cv2.GaussianBlur(img, (0, 0), 1.0)
    reg = detect_valid_region([img])
    assert reg.kind == "letterbox"
    bars = detect_bars(img, valid_region=reg)
    assert len(bars) == 1 and abs(float(bars.width_px[0]) - 7.0) < 0.3


def test_shaft_entering_the_field_reaches_its_border():
    from pencilcal.toolkit.detect.shaft.detector import detect_shafts

    img = field_with_shaft()
    reg = detect_valid_region([img])
    shafts = detect_shafts(img, valid_region=reg)
    assert len(shafts) == 1
    near_end = shafts[0].midline[:2]  # the wide (near) end: where the shaft enters the view
    assert abs(float(reg.distance_to_boundary(near_end))) < 15.0
    assert 45 < shafts[0].width_px < 56


def test_sequence_region_from_images_a_video_or_a_mask(tmp_path):
    from pencilcal.toolkit.io.images import open_images

    (tmp_path / "frames").mkdir()
    vid = cv2.VideoWriter(str(tmp_path / "field.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 10, (640, 480))
    for i in range(20):
        img = field_with_shaft(seed=i % 3)
        cv2.imwrite(str(tmp_path / "frames" / f"{i:02d}.png"), img)
        vid.write(cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))
    vid.release()
    for src in (open_images(tmp_path / "frames"), open_images(tmp_path / "field.avi")):
        reg = sequence_region(src)
        assert reg.kind == "circle" and reg.info["n_frames"] == 16
        assert np.hypot(reg.circle[0] - FIELD[0], reg.circle[1] - FIELD[1]) < 1.5
    (tmp_path / "m.json").write_text('{"circle": [300, 200, 100]}')
    reg = sequence_region(open_images(tmp_path / "frames"), tmp_path / "m.json", shape=(480, 640))
    assert reg.to_dict() == {"circle": [300.0, 200.0, 100.0]} and reg.shape == (480, 640)

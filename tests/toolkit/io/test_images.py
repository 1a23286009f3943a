"""IMAGES: several paths in order, natural sorting, duplicates, videos, the one decoder."""
from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
import pytest

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.images import decode_image, open_images


def _png(path, value=0, size=(4, 6)):
    assert cv2.imwrite(str(path), np.full(size, value, np.uint8))
    return path


def _claimed_png(path, w, h):
    """A tiny PNG whose header claims w x h pixels."""
    def chunk(t, b):
        return struct.pack(">I", len(b)) + t + b + struct.pack(">I", zlib.crc32(t + b) & 0xFFFFFFFF)
    data = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b""))
    path.write_bytes(data)
    return path


def test_several_paths_keep_their_order_and_folders_sort_naturally(tmp_path):
    d = tmp_path / "d"
    d.mkdir()
    for n in ("f10.png", "f2.png", "f1.png"):
        _png(d / n)
    a = _png(tmp_path / "z.png")
    src = open_images([str(a), str(d)])
    assert [f.name for f in src] == ["z.png", "f1.png", "f2.png", "f10.png"]
    assert src.description == f"{a} {d}"
    # one path behaves as before: its description is the path itself
    assert open_images(str(d)).description == str(d)


def test_the_same_image_twice_is_refused(tmp_path):
    a = _png(tmp_path / "a.png")
    with pytest.raises(InputError, match="given twice"):
        open_images([str(a), str(tmp_path)])
    with pytest.raises(InputError, match="given twice"):
        open_images([str(a), str(a)])


def test_a_video_must_come_alone(tmp_path):
    v = tmp_path / "v.avi"
    w = cv2.VideoWriter(str(v), cv2.VideoWriter_fourcc(*"MJPG"), 5, (32, 24))
    for _ in range(3):
        w.write(np.zeros((24, 32, 3), np.uint8))
    w.release()
    assert len(list(open_images([str(v)]))) == 3
    with pytest.raises(InputError, match="only IMAGES argument"):
        open_images([str(v), str(_png(tmp_path / "a.png"))])


def test_a_videos_head_is_read_once_and_yielded_again(tmp_path):
    # the valid region reads a short video's first frames ahead: the run then gets every
    # frame once, in order, the read-ahead ones first, without decoding them again
    v = tmp_path / "v.avi"
    w = cv2.VideoWriter(str(v), cv2.VideoWriter_fourcc(*"MJPG"), 5, (32, 24))
    for k in range(7):
        w.write(np.full((24, 32, 3), 30 * k, np.uint8))
    w.release()
    src = open_images(str(v))
    plain = [f.image for f in open_images(str(v))]
    head = src.head(3)
    assert len(head) == 3 and all(np.array_equal(a, b) for a, b in zip(head, plain))
    frames = list(src)
    assert [f.index for f in frames] == list(range(7))
    assert all(np.array_equal(f.image, b) for f, b in zip(frames, plain))
    assert frames[0].image is head[0]  # the same array: not decoded again
    assert [f.index for f in src] == list(range(7))  # and the source stays re-iterable


def test_no_images_at_all(tmp_path):
    with pytest.raises(InputError, match="no images given"):
        open_images([])


def test_a_header_claiming_too_many_pixels_is_not_decoded(tmp_path):
    p = _claimed_png(tmp_path / "bomb.png", 100000, 100000)
    img, err = decode_image(p)
    assert img is None and "claims" in err and "--max-pixels" in err
    p = _claimed_png(tmp_path / "big.png", 12000, 10000)
    img, err = decode_image(p)
    assert img is None and "12000x10000" in err
    # under a raised limit the same header reaches the decoder (and its data are corrupt)
    img, err = decode_image(p, max_pixels=200_000_000)
    assert img is None and "claims" not in err


def test_exif_orientation_is_applied_in_colour_and_grey(tmp_path):
    """A JPEG whose EXIF says "rotate 90": every command sees it upright, as imread does."""
    from PIL import Image

    rgb = np.zeros((20, 40, 3), np.uint8)
    rgb[:, :10] = 255  # a bright band on the left of the stored pixels
    path = tmp_path / "phone.jpg"
    exif = Image.Exif()
    exif[274] = 6  # rotate 90 deg clockwise to display
    Image.fromarray(rgb).save(path, exif=exif, quality=95)
    colour, _ = decode_image(path)
    grey, _ = decode_image(path, gray=True)
    assert colour.shape[:2] == grey.shape == (40, 20)
    np.testing.assert_allclose(cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY), grey, atol=2)
    assert np.array_equal(colour, cv2.imread(str(path)))


def test_prefetched_yields_in_order_raises_in_order_and_stops_when_left():
    import threading

    from pencilcal.toolkit.io.images import prefetched

    assert list(prefetched(lambda: iter(range(50)), depth=3)) == list(range(50))

    def failing():
        yield 1
        yield 2
        raise ValueError("frame 3 is broken")

    got = []
    with pytest.raises(ValueError, match="frame 3"):
        for x in prefetched(failing):
            got.append(x)
    assert got == [1, 2]

    closed = threading.Event()

    def endless():
        try:
            i = 0
            while True:
                yield i
                i += 1
        finally:
            closed.set()  # the source is closed in its own thread when the consumer leaves

    for x in prefetched(endless, depth=2):
        if x == 5:
            break
    assert closed.wait(5.0)


def test_grey_frames_can_keep_their_colour_for_the_overlay(tmp_path):
    # orient finds its lines on grey frames and draws its overlay on the colour ones: both
    # from one decoding (in the decoding thread for a video), the grey one as a detector
    # converts a colour frame; without keep_colour nothing changes
    rng = np.random.default_rng(0)
    colour = [rng.integers(0, 255, (24, 32, 3)).astype(np.uint8) for _ in range(3)]
    v = tmp_path / "v.avi"
    w = cv2.VideoWriter(str(v), cv2.VideoWriter_fourcc(*"MJPG"), 5, (32, 24))
    for c in colour:
        w.write(c)
    w.release()
    for f in colour:
        cv2.imwrite(str(tmp_path / f"f{len(list(tmp_path.glob('*.png')))}.png"), f)
    for spec in (str(v), str(tmp_path)):
        plain = list(open_images(spec))
        kept = list(open_images(spec, gray=True, keep_colour=True))
        grey = list(open_images(spec, gray=True))
        assert all(f.colour is None and f.drawable is f.image for f in plain + grey)
        for k, p in zip(kept, plain):
            assert np.array_equal(k.colour, p.image) and k.drawable is k.colour
            assert np.array_equal(k.image, cv2.cvtColor(p.image, cv2.COLOR_BGR2GRAY))
    # keep_colour alone (colour frames) keeps nothing twice
    assert all(f.colour is None for f in open_images(str(v), keep_colour=True))

"""Instrument mask files (io.instrument_masks): listing, pairing with the frames, reading, and
their one-line errors naming the file."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.images import Frame, open_images
from pencilcal.toolkit.io.instrument_masks import (mask_files, pair_masks, parse_mask_label, read_mask,
                                                   source_masks)


def test_pairing_by_stem_then_in_order():
    assert pair_masks(["a.jpg", "b.jpg"], ["m/b.png", "m/a.png"]) == {"a.jpg": "m/a.png", "b.jpg": "m/b.png"}
    # a mask for every frame by name, extra masks ignored
    assert pair_masks(["b.jpg"], ["m/a.png", "m/b.png"]) == {"b.jpg": "m/b.png"}
    # no names in common but as many: in order
    assert pair_masks(["1_img.png", "2_img.png"], ["1_label.png", "2_label.png"]) == {
        "1_img.png": "1_label.png", "2_img.png": "2_label.png"}


def test_unmatched_frames_are_named():
    with pytest.raises(InputError, match=r"masks/: 1 mask\(s\) for 3 frame\(s\), and no mask named as b.png, c.png"):
        pair_masks(["a.png", "b.png", "c.png"], ["x/a.png"], where="masks/")
    with pytest.raises(InputError, match="several masks named a"):
        pair_masks(["a.png", "b.png", "c.png"], ["x/a.png", "y/a.png"])


def test_labels():
    assert parse_mask_label("10") == 10 and parse_mask_label(" 0, 255,0") == (0, 255, 0)
    for bad in ("x", "1,2", "-1", "1.5"):
        with pytest.raises(InputError, match="expected a non-negative integer or B,G,R"):
            parse_mask_label(bad)


@pytest.fixture
def folder(tmp_path):
    (tmp_path / "frames").mkdir()
    (tmp_path / "masks").mkdir()
    for k in range(3):
        cv2.imwrite(str(tmp_path / "frames" / f"f{k}.png"), np.zeros((40, 60, 3), np.uint8))
        m = np.zeros((40, 60), np.uint16)
        m[10:20, :] = 10 + k
        cv2.imwrite(str(tmp_path / "masks" / f"f{k}.png"), m)
    return tmp_path


def test_a_source_s_masks_read_as_stored(folder):
    src = open_images(str(folder / "frames"))
    masks = source_masks(src, str(folder / "masks"), labels=["11"], instances=True)
    assert masks.labels == [11] and masks.instances
    frame = next(iter(src))
    got = masks.of(frame)
    assert got["mask"].dtype == np.uint16 and got["mask"].shape == (40, 60) and got["mask"].max() == 10
    with pytest.raises(InputError, match="all integers or all B,G,R"):
        source_masks(src, str(folder / "masks"), labels=["1", "0,255,0"])


def test_bad_mask_files_are_named(folder):
    bad = folder / "masks" / "f1.png"
    bad.write_text("not an image")
    with pytest.raises(InputError, match=r"f1.png: cannot decode the mask"):
        read_mask(bad, (40, 60))
    with pytest.raises(InputError, match=r"f0.png: the mask is 60x40 but its frame is 80x40"):
        read_mask(folder / "masks" / "f0.png", (40, 80, 3))
    (folder / "empty").mkdir()
    with pytest.raises(InputError, match="instrument masks: .*empty: no images in this folder"):
        mask_files(str(folder / "empty"))
    src = open_images(str(folder / "frames"))
    masks = source_masks(src, str(folder / "masks"))
    with pytest.raises(InputError, match="zz.png: no instrument mask paired"):
        masks.of(Frame("zz.png", 0, np.zeros((40, 60, 3), np.uint8)))

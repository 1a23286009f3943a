"""The stereo file written back: `write_stereo` round-trips through `read_stereo` and OpenCV."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from pencilcal.toolkit.camera.stereo import StereoRig, read_stereo, write_stereo
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.frames import rotation_from_rotvec

R = rotation_from_rotvec([0.01, -0.02, 0.03])
T = np.array([-5.0, 0.1, 0.2])
COV = np.diag([1e-6, 2e-6, 3e-6, 4e-4, 5e-4, 6e-4])
COV[0, 3] = COV[3, 0] = 1e-7


@pytest.mark.parametrize("name", ["extrinsics.yml", "rig.yaml", "rig.xml", "rig.json"])
def test_write_stereo_round_trips_with_its_covariance(tmp_path, name):
    write_stereo(tmp_path / name, StereoRig(R, T, cov=COV))
    rig = read_stereo(tmp_path / name)
    assert np.allclose(rig.R_right_from_left, R, atol=1e-15)
    assert np.array_equal(rig.t_right_from_left, T)
    assert np.array_equal(rig.cov, COV)


def test_write_stereo_is_what_opencv_reads_as_stereo_calibrate_output(tmp_path):
    write_stereo(tmp_path / "extrinsics.yml", StereoRig(R, T))
    fs = cv2.FileStorage(str(tmp_path / "extrinsics.yml"), cv2.FILE_STORAGE_READ)
    try:
        assert np.allclose(fs.getNode("R").mat(), R, atol=1e-15)
        assert np.array_equal(fs.getNode("T").mat().ravel(), T)
        assert fs.getNode("cov_right_from_left").empty()
    finally:
        fs.release()


def test_write_stereo_keeps_an_existing_file_and_names_the_suffixes(tmp_path):
    (tmp_path / "rig.yml").write_text("kept")
    with pytest.raises(InputError, match="already exists"):
        write_stereo(tmp_path / "rig.yml", StereoRig(R, T))
    assert (tmp_path / "rig.yml").read_text() == "kept"
    write_stereo(tmp_path / "rig.yml", StereoRig(R, T), force=True)
    assert np.array_equal(read_stereo(tmp_path / "rig.yml").t_right_from_left, T)
    with pytest.raises(InputError, match=r"rig\.txt: .*\.yml, \.yaml, \.xml .* or \.json"):
        write_stereo(tmp_path / "rig.txt", StereoRig(R, T))


def test_frames_pair_by_stem_whatever_the_folder_extension_or_order():
    from pencilcal.toolkit.camera.stereo import pair_frames

    left = [f"left/{i:04d}.png" for i in range(5)]
    right = [f"right/{i:04d}.jpg" for i in (3, 0, 4, 1, 2)]
    assert pair_frames(left, right) == [(0, 1), (1, 3), (2, 4), (3, 0), (4, 2)]
    # the eye's token in the names: L/R, left/right, beside digits or as a word of its own
    assert pair_frames(["img_L_0002.png", "img_L_0001.png"], ["img_R_0001.png", "img_R_0002.png"]) == [(0, 1), (1, 0)]
    assert pair_frames(["f3_left.png", "f4_left.png"], ["f4_right.png", "f3_right.png"]) == [(0, 1), (1, 0)]
    assert pair_frames(["left0007.png", "left0008.png"], ["right0008.png", "right0007.png"]) == [(0, 1), (1, 0)]
    # a video's frame names (no extension) pair frame for frame
    assert pair_frames(["frame_000001", "frame_000002"], ["frame_000001", "frame_000002"]) == [(0, 0), (1, 1)]


def test_frames_that_do_not_pair_by_name_are_one_line_error():
    from pencilcal.toolkit.camera.stereo import pair_frames

    left = [f"{i:04d}.png" for i in range(5)]
    # a frame dropped in the right eye: in order, every later frame would pair wrongly
    with pytest.raises(InputError) as e:
        pair_frames(left, [f"{i:04d}.png" for i in (0, 1, 3, 4, 5)])
    msg = str(e.value)
    assert "0002.png" in msg and "4 of 5" in msg and "\n" not in msg
    with pytest.raises(InputError, match="right frame 0009.png"):
        pair_frames(left[:4], [f"{i:04d}.png" for i in (0, 1, 2, 3, 9)])


def test_frames_pair_in_order_only_where_the_names_say_nothing():
    from pencilcal.toolkit.camera.stereo import pair_frames

    assert pair_frames(["a.png", "b.png"], ["c.png", "d.png"]) == [(0, 0), (1, 1)]  # no stem in common
    assert pair_frames([None, None], ["x.png", "y.png"]) == [(0, 0), (1, 1)]  # no names
    assert pair_frames(["a/1.png", "b/1.png"], ["1.png", "2.png"]) == [(0, 0), (1, 1)]  # a view's stems repeat
    with pytest.raises(InputError, match="2 and 3 frames"):
        pair_frames(["a.png", "b.png"], ["c.png", "d.png", "e.png"])

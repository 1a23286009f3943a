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

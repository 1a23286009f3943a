"""Camera conversion: the reprojection difference over the image, what formats hold, fits."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.camera.convert import (EXACT_PX, convert_camera, fit_model, nearest_model, pixel_grid,
                                              projection_difference, representable, round_trip, truncate_model)
from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.errors import InputError

K = [[612.37, 0.0, 321.19], [0.0, 611.83, 238.71], [0.0, 0.0, 1.0]]
OPENCV5 = Camera("opencv", 640, 480, K, [-0.28, 0.09, 0.0007, -0.0004, -0.012])
# thin prism terms of the size a real 12-coefficient calibration gives
OPENCV12 = Camera("opencv", 640, 480, K, [-0.28, 0.09, 0.0007, -0.0004, -0.012, 0.02, 0.004, 0.001,
                                         0.003, -0.001, 0.002, 0.0008])
FISHEYE = Camera("fisheye", 640, 480, [[300.0, 0, 319.5], [0, 300.0, 239.5], [0, 0, 1]], [0.03, -0.01, 0.002, -0.0005])


def test_pixel_grid_covers_the_image_to_its_outer_corners():
    px = pixel_grid(640, 480, 16.0)
    assert px.min(0).tolist() == [-0.5, -0.5] and px.max(0).tolist() == [639.5, 479.5]
    for corner in ([-0.5, -0.5], [639.5, -0.5], [-0.5, 479.5], [639.5, 479.5]):
        assert np.any(np.all(px == corner, axis=1))
    assert np.diff(np.unique(px[:, 0])).max() <= 16.0 and np.diff(np.unique(px[:, 1])).max() <= 16.0


def test_identical_cameras_differ_by_round_off_only():
    d = projection_difference(OPENCV12, OPENCV12)
    assert d.max_px < 1e-9 and d.rms_px <= d.max_px and d.pixels == 2 * len(pixel_grid(640, 480))


def test_a_principal_point_shift_is_measured_exactly():
    moved = Camera("pinhole", 640, 480, [[612.37, 0, 321.19 + 0.3], [0, 611.83, 238.71], [0, 0, 1]])
    d = projection_difference(Camera("pinhole", 640, 480, K), moved)
    assert d.max_px == pytest.approx(0.3, abs=1e-9) and d.rms_px == pytest.approx(0.3, abs=1e-9)


def test_rays_the_other_camera_cannot_project_count_as_infinite():
    wide = Camera("fisheye", 640, 480, [[100.0, 0, 319.5], [0, 100.0, 239.5], [0, 0, 1]], [0, 0, 0, 0])
    assert projection_difference(wide, Camera("pinhole", 640, 480, wide.K)).max_px == np.inf


def test_different_image_sizes_are_refused():
    with pytest.raises(InputError, match="image sizes"):
        projection_difference(OPENCV5, Camera("opencv", 641, 480, K, OPENCV5.dist))


@pytest.mark.parametrize("camera,name,ok,why", [
    (OPENCV12, "cam.cameramodel", True, ""),
    (OPENCV12, "cam.xml", True, ""),
    (OPENCV12, "cameras.bin", False, "12 opencv coefficients"),
    (FISHEYE, "cam.cameramodel", False, "fisheye"),
    (FISHEYE, "sparse", True, ""),
])
def test_representable_asks_the_writer(camera, name, ok, why):
    got, reason = representable(camera, name)
    assert got is ok and why in reason and "pencilcal-convert" not in reason


def test_round_trip_names_no_temporary_path():
    with pytest.raises(InputError) as e:
        round_trip(FISHEYE, "cam.cameramodel")
    assert str(e.value).startswith("a fisheye camera cannot be written as a .cameramodel")


def test_nearest_model():
    skewed = Camera("opencv", 640, 480, [[612.0, 0.4, 320.0], [0, 611.0, 240.0], [0, 0, 1]], OPENCV5.dist)
    assert nearest_model(OPENCV12, "cameras.txt") == ("opencv", 8, False)
    assert nearest_model(FISHEYE, "cam.cameramodel") == ("opencv", 12, False)
    assert nearest_model(FISHEYE, "cameras.txt") == ("fisheye", 4, False)
    assert nearest_model(skewed, "cameras.txt") == ("opencv", 5, False)
    assert nearest_model(skewed, "cam.yaml") == ("opencv", 5, True)


def test_fit_5_into_4_coefficients_beats_dropping_k3():
    truncated = projection_difference(OPENCV5, truncate_model(OPENCV5, "opencv", 4))
    fit = fit_model(OPENCV5, "opencv", 4)
    d = projection_difference(OPENCV5, fit)
    assert fit.model == "opencv" and fit.dist.size == 4 and fit.meta is None
    # measured: dropping k3 moves the corners by 1.03 px; the fit stays within 0.073 px (RMS 0.008)
    assert truncated.max_px > 1.0
    assert d.max_px < 0.08 and d.rms_px < 0.01


def test_fit_12_into_8_coefficients():
    fit = fit_model(OPENCV12, "opencv", 8)
    d = projection_difference(OPENCV12, fit)
    truncated = projection_difference(OPENCV12, truncate_model(OPENCV12, "opencv", 8))
    # measured: 1.26 px when the thin prism terms are dropped, 0.72 px (RMS 0.17) fitted;
    # the rational terms buy nothing here (their fit has a pole in the image), so k4..k6 = 0
    assert fit.dist.size == 8 and truncated.max_px > 1.2
    assert d.max_px < 0.75 and d.rms_px < 0.18


def test_fit_recovers_a_model_it_holds_exactly():
    fit = fit_model(OPENCV5, "opencv", 8)   # 5 coefficients are 8 with k4..k6 = 0
    assert projection_difference(OPENCV5, fit).max_px < 1e-6


def test_fit_fisheye_as_opencv():
    fit = fit_model(FISHEYE, "opencv", 12)
    d = projection_difference(FISHEYE, fit)
    assert fit.model == "opencv" and fit.dist.size == 12
    assert d.max_px < 0.003  # measured 0.0026 px (RMS 0.0004); the corners are 74 deg off the axis


def test_fit_refuses_rays_beyond_90_degrees():
    wide = Camera("fisheye", 640, 480, [[100.0, 0, 319.5], [0, 100.0, 239.5], [0, 0, 1]], [0, 0, 0, 0])
    with pytest.raises(InputError, match=r"reaches 1\d\d\.\d deg off the axis"):
        fit_model(wide, "opencv", 8)


def test_convert_exact_and_dropping_zero_terms():
    conv = convert_camera(OPENCV5, "cameras.txt")
    assert not conv.fitted and conv.reason == "" and conv.stored == OPENCV5 and conv.difference.max_px < 1e-9
    zero_prism = Camera("opencv", 640, 480, K, np.r_[OPENCV12.dist[:8], 0, 0, 0, 0])
    conv = convert_camera(zero_prism, "cameras.txt")
    assert not conv.fitted and "12 opencv coefficients" in conv.reason
    assert conv.camera.dist.tolist() == OPENCV12.dist[:8].tolist() and conv.difference.max_px < 1e-9


def test_convert_refuses_with_the_difference_it_would_cause():
    with pytest.raises(InputError) as e:
        convert_camera(OPENCV12, "out/cameras.txt")
    msg = str(e.value)
    assert msg.startswith("out/cameras.txt: COLMAP has no camera model for 12 opencv coefficients")
    assert "as opencv with 8 coefficients it would differ by up to 1.26 px over the image (over 0.01 px)" in msg
    # COLMAP's FULL_OPENCV with k4..k6 = 0 reads back as 5 coefficients
    assert "--approximate writes the best-fitting opencv with 5 coefficients (max 0.718 px, RMS 0.17 px" in msg
    assert "\n" not in msg


def test_convert_approximate():
    conv = convert_camera(OPENCV12, "cameras.txt", approximate=True)
    assert conv.fitted and "12 opencv coefficients" in conv.reason
    assert conv.camera.dist.size == 8 and EXACT_PX < conv.difference.max_px < 0.75
    assert conv.difference == projection_difference(OPENCV12, conv.stored)


def test_convert_refuses_a_wide_fisheye_for_mrcal_even_approximately():
    wide = Camera("fisheye", 640, 480, [[100.0, 0, 319.5], [0, 100.0, 239.5], [0, 0, 1]], [0, 0, 0, 0])
    with pytest.raises(InputError, match=r"^cam.cameramodel: a fisheye camera .*deg off the axis"):
        convert_camera(wide, "cam.cameramodel", approximate=True)

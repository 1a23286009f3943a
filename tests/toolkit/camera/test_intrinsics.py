"""The intrinsics as one vector: Jacobian, covariance record, camera files carrying it."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.camera.formats import read_camera, write_camera
from pencilcal.toolkit.camera.intrinsics import (IntrinsicsCovariance, camera_intrinsics_covariance, intrinsic_names,
                                                 intrinsics_vector, jacobian_pixels_wrt_intrinsics, with_intrinsics)
from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.errors import InputError

CAMERAS = [
    Camera("opencv", 720, 576, [[833.0, 0, 280.0], [0, 909.0, 276.0], [0, 0, 1]], [-0.32, 0.45, -0.002, 0.008, 0.7]),
    Camera("opencv", 1280, 720, [[900.0, 0, 640.0], [0, 905.0, 360.0], [0, 0, 1]],
           [-0.2, 0.05, 0.001, -0.001, 0.0, 0.01, 0.002, 0.001, 0.001, -0.001, 0.0005, 0.0002, 0.01, -0.02]),
    Camera("fisheye", 800, 800, [[300.0, 0, 399.5], [0, 301.0, 399.5], [0, 0, 1]], [0.05, -0.01, 0.003, -0.001]),
    Camera("pinhole", 640, 480, [[500.0, 0.5, 319.5], [0, 500.0, 239.5], [0, 0, 1]]),
]


@pytest.mark.parametrize("camera", CAMERAS, ids=lambda c: f"{c.model}{c.dist.size}")
def test_jacobian_matches_finite_differences(camera):
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.35, 0.35, (20, 2))
    J = jacobian_pixels_wrt_intrinsics(camera, xy)
    th = intrinsics_vector(camera)
    assert J.shape == (20, 2, th.size)
    for j in range(th.size):
        h = 1e-5 * max(abs(th[j]), 1e-2)
        e = np.zeros_like(th)
        e[j] = h
        num = (with_intrinsics(camera, th + e).pixels_from_normalized(xy)
               - with_intrinsics(camera, th - e).pixels_from_normalized(xy)) / (2 * h)
        np.testing.assert_allclose(J[:, :, j], num, rtol=1e-5, atol=1e-6 * max(1.0, np.abs(num).max()))


def test_with_intrinsics_keeps_skew_and_refuses_a_wrong_length():
    cam = CAMERAS[3]
    assert with_intrinsics(cam, intrinsics_vector(cam)).skew == 0.5
    with pytest.raises(InputError, match="5 intrinsics"):
        with_intrinsics(cam, np.ones(5))


def test_covariance_record_is_checked():
    names = intrinsic_names(CAMERAS[0])
    good = {"names": names, "cov": np.diag(np.arange(1.0, 10.0)).tolist()}
    c = IntrinsicsCovariance.from_dict(good, "cam.json")
    assert c.for_camera(CAMERAS[0]).shape == (9, 9) and c.std[0] == 1.0
    with pytest.raises(InputError, match="over fx"):
        c.for_camera(CAMERAS[2])
    bad = np.diag(np.arange(1.0, 10.0))
    bad[0, 1] = 5.0
    with pytest.raises(InputError, match="not symmetric"):
        IntrinsicsCovariance.from_dict({"names": names, "cov": bad.tolist()}, "cam.json")
    with pytest.raises(InputError, match="positive semi-definite"):
        IntrinsicsCovariance.from_dict({"names": names, "cov": (-np.eye(9)).tolist()}, "cam.json")
    with pytest.raises(InputError, match="9 x 9"):
        IntrinsicsCovariance.from_dict({"names": names, "cov": np.eye(3).tolist()}, "cam.json")


@pytest.mark.parametrize("name", ["cam.json", "cam.yaml"])
def test_camera_files_carry_the_covariance(tmp_path, name):
    cam = CAMERAS[0]
    C = np.diag(np.arange(1.0, 10.0)) * 1e-3
    C[0, 1] = C[1, 0] = 5e-4
    meta = {"cov_intrinsics": {"names": intrinsic_names(cam), "cov": C.tolist()}}
    write_camera(tmp_path / name, Camera(cam.model, cam.width, cam.height, cam.K, cam.dist, meta=meta))
    back = camera_intrinsics_covariance(read_camera(tmp_path / name))
    np.testing.assert_allclose(back.cov, C, rtol=1e-12)
    assert camera_intrinsics_covariance(cam) is None

"""The kornia undistortion and the segment angles, batched in torch, against the Camera model."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.angles import wrap_angle
from pencilcal.toolkit.pencil import estimator_torch as te
from pencilcal.toolkit.pencil import points_torch as pt
from pencilcal.toolkit.pencil import torch_backend as tb
from pencilcal.toolkit.pencil.spec import image_angles
from tests.toolkit.pencil.test_torch_estimator import closer_error

needs_torch = pytest.mark.skipif(not tb.torch_available(), reason='torch/kornia not installed (pip install -e ".[torch]")')


@needs_torch
class TestUndistortion:
    @pytest.mark.parametrize("dist", [
        [-0.3, 0.12, 0.001, -0.002, 0.0],
        [-0.3, 0.12, 0.0005, 0.0002, -0.02, 0.01, -0.003, 0.002, 0.001, -0.0005, 0.0003, 0.0001, 0.01, -0.02],
    ])
    def test_matches_camera(self, rng, dist):
        from pencilcal.toolkit.camera.model import Camera

        cam = Camera("opencv", 1920, 1080, [[1500.0, 2.0, 955.0], [0, 1498.0, 545.0], [0, 0, 1]], dist)
        px = rng.uniform([0, 0], [1919, 1079], (2000, 2))
        got = pt.undistort_points_torch(px, cam).numpy()
        np.testing.assert_allclose(got, cam.normalized_from_pixels(px), atol=1e-12)

    def test_segment_angles_of_projected_spokes(self, rng):
        from tests.helpers import fan, frame, hd_camera

        cam = hd_camera()
        pen = fan(radius=None)
        seg, R, t = frame(cam, pen, 30.0, 200.0, rng)
        x = t[:2] / t[2]
        out = pt.segment_angles_torch(seg[None], cam, vertex=x[None])
        expect = image_angles(R, x, pen.angles)
        assert out["ok"].all()
        assert np.abs(wrap_angle(out["angles"][0].numpy() - expect)).max() < 1e-9
        # and the fit on them recovers the pose
        fit = te.fit_pencils_torch(out["angles"], pen.angles, x[None], output="numpy")
        assert np.degrees(closer_error(fit, R[None])).max() < 1e-7

    def test_fisheye_refused(self):
        from tests.helpers import hd_camera

        with pytest.raises(InputError, match="fisheye"):
            pt.undistort_points_torch([[0.0, 0.0]], hd_camera("fisheye"))

"""Raw and working pixels (toolkit/detect/working.py)."""
import numpy as np

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.detect.working import to_working, to_working_points


def test_working_points_are_the_cameras_undistorted_pixels():
    """Points of any leading shape come back in that shape, the Camera's own undistortion to
    1e-9 px (the corners of a strong barrel lens included) and the same as `to_working` of
    the segments they make; a copy without a camera."""
    W, H = 854, 480
    cam = Camera("opencv", W, H, [[770.0, 0, 426.5], [0, 770.0, 239.5], [0, 0, 1]], [-0.25, 0.08, 0.001, -0.001, 0.0])
    g = np.stack(np.meshgrid(np.linspace(0, W - 1, 5), np.linspace(0, H - 1, 3)), -1)   # (3, 5, 2)
    got = to_working_points(cam, g)
    assert got.shape == g.shape
    np.testing.assert_allclose(got, cam.undistort_pixels(g.reshape(-1, 2)).reshape(g.shape), atol=1e-9)
    assert np.max(np.abs(got - g)) > 20.0                           # the lens moves the corners
    np.testing.assert_array_equal(to_working_points(cam, g[0, :4]).reshape(-1, 4), to_working(cam, g[0, :4].reshape(-1, 4)))
    same = to_working_points(None, g)
    assert np.array_equal(same, g) and same is not g

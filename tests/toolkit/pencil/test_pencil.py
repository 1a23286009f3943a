"""The pencil file and the exact forward model."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.frames import rotation_from_rotvec
from pencilcal.toolkit.pencil.spec import image_angles, pencil_from_dict, read_pencil, write_pencil


def test_regular_and_explicit_forms():
    a = pencil_from_dict({"start_deg": 10, "step_deg": 20, "count": 4})
    b = pencil_from_dict({"angles_deg": [10, 30, 50, 70]})
    np.testing.assert_allclose(a.angles, b.angles)


@pytest.mark.parametrize("d,msg", [
    ({"angles_deg": [0, 20]}, "at least three"),
    ({"angles_deg": [0, 20, 20]}, "same direction"),
    ({"angles_deg": [0, 20, "x"]}, "numbers"),
    ({"start_deg": 0, "step_deg": 20}, "needs"),
    ({"start_deg": 0, "step_deg": 20, "count": 2.5}, "positive integer"),
    ({"angles_deg": [0, 20, 40], "radius": [50, 10]}, "inner"),
    ({"angles_deg": [0, 20, 40], "vertex": [1.0]}, "vertex"),
    ({"angles_deg": [0, 20, 40], "width": -1}, "width"),
    ({"angles_deg": [0, 20, 40], "spokes": 3}, "unknown key"),
    # hostile or careless files: absurd counts, duplicates, strings where numbers belong
    ({"angles_deg": [float(a) for a in range(0, 1000)]}, "1000 spokes, over the limit of 360"),
    ({"start_deg": 0, "step_deg": 0.36, "count": 1000}, "'count' is 1000 spokes, over the limit of 360"),
    ({"start_deg": 0, "step_deg": 1, "count": 10**12}, "over the limit"),  # never allocated
    ({"angles_deg": [0, 20, 380]}, "spokes 1 and 2 share the same direction .20 and 380 deg"),
    ({"angles_deg": [0, 20, "40"]}, "'angles_deg' must be a list of 3 numbers, got '40'"),
    ({"angles_deg": [0, 20, True]}, "got True"),
    ({"start_deg": "0", "step_deg": 20, "count": 8}, "'start_deg' must be a number"),
    ({"start_deg": 0, "step_deg": float("nan"), "count": 8}, "'step_deg' must be 1 finite"),
    ({"angles_deg": [0, 20, float("inf")]}, "finite"),
    ({"angles_deg": [0, 20, 40], "vertex": ["1", 2]}, "'vertex' must be a list of 2 numbers"),
    ({"angles_deg": [0, 20, 40], "vertex": [1, float("nan")]}, "'vertex' must be 2 finite"),
    ({"angles_deg": [0, 20, 40], "radius": [10, "50"]}, "'radius' must be a list of 2 numbers"),
    ({"angles_deg": [0, 20, 40], "radius": [10, float("inf")]}, "'radius' must be 2 finite"),
    ({"angles_deg": [0, 20, 40], "width": "1.0"}, "'width' must be a number"),
    ({"angles_deg": [0, 20, 40], "width": float("nan")}, "'width' must be 1 finite"),
    ({"angles_deg": [0, 20, 40], "name": 7}, "'name' must be a string"),
])
def test_bad_pencils(d, msg):
    with pytest.raises(InputError, match=msg) as e:
        pencil_from_dict(d, "p.yaml")
    assert str(e.value).startswith("p.yaml: ") and "\n" not in str(e.value)


def test_the_spoke_limit_itself_is_allowed():
    assert pencil_from_dict({"start_deg": 0, "step_deg": 0.5, "count": 360}).count == 360


@pytest.mark.parametrize("ext", [".yaml", ".json"])
def test_round_trip(tmp_path, ext):
    p = pencil_from_dict({"angles_deg": [0, 25, 60, 110], "vertex": [230.0, 60.0], "radius": [10, 50], "width": 0.8})
    write_pencil(tmp_path / f"p{ext}", p)
    q = read_pencil(tmp_path / f"p{ext}")
    np.testing.assert_allclose(q.angles, p.angles, atol=1e-14)
    assert q.vertex.tolist() == p.vertex.tolist() and q.radius.tolist() == p.radius.tolist() and q.width == p.width
    with pytest.raises(InputError, match="already exists"):
        write_pencil(tmp_path / f"p{ext}", p)


def test_image_angles_equal_projection(rng):
    """The closed-form spoke direction equals the direction between projected points."""
    for _ in range(20):
        R = rotation_from_rotvec(rng.normal(size=3) * 0.6)
        t = np.r_[rng.uniform(-30, 30, 2), 300.0]
        if R[:, 2] @ t < 0:
            R = R @ np.diag([1.0, -1, -1])
        th = rng.uniform(0, 2 * np.pi, 5)
        x = t[:2] / t[2]
        d = R[:, :2] @ np.stack([np.cos(th), np.sin(th)])
        p = (t[:, None] + 1e-4 * d)  # points a hair along each spoke
        q = p[:2] / p[2] - x[:, None]
        np.testing.assert_allclose(np.angle(np.exp(1j * (image_angles(R, x, th) - np.arctan2(q[1], q[0])))), 0, atol=1e-6)

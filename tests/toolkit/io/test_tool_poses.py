"""The kinematics file (`io.tool_poses`): the tool's pose in the robot base per frame; every
fault one line naming the file and its line."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.frames import rotation_about_axis
from pencilcal.toolkit.io.tool_poses import read_tool_poses


def write(tmp_path, text, name="kin.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_quaternions_in_metres_and_matrices_in_mm_read_alike(tmp_path):
    R = rotation_about_axis([0.0, 1.0, 0.0], np.radians(30.0))
    c, s = np.cos(np.radians(15.0)), np.sin(np.radians(15.0))
    q = write(tmp_path, f"# dVRK PSM1 measured_cp\nimage, x_m, y_m, z_m, qw, qx, qy, qz\n"
                        f"a.png,0.01,-0.02,-0.15,{c},0,{s},0\nb.png,0,0,-0.1,1,0,0,0\n")
    m = write(tmp_path, "frame,x_mm,y_mm,z_mm," + ",".join(f"r{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3))
              + ",sigma_deg,sigma_mm\n0,10,-20,-150," + ",".join(f"{v:.12f}" for v in R.ravel()) + ",0.1,0.5\n",
              name="m.csv")
    a, b = read_tool_poses(q), read_tool_poses(m)
    assert a.keys == ["a.png", "b.png"] and b.keys == [0]
    assert np.allclose(a.positions[0], b.positions[0]) and np.allclose(a.R_base_from_tool[0], R)
    assert np.allclose(a.axes()[1][0], R[:, 2]) and a.rows.tolist() == [3, 4]
    assert b.sigma_deg.tolist() == [0.1] and a.sigma_mm.tolist() == [0.0, 0.0]
    assert a.index(["b.png", "c.png", "a.png"]).tolist() == [1, -1, 0]
    assert b.index(["x.png", "y.png"]).tolist() == [0, -1]


@pytest.mark.parametrize("text, message", [
    ("", "has no header"),
    ("x_mm,y_mm,z_mm,qw,qx,qy,qz\n", "kin.csv:1: no 'image' or 'frame' column"),
    ("image,x,y,z,qw,qx,qy,qz\n", "kin.csv:1: no tool position"),
    ("image,x_mm,y_mm,z_mm,rx,ry,rz\n", "kin.csv:1: no tool orientation"),
    ("# a comment\n\nimage,x_mm,y_mm,z_mm,rx,ry,rz\n", "kin.csv:3: no tool orientation"),
    ("image,x_mm,y_mm,z_mm,qw,qx,qy,qz\n", "header (line 1) but no poses"),
    ("image,x_mm,y_mm,z_mm,qw,qx,qy,qz\na,1,2,3,1,0,0\n", "kin.csv:2: 7 fields, the header has 8"),
    ("image,x_mm,y_mm,z_mm,qw,qx,qy,qz\na,1,2,nan,1,0,0,0\n", "kin.csv:2: z_mm is not finite"),
    ("image,x_mm,y_mm,z_mm,qw,qx,qy,qz\na,1,2,3,1,0,0,0\n\nb,1,2,x,1,0,0,0\n", "kin.csv:4: z_mm is not a number"),
    ("image,x_mm,y_mm,z_mm,qw,qx,qy,qz\na,1,2,3,0.5,0,0,0\n", "kin.csv:2: the quaternion (qw,qx,qy,qz) has norm"),
    ("image,x_mm,y_mm,z_mm,qw,qx,qy,qz\na,1,2,3,1,0,0,0\na,1,2,3,1,0,0,0\n", "kin.csv:3: image 'a' is listed twice"),
    ("frame,x_mm,y_mm,z_mm,qw,qx,qy,qz\na,1,2,3,1,0,0,0\n", "kin.csv:2: frame must be a frame index"),
    ("frame,x_mm,y_mm,z_mm,qw,qx,qy,qz\n\u00b2,1,2,3,1,0,0,0\n", "kin.csv:2: frame must be a frame index"),
    ("image,x_mm,y_mm,z_mm,qw,qx,qy,qz,sigma_deg\na,1,2,3,1,0,0,0,1\n", "sigma_deg and sigma_mm go together"),
    ("image,x_mm,y_mm,z_mm,qw,qx,qy,qz,sigma_deg,sigma_mm\na,1,2,3,1,0,0,0,1,-1\n", "kin.csv:2: sigma_deg and"),
    ("image,x_mm,y_mm,z_mm," + ",".join(f"r{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3)) + "\na,1,2,3,1,0,0,0,1,0,0,0,-1\n",
     "kin.csv:2: r11..r33 is not a rotation matrix"),
])
def test_faults_are_one_line_naming_file_and_line(tmp_path, text, message):
    with pytest.raises(InputError) as e:
        read_tool_poses(write(tmp_path, text))
    assert message in str(e.value) and "\n" not in str(e.value)
    assert str(e.value).startswith(str(tmp_path / "kin.csv"))


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_tool_poses(tmp_path / "none.csv")

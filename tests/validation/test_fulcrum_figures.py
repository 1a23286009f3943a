"""The report's fulcrum figures (validation.report.fulcrum_figures) on hand-made records:
the projected ellipsoid against the image of a sphere, a 2-D-only fulcrum off the image
with a tiny ellipse (magnified, said so), and the notes when an image or the camera is
missing."""
from __future__ import annotations

import cv2
import numpy as np

from pencilcal.toolkit.camera.formats import camera_to_dict
from pencilcal.toolkit.camera.model import Camera
from pencilcal.validation.report.document import Para, Plot
from pencilcal.validation.report.fulcrum_figures import ellipsoid_outline, fig_top_view, fulcrum_frames

K = np.array([[900.0, 0, 319.5], [0, 900.0, 239.5], [0, 0, 1]])
CAM = Camera("pinhole", 640, 480, K, [])


def test_projected_ellipsoid_is_the_image_of_a_sphere():
    # a sphere of radius r at distance d on the axis images as a circle of radius f r / sqrt(d^2 - r^2)
    for d, r in ((100.0, 2.0), (60.0, 15.0)):
        out = ellipsoid_outline(CAM, [0.0, 0.0, d], np.eye(3) * r**2, 1.0, 10.0)
        radius = np.hypot(*(out - K[:2, 2]).T)
        assert np.allclose(radius, 900.0 * r / np.sqrt(d**2 - r**2), rtol=0.01), (radius.min(), radius.max())
    # an ellipsoid that reaches behind the camera has no outline
    assert ellipsoid_outline(CAM, [0.0, 0.0, 10.0], np.eye(3) * 25.0**2, 1.0, 10.0) is None


def _data(tmp_path, rec, write=True):
    img = np.full((480, 640, 3), 120, np.uint8)
    if write:
        cv2.imwrite(str(tmp_path / "000.png"), img)
    return {"camera": camera_to_dict(CAM), "frames": [{"image": "000.png", "path": str(tmp_path / "000.png")}],
            "fulcrum": rec}


def _rec_2d(vertex):
    """A 2-D fulcrum at raw pixel `vertex` with a 0.05 px ellipse, two midlines towards it."""
    ray = np.r_[(np.asarray(vertex) - K[:2, 2]) / 900.0, 1.0]
    a, b = np.asarray(vertex) + [100.0, 300.0], np.asarray(vertex) + [-150.0, 320.0]
    return {"ok": True, "vertex_px": list(vertex), "vertex_cov_px2": [[2.5e-3, 0.0], [0.0, 1e-3]],
            "ray": (ray / np.linalg.norm(ray)).tolist(), "outliers": [{"image": "000.png", "segment": 1}],
            "midlines": [{"image": "000.png", "shaft": 0, "midline": [*(0.6 * a + 0.4 * np.asarray(vertex)), *a]},
                         {"image": "000.png", "shaft": 1, "midline": [*(0.6 * b + 0.4 * np.asarray(vertex)), *b]}],
            "truth": {"fulcrum_px": [vertex[0] + 0.02, vertex[1]]}}


def test_a_2d_fulcrum_off_the_image(tmp_path):
    rec = _rec_2d([300.0, -60.0])
    blocks = fulcrum_frames(_data(tmp_path, rec), rec, 3)
    assert len(blocks) == 1 and isinstance(blocks[0], Plot)
    cap = blocks[0].caption
    assert "68 % ellipse" in cap and "ellipsoid" not in cap and "magnified" in cap and "truth" in cap
    # the left panel shows the port above the image: the figure is drawn with it
    assert blocks[0].png[:4] == b"\x89PNG"
    assert fig_top_view(rec) is None  # no 3-D point


def test_notes_when_an_image_or_the_camera_is_missing(tmp_path):
    rec = _rec_2d([300.0, 200.0])
    blocks = fulcrum_frames(_data(tmp_path, rec, write=False), rec, 3)
    assert isinstance(blocks[0], Para) and "000.png" in blocks[0].text and "not found" in blocks[0].text
    data = _data(tmp_path, rec)
    data["camera"] = {"model": "nonesuch"}
    blocks = fulcrum_frames(data, rec, 3)
    assert len(blocks) == 1 and "camera" in blocks[0].text
    assert fulcrum_frames(data, rec, 0) == [] and fulcrum_frames(data, {**rec, "midlines": []}, 3) == []

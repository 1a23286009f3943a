"""Regenerate examples/orient: a pencil seen by a distorted camera, with exact truth.

The segments are exact projections of the spokes of examples/orient/pencil.yaml, with
0.3 px of end point noise, a missing spoke and a spurious segment in some frames, so that
`pencilcal orient` has real work to do. Run from the repository root:

    python examples/make_orient_example.py
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.camera.formats import write_camera
from pencilcal.toolkit.geometry.frames import rotation_about_axis, rotation_to_z
from pencilcal.toolkit.pencil.spec import Pencil, project_spokes, write_pencil

OUT = Path(__file__).resolve().parent / "orient"


def main():
    rng = np.random.default_rng(2026)
    K = np.array([[1500.0, 0, 955.0], [0, 1498.0, 545.0], [0, 0, 1]])
    cam = Camera("opencv", 1920, 1080, K, np.array([-0.3, 0.12, 0.0005, 0.0002, -0.02]))
    pencil = Pencil(np.radians(np.arange(8) * 20.0), np.array([0.0, 0.0]), np.array([10.0, 50.0]))
    OUT.mkdir(exist_ok=True)
    write_camera(OUT / "camera.yaml", cam, force=True)
    write_pencil(OUT / "pencil.yaml", pencil, force=True)
    frames, truth = [], []
    z = [0.0, 0.0, 1.0]
    for i, tilt in enumerate(np.linspace(0.0, 70.0, 15)):
        while True:
            px = rng.uniform([500, 300], [1400, 780])
            ray = cam.rays_from_pixels(px)
            R = (rotation_to_z(ray).T @ rotation_about_axis(z, rng.uniform(0, 2 * np.pi))
                 @ rotation_about_axis([1.0, 0, 0], np.radians(tilt)) @ rotation_about_axis(z, rng.uniform(0, 2 * np.pi)))
            t = ray * 220.0 / ray[2]
            seg = project_spokes(cam, R, t, pencil)
            if seg[:, 0::2].min() > 20 and seg[:, 0::2].max() < 1900 and seg[:, 1::2].min() > 20 and seg[:, 1::2].max() < 1060:
                break
        seg = seg + 0.3 * rng.normal(size=seg.shape)
        if i % 3 == 1:
            seg = np.delete(seg, 4, axis=0)  # a spoke the detector missed
        if i % 4 == 2:
            seg = np.r_[seg, [[200.0, 150, 520, 260]]]  # a spurious edge
        frames.append({"image": f"{i:03d}.png", "ok": True, "segments": np.round(seg, 3).tolist()})
        truth.append({"image": f"{i:03d}.png", "R_cam_from_target": R.tolist(), "t_cam_from_target": t.tolist(),
                      "normal": R[:, 2].tolist(), "vertex_px": cam.project(t).tolist(), "tilt_deg": float(tilt)})
    (OUT / "lines.json").write_text(json.dumps({"frames": frames}, indent=1) + "\n")
    (OUT / "truth.json").write_text(json.dumps({"frames": truth}, indent=1) + "\n")
    print(f"wrote {len(frames)} frames to {OUT}")


if __name__ == "__main__":
    main()

"""The validation data the report's tests draw: `synthetic` (a small validation dict made
by validate's own functions, every optional part on request), and checks of the rendered
page (self-contained, decodable images, the summary's rows, the PDF's page count)."""
from __future__ import annotations

import base64
import io
import json
import re

import numpy as np

from pencilcal.toolkit.geometry.frames import rotation_about_axis
from pencilcal.toolkit.io.files import to_jsonable
from pencilcal.validation.validate import frame_errors, summarise

Z = np.array([0.0, 0.0, 1.0])
MODELS = ("exact", "general", "aligned")
METHODS = ("sqpnp", "ippe")


def _twin(R, ray=Z):
    return rotation_about_axis(ray, np.pi) @ R @ rotation_about_axis(Z, np.pi)


def _image(path, w=640, h=480):
    import cv2

    img = np.tile(np.linspace(40, 220, w, dtype=np.uint8), (h, 1))
    cv2.imwrite(str(path), img)
    return str(path)


def synthetic(tmp_path, *, truth=True, sfm=False, calibration=False, failing=True, grid=False, images=True,
              scale=1.0, n=6):
    """A small validation dict in the layout `pencilcal validate` writes (errors and summary
    made by validate's own functions)."""
    rng = np.random.default_rng(7)
    frames = []
    vertex = np.array([320.0, 240.0])
    for i in range(n):
        name = f"{i:03d}.png"
        path = _image(tmp_path / name) if images else str(tmp_path / "gone" / name)
        if failing and i == n - 1:
            frames.append({"image": name, "ok": False, "error": "no pencil lines in this frame", "path": path,
                           "pnp": {}, "pnp_best": None, "board_corners": 0,
                           "orient": {m: {"ok": False, "error": "fewer than three segments"} for m in MODELS}})
            continue
        tilt = 5.0 + 12.0 * i
        R_ref = rotation_about_axis([1.0, 0.0, 0.0], np.radians(tilt))
        t_ref = np.array([-60.0, -40.0, 400.0])
        rec = {"image": name, "ok": True, "error": None, "path": path, "board_corners": 24,
               "reference": "truth" if truth else "pnp", "R_ref": R_ref, "t_ref": t_ref,
               "reference_tilt_deg": tilt,
               "crlb": {"tilt_deg": 0.1 * scale, "normal_deg": None if i == 0 else 0.15 * scale}}
        pnp = {}
        for m in METHODS:
            if not truth and m == "sqpnp":
                Rp = R_ref
            else:
                Rp = R_ref @ rotation_about_axis(rng.normal(size=3), np.radians(0.05 * scale))
            pnp[m] = {"image": name, "ok": True, "method": m, "R_cam_from_target": Rp, "t_cam_from_target": t_ref,
                      "reproj_rms_px": 0.1, "corners": 24, "normal_sigma_deg": 0.04 * scale}
        rec["pnp"], rec["pnp_best"] = pnp, "sqpnp"
        errors, orient = {}, {}
        for m in MODELS:
            err = 0.1 * scale * (1 + i % 3) * (30.0 if m == "aligned" else 1.0)
            R = R_ref @ rotation_about_axis(rng.normal(size=3), np.radians(err))
            Rt = _twin(R)
            ambiguous = grid or i == 2
            if i == 3 and m == "exact" and not grid:  # a wrong twin
                R, Rt = Rt, R
            if grid and i % 2:  # unresolved: the fixed rule picks the other twin here
                R, Rt = Rt, R
            o = {"image": name, "ok": True, "error": None, "vertex_px": vertex,
                 "vertex_cov_px2": [[0.01, 0], [0, 0.02]], "lines_used": 7, "rms_residual_deg": 0.05,
                 "tilt_deg": tilt + 0.05 * scale, "tilt_sigma_deg": 0.1 * scale,
                 "detectable": tilt > 6, "normal": R[:, 2], "normal_sigma_deg": 0.15 * scale, "normal_twin": Rt[:, 2],
                 "R_cam_from_target": R, "R_cam_from_target_twin": Rt, "ambiguous": ambiguous, "model": m,
                 "resolved_by": None if ambiguous else "radius", "ray": Z, "tilt_threshold_deg": 3.0,
                 "labels_ambiguous": i == 1, "spokes": [0, 1, 2, 3, 4, 5, 6, -1]}
            orient[m] = o
            errors[f"orient:{m}"] = frame_errors(R, Rt, ambiguous, R_ref, Z, o["tilt_sigma_deg"], o["normal_sigma_deg"])
        for m in METHODS:
            errors[f"pnp:{m}"] = frame_errors(pnp[m]["R_cam_from_target"], None, False, R_ref, Z, None, 0.04 * scale)
        ang = np.radians(np.arange(8) * 20.0)
        rec["segments"] = [[*(vertex + 20 * np.r_[np.cos(a), np.sin(a)]), *(vertex + 120 * np.r_[np.cos(a), np.sin(a)])]
                           for a in ang]
        rec["orient"], rec["errors"] = orient, errors
        if sfm:
            Rs = R_ref @ rotation_about_axis(rng.normal(size=3), np.radians(0.03))
            rec["sfm"] = {"registered": True, "R_cam_from_target": Rs}
            errors["sfm"] = frame_errors(Rs, None, False, R_ref, Z)
        frames.append(rec)
    keys = [f"orient:{m}" for m in MODELS] + [f"pnp:{m}" for m in METHODS] + (["sfm"] if sfm else [])
    data = {"sequence": str(tmp_path / "seq"), "images": str(tmp_path), "camera_file": "camera.json",
            "camera": {"model": "pinhole", "width": 640, "height": 480,
                       "K": [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]], "dist": []},
            "board": {"type": "charuco", "squares": [7, 5], "square": 25.0, "marker": 18.0,
                      "dictionary": "DICT_5X5_100", "legacy": False},
            "pencil": ({"grid": "auto", "angles_deg": [0, 45, 90, 135, 180, -135, -90, -45]} if grid else
                       {"angles_deg": list(np.arange(8) * 20.0), "vertex": [200.0, 60.0], "radius": [15.0, 80.0]}),
            "calibration": None, "reference": "truth" if truth else "pnp", "models": list(MODELS),
            "methods": list(METHODS), "summary": summarise(frames, keys), "frames": frames,
            "reproducibility": {"versions": {"pencilcal": "0.1.0", "python": "3.11"},
                                "command": ["pencilcal", "validate", "seq", "-o", "v.json"],
                                "inputs_sha256": {"camera.json": "0" * 64}, "created": "2026-01-01T00:00:00+0000"}}
    if sfm:
        data["sfm"] = {"registered": n - 1, "frames": n, "points3D": 1234, "alignment_inliers": n - 1,
                       "alignment_frames": n - 1, "R_world_from_target": np.eye(3), "mean_reprojection_error_px": 0.4}
    if calibration:
        data["calibration"] = {
            "images": str(tmp_path), "rms_px": 0.31, "model": "pinhole",
            "std_intrinsics": {"fx": 0.5, "fy": 0.5, "cx": 0.3, "cy": 0.3},
            "counts": {"images": n, "views_used": n - 1},
            "views": [{"image": f"{i:03d}.png", "used": i != 2, "rms_px": None if i == 4 else 0.3 + 0.01 * i}
                      for i in range(n)],
            "rejected": [{"image": "002.png", "stage": "outlier", "rms_px": 0.9, "reason": "outlier view"},
                         {"image": "001.png", "stage": "outlier", "corner": 3, "residual_px": 2.1,
                          "reason": "outlier corner"}]}
    return json.loads(json.dumps(to_jsonable(data)))  # as read back from the file


_ATTR = re.compile(r"""\b(src|href)\s*=\s*["']([^"']*)["']""", re.I)


def assert_self_contained(page):
    """No resource the browser would fetch: every src is a data: URI, every href a fragment."""
    for attr, value in _ATTR.findall(page):
        if attr.lower() == "src":
            assert value.startswith("data:image/"), value[:80]
        else:
            assert value.startswith("#"), value[:80]
    low = page.lower()
    assert "<script" not in low and "<link" not in low and "<iframe" not in low
    assert "url(" not in low and "@import" not in low
    assert not re.search(r"""(src|href)\s*=\s*["']\s*(https?:)?//""", low)


def decoded_images(page):
    from matplotlib.image import imread

    out = []
    for b64 in re.findall(r'src="data:image/png;base64,([^"]+)"', page):
        raw = base64.b64decode(b64, validate=True)
        assert raw[:8] == b"\x89PNG\r\n\x1a\n"
        img = imread(io.BytesIO(raw), format="png")
        assert img.ndim == 3 and img.shape[0] > 50 and img.shape[1] > 50
        assert float(img[..., :3].std()) > 0.01  # not blank
        out.append(img)
    return out


def pdf_pages(path):
    return len(re.findall(rb"/Type\s*/Page\b", path.read_bytes()))


def summary_rows(page):
    i = page.index('id="summary"')
    table = page[i:page.index("</table>", i)]
    return [re.sub(r"<[^>]+>", "", m).strip() for m in re.findall(r"<tr>\s*<td[^>]*>(.*?)</td>", table)]

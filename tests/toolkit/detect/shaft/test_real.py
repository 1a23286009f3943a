"""Instrument shafts on the shared real sets (../shared/data/real-instruments, SOURCE.txt).

- masked sets (dvrk-suturing-masks, box-trainer-and-greenscreen): the fraction of the
  instruments whose midline is found within 1.5 deg and 15 px of the mask reference
  (`shaft.mask.mask_axis`: the plane bisector of the straight part of each instrument's mask), and
  the detections that match none, per frame;
- the error floor: `shaft.axis.EDGE_FLOOR_PX` is what brings the masked sets' angle errors to
  chi2/N = 1; that is where it was fitted, so it is tested elsewhere: on the phantom
  sequence's fulcrum, and frame by frame on the masked sets (left out one at a time);
- dvrk-lnd-phantom-sequence (20 frames, M1/D1 of stereo_calibration_published.yaml): a shaft
  in every frame, and the fulcrum: the lines' consistent majority, the others named as
  outliers, chi2/dof of its residuals against the sigmas;
- laparoscopy-hysterectomy-frames (no masks): no crash, nothing on the frames without a
  shaft, at most two shafts a frame, and the time per frame (printed, not asserted).

The numbers reached (and the issue's targets) are in docs/method.md's shaft section; each
test asserts what the detector reaches, so that a regression fails. Every test skips with the
reason when the sets are absent.
"""
from __future__ import annotations

import re
import time

import numpy as np
import pytest

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.detect.region.detect import detect_valid_region
from pencilcal.toolkit.detect.shaft.axis import EDGE_FLOOR_PX
from pencilcal.toolkit.detect.shaft.work import axis_matrix
from pencilcal.toolkit.detect.shaft.detector import detect_shafts
from pencilcal.toolkit.errors import EstimationError
from pencilcal.toolkit.pencil.fulcrum import fulcrum_from_frames
from tests.conftest import data_dir
from pencilcal.toolkit.detect.shaft.mask import instruments_in_mask, mask_axis

pytestmark = pytest.mark.slow

ANGLE_TOL_DEG, OFFSET_TOL_PX = 1.5, 15.0
MASKED = [("dvrk-suturing-masks", f"image_{k}_img.png", f"image_{k}_label.png") for k in ("01335", "01420", "01675")]
MASKED += [("box-trainer-and-greenscreen", "box_trainer.jpg", "box_trainer_mask.png"),
           ("box-trainer-and-greenscreen", "greenscreen.png", "greenscreen_mask.png")]
NO_SHAFT = ("T_1_P6_0028", "T_1_P8_0039")  # a grasper's jaw without its shaft; no instrument's shaft


def _read(path, flags=None):
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR if flags is None else flags)
    assert img is not None, path
    return img


def _mask(path):
    import cv2

    m = _read(path, cv2.IMREAD_UNCHANGED)
    return (m[..., 1] == 255) & (m[..., 2] == 0) if m.ndim == 3 else m > 127  # dVRK: BGR (0, 255, 0)


def _line(seg):
    p, q = np.asarray(seg[:2], float), np.asarray(seg[2:], float)
    ln = np.cross(np.r_[p, 1.0], np.r_[q, 1.0])
    return ln / np.hypot(ln[0], ln[1])


def _match(shafts, refs):
    """Greedy one-to-one matching, best score first: [(shaft, ref, angle err [rad], offset
    err [px])] and the unmatched shafts."""
    pairs = []
    for i, s in enumerate(shafts):
        ls = _line(s.ideal_midline)
        for j, r in enumerate(refs):
            a = np.arccos(np.clip(abs(ls[:2] @ r.line[:2]), 0.0, 1.0))
            o = abs(ls[:2] @ r.point + ls[2])
            if np.degrees(a) <= ANGLE_TOL_DEG and o <= OFFSET_TOL_PX:
                pairs.append((i, j, a, o))
    pairs.sort(key=lambda p: -shafts[p[0]].score)
    used_s, used_r, out = set(), set(), []
    for i, j, a, o in pairs:
        if i not in used_s and j not in used_r:
            used_s.add(i)
            used_r.add(j)
            out.append((shafts[i], refs[j], a, o))
    return out, [s for i, s in enumerate(shafts) if i not in used_s]


@pytest.fixture(scope="module")
def masked():
    """Per masked frame: (name, references, detections, matches, unmatched)."""
    root = data_dir("real-instruments")
    out = []
    for folder, img_name, mask_name in MASKED:
        img = _read(root / folder / img_name)
        region = detect_valid_region([img])
        valid, K = region.mask(img.shape[:2]), axis_matrix(None, img.shape[:2])[0]
        refs = [a for a in (mask_axis(m, valid, K) for m in instruments_in_mask(_mask(root / folder / mask_name),
                                                                                min_area=3000)) if a.kind == "shaft"]
        shafts = detect_shafts(img, valid_region=region)
        got, unmatched = _match(shafts, refs)
        out.append((img_name, refs, shafts, got, unmatched))
    return out


def test_masked_sets_found_and_false(masked):
    """Reached: all 9 instruments within 1.5 deg and 15 px (target 90 %), no false detection
    (target <= 0.25 per frame). The right-hand dVRK instruments, black against a dim grey-blue
    drape as instrument-like as they are, come from the last level's second luma split
    (`shaft.regions.DARK_SPLITS`); the one in image_01420 is seen over 1.8 widths only,
    cut by the corner of the view (`shaft.material_cue._elongated`)."""
    refs = sum(len(m[1]) for m in masked)
    found = sum(len(m[3]) for m in masked)
    false = sum(len(m[4]) for m in masked) / len(masked)
    for name, r, s, got, un in masked:
        print(f"{name}: {len(r)} instruments, {len(got)} found "
              f"{[(round(float(np.degrees(a)), 3), round(float(o), 2)) for _, _, a, o in got]}, {len(un)} false")
    print(f"masked: {found}/{refs} found, {false:.2f} false per frame")
    assert refs == 9
    assert found >= 9
    assert false == 0.0


def _angle_terms(masked):
    """Per matched midline: (frame, angle error^2, its statistical variance, the floor's
    variance per px^2 of floor) [rad^2]."""
    return [(name, a * a, s.cov_stat[0, 0], s.cov_floor[0, 0]) for name, _, _, got, _ in masked for s, _, a, _ in got]


def _floor_for(terms):
    """The edge floor [px] that brings sum e^2 / (var_stat + floor^2 var_floor) / N to 1."""
    e2, vs, vf = (np.array([t[k] for t in terms]) for k in (1, 2, 3))
    lo, hi = 0.0, 50.0
    for _ in range(60):
        m = 0.5 * (lo + hi)
        lo, hi = (m, hi) if np.mean(e2 / (vs + m * m * vf)) > 1 else (lo, m)
    return 0.5 * (lo + hi)


def test_floor_is_the_masked_sets_and_holds_frame_by_frame(masked):
    """EDGE_FLOOR_PX is the masked sets' floor (fitted on all of them); left out one frame at
    a time, the floor of the others gives that frame's midlines chi2/N within the 0.999
    quantile of chi2 with their count (measured with the 9 midlines found: the fit 2.96 px,
    left out one frame at a time 2.5-3.4 px, chi2 at most 5.5, image_01335 whose left shaft's
    lower silhouette lies in its own shadow, which the mask follows)."""
    from scipy.stats import chi2

    terms = _angle_terms(masked)
    assert abs(_floor_for(terms) - EDGE_FLOOR_PX) < 0.1 * EDGE_FLOOR_PX
    for name in sorted({t[0] for t in terms}):
        fl = _floor_for([t for t in terms if t[0] != name])
        held = [t for t in terms if t[0] == name]
        c = sum(t[1] / (t[2] + fl * fl * t[3]) for t in held)
        print(f"without {name}: floor {fl:.2f} px, chi2 of its {len(held)} midline(s) {c:.2f}")
        assert c <= chi2.ppf(0.999, len(held))


def _phantom_camera(root, which="1"):
    txt = (root / "stereo_calibration_published.yaml").read_text()

    def block(name):
        m = re.search(rf"\b{name}:\s*\n\s*rows:\s*(\d+)\s*\n\s*cols:\s*(\d+)\s*\n\s*dt:\s*\w\s*\n\s*data:\s*\[([^\]]*)\]",
                      txt)
        r, c = int(m.group(1)), int(m.group(2))
        return np.array([float(x) for x in m.group(3).replace("\n", " ").split(",") if x.strip()]).reshape(r, c)

    d = block("D" + which).ravel()
    return Camera("opencv", 960, 540, block("M" + which), d[:5])


@pytest.fixture(scope="module")
def phantom():
    """(camera, frame names, detections per frame) of the phantom sequence, camera M1/D1."""
    root = data_dir("real-instruments") / "dvrk-lnd-phantom-sequence"
    paths = sorted(root.glob("*.png"), key=lambda p: int(p.stem))
    imgs = [_read(p) for p in paths]
    cam = _phantom_camera(root)
    region = detect_valid_region(imgs)
    return cam, [p.name for p in paths], [detect_shafts(im, cam, valid_region=region) for im in imgs]


def _fulcrum(cam, names, per, floor_px=EDGE_FLOOR_PX):
    frames = []
    for name, shafts in zip(names, per):
        recs = []
        for s in shafts:
            rec = s.to_dict()
            rec["angle_sigma_deg"] = float(np.degrees(np.sqrt(s.cov_stat[0, 0] + floor_px**2 * s.cov_floor[0, 0])))
            recs.append(rec)
        frames.append({"image": name, "ok": True, "segments": np.zeros((0, 4)), "shafts": recs})
    res = fulcrum_from_frames(cam, frames)
    # the lines' chi2/dof about the vertex without the port's play (which brings it to 1)
    return res, res.play["chi2_without"] / res.play["dof"]


def test_phantom_shaft_in_every_frame(phantom):
    """Reached: a detection in 20/20 frames (target: a shaft in >= 18); the frames where the
    fulcrum's majority has no line are named in test_phantom_fulcrum."""
    _, names, per = phantom
    print("detections per frame", [len(d) for d in per])
    assert sum(1 for d in per if d) >= 19


def test_phantom_fulcrum(phantom):
    """The midlines are nearly parallel (directions 170-180 deg, docs/method.md): their common
    point lies far off the image, and frames 2-6 (the shaft high in the view, long) and
    11-20 (low, short, the wrist in view) point to different ones. The fulcrum fit takes the
    consistent majority and names the other lines as outliers (the rim of the phantom's
    cavity, detected beside the shaft in some frames, among them). Reached with the floor
    of the masked sets: 16-18 frames, the lines' chi2/dof without the port's play 1.9-2.7
    from one version of the detector to the next (targets: >= 15 frames, chi2/dof <= 2);
    with the play (an offset term of every line, `fulcrum._vertex_fit`) 18 frames."""
    cam, names, per = phantom
    res, c = _fulcrum(cam, names, per)
    n_out = {}
    for o in res.outliers:
        n_out[o["image"]] = n_out.get(o["image"], 0) + 1
    left_out = [n for n, d in zip(names, per) if d and n_out.get(n, 0) == len(d)]
    print(f"fulcrum: {res.frames_used} frames, {res.lines_used} lines, chi2/dof {c:.2f}, ray sd "
          f"{res.ray_sigma_deg:.2f} deg, vertex {res.vertex_px}; {len(res.outliers)} outlier lines, frames left "
          f"out {left_out}")
    assert res.frames_used >= 15
    assert c <= 3.0
    # without the floor the sigmas are far too small for these lines: they scatter more about
    # the vertex, and the play term takes more (before it, the gate at those sigmas left
    # frames out: 16-17 with the floor, fewer without)
    try:
        res0, c0 = _fulcrum(cam, names, per, floor_px=0.0)
    except EstimationError:
        return
    print(f"without the floor: {res0.frames_used} frames, chi2/dof {c0:.2f}, play {res0.play['sigma_px']:.1f} px "
          f"(with it {res.play['sigma_px']:.1f} px)")
    assert c0 > c and res0.play["sigma_px"] > res.play["sigma_px"] > 0.0
    assert res0.frames_used >= 15


def test_laparoscopy_frames():
    """No crash; nothing on the frames without a shaft; at most two shafts a frame (the
    frames show one or two instruments). Reached: a shaft found in 11 of the 22 frames with
    one, no false detection, by eye on the overlays; blurred and distant white shafts are
    missed. The pixel evidence (`shaft.pixel_evidence`, its least value chosen on the masked
    sources) removes the pale tissue band of T_1_P13_0008 and a grey shaft in shadow on pale
    tissue whose map is weak (T_3_P6_0039, evidence 0.15): without it, 12 and one false."""
    root = data_dir("real-instruments") / "laparoscopy-hysterectomy-frames"
    paths = sorted(root.glob("*.jpg"))
    assert len(paths) == 24
    times, found = [], {}
    for p in paths:
        img = _read(p)
        region = detect_valid_region([img])
        t = time.perf_counter()
        shafts = detect_shafts(img, valid_region=region)
        times.append(time.perf_counter() - t)
        found[p.stem] = shafts
        assert len(shafts) <= 2, p.stem
        assert all(np.all(np.isfinite(s.midline)) and s.angle_sigma > 0 for s in shafts)
    print(f"laparoscopy: {sum(len(v) for v in found.values())} shafts in {len(paths)} frames, "
          f"{1e3 * np.median(times):.0f} ms per frame (median)")
    for name in NO_SHAFT:
        assert found[name] == [], name
    assert sum(1 for v in found.values() if v) >= 11

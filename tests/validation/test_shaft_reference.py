"""The reference the shaft score measures angles against: each mask's axis (`mask.mask_axis`)
set beside the axis the image's own edges give over the same stretch of the same mask
(`shaft.from_mask.shafts_from_masks`, both edges refitted on the image within the mask's
corridor).

On the in-vivo masked sources the detector's median angle error (0.68 deg on cholec, 0.95 deg
on endovis17, docs/method.md) is over the 0.5 deg target; these tests hold that the error is
mostly not the reference's: where the image shows both of a mask's edges, the mask's axis lies
within a few tenths of a degree of the image's, and the detections' own angle sd covers most of
their errors (docs/method.md, where found, how far off). Each figure is guarded, not a target.
Every test skips with the reason when ../shared/data is absent.
"""
from __future__ import annotations

import numpy as np
import pytest

from tests.validation.masked_sources import SOURCES, load_source

pytestmark = pytest.mark.slow

IN_VIVO = ("cholec", "endovis17")


def _angle_deg(l1, l2):
    return float(np.degrees(np.arccos(np.clip(abs(np.asarray(l1[:2]) @ np.asarray(l2[:2])), 0.0, 1.0))))


@pytest.fixture(scope="module")
def reference_gaps():
    """{source: [mask axis against the image's, deg] per shaft reference whose two edges the
    image shows}."""
    from pencilcal.toolkit.detect.shaft.from_mask import shafts_from_masks
    from pencilcal.validation.shaft_score import detection_line

    out = {}
    for name in IN_VIVO:
        frames, region = load_source(name)
        gaps = []
        for _, img, refs, insts in frames:
            for ref, m in zip(refs, insts):
                if ref.kind != "shaft":
                    continue
                got = [s for s in shafts_from_masks(img, [m], valid_region=region) if s.kind == "shaft"]
                if got and got[0].mask_agrees:
                    gaps.append(_angle_deg(ref.line, detection_line(got[0].midline)[0]))
        out[name] = gaps
    return out


def test_mask_axis_agrees_with_the_image(reference_gaps):
    """Where the image shows both edges of a mask, the mask's axis is the image's to 0.4 deg
    (median per source; measured 0.24 cholec, 0.23 endovis17), below the detector's median
    errors there (0.68, 0.95)."""
    for name, gaps in reference_gaps.items():
        print(name, "mask against image [deg]:", np.round(sorted(gaps), 2).tolist())
        assert len(gaps) >= 5, (name, gaps)
        assert np.median(gaps) <= 0.4, (name, np.median(gaps))


def test_detected_angle_errors_against_their_sd():
    """The detections' angle errors against the masks, in their own sd (`Shaft.angle_sigma`):
    cholec's stretches are short (50-330 px seen, 1.2-4.3 widths) and their sd covers their
    errors (rms z 0.55, 11 of 12 within 1 sd); endovis17's readings of one instrument through
    its wrist, in four frames, lie 1.8-2.5 sd off (rms z 1.57, 8 of 11 within 2 sd)."""
    from pencilcal.toolkit.detect.shaft.detector import detect_shafts
    from pencilcal.validation.shaft_score import score_frame

    for name, (rms_max, within2_min) in {"cholec": (0.8, 0.9), "endovis17": (1.8, 0.7)}.items():
        frames, region = load_source(name)
        z = []
        for _, img, refs, _ in frames:
            dets = [s.to_dict() for s in detect_shafts(img, valid_region=region, pixel_evidence=None, tissue_colour=None)]
            for d, _, a, _ in score_frame(dets, refs).matches:
                z.append(a / dets[d]["angle_sigma_deg"])
        z = np.array(z)
        print(name, "angle error / sd:", np.round(np.sort(z), 2).tolist())
        assert len(z) >= 10, name
        assert np.sqrt(np.mean(z**2)) <= rms_max, (name, z)
        assert np.mean(z <= 2.0) >= within2_min, (name, z)


def test_needle_driver_mask_is_its_silhouette_over_tube_and_shaft():
    """endovis17's needle driver (frames 000-003, the instrument at the lower right): its mask
    (all parts, 255) reads one straight part, its silver tube and its dark shaft together, and
    that is the image's silhouette: per 20 px of each of the mask's two edges, the image's edge
    fitted in a corridor of 6 px about the mask's line (`shaft.silhouette.fit_edges`, as the
    detector fits its edges) lies within 3 px of it on both materials (measured: all 72 pieces
    within 3 px, the medians per edge and material -1.5 to +2.4 px). The detector's band reads the tube with its wrist instead (1.0-1.3
    deg off in frames 000, 001, 003; docs/method.md): the reference is not what is wrong."""
    import cv2

    from pencilcal.toolkit.detect.shaft.silhouette import fit_edges
    from pencilcal.toolkit.detect.shaft.work import Validity

    frames, region = load_source("endovis17")
    for path, img, refs, insts in frames[:4]:
        H, W = img.shape[:2]
        right = [k for k, m in enumerate(insts) if np.nonzero(m)[1].mean() > 0.6 * W and np.nonzero(m)[0].mean() > 0.5 * H]
        assert len(right) == 1, path.name
        ref, m = refs[right[0]], insts[right[0]]
        assert ref.kind == "shaft" and 150 <= ref.width_px <= 170 and ref.length_px >= 180, (path.name, ref)
        grey = cv2.blur(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), (7, 7)).astype(float)
        valid, f32 = Validity(region, (H, W)), img.astype(np.float32)
        offsets = {}   # (edge, material): offsets [px], + out of the instrument
        for k, e in enumerate(ref.edges):
            a, b = e[:2], e[2:]
            v = (b - a) / np.linalg.norm(b - a)
            n = np.array([-v[1], v[0]])
            n = n if (a - ref.point) @ n > 0 else -n
            for s0 in np.arange(0.0, np.linalg.norm(b - a) - 19.0, 20.0):
                c = a + (s0 + 10.0) * v
                q = np.rint(c - 25.0 * n).astype(int)   # the instrument beside the edge
                if not m[q[1], q[0]]:
                    continue
                f = fit_edges(f32, None, valid, 2.0, [(a, v, n, s0, s0 + 20.0)], 6.0)[0]
                if f is not None:
                    key = (k, "silver" if grey[q[1], q[0]] > 90 else "dark")
                    offsets.setdefault(key, []).append(float((f.point_at(s0 + 10.0) - c) @ n))
        print(path.name, {k: np.round(v, 1).tolist() for k, v in sorted(offsets.items())})
        for material in ("silver", "dark"):   # the straight part spans both materials
            assert sum(len(v) for (_, mat), v in offsets.items() if mat == material) >= 4, (path.name, material)
        every = np.concatenate([v for v in offsets.values()])
        assert np.mean(np.abs(every) <= 3.0) >= 0.85, (path.name, offsets)
        for key, off in offsets.items():
            assert abs(np.median(off)) <= 3.0, (path.name, key, off)

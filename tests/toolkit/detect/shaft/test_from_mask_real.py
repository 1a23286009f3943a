"""Masks in on the masked real sources (tests/validation/masked_sources.py): every mask
instrument gets an axis within 1 deg and 3 px of the axis its own mask gives
(`mask.mask_axis`), the issue's bar being 98 %; the per-source table is printed (and is in
docs/method.md, masks in). Twice: on the whole frames, and within each source's valid region
detected from its frames, as the commands run (the outline on the region's boundary is then
no silhouette, for the reference as for the refinement).

The agreement threshold (`from_mask.MAX_AGREEMENT_PX`) and the mask edges' error
(`MASK_EDGE_SIGMA_PX`) were chosen on the three sources the detector was built on
(dvrk-suturing, box-trainer, greenscreen); cholec and endovis17 were not used for them.
Skips with the reason when the sets are absent.
"""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.detect.shaft.from_mask import MASK_EDGE_SIGMA_PX, shafts_from_masks
from pencilcal.toolkit.detect.shaft.mask import instruments_in_mask, mask_axis
from tests.conftest import data_dir
from tests.validation.masked_sources import SOURCES

pytestmark = pytest.mark.slow

ANGLE_DEG, OFFSET_PX = 1.0, 3.0
TUNING = ("dvrk-suturing", "box-trainer", "greenscreen")


def _frames(name):
    import cv2

    folder, images, masks, labels, instances = SOURCES[name]
    root = data_dir("real-instruments") / folder
    pairs = list(zip(sorted(root.glob(images)), sorted(root.glob(masks))))
    assert pairs, f"{name}: no frames"
    for ip, mp in pairs:
        yield ip.name, cv2.imread(str(ip), cv2.IMREAD_COLOR), cv2.imread(str(mp), cv2.IMREAD_UNCHANGED), labels, \
            instances


def _source(name, region):
    """Per instrument of the source: (angle error [deg], offset error [px], the shaft); with
    region, within the valid region detected from the source's frames."""
    from pencilcal.toolkit.detect.region.detect import detect_valid_region

    frames = list(_frames(name))
    reg = detect_valid_region([f[1] for f in frames]) if region else None
    rows = []
    for _, img, mask, labels, instances in frames:
        valid = None if reg is None or reg.covers_image(img.shape[:2]) else reg.mask(img.shape[:2])
        refs = [mask_axis(m, valid) for m in instruments_in_mask(mask, labels=labels, instances=instances)]
        shafts = shafts_from_masks(img, mask, labels=labels, instances=instances, valid_region=reg)
        assert [s.instrument for s in shafts] == list(range(len(refs)))
        for ref, sh in zip(refs, shafts):
            p, q = sh.midline[:2], sh.midline[2:]
            ln = np.cross(np.r_[p, 1.0], np.r_[q, 1.0])
            ln /= np.hypot(ln[0], ln[1])
            angle = np.degrees(np.arccos(min(1.0, abs(float(ln[:2] @ ref.line[:2])))))
            rows.append((angle, abs(float(ln[:2] @ ref.point + ln[2])), sh))
    return rows


@pytest.fixture(scope="module", params=[False, True], ids=["whole-frames", "valid-region"])
def table(request):
    return {name: _source(name, request.param) for name in SOURCES}


def test_mask_instruments_get_an_axis_within_1_deg_and_3_px_of_the_mask_s(table):
    print(f"\n{'source':14s} {'within':>8s} {'edges image/mask':>17s} {'parts':>5s} {'angle med':>9s} "
          f"{'offset med':>10s} {'mask offset p90':>15s}")
    ok = total = 0
    for name, rows in table.items():
        good = sum(a <= ANGLE_DEG and o <= OFFSET_PX for a, o, _ in rows)
        ok, total = ok + good, total + len(rows)
        edges = [f for _, _, s in rows for f in s.edge_from]
        offs = [o for _, _, s in rows for o in s.mask_offset_px if o is not None]
        print(f"{name:14s} {good:>4d}/{len(rows):<3d} {edges.count('image'):>10d}/{edges.count('mask'):<6d} "
              f"{sum(s.kind == 'part' for _, _, s in rows):>5d} {np.median([a for a, _, _ in rows]):>9.2f} "
              f"{np.median([o for _, o, _ in rows]):>10.2f} {np.percentile(offs, 90):>15.2f}")
    print(f"{'all':14s} {ok:>4d}/{total:<3d} ({100.0 * ok / total:.1f} %)")
    assert total >= 40 and ok >= 0.98 * total


def test_the_image_shows_most_edges_and_the_mask_edge_error_is_what_the_fallback_assumes(table):
    """On the sources the constants were chosen on, the image's edge is taken for nearly
    every edge, and the mask's edges lie about `MASK_EDGE_SIGMA_PX` from them (RMS at the
    ends); on the others too, at most half of the edges fall back to the mask's."""
    tuning = [s for n in TUNING for _, _, s in table[n]]
    edges = [f for s in tuning for f in s.edge_from]
    assert edges.count("image") >= 0.9 * len(edges)
    offs = np.array([o for s in tuning for o in s.mask_offset_px if o is not None])
    rms = float(np.sqrt(np.mean(offs**2)))
    print(f"\nmask edge offsets on {', '.join(TUNING)}: RMS {rms:.2f} px (of the larger end)")
    assert 0.5 * MASK_EDGE_SIGMA_PX <= rms <= 1.5 * MASK_EDGE_SIGMA_PX
    others = [f for n in SOURCES if n not in TUNING for _, _, s in table[n] for f in s.edge_from]
    assert others.count("image") >= 0.5 * len(others)

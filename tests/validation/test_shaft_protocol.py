"""The shaft detector on real frames it was not tuned on.

- Leave one source out over every masked real source (tests/validation/masked_sources.py):
  each source scored with the detector's setting chosen on the others
  (`validation.shaft_protocol`); the table is docs/method.md's. The assertions hold what the
  detector reaches now, so that a regression fails; the issue's target (>= 90 % found, <= 0.25
  false per frame on every source left out) is printed beside it, not asserted, while it is
  not reached.
- The unmasked hysterectomy frames against the hand-made list of what each frame shows
  (tests/data/real_frames_truth.yaml): a detection matching no listed instrument is false
  (target <= 0.25 per frame).
Every test skips with the reason when ../shared/data is absent.
"""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.detect.shaft.detector import detect_shafts
from pencilcal.validation.shaft_protocol import leave_one_source_out, table_markdown, view_diagonal
from pencilcal.validation.shaft_score import detection_line
from tests.validation.masked_sources import SOURCES, load_source

pytestmark = pytest.mark.slow

#: What the detector reaches per source left out (found, most false per frame): a floor. With
#: endovis17 left out the setting chosen on the others (0.1 of the view's diagonal, which keeps
#: cholec's false detections down) keeps 2 of its 7 detections (all right): the detector's
#: evidence is not comparable between sources (docs/method.md).
REACHED = {"dvrk-suturing": (6, 0.0), "box-trainer": (2, 0.0), "greenscreen": (1, 0.0), "cholec": (6, 0.5),
           "endovis17": (2, 0.0)}


@pytest.fixture(scope="module")
def detected():
    """{source: ([(references, detections) per frame], diagonal)}."""
    out = {}
    for name in SOURCES:
        frames, region = load_source(name)
        per = [(refs, [s.to_dict() for s in detect_shafts(img, valid_region=region)]) for _, img, refs, _ in frames]
        shape = frames[0][1].shape[:2]
        out[name] = (per, view_diagonal(shape, region.mask(shape)))
    return out


def test_leave_one_source_out(detected):
    rows = leave_one_source_out({k: v[0] for k, v in detected.items()}, {k: v[1] for k, v in detected.items()})
    print("\n" + table_markdown(rows))
    for r in rows:
        print(f"{r['source']}: target >= 90 % found ({0.9 * r['instruments']:.1f}), <= 0.25 false per frame")
        found, false = REACHED[r["source"]]
        assert r["found"] >= found, r
        assert r["false_per_frame"] <= false + 1e-9, r
    assert sum(r["found"] for r in rows) >= sum(f for f, _ in REACHED.values())
    # where found, as accurate as the detector is (median <= 0.5 deg on the masked sources)
    errs = [e for r in rows if r["angle_err_deg_median"] is not None for e in [r["angle_err_deg_median"]]]
    assert max(errs) <= 1.0


def _matches(det, inst, angle_deg=6.0):
    """Whether a detected midline lies along a hand-listed instrument: within angle_deg of its
    axis and its line within half a width (+ 10 px, the list's own accuracy) of the axis'
    middle."""
    ln, _ = detection_line(det["midline"])
    a = np.asarray(inst["axis"], float)
    d = (a[2:] - a[:2]) / np.linalg.norm(a[2:] - a[:2])
    ang = np.degrees(np.arccos(min(1.0, abs(float(ln[:2] @ np.array([-d[1], d[0]]))))))
    off = abs(float(ln[:2] @ (0.5 * (a[:2] + a[2:])) + ln[2]))
    return ang <= angle_deg and off <= 0.5 * inst["width_px"] + 10.0


def test_hysterectomy_false_per_frame():
    """Reached: the false detections per frame on the 24 hysterectomy frames against the
    hand-made list (target <= 0.25); detections on an uncertain entry count neither way."""
    import cv2

    from pencilcal.toolkit.detect.region.detect import detect_valid_region
    from tests.conftest import data_dir
    from tests.toolkit.detect.shaft.frames_truth import load_real_frames_truth

    root = data_dir("real-instruments") / "laparoscopy-hysterectomy-frames"
    truth = load_real_frames_truth()["laparoscopy-hysterectomy-frames"]
    false = found = total = 0
    for name, entry in sorted(truth.items()):
        img = cv2.imread(str(root / name))
        dets = [s.to_dict() for s in detect_shafts(img, valid_region=detect_valid_region([img]))]
        listed = entry["instruments"]
        for d in dets:
            hit = [i for i in listed if _matches(d, i)]
            false += not hit
        sure = [i for i in listed if not i["uncertain"]]
        total += len(sure)
        found += sum(any(_matches(d, i) for d in dets) for i in sure)
    per = false / len(truth)
    print(f"hysterectomy: {false} false in {len(truth)} frames ({per:.2f} per frame), {found}/{total} listed found")
    assert per <= 0.25

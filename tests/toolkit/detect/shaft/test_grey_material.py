"""The synthetic hard shafts (`synth.hard_shafts`) and the grey-material rule of the judges
(`shaft.grey_material`): a band darker than its sides and greyer than the tissue is kept
whatever the learned pixel map says."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.detect.region.valid import ValidRegion
from pencilcal.toolkit.detect.shaft.detector import detect_shafts
from pencilcal.toolkit.detect.shaft.grey_material import GREY_FLANK_RATIO, GREY_TISSUE_COLOUR, kept
from pencilcal.toolkit.synth.hard_shafts import HARD_CLASSES, hard_shaft_frame
from pencilcal.validation.shaft_score import score_frame


def _found(kind, seeds, **kw):
    """(found, references, false) of detect_shafts over the frames of a class."""
    f = n = fa = 0
    for s in seeds:
        img, circle, truth = hard_shaft_frame(kind, s)
        region = None if circle is None else ValidRegion.from_circle(*circle, img.shape[1], img.shape[0])
        fs = score_frame([d.to_dict() for d in detect_shafts(img, valid_region=region, **kw)], truth)
        f, n, fa = f + fs.found, n + len(truth), fa + fs.false
    return f, n, fa


@pytest.mark.parametrize("kind", HARD_CLASSES)
def test_hard_frames_truth(kind):
    """Each shaft's truth lies in the frame, its width in its class's range (scaled to the
    frame), and its inside is as much darker or brighter than the tissue beside it as its
    contrast says (the frame's luma, measured along its bisector and 1.5 widths off it;
    blur, noise, haze and texture spread it; a vignetted one's sides may be black)."""
    import cv2

    for s in range(4):
        img, _, truth = hard_shaft_frame(kind, s)
        H, W = img.shape[:2]
        assert (H, W) in ((360, 640), (480, 854))
        assert (len(truth) == 0) == (kind == "none")
        y = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY).astype(float)
        for t in truth:
            assert abs(np.hypot(*t.line[:2]) - 1.0) < 1e-9 and abs(t.line @ np.r_[t.point, 1.0]) < 1e-6
            lo, hi = {"thin": (8, 20), "faint": (12, 45), "dark": (15, 50), "vignette": (15, 50)}[kind]
            assert 0.85 * lo * min(1.0, W / 854) <= t.width_px <= hi * max(1.0, W / 854) + 1e-9
            a, b = t.edges[:, :2].mean(0), t.edges[:, 2:].mean(0)
            u = (b - a) / np.linalg.norm(b - a)
            n = np.array([-u[1], u[0]])
            q = a[None] + np.linspace(0.3, 0.7, 40)[:, None] * (b - a)[None]

            def at(P):
                P = np.clip(np.rint(P).astype(int), 0, [W - 1, H - 1])
                return float(np.median(y[P[:, 1], P[:, 0]]))

            inside = at(q)
            side = 0.5 * (at(q + 1.5 * t.width_px * n) + at(q - 1.5 * t.width_px * n))
            if kind != "vignette":  # (its sides may lie in the black surround)
                assert abs(inside - side) >= 0.2 * t.contrast


def test_kept():
    """The evidence keeps a band, or its colour where it is dark and greyer than the tissue;
    the tissue-colour limit holds for both; without the colour the evidence alone."""
    ev = np.array([0.5, 0.03, 0.03, 0.0, 0.03, 0.9])
    tc = np.array([1.0, 0.4, 0.9, -0.5, 0.4, 1.4])
    dark = np.array([True, True, True, True, False, True])
    assert kept(ev, tc, 0.1, 1.25, dark=dark).tolist() == [True, True, False, True, False, False]
    assert kept(ev, tc, 0.1, None, dark=dark).tolist() == [True, False, False, False, False, True]
    assert kept(ev, np.full(6, np.nan), 0.1, 1.25, dark=dark).tolist() == [False] * 6
    assert kept(ev, tc, 0.1, 1.25, grey=np.nan, dark=dark).tolist() == [True, False, False, False, False, False]
    assert 0.0 < GREY_TISSUE_COLOUR < 0.68  # under every real false band's (module docstring)
    # beside tissue as coloured as the frame's or more, a dark band at most GREY_FLANK_RATIO of
    # its flanks' colour is kept; a flank without the tissue's hue (<= 0, NaN) says nothing
    tc, fl = np.array([0.55, 0.55, 0.55, 0.55, 0.55, 0.3]), np.array([1.0, 0.9, -0.2, np.nan, 1.0, 2.0])
    dark = np.array([True, True, True, True, False, True])
    assert kept(np.zeros(6), tc, 0.1, 1.25, dark=dark, flank=fl).tolist() == [True, False, False, False, False, True]
    assert kept(np.zeros(6), tc, 0.1, 1.25, dark=dark).tolist() == [False] * 5 + [True]
    assert 0.5 < GREY_FLANK_RATIO < 0.84  # under every dark false band's ratio, real or synthetic (module docstring)


def test_hazy_shafts_found_by_their_grey():
    """Shafts seen through haze, 1.5-4 grey levels from the tissue, metal mirroring it: the
    cues find them, the learned map gives them little evidence (0.00-0.11); kept by their
    grey, 10 of the 18 shafts of seeds 0-11 are found (3 without the rule), with no more false
    detections (1, a short reading of a shaft cut by the frame's corner, off by over 1.5
    deg)."""
    found, n, false = _found("faint", range(12))
    assert n == 18 and found >= 10 and false <= 1


def test_black_shafts_on_shadow_kept_by_their_flanks():
    """Black shafts on shadowed tissue mirroring 30-80 % of its colour: those over half the
    frame's tissue colour but at most `GREY_FLANK_RATIO` of the tissue's right beside them are
    kept (a shadow keeps its tissue's colour: a dark band of tissue is as coloured as its
    flanks). Seeds 0-15: 10 of the 21 shafts found (7 by the frame's tissue colour alone),
    no false detection."""
    found, n, false = _found("dark", range(16))
    assert n == 21 and found >= 10 and false == 0


def test_no_shaft_in_tissue_alone():
    """The backdrop alone (folds, fat, highlights, shadows, haze, vignetting at random): no
    detection in 20 frames."""
    assert _found("none", range(20)) == (0, 0, 0)

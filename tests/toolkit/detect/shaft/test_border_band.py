"""A shaft the border of the view cuts lengthwise (`shaft.border_band`): one silhouette edge in
view, the other beyond the border; its axis read from the region between the edge and the
border as a mask's is, and no axis for a scene's edge with background or a void beyond it."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.detect.shaft.border_band import BORDER_CUE
from pencilcal.toolkit.detect.shaft.detector import detect_shafts
from pencilcal.toolkit.detect.shaft.mask import mask_axis


def _tissue(rng, H=360, W=640):
    """A reddish tissue backdrop with smooth shading and noise (BGR uint8)."""
    import cv2

    base = np.empty((H, W, 3), np.float32)
    base[:] = (70, 85, 175)
    shade = cv2.GaussianBlur(rng.normal(0, 25, (H, W)).astype(np.float32), (0, 0), 25)
    base += shade[..., None] * np.array([0.4, 0.5, 1.0], np.float32)
    base += rng.normal(0, 2.0, base.shape).astype(np.float32)
    return base


def _frame(polygon, colour, rng, extra=None):
    """The backdrop with a filled polygon (N, 2) of one colour (and an extra (polygon, colour)),
    blurred as a lens does, with streaks along x inside it (a metal shaft's sheen)."""
    import cv2

    img = _tissue(rng)
    m = np.zeros(img.shape[:2], np.uint8)
    cv2.fillConvexPoly(m, np.asarray(polygon, np.int32), 1)
    inside = np.empty_like(img)
    inside[:] = colour
    inside += rng.normal(0, 2.0, img.shape).astype(np.float32)
    img = np.where(m[..., None] > 0, inside, img)
    if extra is not None:
        q = np.zeros(img.shape[:2], np.uint8)
        cv2.fillConvexPoly(q, np.asarray(extra[0], np.int32), 1)
        img = np.where(q[..., None] > 0, np.float32(extra[1]), img)
    img = cv2.GaussianBlur(img, (0, 0), 1.2)
    return np.clip(img, 0, 255).astype(np.uint8), m > 0


#: A grey shaft across the top-right corner: its lower edge from its tip at (180, 30) to the
#: right border at (639, 150), its upper edge beyond the top border.
SHAFT = [(180, 0), (639, 0), (639, 150), (180, 30)]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_shaft_cut_lengthwise_by_the_border_gets_the_axis_its_mask_gives(seed):
    rng = np.random.default_rng(seed)
    img, truth = _frame(SHAFT, (120, 118, 122), rng)
    found = [s for s in detect_shafts(img) if s.cue == BORDER_CUE]
    ref = mask_axis(truth)
    assert ref.kind == "part" and len(found) == 1, [(s.cue, s.midline) for s in detect_shafts(img)]
    sh = found[0]
    ln = np.cross(np.r_[sh.midline[:2], 1.0], np.r_[sh.midline[2:], 1.0])
    ln /= np.hypot(ln[0], ln[1])
    angle = np.degrees(np.arccos(min(1.0, abs(float(ln[:2] @ ref.line[:2])))))
    offset = abs(float(ln[:2] @ ref.point + ln[2]))
    # the reading of the region found against the truth mask's: a part's tolerances
    # (`validation.shaft_score.Tolerance`: 8 deg, half a width), well inside them
    assert angle <= 3.0 and offset <= 0.25 * ref.width_px, (angle, offset, ref.width_px)
    assert sh.kind == "part" and np.degrees(sh.angle_sigma) >= angle
    # without the cue no shaft is found there: the two-edge cues need the far edge
    assert not [s for s in detect_shafts(img, border_bands=False) if s.cue == BORDER_CUE]
    assert not any(abs(s.midline[1] - 40) < 60 and s.midline[0] > 300 for s in detect_shafts(img, border_bands=False))


def test_a_scene_edge_with_background_running_on_beyond_it_is_no_shaft():
    # a pad's straight edge with a grey drape beyond it, the drape running on past the edge's
    # end up to the border: the material does not end with the silhouette
    rng = np.random.default_rng(3)
    drape = [(0, 0), (639, 0), (639, 150), (180, 30), (0, 30)]
    img, _ = _frame(drape, (120, 118, 122), rng)
    assert not [s for s in detect_shafts(img) if s.cue == BORDER_CUE]


def test_a_void_beyond_an_edge_is_no_shaft():
    # the dark beyond a phantom's edge (no light returned), shaped as the shaft was
    rng = np.random.default_rng(4)
    img, _ = _frame(SHAFT, (4, 4, 5), rng)
    assert not [s for s in detect_shafts(img) if s.cue == BORDER_CUE]


def _vignetted(img, falloff=0.45):
    """img darkened towards the corners as a lens' vignetting does: the light scaled by a gain
    falling from 1 at the middle to 1 - falloff at the corners (every channel alike)."""
    H, W = img.shape[:2]
    yy, xx = np.mgrid[0:H, 0:W]
    rr = np.hypot(xx - W / 2, yy - H / 2) / np.hypot(W / 2, H / 2)
    return np.clip(img * (1.0 - falloff * rr**2)[..., None], 0, 255).astype(np.uint8)


@pytest.mark.parametrize("seed", [701, 719])
def test_a_vignetted_rim_along_the_field_stop_is_no_shaft(seed):
    # a circular field whose light falls off to black at the stop: the ring of tissue the
    # vignetting darkens reads, from its inner edge, as a strip cut by the border; it keeps the
    # tissue's colour and falls towards the stop, where an instrument's material differs
    from pencilcal.toolkit.detect.region.valid import ValidRegion
    from pencilcal.toolkit.synth.hard_shafts import hard_shaft_frame
    from pencilcal.validation.shaft_score import score_frame

    img, circle, truth = hard_shaft_frame("vignette", seed)
    region = ValidRegion.from_circle(*circle, img.shape[1], img.shape[0])
    dets = detect_shafts(img, valid_region=region)
    fs = score_frame([d.to_dict() for d in dets], truth)
    assert not [dets[i].midline for i in fs.false_dets if dets[i].cue == BORDER_CUE]


def test_a_vignetted_shaft_cut_by_the_border_is_still_found():
    # the shaft darkens towards the corner with the tissue, but its grey is not the tissue's
    rng = np.random.default_rng(5)
    img, truth = _frame(SHAFT, (120, 118, 122), rng)
    img = _vignetted(img.astype(np.float32))
    found = [s for s in detect_shafts(img) if s.cue == BORDER_CUE]
    ref = mask_axis(truth)
    assert len(found) == 1
    ln = np.cross(np.r_[found[0].midline[:2], 1.0], np.r_[found[0].midline[2:], 1.0])
    ln /= np.hypot(ln[0], ln[1])
    assert np.degrees(np.arccos(min(1.0, abs(float(ln[:2] @ ref.line[:2]))))) <= 3.0

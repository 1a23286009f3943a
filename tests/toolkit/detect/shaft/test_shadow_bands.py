"""Grey shafts in shadow proposed from the edges of the tissue colour map
(`shaft.shadow_bands`): a grey band in shadow of the same lightness as the tissue beside it
is proposed; a band of the tissue's own colour in shadow, a pale band in the light and a
dark grey band on lit tissue are not; on a real frame the cue finds an instrument the other proposals miss."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.detect.shaft.regions import RegionPairs, material_map
from pencilcal.toolkit.detect.shaft.shadow_bands import MAX_SHADOW, shadow_bands, shadow_channel
from pencilcal.toolkit.detect.shaft.work import Validity, WorkFrame

_POLY = np.array([[0, 60], [420, 110], [420, 134], [0, 84]], np.int32)  # a 24 px band from the left border


def _frame(inside, seed=0, shadow=True):
    """(360, 640, 3) uint8: lit pink tissue below y 170, the same tissue in shadow above
    (dark red, luma 16) where shadow, a band of colour inside (BGR) along `_POLY`, blurred,
    with noise of 1 grey level."""
    import cv2

    rng = np.random.default_rng(seed)
    yy = np.mgrid[:360, :640][0]
    lit = np.clip((yy - 170) / 40.0, 0, 1)[..., None] if shadow else np.ones((360, 640, 1))
    img = lit * np.array([110, 130, 200], np.float32) + (1 - lit) * np.array([4, 6, 40], np.float32)
    m = np.zeros((360, 640), np.uint8)
    cv2.fillConvexPoly(m, _POLY, 1)
    img[m > 0] = inside
    img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), 1.2) + rng.normal(0, 1.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def _proposed(img):
    wf = WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=480)
    s = wf.mean_scale
    return wf, shadow_bands(wf, 8.0 * s, 150.0 * s, 25.0, material_map(wf).luma_noise, 120.0 * s)


@pytest.mark.parametrize("seed", range(3))
def test_grey_band_in_shadow_proposed(seed):
    """A grey shaft lit by the endoscope (luma 26) in the shadow of red tissue (luma 16),
    which the likeness rates alike: one band, 24 px wide, its map the shaft and not the
    tissue beside it."""
    img = _frame((24, 26, 30), seed)
    wf, (lines, pairs, maps) = _proposed(img)
    assert 1 <= len(pairs.i) <= MAX_SHADOW
    s = wf.mean_scale
    assert abs(float(pairs.width[0]) / s - 24.0) < 3.0
    # the middle of the band and tissue 30 px above it (work px)
    x = 200.0
    y = 72.0 + 50.0 * x / 420.0
    assert maps[0][int(round(y * s)), int(round(x * s))] == 1
    assert maps[0][int(round((y - 30) * s)), int(round(x * s))] == 0
    # the tissue colour map: the shaft grey, the shadowed tissue as red as the lit
    t, channel = shadow_channel(wf)
    assert t[int(round(y * s)), int(round(x * s))] < 0.5 < 0.8 < t[int(round((y - 30) * s)), int(round(x * s))]
    assert channel.min() >= 0 and channel.max() <= 255


@pytest.mark.parametrize("seed", range(2))
def test_grey_band_of_the_tissues_lightness_not_proposed(seed):
    """A grey band of the shadowed tissue's own lightness (luma 15 against 16), greyer only:
    its edges do not step in lightness by the edge pairs' least contrast, no band (a shadow
    on the tissue or a blurred thing behind it, as the hysterectomy frame below)."""
    _, (_, pairs, maps) = _proposed(_frame((14, 15, 18), seed))
    assert len(pairs.i) == 0 and maps == []


def test_tissue_coloured_band_not_proposed():
    """A deeper red band in the shadow (a fold's shadow, a gap between tissues): as coloured
    as the tissue, not greyer, no band."""
    _, (_, pairs, maps) = _proposed(_frame((3, 4, 30)))
    assert len(pairs.i) == 0 and maps == []


def test_pale_band_in_light_not_proposed():
    """A pale grey band in the light, brighter than the frame's median (a gallbladder's wall):
    the other cues' to judge, not proposed in shadow."""
    _, (_, pairs, _) = _proposed(_frame((170, 175, 185), shadow=False))
    assert len(pairs.i) == 0


@pytest.mark.parametrize("seed", range(3))
def test_dark_grey_band_on_lit_tissue_not_proposed(seed):
    """A dark grey matte shaft on lit pink tissue (luma 46 against 140 on both sides, as a
    rendered pivot's shaft): greyer than the tissue and darker than the frame's median, but
    darker than both sides, a band the grey levels outline: the grey-level proposals' to
    pair and judge, not proposed from the tissue colour."""
    _, (_, pairs, maps) = _proposed(_frame((45, 46, 50), seed, shadow=False))
    assert len(pairs.i) == 0 and maps == []


def test_cholec_grasper_found_by_its_colour(monkeypatch):
    """cholec's VID03_000210: the grasper at the top left, metal against the shadow, no band
    of the other proposals holds up: found within the score's tolerance with the cue, not
    without it."""
    from pencilcal.toolkit.detect.shaft import material_cue
    from pencilcal.toolkit.detect.shaft.detector import detect_shafts
    from pencilcal.validation.shaft_score import score_frame
    from tests.conftest import data_dir
    from tests.validation.masked_sources import load_source

    if not (data_dir("real-instruments") / "cholec-instance-masks").is_dir():
        pytest.skip("../shared/data/real-instruments/cholec-instance-masks is absent")
    frames, region = load_source("cholec")
    _, img, refs, _ = next(f for f in frames if f[0].name.endswith("VID03_000210.png"))

    def found():
        fs = score_frame([s.to_dict() for s in detect_shafts(img, valid_region=region)], refs)
        return sorted(m[1] for m in fs.matches), fs.false

    assert found() == ([0], 0)
    empty = RegionPairs(i=np.zeros(0, int), j=np.zeros(0, int), width=np.zeros(0), overlap=np.zeros(0))
    monkeypatch.setattr(material_cue, "shadow_bands", lambda *a, **k: (None, empty, []))
    assert found() == ([], 0)


def test_hysterectomy_grey_band_of_the_tissues_lightness_not_read():
    """The hysterectomy frame T_1_P13_0008: the grey band left of the instrument, which the
    frame's list calls a shadow band (its inside 63 grey levels, its sides 65 and 61), is
    no shaft; the instrument is found as before (tests/data/real_frames_truth.yaml)."""
    import cv2

    from pencilcal.toolkit.detect.region.detect import detect_valid_region
    from pencilcal.toolkit.detect.shaft.detector import detect_shafts
    from tests.conftest import data_dir
    from tests.toolkit.detect.shaft.frames_truth import load_real_frames_truth
    from tests.validation.test_shaft_protocol import _matches

    src = "laparoscopy-hysterectomy-frames"
    path = data_dir("real-instruments") / src / "T_1_P13_0008.jpg"
    if not path.is_file():
        pytest.skip(f"{path} is absent")
    img = cv2.imread(str(path))
    listed = load_real_frames_truth()[src]["T_1_P13_0008.jpg"]["instruments"]
    dets = [s.to_dict() for s in detect_shafts(img, valid_region=detect_valid_region([img]))]
    assert all(any(_matches(d, i) for i in listed) for d in dets), [d["midline"] for d in dets]


@pytest.mark.parametrize("seed", range(4))
def test_medians_as_numpy_gives_them(seed):
    """The batched medians and the luma's median from its histogram are np.median's values
    bit for bit: odd and even counts, rows with no sample, a frame with no valid pixel."""
    from pencilcal.toolkit.detect.shaft import shadow_bands as sb

    rng = np.random.default_rng(seed)
    V = rng.normal(0, 50, (40, 15)).astype(np.float32)
    ok = rng.random((40, 15)) < rng.random((40, 1))
    ok[0] = False
    got = sb._medians(V, ok)
    want = [float(np.median(v[o])) if o.any() else np.nan for v, o in zip(V, ok)]
    assert np.array_equal(got, want, equal_nan=True)
    img = rng.integers(0, 256, (61 + seed, 80, 3), dtype=np.uint8)
    mask = np.zeros(img.shape[:2], bool) if seed == 3 else rng.random(img.shape[:2]) < 0.5
    wf = WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=80)
    wf.valid = mask
    luma = wf.luma[mask] if mask.any() else wf.luma
    assert sb._luma_median(wf) == float(np.median(luma))


def _judged_first(wf, wmin, wmax, conv, noise, min_len):
    """The bands as the cue first judged them: every pair `pair_bands` keeps, then the
    shadow and lightness tests pair by pair (the pre-check's reference)."""
    from pencilcal.toolkit.detect.shaft import shadow_bands as sb
    from pencilcal.toolkit.detect.shaft.edge_pairs import MIN_CONTRAST_SD, edge_segments, pair_bands

    t, channel = shadow_channel(wf)
    seg = edge_segments(wf, min_len, channel)
    lines, pairs, _ = pair_bands(wf, wmin, wmax, conv, noise, min_len, 1.0 - t, segments=seg, with_maps=False)
    med = float(np.median(wf.luma[wf.valid]))
    keep = []
    for k, (i, j) in enumerate(zip(pairs.i, pairs.j)):
        (l_in, l_i, l_j), (t_in, t_i, t_j) = sb._cross_samples(wf, lines, [i], [j], (wf.luma, t))[0]
        if (l_in < med and t_in < min(t_i, t_j) and min(abs(l_in - l_i), abs(l_in - l_j)) >= MIN_CONTRAST_SD * noise
                and not l_in < min(l_i, l_j)):
            keep.append(k)
    return pairs.i[keep[:MAX_SHADOW]], pairs.j[keep[:MAX_SHADOW]]


@pytest.mark.parametrize("inside, shadow", [((24, 26, 30), True), ((14, 15, 18), True), ((3, 4, 30), True),
                                            ((170, 175, 185), False)])
def test_tested_before_judged_gives_the_same_bands(inside, shadow):
    """The shadow and lightness tests on every candidate before the material test (which is
    skipped where none passes) keep the bands that judging every pair first keeps."""
    img = _frame(inside, shadow=shadow)
    wf = WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=480)
    s = wf.mean_scale
    args = (wf, 8.0 * s, 150.0 * s, 25.0, material_map(wf).luma_noise, 120.0 * s)
    _, pairs, _ = shadow_bands(*args)
    i, j = _judged_first(*args)
    assert np.array_equal(pairs.i, i) and np.array_equal(pairs.j, j)

"""The shaft detector on real frames it was not tuned on.

- Leave one source out over every masked real source (tests/validation/masked_sources.py):
  each source scored with the detector's setting and least pixel evidence chosen on the
  others (`validation.shaft_protocol`); the table is docs/method.md's. The pixel model is
  trained per fold (`validation.shaft_training.fold_models`): a source's detections are
  judged by a model trained without it, and the others', when its setting is chosen, by one
  trained without either. The assertions hold what the
  detector reaches now, so that a regression fails; the issue's target (>= 90 % found, <= 0.25
  false per frame on every source left out) is printed beside it, not asserted, while it is
  not reached.
- The same with the instrument regions' axes offered (`toolkit.detect.shaft.parts`, each
  source's from the model that never saw it; the least part score chosen on the others).
- The unmasked hysterectomy frames against the hand-made list of what each frame shows
  (tests/data/real_frames_truth.yaml): a detection matching no listed instrument is false
  (target <= 0.25 per frame).
Every test skips with the reason when ../shared/data is absent.
"""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.detect.shaft.detector import detect_shafts
from pencilcal.toolkit.detect.shaft.pixel_evidence import MIN_PIXEL_EVIDENCE, pixel_evidence
from pencilcal.toolkit.detect.shaft.tissue_colour import MAX_TISSUE_COLOUR, shaft_flank_colour, shaft_tissue_colour
from pencilcal.validation.shaft_protocol import (EVIDENCES, PART_SETTINGS, TISSUE_COLOURS, choose_setting,
                                                leave_one_source_out, part_records, table_markdown,
                                                view_diagonal)
from pencilcal.validation.shaft_score import detection_line, score_frame
from tests.validation.masked_sources import SOURCES, load_source

pytestmark = pytest.mark.slow

#: What the detector reaches per source left out (found, most false per frame): a floor. The
#: pixel evidence chosen on the others removes cholec's low-scored false detections, so the
#: least score chosen for endovis17 is 0 (it was 0.1 of the view's diagonal, which kept 2 of its
#: 7 detections); with cholec left out the others have no false detection to remove and the
#: evidence chosen is 0: its false detections stay (docs/method.md). The bands from a single
#: edge (shaft.partner) find two more of cholec's; the mask's axis read by the instrument's shaft
#: (`mask.mask_axis`) turns one of cholec's false detections, on a clip applier's shaft, into a find;
#: the bands between two grey-level edges (shaft.edge_pairs) find two dark graspers more in cholec,
#: and the judge's tests for a band with one side alike (background beside an instrument) and for a
#: distal part of an instrument whose material runs on remove two of its jaw readings, one find with them;
#: a thin shaft's edges seen along 1.5 of its widths, under the least length, find one more in cholec;
#: a band's score at most the length along which both its edges are seen turns one false (edges
#: 3-4 deg off the axis, one drifting) into a find. The most tissue colour chosen on the others (1.25
#: for every source, `shaft.tissue_colour`) removes no find and no false detection here: the masked
#: sources hold no tissue gap it removes. The bands from a single edge searched into its own
#: region (`material_cue._inward_bands`) with the least elongation at the border 1.25 widths find
#: endovis17's close dark left shaft in frame003 (the factor chosen by the nested protocol for the
#: other four sources left out; for endovis17 itself they tie and 1.5 would stay: docs/method.md).
#: A band whose run the border of the view cuts, seen up to the border and elongated by its
#: instrument's material beyond its collar (`material_cue._to_border`, `_elongated`; no new
#: constant) finds endovis17's left shaft in frame000 too.
#: A strip of tissue lit beside a better shaft, its inside between its sides in lightness, is that
#: shaft's halo (`material_cue.select`): cholec's one false detection goes.
#: A band nearer the border where its material enters the view than its material's far end is no
#: distal part (`material_cue._near_entry`; no constant): cholec's thin instrument in VID03_000150.
#: A pair of grey-level edges whose inside is not one material but whose rims are, an instrument's
#: outline (`shaft.edge_pairs._outline`: a clip applier's two limbs and the slot between them),
#: finds cholec's clip applier in VID03_000120 (no protocol result: no other source has one).
#: With both, cholec 12/23 at 0 false a frame.
#: The bands into their own region kept bright or dark, on the edge pairs' colour map and only
#: along their seed, their edges not grown beyond (`material_cue._inward_bands`; no new constant)
#: find endovis17's lit grey left shaft in frame002.
#: A region band at least the least length wide whose run the border of the view cuts, counted
#: from 0.75 of its width and proposed after every other proposer (`material_cue._cut_bands`,
#: `region_bands.CUT_RUN_WIDTHS`) finds endovis17's close left shaft in frame001 (0.95 deg the
#: median angle error, 0.83 before); the other rows, the hysterectomy and the phantom unchanged.
#: A shaft the border of the view cuts lengthwise, one edge in view (`shaft.border_band`: the
#: region between that edge and the border read as a mask's is, kind part) finds endovis17's
#: top-right shaft across the frame's corner in frames 002-004 (its masks' principal axes, 0.2,
#: 4.0 and 2.4 deg off); the other rows, the hysterectomy and the phantom unchanged.
#: A grey band in shadow between two edges of the tissue colour map (`shaft.shadow_bands`; no
#: constant chosen on cholec by the protocol) finds the metal clip applier in VID03_000090 and the
#: grasper at the top left of 000210, and reads the grey grasper at the very top left of 000120
#: along its lit upper half (half its width off: false): cholec 14/23 at 0.10 false a frame (the
#: other rows unchanged; box-trainer's evidence chosen 0.4, its row the same). With the band's
#: step in lightness from both sides asked too, the same (the hysterectomy 0 false, was 1).
REACHED = {"dvrk-suturing": (6, 0.0), "box-trainer": (2, 0.0), "greenscreen": (1, 0.0), "cholec": (14, 0.1),
           "endovis17": (14, 0.0)}


@pytest.fixture(scope="module")
def detected():
    """({source: [(references, detections) per frame]}, {source: diagonal}, {held source:
    {other source: frames}}): the detections at the detector's defaults, not judged by the
    shipped pixel model, each carrying the pixel evidence of a model that never saw its
    source (and, in the choice frames, never saw the held one either)."""
    from pencilcal.validation.shaft_training import fold_models, pixel_samples

    loaded = {name: load_source(name) for name in SOURCES}
    found = {name: [detect_shafts(img, valid_region=region, pixel_evidence=None, tissue_colour=None)
                    for _, img, _, _ in frames] for name, (frames, region) in loaded.items()}
    samples = {name: [pixel_samples(img, np.any(insts, 0) if insts else np.zeros(img.shape[:2], bool), region)
                      for _, img, _, insts in frames] for name, (frames, region) in loaded.items()}
    models = fold_models(samples)
    dets, diag = {}, {}
    for name, (frames, region) in loaded.items():
        dets[name] = [[dict(s.to_dict(), tissue_colour=float(t), flank_colour=float(f))
                       for s, t, f in zip(ss, shaft_tissue_colour(img, ss, region), shaft_flank_colour(img, ss, region))]
                      for (_, img, _, _), ss in zip(frames, found[name])]
        shape = frames[0][1].shape[:2]
        diag[name] = view_diagonal(shape, region.mask(shape))

    def judged(name, left_out):
        frames, region = loaded[name]
        out = []
        model = models[frozenset(left_out)]
        for (_, img, refs, _), ds, ss in zip(frames, dets[name], found[name]):
            ev = pixel_evidence(img, ds, valid_region=region, model=model)
            # the instrument regions, from the same model (`shaft.parts`), each with the
            # detections touching it: judged with them, not against them before they are
            parts = part_records(img, ss, valid_region=region, model=model)
            out.append((refs, [dict(d, pixel_evidence=float(e)) for d, e in zip(ds, ev)] + parts))
        return out

    scored = {name: judged(name, {name}) for name in SOURCES}
    choice = {held: {o: judged(o, {o, held}) for o in SOURCES if o != held} for held in SOURCES}
    return scored, diag, choice


def test_leave_one_source_out(detected):
    scored, diag, choice = detected
    rows = leave_one_source_out(scored, diag, evidences=EVIDENCES, choice_frames=choice, colours=TISSUE_COLOURS)
    print("\n" + table_markdown(rows))
    for r in rows:
        print(f"{r['source']}: target >= 90 % found ({0.9 * r['instruments']:.1f}), <= 0.25 false per frame")
        found, false = REACHED[r["source"]]
        assert r["found"] >= found, r
        assert r["false_per_frame"] <= false + 1e-9, r
    assert sum(r["found"] for r in rows) >= sum(f for f, _ in REACHED.values())
    # where found, as accurate as the detector is (median <= 0.5 deg on the masked sources),
    # on the shafts' references (a part's principal axis is its mask's own reading, its sd
    # atan(width / length): `test_border_axes_within_their_sigmas`)
    errs = [np.median([e for e, _ in v]) for v in _shaft_errors(scored, diag, rows).values() if v]
    assert max(errs) <= 1.0
    # the shipped least evidence is the protocol's choice over all five sources, each judged
    # by a model that never saw it
    _, evidence, colour = choose_setting(scored, diag, evidences=EVIDENCES, colours=TISSUE_COLOURS)
    assert evidence == pytest.approx(MIN_PIXEL_EVIDENCE)
    # and so is the most tissue colour
    assert colour == pytest.approx(MAX_TISSUE_COLOUR)


def _shaft_errors(scored, diag, rows, kind="shaft", cue=None):
    """{source: [(angle error [deg], detection)] of the instruments of `kind` found (by
    detections of `cue`, any where None)}, each source with its setting chosen on the others
    (rows)."""
    from pencilcal.validation.shaft_protocol import filtered

    out = {}
    for r in rows:
        name = r["source"]
        out[name] = []
        for refs, dets in scored[name]:
            kept = filtered(dets, r["setting"], diag[name], r["evidence"], r["colour"], r.get("part", float("inf")))
            fs = score_frame(kept, refs)
            out[name] += [(m[2], kept[m[0]]) for m in fs.matches if refs[m[1]].kind == kind
                          and (cue is None or kept[m[0]].get("cue") == cue)]
    return out


def test_border_axes_within_their_sigmas(detected):
    """The axes of shafts cut lengthwise by the border (cue "border") that find a part's
    reference lie within 2.5 of their own angle sd (atan(width / length)) of its axis: endovis17's
    top-right shaft across the frame's corner in frames 002-004."""
    scored, diag, choice = detected
    rows = leave_one_source_out(scored, diag, evidences=EVIDENCES, choice_frames=choice, colours=TISSUE_COLOURS)
    got = [(e, d["angle_sigma_deg"]) for v in _shaft_errors(scored, diag, rows, "part", "border").values()
           for e, d in v]
    print("border axes on parts (angle error, sd) [deg]:", [(round(e, 2), round(sd, 1)) for e, sd in got])
    assert len(got) >= 3 and all(e <= 2.5 * sd for e, sd in got), got


#: With the instrument regions' axes (`shaft.parts`, `lines --shaft --parts`) offered too, the
#: least part score chosen on the others (none among the choices): what each source reaches
#: (found, most false per frame). Chosen on the others, parts are taken only where they add a
#: find there without passing 0.25 false a frame; they add none on any source, so where a
#: score is chosen (0.3 with greenscreen left out; with dvrk-suturing too before the grey bands
#: in shadow) it adds nothing there, and the parts stay
#: off by default (docs/method.md, distal parts). Since a region is grown back into the view's
#: rim, glare is no region, and an axis shorter than its width (a principal axis: two widths)
#: or with the tissue's hue is dropped, dvrk-suturing gets no false part (it got one in one of
#: its 3 frames); cholec's white hook (VID03_000180), found before by a pair of stretches
#: 86 px long across its 154 px, 4.5 deg off, is no longer read. Each region is judged with the
#: detections touching it (`part_records`, `filtered`): a band the setting drops takes no region
#: away, so a band proposed and dropped cannot make a part score look free on the others (the
#: table unchanged; with a dull grey band proposed on cholec, box-trainer stays at 0 false).
#: With the axes of shafts cut lengthwise by the border (`shaft.border_band`) endovis17 reaches
#: 14 here too (its top-right shaft's regions are then read by the border cue: the least part
#: score chosen on the others adds nothing).
PARTS_REACHED = {"dvrk-suturing": (6, 0.0), "box-trainer": (2, 0.0), "greenscreen": (1, 0.0), "cholec": (14, 0.1),
                 "endovis17": (14, 0.0)}


def test_leave_one_source_out_with_parts(detected):
    scored, diag, choice = detected
    rows = leave_one_source_out(scored, diag, evidences=EVIDENCES, choice_frames=choice, colours=TISSUE_COLOURS,
                                parts=PART_SETTINGS)
    print("\n" + table_markdown(rows))
    for r in rows:
        found, false = PARTS_REACHED[r["source"]]
        assert r["found"] >= found and r["false_per_frame"] <= false + 1e-9, r
    # the parts found where cholec's masks show a distal part alone, and their sigma: none since
    # a pair of stretches shorter than its width is no axis (the white hook's was 4.5 deg off at
    # a sd of 1.9: 2.3 sd); any found must lie within 2.5 of its own sd (docs/method.md)
    hits, how = [], []
    for refs, dets in scored["cholec"]:
        for d in dets:
            if d.get("cue") == "pixels":
                fs = score_frame([d], refs)
                hits += [(m[2], d["angle_sigma_deg"]) for m in fs.matches]
                how += [(d["kind"], round(m[3], 2), round(refs[m[1]].width_px, 1)) for m in fs.matches]
    print("cholec's parts found (angle error, sd) [deg]:", [(round(e, 2), round(s, 2)) for e, s in hits],
          "(kind, offset error [px], the reference's width [px]):", how)
    assert all(err <= 2.5 * sd for err, sd in hits), hits


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


#: Reached on the unmasked sets against their hand-made lists: the most false detections per
#: frame and the fewest listed instruments found (the target: <= 0.25 false a frame), and
#: whether the frames are one video's (one valid region from all of them, as `fulcrum IMAGES`
#: does) or several videos' (each its own). The phantom's 13 false bands in the dark gap between
#: the fat and the bowel (0.65 a frame) go by their tissue colour (`shaft.tissue_colour`,
#: docs/method.md): none is left.
UNMASKED_REACHED = {"laparoscopy-hysterectomy-frames": (0.0, 14, False),
                    "dvrk-lnd-phantom-sequence": (0.0, 19, True)}


@pytest.mark.parametrize("source", sorted(UNMASKED_REACHED))
def test_unmasked_false_per_frame(source):
    """The false detections per frame on the unmasked real frames against the hand-made list
    (target <= 0.25); detections on an uncertain entry count neither way. The frames are in no
    pixel model's training: a check of the shipped least pixel evidence. Hysterectomy: 0 false
    in 24 frames (T_1_P13_0008's grey band left of the instrument, which the list calls a
    shadow band, was proposed in shadow by `shaft.shadow_bands` until a band in shadow had to
    step in lightness from both sides too), 14 of 20 listed found; the dVRK phantom (no lens
    model given, the valid
    region from all 20 frames): the instrument in 19 of 20 frames, no false band (the 13 in
    the dark gap between fat and bowel, 0.65 a frame, pass the pixel evidence but not the
    tissue colour: 1.72-2.39 against at most 0.72 for the instrument)."""
    import cv2

    from pencilcal.toolkit.detect.region.detect import detect_valid_region
    from tests.conftest import data_dir
    from tests.toolkit.detect.shaft.frames_truth import load_real_frames_truth

    root = data_dir("real-instruments") / source
    truth = load_real_frames_truth()[source]
    imgs = {name: cv2.imread(str(root / name)) for name in sorted(truth)}
    most_false, fewest_found, one_video = UNMASKED_REACHED[source]
    shared = detect_valid_region(list(imgs.values())) if one_video else None
    false = found = total = 0
    for name, img in imgs.items():
        region = shared if shared is not None else detect_valid_region([img])
        dets = [s.to_dict() for s in detect_shafts(img, valid_region=region)]
        listed = truth[name]["instruments"]
        for d in dets:
            hit = [i for i in listed if _matches(d, i)]
            false += not hit
        sure = [i for i in listed if not i["uncertain"]]
        total += len(sure)
        found += sum(any(_matches(d, i) for d in dets) for i in sure)
    per = false / len(truth)
    print(f"{source}: {false} false in {len(truth)} frames ({per:.2f} per frame), {found}/{total} listed found"
          f" (target <= 0.25 false a frame)")
    assert per <= most_false and found >= fewest_found

"""Leave one source out: the shaft detector scored on each masked source with its setting
chosen on the others.

A detector tuned on the frames it is scored on says nothing about the next hospital's video.
The protocol here keeps the two apart. For each source in turn:

1. the detector's setting (`SETTINGS`: the least evidence a detection must have, the length
   along which its band is seen, as a fraction of the view's diagonal, `view_diagonal`; and,
   where the detections carry it, `EVIDENCES`: the least pixel evidence, the learned
   instrument map's median inside the band, `toolkit.detect.shaft.pixel_evidence`; and,
   where they carry it, `TISSUE_COLOURS`: the most tissue colour, the band's colour along
   the tissue's hue against the frame's, `toolkit.detect.shaft.tissue_colour`) is chosen on
   the *other* sources: the one that finds the most instruments there with at most
   `MAX_FALSE_PER_FRAME` false detections per frame (ties: fewer false, then the smaller
   setting and evidence, then the *smaller* most tissue colour: the masked sources hold
   few tissue gaps for it to remove, so what they measure of it is what it costs, and the
   strictest that costs nothing there is chosen);
2. the left-out source is scored with that setting (`shaft_score`).

A learned map must itself never have seen the source it judges: the scored source's
detections carry the evidence of a model trained without it, and those of the others, when
the setting is chosen for it, that of a model trained without either
(`leave_one_source_out`'s ``choice_frames``; `validation.shaft_training.fold_models`).

The table (`leave_one_source_out`) gives per source the setting chosen, found / instruments,
false per frame and the median angle and offset errors; the same run over one lab's own
annotated sources validates the detector on their frames. Detections are computed once per
frame at the detector's defaults and the setting filters them, so the protocol costs one
detection per frame.

The evidence is measured against the *view*, the valid region's bounding box, not the image:
a letterboxed da Vinci frame (1920x1080, the scene in its middle 1280x1024) shows its
instruments as large as a frame cropped to the scene, and its black bars hold none. Against
the image diagonal its shafts scored 0.06-0.09 and the setting chosen on the other sources
(0.1) dropped them all; against the view's diagonal (1611 of 2203 px) the same shafts score
0.08-0.12.

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.detect.shaft.mask import mask_axis
>>> m = np.zeros((100, 200), bool); m[40:60, :150] = True
>>> ref = [mask_axis(m)]
>>> good = {"midline": [0.0, 50.0, 140.0, 49.5], "score": 130.0}
>>> weak = {"midline": [0.0, 5.0, 60.0, 30.0], "score": 20.0}
>>> frames = {"a": [(ref, [good, weak])], "b": [(ref, [good])], "c": [(ref, [good, weak])]}
>>> rows = leave_one_source_out(frames, diagonal={k: view_diagonal(m.shape) for k in "abc"})
>>> [(r["source"], r["setting"], r["found"], r["false"]) for r in rows]
[('a', 0.1, 1, 0), ('b', 0.1, 1, 0), ('c', 0.1, 1, 0)]
>>> weak["pixel_evidence"], good["pixel_evidence"] = 0.1, 0.9                 # the map says tissue
>>> rows = leave_one_source_out(frames, {k: view_diagonal(m.shape) for k in "abc"}, evidences=(0.0, 0.5))
>>> [(r["setting"], r["evidence"], r["found"], r["false"]) for r in rows]
[(0.0, 0.5, 1, 0), (0.0, 0.5, 1, 0), (0.0, 0.5, 1, 0)]
>>> weak["pixel_evidence"], weak["tissue_colour"], good["tissue_colour"] = 0.9, 2.2, 0.1   # a tissue gap
>>> rows = leave_one_source_out(frames, {k: view_diagonal(m.shape) for k in "abc"}, colours=(1.25, float("inf")))
>>> [(r["setting"], r["colour"], r["found"], r["false"]) for r in rows]
[(0.0, 1.25, 1, 0), (0.0, 1.25, 1, 0), (0.0, 1.25, 1, 0)]
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.shaft.grey_material import kept
from pencilcal.toolkit.detect.shaft.parts import PART_CUE
from pencilcal.validation.shaft_score import Tolerance, score_frame, summarize

__all__ = ["SETTINGS", "EVIDENCES", "TISSUE_COLOURS", "PART_SETTINGS", "PART_CUE", "MAX_FALSE_PER_FRAME", "view_diagonal", "filtered", "part_records", "choose_setting", "leave_one_source_out", "table_markdown"]

#: The settings tried: the least evidence (`Shaft.score`: the length along which the band is
#: seen as a shaft) as a fraction of the view's diagonal (`view_diagonal`).
SETTINGS = (0.0, 0.05, 0.1, 0.15, 0.2, 0.3)
#: The least pixel evidences tried (`toolkit.detect.shaft.pixel_evidence`; a detection
#: without one passes).
EVIDENCES = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7)
#: The most tissue colours tried (`toolkit.detect.shaft.tissue_colour`; a detection without
#: one passes): from a quarter above the bound an instrument keeps to (1: the tissue's own
#: colour, which a metal shaft mirrors at most) to not judged (inf).
TISSUE_COLOURS = (1.25, 1.5, 2.0, 3.0, float("inf"))
#: The least scores tried for an instrument region's axis (`toolkit.detect.shaft.parts`, cue
#: `PART_CUE`: a distal part alone, or an instrument the shaft cues missed), as a fraction of
#: the view's diagonal; inf: no parts.
PART_SETTINGS = (float("inf"), 0.05, 0.1, 0.15, 0.2, 0.3)
#: The most false detections per frame a chosen setting may give on the other sources.
MAX_FALSE_PER_FRAME = 0.25


def view_diagonal(shape, valid=None):
    """The diagonal [px] of the view: the bounding box of the valid pixels (valid: (H, W)
    bool, e.g. `region.ValidRegion.mask(shape)`), the whole image (shape (H, W)) without one
    or where none is valid.

    >>> import numpy as np
    >>> v = np.zeros((1080, 1920), bool); v[28:1052, 320:1600] = True      # letterboxed
    >>> round(view_diagonal(v.shape), 1), round(view_diagonal(v.shape, v), 1)
    (2202.9, 1639.2)
    """
    H, W = int(shape[0]), int(shape[1])
    if valid is not None:
        v = np.asarray(valid, bool)
        rows, cols = np.flatnonzero(v.any(1)), np.flatnonzero(v.any(0))
        if rows.size:
            H, W = rows[-1] - rows[0] + 1, cols[-1] - cols[0] + 1
    return float(np.hypot(H, W))


def filtered(detections, setting, diagonal, evidence=0.0, colour=float("inf"), part=float("inf")):
    """The detections (list of dict, lines.json shaft records) whose score reaches setting x
    diagonal [px] (an instrument region's, cue `PART_CUE`: part x diagonal), whose
    ``pixel_evidence`` (where they carry one) reaches evidence and whose ``tissue_colour``
    (where they carry one) stays within colour; one darker than its sides and greyer than
    the tissue, or than the tissue beside it (its ``flank_colour``, where it carries one), is
    kept whatever its evidence (`toolkit.detect.shaft.grey_material.kept`). An instrument
    region's axis that carries ``touches`` (`part_records`: the positions in detections of the
    shafts touching its region) is kept only where none of them is: the jaws beyond a shaft
    found are that instrument's, a shaft dropped here found nothing."""
    keep = kept([float(d.get("pixel_evidence", 1.0)) for d in detections],
                [float(d.get("tissue_colour", 0.0)) for d in detections], evidence, colour,
                dark=np.array([d.get("polarity") == "dark" for d in detections], bool),
                flank=[float(d.get("flank_colour", np.nan)) for d in detections])
    keep = [bool(k) and float(d.get("score", 0.0)) >= (part if d.get("cue") == PART_CUE else setting) * diagonal
            for d, k in zip(detections, keep)]
    shaft = [k and d.get("cue") != PART_CUE for d, k in zip(detections, keep)]
    return [d for d, k in zip(detections, keep)
            if k and not (d.get("cue") == PART_CUE and any(shaft[j] for j in d.get("touches", ())))]


def part_records(image, shafts, first=0, *, valid_region=None, model=None):
    """The instrument regions' axes of one frame as the protocol judges them: lines.json
    records (`toolkit.detect.shaft.parts.part_axes`, the band's ``tissue_colour`` not yet
    judged), each with ``touches``, the positions of the shafts touching its region in the
    frame's detections, where shafts (`Shaft`, not yet judged) lie from position first on.
    Formed against the shafts before they are judged and judged with them (`filtered`): which
    regions are an instrument's turns on the shafts kept, not on those proposed."""
    from pencilcal.toolkit.detect.shaft.parts import part_axes
    from pencilcal.toolkit.detect.shaft.tissue_colour import shaft_tissue_colour

    axes = part_axes(image, shafts, valid_region=valid_region, model=model)
    colours = shaft_tissue_colour(image, [a for a, _ in axes], valid_region) if axes else []
    return [dict(a.to_dict(), tissue_colour=float(c), touches=[first + j for j in t])
            for (a, t), c in zip(axes, colours)]


def _scores(frames, setting, diagonal, tol, evidence=0.0, colour=float("inf"), part=float("inf")):
    return [score_frame(filtered(dets, setting, diagonal, evidence, colour, part), refs, tol) for refs, dets in frames]


def choose_setting(sources, diagonal, settings=SETTINGS, tol=Tolerance(), max_false=MAX_FALSE_PER_FRAME,
                   evidences=(0.0,), colours=(float("inf"),), parts=None):
    """The (setting, evidence, most tissue colour) that finds the most instruments over
    `sources` ({name: [(references, detections) per frame]}) with at most max_false false
    detections per frame (ties: fewer false, then the smaller setting, then the smaller
    evidence, then the smaller colour); the one with the fewest false when none keeps to it.
    parts: the least part scores tried (`PART_SETTINGS`; ties: the larger, no parts first):
    the choice is then (setting, evidence, colour, part)."""
    best = None
    for s in settings:
        for e in evidences:
            for c in colours:
                for p in (float("inf"),) if parts is None else parts:
                    S = summarize([f for name, frames in sources.items()
                                   for f in _scores(frames, s, diagonal[name], tol, e, c, p)])
                    key = (S["false_per_frame"] <= max_false, S["found"], -S["false"], -s, -e, -c, p)
                    if best is None or key > best[0]:
                        best = (key, (s, e, c, p))
    return best[1][:3] if parts is None else best[1]


def leave_one_source_out(frames, diagonal, settings=SETTINGS, tol=Tolerance(), max_false=MAX_FALSE_PER_FRAME,
                         evidences=(0.0,), choice_frames=None, colours=(float("inf"),), parts=None):
    """The protocol's table (module docstring).

    Parameters
    ----------
    frames : dict
        {source: [(references (list of MaskAxis), detections (list of dict)) per frame]}.
    diagonal : dict
        {source: its view's diagonal [px] (`view_diagonal`)}.
    evidences : sequence of float
        The least pixel evidences tried (`EVIDENCES`; (0,): none).
    choice_frames : dict, optional
        {held source: {other source: frames}}: the others' frames the setting for the held
        source is chosen on (their detections' pixel evidence from a model that saw neither);
        default `frames`.
    colours : sequence of float
        The most tissue colours tried (`TISSUE_COLOURS`; (inf,): none).
    parts : sequence of float, optional
        The least part scores tried (`PART_SETTINGS`); default none (no parts).

    Returns
    -------
    list of dict
        Per source: source, setting, evidence, colour and part (chosen on the others), and
        `shaft_score.summarize`'s keys for the source scored with them.
    """
    rows = []
    for held in frames:
        pool = frames if choice_frames is None else {**frames, **choice_frames.get(held, {})}
        others = {k: v for k, v in pool.items() if k != held}
        s, e, c, p = choose_setting(others, diagonal, settings, tol, max_false, evidences, colours,
                                    (float("inf"),) if parts is None else parts) if others \
            else (settings[0], 0.0, float("inf"), float("inf"))
        rows.append({"source": held, "setting": s, "evidence": e, "colour": c, "part": p,
                     **summarize(_scores(frames[held], s, diagonal[held], tol, e, c, p))})
    return rows


def table_markdown(rows):
    """The table as Markdown (docs/method.md)."""
    out = ["| source left out | setting chosen on the others | pixel evidence chosen on the others | "
           "most tissue colour chosen on the others | least part score chosen on the others | found | "
           "false per frame | median angle error | median offset error |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        a = "-" if r["angle_err_deg_median"] is None else f"{r['angle_err_deg_median']:.2f} deg"
        o = "-" if r["offset_err_px_median"] is None else f"{r['offset_err_px_median']:.1f} px"
        out.append(f"| {r['source']} | {r['setting']:g} | {r.get('evidence', 0.0):g} | "
                   f"{r.get('colour', float('inf')):g} | {r.get('part', float('inf')):g} | "
                   f"{r['found']}/{r['instruments']} | "
                   f"{r['false_per_frame']:.2f} | {a} | {o} |")
    return "\n".join(out)


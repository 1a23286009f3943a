"""Leave one source out: the shaft detector scored on each masked source with its setting
chosen on the others.

A detector tuned on the frames it is scored on says nothing about the next hospital's video.
The protocol here keeps the two apart. For each source in turn:

1. the detector's setting (`SETTINGS`: the least evidence a detection must have, as a
   fraction of the image diagonal along which its band is seen) is chosen on the *other*
   sources: the one that finds the most instruments there with at most `MAX_FALSE_PER_FRAME`
   false detections per frame (ties: fewer false);
2. the left-out source is scored with that setting (`shaft_score`).

The table (`leave_one_source_out`) gives per source the setting chosen, found / instruments,
false per frame and the median angle and offset errors; the same run over one lab's own
annotated sources validates the detector on their frames. Detections are computed once per
frame at the detector's defaults and the setting filters them, so the protocol costs one
detection per frame.

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.detect.shaft.mask import mask_axis
>>> m = np.zeros((100, 200), bool); m[40:60, :150] = True
>>> ref = [mask_axis(m)]
>>> good = {"midline": [0.0, 50.0, 140.0, 49.5], "score": 130.0}
>>> weak = {"midline": [0.0, 5.0, 60.0, 30.0], "score": 20.0}
>>> frames = {"a": [(ref, [good, weak])], "b": [(ref, [good])], "c": [(ref, [good, weak])]}
>>> rows = leave_one_source_out(frames, diagonal={"a": 224.0, "b": 224.0, "c": 224.0})
>>> [(r["source"], r["setting"], r["found"], r["false"]) for r in rows]
[('a', 0.1, 1, 0), ('b', 0.1, 1, 0), ('c', 0.1, 1, 0)]
"""
from __future__ import annotations

from pencilcal.validation.shaft_score import Tolerance, score_frame, summarize

__all__ = ["SETTINGS", "MAX_FALSE_PER_FRAME", "filtered", "choose_setting", "leave_one_source_out", "table_markdown"]

#: The settings tried: the least evidence (`Shaft.score`: the length along which the band is
#: seen as a shaft) as a fraction of the image diagonal.
SETTINGS = (0.0, 0.05, 0.1, 0.15, 0.2, 0.3)
#: The most false detections per frame a chosen setting may give on the other sources.
MAX_FALSE_PER_FRAME = 0.25


def filtered(detections, setting, diagonal):
    """The detections (list of dict, lines.json shaft records) whose score reaches setting x
    diagonal [px]."""
    return [d for d in detections if float(d.get("score", 0.0)) >= setting * diagonal]


def _scores(frames, setting, diagonal, tol):
    return [score_frame(filtered(dets, setting, diagonal), refs, tol) for refs, dets in frames]


def choose_setting(sources, diagonal, settings=SETTINGS, tol=Tolerance(), max_false=MAX_FALSE_PER_FRAME):
    """The setting that finds the most instruments over `sources` ({name: [(references,
    detections) per frame]}) with at most max_false false detections per frame (ties: fewer
    false, then the smaller setting); the one with the fewest false when none keeps to it."""
    best = None
    for s in settings:
        S = summarize([f for name, frames in sources.items() for f in _scores(frames, s, diagonal[name], tol)])
        key = (S["false_per_frame"] <= max_false, S["found"], -S["false"], -s)
        if best is None or key > best[0]:
            best = (key, s)
    return best[1]


def leave_one_source_out(frames, diagonal, settings=SETTINGS, tol=Tolerance(), max_false=MAX_FALSE_PER_FRAME):
    """The protocol's table (module docstring).

    Parameters
    ----------
    frames : dict
        {source: [(references (list of MaskAxis), detections (list of dict)) per frame]}.
    diagonal : dict
        {source: its images' diagonal [px]}.

    Returns
    -------
    list of dict
        Per source: source, setting (chosen on the others), and `shaft_score.summarize`'s keys
        for the source scored with it.
    """
    rows = []
    for held in frames:
        others = {k: v for k, v in frames.items() if k != held}
        s = choose_setting(others, diagonal, settings, tol, max_false) if others else settings[0]
        rows.append({"source": held, "setting": s, **summarize(_scores(frames[held], s, diagonal[held], tol))})
    return rows


def table_markdown(rows):
    """The table as Markdown (docs/method.md)."""
    out = ["| source left out | setting chosen on the others | found | false per frame | median angle error | "
           "median offset error |", "|---|---|---|---|---|---|"]
    for r in rows:
        a = "-" if r["angle_err_deg_median"] is None else f"{r['angle_err_deg_median']:.2f} deg"
        o = "-" if r["offset_err_px_median"] is None else f"{r['offset_err_px_median']:.1f} px"
        out.append(f"| {r['source']} | {r['setting']:g} | {r['found']}/{r['instruments']} | "
                   f"{r['false_per_frame']:.2f} | {a} | {o} |")
    return "\n".join(out)


"""One frame of a radial target as `pencilcal orient IMAGES` measures it.

Two steps around the detector and the estimator, shared by the command and a Python user:

1. `radial_frame`: a radial target's edges (a star's wedges, a dartboard's sector boundaries)
   detected and oriented, each edge trimmed where it runs on past the ring the spokes end on
   (`toolkit.detect.radial.trimmed_at_spokes_end`, as `validate` and the photographs' checks
   measure them);
2. `as_star_frame`: a pencil file of plain lines all round the vertex (`spec.may_be_star`)
   whose bars fitted poorly (`wants_star`) measured again as a Siemens star's wedges along
   those lines (`spec.as_star`), both polarities, the best measurement kept (`star_key`).

The orientation itself is the caller's (``orient(pencil, lines record, keep_lines)``: the
command's holds its prior, model and noise options); so is the tracking state, a dict with
``previous`` (the previous frame's orientation or None) and ``tracked`` (a count), or None.

Example
-------
>>> def orient(pen, fr, keep):                                        # doctest: +SKIP
...     return orient_segments(cam, fr["segments"], pen, keep_lines=keep, ideal=fr.get("ideal"))
>>> fr, rec = radial_frame("f.png", image, cam, star, "auto", kw, orient)  # doctest: +SKIP
"""
from __future__ import annotations

__all__ = ["STAR_FALLBACK", "star_key", "wants_star", "radial_frame", "as_star_frame"]

#: A pencil of lines all round its vertex without a bar width (`spec.may_be_star`) whose bars
#: fit fewer of its spokes than this fraction, or leave the twin unresolved, is measured
#: again as a Siemens star's wedges along them: the fraction `orient` warns at.
STAR_FALLBACK = 0.9


def star_key(rec, pencil):
    """How good one measurement of a `may_be_star` frame is, compared as a tuple: an
    estimate, most spokes used (STAR_FALLBACK of them), the twin resolved, the spokes used.

    >>> from types import SimpleNamespace as R; from pencilcal.toolkit.pencil.spec import pencil_from_dict
    >>> pen = pencil_from_dict({"start_deg": 0, "step_deg": 5.625, "count": 64})
    >>> star_key(R(ok=True, spokes_used=60, ambiguous=False), pen)
    (True, True, True, 60)
    """
    used = int(rec.spokes_used or 0) if rec.ok else 0
    return bool(rec.ok), used >= STAR_FALLBACK * pencil.count, bool(rec.ok and not rec.ambiguous), used


def wants_star(rec, pencil):
    """Whether a frame measured as bars of `pencil` is measured again as a star's wedges
    (`as_star_frame`): the file's lines may be a star's (`spec.may_be_star`) and the bars'
    orientation `rec` is missing, used under STAR_FALLBACK of the spokes or left the twin open."""
    from pencilcal.toolkit.pencil.spec import may_be_star

    return may_be_star(pencil) and star_key(rec, pencil)[:3] != (True, True, True)


def radial_frame(name, image, camera, pencil, detector, lines_kw, orient, state=None):
    """A radial target's edges in one frame and their orientation, each edge trimmed where it
    runs on past the ring the spokes end on (a dartboard's double ring), as
    `toolkit.detect.radial.trimmed_at_spokes_end` detects and orients them: (lines record
    (dict), orientation).

    image: the decoded frame (H, W) or (H, W, 3); lines_kw: `detect.lines.detect_frame_lines`'
    keywords (``radial``, ``radial_joint`` and ``valid_region`` among them); orient(pencil,
    lines record, keep_lines): the orientation of one record; state: the tracking state
    (module docstring) or None. Both passes start from the state as the previous frame left
    it; the orientation is returned without its labelled lines.
    """
    from pencilcal.toolkit.detect.edges import DEFAULT_GAMMA
    from pencilcal.toolkit.detect.image import GrayImage
    from pencilcal.toolkit.detect.lines import detect_frame_lines
    from pencilcal.toolkit.detect.radial import trimmed_at_spokes_end

    before = None if state is None else (state["previous"], state["tracked"])
    memo = {}  # the second pass reuses the edges the first located

    def detect(outer, predicted=None):
        return detect_frame_lines(name, image, camera, detector, radial_outer=outer, radial_memo=memo,
                                  radial_predicted=predicted, **lines_kw)

    def oriented(found):
        if state is not None:
            state.update(previous=before[0], tracked=before[1])
        rec = orient(pencil, found.to_dict(), True)  # the ring's estimate needs the labelled lines
        if state is not None and state["previous"] is not None:
            state["previous"] = state["previous"].replace(lines=None)
        return rec

    img = GrayImage(image, lines_kw.get("valid_region"))
    found, rec = trimmed_at_spokes_end(detect, oriented, camera, pencil, img, lines_kw["radial_joint"],
                                       lines_kw.get("gamma", DEFAULT_GAMMA))
    if state is not None and not rec.ok:
        state["previous"] = None  # a final labelling refused after `orient` kept it is no frame to track from
    return found.to_dict(), rec.replace(lines=None)


def as_star_frame(name, image, camera, pencil, detector, lines_kw, orient, bars, state=None, before=None):
    """A frame whose plain pencil file's lines (`spec.may_be_star`) the bars fitted poorly,
    measured as the wedges of a star along them (`spec.as_star`) by `radial_frame`: dark on
    light, then light on dark unless the first used most spokes and resolved the twin.
    Returns the best measurement (`star_key`; on a tie the bars', `bars`: (lines record,
    orientation)), its orientation that of the file's pencil (the same spokes and target
    frame). Each measurement starts from the tracking state `before` the bars' (a dict; both
    None without tracking); `state` is left as the kept measurement left it. Other arguments
    as `radial_frame`'s (lines_kw: the bars' keywords; its bar options are replaced).
    """
    from pencilcal.toolkit.detect.lines import radial_edge_count, radial_joint_mode
    from pencilcal.toolkit.pencil.spec import as_star

    best, best_state = bars, None if state is None else dict(state)
    for polarity in ("dark", "light"):
        if state is not None:
            state.update(before)
        star = as_star(pencil, polarity)
        kw = dict(lines_kw, bars=False, bar_tracker=None, radial=radial_edge_count(star),
                  radial_joint=radial_joint_mode(star))
        fr, rec = radial_frame(name, image, camera, star, detector, kw, orient, state)
        if star_key(rec, pencil) > star_key(best[1], pencil):
            best, best_state = (fr, rec), None if state is None else dict(state)
        if star_key(rec, pencil)[:3] == (True, True, True):
            break  # the other polarity's edges are at the same angles: it measures them again
    if state is not None:
        state.update(best_state)
    return best

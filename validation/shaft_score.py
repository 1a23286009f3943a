"""Detected shafts scored against instrument masks: found, missed, false, and how far off.

The reference of each instrument is the axis its mask gives by its own outline
(`toolkit.detect.shaft.mask.mask_axis`): the plane bisector of its two straight silhouette
stretches (kind "shaft"), or, where the mask has no such pair (the distal part alone: jaws,
a hook), its principal axis (kind "part"), which is only good to a few degrees.

A detection *finds* an instrument when its midline is within the angle and offset
tolerances of the instrument's axis (`Tolerance`): the angle between the two lines, and the
distance from the reference's point (the middle of its straight part) to the detected line.
The matching is one to one, best detection score first. A detection that matches no
instrument is *false*, unless its centre lies on a mask pixel of an instrument too small to
have a reference (`mask.MIN_INSTRUMENT_AREA`), where it is neither. Each instrument is
*found* or *missed*.

Frames are scored one by one (`score_frame`) and summed per source (`summarize`); the
leave-one-source-out protocol that chooses the detector's setting on the other sources is
`validation.shaft_protocol`.

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.detect.shaft.mask import mask_axis
>>> m = np.zeros((200, 300), bool); m[80:120, :200] = True
>>> refs = [mask_axis(m)]
>>> det = [{"midline": [0.0, 100.5, 190.0, 99.0], "score": 150.0}, {"midline": [0, 10, 100, 60], "score": 90.0}]
>>> fs = score_frame(det, refs)
>>> fs.found, fs.missed, fs.false, [round(e, 2) for e in fs.angle_err_deg]
(1, 0, 1, [0.45])
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pencilcal.toolkit.geometry.projective import line_through

__all__ = ["Tolerance", "FrameScore", "score_frame", "summarize", "detection_line", "frame_references", "score_record"]


@dataclass(frozen=True)
class Tolerance:
    """When a detected midline finds an instrument.

    angle_deg, offset_px: for an instrument whose mask shows its straight shaft (the
    detector's shafts are good to a few tenths of a degree and a pixel or two: the
    tolerances take the mask's own error, a hand-drawn polygon, and keep a detection on the
    wrong instrument out); part_angle_deg, part_offset_frac: for a distal part alone, whose
    reference is the mask's principal axis, the offset as a fraction of its width (at least
    offset_px).
    """

    angle_deg: float = 1.5
    offset_px: float = 15.0
    part_angle_deg: float = 8.0
    part_offset_frac: float = 0.5

    def limits(self, ref):
        """(angle [rad], offset [px]) of one reference (`MaskAxis`)."""
        if ref.kind == "shaft":
            return np.radians(self.angle_deg), self.offset_px
        return np.radians(self.part_angle_deg), max(self.offset_px, self.part_offset_frac * ref.width_px)


@dataclass
class FrameScore:
    """One frame's score (`score_frame`).

    matches: (detection index, reference index, angle error [deg], offset error [px]) per
    found instrument; missed: the references not found; false: the detections that found
    none (and lie on no small instrument); ignored: detections on an instrument too small to
    score.
    """

    references: int
    detections: int
    matches: list = field(default_factory=list)
    missed_refs: list = field(default_factory=list)
    false_dets: list = field(default_factory=list)
    ignored_dets: list = field(default_factory=list)

    @property
    def found(self) -> int:
        return len(self.matches)

    @property
    def missed(self) -> int:
        return len(self.missed_refs)

    @property
    def false(self) -> int:
        return len(self.false_dets)

    @property
    def angle_err_deg(self) -> list:
        return [m[2] for m in self.matches]

    @property
    def offset_err_px(self) -> list:
        return [m[3] for m in self.matches]

    @classmethod
    def from_dict(cls, d):
        """The score of a `to_dict` record (score.json's frames)."""
        return cls(references=d["instruments"], detections=d["detections"],
                   matches=[(m["detection"], m["instrument"], m["angle_err_deg"], m["offset_err_px"])
                            for m in d["matches"]],
                   missed_refs=list(d["missed_instruments"]), false_dets=list(d["false_detections"]),
                   ignored_dets=list(d["ignored_detections"]))

    def to_dict(self) -> dict:
        return {"instruments": self.references, "detections": self.detections, "found": self.found,
                "missed": self.missed, "false": self.false,
                "matches": [{"detection": int(d), "instrument": int(r), "angle_err_deg": float(a),
                             "offset_err_px": float(o)} for d, r, a, o in self.matches],
                "missed_instruments": [int(r) for r in self.missed_refs],
                "false_detections": [int(d) for d in self.false_dets],
                "ignored_detections": [int(d) for d in self.ignored_dets]}


def detection_line(midline):
    """(line (3,) with a^2 + b^2 = 1, centre (2,)) of a midline [x1, y1, x2, y2] [px]."""
    p, q = np.asarray(midline[:2], float), np.asarray(midline[2:4], float)
    ln = line_through(p, q)
    return ln / np.hypot(ln[0], ln[1]), 0.5 * (p + q)


def score_frame(detections, references, tol=Tolerance(), small_mask=None):
    """Score one frame's detections against its instruments' axes.

    Parameters
    ----------
    detections : list of dict
        Shaft records as lines.json holds them (``midline`` [raw px], ``score``).
    references : list of MaskAxis
        The instruments' axes (`mask.mask_axis`), raw pixels.
    tol : Tolerance
    small_mask : (H, W) bool, optional
        Pixels of instruments too small to score: a detection centred there is ignored.

    Returns
    -------
    FrameScore
    """
    pairs = []
    lines = [detection_line(d["midline"]) for d in detections]
    for i, (ln, _) in enumerate(lines):
        for j, r in enumerate(references):
            a_max, o_max = tol.limits(r)
            a = float(np.arccos(np.clip(abs(ln[:2] @ r.line[:2]), 0.0, 1.0)))
            o = float(abs(ln[:2] @ r.point + ln[2]))
            if a <= a_max and o <= o_max:
                pairs.append((i, j, a, o))
    pairs.sort(key=lambda p: (-float(detections[p[0]].get("score", 0.0)), p[2]))
    fs = FrameScore(references=len(references), detections=len(detections))
    used_d, used_r = set(), set()
    for i, j, a, o in pairs:
        if i not in used_d and j not in used_r:
            used_d.add(i)
            used_r.add(j)
            fs.matches.append((i, j, float(np.degrees(a)), o))
    fs.missed_refs = [j for j in range(len(references)) if j not in used_r]
    for i, (_, c) in enumerate(lines):
        if i in used_d:
            continue
        x, y = int(round(c[0])), int(round(c[1]))
        on_small = small_mask is not None and 0 <= y < small_mask.shape[0] and 0 <= x < small_mask.shape[1] \
            and bool(small_mask[y, x])
        (fs.ignored_dets if on_small else fs.false_dets).append(i)
    return fs


def summarize(frames):
    """Totals of a list of `FrameScore`: found, instruments, recall, false per frame, and the
    median and 90th percentile of the found ones' angle [deg] and offset [px] errors."""
    found = sum(f.found for f in frames)
    total = sum(f.references for f in frames)
    false = sum(f.false for f in frames)
    a = np.array([e for f in frames for e in f.angle_err_deg])
    o = np.array([e for f in frames for e in f.offset_err_px])

    def q(v, p):
        return float(np.percentile(v, p)) if v.size else None

    return {"frames": len(frames), "instruments": total, "found": found,
            "recall": found / total if total else None, "false": false,
            "false_per_frame": false / len(frames) if frames else None,
            "angle_err_deg_median": q(a, 50), "angle_err_deg_p90": q(a, 90),
            "offset_err_px_median": q(o, 50), "offset_err_px_p90": q(o, 90)}


def frame_references(mask_image, labels=None, instances=False, valid=None, K=None):
    """The references of one frame's mask: (list of MaskAxis, their instruments' masks (list of
    (H, W) bool), small (H, W) bool: the pixels of instruments too small to score,
    `mask.MIN_INSTRUMENT_AREA`, None when there are none).

    mask_image: the mask as stored; labels, instances: as `mask.instruments_in_mask`; valid:
    the valid region's mask (H, W) bool; K: the axis camera (`shaft.work.axis_matrix`)."""
    from pencilcal.toolkit.detect.shaft.mask import MIN_INSTRUMENT_AREA, instruments_in_mask, mask_axis

    every = instruments_in_mask(mask_image, labels, instances, min_area=1)
    big = [m for m in every if int(m.sum()) >= MIN_INSTRUMENT_AREA]
    small = [m for m in every if int(m.sum()) < MIN_INSTRUMENT_AREA]
    refs = [a for a in (mask_axis(m, valid, K) for m in big) if a is not None]
    return refs, big, (np.any(small, axis=0) if small else None)


def score_record(frame_score, references):
    """One frame's record in score.json: `FrameScore.to_dict` with each instrument's axis
    (kind, line's segment [px], width)."""
    return {**frame_score.to_dict(),
            "references": [{"kind": r.kind, "axis": [float(v) for v in r.segment()], "width_px": float(r.width_px)}
                           for r in references]}

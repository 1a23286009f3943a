"""The answer a report opens with: one verdict line, then the few numbers that matter.

A reviewer reads this first: what was measured, the headline figure with its unit and its
sigma, and whether it passes against its stated tolerance (`Headline.line`, a status and
one sentence), then a small table (`Headline.table`). The same line ends `pencilcal
validate`, `report` and `demo` on the terminal.

- Orientation (any validation): the plane normal's error against the reference (the
  truth, else the board's PnP pose), the tilt's, and the normal against PnP and the
  reconstruction. The tolerance is the reported sigma: the fraction of errors within one
  sigma must lie in the binomial band honest sigmas give (`gates.gate`). The twin must be
  chosen: frames left ambiguous are counted with what resolves them.
- Fulcrum (a validation with a ``fulcrum`` record: a pivot): its image [px] and 3-D point
  [mm, the board's unit] against the truth where known, the tolerance their covariance
  (chi-square of the error, p above `P_MIN`), and the frames in which no shaft was found.

The book chapter's models kept for comparison (`facts.comparison_keys`) are listed grey,
labelled as comparisons, never judged.

Status: PASS; FAIL (a tolerance missed, a twin chosen wrong); CHECK (nothing failed but
something is unsettled: a twin left ambiguous, too few frames to judge the sigmas); NOT
JUDGED (no truth for the fulcrum, no orientation at all).

Example
-------
>>> h = headline({"frames": [], "summary": {}})
>>> h.status, h.line
('NOT JUDGED', 'NOT JUDGED: the validation file holds no frames.')
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np

from .document import Cell, Table
from .facts import comparison_keys, method_errors, primary_method, reference_phrase
from .format import finite, lookup, num, pct
from .gates import gate

__all__ = ["Headline", "headline", "no_shaft_frames", "P_MIN", "STATUS_CLASS"]

#: a fulcrum's error passes when its chi-square in the covariance has a p-value above this
P_MIN = 0.01

#: the document class of each status (the colour of the verdict and its cell)
STATUS_CLASS = {"PASS": "good", "FAIL": "bad", "CHECK": "warn", "NOT JUDGED": "muted"}

_WORST = ("FAIL", "CHECK", "NOT JUDGED", "PASS")


@dataclass
class Headline:
    """status (PASS, FAIL, CHECK, NOT JUDGED); sentence: what was measured and the headline
    figure; table: the numbers that matter (`Table`)."""

    status: str
    sentence: str
    table: Table | None

    @property
    def line(self):
        """The verdict as one line: "STATUS: sentence"."""
        return f"{self.status}: {self.sentence}"


def _worst(*statuses):
    return min((s for s in statuses if s), key=_WORST.index, default="PASS")


def _judged(g):
    """(status, words) of a coverage `Gate`."""
    words = f"{pct(g.found)} within 1 sigma ({pct(g.band[0])}-{pct(g.band[1])} expected)"
    if g.status == "PASS":
        return "PASS", words
    if g.status == "FAIL":
        return "FAIL", words + (": sigmas too small" if g.found < g.band[0] else ": sigmas too large")
    return "CHECK", f"{words}: too few frames to judge"


def _cell(status, words):
    return Cell(f"{status}: {words}" if words else status, STATUS_CLASS.get(status))


# ----------------------------------------------------------------------------------------
# orientation


def _sigma(e, what):
    """The sigma an error record is judged by [deg] (its coverage sigma, else its own)."""
    return finite(e.get(f"coverage_{what}_sigma_deg")) or finite(e.get(f"{what}_sigma_deg"))


def _coverage_gate(label, quantity, pairs):
    """The `Gate` of (error, sigma) pairs, or None without any."""
    pairs = [(a, b) for a, b in pairs if a is not None and b]
    if not pairs:
        return None
    e, s = np.abs(np.array(pairs, float)).T
    expected = 0.6827 if quantity == "tilt" else 1.0 - math.exp(-1.0)
    return gate(label, quantity, float(np.mean(e <= s)), expected, len(pairs))


def _against(data, prim, other):
    """The primary model's normal against another estimate of the same frames, per frame:
    (angle [deg], combined sigma [deg] or None). other: "pnp" (the frame's best PnP
    method) or "sfm" (the aligned reconstruction)."""
    model = prim.split(":", 1)[1]
    out = []
    for _, fr, e in method_errors(data, prim):
        n = lookup(fr, "orient", model, "normal")
        if other == "pnp":
            rec = lookup(fr, "pnp", fr.get("pnp_best") or "")
            m = None if not isinstance(rec, dict) or not rec.get("ok", True) else rec.get("normal")
            if m is None and isinstance(rec, dict) and rec.get("R_cam_from_target") is not None:
                m = np.asarray(rec["R_cam_from_target"], float)[:, 2]
            s_other = None if m is None else finite(rec.get("normal_sigma_total_deg")) or finite(
                rec.get("normal_sigma_deg"))
        else:
            R = lookup(fr, "sfm", "R_cam_from_target")
            m = None if R is None else np.asarray(R, float)[:, 2]
            s_other = None
        if n is None or m is None:
            continue
        a, b = np.asarray(n, float), np.asarray(m, float)
        ang = math.degrees(math.atan2(np.linalg.norm(np.cross(a, b)), float(a @ b)))
        s_own = finite(e.get("normal_sigma_deg"))
        out.append((ang, None if s_own is None or s_other is None else math.hypot(s_own, s_other)))
    return out


def _twin_words(data, prim):
    """(status, words, ambiguous count) of how the primary model's twin was chosen."""
    model = prim.split(":", 1)[1]
    s = data["summary"][prim]
    k = int(s.get("frames") or 0)
    twin = s.get("twin") or {}
    wrong, amb = int(twin.get("wrong", 0)), int(twin.get("ambiguous", 0))
    by = Counter(str(lookup(fr, "orient", model, "resolved_by") or "") for _, fr, e in method_errors(data, prim)
                 if e.get("twin") in ("right", "wrong"))
    names = {"radius": "the spoke radii", "continuity": "continuity", "prior": "a prior pose"}
    how = ", ".join(f"{c} by {names.get(r, r or 'its own fit')}" for r, c in by.most_common())
    resolved = k - amb
    if amb:
        why = ("the pencil file gives no spoke radii" if not lookup(data, "pencil", "radius")
               else "the spoke radii could not tell the twins apart")
        words = (f"left ambiguous in {amb} of {k} frames ({why}; continuity from a resolved frame or a prior "
                 f"pose resolves them)")
        return ("FAIL" if wrong else "CHECK"), words + (f"; chosen wrong in {wrong}" if wrong else ""), amb
    words = f"resolved in {'all ' if resolved == k else ''}{resolved}" + (f" ({how})" if how else "")
    if wrong:
        return "FAIL", f"{words}, chosen wrong in {wrong}", 0
    return "PASS", words, 0


def _orientation_rows(data, prim, n):
    """(rows of the table, statuses of what is judged, the normal's gate)."""
    s = data["summary"][prim]
    k = int(s.get("frames") or 0)
    ref = _reference_name(data)
    model = prim.split(":", 1)[1]
    errs = [e for _, _, e in method_errors(data, prim)]
    rows, statuses = [], []

    def med(v):
        v = [x for x in v if x is not None]
        return float(np.median(v)) if v else None

    normal_gate = _coverage_gate(prim, "normal", [(finite(e.get("normal_closer_deg")), _sigma(e, "normal"))
                                                  for e in errs])
    nn = s.get("normal") or {}
    st, words = _judged(normal_gate) if normal_gate else ("CHECK", "no sigmas to judge")
    statuses.append(st)
    rows.append([f"plane normal ({model} model) vs {ref}",
                 f"{num(nn.get('median'), ' deg')} median, RMS {num(nn.get('rmse'))}",
                 num(med(_sigma(e, "normal") for e in errs), " deg"), f"{k} / {n}", _cell(st, words)])
    tilt_gate = _coverage_gate(prim, "tilt", [(finite(e.get("tilt_deg")), _sigma(e, "tilt")) for e in errs])
    if tilt_gate is not None:
        st, words = _judged(tilt_gate)
        statuses.append(st)
        tt = s.get("tilt") or {}
        rows.append([f"tilt vs {ref}", f"{num(tt.get('median'), ' deg')} median, RMS {num(tt.get('rmse'))}",
                     num(med(_sigma(e, "tilt") for e in errs), " deg"), f"{tilt_gate.count} / {n}", _cell(st, words)])
    for other, name in (("pnp", "PnP (board corners)"), ("sfm", "SfM (pycolmap, aligned)")):
        if other == "pnp" and data.get("reference") == "pnp":
            continue  # the first row is against PnP already
        pairs = _against(data, prim, other)
        if not pairs:
            continue
        ang = np.array([a for a, _ in pairs])
        g = _coverage_gate(f"{prim} vs {other}", "normal", pairs)
        st, words = _judged(g) if g is not None else (None, "no sigma to judge by")
        if st:
            statuses.append(st)
        rows.append([f"plane normal vs {name}", f"{num(np.median(ang), ' deg')} median, RMS "
                                                f"{num(np.sqrt(np.mean(ang ** 2)))}",
                     num(med(b for _, b in pairs), " deg (both)") if g is not None else "–", f"{len(pairs)} / {n}",
                     _cell(st, words) if st else Cell(words, "muted")])
    st, words, _ = _twin_words(data, prim)
    statuses.append(st)
    rows.append(["twin (which of the two solutions)", f"{k - _twin_words(data, prim)[2]} of {k} resolved", "–",
                 f"{k} / {n}", _cell(st, words)])
    return rows, statuses, normal_gate


def _comparison_rows(data, prim, n):
    """The chapter's models, grey: their median normal error, never judged."""
    rows = []
    for key in comparison_keys(data):
        s = lookup(data, "summary", key) or {}
        if not s.get("frames"):
            continue
        rows.append([Cell(f"comparison: the chapter's {key.split(':', 1)[1]} model", "muted"),
                     Cell(f"{num(lookup(s, 'normal_closer', 'median'), ' deg')} median (closer twin)", "muted"),
                     Cell("–", "muted"), Cell(f"{s['frames']} / {n}", "muted"),
                     Cell("comparison only, not judged", "muted")])
    return rows


def _reference_name(data):
    """The reference in a few words."""
    return {"truth": "the ground truth", "pnp": "the board's PnP pose"}.get(data.get("reference"),
                                                                              reference_phrase(data))


def _orientation_sentence(data, prim, n, normal_gate):
    s = data["summary"][prim]
    k = int(s.get("frames") or 0)
    model = prim.split(":", 1)[1]
    nn, nc = s.get("normal") or {}, s.get("normal_closer") or {}
    sig = [_sigma(e, "normal") for _, _, e in method_errors(data, prim)]
    sig = [v for v in sig if v is not None]
    twin_words = _twin_words(data, prim)[1]
    figure = f"median error {num(nn.get('median'), ' deg')}"
    if abs((finite(nn.get("median")) or 0.0) - (finite(nc.get("median")) or 0.0)) > 1e-6:
        figure += f" as reported ({num(nc.get('median'), ' deg')} for the closer twin)"
    text = (f"plane normal from the fan's image angles ({model} model) vs {_reference_name(data)}: {figure}, "
            f"sigma {num(np.median(sig) if sig else None, ' deg')}, {k} of {n} frames")
    if normal_gate is not None:
        text += f"; {_judged(normal_gate)[1]}"
    return text + f"; twin {twin_words}."


def _orientation(data):
    n = len(data["frames"])
    prim = primary_method(data)
    if prim is None:
        return Headline("FAIL", f"no frame of {n} gave an orientation from the fan's image angles.", None)
    rows, statuses, normal_gate = _orientation_rows(data, prim, n)
    rows += _comparison_rows(data, prim, n)
    table = Table(["measured", "value", "sigma", "frames", "against the tolerance"], rows, None,
                  "The tolerance of an error is its reported sigma: honest sigmas hold the error within 1 sigma in "
                  "68% of frames for the tilt and 63% for the normal, within the binomial band for this many frames. "
                  "The chapter's models are shown for comparison only.", numeric_from=9)
    return Headline(_worst(*statuses), _orientation_sentence(data, prim, n, normal_gate), table)


# ----------------------------------------------------------------------------------------
# fulcrum


def _xyz(v, digits=1):
    try:
        return "(" + ", ".join(f"{float(x):.{digits}f}" for x in v) + ")"
    except (TypeError, ValueError):
        return "–"


def no_shaft_frames(data, rec):
    """Images of the frames in which no shaft was found (list of str)."""
    seen = {m.get("image") for m in rec.get("midlines") or [] if isinstance(m, dict)}
    return [str(f.get("image")) for f in data["frames"] if f.get("image") not in seen]


def _p_status(p):
    p = finite(p)
    return None if p is None else ("PASS" if p >= P_MIN else "FAIL")


def _fulcrum_rows(data, rec):
    t = rec.get("truth") or {}
    cov = rec.get("vertex_cov_px2")
    vs = None if cov is None else float(np.sqrt(np.trace(np.asarray(cov, float))))
    chi_v = finite(t.get("vertex_chi2"))
    p_v = None if chi_v is None else math.exp(-chi_v / 2.0)  # chi2 with 2 dof
    rows, statuses = [], []
    st = _p_status(p_v)
    statuses.append(st or "NOT JUDGED")
    rows.append(["fulcrum's image [px]", _xyz(rec.get("vertex_px"), 2), num(vs, " px"),
                 num(t.get("vertex_error_px"), " px"),
                 _cell(st, f"chi2 {num(chi_v)} (2 dof), p {num(p_v)}") if st else Cell("no truth", "muted")])
    if rec.get("point") is not None:
        st = _p_status(t.get("point_p_value"))
        statuses.append(st or "NOT JUDGED")
        rows.append(["3-D fulcrum, camera frame [mm]", _xyz(rec["point"]), num(rec.get("point_sigma"), " mm"),
                     num(t.get("point_error_norm"), " mm"),
                     _cell(st, f"chi2 {num(t.get('point_chi2'))} (3 dof), p {num(t.get('point_p_value'))}") if st
                     else Cell("no truth", "muted")])
    board = rec.get("board_frame")
    if isinstance(board, dict) and board.get("point") is not None:
        bs = float(np.sqrt(np.trace(np.asarray(board["point_cov"], float))))
        rows.append(["3-D fulcrum, board frame [mm]", _xyz(board["point"]), num(bs, " mm"),
                     num(board.get("error"), " mm"),
                     Cell(f"median over {board.get('frames')} PnP poses (their own error not included)", "muted")])
    missing = no_shaft_frames(data, rec)
    n = len(data["frames"])
    out = len(rec.get("outliers") or [])
    words = (f"no shaft found in {', '.join(missing[:4])}" + (f" and {len(missing) - 4} more" if len(missing) > 4 else "")
             if missing else "a shaft in every frame") + (f"; {out} left out as outliers" if out else "")
    rows.append(["frames with a shaft", f"{n - len(missing)} of {n}", "–", "–", Cell(words, "warn" if missing else None)])
    return rows, statuses, missing


def _fan_row(data, prim, n):
    """The fulcrum table's row of the fan's orientation (the camera's view of the sheet)."""
    s = lookup(data, "summary", prim) or {}
    sig = [_sigma(e, "normal") for _, _, e in method_errors(data, prim)]
    sig = [v for v in sig if v is not None]
    g = _coverage_gate(prim, "normal", [(finite(e.get("normal_closer_deg")), _sigma(e, "normal"))
                                        for _, _, e in method_errors(data, prim)])
    st, words = _judged(g) if g is not None else ("CHECK", "no sigmas to judge")
    twin_st, twin_words, _ = _twin_words(data, prim)
    return [f"the fan's plane normal ({prim.split(':', 1)[1]} model), {s.get('frames', 0)} of {n} frames",
            "–", num(np.median(sig) if sig else None, " deg"),
            f"{num(lookup(s, 'normal', 'median'), ' deg')} median",
            _cell(_worst(st, twin_st), f"{words}; twin {twin_words}")]


def _fulcrum(data, rec):
    n = len(data["frames"])
    if not rec.get("ok"):
        return Headline("FAIL", f"no fulcrum from the shafts of {n} frames: {rec.get('error')}.", None)
    rows, statuses, missing = _fulcrum_rows(data, rec)
    prim = primary_method(data)
    if prim is not None:
        rows.append(_fan_row(data, prim, n))
    t = rec.get("truth") or {}
    where = (f"the 3-D point {_xyz(rec['point'])} mm in the camera frame, sigma {num(rec.get('point_sigma'), ' mm')}"
             + (f", {num(t.get('point_error_norm'), ' mm')} from the truth" if "point_error_norm" in t else "")
             if rec.get("point") is not None else "")
    image = (f"its image {_xyz(rec.get('vertex_px'), 2)} px, sigma "
             f"{num(float(np.sqrt(np.trace(np.asarray(rec['vertex_cov_px2'], float)))), ' px')}"
             + (f", {num(t.get('vertex_error_px'), ' px')} from the truth" if "vertex_error_px" in t else "")
             if rec.get("vertex_px") is not None and rec.get("vertex_cov_px2") is not None else "")
    parts = [p for p in (where, image) if p]
    shafts = f"shafts found in {n - len(missing)} of {n} frames" + (
        f" (none in {', '.join(missing[:3])}{' ...' if len(missing) > 3 else ''})" if missing else "")
    sentence = "fulcrum of the pivoting instrument: " + "; ".join(parts + [shafts]) + "."
    status = _worst(*statuses)
    if not t:
        status = "NOT JUDGED"
        sentence += " No truth to judge it against."
    table = Table(["measured", "value", "sigma (RMS)", "error vs truth", "against the tolerance"], rows, None,
                  "Lengths in mm (the board's unit and the shaft diameter's). The tolerance of the fulcrum is its "
                  f"covariance: the error's chi-square, with p above {P_MIN:g}.", numeric_from=9)
    return Headline(status, sentence, table)


def headline(data):
    """The report's `Headline` for a validation dict: the fulcrum's for a pivot (a
    ``fulcrum`` record), else the orientation's."""
    if not data["frames"]:
        return Headline("NOT JUDGED", "the validation file holds no frames.", None)
    rec = data.get("fulcrum")
    if isinstance(rec, dict):
        return _fulcrum(data, rec)
    return _orientation(data)

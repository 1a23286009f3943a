"""The report's tables of numbers: the summary of every method side by side, and the
per-frame tables (reference and flags, normal error, tilt error). Angles in degrees.

Example
-------
>>> data = {"frames": [{"image": "a.png", "ok": True}], "models": ["exact"],
...         "summary": {"orient:exact": {"frames": 1, "normal": {"median": 0.2}, "normal_closer": {"median": 0.2}}}}
>>> t = summary_table(data)
>>> t.rows[0][:3], len(t.columns)
([Cell(text='orient:exact', cls=None, title=None), '1 / 1', '0.200'], 17)
"""
from __future__ import annotations

from .document import Cell, Table
from .facts import method_keys, method_label, primary_method, reference_counts, reference_phrase, same_as_reference
from .format import finite, lookup, num, pct
from .verdict import coverage_judgement

__all__ = ["summary_table", "frame_tables"]


def _cov_cell(c, skip=False):
    """A coverage record {fraction, expected, count} as a cell coloured by its judgement."""
    if skip:
        return Cell("– (reference)", "muted")
    if not isinstance(c, dict) or finite(c.get("fraction")) is None:
        return Cell("–", "muted")
    verdict_cls, words = coverage_judgement(c.get("fraction"), c.get("expected"), c.get("count"))
    cls = {"ok": "good", "low": "bad", "high": "warn"}.get(verdict_cls)
    return Cell(f"{pct(c['fraction'])} / {pct(c.get('expected'))}", cls, f"n = {c.get('count')}: {words}")


def summary_table(data):
    """The summary table: one row per method (Table)."""
    summ = data["summary"]
    n = len(data["frames"])
    refs = reference_counts(data)
    cols = ["method", "frames", "median", "RMSE", "p95", "median", "RMSE", "p95", "chosen", "closer",
            "median", "RMSE", "p95", "twin: right, wrong, ambiguous", "normal", "tilt", "detect-able"]
    groups = [("", 2), ("normal error, chosen [deg]", 3), ("normal error, closer twin [deg]", 3),
              ("rotation error, median [deg]", 2), ("|tilt error| [deg]", 3), ("", 1),
              ("sigma coverage, found / expected", 2), ("", 1)]
    rows = []
    for key in method_keys(data):
        s = summ.get(key) or {"frames": 0}
        k = int(s.get("frames") or 0)
        name = method_label(key)
        same = same_as_reference(data, key)
        title = None
        if refs.get(key.split(":", 1)[-1]) and key.startswith("pnp:"):
            name += " †"
            title = f"the reference in {refs[key.split(':', 1)[1]]} frames (error 0 there by construction)"
        if k == 0:
            rows.append([Cell(name, None, title), Cell(f"0 / {n}", "bad")] + [Cell("–", "muted")] * (len(cols) - 2))
            continue
        twin = s.get("twin") or {}
        tw = "–" if not any(twin.get(t) for t in ("right", "wrong", "ambiguous")) else \
            " / ".join(str(int(twin.get(t, 0))) for t in ("right", "wrong", "ambiguous"))
        twin_cls = "bad" if twin.get("wrong") else "warn" if twin.get("ambiguous") else None
        det = s.get("detectable")
        row = [Cell(name, None, title), f"{k} / {n}"]
        for grp in ("normal", "normal_closer"):
            row += [num(lookup(s, grp, "median")), num(lookup(s, grp, "rmse")), num(lookup(s, grp, "p95"))]
        row += [num(lookup(s, "rotation", "median")), num(lookup(s, "rotation_closer", "median"))]
        row += [num(lookup(s, "tilt", "median")), num(lookup(s, "tilt", "rmse")), num(lookup(s, "tilt", "p95"))]
        row += [Cell(tw, twin_cls), _cov_cell(s.get("normal_coverage"), same), _cov_cell(s.get("tilt_coverage"), same),
                "–" if det is None else f"{int(det)} / {k}"]
        rows.append(row)
    cap = ("Errors against the " + reference_phrase(data) + ". Chosen: the solution the method reports; closer twin: "
           "the better of the two solutions (the fair measure where the twin is unresolved). Coverage: the fraction "
           "of errors within the reported 1-sigma (68.3% expected for the tilt, 63.2% for the normal's RMS angle); "
           "hover for the binomial check.")
    if refs:
        cap += " † marks the PnP method that is the per-frame reference."
    return Table(cols, rows, groups, cap, numeric_from=1)


def _bound(v):
    """A Cramer-Rao bound for the table: none at zero tilt, where it is not defined."""
    v = finite(v)
    return Cell(num(v)) if v is not None and v > 0 else Cell("–", "muted", "not defined (zero tilt) or not computed")


def _yes_no(v):
    """A flag in words: yes, no, or a dash when absent."""
    return "–" if v is None else ("yes" if v else "no")


def _info_row(i, f, model):
    """One frame's reference, bound, and the orient model's estimate and flags."""
    o = lookup(f, "orient", model) or {}
    ref = f.get("reference")
    if ref == "pnp" and f.get("pnp_best"):
        ref = f"pnp:{f['pnp_best']}"
    tilt = "–"
    if o.get("ok"):
        tilt = f"{num(o.get('tilt_deg'))} +- {num(o.get('tilt_sigma_deg'))}"
    err = f.get("error") or (o.get("error") if not o.get("ok") else None)
    return [str(i), str(f.get("image", "?")), Cell(_yes_no(f.get("ok")), None if f.get("ok") else "bad"),
            ref or "–", num(f.get("reference_tilt_deg")), _bound(lookup(f, "crlb", "normal_deg")),
            _bound(lookup(f, "crlb", "tilt_deg")), tilt,
            Cell(_yes_no(o.get("detectable")), "warn" if o.get("detectable") is False else None),
            Cell(_yes_no(o.get("ambiguous")), "warn" if o.get("ambiguous") else None),
            o.get("resolved_by") or "–",
            Cell("yes, normal too", "warn") if o.get("normal_ambiguous") else _yes_no(o.get("labels_ambiguous")),
            "–" if o.get("lines_used") is None else str(o.get("lines_used")),
            num(o.get("rms_residual_deg")),
            "–" if f.get("board_corners") is None else str(f.get("board_corners")),
            Cell(err or "", "muted")]


def _error_cells(e):
    """(normal cell, tilt cell) of one frame's error record for one method."""
    if not isinstance(e, dict):
        return Cell("–", "muted"), Cell("–", "muted")
    a, b = finite(e.get("normal_closer_deg")), finite(e.get("normal_deg"))
    twin = e.get("twin")
    txt = num(a)
    if b is not None and a is not None and abs(b - a) > 1e-9:
        txt += f" [{num(b)}]"
    cls = "bad" if twin == "wrong" else "warn" if twin == "ambiguous" else None
    t = num(e.get("tilt_deg"))
    if finite(e.get("tilt_sigma_deg")) is not None:
        t += f" +- {num(e.get('tilt_sigma_deg'))}"
    return Cell(txt, cls, f"twin: {twin}" if twin and twin != "none" else None), t


def frame_tables(data):
    """(frames and flags, normal error per method, tilt error per method): three Tables
    with one row per frame, failed frames marked."""
    frames = data["frames"]
    keys = [k for k in method_keys(data) if any(lookup(f, "errors", k) for f in frames)]
    prim = primary_method(data)
    model = prim.split(":", 1)[1] if prim else ((data.get("models") or ["exact"])[0])
    info_cols = ["#", "image", "ok", "reference", "ref tilt", "CRLB normal", "CRLB tilt", "est. tilt +- sigma",
                 "detectable", "ambiguous", "resolved by", "labels ambig.", "lines used", "RMS resid. [deg]",
                 "board corners", "error"]
    info = [_info_row(i, f, model) for i, f in enumerate(frames)]
    bad_rows = [None if f.get("ok") else "bad" for f in frames]
    t_info = Table(info_cols, info, None, f"Per frame: the reference, the Cramer-Rao bound at the reference pose, and "
                                          f"the {model} model's estimate and flags. Angles in degrees.", numeric_from=4,
                   row_cls=bad_rows, text_cols=(10, 15))
    ncols = ["#", "image", "ref tilt"] + [method_label(k) for k in keys]
    nrows, trows = [], []
    for i, f in enumerate(frames):
        nr = [str(i), str(f.get("image", "?")), num(f.get("reference_tilt_deg"))]
        tr = list(nr)
        for k in keys:
            n_cell, t_cell = _error_cells(lookup(f, "errors", k))
            nr.append(n_cell)
            tr.append(t_cell)
        nrows.append(nr)
        trows.append(tr)
    t_norm = Table(ncols, nrows, None, "Normal error per frame and method [deg]: the closer twin, and in brackets the "
                                       "reported (chosen) solution where it differs. Red: the twin was chosen wrong; "
                                       "amber: left ambiguous.", numeric_from=2, row_cls=bad_rows)
    t_tilt = Table(ncols, trows, None, "Tilt error per frame and method [deg], signed (estimate minus reference), with "
                                       "the reported sigma where the method gives one.", numeric_from=2,
                   row_cls=bad_rows)
    return t_info, t_norm, t_tilt

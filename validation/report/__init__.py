"""Validation report: one self-contained HTML page (or a PDF) from a validation.json.

`pencilcal validate` writes what was measured; this module turns it into what a reviewer
reads, in this order:

1. header: what was validated (sequence, frames, camera, board, pencil, reference) and a
   verdict in plain words, *computed from the numbers* (`verdict`), which also says what
   the file does not cover (no truth, no reconstruction, no calibration statistics,
   frames that failed);
2. the summary table: every method side by side (`summary_table`);
3. error versus reference tilt with the per-frame Cramer-Rao bound, and the calibration
   of the reported sigmas (`fig_error_vs_tilt`, `fig_sigma_calibration`);
4. per-frame tables;
5. overlays on sample frames spread over the tilt range (`fig_overlay`): the detected
   pencil segments by spoke, the vertex with its covariance ellipse, the board axes at the
   reference pose, the estimated normal and its twin;
6. calibration quality (when the file has it); 7. the reconstruction (with --sfm);
8. a `pencilcal sensitivity` plan next to what was measured (when given);
9. reproducibility: versions, commands, input hashes.

The content is built once as a list of sections of simple blocks (`Para`, `Table`,
`Plot`, ...) and rendered to HTML (`render_html`: CSS inline, images as base64 PNG, no
script, no network resource) or to a multi-page A4 PDF with matplotlib's PdfPages
(`render_pdf`). `write_report` picks the format by suffix and writes atomically.

Every missing optional part (no sfm, no calibration, no truth, frames with ok false, a
grid pencil, images that moved) renders as a note; a file that is not JSON or not a
validation file is an `InputError` naming it.

Example
-------
>>> from pencilcal.validation.report import build_report, render_html
>>> data = {"reference": "truth", "models": ["exact"], "methods": [], "summary": {"orient:exact": {"frames": 0}},
...         "frames": [{"image": "a.png", "ok": False, "error": "no pencil lines in this frame"}]}
>>> page = render_html(build_report(data, samples=0))
>>> "No frame gave an angular-variation estimate" in page and "http" not in page
True
"""
from __future__ import annotations

import base64
import datetime as _dt
import hashlib
import html
import io
import math
import platform
import shlex
import textwrap
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pencilcal.toolkit.errors import InputError, PencilcalError
from pencilcal.toolkit.io.files import atomic_path, atomic_write, check_writable, load_structured

from ..metrics import EXPECTED_COVERAGE
from ..validation_file import check_validation, load_validation

__all__ = [
    "load_validation",
    "load_sensitivity",
    "check_validation",
    "build_report",
    "render_html",
    "render_pdf",
    "write_report",
    "verdict",
    "summary_table",
    "method_keys",
    "coverage_judgement",
    "Report",
    "Section",
    "Para",
    "Table",
    "Cell",
    "Plot",
    "Details",
    "FORMATS",
]

FORMATS = {".html": "html", ".htm": "html", ".pdf": "pdf"}
# a method whose errors stay below this in every frame *is* the reference (PnP against the
# best PnP): it is listed, but neither plotted nor judged
_SAME_AS_REFERENCE_DEG = 1e-6
_DPI = 100


# ----------------------------------------------------------------------------------------
# content blocks


@dataclass
class Cell:
    """One table cell: text, an optional class (good, warn, bad, muted) and a tooltip."""

    text: str
    cls: str | None = None
    title: str | None = None


@dataclass
class Para:
    """A paragraph of plain text; kind: text, lead (the verdict), note, caption."""

    text: str
    kind: str = "text"


@dataclass
class Bullets:
    items: list


@dataclass
class Table:
    """columns: header names; rows: lists of str or Cell; groups: (label, span) above the header."""

    columns: list
    rows: list
    groups: list | None = None
    caption: str | None = None
    numeric_from: int = 1
    row_cls: list | None = None
    text_cols: tuple = ()

    def numeric(self, j):
        """Is column j right-aligned numbers?"""
        return j >= self.numeric_from and j not in self.text_cols


@dataclass
class Plot:
    """A matplotlib figure, rendered once to PNG."""

    png: bytes
    caption: str
    alt: str


@dataclass
class Details:
    """A collapsible group of blocks (HTML <details>; printed whole in the PDF)."""

    summary: str
    blocks: list
    open: bool = False


@dataclass
class Pre:
    text: str


@dataclass
class Section:
    id: str
    title: str
    blocks: list = field(default_factory=list)


@dataclass
class Report:
    title: str
    subtitle: str
    sections: list


# ----------------------------------------------------------------------------------------
# small helpers


def _g(d, *keys, default=None):
    """d[k1][k2]... or `default` when any level is missing, None or not a mapping."""
    for k in keys:
        if isinstance(d, dict):
            d = d.get(k)
        elif isinstance(d, list) and isinstance(k, int) and -len(d) <= k < len(d):
            d = d[k]
        else:
            return default
        if d is None:
            return default
    return d


def _f(x):
    """A finite float, or None."""
    if isinstance(x, bool) or x is None:
        return None
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def num(x, unit=""):
    """Angles and errors for people: 3 significant digits, tiny values in e-notation."""
    v = _f(x)
    if v is None:
        return "–"
    if v == 0:
        s = "0"
    elif abs(v) < 1e-3:
        s = f"{v:.1e}"
    elif abs(v) >= 1000:
        s = f"{v:.0f}"
    else:
        s = f"{v:#.3g}".rstrip(".")
    return s + unit


def _nan(x):
    v = _f(x)
    return np.nan if v is None else v


def pct(x):
    v = _f(x)
    return "–" if v is None else f"{100 * v:.0f}%"


def _label(key):
    """How a method is named on the page: its key in validation.json."""
    return str(key)


def _sha256(path):
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _png(fig, dpi=_DPI):
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, metadata={"Software": None}, pil_kwargs={"compress_level": 4})
    return buf.getvalue()


def _figure(**kw):
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    return Figure(layout="constrained", **kw)


# ----------------------------------------------------------------------------------------
# input


def load_sensitivity(path):
    """Read a sensitivity.json of `pencilcal sensitivity`; InputError naming the file."""
    p = Path(path)
    d = load_structured(p, "sensitivity file")
    if not isinstance(d, dict) or not isinstance(d.get("maps"), dict) or not isinstance(d.get("setup"), dict):
        raise InputError(f"{p}: not a sensitivity file (expected 'setup' and 'maps', as `pencilcal sensitivity` "
                         f"writes)")
    return d


# ----------------------------------------------------------------------------------------
# facts drawn from the data


def method_keys(data):
    """Every method of the file, in reading order: orient models, PnP methods, sfm, others."""
    summ = data.get("summary") or {}
    order = [f"orient:{m}" for m in (data.get("models") or [])] + [f"pnp:{m}" for m in (data.get("methods") or [])]
    if "sfm" in summ or isinstance(data.get("sfm"), dict):
        order.append("sfm")
    for k in summ:
        if k not in order:
            order.append(k)
    # orient first, then pnp, then the rest, each group in the file's order
    rank = lambda k: 0 if k.startswith("orient:") else 1 if k.startswith("pnp:") else 2  # noqa: E731
    return sorted(dict.fromkeys(order), key=lambda k: (rank(k), order.index(k)))


def _errors(data, key):
    """[(frame index, frame, error record)] of one method."""
    out = []
    for i, fr in enumerate(data["frames"]):
        e = _g(fr, "errors", key)
        if isinstance(e, dict):
            out.append((i, fr, e))
    return out


def _same_as_reference(data, key):
    """True when the method's errors vanish in every frame (it is the reference itself)."""
    vals = [_f(e.get("normal_deg")) for _, _, e in _errors(data, key)]
    vals = [v for v in vals if v is not None]
    rot = [_f(e.get("rotation_deg")) for _, _, e in _errors(data, key)]
    rot = [v for v in rot if v is not None]
    return bool(vals) and max(vals + rot) < _SAME_AS_REFERENCE_DEG


def _reference_counts(data):
    """How often each PnP method was the per-frame reference (reference pnp)."""
    return Counter(f.get("pnp_best") for f in data["frames"]
                   if f.get("reference") == "pnp" and f.get("pnp_best") and f.get("R_ref") is not None)


def _primary(data):
    for key in ("orient:exact", "orient:general", "orient:aligned"):
        if (_g(data, "summary", key, "frames") or 0) > 0:
            return key
    for key in method_keys(data):
        if key.startswith("orient:") and (_g(data, "summary", key, "frames") or 0) > 0:
            return key
    return None


def coverage_judgement(fraction, expected, n):
    """('ok' | 'low' | 'high' | None, words): is a coverage consistent with the expected
    rate for n frames (binomial, two standard errors)?"""
    fraction, expected = _f(fraction), _f(expected)
    if fraction is None or expected is None or not n:
        return None, "no sigmas to check"
    se = math.sqrt(expected * (1 - expected) / n)
    z = (fraction - expected) / se if se > 0 else 0.0
    band = f"the binomial band of +-{100 * 2 * se:.0f} points for {n} frames"
    if abs(z) <= 2:
        return "ok", f"consistent with the {pct(expected)} expected, within {band}"
    if z < 0:
        return "low", f"fewer than the {pct(expected)} expected, beyond {band}: the reported sigmas are too small"
    return "high", f"more than the {pct(expected)} expected, beyond {band}: the reported sigmas are too large"


def _combined_coverage(data, key):
    """Normal coverage against sqrt(sigma_est^2 + sigma_ref^2) when the reference is PnP."""
    pairs = []
    for _, fr, e in _errors(data, key):
        if fr.get("reference") != "pnp":
            continue
        s_est = _f(e.get("normal_sigma_deg"))
        s_ref = _f(_g(fr, "pnp", fr.get("pnp_best") or "", "normal_sigma_deg"))
        err = _f(e.get("normal_closer_deg") if key.startswith("orient") else e.get("normal_deg"))
        if None not in (s_est, s_ref, err):
            pairs.append((err, math.hypot(s_est, s_ref)))
    if not pairs:
        return None
    e, s = np.array(pairs).T
    return {"fraction": float(np.mean(e <= s)), "expected": float(EXPECTED_COVERAGE["normal"]), "count": len(pairs)}


def _crlb_ratio(data, key):
    """RMS error (closer twin) over the RMS per-frame Cramer-Rao bound of the normal."""
    pairs = [(_f(e.get("normal_closer_deg")), _f(_g(fr, "crlb", "normal_deg"))) for _, fr, e in _errors(data, key)]
    pairs = [(a, b) for a, b in pairs if a is not None and b is not None and b > 0]
    if not pairs:
        return None
    e, b = np.array(pairs).T
    rms_b = float(np.sqrt(np.mean(b**2)))
    return {"ratio": float(np.sqrt(np.mean(e**2)) / rms_b), "bound_rms": rms_b, "count": len(pairs)}


def _failures(data):
    """Counter of the reasons frames were not validated."""
    return Counter(str(f.get("error") or "no estimate") for f in data["frames"] if not f.get("ok"))


def _orient_failures(data, model):
    return Counter(str(_g(f, "orient", model, "error") or "no estimate") for f in data["frames"]
                   if isinstance(_g(f, "orient", model), dict) and not _g(f, "orient", model, "ok"))


def _reasons(counter, limit=3):
    items = counter.most_common()
    txt = "; ".join(f"{n} x '{r}'" for r, n in items[:limit])
    if len(items) > limit:
        txt += f"; {sum(n for _, n in items[limit:])} other"
    return txt


def _ref_phrase(data):
    ref = data.get("reference")
    if ref == "truth":
        return "ground-truth poses (truth.json)"
    if ref == "pnp":
        return "board pose from PnP (best method per frame)"
    return f"reference ({ref or 'unknown'})"


def _distinct_directions(angles):
    try:
        return int(np.unique(np.round(np.mod(np.asarray(angles, float), 180.0), 6) % 180.0).size)
    except (TypeError, ValueError):
        return 0


def _pencil_phrase(data):
    p = data.get("pencil") or {}
    if not isinstance(p, dict):
        return "pencil: unknown"
    n = len(p.get("angles_deg") or [])
    if p.get("grid") is not None:
        where = "the best detected inner corner of each frame" if p.get("grid") == "auto" else f"corner {p['grid']}"
        d = _distinct_directions(p.get("angles_deg"))
        return f"the board's grid lines through {where} ({n} spokes in {d} line directions; no spoke radii)"
    radius = p.get("radius")
    return (f"a printed fan of {n} spokes" + (f", radius {num(radius[0])}-{num(radius[1])}"
                                              if isinstance(radius, list) and len(radius) == 2 else ", no radii"))


def _calibration_same_images(data):
    cal = data.get("calibration")
    if not isinstance(cal, dict) or not cal.get("images") or not data.get("images"):
        return False
    try:
        return Path(str(cal["images"])).resolve() == Path(str(data["images"])).resolve()
    except OSError:
        return str(cal["images"]) == str(data["images"])


def verdict(data):
    """(paragraph, notes): the verdict in plain words and the list of what is missing or
    worth a reviewer's attention, all computed from the numbers in `data`."""
    frames = data["frames"]
    n = len(frames)
    summ = data["summary"]
    ref = data.get("reference")
    notes = []
    s_out = []
    prim = _primary(data)
    if n == 0:
        return "The validation file holds no frames.", ["no frames"]
    if prim is None:
        models = data.get("models") or ["exact"]
        why = _orient_failures(data, models[0])
        s_out.append(f"No frame gave an angular-variation estimate ({n} frames"
                     + (f"; {_reasons(why)}" if why else "") + ").")
    else:
        s = summ[prim]
        model = prim.split(":", 1)[1]
        k = int(s.get("frames") or 0)
        nn, nc = s.get("normal") or {}, s.get("normal_closer") or {}
        twin = s.get("twin") or {}
        right, wrong, amb = (int(twin.get(t, 0)) for t in ("right", "wrong", "ambiguous"))
        head = (f"The angular-variation estimate of the plane normal ({model} model) agrees with the "
                f"{_ref_phrase(data)} to {num(nc.get('median'))} deg (median; RMSE {num(nc.get('rmse'))}, "
                f"95th percentile {num(nc.get('p95'))} deg) on {k} of {n} frames")
        lucky = [e for _, _, e in _errors(data, prim) if e.get("twin") == "ambiguous"
                 and _f(e.get("normal_deg")) is not None and _f(e.get("normal_closer_deg")) is not None
                 and abs(_f(e["normal_deg"]) - _f(e["normal_closer_deg"])) <= 1e-9]
        if wrong == 0 and amb == 0:
            s_out.append(head + (f", with the twin solution resolved in all {right}." if right else "."))
        elif wrong == 0 and len(lucky) == amb:
            rule = "the twin closer to the optical axis (a fixed rule, not an estimate)"
            s_out.append(head + (f". The twin was resolved in {right} frames; in the other {amb} it was left ambiguous "
                                 f"and the reported normal, {rule}, happened to be the right one." if right else
                                 f". The twin was left ambiguous in all {amb} frames; the reported normal, {rule}, "
                                 f"happened to be the right one in each."))
        else:
            s_out.append(head + " when the twin solution closer to the reference is taken.")
            why = ""
            if amb and amb == k:
                why = (" (the pencil has no spoke radii to choose with)" if not _g(data, "pencil", "radius")
                       else " (the spoke radii could not tell them apart)")
            how = (f"the twin was left ambiguous in all {k} frames{why}" if amb == k else
                   f"the twin was chosen right in {right}, wrong in {wrong} and left ambiguous in {amb} "
                   f"frame{'s' if amb != 1 else ''}{why}")
            s_out.append(
                f"As reported, with the twin the method chose, the median is {num(nn.get('median'))} deg "
                f"(RMSE {num(nn.get('rmse'))} deg): {how}"
                + ("; an ambiguous frame reports the twin closer to the optical axis, a fixed rule, not an estimate."
                   if amb else "."))
        cr = _crlb_ratio(data, prim)
        if cr is not None:
            s_out.append(f"Its RMS error is {cr['ratio']:.2f} times the Cramer-Rao bound of these frames "
                         f"(RMS bound {num(cr['bound_rms'])} deg over {cr['count']} frames; 1 is the best any "
                         f"unbiased estimator can do, and chance alone moves the ratio by about "
                         f"+-{0.5 / math.sqrt(cr['count']):.2f} for {cr['count']} frames"
                         + ("; the PnP reference's own error is part of every error here)." if ref != "truth"
                            else ")."))
        covs = []
        for what, c in (("normal", s.get("normal_coverage")), ("tilt", s.get("tilt_coverage"))):
            if isinstance(c, dict) and _f(c.get("fraction")) is not None:
                _, words = coverage_judgement(c.get("fraction"), c.get("expected"), c.get("count"))
                covs.append(f"{pct(c['fraction'])} of the {what} errors ({words})")
        if covs:
            s_out.append("Its reported sigmas cover " + " and ".join(covs) + ".")
        else:
            s_out.append("It reports no sigmas to check.")
        if ref == "pnp":
            cc = _combined_coverage(data, prim)
            if cc is not None:
                _, words = coverage_judgement(cc["fraction"], cc["expected"], cc["count"])
                s_out.append(f"Against the combined sigma of the estimate and the PnP reference, the coverage of the "
                             f"normal errors is {pct(cc['fraction'])} ({words}).")
        det = s.get("detectable")
        if det is not None:
            low = [(_f(fr.get("reference_tilt_deg")), fr.get("image")) for _, fr, _ in _errors(data, prim)
                   if _g(fr, "orient", model, "detectable") is False]
            txt = f"The tilt was detectable in {int(det)} of {k} frames"
            if low:
                tilts = ", ".join(f"{num(t)}" for t, _ in sorted(low, key=lambda x: (x[0] is None, x[0] or 0))[:6]
                                  if t is not None)
                txt += (f"; in the other {len(low)}" + (f" (reference tilt {tilts} deg)" if tilts else "")
                        + " it cannot be told from a frontal pencil and the reported tilt is an upper bound, "
                          "not a measurement")
            s_out.append(txt + ".")
        others = [kk for kk in method_keys(data) if kk.startswith("orient:") and kk != prim
                  and (_g(summ, kk, "frames") or 0) > 0]
        if others:
            parts = [f"{kk.split(':', 1)[1]} {num(_g(summ, kk, 'normal_closer', 'median'))} deg" for kk in others]
            s_out.append("The chapter's other models give medians (closer twin) of " + ", ".join(parts) + ".")
    pnp = [kk for kk in method_keys(data) if kk.startswith("pnp:") and (_g(summ, kk, "frames") or 0) > 0]
    if pnp:
        meds = {kk: _f(_g(summ, kk, "normal", "median")) for kk in pnp}
        meds = {kk: m for kk, m in meds.items() if m is not None}
        if ref == "truth" and meds:
            best = min(meds, key=meds.get)
            txt = (f"PnP from the board corners reaches {num(meds[best])} deg (median normal error, "
                   f"{best.split(':', 1)[1]}; {len(meds)} methods, medians {num(min(meds.values()))}-"
                   f"{num(max(meds.values()))} deg)")
            mine = _f(_g(summ, prim, "normal_closer", "median")) if prim else None
            if mine is not None and meds[best] > 0:
                txt += f"; the angular-variation estimate's median is {num(mine / meds[best])} times that"
            s_out.append(txt + ".")
        elif ref != "truth":
            mx = [_f(_g(summ, kk, "normal", "max")) for kk in pnp]
            mx = [m for m in mx if m is not None]
            counts = _reference_counts(data)
            who = ", ".join(f"{m} in {c}" for m, c in counts.most_common())
            s_out.append(f"The PnP methods agree with the reference (the best PnP pose per frame: {who}) to "
                         f"{num(max(mx) if mx else None)} deg at most; this measures agreement between PnP methods, "
                         f"not their accuracy.")
    sfm = data.get("sfm")
    if isinstance(sfm, dict):
        med = _g(summ, "sfm", "normal", "median")
        s_out.append(f"The reconstruction registered {sfm.get('registered', '?')} of {sfm.get('frames', '?')} frames "
                     f"({sfm.get('points3D', '?')} points, mean reprojection error "
                     f"{num(sfm.get('mean_reprojection_error_px'))} px; rotation alignment "
                     f"{sfm.get('alignment_inliers', '?')} of {sfm.get('alignment_frames', '?')} frames inliers)"
                     + (f"; its aligned normals agree with the reference to {num(med)} deg (median)."
                        if med is not None else "; no frame has an SfM error."))
    # what is missing
    fails = _failures(data)
    if fails:
        notes.append(f"{sum(fails.values())} of {n} frames were not validated: {_reasons(fails, 4)}.")
    if ref != "truth":
        sig = [_f(_g(f, "pnp", f.get("pnp_best") or "", "normal_sigma_deg")) for f in frames if f.get("pnp_best")]
        sig = [v for v in sig if v is not None]
        notes.append("No ground truth: errors are measured against PnP from the board corners, whose own error is part "
                     "of every number" + (f" (median reported sigma of the reference normal {num(np.median(sig))} deg)"
                                          if sig else "") + ".")
    if not isinstance(sfm, dict):
        notes.append("No reconstruction (run `pencilcal validate --sfm` to compare with pycolmap).")
    cal = data.get("calibration")
    if not isinstance(cal, dict) or not cal:
        notes.append("No calibration statistics (give `pencilcal validate --calibration calib.json`, the report of "
                     "`pencilcal calibrate --report`, or a camera file that carries them).")
    elif _calibration_same_images(data):
        notes.append("The camera was calibrated on the same images it is validated on; the intrinsics are not "
                     "independent of the test data.")
    no_tilt = sum(1 for f in frames if f.get("ok") and _f(f.get("reference_tilt_deg")) is None)
    if no_tilt:
        notes.append(f"{no_tilt} validated frame{'s have' if no_tilt != 1 else ' has'} no reference tilt (no pencil "
                     f"vertex in the reference pose).")
    if prim is not None:
        model = prim.split(":", 1)[1]
        flags = [(bool(_g(f, "orient", model, "labels_ambiguous")), bool(_g(f, "orient", model, "normal_ambiguous")))
                 for _, f, _ in _errors(data, prim)]
        lab = sum(1 for la, na in flags if la and not na)
        nrm = sum(1 for _, na in flags if na)
        if lab:
            notes.append(f"{lab} frame{'s' if lab != 1 else ''} with spoke labels that could shift (in-plane angle "
                         f"unknown; the normal is unaffected).")
        if nrm:
            notes.append(f"{nrm} frame{'s' if nrm != 1 else ''} whose normal is ambiguous: another labelling of "
                         f"{'their' if nrm != 1 else 'its'} lines fits about as well and puts the normal elsewhere "
                         f"(normal_alternatives); the errors shown are those of the labelling reported.")
    missing = [t for t, ok in (("ground truth", ref == "truth"), ("a reconstruction", isinstance(sfm, dict)),
                               ("calibration statistics", isinstance(cal, dict) and bool(cal))) if not ok]
    if missing:
        s_out.append("Not covered by this file: " + ", ".join(missing) + ".")
    return " ".join(s_out), notes


# ----------------------------------------------------------------------------------------
# tables


def _cov_cell(c, skip=False):
    if skip:
        return Cell("– (reference)", "muted")
    if not isinstance(c, dict) or _f(c.get("fraction")) is None:
        return Cell("–", "muted")
    verdict_cls, words = coverage_judgement(c.get("fraction"), c.get("expected"), c.get("count"))
    cls = {"ok": "good", "low": "bad", "high": "warn"}.get(verdict_cls)
    return Cell(f"{pct(c['fraction'])} / {pct(c.get('expected'))}", cls, f"n = {c.get('count')}: {words}")


def summary_table(data):
    """The summary table: one row per method (Table)."""
    summ = data["summary"]
    n = len(data["frames"])
    refs = _reference_counts(data)
    cols = ["method", "frames", "median", "RMSE", "p95", "median", "RMSE", "p95", "chosen", "closer",
            "median", "RMSE", "p95", "twin: right, wrong, ambiguous", "normal", "tilt", "detect-able"]
    groups = [("", 2), ("normal error, chosen [deg]", 3), ("normal error, closer twin [deg]", 3),
              ("rotation error, median [deg]", 2), ("|tilt error| [deg]", 3), ("", 1),
              ("sigma coverage, found / expected", 2), ("", 1)]
    rows = []
    for key in method_keys(data):
        s = summ.get(key) or {"frames": 0}
        k = int(s.get("frames") or 0)
        name = _label(key)
        same = _same_as_reference(data, key)
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
            row += [num(_g(s, grp, "median")), num(_g(s, grp, "rmse")), num(_g(s, grp, "p95"))]
        row += [num(_g(s, "rotation", "median")), num(_g(s, "rotation_closer", "median"))]
        row += [num(_g(s, "tilt", "median")), num(_g(s, "tilt", "rmse")), num(_g(s, "tilt", "p95"))]
        row += [Cell(tw, twin_cls), _cov_cell(s.get("normal_coverage"), same), _cov_cell(s.get("tilt_coverage"), same),
                "–" if det is None else f"{int(det)} / {k}"]
        rows.append(row)
    cap = ("Errors against the " + _ref_phrase(data) + ". Chosen: the solution the method reports; closer twin: the "
           "better of the two solutions (the fair measure where the twin is unresolved). Coverage: the fraction of "
           "errors within the reported 1-sigma (68.3% expected for the tilt, 63.2% for the normal's RMS angle); "
           "hover for the binomial check.")
    if refs:
        cap += " † marks the PnP method that is the per-frame reference."
    return Table(cols, rows, groups, cap, numeric_from=1)


def _bound(v):
    """A Cramer-Rao bound for the table: none at zero tilt, where it is not defined."""
    v = _f(v)
    return Cell(num(v)) if v is not None and v > 0 else Cell("–", "muted", "not defined (zero tilt) or not computed")


def _frame_tables(data):
    frames = data["frames"]
    keys = [k for k in method_keys(data) if any(_g(f, "errors", k) for f in frames)]
    prim = _primary(data)
    model = prim.split(":", 1)[1] if prim else ((data.get("models") or ["exact"])[0])
    info_cols = ["#", "image", "ok", "reference", "ref tilt", "CRLB normal", "CRLB tilt", "est. tilt +- sigma",
                 "detectable", "ambiguous", "resolved by", "labels ambig.", "lines used", "RMS resid. [deg]",
                 "board corners", "error"]
    info = []
    for i, f in enumerate(frames):
        o = _g(f, "orient", model) or {}
        ref = f.get("reference")
        if ref == "pnp" and f.get("pnp_best"):
            ref = f"pnp:{f['pnp_best']}"
        tilt = "–"
        if o.get("ok"):
            tilt = f"{num(o.get('tilt_deg'))} +- {num(o.get('tilt_sigma_deg'))}"
        err = f.get("error") or (o.get("error") if not o.get("ok") else None)
        yn = lambda v: "–" if v is None else ("yes" if v else "no")  # noqa: E731
        info.append([str(i), str(f.get("image", "?")), Cell(yn(f.get("ok")), None if f.get("ok") else "bad"),
                     ref or "–", num(f.get("reference_tilt_deg")), _bound(_g(f, "crlb", "normal_deg")),
                     _bound(_g(f, "crlb", "tilt_deg")), tilt,
                     Cell(yn(o.get("detectable")), "warn" if o.get("detectable") is False else None),
                     Cell(yn(o.get("ambiguous")), "warn" if o.get("ambiguous") else None),
                     o.get("resolved_by") or "–",
                     Cell("yes, normal too", "warn") if o.get("normal_ambiguous") else yn(o.get("labels_ambiguous")),
                     "–" if o.get("lines_used") is None else str(o.get("lines_used")),
                     num(o.get("rms_residual_deg")),
                     "–" if f.get("board_corners") is None else str(f.get("board_corners")),
                     Cell(err or "", "muted")])
    bad_rows = [None if f.get("ok") else "bad" for f in frames]
    t_info = Table(info_cols, info, None, f"Per frame: the reference, the Cramer-Rao bound at the reference pose, and "
                                          f"the {model} model's estimate and flags. Angles in degrees.", numeric_from=4,
                   row_cls=bad_rows, text_cols=(10, 15))
    ncols = ["#", "image", "ref tilt"] + [_label(k) for k in keys]
    nrows, trows = [], []
    for i, f in enumerate(frames):
        nr = [str(i), str(f.get("image", "?")), num(f.get("reference_tilt_deg"))]
        tr = list(nr)
        for k in keys:
            e = _g(f, "errors", k)
            if not isinstance(e, dict):
                nr.append(Cell("–", "muted"))
                tr.append(Cell("–", "muted"))
                continue
            a, b = _f(e.get("normal_closer_deg")), _f(e.get("normal_deg"))
            twin = e.get("twin")
            txt = num(a)
            if b is not None and a is not None and abs(b - a) > 1e-9:
                txt += f" [{num(b)}]"
            cls = "bad" if twin == "wrong" else "warn" if twin == "ambiguous" else None
            nr.append(Cell(txt, cls, f"twin: {twin}" if twin and twin != "none" else None))
            t = num(e.get("tilt_deg"))
            if _f(e.get("tilt_sigma_deg")) is not None:
                t += f" +- {num(e.get('tilt_sigma_deg'))}"
            tr.append(t)
        nrows.append(nr)
        trows.append(tr)
    t_norm = Table(ncols, nrows, None, "Normal error per frame and method [deg]: the closer twin, and in brackets the "
                                       "reported (chosen) solution where it differs. Red: the twin was chosen wrong; "
                                       "amber: left ambiguous.", numeric_from=2, row_cls=bad_rows)
    t_tilt = Table(ncols, trows, None, "Tilt error per frame and method [deg], signed (estimate minus reference), with "
                                       "the reported sigma where the method gives one.", numeric_from=2,
                   row_cls=bad_rows)
    return t_info, t_norm, t_tilt


# ----------------------------------------------------------------------------------------
# figures

_ORIENT_STYLE = {"exact": ("C0", "o"), "general": ("C1", "s"), "aligned": ("C2", "^")}
_OTHER_MARKERS = ["D", "v", "<", ">", "P", "h", "*"]


def _style(key, i):
    if key.startswith("orient:"):
        return _ORIENT_STYLE.get(key.split(":", 1)[1], (f"C{i % 10}", "o")) + (True,)
    if key == "sfm":
        return ("C8", "X", True)
    return (f"C{3 + i % 5}", _OTHER_MARKERS[i % len(_OTHER_MARKERS)], False)


def _x_of(data):
    """(x per frame index, axis label): the reference tilt, else the frame index."""
    xs = {i: _f(f.get("reference_tilt_deg")) for i, f in enumerate(data["frames"])}
    if any(v is not None for v in xs.values()):
        return xs, "reference tilt [deg]"
    return {i: float(i) for i in xs}, "frame"


def _plotted_keys(data):
    keys, hidden = [], []
    for k in method_keys(data):
        if not _errors(data, k):
            continue
        (hidden if _same_as_reference(data, k) else keys).append(k)
    return keys, hidden


def _error_signature(data, key):
    rows = []
    for i, _, e in _errors(data, key):
        rows.append([i] + [np.nan if _f(e.get(c)) is None else _f(e.get(c))
                           for c in ("normal_deg", "normal_closer_deg", "tilt_deg")])
    return np.array(rows, float).reshape(-1, 4)


def _duplicates(data, keys):
    """{key: earlier key} for methods whose per-frame errors repeat an earlier method's (to 1e-4)."""
    sig = {k: _error_signature(data, k) for k in keys}
    out = {}
    for j, k in enumerate(keys):
        for prev in keys[:j]:
            if prev in out:
                continue
            a, b = sig[prev], sig[k]
            if a.shape == b.shape and a.size and np.allclose(a, b, rtol=1e-4, atol=1e-9, equal_nan=True):
                out[k] = prev
                break
    return out


def fig_error_vs_tilt(data):
    """Normal error and tilt error of every method against the reference tilt, with the
    per-frame Cramer-Rao bound and the reported sigmas. Returns Plot or None."""
    keys, hidden = _plotted_keys(data)
    if not keys:
        return None
    dup = _duplicates(data, keys)
    keys = [k for k in keys if k not in dup]
    alias = {k: [d for d, p in dup.items() if p == k] for k in keys}
    name = {k: _label(k) + (f" (= {', '.join(_label(a) for a in alias[k])})" if alias[k] else "") for k in keys}
    prim = _primary(data)
    xs, xlabel = _x_of(data)
    fig = _figure(figsize=(11, 7.6))
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    # the bound, per frame, in order of x
    b = sorted((xs[i], _f(_g(f, "crlb", "normal_deg")), _f(_g(f, "crlb", "tilt_deg")))
               for i, f in enumerate(data["frames"]) if xs.get(i) is not None)
    bn = [(x, v) for x, v, _ in b if v is not None and v > 0]
    bt = [(x, v) for x, _, v in b if v is not None and v > 0]
    positive = []
    if bn:
        x, v = np.array(bn).T
        ax1.fill_between(x, 1e-12, v, color="0.6", alpha=0.25, lw=0, label="below the Cramer-Rao bound")
        ax1.plot(x, v, "-", color="0.3", lw=1.0, label="bound (per frame)")
        ax1.plot(x, 2 * v, "--", color="0.3", lw=1.0, label="2 x bound")
        positive += list(v)
    if bt:
        x, v = np.array(bt).T
        ax2.fill_between(x, -2 * v, 2 * v, color="0.6", alpha=0.15, lw=0, label="+-2 x bound")
        ax2.fill_between(x, -v, v, color="0.6", alpha=0.3, lw=0, label="+-1 x bound")
    ax2.axhline(0, color="0.2", lw=0.6)
    chosen_label = False
    tilt_abs, tilt_prim = [], []
    for i, k in enumerate(keys):
        color, marker, filled = _style(k, i)
        rows = [(xs.get(j), e) for j, _, e in _errors(data, k) if xs.get(j) is not None]
        if not rows:
            continue
        x = np.array([r[0] for r in rows])
        closer = np.array([_nan(r[1].get("normal_closer_deg")) for r in rows])
        chosen = np.array([_nan(r[1].get("normal_deg")) for r in rows])
        tilt = np.array([_nan(r[1].get("tilt_deg")) for r in rows])
        ts = np.array([_nan(r[1].get("tilt_sigma_deg")) for r in rows])
        ns = np.array([_nan(r[1].get("normal_sigma_deg")) for r in rows])
        kw = dict(color=color, marker=marker, ls="none", ms=6 if filled else 5,
                  mfc=color if filled else "none", mew=1.2, alpha=0.9)
        ax1.plot(x, np.where(closer > 0, closer, np.nan), label=name[k], **kw)
        positive += [v for v in closer if v > 0]
        diff = np.abs(chosen - closer) > 1e-9
        if diff.any():
            ax1.plot(x[diff], chosen[diff], ls="none", marker="x", color=color, ms=6, mew=1.0,
                     label=None if chosen_label else "as reported (other twin)")
            chosen_label = True
            positive += list(chosen[diff][chosen[diff] > 0])
        if k.startswith("orient:") and np.isfinite(ns).any():
            ax1.plot(x, ns, ls="none", marker="_", color=color, ms=12, mew=2,
                     label=f"{_label(k)}: reported sigma")
        if k.startswith("orient:") and np.isfinite(ts).any():
            ax2.errorbar(x, tilt, yerr=np.where(np.isfinite(ts), ts, 0), fmt=marker, color=color, ms=5,
                         mfc=color if filled else "none", capsize=3, lw=1, label=f"{name[k]} +- reported sigma")
        else:
            ax2.plot(x, tilt, label=name[k], **kw)
        tilt_abs += [abs(v) for v in tilt if np.isfinite(v)]
        if k == prim:
            tilt_prim += [abs(v) for v in tilt if np.isfinite(v)]
    ax1.set_yscale("log")
    pos = [p for p in positive if np.isfinite(p) and p > 0]
    if pos:
        ax1.set_ylim(min(pos) / 2, max(pos) * 2)
    ax1.set_ylabel("normal error [deg] (closer twin)")
    ax1.set_title("Normal error against the " + _ref_phrase(data))
    ax1.grid(True, which="both", alpha=0.25)
    ax1.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), framealpha=0.7)
    symlog = None
    if tilt_abs:
        # a linear band that holds the bound and most errors, logarithmic beyond (outliers)
        inner = max([2.5 * v for _, v in bt] + [float(np.percentile(tilt_prim or tilt_abs, 95)) * 1.2] + [1e-6])
        if max(tilt_abs) > 8 * inner:
            symlog = _nice(inner)
            ax2.set_yscale("symlog", linthresh=symlog, linscale=2.0)
    ax2.set_ylabel("tilt error [deg] (estimate - reference)")
    ax2.set_xlabel(xlabel)
    ax2.grid(True, alpha=0.25)
    ax2.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), framealpha=0.7)
    missing = sum(1 for i, f in enumerate(data["frames"]) if f.get("errors") and xs.get(i) is None)
    cap = ("Top: the angle between each method's normal and the reference normal (closer twin; a cross marks the "
           "solution the method reported where it is the other twin), with the Cramer-Rao bound of each frame's lines "
           "at the reference pose (shaded below 1x, dashed 2x) and the orient sigma as a tick (a point above its "
           "tick lies outside 1 sigma). Bottom: the signed tilt error with the orient sigmas as error bars, in the "
           "+-1x and +-2x bound bands.")
    if symlog:
        cap += f" The tilt axis is linear within +-{num(symlog)} deg and logarithmic beyond."
    if dup:
        cap += " Drawn once, as their errors agree to 1e-4: " + "; ".join(
            f"{_label(k)} = {_label(p)}" for k, p in dup.items()) + "."
    if hidden:
        cap += (f" Not drawn: {', '.join(_label(h) for h in hidden)}, equal to the reference in every frame "
                f"(< 1e-6 deg).")
    if missing:
        cap += f" {missing} frames with errors but no reference tilt are left out."
    return Plot(_png(fig), cap, "Error versus reference tilt")


def _nice_floor(v):
    """The largest of 1, 2, 5 x 10^k at or below v, and at least 1."""
    if not (v > 1):
        return 1.0
    k = math.floor(math.log10(v))
    return float(max(m * 10**k for m in (1, 2, 5) if m * 10**k <= v * (1 + 1e-12)))


def _nice(v):
    """The smallest of 1, 2, 5 x 10^k at or above v."""
    k = math.floor(math.log10(v))
    for m in (1, 2, 5, 10):
        if m * 10**k >= v * (1 - 1e-12):
            return m * 10**k
    return 10 ** (k + 1)


def _half_normal_cdf(z):
    return np.array([math.erf(v / math.sqrt(2)) for v in np.ravel(z)])


def fig_sigma_calibration(data):
    """Reported sigma against actual error, and the distribution of error/sigma against
    what correct sigmas give. Returns Plot or None."""
    keys, _ = _plotted_keys(data)
    series = []  # (label, err, sigma, kind, color)
    for i, k in enumerate(keys):
        color = _style(k, i)[0]
        rows = [e for _, _, e in _errors(data, k)]
        if k.startswith("orient:"):
            t = [(abs(_f(e.get("tilt_deg"))), _f(e.get("tilt_sigma_deg"))) for e in rows
                 if _f(e.get("tilt_deg")) is not None and _f(e.get("tilt_sigma_deg"))]
            if t:
                series.append((f"{_label(k)} tilt", *np.array(t).T, "tilt", color, "o"))
            nrm = [(_f(e.get("normal_closer_deg")), _f(e.get("normal_sigma_deg"))) for e in rows
                   if _f(e.get("normal_closer_deg")) is not None and _f(e.get("normal_sigma_deg"))]
        else:
            nrm = [(_f(e.get("normal_deg")), _f(e.get("normal_sigma_deg"))) for e in rows
                   if _f(e.get("normal_deg")) is not None and _f(e.get("normal_sigma_deg"))]
        if nrm:
            series.append((f"{_label(k)} normal", *np.array(nrm).T, "normal", color, "s"))
    if data.get("reference") == "pnp":
        prim = _primary(data)
        if prim:
            pairs = []
            for _, fr, e in _errors(data, prim):
                s_ref = _f(_g(fr, "pnp", fr.get("pnp_best") or "", "normal_sigma_deg"))
                if s_ref and _f(e.get("normal_sigma_deg")) and _f(e.get("normal_closer_deg")) is not None:
                    pairs.append((_f(e["normal_closer_deg"]), math.hypot(_f(e["normal_sigma_deg"]), s_ref)))
            if pairs:
                series.append((f"{_label(prim)} normal vs combined sigma (with PnP)", *np.array(pairs).T, "normal",
                               "k", "D"))
    if not series:
        return None
    # keep the plot readable: a method that repeats another's errors and sigmas is named, not redrawn
    kept, same = [], []
    for sr in series:
        for j, other in enumerate(kept):
            if other[3] == sr[3] and other[1].shape == sr[1].shape \
                    and np.allclose(other[1], sr[1], rtol=1e-4, atol=1e-9) \
                    and np.allclose(other[2], sr[2], rtol=1e-4, atol=1e-9):
                same[j].append(sr[0].rsplit(" ", 1)[0])
                break
        else:
            kept.append(sr)
            same.append([])
    series = [(lab + (f" (= {', '.join(o)})" if len(o) == 1 else f" (= {len(o)} others)" if o else ""),) + sr[1:]
              for (lab, *_), sr, o in zip(kept, kept, same)]
    merged = [f"{sr[0].split(' (=')[0]} = {', '.join(o)}" for sr, o in zip(series, same) if o]
    fig = _figure(figsize=(11, 4.8))
    ax1, ax2 = fig.subplots(1, 2)
    allv = []
    for label, e, s, kind, color, marker in series:
        ok = (e > 0) & (s > 0)
        ax1.plot(s[ok], e[ok], ls="none", marker=marker, ms=4, color=color, mfc="none" if kind == "normal" else color,
                 alpha=0.8, label=label)
        allv += list(e[ok]) + list(s[ok])
        z = np.sort(e / s)
        ax2.step(np.r_[0, z], np.r_[0, np.arange(1, z.size + 1) / z.size], where="post", color=color,
                 ls="-" if kind == "tilt" else "--", label=f"{label} (n={z.size})")
    if allv:
        lo, hi = min(allv) / 2, max(allv) * 2
        g = np.array([lo, hi])
        ax1.plot(g, g, "k-", lw=0.8, label="error = sigma")
        ax1.plot(g, 1.96 * g, "k:", lw=0.8, label="95% (tilt: 1.96 sigma; normal: 1.73)")
        ax1.plot(g, 1.731 * g, "k:", lw=0.8)
        ax1.set_xlim(lo, hi)
        ax1.set_ylim(lo, hi)
    ax1.set_xscale("log")
    ax1.set_yscale("log")
    ax1.set_xlabel("reported sigma [deg]")
    ax1.set_ylabel("|error| [deg]")
    ax1.set_title("Reported sigma against actual error")
    ax1.grid(True, which="both", alpha=0.25)
    zmax = 4.0
    z = np.linspace(0, zmax, 200)
    ax2.plot(z, _half_normal_cdf(z), color="0.5", lw=2.5, alpha=0.5, label="expected, tilt (1-D Gaussian)")
    ax2.plot(z, 1 - np.exp(-z**2), color="0.5", lw=2.5, alpha=0.5, ls="--",
             label="expected, normal (2-D, RMS sigma)")
    ax2.axvline(1.0, color="0.4", lw=0.6)
    ax2.set_xlim(0, zmax)
    ax2.set_ylim(0, 1.02)
    ax2.set_xlabel("|error| / reported sigma")
    ax2.set_ylabel("fraction of frames")
    ax2.set_title("Calibration of the uncertainties")
    ax2.grid(True, alpha=0.25)
    ax1.legend(fontsize=6.5, loc="upper left", framealpha=0.7)
    ax2.legend(fontsize=6.5, loc="lower right", framealpha=0.7)
    cap = ("Left: each point is one frame; with correct sigmas the tilt points scatter about the solid line with 95% "
           "below the dotted one. Right: the fraction of frames with |error| / sigma below each value, against the "
           "curves correct sigmas give (68.3% at 1 for the tilt, 63.2% for the normal's RMS angle). A curve to the "
           "right of its expectation means sigmas that are too small.")
    if data.get("reference") == "pnp":
        cap += (" With PnP as the reference the errors include the reference's own; the black curve uses the combined "
                "sigma of both.")
    if merged:
        cap += " Drawn once, as their errors and sigmas agree to 1e-4: " + "; ".join(merged) + "."
    return Plot(_png(fig), cap, "Calibration of the reported sigmas")


def _camera(data):
    from pencilcal.toolkit.camera.formats import camera_from_dict

    try:
        return camera_from_dict(data.get("camera"), source="validation camera"), None
    except PencilcalError as e:
        return None, str(e)


def _sample_frames(data, count):
    """Indices of `count` validated frames spread evenly over the reference tilt."""
    if count <= 0:
        return []
    xs, _ = _x_of(data)
    cand = [i for i, f in enumerate(data["frames"]) if f.get("ok") or _g(f, "orient", "exact", "ok")]
    if not cand:
        cand = list(range(len(data["frames"])))
    cand.sort(key=lambda i: (xs.get(i) is None, xs.get(i) or 0.0, i))
    if len(cand) <= count:
        return cand
    pick = np.unique(np.round(np.linspace(0, len(cand) - 1, count)).astype(int))
    return [cand[p] for p in pick]


def _image_path(data, fr, roots=()):
    """The frame's image: its recorded path, else that path under the validation file's
    folder, else the image name in the file's images folder."""
    path = fr.get("path")
    cands = []
    if path:
        cands.append(Path(str(path)))
        if not Path(str(path)).is_absolute():
            cands += [Path(r) / str(path) for r in roots]
    if fr.get("image") and data.get("images"):
        cands.append(Path(str(data["images"])) / str(fr["image"]))
    for c in cands:
        if c.is_file():
            return str(c)
    return path


def _read_image(path):
    import cv2

    if not path or not Path(str(path)).is_file():
        return None, f"image not found at {path}"
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        return None, f"cannot decode {path}"
    return img[..., ::-1], None


def _proj_polyline(cam, P, rmax):
    """Project camera-frame points; NaN where behind the camera or beyond the lens's field."""
    P = np.asarray(P, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        xy = P[:, :2] / P[:, 2:3]
        r = np.hypot(xy[:, 0], xy[:, 1])
        uv = cam.project(P)
    bad = ~(P[:, 2] > 0) | (r > rmax) | ~np.isfinite(uv).all(1)
    uv[bad] = np.nan
    return uv


def _field_radius(cam):
    """Largest normalised radius the image sees (points beyond it can fold back in)."""
    try:
        corners = np.array([[0, 0], [cam.width - 1, 0], [0, cam.height - 1], [cam.width - 1, cam.height - 1]], float)
        rays = cam.rays_from_pixels(corners)
        r = np.hypot(rays[:, 0] / rays[:, 2], rays[:, 1] / rays[:, 2])
        return float(np.nanmax(r)) * 1.15 if np.isfinite(r).any() else 10.0
    except Exception:  # noqa: BLE001 - a drawing aid only
        return 10.0


def _vertex_3d(fr, o, data):
    """The vertex in the camera frame at the reference pose: the vertex ray met with the
    board plane (else the pencil file's vertex, else None)."""
    R, t = fr.get("R_ref"), fr.get("t_ref")
    if R is None or t is None:
        return None
    R, t = np.asarray(R, float), np.asarray(t, float)
    n = R[:, 2]
    ray = o.get("ray")
    if ray is not None:
        ray = np.asarray(ray, float)
        d = float(n @ ray)
        if abs(d) > 1e-9:
            lam = float(n @ t) / d
            if lam > 0:
                return lam * ray
    v = _g(data, "pencil", "vertex")
    if isinstance(v, list) and len(v) == 2:
        return R @ np.r_[np.asarray(v, float), 0.0] + t
    return None


def _segment_point_at(sgm, v, r):
    """The point of segment `sgm` (x1, y1, x2, y2) whose distance to `v` is closest to r."""
    p, q = np.asarray(sgm[:2], float), np.asarray(sgm[2:], float)
    t = np.linspace(0, 1, 101)[:, None]
    pts = p + t * (q - p)
    return pts[np.argmin(np.abs(np.hypot(*(pts - v).T) - r))]


def fig_overlay(data, index, cam, field_r, roots=()):
    """The sample frame `index` with everything the estimate and the reference say about it.

    Returns (png bytes, caption) or (None, reason)."""
    import matplotlib
    from matplotlib import patheffects
    from matplotlib.patches import Ellipse

    fr = data["frames"][index]
    img, why = _read_image(_image_path(data, fr, roots))
    if img is None:
        return None, f"{fr.get('image')}: {why}; no overlay."
    o = _g(fr, "orient", "exact") or {}
    if not o:
        for m in data.get("models") or []:
            if isinstance(_g(fr, "orient", m), dict):
                o = fr["orient"][m]
                break
    try:
        segs = np.asarray(fr.get("segments") or [], float).reshape(-1, 4)
    except ValueError:
        segs = np.zeros((0, 4))
    spokes = o.get("spokes")
    labels = spokes if isinstance(spokes, list) and len(spokes) == len(segs) else None
    vpx = np.asarray(o["vertex_px"], float) if o.get("vertex_px") is not None else None
    h, w = img.shape[:2]
    zoom = segs.size > 0 or vpx is not None
    panel_w = 5.6
    fig = _figure(figsize=(2 * panel_w if zoom else panel_w + 1, panel_w * h / w + 1.5))
    axes = fig.subplots(1, 2 if zoom else 1, squeeze=False)[0]
    board = data.get("board") or {}
    size = None
    try:
        if board.get("type") == "charuco":
            size = (board["squares"][0] * board["square"], board["squares"][1] * board["square"])
        elif board.get("squares") and board.get("square"):
            size = ((board["squares"][0] - 1) * board["square"], (board["squares"][1] - 1) * board["square"])
    except (KeyError, TypeError, IndexError):
        size = None
    L = 0.4 * min(size) if size else None
    R_ref = np.asarray(fr["R_ref"], float) if fr.get("R_ref") is not None else None
    t_ref = np.asarray(fr["t_ref"], float) if fr.get("t_ref") is not None else None
    P0 = _vertex_3d(fr, o, data) if cam is not None else None
    notes = []
    if cam is not None and (cam.width, cam.height) != (w, h):
        notes.append(f"the image is {w}x{h}, the camera {cam.width}x{cam.height}")
    # the zoom window: around the vertex (else the segments), with the image's aspect
    if zoom:
        pts = np.concatenate([segs[:, :2], segs[:, 2:]]) if segs.size else vpx[None]
        span = float(max(np.ptp(pts[:, 0]), np.ptp(pts[:, 1]), 40.0))
        centre = vpx if vpx is not None else pts.mean(0)
        half = max(0.3 * span, 30.0)
        hx, hy = (half * w / h, half) if w >= h else (half, half * h / w)
        hx, hy = min(hx, w / 2), min(hy, h / 2)
        cx = min(max(centre[0], hx - 0.5), w - 0.5 - hx)
        cy = min(max(centre[1], hy - 0.5), h - 0.5 - hy)
        zoom_box = (cx - hx, cx + hx, cy + hy, cy - hy)
    scale = 1.0
    ell = None
    if vpx is not None and o.get("vertex_cov_px2") is not None:
        cov = np.asarray(o["vertex_cov_px2"], float)
        if cov.shape == (2, 2) and np.all(np.isfinite(cov)):
            ev, evec = np.linalg.eigh(cov)
            a3 = 3 * np.sqrt(np.clip(ev, 0, None))
            if a3.max() > 0:
                target = 0.04 * 2 * hx if zoom else 0.015 * w
                scale = _nice_floor(target / a3.max())
                ell = (2 * a3[1] * scale, 2 * a3[0] * scale, math.degrees(math.atan2(evec[1, 1], evec[0, 1])))
    cmap = matplotlib.colormaps["tab10"]
    handles = {}

    def keep(name, artist):
        handles.setdefault(name, artist)

    for ai, ax in enumerate(axes):
        ax.imshow(img, interpolation="antialiased")
        ax.set_xticks([])
        ax.set_yticks([])
        lw = 1.0 if ai == 0 else 1.8
        # board outline and axes at the reference pose
        if cam is not None and R_ref is not None and t_ref is not None and size:
            s = np.linspace(0, 1, 40)[:, None]
            W, H = size
            corners = np.array([[0, 0, 0], [W, 0, 0], [W, H, 0], [0, H, 0], [0, 0, 0]], float)
            outline = np.concatenate([c0 + s * (c1 - c0) for c0, c1 in zip(corners[:-1], corners[1:])])
            uv = _proj_polyline(cam, (R_ref @ outline.T).T + t_ref, field_r)
            keep("board outline (reference pose)", ax.plot(uv[:, 0], uv[:, 1], "-", color="cyan", lw=0.9)[0])
            for axis, col, name in ((0, "red", "x"), (1, "lime", "y"), (2, "blue", "z")):
                e = np.zeros(3)
                e[axis] = L
                uv = _proj_polyline(cam, (R_ref @ (s * e).T).T + t_ref, field_r)
                keep(f"board {name} axis (reference pose)", ax.plot(uv[:, 0], uv[:, 1], "-", color=col, lw=2.4)[0])
        # pencil segments by spoke
        for j, sgm in enumerate(segs):
            k = labels[j] if labels is not None else None
            if k is None:
                keep("segment (no label)", ax.plot(sgm[0::2], sgm[1::2], "-", color="yellow", lw=lw)[0])
            elif int(k) < 0:
                keep("rejected segment", ax.plot(sgm[0::2], sgm[1::2], "--", color="red", lw=lw)[0])
            else:
                c = cmap(int(k) % 10)
                keep("pencil segment, numbered by spoke", ax.plot(sgm[0::2], sgm[1::2], "-", color=c, lw=lw + 0.6)[0])
                if ai == 1 and vpx is not None:
                    ax.annotate(str(int(k)), _segment_point_at(sgm, vpx, 0.8 * min(hx, hy)), color="white",
                                fontsize=7, ha="center", va="center", annotation_clip=True,
                                bbox=dict(boxstyle="round,pad=0.15", fc=c, ec="none", alpha=0.85))
        # vertex and its covariance
        if vpx is not None:
            keep("vertex", ax.plot(*vpx, "+", color="magenta", ms=12 if ai else 8, mew=1.5)[0])
            if ell is not None:
                e = Ellipse(vpx, ell[0], ell[1], angle=ell[2], fill=False, color="magenta", lw=1.4)
                ax.add_patch(e)
                keep("vertex 3-sigma ellipse" + (f" x{scale:g}" if scale > 1 else ""), e)
        # normals from the vertex
        if cam is not None and P0 is not None and L:
            s = np.linspace(0, 1, 20)[:, None]
            # the reference last and thinner: it shows inside an estimate that lies on it
            for vec, col, ls, name, wid in ((o.get("normal"), "white", "-", "estimated normal", 3.2),
                                            (o.get("normal_twin"), "white", (0, (2, 2)), "twin normal", 3.2),
                                            (R_ref[:, 2] if R_ref is not None else None, "blue", "-",
                                             "reference normal", 1.3)):
                if vec is None:
                    continue
                uv = _proj_polyline(cam, P0 + s * (L * np.asarray(vec, float)), field_r)
                lw_n = wid if ai else wid * 0.7
                ln = ax.plot(uv[:, 0], uv[:, 1], ls=ls, color=col, lw=lw_n,
                             path_effects=[patheffects.withStroke(linewidth=lw_n + 1.6, foreground="black")])[0]
                keep(name, ln)
                if np.isfinite(uv[-1]).all():
                    ax.plot(*uv[-1], "o", color=col, ms=4, mec="black")
        ax.set_xlim(-0.5, w - 0.5)
        ax.set_ylim(h - 0.5, -0.5)
    if zoom:
        x0, x1, y0, y1 = zoom_box
        axes[1].set_xlim(x0, x1)
        axes[1].set_ylim(y0, y1)
        axes[1].set_title("around the vertex", fontsize=9)
        axes[0].add_patch(matplotlib.patches.Rectangle((x0, y1), x1 - x0, y0 - y1, fill=False, ec="white", lw=0.8,
                                                       ls="--"))
    if handles:
        fig.legend(list(handles.values()), list(handles.keys()), loc="outside lower center", ncol=4, fontsize=7,
                   framealpha=0.8)
    e = _g(fr, "errors", "orient:exact") or {}
    title = f"{fr.get('image')}: reference tilt {num(fr.get('reference_tilt_deg'))} deg"
    if o.get("ok"):
        title += (f"; estimate {num(o.get('tilt_deg'))} +- {num(o.get('tilt_sigma_deg'))} deg"
                  + ("" if o.get("detectable", True) else " (not detectable)"))
    if e:
        title += f"; normal error {num(e.get('normal_closer_deg'))} deg (twin {e.get('twin')})"
    elif o and not o.get("ok"):
        title += f"; no estimate: {o.get('error')}"
    fig.suptitle(title, fontsize=9)
    cap = (f"Frame {index} ({fr.get('image')}); right: the dashed box of the left panel. Pencil segments coloured "
           f"and numbered by the spoke they were assigned to, rejected ones dashed red; the vertex with its 3-sigma "
           f"covariance ellipse" + (f" magnified {scale:g} times" if scale > 1 else "")
           + "; the board's x (red), y (green) and z (blue) axes and its outline (cyan) at the reference pose; "
             "from the vertex the reference normal (blue), the estimated normal (white) and its twin (white "
             "dashed), projected from where the vertex's ray meets the board plane.")
    if cam is None:
        cap += " No usable camera in the file: nothing is projected."
    elif R_ref is None:
        cap += " No reference pose in this frame: no board axes."
    if notes:
        cap += " Note: " + "; ".join(notes) + "."
    return _png(fig, dpi=100), cap


def _view_table_and_fig(cal):
    views = cal.get("views") if isinstance(cal.get("views"), list) else None
    blocks = []
    if views:
        names = [str(v.get("image", i)) for i, v in enumerate(views)]
        rms = [_f(v.get("rms_px")) for v in views]
        used = [bool(v.get("used")) for v in views]
        # a view rejected as an outlier keeps its RMS in the rejected list
        rejected_rms = {str(r.get("image")): _f(r.get("rms_px")) for r in cal.get("rejected") or []
                        if isinstance(r, dict) and r.get("corner") is None and _f(r.get("rms_px")) is not None}
        rms = [r if r is not None else rejected_rms.get(nm) for r, nm in zip(rms, names)]
        if any(r is not None for r in rms):
            fig = _figure(figsize=(10, 3.6))
            ax = fig.subplots()
            x = np.arange(len(views))
            ax.bar(x, [r or 0 for r in rms], color=["C0" if u else "C3" for u in used], width=0.8)
            for i, r in enumerate(rms):
                if r is None:
                    ax.plot(i, 0, "x", color="0.4", ms=4)
            total = _f(cal.get("rms_px"))
            if total is not None:
                ax.axhline(total, color="k", ls="--", lw=1, label=f"overall RMS {num(total)} px")
                ax.legend(fontsize=8)
            ax.set_xticks(x, names, rotation=90, fontsize=max(4, min(8, 400 // max(len(x), 1))))
            ax.set_ylabel("reprojection RMS [px]")
            ax.set_title("Per-view reprojection error (blue: used; red: rejected; x: no board)")
            ax.set_xlim(-0.7, len(x) - 0.3)
            blocks.append(Plot(_png(fig), "Per-view RMS reprojection error of the calibration; views without a "
                                          "usable board are marked with a cross at zero.", "Per-view errors"))
    return blocks


_DIST_NAMES = {"opencv": ["k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "taux", "tauy"],
               "fisheye": ["k1", "k2", "k3", "k4"], "pinhole": []}


def _calibration_section(data):
    cal = data.get("calibration")
    sec = Section("calibration", "6. Calibration quality")
    if not isinstance(cal, dict) or not cal:
        sec.blocks.append(Para("Not in this file: validate was given no calibration report (--calibration) and the "
                               "camera file carries no statistics.", "note"))
        return sec
    cam = data.get("camera") or {}
    kv = []
    if _f(cal.get("rms_px")) is not None:
        kv.append(("RMS reprojection error", f"{num(cal['rms_px'])} px"))
    for k in ("model", "coefficients", "fix_aspect", "flags", "images", "image_size"):
        if cal.get(k) not in (None, [], ""):
            v = cal[k]
            kv.append((k.replace("_", " "), ", ".join(map(str, v)) if isinstance(v, list) else str(v)))
    for k in ("views_used", "views_total", "corners_used"):
        if cal.get(k) is not None:
            kv.append((k.replace("_", " "), str(cal[k])))
    counts = cal.get("counts")
    if isinstance(counts, dict):
        for k, v in counts.items():
            kv.append((k.replace("_", " "), str(v)))
    if kv:
        sec.blocks.append(Table(["quantity", "value"], [[a, b] for a, b in kv], None, None, numeric_from=9))
    if _calibration_same_images(data):
        sec.blocks.append(Para("The calibration used the same images as this validation.", "note"))
    cal_cam = cal.get("camera")
    if isinstance(cal_cam, dict) and cal_cam.get("K") is not None and cam.get("K") is not None:
        try:
            same = np.allclose(np.asarray(cal_cam["K"], float), np.asarray(cam["K"], float), rtol=1e-9, atol=1e-9)
        except (TypeError, ValueError):
            same = False
        if not same:
            sec.blocks.append(Para("The calibration report's camera differs from the camera this validation used.",
                                   "note"))
    std = cal.get("std_intrinsics")
    if isinstance(std, dict) and std:
        K = cam.get("K")
        vals = {}
        try:
            if K is not None:
                vals.update(fx=K[0][0], fy=K[1][1], cx=K[0][2], cy=K[1][2], skew=K[0][1])
            names = _DIST_NAMES.get(cam.get("model"), [])
            vals.update(dict(zip(names, cam.get("dist") or [])))
        except (TypeError, IndexError):
            pass
        rows = []
        for k, s in std.items():
            v = _f(vals.get(k))
            sv = _f(s)
            rel = f"{100 * sv / abs(v):.2g}%" if v and sv is not None else "–"
            rows.append([k, "–" if v is None else f"{v:.6g}", "–" if sv is None else f"{sv:.3g}", rel])
        sec.blocks.append(Table(["parameter", "value", "sigma", "sigma / |value|"], rows, None,
                                "Intrinsics of the validated camera with the calibration's standard deviations.",
                                numeric_from=1))
    sec.blocks += _view_table_and_fig(cal)
    rej = cal.get("rejected")
    if isinstance(rej, list) and rej:
        rows = [[str(r.get("image", "")), str(r.get("stage", "")),
                 "–" if r.get("corner") is None else str(r.get("corner")),
                 num(r.get("residual_px", r.get("rms_px"))), Cell(str(r.get("reason", "")), "muted")]
                for r in rej if isinstance(r, dict)]
        stages = Counter(str(r.get("stage")) for r in rej if isinstance(r, dict))
        sec.blocks.append(Details(f"Rejected views and corners ({', '.join(f'{v} {k}' for k, v in stages.items())})",
                                  [Table(["image", "stage", "corner", "residual [px]", "reason"], rows, None, None,
                                         numeric_from=2, text_cols=(4,))]))
    return sec


def _sfm_section(data):
    sec = Section("sfm", "7. Reconstruction (SfM)")
    sfm = data.get("sfm")
    if not isinstance(sfm, dict):
        sec.blocks.append(Para("Not in this file: run `pencilcal validate --sfm` to compare with a pycolmap "
                               "reconstruction (intrinsics held fixed) aligned to the board frame.", "note"))
        return sec
    reg = sum(1 for f in data["frames"] if _g(f, "sfm", "registered"))
    rows = [["registered frames", f"{sfm.get('registered', '–')} of {sfm.get('frames', '–')}"],
            ["3D points", str(sfm.get("points3D", "–"))],
            ["mean reprojection error", f"{num(sfm.get('mean_reprojection_error_px'))} px"],
            ["rotation alignment inliers",
             f"{sfm.get('alignment_inliers', '–')} of {sfm.get('alignment_frames', '–')} frames shared with PnP"],
            ["frames with an SfM pose in this file", str(reg)]]
    Rwt = sfm.get("R_world_from_target")
    if Rwt is not None:
        try:
            R = np.asarray(Rwt, float)
            ang = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(R) - 1) / 2))))
            rows.append(["R_world_from_target (angle)", f"{num(ang)} deg"])
        except (TypeError, ValueError):
            pass
    sec.blocks.append(Table(["quantity", "value"], rows, None,
                            "The reconstruction is aligned to the board frame by robust rotation averaging against the "
                            "PnP poses; its errors are in the summary table (row sfm).", numeric_from=9))
    s = _g(data, "summary", "sfm")
    if isinstance(s, dict) and s.get("frames"):
        sec.blocks.append(Para(f"SfM normal error against the {_ref_phrase(data)}: median "
                               f"{num(_g(s, 'normal', 'median'))} deg, RMSE {num(_g(s, 'normal', 'rmse'))} deg, "
                               f"95th percentile {num(_g(s, 'normal', 'p95'))} deg over {s['frames']} frames."))
    return sec


def _as_arrays(obj):
    """JSON lists of numbers (with nulls) back to float arrays, as the heatmap code expects."""
    def nan(v):
        if isinstance(v, list):
            return [nan(x) for x in v]
        return np.nan if v is None else v

    if isinstance(obj, dict):
        return {k: _as_arrays(v) for k, v in obj.items()}
    if isinstance(obj, list):
        try:
            a = np.array(nan(obj), dtype=float)
            if a.dtype == float and a.ndim >= 1:
                return a
        except (TypeError, ValueError):
            pass
        return [_as_arrays(v) for v in obj]
    return obj


def _spacing(angles):
    """Spacing of a pencil's line directions: one number for a regular fan, else the range."""
    try:
        a = np.unique(np.round(np.mod(np.asarray(angles, float), 180.0), 6))
    except (TypeError, ValueError):
        return "–"
    if a.size < 2:
        return "–"
    d = np.diff(a)
    if np.allclose(d, d[0], atol=1e-6):
        return num(d[0])
    return f"irregular, {num(d.min())}-{num(d.max())}"


def _sensitivity_section(data, sens):
    sec = Section("sensitivity", "8. Planned sensitivity")
    if sens is None:
        sec.blocks.append(Para("Not given: `pencilcal report --sensitivity sensitivity.json` adds the plan of "
                               "`pencilcal sensitivity` next to what was measured.", "note"))
        return sec
    from .. import sensitivity as sv

    st = sens.get("setup") or {}
    ans = sens.get("answer") or {}
    if ans.get("text"):
        sec.blocks.append(Para(str(ans["text"]), "lead"))
    pencil_n = len(_g(data, "pencil", "angles_deg", default=[]) or [])
    fx = _g(data, "camera", "K", 0, 0)
    sig = []
    for f in data["frames"]:
        s = _g(f, "orient", "exact", "lines", "sigma")
        if isinstance(s, list):
            sig += [v for v in (_f(x) for x in s) if v is not None]
    rows = [["spokes", str(st.get("spokes", "–")), str(pencil_n or "–")],
            ["spoke spacing [deg]", num(st.get("step_deg")), _spacing(_g(data, "pencil", "angles_deg"))],
            ["line-angle noise [deg]", num(st.get("sigma_deg")),
             (num(math.degrees(float(np.median(sig)))) + " (median reported)") if sig else "–"],
            ["focal length [px]", num(st.get("focal_px")), num(fx)],
            ["trials per cell", str(st.get("trials", "–")), "–"],
            ["accuracy asked [deg]", num(st.get("accuracy_deg")), "–"]]
    sec.blocks.append(Table(["set-up", "planned", "this sequence"], rows, None,
                            "The plan holds only as far as its set-up matches the sequence.", numeric_from=1))
    det = sens.get("detection")
    if isinstance(det, dict):
        drows = [["rule 2 sqrt(sigma)", num(det.get("rule_2sqrt_sigma_deg"))],
                 ["exact (largest angle change = sigma)", num(det.get("exact_deg"))]]
        for m in det.get("measured") or []:
            drows.append([f"measured at {num(m.get('offaxis_deg'))} deg off axis: 50% / 90% detectable",
                          f"{num(m.get('rate50_deg'))} / {num(m.get('rate90_deg'))}"])
        sec.blocks.append(Table(["detection threshold", "tilt [deg]"], drows, None, None, numeric_from=1))
    maps = _as_arrays(sens.get("maps") or {})
    acc = _f(st.get("accuracy_deg")) or 1.0
    sigma = _f(st.get("sigma_deg")) or 0.1
    for key, fn, size in (("tilt_offaxis", lambda fig, m: sv._heat_tilt_offaxis(fig, m, acc, sigma), (11, 4.4)),
                          ("spokes_spacing", lambda fig, m: sv._heat_spokes_spacing(fig, m), (11, 4.4)),
                          ("noise", lambda fig, m: sv._heat_noise(fig, m, acc), (7.5, 4.4))):
        if key not in maps:
            continue
        try:
            fig = _figure(figsize=size)
            fn(fig, maps[key])
            sec.blocks.append(Plot(_png(fig), f"Sensitivity map {key.replace('_', ' x ')} (docs/sensitivity.md, "
                                              f"'Reading the heatmaps').", f"sensitivity {key}"))
        except (KeyError, TypeError, ValueError, IndexError, AttributeError) as e:
            sec.blocks.append(Para(f"The {key} map could not be drawn ({type(e).__name__}: {e}).", "note"))
    m = maps.get("tilt_offaxis")
    prim = _primary(data)
    if isinstance(m, dict) and isinstance(m.get("tilts_deg"), np.ndarray):
        try:
            sec.blocks.append(_fig_planned_vs_measured(data, m, prim))
        except (KeyError, TypeError, ValueError, IndexError) as e:
            sec.blocks.append(Para(f"The planned-versus-measured plot could not be drawn ({e}).", "note"))
    return sec


def _fig_planned_vs_measured(data, m, prim):
    import matplotlib

    fig = _figure(figsize=(9, 4.6))
    ax = fig.subplots()
    t, off = m["tilts_deg"], np.atleast_1d(m["offaxis_deg"])
    mc = m.get("mc") if isinstance(m.get("mc"), dict) else None
    curves = mc["normal_rmse_deg"] if mc is not None else m["crb"]["normal_deg"]
    curves = np.atleast_2d(curves)
    lo, hi = float(np.nanmin(off)), float(np.nanmax(off))
    norm = matplotlib.colors.Normalize(vmin=lo, vmax=max(hi, lo + 1))
    cmap = matplotlib.colormaps["viridis"]
    for k, o in enumerate(off):
        ax.plot(t, curves[k], "-", color=cmap(norm(o)), lw=1.5,
                label=f"planned RMS ({'Monte Carlo' if mc is not None else 'bound'}), {num(o)} deg off axis")
    if prim:
        model = prim.split(":", 1)[1]
        pts = []
        for _, fr, e in _errors(data, prim):
            x, y = _f(fr.get("reference_tilt_deg")), _f(e.get("normal_closer_deg"))
            ray = _g(fr, "orient", model, "ray")
            if x is None or y is None or y <= 0:
                continue
            offa = math.degrees(math.acos(max(-1.0, min(1.0, float(ray[2]))))) if isinstance(ray, list) else np.nan
            pts.append((x, y, offa))
        if pts:
            p = np.array(pts)
            sc = ax.scatter(p[:, 0], p[:, 1], c=np.where(np.isfinite(p[:, 2]), p[:, 2], np.nanmin(off)), cmap=cmap,
                            norm=norm, edgecolors="k", s=28, zorder=3, label=f"measured, {_label(prim)} (closer twin)")
            fig.colorbar(sc, ax=ax, label="vertex off axis [deg]")
        b = [(_f(f.get("reference_tilt_deg")), _f(_g(f, "crlb", "normal_deg"))) for f in data["frames"]]
        b = sorted((x, y) for x, y in b if x is not None and y is not None and y > 0)
        if b:
            x, y = np.array(b).T
            ax.plot(x, y, "k.", ms=4, label="this sequence's bound (per frame)")
    ax.set_yscale("log")
    ax.set_xlabel("tilt against the vertex ray [deg]")
    ax.set_ylabel("normal error [deg]")
    ax.set_title("Planned against measured")
    ax.grid(True, which="both", alpha=0.25)
    ax.legend(fontsize=7, framealpha=0.7)
    return Plot(_png(fig), "The plan's RMS normal error over tilt (one curve per off-axis angle of the plan) with the "
                           "errors measured here (one point per frame, coloured by how far off axis its vertex was) "
                           "and this sequence's own per-frame bound. Single frames scatter about an RMS curve; the "
                           "summary table has the RMS.", "planned vs measured")


def _repro_section(data, source, report_command, sens_path):
    sec = Section("reproducibility", "9. Reproducibility")
    r = data.get("reproducibility") or {}
    rows = []
    cmd = r.get("command")
    if isinstance(cmd, list) and cmd:
        c = [str(x) for x in cmd]
        if Path(c[0]).name in ("pencilcal", "__main__.py", "main.py"):
            c[0] = "pencilcal"
        rows.append(["validation command", shlex.join(c)])
    rows.append(["validation created", str(r.get("created", "–"))])
    if source is not None:
        rows.append(["validation file", str(source)])
        try:
            rows.append(["validation file SHA-256", _sha256(source)])
        except OSError:
            pass
    if sens_path is not None:
        rows.append(["sensitivity file", str(sens_path)])
        try:
            rows.append(["sensitivity file SHA-256", _sha256(sens_path)])
        except OSError:
            pass
    if report_command:
        rows.append(["report command", report_command])
    rows.append(["report created", _dt.datetime.now().astimezone().strftime("%Y-%m-%dT%H:%M:%S%z")])
    for k in ("sequence", "images", "camera_file"):
        if data.get(k):
            rows.append([k.replace("_", " "), str(data[k])])
    sec.blocks.append(Table(["item", "value"], rows, None, None, numeric_from=9))
    versions = r.get("versions")
    vrows = []
    if isinstance(versions, dict):
        vrows = [[str(k), str(v)] for k, v in versions.items()]
    import matplotlib

    try:
        from importlib.metadata import version

        pv = version("pencilcal")
    except Exception:  # noqa: BLE001 - a source tree without installing
        pv = "unknown"
    vrows += [["report: pencilcal", pv], ["report: python", platform.python_version()],
              ["report: numpy", np.__version__], ["report: matplotlib", matplotlib.__version__]]
    sec.blocks.append(Table(["software", "version"], vrows, None,
                            "Versions of the validation run, then those that drew this report.", numeric_from=9))
    hashes = r.get("inputs_sha256")
    if isinstance(hashes, dict) and hashes:
        sec.blocks.append(Details(f"Input files and their SHA-256 ({len(hashes)})",
                                  [Table(["file", "SHA-256"],
                                         [[str(k), Cell(str(v), "mono")] for k, v in hashes.items()],
                                         None, None, numeric_from=9)]))
    else:
        sec.blocks.append(Para("The validation file lists no input hashes.", "note"))
    return sec


# ----------------------------------------------------------------------------------------
# the report


def _header(data, title):
    frames = data["frames"]
    n = len(frames)
    ok = sum(1 for f in frames if f.get("ok"))
    cam = data.get("camera") or {}
    board = data.get("board") or {}
    rows = [["sequence", str(data.get("sequence", "–"))],
            ["frames", f"{n} ({ok} validated)"],
            ["reference", _ref_phrase(data)]]
    refs = _reference_counts(data)
    if refs:
        rows[-1][1] += " – " + ", ".join(f"{m}: {c} frames" for m, c in refs.most_common())
    if cam:
        fx = _g(cam, "K", 0, 0)
        rows.append(["camera", f"{cam.get('model', '?')} {cam.get('width', '?')}x{cam.get('height', '?')}, "
                               f"fx {num(fx)} px" + (f" ({data['camera_file']})" if data.get("camera_file") else "")])
    if board:
        rows.append(["board", f"{board.get('type', '?')} {board.get('squares')} squares of {num(board.get('square'))}"
                              + (f", markers {num(board.get('marker'))}, {board.get('dictionary')}"
                                 + (", legacy layout" if board.get("legacy") else "")
                                 if board.get("type") == "charuco" else "")])
    rows.append(["pencil", _pencil_phrase(data)])
    rows.append(["orient models", ", ".join(data.get("models") or []) or "–"])
    rows.append(["PnP methods", ", ".join(data.get("methods") or []) or "–"])
    rows.append(["validated on", str(_g(data, "reproducibility", "created", default="–"))])
    return rows


def build_report(data, *, title=None, samples=4, sensitivity=None, source=None, report_command=None,
                 sensitivity_path=None):
    """The report's content (Report) from a validation dict (`load_validation`).

    title: page title (default from the sequence); samples: overlay frames; sensitivity:
    a sensitivity.json dict or None; source: the validation file's path (hashed in the
    reproducibility block); report_command: the command line that made the report.
    """
    check_validation(data, str(source) if source is not None else "validation data")
    seq = str(data.get("sequence") or (Path(source).stem if source else "validation"))
    title = title or f"Validation report: {seq}"
    created = _g(data, "reproducibility", "created", default="unknown date")
    subtitle = (f"{len(data['frames'])} frames against the {_ref_phrase(data)}; validated {created}; report drawn "
                f"{_dt.datetime.now().astimezone().strftime('%Y-%m-%d %H:%M %Z').strip()}")
    sections = []
    text, notes = verdict(data)
    s1 = Section("verdict", "1. What was validated, and the verdict",
                 [Table(["", ""], _header(data, title), None, None, numeric_from=9), Para(text, "lead")])
    if notes:
        s1.blocks.append(Para("For the reviewer:", "text"))
        s1.blocks.append(Bullets(notes))
    sections.append(s1)
    sections.append(Section("summary", "2. Summary of every method", [summary_table(data)]))
    s3 = Section("plots", "3. Error against tilt, and the calibration of the sigmas")
    for p in (fig_error_vs_tilt(data), fig_sigma_calibration(data)):
        if p is not None:
            s3.blocks.append(p)
    if not s3.blocks:
        s3.blocks.append(Para("No method produced an error against the reference: nothing to plot.", "note"))
    sections.append(s3)
    t_info, t_norm, t_tilt = _frame_tables(data)
    sections.append(Section("frames", "4. Per frame", [
        Details(f"Frames, reference and flags ({len(data['frames'])} frames)", [t_info],
                open=len(data["frames"]) <= 15),
        Details("Normal error per method", [t_norm]),
        Details("Tilt error per method", [t_tilt])]))
    s5 = Section("overlays", "5. Sample frames")
    if samples > 0:
        cam, cam_err = _camera(data)
        if cam_err:
            s5.blocks.append(Para(f"The camera in the file cannot be used ({cam_err}); overlays show the image "
                                  f"measurements only.", "note"))
        field_r = _field_radius(cam) if cam is not None else 10.0
        picks = _sample_frames(data, samples)
        if picks:
            xs, _ = _x_of(data)
            s5.blocks.append(Para(f"{len(picks)} frames spread over the reference tilt: "
                                  + ", ".join(f"{data['frames'][i].get('image')} ({num(xs.get(i))} deg)" for i in picks)
                                  + "."))
        for i in picks:
            png, cap = fig_overlay(data, i, cam, field_r, [Path(source).parent] if source is not None else [])
            s5.blocks.append(Plot(png, cap, f"overlay {data['frames'][i].get('image')}") if png else Para(cap, "note"))
        if not picks:
            s5.blocks.append(Para("No frame to show.", "note"))
    else:
        s5.blocks.append(Para("No sample frames asked for (--samples 0).", "note"))
    sections.append(s5)
    sections.append(_calibration_section(data))
    sections.append(_sfm_section(data))
    sections.append(_sensitivity_section(data, sensitivity))
    sections.append(_repro_section(data, source, report_command, sensitivity_path))
    return Report(title, subtitle, sections)


# ----------------------------------------------------------------------------------------
# HTML

_CSS = """
body{font-family:-apple-system,"Segoe UI",Roboto,"DejaVu Sans",Arial,sans-serif;margin:0;color:#1b1f23;
background:#fff;line-height:1.45;font-size:14px}
main{max-width:1400px;margin:0 auto;padding:18px 28px 60px}
h1{font-size:24px;margin:8px 0 2px} .subtitle{color:#586069;margin:0 0 14px}
h2{font-size:19px;border-bottom:2px solid #d0d7de;padding-bottom:3px;margin-top:34px}
nav{background:#f6f8fa;border:1px solid #d0d7de;border-radius:6px;padding:6px 12px;font-size:13px}
nav a{margin-right:14px;color:#0550ae;text-decoration:none}
p.lead{background:#f1f8ff;border-left:4px solid #0969da;padding:10px 14px;font-size:15px}
p.note{color:#6e4c00;background:#fff8e1;border-left:4px solid #d4a72c;padding:6px 12px}
p.caption{color:#57606a;font-size:12.5px;margin-top:4px}
table{border-collapse:collapse;margin:8px 0 4px;font-size:12.5px}
th,td{border:1px solid #d0d7de;padding:3px 6px;vertical-align:top}
th{background:#f6f8fa;font-weight:600;text-align:center}
td.num{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
tr:nth-child(even) td{background:#fbfcfd}
td.good{background:#dafbe1 !important} td.warn{background:#fff4cc !important} td.bad{background:#ffd8d3 !important}
td.muted{color:#6e7781} tr.bad td:nth-child(-n+3){color:#a40e26;font-weight:600}
td.mono{font-family:"DejaVu Sans Mono",Menlo,Consolas,monospace;font-size:11.5px}
.scroll{overflow-x:auto}
figure{margin:14px 0 22px} figure img{max-width:100%;height:auto;border:1px solid #e1e4e8}
figcaption{color:#57606a;font-size:12.5px;margin-top:4px}
details{margin:8px 0;border:1px solid #d0d7de;border-radius:6px;padding:4px 10px}
summary{cursor:pointer;font-weight:600;padding:3px 0}
ul{margin-top:2px}
@media print{details{border:none} nav{display:none}}
"""


def _cell_html(c, numeric):
    if not isinstance(c, Cell):
        c = Cell(str(c))
    cls = " ".join(x for x in (("num" if numeric else ""), c.cls or "") if x)
    attr = f' class="{cls}"' if cls else ""
    if c.title:
        attr += f' title="{html.escape(c.title)}"'
    return f"<td{attr}>{html.escape(c.text)}</td>"


def _table_html(t):
    out = ['<div class="scroll"><table>']
    if t.groups:
        out.append("<tr>" + "".join(f'<th colspan="{span}">{html.escape(g)}</th>' for g, span in t.groups) + "</tr>")
    if any(t.columns):
        out.append("<tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in t.columns) + "</tr>")
    for i, row in enumerate(t.rows):
        cls = t.row_cls[i] if t.row_cls and i < len(t.rows) else None
        out.append(f'<tr class="{cls}">' if cls else "<tr>")
        out.append("".join(_cell_html(c, t.numeric(j)) for j, c in enumerate(row)) + "</tr>")
    out.append("</table></div>")
    if t.caption:
        out.append(f'<p class="caption">{html.escape(t.caption)}</p>')
    return "\n".join(out)


def _block_html(b):
    if isinstance(b, Para):
        cls = {"lead": "lead", "note": "note", "caption": "caption"}.get(b.kind)
        attr = f' class="{cls}"' if cls else ""
        return f"<p{attr}>{html.escape(b.text)}</p>"
    if isinstance(b, Bullets):
        return "<ul>" + "".join(f"<li>{html.escape(str(i))}</li>" for i in b.items) + "</ul>"
    if isinstance(b, Table):
        return _table_html(b)
    if isinstance(b, Plot):
        data = base64.b64encode(b.png).decode("ascii")
        return (f'<figure><img src="data:image/png;base64,{data}" alt="{html.escape(b.alt)}">'
                f"<figcaption>{html.escape(b.caption)}</figcaption></figure>")
    if isinstance(b, Details):
        return (f"<details{' open' if b.open else ''}><summary>{html.escape(b.summary)}</summary>"
                + "\n".join(_block_html(x) for x in b.blocks) + "</details>")
    if isinstance(b, Pre):
        return f"<pre>{html.escape(b.text)}</pre>"
    raise TypeError(f"unknown block {type(b).__name__}")


def render_html(report):
    """The report as one self-contained HTML page (str)."""
    nav = " ".join(f'<a href="#{s.id}">{html.escape(s.title)}</a>' for s in report.sections)
    body = [f"<h1>{html.escape(report.title)}</h1>", f'<p class="subtitle">{html.escape(report.subtitle)}</p>',
            f"<nav>{nav}</nav>"]
    for s in report.sections:
        body.append(f'<section id="{s.id}"><h2>{html.escape(s.title)}</h2>')
        body += [_block_html(b) for b in s.blocks]
        body.append("</section>")
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            "<meta name=\"generator\" content=\"pencilcal report\">"
            f"<title>{html.escape(report.title)}</title><style>{_CSS}</style></head>\n<body><main>\n"
            + "\n".join(body) + "\n</main></body></html>\n")


# ----------------------------------------------------------------------------------------
# PDF


class _Pdf:
    """Flowing A4 pages of text, monospace tables and raster figures on matplotlib's PdfPages."""

    W, H, M = 8.27, 11.69, 0.6

    def __init__(self, pdf):
        self.pdf = pdf
        self.fig = None
        self.y = 0.0
        self.pages = 0

    def flush(self):
        if self.fig is not None:
            self.fig.text(0.5, 0.25 / self.H, str(self.pages), ha="center", fontsize=7, color="0.5")
            self.pdf.savefig(self.fig)
            self.fig = None

    def _new(self):
        from matplotlib.figure import Figure

        self.flush()
        self.fig = Figure(figsize=(self.W, self.H))
        self.y = self.H - self.M
        self.pages += 1

    def _need(self, h):
        if self.fig is None or self.y - h < self.M:
            self._new()

    def line(self, s, size=9.0, weight="normal", family="sans-serif", color="black", indent=0.0):
        h = size * 1.4 / 72
        self._need(h)
        self.fig.text((self.M + indent) / self.W, self.y / self.H, s, fontsize=size, weight=weight, family=family,
                      color=color, va="top", ha="left")
        self.y -= h

    def space(self, h=0.08):
        self.y -= h

    def para(self, text, size=9.0, color="black", indent=0.0, weight="normal"):
        width = int((self.W - 2 * self.M - indent) * 72 / (size * 0.56))
        for ln in textwrap.wrap(text, width) or [""]:
            self.line(ln, size, color=color, indent=indent, weight=weight)
        self.space()

    def heading(self, text, size=13.0):
        self._need(size * 3 / 72 + 2.0)  # never alone at the foot of a page
        self.space(0.12)
        self.line(text, size, weight="bold")
        self.space(0.04)

    def table(self, t, size=6.5):
        width = int((self.W - 2 * self.M) * 72 / (size * 0.602))

        def txt(c):
            return (c.text if isinstance(c, Cell) else str(c)).replace("\n", " ")

        ncol = len(t.columns)
        heads = list(t.columns)
        group_of = [""] * ncol
        group_end = list(range(1, ncol + 1))
        if t.groups:
            j = 0
            for g, span in t.groups:
                if g and j < ncol:
                    group_of[j] = g
                    group_end[j] = j + span
                j += span
        body = [[txt(c) for c in r] + [""] * (ncol - len(r)) for r in t.rows]
        widths = [min(max([len(heads[j])] + [len(r[j]) for r in body]), 40) for j in range(ncol)]
        keys = list(range(min(2, max(t.numeric_from, 1), ncol)))
        # split wide tables into column chunks that repeat the key columns
        chunks, cur = [], list(keys)
        used = sum(widths[j] + 2 for j in cur)
        for j in range(len(keys), ncol):
            if used + widths[j] + 2 > width and len(cur) > len(keys):
                chunks.append(cur)
                cur = list(keys)
                used = sum(widths[k] + 2 for k in cur)
            cur.append(j)
            used += widths[j] + 2
        chunks.append(cur)
        for cols in chunks:
            w = {j: widths[j] for j in cols}
            last = cols[-1]
            # the last column takes what is left of the line, and wraps
            w[last] = max(widths[last], min(width - sum(w[j] + 2 for j in cols[:-1]),
                                            max(len(r[last]) for r in body) if body else 0, 200))

            def cell(v, j):
                if len(v) > w[j] and j != last:
                    v = v[:w[j] - 1] + "~"
                return v.rjust(w[j]) if t.numeric(j) else v.ljust(w[j])

            if any(group_of[j] for j in cols):
                line, pos = "", 0
                for j in cols:
                    if group_of[j]:
                        room = sum(w[k] + 2 for k in cols if j <= k < group_end[j]) - 2
                        line = line.ljust(pos) + group_of[j][:room].center(room)
                    pos += w[j] + 2
                self.line(line[:width], size, family="monospace", color="0.3")
            self.line("  ".join(cell(heads[j], j) for j in cols), size, family="monospace", weight="bold")
            for r, cls in zip(body, t.row_cls or [None] * len(body)):
                wrapped = textwrap.wrap(r[last], max(w[last], 10)) or [""] if len(r[last]) > w[last] else [r[last]]
                color = "#b00000" if cls == "bad" else "black"
                self.line("  ".join(cell(r[j], j) if j != last else cell(wrapped[0], j) for j in cols), size,
                          family="monospace", color=color)
                pad = sum(w[j] + 2 for j in cols[:-1])
                for cont in wrapped[1:]:
                    self.line(" " * pad + cont, size, family="monospace", color=color)
            self.space(0.06)
        if t.caption:
            self.para(t.caption, 7.5, color="0.35")

    def image(self, png, caption):
        from matplotlib.image import imread

        img = imread(io.BytesIO(png), format="png")
        w = self.W - 2 * self.M
        h = w * img.shape[0] / img.shape[1]
        cap_h = (len(textwrap.wrap(caption, int(w * 72 / 3.75))) + 1) * 7.5 * 1.4 / 72
        if h + cap_h > self.H - 2 * self.M:
            h = self.H - 2 * self.M - cap_h
            w = h * img.shape[1] / img.shape[0]
        self._need(h + cap_h)
        ax = self.fig.add_axes([self.M / self.W, (self.y - h) / self.H, w / self.W, h / self.H])
        ax.imshow(img, interpolation="antialiased")
        ax.set_axis_off()
        self.y -= h + 0.05
        self.para(caption, 7.5, color="0.35")

    def block(self, b):
        if isinstance(b, Para):
            if b.kind == "lead":
                self.para(b.text, 9.5, color="#0b3d91")
            elif b.kind == "note":
                self.para(b.text, 8.5, color="#7a5200")
            elif b.kind == "caption":
                self.para(b.text, 7.5, color="0.35")
            else:
                self.para(b.text, 9)
        elif isinstance(b, Bullets):
            for it in b.items:
                self.para("- " + str(it), 8.5, indent=0.15)
        elif isinstance(b, Table):
            self.table(b)
        elif isinstance(b, Plot):
            self.image(b.png, b.caption)
        elif isinstance(b, Details):
            self.line(b.summary, 9.5, weight="bold")
            for x in b.blocks:
                self.block(x)
        elif isinstance(b, Pre):
            for ln in b.text.splitlines():
                self.line(ln, 7, family="monospace")


def _paginate(report, sink):
    """Lay the report out on A4 pages, handing each page (a Figure) to sink.savefig."""
    doc = _Pdf(sink)
    doc._new()
    doc.para(report.title, 15, weight="bold")
    doc.para(report.subtitle, 8.5, color="0.35")
    for s in report.sections:
        if s.id in ("frames", "overlays", "calibration", "reproducibility"):
            doc._new()
        doc.heading(s.title)
        for b in s.blocks:
            doc.block(b)
    doc.flush()
    return doc.pages


def render_pdf(report, path):
    """Write the report as a multi-page A4 PDF to `path` (not atomic; see write_report).
    Returns the number of pages."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.backends.backend_pdf import PdfPages

    with PdfPages(path, metadata={"Title": report.title, "Creator": "pencilcal report"}) as pdf:
        return _paginate(report, pdf)


# ----------------------------------------------------------------------------------------


def write_report(path, data, *, force=False, title=None, samples=4, sensitivity=None, source=None,
                 report_command=None, sensitivity_path=None):
    """Build the report and write it to `path` (.html/.htm or .pdf), atomically, never
    over an existing file unless `force`. Returns the Report."""
    p = Path(path)
    fmt = FORMATS.get(p.suffix.lower())
    if fmt is None:
        raise InputError(f"{p}: unknown report format {p.suffix!r}; expected .html or .pdf")
    check_writable(p, force)  # before the work
    try:
        report = build_report(data, title=title, samples=samples, sensitivity=sensitivity, source=source,
                              report_command=report_command, sensitivity_path=sensitivity_path)
    except (KeyError, TypeError, ValueError, IndexError, AttributeError) as e:
        if isinstance(e, PencilcalError):
            raise
        where = str(source) if source is not None else "validation data"
        raise InputError(f"{where}: malformed validation file ({type(e).__name__}: {e})") from None
    if fmt == "html":
        atomic_write(p, render_html(report), force)
    else:
        with atomic_path(p, force) as tmp:
            render_pdf(report, tmp)
    return report

"""The report's sections on what else the file holds: calibration quality, the
reconstruction (SfM), a `pencilcal sensitivity` plan next to what was measured, and the
reproducibility block (versions, commands, input hashes). Each returns a `Section`; a
part the file lacks becomes a note saying how to add it.

Example
-------
>>> sec = sfm_section({"frames": [], "summary": {}})
>>> sec.title, sec.blocks[0].kind
('7. Reconstruction (SfM)', 'note')
>>> _spacing([0, 20, 40, 60]), _spacing([0, 10, 40])
('20.0', 'irregular, 10.0-30.0')
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import math
import platform
import shlex
from collections import Counter
from pathlib import Path

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import load_structured

from .document import Cell, Details, Para, Section, Table
from .facts import calibration_same_images, method_errors, method_label, primary_method, reference_phrase
from .figures import MAX_WIDTH_IN, legend_below, new_figure, plot_of
from .format import finite, lookup, num

__all__ = ["load_sensitivity", "calibration_section", "sfm_section", "sensitivity_section", "reproducibility_section"]


def load_sensitivity(path):
    """Read a sensitivity.json of `pencilcal sensitivity`; InputError naming the file."""
    p = Path(path)
    d = load_structured(p, "sensitivity file")
    if not isinstance(d, dict) or not isinstance(d.get("maps"), dict) or not isinstance(d.get("setup"), dict):
        raise InputError(f"{p}: not a sensitivity file (expected 'setup' and 'maps', as `pencilcal sensitivity` "
                         f"writes)")
    return d


def _sha256(path):
    """The SHA-256 of a file's bytes, as hex."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


# ----------------------------------------------------------------------------------------
# calibration


def _view_table_and_fig(cal):
    """[Plot] of the per-view reprojection RMS [px] of the calibration, or [] without views."""
    views = cal.get("views") if isinstance(cal.get("views"), list) else None
    blocks = []
    if views:
        names = [str(v.get("image", i)) for i, v in enumerate(views)]
        rms = [finite(v.get("rms_px")) for v in views]
        used = [bool(v.get("used")) for v in views]
        # a view rejected as an outlier keeps its RMS in the rejected list
        rejected_rms = {str(r.get("image")): finite(r.get("rms_px")) for r in cal.get("rejected") or []
                        if isinstance(r, dict) and r.get("corner") is None and finite(r.get("rms_px")) is not None}
        rms = [r if r is not None else rejected_rms.get(nm) for r, nm in zip(rms, names)]
        known = [r for r in rms if r is not None]
        if len(known) == 1:  # one bar is no plot
            blocks.append(Para(f"One view with a reprojection error: {num(known[0])} px RMS.", "note"))
        elif known:
            blocks.append(_fig_views(names, rms, used, finite(cal.get("rms_px"))))
    return blocks


def _fig_views(names, rms, used, total):
    """The per-view RMS [px] as bars (Plot); rms: per view, None where it had no board."""
    fig = new_figure(figsize=(MAX_WIDTH_IN, 3.8))
    ax = fig.subplots()
    x = np.arange(len(names))
    ax.bar(x, [r or 0 for r in rms], color=["C0" if u else "C3" for u in used], width=0.8)
    for i, r in enumerate(rms):
        if r is None:
            ax.plot(i, 0, "x", color="0.4", ms=4)
    if total is not None:
        ax.axhline(total, color="k", ls="--", lw=1, label=f"overall RMS {num(total)} px")
        legend_below(fig, *ax.get_legend_handles_labels())
    step = max(1, -(-len(names) // 45))  # at most 45 names, each legible
    ax.set_xticks(x[::step], names[::step], rotation=90, fontsize=8)
    ax.set_xlabel("view" + (f" (every {step}th named)" if step > 1 else ""))
    ax.set_ylabel("reprojection RMS [px]")
    ax.set_title("Per-view reprojection error (blue: used; red: rejected; x: no board)", fontsize=10)
    ax.set_xlim(-0.7, len(x) - 0.3)
    return plot_of(fig, "Per-view RMS reprojection error of the calibration; views without a usable board "
                                "are marked with a cross at zero.", "Per-view errors")


# the names of the distortion coefficients of each camera model, in the file's order
_DIST_NAMES = {"opencv": ["k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "taux", "tauy"],
               "fisheye": ["k1", "k2", "k3", "k4"], "pinhole": []}


def calibration_section(data):
    """Section 6: the calibration's statistics, the validated camera's intrinsics with their
    sigmas, the per-view errors and the rejected views and corners."""
    cal = data.get("calibration")
    sec = Section("calibration", "6. Calibration quality")
    if not isinstance(cal, dict) or not cal:
        sec.blocks.append(Para("Not in this file: validate was given no calibration report (--calibration) and the "
                               "camera file carries no statistics.", "note"))
        return sec
    cam = data.get("camera") or {}
    kv = []
    if finite(cal.get("rms_px")) is not None:
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
    if calibration_same_images(data):
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
            v = finite(vals.get(k))
            sv = finite(s)
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


# ----------------------------------------------------------------------------------------
# reconstruction


def sfm_section(data):
    """Section 7: the reconstruction's registration, points, reprojection error and alignment."""
    sec = Section("sfm", "7. Reconstruction (SfM)")
    sfm = data.get("sfm")
    if not isinstance(sfm, dict):
        sec.blocks.append(Para("Not in this file: run `pencilcal validate --sfm` to compare with a pycolmap "
                               "reconstruction (intrinsics held fixed) aligned to the board frame.", "note"))
        return sec
    reg = sum(1 for f in data["frames"] if lookup(f, "sfm", "registered"))
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
    s = lookup(data, "summary", "sfm")
    if isinstance(s, dict) and s.get("frames"):
        sec.blocks.append(Para(f"SfM normal error against the {reference_phrase(data)}: median "
                               f"{num(lookup(s, 'normal', 'median'))} deg, "
                               f"RMSE {num(lookup(s, 'normal', 'rmse'))} deg, "
                               f"95th percentile {num(lookup(s, 'normal', 'p95'))} deg over {s['frames']} frames."))
    return sec


# ----------------------------------------------------------------------------------------
# sensitivity plan


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


def sensitivity_section(data, sens):
    """Section 8: a sensitivity.json's answer, its set-up next to this sequence's, its
    detection thresholds, its heatmaps and its curves against the errors measured here.
    sens: the sensitivity dict (`load_sensitivity`) or None."""
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
    pencil_n = len(lookup(data, "pencil", "angles_deg", default=[]) or [])
    fx = lookup(data, "camera", "K", 0, 0)
    sig = []
    for f in data["frames"]:
        s = lookup(f, "orient", "exact", "lines", "sigma")
        if isinstance(s, list):
            sig += [v for v in (finite(x) for x in s) if v is not None]
    rows = [["spokes", str(st.get("spokes", "–")), str(pencil_n or "–")],
            ["spoke spacing [deg]", num(st.get("step_deg")), _spacing(lookup(data, "pencil", "angles_deg"))],
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
    acc = finite(st.get("accuracy_deg")) or 1.0
    sigma = finite(st.get("sigma_deg")) or 0.1
    for key, fn, size in (("tilt_offaxis", lambda fig, m: sv._heat_tilt_offaxis(fig, m, acc, sigma), (9, 5.2)),
                          ("spokes_spacing", lambda fig, m: sv._heat_spokes_spacing(fig, m), (9, 4.4)),
                          ("noise", lambda fig, m: sv._heat_noise(fig, m, acc), (7.5, 5.2))):
        if key not in maps:
            continue
        try:
            fig = new_figure(figsize=size)
            fn(fig, maps[key])
            sec.blocks.append(plot_of(fig, f"Sensitivity map {key.replace('_', ' x ')} (docs/sensitivity.md, "
                                                   f"'Reading the heatmaps').", f"sensitivity {key}"))
        except (KeyError, TypeError, ValueError, IndexError, AttributeError) as e:
            sec.blocks.append(Para(f"The {key} map could not be drawn ({type(e).__name__}: {e}).", "note"))
    m = maps.get("tilt_offaxis")
    prim = primary_method(data)
    if isinstance(m, dict) and isinstance(m.get("tilts_deg"), np.ndarray):
        try:
            sec.blocks.append(_fig_planned_vs_measured(data, m, prim))
        except (KeyError, TypeError, ValueError, IndexError) as e:
            sec.blocks.append(Para(f"The planned-versus-measured plot could not be drawn ({e}).", "note"))
    return sec


def _fig_planned_vs_measured(data, m, prim):
    """The plan's RMS normal error over tilt, one curve per off-axis angle [deg], with the
    errors of the primary method `prim` and this sequence's per-frame bound (Plot). m: the
    plan's tilt x off-axis map (arrays, `_as_arrays`)."""
    import matplotlib

    fig = new_figure(figsize=(9, 5.4))
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
        for _, fr, e in method_errors(data, prim):
            x, y = finite(fr.get("reference_tilt_deg")), finite(e.get("normal_closer_deg"))
            ray = lookup(fr, "orient", model, "ray")
            if x is None or y is None or y <= 0:
                continue
            offa = math.degrees(math.acos(max(-1.0, min(1.0, float(ray[2]))))) if isinstance(ray, list) else np.nan
            pts.append((x, y, offa))
        if pts:
            p = np.array(pts)
            sc = ax.scatter(p[:, 0], p[:, 1], c=np.where(np.isfinite(p[:, 2]), p[:, 2], np.nanmin(off)), cmap=cmap,
                            norm=norm, edgecolors="k", s=28, zorder=3,
                            label=f"measured, {method_label(prim)} (closer twin)")
            fig.colorbar(sc, ax=ax, label="vertex off axis [deg]")
        b = [(finite(f.get("reference_tilt_deg")), finite(lookup(f, "crlb", "normal_deg"))) for f in data["frames"]]
        b = sorted((x, y) for x, y in b if x is not None and y is not None and y > 0)
        if b:
            x, y = np.array(b).T
            ax.plot(x, y, "k.", ms=4, label="this sequence's bound (per frame)")
    ax.set_yscale("log")
    ax.set_xlabel("tilt against the vertex ray [deg]")
    ax.set_ylabel("normal error [deg]")
    ax.set_title("Planned against measured")
    ax.grid(True, which="both", alpha=0.25)
    legend_below(fig, *ax.get_legend_handles_labels(), ncol=2)
    caption = ("The plan's RMS normal error over tilt (one curve per off-axis angle of the plan) with the errors "
               "measured here (one point per frame, coloured by how far off axis its vertex was) and this sequence's "
               "own per-frame bound. Single frames scatter about an RMS curve; the summary table has the RMS.")
    return plot_of(fig, caption, "planned vs measured")


# ----------------------------------------------------------------------------------------
# reproducibility


def reproducibility_section(data, source, report_command, sens_path):
    """Section 9: the commands, files and their SHA-256, and the software versions of the
    validation run and of this report. source, sens_path: the files read (or None)."""
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
    for what, path in (("validation", source), ("sensitivity", sens_path)):
        if path is not None:
            rows.append([f"{what} file", str(path)])
            try:
                rows.append([f"{what} file SHA-256", _sha256(path)])
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

"""Where the shaft detector loses each mask instrument of the masked real sources: a
diagnostic, not a test (run ``python -m tests.validation.shaft_funnel [SOURCE ...] [--out DIR]``).

Per instrument of every frame (tests/validation/masked_sources.py) the material cue's stages
are traced (the detector is run once per frame with its stages wrapped) and the first one
that loses it is named:

- ``no material cue``: the frame was judged to have no colour (`shaft.regions.material_map`)
  and only the edge cue searched it;
- ``no segment``: no straight region boundary (`shaft.regions.boundary_lines`, any level)
  runs along the mask's outline (`SEGMENT_ON_OUTLINE` of it within `OUTLINE_PX`);
- ``no band``: segments, but no band between two of them evaluated along the axis (for a
  mask with two straight stretches: whether the segments lie on one or both of them);
- ``not proposed: ...``: a band along it, but `shaft.region_bands.proposed` said no (which
  part: the material of a side, the run's length, its shaft stations);
- ``not refined``: proposed but suppressed by a better overlapping band, or past the
  refinement cap;
- ``rejected: ...``: refined, and `shaft.material_cue.judge_band` names the test it failed,
  with the band's values that test reads (its edges seen together and width [px], their
  convergence [deg], its instrument's material along it [px], the length that needs no border
  [px], the two sides' contrasts);
- ``not selected: ...``: held, and dropped by the named step of `shaft.material_cue.select`
  as another reading of a better one (or over the cap);
- ``below setting``: detected, but under the setting the leave-one-source-out protocol
  chose on the other sources;
- ``found``.

It also prints each source's found and false detections at every setting of the protocol
(`validation.shaft_protocol.SETTINGS`): how near each choice lies to the bound on false
detections of the other sources.

A band or shaft lies "along" an instrument within `ALONG_DEG` (parts `ALONG_PART_DEG`) and
its line passes within max(`ALONG_PX`, half the width) of the reference's point. The
overlays (``--out``): the mask's outline green, segments blue, the edge pairs proposed
(`shaft.edge_pairs`) cyan, evaluated bands' axes yellow, detections red (thick: kept at the chosen setting), the missed references' axes
magenta.
"""
from __future__ import annotations

import argparse
import json
from collections import Counter
from contextlib import contextmanager
from pathlib import Path

import numpy as np

OUTLINE_PX = 4.0
SEGMENT_ON_OUTLINE = 0.7
ALONG_DEG, ALONG_PART_DEG, ALONG_PX = 4.0, 10.0, 15.0


@contextmanager
def traced():
    """Wraps the material cue's stages; yields the dict they record into (per detect call)."""
    from pencilcal.toolkit.detect.shaft import detector as det
    from pencilcal.toolkit.detect.shaft import material_cue as mc

    rec = {}
    saved = {n: getattr(mc, n) for n in ("evaluate_many", "_bands", "judge_band", "pair_bands")}
    saved_sel, saved_regions = det.select, det.frame_regions

    def frame_regions(mm, work, seg_min):
        out = saved_regions(mm, work, seg_min)
        for L in out.lines:
            rec.setdefault("segments", []).extend(
                np.c_[L.p + L.lo[:, None] * L.u, L.p + L.hi[:, None] * L.u].tolist())
        return out

    def pair_bands(*a, **k):
        lines, pairs, maps = saved["pair_bands"](*a, **k)
        rec.setdefault("pairs", []).extend(
            [np.r_[lines.p[i] + lines.lo[i] * lines.u[i], lines.p[i] + lines.hi[i] * lines.u[i],
                   lines.p[j] + lines.lo[j] * lines.u[j], lines.p[j] + lines.hi[j] * lines.u[j]].tolist()
             for i, j in zip(pairs.i, pairs.j)])
        return lines, pairs, maps

    def evaluate_many(*a, **k):
        out = saved["evaluate_many"](*a, **k)
        rec.setdefault("evaluated", []).extend(e for got in out for e in got)
        return out

    def bands(*a, **k):
        out = saved["_bands"](*a, **k)
        rec["proposed"] = list(out[0])  # (bands, the inner bands' outer ones)
        return out

    def judge_band(*a, **k):
        sh, why = saved["judge_band"](*a, **k)
        rec.setdefault("judged", []).append((a[0], sh, why, _judged_values(*a)))
        return sh, why

    def select(shafts, n):
        rec["held"] = list(shafts)
        return saved_sel(shafts, n)

    for n, f in (("evaluate_many", evaluate_many), ("_bands", bands), ("judge_band", judge_band),
                 ("pair_bands", pair_bands)):
        setattr(mc, n, f)
    det.select, det.frame_regions = select, frame_regions
    try:
        yield rec
    finally:
        for n, f in saved.items():
            setattr(mc, n, f)
        det.select, det.frame_regions = saved_sel, saved_regions


def _judged_values(e, stretch, fits, camera, validity, o, K, s, corridor, long_len):
    """The values `material_cue.judge_band`'s tests read, as text (module docstring)."""
    from pencilcal.toolkit.detect.shaft.material_cue import midline_from_edges

    m = None if fits is None else midline_from_edges(K, fits[0], fits[1])
    if m is None:
        return ""
    seen = float(np.hypot(*(m.ends[1] - m.ends[0])))
    ext = (e.ext[1] - e.ext[0]) * e.step / s
    cs = ", ".join(f"{c:.0f}" for c in np.asarray(e.side_contrast, float))
    return (f"seen {seen:.0f} px, width {m.width_px:.0f}, converging {m.convergence_deg:.1f} deg, material "
            f"{ext:.0f} px, no border needed from {long_len:.0f} px, side contrasts {cs}")


def _dropped_by(band, held):
    """The step of `material_cue.select` that drops a held shaft (`MaterialShaft`) from held."""
    from pencilcal.toolkit.detect.shaft import material_cue as mc

    left = list(held)
    for name, step in (("inside a held one", mc._inside_held), ("overlapping a better one", mc._overlapping),
                       ("along a better one's axis", mc._coaxial), ("a ramp beside a better one", mc._ramps_beside),
                       ("a short extension", mc._short_extensions), ("beyond an entry", mc.beyond_entry)):
        left = step(left)
        if not any(sh is band for sh in left):
            return name
    return "over the cap"


def _line_of(P):
    """(line (3,), centre) of the TLS line through points P (N, 2)."""
    c = P.mean(0)
    _, _, vt = np.linalg.svd(P - c)
    u = vt[0]
    n = np.array([-u[1], u[0]])
    return np.r_[n, -n @ c], c


def along(line, ref):
    """Whether a line (3,) lies along a reference (`mask.MaskAxis`), loosely (module docstring)."""
    a = np.degrees(np.arccos(min(1.0, abs(float(line[:2] @ ref.line[:2])))))
    o = abs(float(line[:2] @ ref.point + line[2]))
    return a <= (ALONG_DEG if ref.kind == "shaft" else ALONG_PART_DEG) and o <= max(ALONG_PX, 0.5 * ref.width_px)


def _band_line(e, work, ends=None):
    i0, i1 = e.run if ends is None else ends
    return _line_of(work.to_ideal(e.C[i0:i1]))[0]


def _outline_dist(mask):
    import cv2

    m = mask.astype(np.uint8)
    edge = m - cv2.erode(m, np.ones((3, 3), np.uint8))
    return cv2.distanceTransform((edge == 0).astype(np.uint8), cv2.DIST_L2, 3)


def _on_outline(seg_ideal, dist):
    H, W = dist.shape
    t = np.linspace(0, 1, 25)[:, None]
    P = seg_ideal[:2] * (1 - t) + seg_ideal[2:] * t
    x, y = np.clip(np.round(P[:, 0]).astype(int), 0, W - 1), np.clip(np.round(P[:, 1]).astype(int), 0, H - 1)
    return float(np.mean(dist[y, x] <= OUTLINE_PX)) >= SEGMENT_ON_OUTLINE


def _why_not_proposed(e, min_len, ang_thr):
    from pencilcal.toolkit.detect.shaft.region_bands import FILL_SIDE

    sides = [(f <= FILL_SIDE) or (np.isfinite(a) and a > ang_thr) for f, a in zip(e.fall, e.ang)]
    if not all(sides):
        return "side of like material"
    if e.run_len < min_len:
        return "run short"
    return "few shaft stations"


def stage_of(ref, mask, rec, work, dets, kept, min_len, ang_thr):
    """The first stage that loses one instrument (module docstring)."""
    from pencilcal.validation.shaft_score import Tolerance, detection_line

    tol = Tolerance()
    a_max, o_max = tol.limits(ref)

    def hits(d):
        ln, _ = detection_line(d["midline"])
        return (np.arccos(min(1.0, abs(float(ln[:2] @ ref.line[:2])))) <= a_max
                and abs(float(ln[:2] @ ref.point + ln[2])) <= o_max)

    if any(hits(d) for d in kept):
        return "found"
    if any(hits(d) for d in dets):
        return "below setting"
    held = rec.get("held", [])
    on = [sh for sh in held if along(sh.midline.line, ref)]
    if on:
        return "not selected: " + _dropped_by(on[0], held)
    judged = [(e, why, v) for e, sh, why, v in rec.get("judged", []) if along(_band_line(e, work), ref)]
    if judged:
        return "rejected: " + (judged[0][1] or "scored off tolerance") + (f" ({judged[0][2]})" if judged[0][2] else "")
    ev = [e for e in rec.get("evaluated", []) if along(_band_line(e, work), ref)]
    if any(e in rec.get("proposed", []) for e in ev):
        return "not refined"
    if ev:
        from pencilcal.toolkit.detect.shaft.region_bands import proposed

        ok = [e for e in ev if proposed(e, min_len, ang_thr)]
        return "not refined" if ok else "not proposed: " + _why_not_proposed(ev[0], min_len, ang_thr)
    if "segments" not in rec:
        return "no material cue"
    dist = _outline_dist(mask)
    segs = [work.to_ideal(np.asarray(s).reshape(2, 2)).reshape(4) for s in rec.get("segments", [])
            + [q for pr in rec.get("pairs", []) for q in np.asarray(pr).reshape(2, 4)]]
    on = [s for s in segs if _on_outline(s, dist)]
    if not on:
        return "no segment"
    if ref.edges is None:
        return "no band"
    n = sum(any(_on_stretch(s, E) for s in on) for E in ref.edges)
    return "no band (segments on " + ("neither", "one", "both")[n] + " of its straight stretches)"


def _on_stretch(seg, E):
    """Whether a segment (4,) lies along a straight outline stretch E (4,): within
    `ALONG_DEG` of it, its middle within `OUTLINE_PX` of its line and alongside it."""
    d = (E[2:] - E[:2]) / np.linalg.norm(E[2:] - E[:2])
    u = (seg[2:] - seg[:2]) / max(np.linalg.norm(seg[2:] - seg[:2]), 1e-9)
    c = 0.5 * (seg[:2] + seg[2:]) - E[:2]
    return (abs(float(d[0] * u[1] - d[1] * u[0])) <= np.sin(np.radians(ALONG_DEG))
            and abs(float(d[0] * c[1] - d[1] * c[0])) <= OUTLINE_PX
            and 0.0 <= float(c @ d) <= float(np.linalg.norm(E[2:] - E[:2])))


def _cache_path(out, name):
    """Where one source's trace is kept between runs: beside the overlays in OUT."""
    return Path(out) / f"funnel-{name}.json"


def run_source(name, out=None):
    """Trace one source: its per-frame (detections, per-instrument stage) and its diagonal."""
    import cv2

    from pencilcal.toolkit.detect.shaft.detector import _WORK_PX, detect_shafts
    from pencilcal.toolkit.detect.shaft.regions import scene_angle
    from pencilcal.toolkit.detect.shaft.work import Validity, WorkFrame
    from pencilcal.validation.shaft_protocol import view_diagonal
    from tests.validation.masked_sources import load_source

    frames, region = load_source(name)
    shape = frames[0][1].shape[:2]
    rows = []
    for path, img, refs, insts in frames:
        with traced() as rec:
            dets = [s.to_dict() for s in detect_shafts(img, valid_region=region)]
        work = WorkFrame(img, None, Validity(region, img.shape[:2]), _WORK_PX)
        H, W = img.shape[:2]
        s = work.mean_scale
        min_len = 3.0 * 0.02 * max(H, W) * s
        vin = work.valid & (work.dist > 1.0)
        ang_thr = 2.0 * scene_angle(work.bgr, vin, 0.5 * 0.02 * max(H, W) * s)
        rows.append({"frame": path.name, "detections": dets,
                     "trace": {"segments": len(rec.get("segments", [])), "evaluated": len(rec.get("evaluated", [])),
                               "proposed": len(rec.get("proposed", [])),
                               "judged": [why for _, _, why, _ in rec.get("judged", [])]},
                     "_rec": rec, "_work": work, "_refs": refs, "_insts": insts, "_img": img,
                     "_min_len": min_len, "_ang_thr": ang_thr})
    return rows, view_diagonal(shape, region.mask(shape))


def _overlay(row, kept, stages, path):
    import cv2

    img = row["_img"].copy()
    work = row["_work"]
    for m in row["_insts"]:
        cs, _ = cv2.findContours(m.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(img, cs, -1, (0, 255, 0), 1)
    for sg in row["_rec"].get("segments", []):
        q = work.to_ideal(np.asarray(sg).reshape(2, 2))
        cv2.line(img, tuple(map(int, q[0])), tuple(map(int, q[1])), (255, 120, 0), 1)
    for pr in row["_rec"].get("pairs", []):
        for sg in np.asarray(pr).reshape(2, 4):
            q = work.to_ideal(sg.reshape(2, 2))
            cv2.line(img, tuple(map(int, q[0])), tuple(map(int, q[1])), (255, 255, 0), 1)
    for e in row["_rec"].get("evaluated", []):
        q = work.to_ideal(e.C[[e.run[0], e.run[1] - 1]])
        cv2.line(img, tuple(map(int, q[0])), tuple(map(int, q[1])), (0, 220, 255), 1)
    for d in row["detections"]:
        m = np.asarray(d["midline"]).astype(int)
        cv2.line(img, (m[0], m[1]), (m[2], m[3]), (0, 0, 255), 3 if d in kept else 1)
        for e in np.asarray(d["edges"]).astype(int):
            cv2.line(img, (e[0], e[1]), (e[2], e[3]), (0, 0, 160), 1)
    for ref, st in zip(row["_refs"], stages):
        if st != "found":
            sg = ref.segment().astype(int)
            cv2.line(img, (sg[0], sg[1]), (sg[2], sg[3]), (255, 0, 255), 2)
            cv2.putText(img, st[:28], (int(ref.point[0]), int(ref.point[1])), cv2.FONT_HERSHEY_SIMPLEX,
                        0.5 if img.shape[1] < 1000 else 1.0, (255, 0, 255), 1 if img.shape[1] < 1000 else 2)
    scale = min(1.0, 960.0 / img.shape[1])
    cv2.imwrite(str(path), cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA))


def main(argv=None):
    from pencilcal.validation.shaft_protocol import filtered, leave_one_source_out
    from tests.validation.masked_sources import SOURCES

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sources", nargs="*", default=list(SOURCES))
    ap.add_argument("--out", default="shaft-funnel", help="folder of the overlays and the traces kept between runs")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    traced_rows, diag = {}, {}
    for name in SOURCES:
        cached = _cache_path(out, name)
        if name in a.sources or not cached.exists():
            rows, diag[name] = run_source(name)
            traced_rows[name] = rows
            cached.write_text(json.dumps({"diagonal": diag[name], "frames": [
                {"frame": r["frame"], "detections": r["detections"], "trace": r["trace"]} for r in rows]}))
        else:
            diag[name] = json.loads(cached.read_text())["diagonal"]
    frames = {}
    for name in SOURCES:
        c = json.loads(_cache_path(out, name).read_text())
        from tests.validation.masked_sources import load_source

        refs = traced_rows[name] if name in traced_rows else None
        if refs is None:
            fr, _ = load_source(name)
            frames[name] = [(f[2], r["detections"]) for f, r in zip(fr, c["frames"])]
        else:
            frames[name] = [(r["_refs"], r["detections"]) for r in refs]
    table = {r["source"]: r for r in leave_one_source_out(frames, diag)}
    # found / false of every source at every setting: how near the choice is to its bound
    from pencilcal.validation.shaft_protocol import SETTINGS
    from pencilcal.validation.shaft_score import score_frame, summarize

    for name, fr in frames.items():
        cells = []
        for st in SETTINGS:
            S = summarize([score_frame(filtered(d, st, diag[name]), r) for r, d in fr])
            cells.append(f"{st:g}: {S['found']}/{S['instruments']} ({S['false']} false)")
        print(f"{name} by setting: " + ", ".join(cells))
    for name, rows in traced_rows.items():
        setting = table[name]["setting"]
        count = Counter()
        for row in rows:
            kept = filtered(row["detections"], setting, diag[name])
            stages = [stage_of(ref, m, row["_rec"], row["_work"], row["detections"], kept, row["_min_len"],
                               row["_ang_thr"]) for ref, m in zip(row["_refs"], row["_insts"])]
            count.update(stages)
            print(f"{name} {row['frame']}: " + "; ".join(f"{r.kind} w{r.width_px:.0f}: {s}"
                                                        for r, s in zip(row["_refs"], stages)))
            _overlay(row, kept, stages, out / f"{name}-{Path(row['frame']).stem}.png")
        t = table[name]
        print(f"== {name}: setting {setting}, found {t['found']}/{t['instruments']}, "
              f"false/frame {t['false_per_frame']:.2f}; " + ", ".join(f"{k} {v}" for k, v in count.most_common()))


if __name__ == "__main__":
    main()

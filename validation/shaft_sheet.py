"""The contact sheet of a shaft score: every frame with its instruments and detections drawn,
in one self-contained HTML page (`pencilcal score --sheet`).

Per frame: each instrument's mask outline (green) and its reference axis (dark green), each
detection's midline: blue where it found an instrument, red where it is false, grey where it
lies on an instrument too small to score; its caption says found / missed / false. The page
opens with the verdict line (found of how many, false per frame, the errors) and the table of
frames.

Example
-------
>>> import numpy as np
>>> from pencilcal.validation.shaft_score import score_frame
>>> img = np.zeros((60, 80, 3), np.uint8)
>>> fs = score_frame([], [])
>>> html = contact_sheet([("a.png", overlay(img, [], [], [], fs), fs)], {"found": 0, "instruments": 0,
...     "recall": None, "false": 0, "false_per_frame": 0.0, "frames": 1, "angle_err_deg_median": None,
...     "angle_err_deg_p90": None, "offset_err_px_median": None, "offset_err_px_p90": None})
>>> html.startswith("<!DOCTYPE html>"), "a.png" in html
(True, True)
"""
from __future__ import annotations

import base64
import html as _html

import numpy as np

__all__ = ["overlay", "contact_sheet", "verdict_line", "SHEET_WIDTH_PX"]

#: Width of each frame on the sheet [px].
SHEET_WIDTH_PX = 600


def overlay(image, masks, references, detections, frame_score):
    """The frame (BGR) with its instruments and detections drawn (module docstring), reduced to
    `SHEET_WIDTH_PX` wide. masks: one (H, W) bool per reference (or [])."""
    import cv2

    img = np.asarray(image)
    img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img[..., :3].copy()
    s = SHEET_WIDTH_PX / img.shape[1]
    out = cv2.resize(img, (SHEET_WIDTH_PX, max(1, int(round(img.shape[0] * s)))), interpolation=cv2.INTER_AREA)

    def pt(p):
        return int(round((p[0] + 0.5) * s - 0.5)), int(round((p[1] + 0.5) * s - 0.5))

    for m in masks:
        small = cv2.resize(np.asarray(m, np.uint8), (out.shape[1], out.shape[0]), interpolation=cv2.INTER_NEAREST)
        cs, _ = cv2.findContours(small, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(out, cs, -1, (0, 220, 0), 1)
    for r in references:
        a = r.segment()
        cv2.line(out, pt(a[:2]), pt(a[2:]), (0, 120, 0), 1, cv2.LINE_AA)
    found = {m[0] for m in frame_score.matches}
    ignored = set(frame_score.ignored_dets)
    for k, d in enumerate(detections):
        colour = (255, 120, 0) if k in found else ((160, 160, 160) if k in ignored else (0, 0, 255))
        m = d["midline"]
        cv2.line(out, pt(m[:2]), pt(m[2:]), colour, 2, cv2.LINE_AA)
    return out


def verdict_line(summary):
    """One line: found of how many, false per frame, the found ones' median errors."""
    if not summary["instruments"]:
        head = "no instrument in the masks"
    else:
        head = f"found {summary['found']} of {summary['instruments']} instruments ({100 * summary['recall']:.0f} %)"
    line = f"{head}, {summary['false_per_frame']:.2f} false per frame over {summary['frames']} frames"
    if summary["angle_err_deg_median"] is not None:
        line += (f"; median error {summary['angle_err_deg_median']:.2f} deg, "
                 f"{summary['offset_err_px_median']:.1f} px")
    return line


def _png(img):
    import cv2

    ok, buf = cv2.imencode(".png", img)
    return base64.b64encode(buf.tobytes()).decode("ascii")


def contact_sheet(items, summary, title="Shafts scored against instrument masks"):
    """The page (str): items a list of (frame name, overlay BGR, FrameScore); summary:
    `shaft_score.summarize` of them."""
    esc = _html.escape
    rows = "".join(f"<tr><td>{esc(str(n))}</td><td>{f.references}</td><td>{f.found}</td><td>{f.missed}</td>"
                   f"<td>{f.false}</td></tr>" for n, _, f in items)
    figs = "".join(f'<figure><img src="data:image/png;base64,{_png(img)}" alt="{esc(str(n))}" width="{img.shape[1]}">'
                   f"<figcaption>{esc(str(n))}: {f.found} found, {f.missed} missed, {f.false} false</figcaption>"
                   "</figure>" for n, img, f in items)
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{esc(title)}</title><style>"
            "body{font-family:sans-serif;margin:16px;max-width:1340px}h1{font-size:20px}"
            ".verdict{font-size:17px;font-weight:bold;margin:8px 0 12px}"
            "table{border-collapse:collapse;margin-bottom:16px}td,th{border:1px solid #ccc;padding:2px 8px}"
            "figure{display:inline-block;margin:4px;vertical-align:top}figcaption{font-size:13px}"
            ".key span{margin-right:14px}</style></head><body>"
            f"<h1>{esc(title)}</h1><p class='verdict'>{esc(verdict_line(summary))}</p>"
            "<p class='key'><span style='color:#00b000'>mask outline</span><span style='color:#007800'>reference "
            "axis</span><span style='color:#0078ff'>found</span><span style='color:#f00'>false</span>"
            "<span style='color:#888'>on an instrument too small to score</span></p>"
            "<table><tr><th>frame</th><th>instruments</th><th>found</th><th>missed</th><th>false</th></tr>"
            f"{rows}</table>{figs}</body></html>")

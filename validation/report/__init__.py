"""Validation report: one self-contained HTML page (or a PDF) from a validation.json.

`pencilcal validate` writes what was measured; this module turns it into what a reviewer
reads, in this order:

0. the answer (`headline`): one verdict line (what was measured, the headline figure with
   its unit and sigma, PASS/FAIL/CHECK against its tolerance) and the numbers that matter;
   a pivot's report leads with the fulcrum, and its fulcrum section comes second;
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

Modules: `document` (the blocks), `format` (values and numbers for people), `facts`
(methods, errors, phrases the parts share), `headline` (the answer first), `verdict`, `tables`, `figures` (error
against tilt, calibration of the sigmas), `overlay` (sample frames), `sections`
(calibration, reconstruction, sensitivity plan, reproducibility), `html`, `pdf`, and
`build` (the whole report, written). The validation.json itself is read by
`pencilcal.validation.validation_file`.

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

from ..validation_file import check_validation, load_validation
from .build import FORMATS, build_report, write_report
from .document import Bullets, Cell, Details, Para, Plot, Pre, Report, Section, Table
from .facts import method_keys, method_label
from .headline import Headline, headline
from .figures import fig_error_vs_tilt, fig_sigma_calibration
from .format import num, pct
from .html import render_html
from .overlay import fig_overlay
from .pdf import render_pdf
from .sections import load_sensitivity
from .tables import summary_table
from .verdict import coverage_judgement, verdict

__all__ = [
    "load_validation",
    "load_sensitivity",
    "check_validation",
    "build_report",
    "render_html",
    "render_pdf",
    "write_report",
    "verdict",
    "headline",
    "Headline",
    "summary_table",
    "method_keys",
    "method_label",
    "coverage_judgement",
    "fig_error_vs_tilt",
    "fig_sigma_calibration",
    "fig_overlay",
    "num",
    "pct",
    "Report",
    "Section",
    "Para",
    "Bullets",
    "Table",
    "Cell",
    "Plot",
    "Details",
    "Pre",
    "FORMATS",
]

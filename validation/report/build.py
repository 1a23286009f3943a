"""The whole report: its answer first (`headline`: the verdict line and the numbers that
matter), then its sections in reading order, numbered as they come (`build_report`); a
pivot's report puts the fulcrum right after the first section. `write_report` writes it in
the format its suffix names (atomically, through `files.atomic_write` and
`files.atomic_path`).
"""
from __future__ import annotations

import datetime as _dt
import re
from pathlib import Path

from pencilcal.toolkit.errors import InputError, PencilcalError
from pencilcal.toolkit.io.files import atomic_path, atomic_write, check_writable, to_jsonable

from ..validation_file import check_validation
from .document import Bullets, Details, Para, Report, Section, Table, Verdict
from .facts import pencil_phrase, reference_counts, reference_phrase
from .gates import failed_gates_sentence, fig_nees, gates, gates_table
from .figures import fig_error_vs_tilt, fig_sigma_calibration
from .format import lookup, num
from .headline import headline
from .html import render_html
from .fulcrum_section import fulcrum_section
from .overlay import overlay_section
from .pdf import render_pdf
from .sections import calibration_section, reproducibility_section, sensitivity_section, sfm_section
from .tables import frame_tables, summary_table
from .verdict import verdict

__all__ = ["FORMATS", "build_report", "write_report"]

#: report file suffix -> format
FORMATS = {".html": "html", ".htm": "html", ".pdf": "pdf"}


def _header(data, title):
    """The rows of the header table: what was validated."""
    frames = data["frames"]
    n = len(frames)
    ok = sum(1 for f in frames if f.get("ok"))
    cam = data.get("camera") or {}
    board = data.get("board") or {}
    rows = [["sequence", str(data.get("sequence", "–"))],
            ["frames", f"{n} ({ok} validated)"],
            ["reference", reference_phrase(data)]]
    refs = reference_counts(data)
    if refs:
        rows[-1][1] += " – " + ", ".join(f"{m}: {c} frames" for m, c in refs.most_common())
    if cam:
        fx = lookup(cam, "K", 0, 0)
        rows.append(["camera", f"{cam.get('model', '?')} {cam.get('width', '?')}x{cam.get('height', '?')}, "
                               f"fx {num(fx)} px" + (f" ({data['camera_file']})" if data.get("camera_file") else "")])
    if board:
        rows.append(["board", f"{board.get('type', '?')} {board.get('squares')} squares of {num(board.get('square'))}"
                              + (f", markers {num(board.get('marker'))}, {board.get('dictionary')}"
                                 + (", legacy layout" if board.get("legacy") else "")
                                 if board.get("type") == "charuco" else "")])
    rows.append(["pencil", pencil_phrase(data)])
    rows.append(["orient models", ", ".join(data.get("models") or []) or "–"])
    rows.append(["PnP methods", ", ".join(data.get("methods") or []) or "–"])
    rows.append(["validated on", str(lookup(data, "reproducibility", "created", default="–"))])
    return rows


def _verdict_section(data, title):
    """Section 1: the header table, the verdict and the reviewer's notes."""
    text, notes = verdict(data)
    gs = gates(data)
    failed = failed_gates_sentence(gs)
    s1 = Section("verdict", "1. What was validated, and the verdict",
                 [Table(["", ""], _header(data, title), None, None, numeric_from=9)])
    if gs:
        s1.blocks.append(gates_table(gs))
    s1.blocks.append(Para(f"{failed} {text}" if failed else text, "lead"))
    if notes:
        s1.blocks.append(Para("For the reviewer:", "text"))
        s1.blocks.append(Bullets(notes))
    return s1


def _plots_section(data):
    """Section 3: error against tilt and the calibration of the sigmas (or a note)."""
    s3 = Section("plots", "3. Error against tilt, and the calibration of the sigmas")
    for p in (fig_error_vs_tilt(data), fig_sigma_calibration(data), fig_nees(data)):
        if p is not None:
            s3.blocks.append(p)
    if not s3.blocks:
        s3.blocks.append(Para("No method produced an error against the reference: nothing to plot.", "note"))
    return s3


def _frames_section(data):
    """Section 4: the per-frame tables, each collapsible."""
    t_info, t_norm, t_tilt = frame_tables(data)
    return Section("frames", "4. Per frame", [
        Details(f"Frames, reference and flags ({len(data['frames'])} frames)", [t_info],
                open=len(data["frames"]) <= 15),
        Details("Normal error per method", [t_norm]),
        Details("Tilt error per method", [t_tilt])])


def build_report(data, *, title=None, samples=4, sensitivity=None, source=None, report_command=None,
                 sensitivity_path=None):
    """The report's content (Report) from a validation dict (`load_validation`).

    title: page title (default from the sequence); samples: overlay frames; sensitivity:
    a sensitivity.json dict or None; source: the validation file's path (hashed in the
    reproducibility block); report_command: the command line that made the report;
    sensitivity_path: the sensitivity file's path (hashed too).
    """
    check_validation(data, str(source) if source is not None else "validation data")
    seq = str(data.get("sequence") or (Path(source).stem if source else "validation"))
    title = title or f"Validation report: {seq}"
    created = lookup(data, "reproducibility", "created", default="unknown date")
    subtitle = (f"{len(data['frames'])} frames against the {reference_phrase(data)}; validated {created}; report "
                f"drawn {_dt.datetime.now().astimezone().strftime('%Y-%m-%d %H:%M %Z').strip()}")
    sections = [_verdict_section(data, title),
                Section("summary", "2. Summary of every method", [summary_table(data)]),
                _plots_section(data),
                _frames_section(data),
                overlay_section(data, samples, source),
                calibration_section(data),
                sfm_section(data),
                sensitivity_section(data, sensitivity),
                reproducibility_section(data, source, report_command, sensitivity_path)]
    fulcrum = fulcrum_section(data, number=2, samples=min(samples, 3), source=source)
    if fulcrum is not None:
        sections.insert(1, fulcrum)  # a pivot's report leads with its subject
    head = headline(data)
    lead = [Verdict(head.status, head.sentence)] + ([head.table] if head.table is not None else [])
    return Report(title, subtitle, _numbered(sections), lead)


def _numbered(sections):
    """The sections with their titles numbered 1, 2, ... in reading order."""
    for i, s in enumerate(sections, 1):
        s.title = re.sub(r"^\d+\.\s*", "", s.title)
        s.title = f"{i}. {s.title}"
    return sections


def write_report(path, data, *, force=False, title=None, samples=4, sensitivity=None, source=None,
                 report_command=None, sensitivity_path=None):
    """Build the report and write it to `path` (.html/.htm or .pdf), atomically, never
    over an existing file unless `force`. Returns the Report."""
    p = Path(path)
    fmt = FORMATS.get(p.suffix.lower())
    if fmt is None:
        raise InputError(f"{p}: unknown report format {p.suffix!r}; expected .html or .pdf")
    check_writable(p, force)  # before the work
    # what validate returns in memory (numpy arrays inside) reads as the file does
    data = to_jsonable(data)
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

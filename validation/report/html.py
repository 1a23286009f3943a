"""The report as one self-contained HTML page: styles inline, images as base64 PNG, no
script and no resource fetched from the network.

Example
-------
>>> from .document import Para, Report, Section
>>> page = render_html(Report("A <title>", "sub", [Section("verdict", "1. Verdict", [Para("fine", "lead")])]))
>>> "<h1>A &lt;title&gt;</h1>" in page, '<p class="lead">fine</p>' in page, "http" in page
(True, True, False)
"""
from __future__ import annotations

import base64
import html

from .document import Bullets, Cell, Details, Para, Plot, Pre, Table, Verdict

__all__ = ["render_html"]

_CSS = """
body{font-family:-apple-system,"Segoe UI",Roboto,"DejaVu Sans",Arial,sans-serif;margin:0;color:#1b1f23;
background:#fff;line-height:1.45;font-size:14px}
main{max-width:1400px;margin:0 auto;padding:18px 28px 60px}
h1{font-size:24px;margin:8px 0 2px} .subtitle{color:#586069;margin:0 0 14px}
h2{font-size:19px;border-bottom:2px solid #d0d7de;padding-bottom:3px;margin-top:34px}
nav{background:#f6f8fa;border:1px solid #d0d7de;border-radius:6px;padding:6px 12px;font-size:13px}
nav a{margin-right:14px;color:#0550ae;text-decoration:none}
p.lead{background:#f1f8ff;border-left:4px solid #0969da;padding:10px 14px;font-size:15px}
p.verdict{font-size:16px;padding:10px 14px;margin:6px 0 10px;border-left:6px solid #6e7781;background:#f6f8fa}
p.verdict b{display:inline-block;padding:1px 8px;margin-right:8px;border-radius:4px;color:#fff;background:#6e7781}
p.verdict.good{border-color:#1a7f37;background:#effbf1} p.verdict.good b{background:#1a7f37}
p.verdict.bad{border-color:#cf222e;background:#fff0ee} p.verdict.bad b{background:#cf222e}
p.verdict.warn{border-color:#bf8700;background:#fff8e1} p.verdict.warn b{background:#9a6700}
div.lead table{font-size:13px} div.lead td{white-space:normal} div.lead td:not(:last-child){white-space:nowrap}
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
    """One <td>, escaped, with its class and tooltip."""
    if not isinstance(c, Cell):
        c = Cell(str(c))
    cls = " ".join(x for x in (("num" if numeric else ""), c.cls or "") if x)
    attr = f' class="{cls}"' if cls else ""
    if c.title:
        attr += f' title="{html.escape(c.title)}"'
    return f"<td{attr}>{html.escape(c.text)}</td>"


def _table_html(t):
    """A Table as a scrollable <table> with its group row, header and caption."""
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
    """Any block of the document model as HTML."""
    if isinstance(b, Para):
        cls = {"lead": "lead", "note": "note", "caption": "caption"}.get(b.kind)
        attr = f' class="{cls}"' if cls else ""
        return f"<p{attr}>{html.escape(b.text)}</p>"
    if isinstance(b, Verdict):
        from .headline import STATUS_CLASS

        cls = STATUS_CLASS.get(b.status, "muted")
        return f'<p class="verdict {cls}" id="verdict"><b>{html.escape(b.status)}</b>{html.escape(b.text)}</p>'
    if isinstance(b, Bullets):
        return "<ul>" + "".join(f"<li>{html.escape(str(i))}</li>" for i in b.items) + "</ul>"
    if isinstance(b, Table):
        return _table_html(b)
    if isinstance(b, Plot):
        data = base64.b64encode(b.png).decode("ascii")
        alt = f"{b.alt} ({b.axes})" if b.axes else b.alt
        return (f'<figure><img src="data:image/png;base64,{data}" alt="{html.escape(alt)}">'
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
    body = [f"<h1>{html.escape(report.title)}</h1>", f'<p class="subtitle">{html.escape(report.subtitle)}</p>']
    if report.lead:
        body.append('<div class="lead">' + "\n".join(_block_html(b) for b in report.lead) + "</div>")
    body.append(f"<nav>{nav}</nav>")
    for s in report.sections:
        body.append(f'<section id="{s.id}"><h2>{html.escape(s.title)}</h2>')
        body += [_block_html(b) for b in s.blocks]
        body.append("</section>")
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            "<meta name=\"generator\" content=\"pencilcal report\">"
            f"<title>{html.escape(report.title)}</title><style>{_CSS}</style></head>\n<body><main>\n"
            + "\n".join(body) + "\n</main></body></html>\n")

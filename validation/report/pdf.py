"""The report as a multi-page A4 PDF, laid out on matplotlib's PdfPages: flowing text,
monospace tables (wide ones split into column chunks that repeat the key columns) and
raster figures. Sizes are in inches (A4: 8.27 x 11.69), font sizes in points.
"""
from __future__ import annotations

import io
import textwrap

from .document import Bullets, Cell, Details, Para, Plot, Pre, Table, Verdict

__all__ = ["render_pdf"]


def _cell_text(c):
    """A cell's text on one line."""
    return (c.text if isinstance(c, Cell) else str(c)).replace("\n", " ")


def _column_groups(groups, ncol):
    """(label of the group starting at each column or "", the column after that group)."""
    group_of = [""] * ncol
    group_end = list(range(1, ncol + 1))
    if groups:
        j = 0
        for g, span in groups:
            if g and j < ncol:
                group_of[j] = g
                group_end[j] = j + span
            j += span
    return group_of, group_end


def _column_chunks(widths, keys, width):
    """Split wide tables into column chunks that repeat the key columns: [[column index]],
    each at most `width` characters (columns take their width + 2) where it can be."""
    ncol = len(widths)
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
    return chunks

class _Pdf:
    """Flowing A4 pages of text, monospace tables and raster figures on matplotlib's PdfPages."""

    W, H, M = 8.27, 11.69, 0.6

    def __init__(self, pdf):
        """pdf: what takes the pages (PdfPages, or anything with savefig(figure))."""
        self.pdf = pdf
        self.fig = None
        self.y = 0.0
        self.pages = 0

    def flush(self):
        """Number the page in hand and hand it to the sink."""
        if self.fig is not None:
            self.fig.text(0.5, 0.25 / self.H, str(self.pages), ha="center", fontsize=7, color="0.5")
            self.pdf.savefig(self.fig)
            self.fig = None

    def new_page(self):
        """Start a page (handing on the one in hand)."""
        from matplotlib.figure import Figure

        self.flush()
        self.fig = Figure(figsize=(self.W, self.H))
        self.y = self.H - self.M
        self.pages += 1

    def _need(self, h):
        """A new page unless `h` inches are left on this one."""
        if self.fig is None or self.y - h < self.M:
            self.new_page()

    def line(self, s, size=9.0, weight="normal", family="sans-serif", color="black", indent=0.0):
        """One line of text at the current height; size in points, indent in inches."""
        h = size * 1.4 / 72
        self._need(h)
        self.fig.text((self.M + indent) / self.W, self.y / self.H, s, fontsize=size, weight=weight, family=family,
                      color=color, va="top", ha="left")
        self.y -= h

    def space(self, h=0.08):
        """Vertical space of h inches."""
        self.y -= h

    def para(self, text, size=9.0, color="black", indent=0.0, weight="normal"):
        """A paragraph wrapped to the page width."""
        width = int((self.W - 2 * self.M - indent) * 72 / (size * 0.56))
        for ln in textwrap.wrap(text, width) or [""]:
            self.line(ln, size, color=color, indent=indent, weight=weight)
        self.space()

    def heading(self, text, size=13.0):
        """A section heading, kept with what follows it."""
        self._need(size * 3 / 72 + 2.0)  # never alone at the foot of a page
        self.space(0.12)
        self.line(text, size, weight="bold")
        self.space(0.04)

    def table(self, t, size=6.5):
        """A Table in monospace, split into column chunks that fit the line width; its
        caption below."""
        width = int((self.W - 2 * self.M) * 72 / (size * 0.602))
        ncol = len(t.columns)
        heads = list(t.columns)
        groups = _column_groups(t.groups, ncol)
        body = [[_cell_text(c) for c in r] + [""] * (ncol - len(r)) for r in t.rows]
        widths = [min(max([len(heads[j])] + [len(r[j]) for r in body]), 40) for j in range(ncol)]
        keys = list(range(min(2, max(t.numeric_from, 1), ncol)))
        for cols in _column_chunks(widths, keys, width):
            self._table_chunk(t, cols, heads, body, widths, groups, width, size)
            self.space(0.06)
        if t.caption:
            self.para(t.caption, 7.5, color="0.35")

    def _table_chunk(self, t, cols, heads, body, widths, groups, width, size):
        """The columns `cols` of a table: group labels, header, rows (the last column wraps)."""
        group_of, group_end = groups
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

    def image(self, png, caption):
        """A PNG at the page width (or smaller, to fit one page) with its caption."""
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
        """Any block of the document model."""
        if isinstance(b, Para):
            if b.kind == "lead":
                self.para(b.text, 9.5, color="#0b3d91")
            elif b.kind == "note":
                self.para(b.text, 8.5, color="#7a5200")
            elif b.kind == "caption":
                self.para(b.text, 7.5, color="0.35")
            else:
                self.para(b.text, 9)
        elif isinstance(b, Verdict):
            color = {"PASS": "#1a7f37", "FAIL": "#cf222e", "CHECK": "#9a6700"}.get(b.status, "0.3")
            self.para(f"{b.status}: {b.text}", 10.5, color=color, weight="bold")
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
    doc.new_page()
    doc.para(report.title, 15, weight="bold")
    doc.para(report.subtitle, 8.5, color="0.35")
    for b in report.lead:
        doc.block(b)
    for s in report.sections:
        if s.id in ("frames", "overlays", "calibration", "reproducibility"):
            doc.new_page()
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

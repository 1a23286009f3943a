"""The report's content as simple blocks, built once and rendered to HTML or PDF.

A `Report` is a title, a subtitle, its lead (the blocks before everything else: the
`Verdict` and the numbers that matter) and a list of `Section`s; a section holds blocks:
`Para`, `Verdict`, `Bullets`, `Table` (of str or `Cell`), `Plot` (a PNG), `Details` (a collapsible
group of blocks) and `Pre`. The renderers (`html.render_html`, `pdf.render_pdf`) know
every block type; nothing here depends on how it is drawn.

Example
-------
>>> t = Table(["method", "frames", "note"], [["orient:exact", "5 / 6", Cell("fine", "good")]], text_cols=(2,))
>>> [t.numeric(j) for j in range(3)]
[False, True, False]
>>> Report("title", "sub", [Section("summary", "2. Summary", [t])]).sections[0].blocks[0].rows[0][2].cls
'good'
"""
from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["Cell", "Para", "Verdict", "Bullets", "Table", "Plot", "Details", "Pre", "Section", "Report"]


@dataclass
class Cell:
    """One table cell: text, an optional class (good, warn, bad, muted, mono) and a tooltip."""

    text: str
    cls: str | None = None
    title: str | None = None


@dataclass
class Para:
    """A paragraph of plain text; kind: text, lead (the verdict), note, caption."""

    text: str
    kind: str = "text"


@dataclass
class Verdict:
    """The report's answer in one line: status (PASS, FAIL, CHECK, NOT JUDGED) and the
    sentence saying what was measured, its headline figure and its tolerance."""

    status: str
    text: str


@dataclass
class Bullets:
    """A bulleted list; items: anything str() turns into one line of text."""

    items: list


@dataclass
class Table:
    """columns: header names; rows: lists of str or Cell; groups: (label, span) above the
    header; caption: text below; numeric_from: the first column of right-aligned numbers
    (text_cols excepted); row_cls: a class per row (None, or "bad" for a failed frame)."""

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
    """A matplotlib figure, rendered once to PNG: the file's bytes, a caption, alt text and
    what its axes show ("x: reference tilt [deg]; y: ...", "image" for a frame drawn on;
    `figures.plot_of` reads them off the figure)."""

    png: bytes
    caption: str
    alt: str
    axes: str = ""


@dataclass
class Details:
    """A collapsible group of blocks (HTML <details>; printed whole in the PDF)."""

    summary: str
    blocks: list
    open: bool = False


@dataclass
class Pre:
    """Preformatted text, kept line by line."""

    text: str


@dataclass
class Section:
    """A numbered part of the report: id (the HTML anchor), title and blocks."""

    id: str
    title: str
    blocks: list = field(default_factory=list)


@dataclass
class Report:
    """The whole report: title, subtitle, sections in reading order, and the lead: the
    blocks a reader sees first, before the sections (the verdict and its table)."""

    title: str
    subtitle: str
    sections: list
    lead: list = field(default_factory=list)

"""``report.pdf``: the handover report (report/handover.py) on A4 pages, for printing and
for whoever takes a PDF (matplotlib's PDF backend, the ``plots`` extra). The same content
as report.html, flowed top to bottom: the summary, then each section's text, list, table
(monospaced columns, a smaller type for wide tables, long cells cut with an ellipsis) and
figure (page-wide, on a new page when it does not fit), a footer with the title and the
page number on every page. The text is searchable and copyable: in the standard PDF fonts
(Helvetica, Courier; not embedded) when it is all Latin-1, else in DejaVu embedded as
TrueType (Type 42), whatever the script."""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pdcov.atomic import atomic_path
from pdcov.report.handover import Handover, Section, Table
from pdcov.report.plots import pyplot

_PAGE_IN = (8.27, 11.69)  # A4 portrait
_MARGIN_IN = 0.6
_BODY_PT, _HEADING_PT, _TITLE_PT, _MIN_TABLE_PT = 8.5, 12.0, 15.0, 5.0
_LINE = 1.45  # line height, in font sizes
_MONO_EM = 0.6  # a monospaced character's width, in font sizes
_MAX_CELL_CHARS = 48
_PT_IN = 1 / 72


@dataclass
class _Pages:
    """The PDF being written: its pages, the current one and the cursor (inches from the
    page's top)."""

    pdf: Any
    title: str
    plt: Any
    plain: str  # the weight of plain text
    fig: Any = None
    y_in: float = 0.0
    number: int = 0

    @property
    def width_in(self) -> float:
        return _PAGE_IN[0] - 2 * _MARGIN_IN

    def new_page(self) -> None:
        self.finish_page()
        self.fig = self.plt.figure(figsize=_PAGE_IN)
        self.number += 1
        self.y_in = _MARGIN_IN

    def finish_page(self) -> None:
        if self.fig is not None:
            self.text(f"pdcov handover: {self.title}    page {self.number}", 7,
                      y_in=_PAGE_IN[1] - _MARGIN_IN / 2, colour="0.4")
            self.pdf.savefig(self.fig)
            self.plt.close(self.fig)
            self.fig = None

    def room(self, height_in: float) -> None:
        """A new page unless ``height_in`` fits below the cursor."""
        if self.fig is None or self.y_in + height_in > _PAGE_IN[1] - _MARGIN_IN:
            self.new_page()

    def text(self, s: str, size_pt: float, *, x_in: float = 0.0, y_in: float | None = None,
             weight: str | None = None, family: str = "sans-serif", colour: str = "black",
             ha: str = "left") -> None:
        y = self.y_in if y_in is None else y_in
        self.fig.text((_MARGIN_IN + x_in) / _PAGE_IN[0], 1 - y / _PAGE_IN[1], s,
                      fontsize=size_pt, fontweight=weight or self.plain, family=family,
                      color=colour, ha=ha, va="top", parse_math=False)  # '$' is a dollar

    def line(self, s: str, size_pt: float, **kw: Any) -> None:
        """``s`` at the cursor, wrapped to the page's width, the cursor moved below it."""
        per_line = max(20, int(self.width_in / (size_pt * _PT_IN * 0.5)))
        for k in range(0, max(len(s), 1), per_line):
            self.room(size_pt * _LINE * _PT_IN)
            self.text(s[k:k + per_line], size_pt, **kw)
            self.y_in += size_pt * _LINE * _PT_IN


def _cut(s: str) -> str:
    return s if len(s) <= _MAX_CELL_CHARS else s[:_MAX_CELL_CHARS - 1] + "…"


def _table(pages: _Pages, t: Table) -> None:
    head = [list(t.header)] if any(t.header) else []  # a summary's rows have no header
    cells = head + [[_cut(c) for c in row] for row in t.rows]
    widths = [max(len(r[i]) if i < len(r) else 0 for r in cells) for i in range(len(t.header))]
    chars = sum(widths) + 2 * (len(widths) - 1)
    size = max(_MIN_TABLE_PT, min(_BODY_PT, pages.width_in / (chars * _MONO_EM * _PT_IN)))
    step_in = size * _LINE * _PT_IN
    for k, row in enumerate(cells):
        pages.room(step_in)
        x_chars = 0
        for i, (cell, w) in enumerate(zip(row, widths, strict=False)):
            right = i in t.numeric and k >= len(head)
            x_in = (x_chars + (w if right else 0)) * size * _MONO_EM * _PT_IN
            pages.text(cell, size, x_in=x_in, family="monospace", ha="right" if right else
                       "left", weight="bold" if k < len(head) else None)
            x_chars += w + 2
        pages.y_in += step_in
    pages.y_in += step_in / 2


def _figure_size_in(pages: _Pages, image: Any) -> tuple[float, float]:
    """(width, height) in inches: the page's width, or less for a figure taller than a
    page."""
    h_px, w_px = image.shape[:2]
    full_in = _PAGE_IN[1] - 2 * _MARGIN_IN
    w_in = pages.width_in
    h_in = w_in * h_px / w_px
    return (w_in * full_in / h_in, full_in) if h_in > full_in else (w_in, h_in)


def _figure(pages: _Pages, image: Any) -> None:
    w_in, h_in = _figure_size_in(pages, image)
    pages.room(h_in)
    ax = pages.fig.add_axes([_MARGIN_IN / _PAGE_IN[0], 1 - (pages.y_in + h_in) / _PAGE_IN[1],
                             w_in / _PAGE_IN[0], h_in / _PAGE_IN[1]])
    ax.imshow(image, interpolation="none")  # embedded at its own pixels, not resampled
    ax.set_axis_off()
    pages.y_in += h_in + 0.1


def _section(pages: _Pages, s: Section) -> None:
    image = None if s.figure is None else pages.plt.imread(io.BytesIO(s.figure.png),
                                                           format="png")
    first_in = _HEADING_PT * _LINE * _PT_IN * 3  # a heading never ends a page, nor is it
    if image is not None and not (s.text or s.items or s.table):  # parted from its figure
        first_in += _figure_size_in(pages, image)[1]
    pages.room(first_in)
    pages.y_in += 0.1
    pages.line(s.heading, _HEADING_PT, weight="bold")
    for t in s.text:
        pages.line(t, _BODY_PT)
    for item in s.items:
        pages.line(f"• {item}", _BODY_PT)
    if s.table is not None:
        _table(pages, s.table)
    if image is not None:
        _figure(pages, image)
    if s.missing is not None:
        pages.line(s.missing, _BODY_PT, colour="#8a6d3b")


def _texts(report: Handover) -> list[str]:
    texts = [report.title, *(t for row in report.summary for t in row)]
    for s in report.sections:
        texts += [s.heading, *s.text, *s.items, s.missing or ""]
        if s.table is not None:
            texts += [*s.table.header, *(c for row in s.table.rows for c in row)]
    return texts


def _fonts(report: Handover) -> tuple[Any, str]:
    """The PDF's fonts (rc settings) and the weight of plain text in them: the standard
    Helvetica and Courier (not embedded: a page in a tenth of a second; their plain weight
    is 'medium') when every text is in their WinAnsi encoding, else DejaVu embedded as
    TrueType (any script; 1.5 s more)."""
    try:
        "".join(_texts(report)).encode("cp1252")
    except UnicodeEncodeError:
        return {"pdf.fonttype": 42}, "normal"
    return {"pdf.use14corefonts": True}, "medium"


def write_handover_pdf(path: Path, report: Handover) -> Path:
    """``report`` as a PDF at ``path`` (atomically); the path."""
    plt = pyplot()
    from matplotlib import rc_context
    from matplotlib.backends.backend_pdf import PdfPages

    fonts, plain = _fonts(report)
    with rc_context(fonts), atomic_path(path) as tmp:
        with PdfPages(tmp, metadata={"Title": f"pdcov handover: {report.title}",
                                     "Creator": "pdcov"}) as pdf:
            pages = _Pages(pdf, report.title, plt, plain)
            pages.new_page()
            pages.line(f"pdcov handover: {report.title}", _TITLE_PT, weight="bold")
            pages.y_in += 0.1
            _table(pages, Table(("", ""), report.summary))
            for s in report.sections:
                _section(pages, s)
            pages.finish_page()
    return path

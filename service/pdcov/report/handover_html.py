"""``report.html``: the handover report (report/handover.py) as one self-contained page. No
reference leaves the file: the figures are inline ``data:`` URIs, the style is inline,
there is no script, and a Content-Security-Policy forbids any load but those. Every string
is escaped (``html.escape``)."""

from __future__ import annotations

import base64
import html
import struct
from typing import Any

from pdcov.report.handover import Handover, Section, Table
from pdcov.report.run_files import PNG_SIGNATURE

_CSP = "default-src 'none'; img-src data:; style-src 'unsafe-inline'"
_STYLE = """
body { font-family: sans-serif; margin: 1.5em auto; max-width: 60em; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.5em 0; }
th, td { border: 1px solid #ccc; padding: 0.2em 0.6em; text-align: left; }
td.n { text-align: right; font-variant-numeric: tabular-nums; }
img { max-width: 100%; height: auto; }
p.missing { color: #8a6d3b; font-style: italic; }
"""


def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)


def png_size(data: bytes) -> tuple[int, int]:
    """(width, height) of a PNG from its IHDR chunk."""
    if not data.startswith(PNG_SIGNATURE) or len(data) < 24:
        raise ValueError("not a PNG")
    width, height = struct.unpack(">II", data[16:24])
    return int(width), int(height)


def _table(t: Table) -> str:
    head = "".join(f"<th>{_e(h)}</th>" for h in t.header)
    body = "".join("<tr>" + "".join(
        f'<td class="n">{_e(c)}</td>' if i in t.numeric else f"<td>{_e(c)}</td>"
        for i, c in enumerate(row)) + "</tr>\n" for row in t.rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>\n{body}</tbody></table>\n"


def _section(s: Section) -> str:
    out = f"<h2>{_e(s.heading)}</h2>\n" + "".join(f"<p>{_e(t)}</p>\n" for t in s.text)
    if s.items:
        out += "<ul>" + "".join(f"<li>{_e(i)}</li>" for i in s.items) + "</ul>\n"
    if s.table is not None:
        out += _table(s.table)
    if s.figure is not None:
        w, h = png_size(s.figure.png)
        uri = "data:image/png;base64," + base64.b64encode(s.figure.png).decode("ascii")
        out += f'<p><img src="{uri}" width="{w}" height="{h}" alt="{_e(s.figure.alt)}"></p>\n'
    if s.missing is not None:
        out += f'<p class="missing">{_e(s.missing)}</p>\n'
    return out


def handover_html(report: Handover) -> str:
    """The page of ``report``."""
    summary = "".join(f"<tr><th>{_e(k)}</th><td>{_e(v)}</td></tr>\n" for k, v in report.summary)
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\n"
            f'<meta http-equiv="Content-Security-Policy" content="{_CSP}">\n'
            f"<title>pdcov handover: {_e(report.title)}</title>\n<style>{_STYLE}</style>\n"
            f"</head><body>\n<h1>pdcov handover: {_e(report.title)}</h1>\n"
            f"<table>\n{summary}</table>\n" + "".join(_section(s) for s in report.sections)
            + "</body></html>\n")

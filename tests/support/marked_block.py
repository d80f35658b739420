"""A generated block between two marker lines of a text file (README.md, docs/*.md), which
the benchmarks write their tables into; shared by the benchmarks and its test."""

from __future__ import annotations

from pathlib import Path


def write_marked_block(path: Path, block: str, start: str, end: str) -> None:
    """Replace the text between the markers ``start`` and ``end`` of ``path`` (appending
    them at its end when absent, creating the file when missing); nothing else changes."""
    text = path.read_text() if path.exists() else ""
    body = f"{start}\n{block}\n{end}"
    if start in text and end in text:
        head, rest = text.split(start, 1)
        tail = rest.split(end, 1)[1]
        text = head + body + tail
    else:
        text = text.rstrip("\n") + ("\n\n" if text else "") + body + "\n"
    path.write_text(text)

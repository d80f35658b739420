"""report.html read back with the standard library's html.parser, for the report's tests:
every attribute and inline style that could load something, the images, and the tables."""

from __future__ import annotations

import base64
import io
import re
from html.parser import HTMLParser

_URL = re.compile(r"url\(\s*['\"]?([^'\")]*)", re.I)
_EXTERNAL = ("http:", "https:", "//", "file:")


class ReportPage(HTMLParser):
    """The page's references (every src, href, and url() in a style), images and tables
    (each a list of rows of cell texts, the header row first)."""

    def __init__(self, text: str) -> None:
        super().__init__(convert_charrefs=True)
        self.references: list[str] = []
        self.images: list[dict[str, str]] = []
        self.tables: list[list[list[str]]] = []
        self.tags: list[str] = []
        self._cell: list[str] | None = None
        self._style = False
        self.feed(text)
        self.close()

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append(tag)
        a = {k: v or "" for k, v in attrs}
        self.references += [a[k] for k in ("src", "href", "action", "data", "srcset")
                            if k in a]
        self.references += _URL.findall(a.get("style", ""))
        if tag == "img":
            self.images.append(a)
        elif tag == "table":
            self.tables.append([])
        elif tag == "tr":
            self.tables[-1].append([])
        elif tag in ("td", "th"):
            self._cell = []
        self._style = tag == "style"

    def handle_endtag(self, tag: str) -> None:
        if tag in ("td", "th") and self._cell is not None:
            self.tables[-1][-1].append("".join(self._cell).strip())
            self._cell = None
        self._style = False

    def handle_data(self, data: str) -> None:
        if self._cell is not None:
            self._cell.append(data)
        if self._style:
            self.references += _URL.findall(data) + re.findall(r"@import\s+(\S+)", data)

    def external(self) -> list[str]:
        """The references that leave the file."""
        return [r for r in self.references if r.strip().lower().startswith(_EXTERNAL)]

    def table(self, first_header: str) -> list[list[str]]:
        """The rows (no header) of the table whose first header cell is ``first_header``."""
        [found] = [t for t in self.tables if t and t[0] and t[0][0] == first_header]
        return found[1:]


def inline_png_size(src: str) -> tuple[int, int]:
    """(width, height) of an inline data:image/png;base64 image, decoded by Pillow."""
    from PIL import Image

    prefix = "data:image/png;base64,"
    assert src.startswith(prefix), src[:40]
    with Image.open(io.BytesIO(base64.b64decode(src[len(prefix):], validate=True))) as im:
        assert im.format == "PNG"
        return im.size

"""Reading the user's text files (YAML, CSV) with errors that name the file.

Text is UTF-8; a leading byte-order mark (spreadsheet programs and Windows editors write one)
is accepted and dropped. A byte that is not UTF-8 is an error naming the file, the line and
the byte offset, never a traceback.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from pdcov.errors import ConfigError, PdcovError


def read_text(path: str | Path, what: str, error: type[PdcovError] = ConfigError,
              max_bytes: int | None = None) -> str:
    """The text of a UTF-8 file (BOM dropped, newlines as written); ``error`` names the
    file, what it should be and, for a byte that is not UTF-8, where it is. A file larger
    than ``max_bytes`` is refused before it is read."""
    path = Path(path)
    try:
        if max_bytes is not None and (size := path.stat().st_size) > max_bytes:
            raise error(f"{path}: {size:,} bytes, more than the {max_bytes:,} a {what} may "
                        "have")
        data = path.read_bytes()
    except OSError as exc:
        raise error(f"{path}: cannot read {what} ({exc.strerror or exc})") from None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise error(f"{path}:{line}: byte 0x{data[exc.start]:02x} at byte offset {exc.start} "
                    f"is not UTF-8; save the {what} as UTF-8 text") from None


def load_yaml(path: str | Path, what: str, error: type[ConfigError] = ConfigError,
              max_bytes: int | None = None) -> Any:
    """The parsed document of a YAML file (at most ``max_bytes``); ``error`` names the file
    and what it should be."""
    text = read_text(path, what, error, max_bytes)
    try:
        return yaml.safe_load(text)
    # ValueError: an integer of more than 4300 digits (int's conversion limit, CVE-2020-10735);
    # RecursionError: collections nested too deep for the parser.
    except (yaml.YAMLError, ValueError, RecursionError) as exc:
        raise error(f"{path}: not valid YAML ({exc})") from None

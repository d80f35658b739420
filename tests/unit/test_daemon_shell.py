"""The daemon's asyncio shell is the event loop's wiring only (issue 36, docs/service.md):
of service/ and bus/, only daemon.py and mavlink_io.py use asyncio, about 300 lines
together; the I/O they ask for is in modules without the loop (contract loop-in-shell)."""

from __future__ import annotations

import re
from pathlib import Path

PKG = Path(__file__).resolve().parents[2] / "service" / "pdcov"
USES_ASYNCIO = re.compile(r"^import asyncio|^from asyncio|asyncio\.", re.MULTILINE)


def test_only_the_shell_uses_asyncio_and_it_is_short() -> None:
    lines = {p.relative_to(PKG).as_posix(): len(text.splitlines())
             for folder in ("service", "bus") for p in sorted((PKG / folder).glob("*.py"))
             if USES_ASYNCIO.search(text := p.read_text(encoding="utf-8"))}
    assert set(lines) == {"service/daemon.py", "service/mavlink_io.py"}, lines
    assert sum(lines.values()) <= 300, lines

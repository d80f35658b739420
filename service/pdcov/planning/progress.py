"""Progress of long planning work on stderr: a live bar on a terminal; elsewhere (a log file,
a pipe, a service journal) one plain line every few seconds, so a long run is never silent."""

from __future__ import annotations

import sys
from collections.abc import Iterable
from typing import IO, TypeVar

from tqdm import tqdm

T = TypeVar("T")


class _Lines:
    """A stream that turns tqdm's carriage-return redraws into whole lines."""

    def __init__(self, stream: IO[str]) -> None:
        self._stream = stream

    def write(self, text: str) -> None:
        text = text.replace("\r", "").strip("\n")
        if text.strip():
            self._stream.write(text + "\n")

    def flush(self) -> None:
        self._stream.flush()


def progress(items: Iterable[T], *, desc: str, unit: str, total: int | None = None,
             enabled: bool = True, every_s: float = 5.0) -> Iterable[T]:
    """``items`` with progress on stderr (module docstring); ``every_s`` s between lines when
    stderr is not a terminal."""
    if not enabled:
        return items
    if sys.stderr.isatty():
        return tqdm(items, desc=desc, unit=unit, total=total)
    return tqdm(items, desc=desc, unit=unit, total=total, file=_Lines(sys.stderr), ascii=True,
                mininterval=every_s, maxinterval=max(every_s, 0.1), ncols=80)

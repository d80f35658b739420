"""``pdcov serve``'s log lines as journald reads them from stderr: ``setup_logging``."""

from __future__ import annotations

import logging
import sys

__all__ = ["JournalFormatter", "setup_logging"]


class JournalFormatter(logging.Formatter):
    """``<N>message``: the syslog level as journald reads it from stderr; no time stamp
    (journald adds its own)."""

    LEVELS = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3,
              logging.CRITICAL: 2}

    def format(self, record: logging.LogRecord) -> str:
        level = self.LEVELS.get(record.levelno, 6)
        return f"<{level}>{record.name}: {super().format(record)}"


def setup_logging(level: int = logging.INFO) -> None:
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JournalFormatter("%(message)s"))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level)

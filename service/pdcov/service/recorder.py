"""The telemetry the daemon used, recorded as .tlog files in its state directory, so that
every flight can be evaluated again offline (``pdcov evaluate --log``).

A tlog record is an 8-byte big-endian wall-clock stamp (microseconds since the Unix epoch)
and the MAVLink frame as received. Files are named ``flight-<UTC start>-<n>.tlog``; a file
is closed at ``max_bytes`` and a new one begun; the oldest are deleted while all together
exceed ``keep_bytes``. Writes are buffered and flushed each second (``flush``). When a
write fails (a full disk) the recorder says why (``error``), drops what comes for
RETRY_S and then begins a new file.
"""

from __future__ import annotations

import logging
import struct
import time
from pathlib import Path
from typing import IO

log = logging.getLogger(__name__)
_STAMP = struct.Struct(">Q")
RETRY_S = 10.0


class TlogRecorder:
    """Appends MAVLink frames to rotating tlog files in ``folder``."""

    def __init__(self, folder: Path, max_bytes: int, keep_bytes: int) -> None:
        self.folder = folder
        self.max_bytes = max_bytes
        self.keep_bytes = keep_bytes
        self._fh: IO[bytes] | None = None
        self._size = 0
        self._n = 0
        self._stem = time.strftime("flight-%Y%m%dT%H%M%SZ", time.gmtime())
        self.path: Path | None = None
        self.error: str | None = None   # why the last write failed; None while recording
        self._retry_s = 0.0             # monotonic time of the next attempt after a failure

    @property
    def failed(self) -> bool:
        return self.error is not None

    def write(self, frame: bytes, wall_time_s: float) -> None:
        if self.error is not None:
            if time.monotonic() < self._retry_s:
                return
            self.close()  # then a new file: the failed one may end in a torn record
        try:
            fh = self._fh
            if fh is None or self._size >= self.max_bytes:
                fh = self._rotate()
            record = _STAMP.pack(int(wall_time_s * 1e6)) + frame
            fh.write(record)
            self._size += len(record)
            if self.error is not None:
                log.warning("recording again in %s after: %s", self.path, self.error)
                self.error = None
        except OSError as exc:
            self._failed(exc)

    def _failed(self, exc: OSError) -> None:
        if self.error is None:
            log.error("recording paused (retrying every %g s): cannot write %s: %s",
                      RETRY_S, self.path, exc)
        self.error = f"{self.path}: {exc.strerror or exc}"
        self._retry_s = time.monotonic() + RETRY_S

    def _rotate(self) -> IO[bytes]:
        """A new recording file (the oldest removed above keep_bytes); returns it open."""
        self.close()
        self.folder.mkdir(parents=True, exist_ok=True)
        self._n += 1
        self.path = self.folder / f"{self._stem}-{self._n}.tlog"
        self._fh = fh = self.path.open("ab")
        self._size = 0
        files = sorted(self.folder.glob("flight-*.tlog"), key=lambda p: p.stat().st_mtime)
        total = sum(p.stat().st_size for p in files)
        for old in files:
            if total <= self.keep_bytes or old == self.path:
                break
            total -= old.stat().st_size
            old.unlink()
            log.info("recording %s removed (recordings above %d bytes)", old.name,
                     self.keep_bytes)
        return fh

    def flush(self) -> None:
        if self._fh is not None and self.error is None:
            try:
                self._fh.flush()
            except OSError as exc:
                self._failed(exc)

    def close(self) -> None:
        if self._fh is not None:
            try:
                self._fh.close()
            except OSError:
                pass
            self._fh = None

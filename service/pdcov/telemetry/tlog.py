"""MAVLink telemetry log (.tlog) records -> decoded messages, resynchronising past damage.

A tlog is a sequence of records: an 8-byte big-endian wall-clock stamp (microseconds) and
one MAVLink 1 or 2 frame. pymavlink's own tlog readers guess the protocol from the first
magic byte they meet (a MAVLink 1 magic in leading junk makes every MAVLink 2 message
"unknown") and index the file with a heuristic that raises on junk at its end; so the
records are framed here and each frame is decoded by the MAVLink 2 dialect, which reads
both protocol versions.

In step (each record where the last one ended) a frame is taken as it is: a known message
whose checksum fails, or bytes that are no frame, start a resynchronisation. A resync point
is a known message with a valid checksum followed by another record (or the end of the
file), so that random bytes are not taken for a message. Unknown message ids (a dialect
newer than pymavlink's) cannot be checked and are skipped, in step only. A frame that runs
past the end of the file is a cut log.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

STAMP_LEN = 8
_MAGIC_V1 = 0xFE
_MAGIC_V2 = 0xFD
_MAGIC = re.compile(b"[\xfd\xfe]")
_MIN_FRAME = 8  # MAVLink 1 header (6) + checksum (2), empty payload


@dataclass(slots=True)
class LogDamage:
    """What reading a log skipped: runs of bytes that are not records ((offset, length) in
    the file), messages of unknown id, and the offset of a record cut by the end of the
    file. ``kind`` names the records ("MAVLink", "DataFlash records")."""

    size: int = 0
    kind: str = "MAVLink"
    junk: list[tuple[int, int]] = field(default_factory=list)
    unknown: int = 0
    cut_at: int | None = None

    def describe(self) -> list[str]:
        """Summary lines (none when the file was read whole)."""
        lines = []
        inner = self.junk
        if inner and sum(inner[-1]) == self.size:
            end_o = inner[-1][0]
            inner = inner[:-1]
            lines.append(f"reading stopped at byte {end_o} of {self.size}: the last "
                         f"{self.size - end_o} bytes are not {self.kind} (damaged or padded); "
                         "the messages before them are used")
        if inner:
            shown = ", ".join(f"{n} B at byte {o}" for o, n in inner[:3])
            more = f" and {len(inner) - 3} more" if len(inner) > 3 else ""
            lines.insert(0, f"skipped {len(inner)} runs of bytes that are not {self.kind} "
                            f"({sum(n for _o, n in inner)} bytes: {shown}{more}); "
                            "resynchronised after each")
        if self.unknown:
            lines.append(f"skipped {self.unknown} messages of unknown ids")
        if self.cut_at is not None:
            lines.append(f"the log is cut short: its last record (from byte {self.cut_at} "
                         f"of {self.size}) is incomplete; the messages before it are used")
        return lines


def _frame_len(data: bytes | memoryview, i: int) -> int | None:
    """Length of the frame whose magic byte is at i, None when no header fits."""
    n = len(data)
    if data[i] == _MAGIC_V1:
        return data[i + 1] + _MIN_FRAME if i + 6 <= n else None
    if i + 10 > n:
        return None
    signed = data[i + 2] & mavlink.MAVLINK_IFLAG_SIGNED
    return data[i + 1] + 12 + (mavlink.MAVLINK_SIGNATURE_BLOCK_LEN if signed else 0)


class TlogScanner:
    """Decode the records of tlog bytes; ``damage`` says what was skipped."""

    def __init__(self, data: bytes) -> None:
        self._data = data
        self._mav = mavlink.MAVLink(None)
        self._mav.robust_parsing = True
        self.damage = LogDamage(size=len(data))

    def _decode(self, i: int) -> tuple[str, int, Any]:
        """('ok' | 'unknown' | 'bad' | 'cut', frame length, message) of a frame at i."""
        data = self._data
        if i >= len(data) or data[i] not in (_MAGIC_V1, _MAGIC_V2):
            return ("cut" if i >= len(data) else "bad"), 0, None
        n = _frame_len(data, i)
        if n is None or i + n > len(data):
            return "cut", 0, None
        try:
            msg = self._mav.decode(bytearray(data[i:i + n]))
        except (mavlink.MAVError, ValueError, IndexError):
            return "bad", n, None
        if isinstance(msg, mavlink.MAVLink_unknown):
            return "unknown", n, None
        return "ok", n, msg

    def _confirmed(self, end: int) -> bool:
        """True when a record can start at ``end`` (the end of a resync candidate)."""
        if end == len(self._data):
            return True
        status, _n, _m = self._decode(end + STAMP_LEN)
        return status in ("ok", "unknown")

    def _resync(self, start: int) -> int | None:
        """Offset of the next confirmed frame at or after ``start``, None if none follows."""
        for m in _MAGIC.finditer(self._data, start):
            j = m.start()
            status, n, _msg = self._decode(j)
            if status == "ok" and self._confirmed(j + n):
                return j
        return None

    def messages(self) -> Iterator[Any]:
        """The decoded messages, in file order."""
        size = len(self._data)
        i = STAMP_LEN  # where the next frame should start (after its record's stamp)
        while i - STAMP_LEN < size:
            status, n, msg = self._decode(i)
            if status == "ok":
                yield msg
                i += n + STAMP_LEN
                continue
            if status == "unknown" and self._confirmed(i + n):
                self.damage.unknown += 1
                i += n + STAMP_LEN
                continue
            record = i - STAMP_LEN
            j = self._resync(record)
            if j is None and status == "cut":
                self.damage.cut_at = record
                return
            if j is None:
                self.damage.junk.append((record, size - record))
                return
            self.damage.junk.append((record, max(j - i, 1)))
            i = j

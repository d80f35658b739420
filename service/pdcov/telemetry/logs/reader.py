"""``read_flight_log``: a log's format from its first bytes (.tlog, DataFlash .bin, PX4 .ulg),
read by its reader into one ``FlightLog``; a log with no attitude or position is an error.
"""

from __future__ import annotations

from pathlib import Path

from pdcov.errors import TelemetryError
from pdcov.telemetry.logs.dataflash import read_dataflash
from pdcov.telemetry.logs.flight_log import FlightLog
from pdcov.telemetry.logs.tlog import read_tlog
from pdcov.telemetry.logs.ulog import read_ulog

DATAFLASH_MAGIC = b"\xa3\x95"
ULOG_MAGIC = b"ULog\x01\x12\x35"


def read_flight_log(path: str | Path, *, system_id: int | None = None,
                    gimbal_instance: int = 1) -> FlightLog:
    """Read a .tlog, DataFlash .bin or .ulg file (format from its first bytes).

    system_id: the MAVLink system to follow (tlogs); None = the autopilot announced by
    HEARTBEAT. gimbal_instance: the gimbal to follow where several report (the mount's
    ``instance``, as the live tracker uses it). Raises TelemetryError naming the file when
    it cannot be read or holds no attitude or position.
    """
    path = Path(path)
    try:
        with path.open("rb") as f:
            head = f.read(4096)
    except OSError as exc:
        raise TelemetryError(f"{path}: cannot open log: {exc.strerror or exc}") from None
    if not head:
        raise TelemetryError(f"{path}: empty file, not a flight log")
    if head.startswith(ULOG_MAGIC):
        log = read_ulog(path, gimbal_instance)
    elif head.startswith(DATAFLASH_MAGIC):
        log = read_dataflash(path, gimbal_instance)
    elif b"FMT," in head and _mostly_text(head):
        raise TelemetryError(
            f"{path}: a text DataFlash log (.log); pdcov reads binary DataFlash (.bin), "
            "MAVLink .tlog and PX4 .ulg logs only. Use the .bin the autopilot wrote, or "
            "convert this one with a tool that understands its layout")
    else:
        log = read_tlog(path, system_id, gimbal_instance)
    if len(log.attitude.t_s) == 0:
        raise TelemetryError(f"{path}: no attitude messages (ATTITUDE / ATT / "
                             f"vehicle_attitude) for the followed vehicle")
    if len(log.position.t_s) == 0:
        raise TelemetryError(f"{path}: no position messages (GLOBAL_POSITION_INT / POS / "
                             f"vehicle_global_position) with a valid fix")
    return log


def _mostly_text(head: bytes) -> bool:
    printable = sum(32 <= b < 127 or b in (9, 10, 13) for b in head)
    return printable > 0.95 * len(head)

"""The mission config's ``log`` section: how a flight log is framed and which of its
samples count (frame source, telemetry gap, autopilot, estimator status)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from pdcov.config.values import number
from pdcov.errors import ConfigError, where
from pdcov.ids import SYSTEM_IDS, valid_system_id


@dataclass(frozen=True, slots=True)
class LogSection:
    """``log``: how frames are placed in a log (frame_source 'rate' or 'capture'), the
    telemetry gap that skips frames (s), the autopilot to follow (a MAVLink system id; None:
    from its HEARTBEAT) and whether the estimator's status can skip frames."""

    frame_source: str = "rate"
    max_gap_s: float = 1.0
    system_id: int | None = None
    estimator_status: bool = True

    @classmethod
    def from_mapping(cls, doc: Mapping[str, Any], src: str | None) -> LogSection:
        frame_source = doc.get("frame_source", "rate")
        if frame_source not in ("rate", "capture"):
            raise ConfigError(f"{where(src, 'log.frame_source')}: expected 'rate' or "
                              f"'capture', got {frame_source!r}")
        system_id = doc.get("system_id")
        if system_id is not None and not valid_system_id(system_id):
            raise ConfigError(f"{where(src, 'log.system_id')}: expected a MAVLink system id "
                              f"{SYSTEM_IDS.start}..{SYSTEM_IDS.stop - 1}, got {system_id!r}")
        estimator_status = doc.get("estimator_status", True)
        if not isinstance(estimator_status, bool):
            raise ConfigError(f"{where(src, 'log.estimator_status')}: expected true or false, "
                              f"got {estimator_status!r}")
        return cls(frame_source,
                   number(doc, "max_gap_s", src, "log", default=1.0, positive=True),
                   system_id, estimator_status)

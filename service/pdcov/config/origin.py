"""The mission config's ``origin`` section: where the ENU frame (m) of the grid is placed."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from pdcov.config.values import number


@dataclass(frozen=True, slots=True)
class OriginSection:
    """``origin``: the ENU origin (degrees) and the ground altitude there (m MSL; None: the
    autopilot's home altitude)."""

    lat_deg: float
    lon_deg: float
    ground_alt_msl_m: float | None = None

    @classmethod
    def from_mapping(cls, doc: Mapping[str, Any], src: str | None) -> OriginSection:
        ground = (None if doc.get("ground_alt_msl_m") is None
                  else number(doc, "ground_alt_msl_m", src, "origin"))
        return cls(number(doc, "lat_deg", src, "origin"), number(doc, "lon_deg", src, "origin"),
                   ground)

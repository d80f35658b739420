"""The fleet roster: which vehicle ids the ground station merges (``fleet.vehicles`` of its
mission config). A vehicle heard that is not on it is unknown: listed with the reason,
never given a feed, so it reaches no fleet figure, export or report. Without a roster
every vehicle heard is merged, as before, and the views say there is none."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from pdcov.errors import ConfigError, where
from pdcov.ids import VEHICLE_ID_RULE, valid_vehicle_id
from pdcov.schema import Section, check_keys

NOT_ON_ROSTER = "not on fleet.vehicles"
"""Why a vehicle heard is unknown."""
NO_ROSTER = "no fleet roster (fleet.vehicles): every vehicle heard is merged"


@dataclass(frozen=True, slots=True)
class Roster:
    """vehicles: the ids merged, or None (no roster: every id)."""

    vehicles: frozenset[str] | None = None

    def __post_init__(self) -> None:
        bad = sorted(v for v in self.vehicles or () if not valid_vehicle_id(v))
        if bad:
            raise ConfigError(f"{bad[0]!r}: expected {VEHICLE_ID_RULE}")

    def admits(self, vehicle_id: str) -> bool:
        return self.vehicles is None or vehicle_id in self.vehicles

    @property
    def notice(self) -> str | None:
        """What the views show about the roster itself: only that there is none."""
        return NO_ROSTER if self.vehicles is None else None


@dataclass(frozen=True, slots=True)
class FleetSection:
    """The ``fleet`` section of the ground station's mission config. vehicles: the ids on
    the roster (docs/mission-config.md "fleet")."""

    vehicles: tuple[str, ...] | None = None


FLEET_CONFIG = Section.of_dataclass(FleetSection)


def roster_of(raw: Mapping[str, Any], source: str | None = None) -> Roster:
    """The roster of a mission config mapping (``Mission.raw``); ConfigError naming the
    field for anything but a list of vehicle ids."""
    section = raw.get("fleet")
    if section is None:
        return Roster()
    if not isinstance(section, Mapping):
        raise ConfigError(f"{where(source, 'fleet')}: expected a mapping")
    check_keys(section, FLEET_CONFIG, source, "fleet")
    vehicles = section.get("vehicles")
    if vehicles is None:
        return Roster()
    if not isinstance(vehicles, list) or not vehicles:
        raise ConfigError(f"{where(source, 'fleet.vehicles')}: expected a non-empty list of "
                          "vehicle ids")
    try:
        return Roster(frozenset(vehicles))
    except (ConfigError, TypeError) as exc:
        raise ConfigError(f"{where(source, 'fleet.vehicles')}: {exc}") from None

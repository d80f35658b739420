"""Where a re-tasking mission may send the aircraft: the one rule the daemon enforces before
anything reaches the autopilot and the ground station checks before sending
(``service.retask_limits``, docs/service.md).

Every positional item (waypoint, loiter, take-off, land: a take-off or landing at lat/lon 0
means "here") lies inside the mission's domain boundary grown by ``margin_m``; every
altitude is within [``min_alt_m``, ``max_alt_m``] above home: MAV_FRAME_GLOBAL_RELATIVE_ALT
as written, MAV_FRAME_GLOBAL (AMSL) minus home's altitude, MAV_FRAME_GLOBAL_TERRAIN_ALT
(above the terrain) against the same bounds; a landing's altitude is not checked (the
autopilot lands where it is told). A speed change's speed is at most ``max_speed_m_s``;
the mission has at most ``max_items`` items. Home is the mission origin with the ground
altitude the daemon uses (``Origin``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from typing import Any

import shapely
from shapely.geometry import Polygon

from pdcov.core.geodesy import Origin, geodetic_to_enu
from pdcov.core.mission import (
    MAV_CMD_DO_CHANGE_SPEED,
    MAV_CMD_NAV_LAND,
    MAV_CMD_NAV_LOITER_TIME,
    MAV_CMD_NAV_TAKEOFF,
    MAV_CMD_NAV_WAYPOINT,
    MAV_FRAME_GLOBAL,
    MAV_FRAME_GLOBAL_RELATIVE_ALT,
    MAV_FRAME_GLOBAL_TERRAIN_ALT,
    MissionItem,
)
from pdcov.errors import ConfigError

POSITION_COMMANDS = frozenset({MAV_CMD_NAV_WAYPOINT, MAV_CMD_NAV_LOITER_TIME,
                               MAV_CMD_NAV_TAKEOFF, MAV_CMD_NAV_LAND})
GLOBAL_FRAMES = frozenset({MAV_FRAME_GLOBAL, MAV_FRAME_GLOBAL_RELATIVE_ALT,
                           MAV_FRAME_GLOBAL_TERRAIN_ALT})
MAX_REASONS = 5
"""Item reasons kept in a verdict (the count of all is given)."""


@dataclass(frozen=True, slots=True)
class RetaskLimits:
    """``service.retask_limits``: margin_m around the domain, min_alt_m / max_alt_m above
    home (m), max_speed_m_s, max_items."""

    margin_m: float = 100.0
    min_alt_m: float = 2.0
    max_alt_m: float = 120.0
    max_speed_m_s: float = 15.0
    max_items: int = 1000

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"service.retask_limits.{f.name}: expected a number, "
                                  f"got {v!r}")
        if self.margin_m < 0:
            raise ConfigError(f"service.retask_limits.margin_m: expected >= 0 m, got "
                              f"{self.margin_m}")
        if not 0 <= self.min_alt_m < self.max_alt_m:
            raise ConfigError("service.retask_limits: expected 0 <= min_alt_m < max_alt_m, "
                              f"got {self.min_alt_m} and {self.max_alt_m}")
        if self.max_speed_m_s <= 0:
            raise ConfigError(f"service.retask_limits.max_speed_m_s: expected > 0, got "
                              f"{self.max_speed_m_s}")
        if not (isinstance(self.max_items, int) and 1 <= self.max_items <= 1000):
            raise ConfigError(f"service.retask_limits.max_items: expected 1..1000, got "
                              f"{self.max_items!r}")

    @classmethod
    def from_service(cls, service: Any) -> RetaskLimits:
        """The limits of a config's ``service`` section (a mapping or None; absent keys:
        the defaults), ConfigError naming an unknown key."""
        raw = (service or {}).get("retask_limits") if isinstance(service, Mapping) else None
        if raw is None:
            return cls()
        if not isinstance(raw, Mapping):
            raise ConfigError("service.retask_limits: expected a mapping")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(raw) - known)
        if unknown:
            raise ConfigError(f"service.retask_limits: unknown key {unknown[0]!r} (expected "
                              f"{', '.join(sorted(known))})")
        return cls(**raw)


@dataclass(frozen=True, slots=True)
class BoundsVerdict:
    """What is out of bounds: one line per item (at most MAX_REASONS) and how many items
    in all; ``ok`` when none."""

    reasons: tuple[str, ...]
    n_out: int

    @property
    def ok(self) -> bool:
        return self.n_out == 0

    def text(self) -> str:
        more = self.n_out - len(self.reasons)
        return "; ".join(self.reasons) + (f"; and {more} more" if more > 0 else "")


def _altitude_above_home_m(it: MissionItem, home: Origin) -> float:
    return it.z_m - home.ground_alt_msl_m if it.frame == MAV_FRAME_GLOBAL else it.z_m


def check_mission_bounds(items: Sequence[MissionItem], boundary_enu_m: Polygon, home: Origin,
                         limits: RetaskLimits) -> BoundsVerdict:
    """The items (no ArduPilot home item) against ``limits`` (module docstring):
    ``boundary_enu_m`` the domain boundary (ENU m about ``home``'s lat/lon)."""
    reasons: list[str] = []
    if len(items) > limits.max_items:
        reasons.append(f"{len(items)} items, the limit is {limits.max_items}")
    allowed = boundary_enu_m.buffer(limits.margin_m)
    shapely.prepare(allowed)
    for i, it in enumerate(items):
        why = _item_reason(it, allowed, home, limits)
        if why is not None:
            reasons.append(f"item {i}: {why}")
    return BoundsVerdict(tuple(reasons[:MAX_REASONS]), len(reasons))


def _item_reason(it: MissionItem, allowed: Any, home: Origin, limits: RetaskLimits
                 ) -> str | None:
    if it.command == MAV_CMD_DO_CHANGE_SPEED:
        speed = it.param2
        if math.isfinite(speed) and speed > limits.max_speed_m_s:
            return f"speed {speed:g} m/s, the limit is {limits.max_speed_m_s:g} m/s"
        return None
    if it.command not in POSITION_COMMANDS or it.frame not in GLOBAL_FRAMES:
        return None
    here = it.command in (MAV_CMD_NAV_TAKEOFF, MAV_CMD_NAV_LAND) and it.lat_deg == 0 \
        and it.lon_deg == 0
    if not here:
        e, n, _ = geodetic_to_enu(it.lat_deg, it.lon_deg, home.ground_alt_msl_m, home)
        if not shapely.contains_xy(allowed, float(e), float(n)):
            distance = shapely.distance(allowed, shapely.Point(float(e), float(n)))
            return (f"{distance:.0f} m outside the domain grown by {limits.margin_m:g} m "
                    f"(ENU {float(e):.0f}, {float(n):.0f} m)")
    if it.command == MAV_CMD_NAV_LAND:
        return None
    alt = _altitude_above_home_m(it, home)
    if not limits.min_alt_m <= alt <= limits.max_alt_m:
        above = "above the terrain" if it.frame == MAV_FRAME_GLOBAL_TERRAIN_ALT \
            else "above home"
        return (f"{alt:.1f} m {above}, the limits are {limits.min_alt_m:g} to "
                f"{limits.max_alt_m:g} m")
    return None

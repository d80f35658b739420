"""The DEM cross-check: the mission's DEM against what the aircraft measures (``TerrainCheck``).

A wrong DEM or vertical datum is the commonest terrain error, and it moves every cell's
pixel size and line of sight. Three measurements say where the ground is:

* the autopilot's terrain database (TERRAIN_REPORT, DataFlash TERR): the ground's height
  m AMSL at a point;
* a downward rangefinder (DISTANCE_SENSOR, RFND, ULog distance_sensor, orientation 25): the
  distance along the body's down axis to the ground. The ground point it measured is the
  vehicle's position (interpolated at the reading, m AMSL) plus that distance along the axis
  (the attitude interpolated too), so no assumption of flat ground is made; readings tilted
  more than MAX_TILT_DEG are not used (a wide beam then returns its nearest edge, not its
  axis);
* the home position: the vehicle stood on the ground there (m AMSL). A home further than
  ``terrain.max_home_offset_m`` from the DEM refuses the DEM (``home_refused``): every
  cell's height above ground would be off by as much, so the daemon counts no frame over
  it and evaluate stops (a wrong map is worse than none).

Each gives a difference, always the DEM's height minus the aircraft's (m; +12: the DEM is
12 m too high, or the aircraft's altitudes 12 m too low). A difference beyond the margin
(``terrain.check_margin_m``) is a mismatch: counted, with the latest and the largest.

The same object checks a link live (``LiveCoverage`` feeds it every sample in arrival order)
and a whole log offline (``check_flight_log`` feeds it the log's samples in time order), so
both give the same counts for the same telemetry. Pure: numpy and the core; the DEM is any
object with ``height_msl_m(lat_deg, lon_deg)`` (``core.dem.Dem``), NaN outside it.
"""

from __future__ import annotations

import bisect
import math
from collections import Counter, deque
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from pdcov.config.terrain import DEFAULT_TERRAIN_MARGIN_M
from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.core.rotations import R_from_quat_wxyz
from pdcov.telemetry.frame_policy import TextEnum
from pdcov.telemetry.samples import (
    MAV_SENSOR_ROTATION_PITCH_270,
    AttitudeSample,
    HomeSample,
    PositionSample,
    RangefinderSample,
    Sample,
    TerrainReportSample,
)

if TYPE_CHECKING:
    from pdcov.config.mission import Mission
    from pdcov.telemetry.logs import FlightLog

__all__ = ["CheckSource", "HeightsMsl", "Mismatch", "Refused",
           "TerrainCheck", "check_flight_log", "terrain_check_for"]

MAX_TILT_DEG = 30.0
"""Rangefinder readings whose axis is tilted more than this from the vertical are not used."""
MAX_BRACKET_S = 1.0
"""A reading is placed between position (and attitude) samples at most this far apart (s)."""
HISTORY_S = 10.0
"""Position and attitude samples kept for readings still to place (s of autopilot time)."""
MAX_PENDING = 1000
"""Readings waiting for the position after them; beyond, the oldest are refused."""


class HeightsMsl(Protocol):
    """A DEM: ground heights m AMSL at WGS84 degrees, bilinear, NaN outside or in nodata."""

    def height_msl_m(self, lat_deg: Any, lon_deg: Any) -> np.ndarray: ...


class CheckSource(TextEnum):
    """What the aircraft measured the ground with."""

    TERRAIN_REPORT = "terrain_report"
    RANGEFINDER = "rangefinder"
    HOME = "home"


class Refused(TextEnum):
    """Why a measurement was not compared (counted in ``refused``)."""

    NO_TERRAIN_DATA = "terrain report without data"
    NOT_DOWNWARD = "rangefinder not downward"
    OUT_OF_RANGE = "rangefinder out of range"
    TILTED = "rangefinder tilted"
    NO_POSE = "rangefinder without position"
    NOT_FINITE = "not finite"
    OUTSIDE_DEM = "outside the DEM"


@dataclass(frozen=True, slots=True)
class Mismatch:
    """One disagreement: difference_m = DEM height minus the aircraft's (m), at the ground
    point measured (WGS84 degrees) and time t_s (autopilot clock, s; NaN for a home or
    terrain report before the autopilot's first time: they need none)."""

    source: CheckSource
    difference_m: float
    lat_deg: float
    lon_deg: float
    t_s: float

    def as_dict(self) -> dict[str, Any]:
        return {"source": str(self.source), "difference_m": round(self.difference_m, 2),
                "lat_deg": round(self.lat_deg, 7), "lon_deg": round(self.lon_deg, 7),
                "t_s": round(self.t_s, 3) if math.isfinite(self.t_s) else None}

    def describe(self) -> str:
        when = f", t {self.t_s:.1f} s" if math.isfinite(self.t_s) else ""
        return (f"{self.difference_m:+.1f} m ({self.source} at {self.lat_deg:.6f}, "
                f"{self.lon_deg:.6f}{when})")


@dataclass(frozen=True, slots=True)
class _Fix:
    """A position (deg, m AMSL) or attitude (unit quaternion w, x, y, z) at t_s."""

    t_s: float
    values: tuple[float, ...]


class _Track:
    """Time-sorted samples of one stream within HISTORY_S of its newest; equal times: the
    later sample replaces the earlier (as ``series`` keeps them)."""

    def __init__(self) -> None:
        self.t_s: list[float] = []
        self.fixes: list[_Fix] = []

    @property
    def newest_t_s(self) -> float:
        return self.t_s[-1] if self.t_s else -math.inf

    def add(self, fix: _Fix) -> None:
        i = bisect.bisect_left(self.t_s, fix.t_s)
        if i < len(self.t_s) and self.t_s[i] == fix.t_s:
            self.fixes[i] = fix
        else:
            self.t_s.insert(i, fix.t_s)
            self.fixes.insert(i, fix)
        old = bisect.bisect_left(self.t_s, self.t_s[-1] - HISTORY_S) - 1
        if old > 0:
            del self.t_s[:old], self.fixes[:old]

    def bracket(self, t_s: float) -> tuple[_Fix, _Fix, float] | None:
        """The samples at or before and at or after ``t_s`` and the weight of the later,
        or None when either is missing or they lie more than MAX_BRACKET_S apart."""
        j = bisect.bisect_left(self.t_s, t_s)
        if j == len(self.t_s):
            return None
        after = self.fixes[j]
        if after.t_s == t_s:
            return after, after, 0.0
        if j == 0 or after.t_s - self.t_s[j - 1] > MAX_BRACKET_S:
            return None
        before = self.fixes[j - 1]
        return before, after, (t_s - before.t_s) / (after.t_s - before.t_s)


class TerrainCheck:
    """The DEM's heights against the aircraft's measurements (module docstring).

    ``add(sample)`` takes every telemetry sample (the others are ignored); then
    ``checked`` {CheckSource: n compared}, ``refused`` {Refused: n}, ``mismatches`` (beyond
    margin_m, m), ``largest`` and ``latest`` (Mismatch or None) say what was found.
    """

    def __init__(self, dem: HeightsMsl, margin_m: float = DEFAULT_TERRAIN_MARGIN_M,
                 max_home_offset_m: float = math.inf) -> None:
        if not (math.isfinite(margin_m) and margin_m > 0):
            raise ValueError(f"terrain check margin: expected a positive number of metres, "
                             f"got {margin_m}")
        self.dem = dem
        self.margin_m = float(margin_m)
        self.max_home_offset_m = float(max_home_offset_m)
        self.home_refused: Mismatch | None = None
        """The first home beyond max_home_offset_m from the DEM (None: none so far)."""
        self.checked: Counter[CheckSource] = Counter()
        self.refused: Counter[Refused] = Counter()
        self.mismatches = 0
        self.largest: Mismatch | None = None
        self.latest: Mismatch | None = None
        self._positions = _Track()
        self._attitudes = _Track()
        self._pending: deque[RangefinderSample] = deque()
        self._last_home: tuple[float, float, float] | None = None

    # --- samples in -----------------------------------------------------------------------

    def add(self, sample: Sample) -> None:
        """One sample, in arrival order (live) or time order (a log)."""
        if isinstance(sample, PositionSample):
            fix = (sample.lat_deg, sample.lon_deg, sample.alt_msl_m)
            if math.isfinite(sample.t_s) and all(map(math.isfinite, fix)):
                self._positions.add(_Fix(sample.t_s, fix))
                self._place_pending()
        elif isinstance(sample, AttitudeSample):
            q = sample.q_ned_body_wxyz
            norm = math.sqrt(sum(v * v for v in q))
            if math.isfinite(sample.t_s) and math.isfinite(norm) and norm > 0.5:
                self._attitudes.add(_Fix(sample.t_s, tuple(v / norm for v in q)))
                self._place_pending()
        elif isinstance(sample, TerrainReportSample):
            self._terrain_report(sample)
        elif isinstance(sample, RangefinderSample):
            self._rangefinder(sample)
        elif isinstance(sample, HomeSample):
            self._home(sample)

    def _terrain_report(self, r: TerrainReportSample) -> None:
        if not r.has_data:
            self.refused[Refused.NO_TERRAIN_DATA] += 1
        elif not all(map(math.isfinite, (r.lat_deg, r.lon_deg, r.terrain_alt_msl_m))):
            self.refused[Refused.NOT_FINITE] += 1
        else:
            self._compare(CheckSource.TERRAIN_REPORT, r.lat_deg, r.lon_deg,
                          r.terrain_alt_msl_m, r.t_s)

    def _home(self, h: HomeSample) -> None:
        key = (h.lat_deg, h.lon_deg, h.alt_msl_m)
        if key == self._last_home:
            return  # HOME_POSITION repeats at 0.2 Hz: each home is compared once
        self._last_home = key
        if not all(map(math.isfinite, key)):
            self.refused[Refused.NOT_FINITE] += 1
            return
        self._compare(CheckSource.HOME, h.lat_deg, h.lon_deg, h.alt_msl_m, h.t_s)

    def _rangefinder(self, r: RangefinderSample) -> None:
        if r.orientation != MAV_SENSOR_ROTATION_PITCH_270:
            self.refused[Refused.NOT_DOWNWARD] += 1
        elif not (math.isfinite(r.distance_m) and math.isfinite(r.t_s)):
            self.refused[Refused.NOT_FINITE] += 1
        elif not r.in_range or r.distance_m <= 0:
            self.refused[Refused.OUT_OF_RANGE] += 1
        else:
            if len(self._pending) >= MAX_PENDING:
                self._pending.popleft()
                self.refused[Refused.NO_POSE] += 1
            self._pending.append(r)
            self._place_pending()

    def _place_pending(self) -> None:
        """Compare the waiting readings that a position and an attitude at or after them
        now bracket (the samples before them are in: telemetry comes in order)."""
        newest = min(self._positions.newest_t_s, self._attitudes.newest_t_s)
        while self._pending and self._pending[0].t_s <= newest:
            self._place(self._pending.popleft())

    def _place(self, r: RangefinderSample) -> None:
        pos, att = self._positions.bracket(r.t_s), self._attitudes.bracket(r.t_s)
        if pos is None or att is None:
            self.refused[Refused.NO_POSE] += 1
            return
        p0, p1, w = pos
        lat, lon, alt = (a + w * (b - a) for a, b in zip(p0.values, p1.values, strict=True))
        a0, a1, wq = att
        q1 = np.asarray(a1.values)
        q = (1.0 - wq) * np.asarray(a0.values) + wq * (q1 if np.dot(a0.values, q1) >= 0
                                                       else -q1)
        axis_ned = R_from_quat_wxyz(q)[:, 2]  # the body's down (FRD z) axis, in NED
        if axis_ned[2] < math.cos(math.radians(MAX_TILT_DEG)):
            self.refused[Refused.TILTED] += 1
            return
        d = r.distance_m
        hit = enu_to_geodetic(np.array([d * axis_ned[1], d * axis_ned[0], -d * axis_ned[2]]),
                              Origin(lat, lon, alt))
        self._compare(CheckSource.RANGEFINDER, float(hit[0]), float(hit[1]), float(hit[2]),
                      r.t_s)

    def _compare(self, source: CheckSource, lat_deg: float, lon_deg: float,
                 ground_alt_msl_m: float, t_s: float) -> None:
        dem_m = float(np.asarray(self.dem.height_msl_m(lat_deg, lon_deg), float).reshape(-1)[0])
        if not math.isfinite(dem_m):
            self.refused[Refused.OUTSIDE_DEM] += 1
            return
        self.checked[source] += 1
        diff = dem_m - ground_alt_msl_m
        if abs(diff) <= self.margin_m:
            return
        m = Mismatch(source, diff, lat_deg, lon_deg, t_s)
        if (source == CheckSource.HOME and self.home_refused is None
                and abs(diff) > self.max_home_offset_m):
            self.home_refused = m
        self.mismatches += 1
        self.latest = m
        if self.largest is None or abs(diff) > abs(self.largest.difference_m):
            self.largest = m

    # --- what it found --------------------------------------------------------------------

    def as_dict(self) -> dict[str, Any]:
        """The status's and metrics.json's ``terrain_check`` object (docs/protocol.md)."""
        return {"margin_m": self.margin_m,
                "checked": {str(s): self.checked[s] for s in CheckSource},
                "mismatches": self.mismatches,
                "refused": {str(k): n for k, n in sorted(self.refused.items())},
                "largest": None if self.largest is None else self.largest.as_dict(),
                "latest": None if self.latest is None else self.latest.as_dict()}

    def home_refusal(self) -> str | None:
        """Why the DEM is refused (a home beyond max_home_offset_m), None when it is not."""
        m = self.home_refused
        if m is None:
            return None
        return (f"terrain check: the home is {-m.difference_m:+.1f} m from the DEM's height "
                f"there ({m.lat_deg:.6f}, {m.lon_deg:.6f}), more than "
                f"terrain.max_home_offset_m = {self.max_home_offset_m:g} m: no coverage is "
                "counted over this DEM; fix the DEM's datum (terrain.vertical_datum, "
                "geoid_height_m) or the DEM, or raise terrain.max_home_offset_m if it is "
                "known to be off")

    def summary_line(self) -> str:
        """One line: counts and the largest difference."""
        n = sum(self.checked.values())
        what = ", ".join(f"{self.checked[s]} {s}" for s in CheckSource if self.checked[s])
        refused = ", ".join(f"{k}: {v}" for k, v in sorted(self.refused.items()))
        tail = f"; not compared: {refused}" if refused else ""
        if n == 0:
            return ("terrain check: no terrain report, downward rangefinder reading or home "
                    f"to compare with the DEM{tail}")
        if self.largest is None:
            return (f"terrain check: {n} measurements ({what}) agree with the DEM within "
                    f"{self.margin_m:g} m{tail}")
        return (f"terrain check: {self.mismatches} of {n} measurements ({what}) disagree with "
                f"the DEM by more than {self.margin_m:g} m, largest "
                f"{self.largest.describe()}, DEM minus aircraft{tail}")

    def warning(self) -> str | None:
        """The daemon's log line for the latest mismatch (and what to check); None before
        the first."""
        if self.latest is None or self.largest is None:
            return None
        return (f"terrain check: DEM minus the aircraft's ground {self.latest.describe()}, "
                f"beyond the margin of {self.margin_m:g} m; {self.mismatches} "
                f"disagreements so far, largest "
                f"{self.largest.difference_m:+.1f} m: check the DEM's vertical datum "
                "(terrain.vertical_datum, geoid_height_m), that it is the DEM of this site, "
                "and the barometer's drift (docs/operations.md)")


def check_flight_log(check: TerrainCheck, log: FlightLog) -> None:
    """Feed ``check`` a whole log's samples in time order (of equal times: positions,
    attitudes, then the measurements), as the daemon receives them."""
    events: list[tuple[float, int, Sample]] = []
    pos, att = log.position, log.attitude
    events += [(float(t), 0, PositionSample(float(t), float(la), float(lo), float(al)))
               for t, la, lo, al in zip(pos.t_s, pos.lat_deg, pos.lon_deg, pos.alt_msl_m,
                                        strict=True)]
    events += [(float(t), 0, AttitudeSample(float(t), (float(q[0]), float(q[1]), float(q[2]),
                                                       float(q[3]))))
               for t, q in zip(att.t_s, att.q_ned_body_wxyz, strict=True)]
    measured: Iterable[Sample] = (*log.homes, *log.terrain_reports, *log.rangefinder)
    events += [(s.t_s, 1, s) for s in measured]
    for _t, _k, sample in sorted(events, key=lambda e: (e[0], e[1])):
        check.add(sample)


def terrain_check_for(mission: Mission) -> TerrainCheck | None:
    """The check of a mission with a DEM (``mission.dem``, margin
    ``mission.terrain_check_margin_m``, home refused beyond
    ``mission.terrain_max_home_offset_m``), None without one: what both drivers build."""
    if mission.dem is None:
        return None
    return TerrainCheck(mission.dem, mission.terrain_check_margin_m,
                        mission.terrain_max_home_offset_m)

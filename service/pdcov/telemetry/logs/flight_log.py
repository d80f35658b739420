"""The flight log pdcov reads: ``FlightLog``, one vehicle's time-sorted telemetry series.

Times are seconds in the autopilot's boot clock, monotonic across restarts; positions lat/lon
degrees and altitude m AMSL, attitudes quaternions (body FRD -> NED), as ``samples`` holds
them. Also the small parts every reader shares: the time shift, the restart note and the
estimator series with its source.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import TypeVar

from pdcov.telemetry.clocks import REBOOT_GAP_S
from pdcov.telemetry.recorded_frames import RecordedBox
from pdcov.telemetry.sample_gate import SampleGate
from pdcov.telemetry.samples import (
    CaptureSample,
    EstimatorSample,
    GimbalSample,
    HomeSample,
    LensSample,
    RangefinderSample,
    Sample,
    TerrainReportSample,
    UtcSample,
)
from pdcov.telemetry.series import (
    AttitudeSeries,
    EstimatorSeries,
    GimbalSeries,
    GnssAccuracySeries,
    MountTargetSeries,
    PositionSeries,
)

_Sample = TypeVar("_Sample", bound=Sample)
_Series = TypeVar("_Series", AttitudeSeries, PositionSeries, GimbalSeries, MountTargetSeries,
                   EstimatorSeries, GnssAccuracySeries)


@dataclass(frozen=True, slots=True)
class FlightLog:
    """What pdcov uses of one flight log, for one vehicle (``system_id``).

    All times are seconds in the autopilot's boot clock (monotonic across restarts). gimbal
    holds the chosen source (``gimbal_source`` = (system, component, gimbal_device_id)) only;
    homes are in log order; params hold each parameter's last value. notes say, in words,
    which clock, sources and fallbacks were used (for summaries); damage says what was
    skipped or cut while reading (also among the notes). estimator: the position
    estimator's verdicts (empty when the log carries none); estimator_source names the
    messages they came from. terrain_reports and rangefinder: the autopilot's terrain
    database reports and rangefinder readings (any orientation), in log order, for the
    DEM cross-check (``terrain_check``). boxes: the detector boxes ``pdcov serve``
    recorded with its frames (recorded_frames; a tlog's only), stamped as their frames'
    capture events. lens: the cameras' zoom reports (CAMERA_FOV_STATUS, CAMERA_SETTINGS,
    CAMERA_INFORMATION; a tlog's only), in log order. gnss_accuracy: the accuracy the
    autopilot's GNSS receiver reported (GPS_RAW_INT, GPA, vehicle_gps_position; empty when
    the log carries none). faults: the bad messages and samples counted while reading, by
    the daemon's fault keys (a tlog's: telemetry/sample_gate.py, rejected_messages,
    other_systems_messages; only those counted). gimbal_reports: every gimbal report of
    the vehicle (any device; ``gimbal`` follows one: choose.for_gimbal follows another),
    autopilot_component: the followed autopilot's MAVLink component (1 for other logs).
    armed_states: (t_s, armed) where the autopilot's armed state is first known and where
    it changes (a tlog's HEARTBEATs, DataFlash ARM / EV records, ULog vehicle_status; t_s
    -inf: known from the log's start); None: the log tells none (as a link without
    HEARTBEAT). utc: the autopilot's real-time clock beside its boot clock, in log order
    (SYSTEM_TIME, DataFlash GPS GWk/GMS, ULog vehicle_gps_position time_utc_usec), for
    core/utc_clock.UtcClock.
    """

    path: str
    format: str
    system_id: int | None
    attitude: AttitudeSeries
    position: PositionSeries
    gimbal: GimbalSeries
    gimbal_source: tuple[int, int, int] | None
    homes: tuple[HomeSample, ...]
    captures: tuple[CaptureSample, ...]
    params: Mapping[str, float]
    mount_targets: MountTargetSeries
    restarts_t_s: tuple[float, ...] = ()
    notes: tuple[str, ...] = ()
    damage: tuple[str, ...] = ()
    estimator: EstimatorSeries = field(
        default_factory=lambda: EstimatorSeries.from_samples([]))
    estimator_source: str = ""
    terrain_reports: tuple[TerrainReportSample, ...] = ()
    rangefinder: tuple[RangefinderSample, ...] = ()
    boxes: tuple[RecordedBox, ...] = ()
    lens: tuple[LensSample, ...] = ()
    gnss_accuracy: GnssAccuracySeries = field(
        default_factory=lambda: GnssAccuracySeries.from_samples([]))
    faults: Mapping[str, int] = field(default_factory=dict)
    gimbal_reports: tuple[GimbalSample, ...] = ()
    autopilot_component: int = 1
    armed_states: tuple[tuple[float, bool], ...] | None = None
    utc: tuple[UtcSample, ...] = ()



def gated(gate: SampleGate, samples: Iterable[_Sample]) -> list[_Sample]:
    """The ``samples`` (time order) the sample gate admits, the others counted in its
    faults: the daemon's checks (telemetry/sample_gate.py), for the readers whose log is
    no MAVLink stream (DataFlash, ULog)."""
    return [s for s in samples if gate.admit(s)]


def armed_changes(states: Iterable[tuple[float, bool]]
                  ) -> tuple[tuple[float, bool], ...] | None:
    """The first of ``states`` ((t_s, armed), time order) and those that change it; None
    without any."""
    out: list[tuple[float, bool]] = []
    for t_s, armed in states:
        if not out or out[-1][1] != armed:
            out.append((t_s, armed))
    return tuple(out) if out else None


def estimator_series(samples: list[EstimatorSample], source: str
                     ) -> tuple[EstimatorSeries, str]:
    """The series of ``samples`` and its ``source``, no source when empty."""
    series = EstimatorSeries.from_samples(samples)
    return series, source if len(series.t_s) else ""



def restart_note(n: int, field_name: str) -> str:
    return (f"{field_name} restarted {n}x (autopilot reboot): t_s is the last boot's own time; "
            f"earlier boots are placed before it with a {REBOOT_GAP_S:.0f} s gap, so no frame "
            "interpolates across a reboot")


def shifted(log: FlightLog, dt_s: float) -> FlightLog:
    """The same log with every time moved by ``dt_s`` seconds."""
    if dt_s == 0.0:
        return log

    def series(x: _Series) -> _Series:
        return replace(x, t_s=x.t_s + dt_s)

    return replace(log, attitude=series(log.attitude), position=series(log.position),
                   gimbal=series(log.gimbal), mount_targets=series(log.mount_targets),
                   estimator=series(log.estimator),
                   gnss_accuracy=series(log.gnss_accuracy),
                   homes=tuple(replace(h, t_s=h.t_s + dt_s) for h in log.homes),
                   captures=tuple(replace(c, t_s=c.t_s + dt_s) for c in log.captures),
                   terrain_reports=tuple(replace(r, t_s=r.t_s + dt_s)
                                         for r in log.terrain_reports),
                   rangefinder=tuple(replace(r, t_s=r.t_s + dt_s) for r in log.rangefinder),
                   boxes=tuple(replace(b, t_s=b.t_s + dt_s) for b in log.boxes),
                   gimbal_reports=tuple(replace(g, t_s=g.t_s + dt_s)
                                        for g in log.gimbal_reports),
                   lens=tuple(replace(s, t_s=s.t_s + dt_s) for s in log.lens),
                   utc=tuple(replace(u, t_s=u.t_s + dt_s) for u in log.utc),
                   restarts_t_s=tuple(t + dt_s for t in log.restarts_t_s),
                   armed_states=None if log.armed_states is None else
                   tuple((t + dt_s, a) for t, a in log.armed_states))

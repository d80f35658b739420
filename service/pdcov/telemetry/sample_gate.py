"""Which telemetry samples are fit to use: ``SampleGate``, one rule for the link and for logs.

The daemon (service/coverage.py) and the .tlog reader (telemetry/logs/tlog.py) pass every
sample ``LinkProtocol.receive`` returns through one gate, in arrival (log) order, and count
what it refuses under the same fault keys (the status's ``faults``, evaluate's report):
``untimed_samples`` (no time in the autopilot clock yet: another component's sample before
the autopilot's first timed message), ``nan_samples`` (an attitude or gimbal quaternion that
is no rotation, a position with a NaN), ``invalid_samples`` (a latitude or longitude out of
range, a home without a finite altitude). Counted but kept: ``position_jumps`` (faster than
pose_tracker.MAX_SPEED_MPS from the previous position: the tracker skips the frames between)
and ``gimbal_failures`` (a gimbal report with failure flags set).
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np

from pdcov.bus.faults import Fault
from pdcov.core.geodesy import Origin, geodetic_to_enu
from pdcov.telemetry.pose_tracker import MAX_SPEED_MPS, POSITION_JUMP_SLACK_M
from pdcov.telemetry.samples import (
    AttitudeSample,
    GimbalSample,
    HomeSample,
    PositionSample,
    Sample,
    usable_quaternion,
)

__all__ = ["SampleGate", "position_jump", "valid_home"]


def valid_home(home: HomeSample) -> bool:
    """A home with a finite altitude and a latitude and longitude in range (the gate
    admits no other, once timed)."""
    return (math.isfinite(home.alt_msl_m) and abs(home.lat_deg) <= 90
            and abs(home.lon_deg) <= 180)


def position_jump(a: PositionSample, b: PositionSample) -> bool:
    """True when the reported position moved faster than pose_tracker.MAX_SPEED_MPS (+
    slack) from sample ``a`` to the later sample ``b``: the rule ``PoseTracker.frames_at``
    skips frames by, for counting."""
    dt = b.t_s - a.t_s
    if not dt > 0:
        return False
    limit_m = MAX_SPEED_MPS * dt + POSITION_JUMP_SLACK_M
    # A bound on the straight-line step, cheap (the log's every sample comes here): along
    # the meridian, then the parallel (radius of curvature at most 6.4e6 m), then up.
    r_m = 6.4e6 + max(abs(a.alt_msl_m), abs(b.alt_msl_m))
    bound_m = (r_m * math.radians(abs(b.lat_deg - a.lat_deg) + abs(b.lon_deg - a.lon_deg))
               + abs(b.alt_msl_m - a.alt_msl_m))
    if bound_m <= limit_m:
        return False
    step = geodetic_to_enu(b.lat_deg, b.lon_deg, b.alt_msl_m,
                           Origin(a.lat_deg, a.lon_deg, a.alt_msl_m))
    return float(np.linalg.norm(step)) > limit_m


class SampleGate:
    """The samples' checks (module docstring); ``faults``: the counter counted into."""

    __slots__ = ("_last_position", "faults")

    def __init__(self, faults: Counter) -> None:
        self.faults = faults
        self._last_position: PositionSample | None = None

    def admit(self, sample: Sample) -> bool:
        """Whether ``sample`` (stamped in the autopilot clock, s) is used; counts it if not."""
        if not math.isfinite(sample.t_s):
            self.faults[Fault.UNTIMED_SAMPLES] += 1
            return False
        if isinstance(sample, AttitudeSample):
            if not usable_quaternion(sample.q_ned_body_wxyz):
                self.faults[Fault.NAN_SAMPLES] += 1
                return False
        elif isinstance(sample, PositionSample):
            return self._position(sample)
        elif isinstance(sample, GimbalSample):
            if sample.failure_flags:
                self.faults[Fault.GIMBAL_FAILURES] += 1
            norm = math.sqrt(sum(v * v for v in sample.q_wxyz))
            if not (math.isfinite(norm) and norm > 0.5):
                self.faults[Fault.NAN_SAMPLES] += 1
                return False
        elif isinstance(sample, HomeSample) and not valid_home(sample):
            self.faults[Fault.INVALID_SAMPLES] += 1
            return False
        return True

    def _position(self, sample: PositionSample) -> bool:
        if not (math.isfinite(sample.lat_deg) and math.isfinite(sample.lon_deg)
                and math.isfinite(sample.alt_msl_m)):
            self.faults[Fault.NAN_SAMPLES] += 1
            return False
        if abs(sample.lat_deg) > 90 or abs(sample.lon_deg) > 180:
            self.faults[Fault.INVALID_SAMPLES] += 1
            return False
        last = self._last_position
        if last is not None and position_jump(last, sample):
            self.faults[Fault.POSITION_JUMPS] += 1
        if last is None or sample.t_s > last.t_s:
            self._last_position = sample
        return True

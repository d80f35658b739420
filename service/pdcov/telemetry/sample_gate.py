"""Which telemetry samples are fit to use: ``SampleGate``, one rule for the link and for logs.

The daemon (service/coverage.py) and the .tlog reader (telemetry/logs/tlog.py) pass every
sample ``LinkProtocol.receive`` returns through one gate, in arrival (log) order, and count
what it refuses under the same fault keys (the status's ``faults``, evaluate's report):
``untimed_samples`` (no time in the autopilot clock yet: another component's sample before
the autopilot's first timed message), ``nan_samples`` (an attitude or gimbal quaternion that
is no rotation, a position with a NaN), ``invalid_samples`` (a latitude or longitude out of
range, a home without a finite altitude). Counted but kept: ``position_jumps`` (faster than
pose_tracker.MAX_SPEED_MPS from the previous position: the tracker skips the frames between)
and ``gimbal_failure_reports`` (a gimbal report with failure flags set).
"""

from __future__ import annotations

import math
from collections import Counter

from pdcov.telemetry.pose_tracker import position_jump
from pdcov.telemetry.samples import (
    AttitudeSample,
    GimbalSample,
    HomeSample,
    PositionSample,
    Sample,
    usable_quaternion,
)

__all__ = ["SampleGate"]


class SampleGate:
    """The samples' checks (module docstring); ``faults``: the counter counted into."""

    __slots__ = ("_last_position", "faults")

    def __init__(self, faults: Counter) -> None:
        self.faults = faults
        self._last_position: PositionSample | None = None

    def admit(self, sample: Sample) -> bool:
        """Whether ``sample`` (stamped in the autopilot clock, s) is used; counts it if not."""
        if not math.isfinite(sample.t_s):
            self.faults["untimed_samples"] += 1
            return False
        if isinstance(sample, AttitudeSample):
            if not usable_quaternion(sample.q_ned_body_wxyz):
                self.faults["nan_samples"] += 1
                return False
        elif isinstance(sample, PositionSample):
            return self._position(sample)
        elif isinstance(sample, GimbalSample):
            if sample.failure_flags:
                self.faults["gimbal_failure_reports"] += 1
            norm = math.sqrt(sum(v * v for v in sample.q_wxyz))
            if not (math.isfinite(norm) and norm > 0.5):
                self.faults["nan_samples"] += 1
                return False
        elif isinstance(sample, HomeSample) and not (
                math.isfinite(sample.alt_msl_m) and abs(sample.lat_deg) <= 90
                and abs(sample.lon_deg) <= 180):
            self.faults["invalid_samples"] += 1
            return False
        return True

    def _position(self, sample: PositionSample) -> bool:
        if not (math.isfinite(sample.lat_deg) and math.isfinite(sample.lon_deg)
                and math.isfinite(sample.alt_msl_m)):
            self.faults["nan_samples"] += 1
            return False
        if abs(sample.lat_deg) > 90 or abs(sample.lon_deg) > 180:
            self.faults["invalid_samples"] += 1
            return False
        last = self._last_position
        if last is not None and position_jump(last, sample):
            self.faults["position_jumps"] += 1
        if last is None or sample.t_s > last.t_s:
            self._last_position = sample
        return True

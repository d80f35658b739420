"""Synthetic MAVLink telemetry logs (.tlog) written from known samples, for tests.

A tlog is a sequence of (8-byte big-endian microseconds wall-clock stamp, MAVLink frame).
``write_tlog`` encodes pdcov's own sample types with pymavlink, so that a test can read the
file back through pdcov and compare with what it wrote. ``samples_from_poses`` turns known
vehicle poses (ENU position, body attitude) into the samples an autopilot would send.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.core.rotations import R_from_quat_wxyz, euler_zyx_from_R, quat_wxyz_from_R
from pdcov.telemetry.samples import (
    AttitudeSample,
    CaptureSample,
    GimbalSample,
    HomeSample,
    ParamSample,
    PositionSample,
)

MAV_TYPE_QUADROTOR = 2
MAV_TYPE_GCS = 6
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_INVALID = 8


class _Sink:
    """File-like object collecting the bytes pymavlink sends."""

    def __init__(self) -> None:
        self.data = b""

    def write(self, data: bytes) -> None:
        self.data += bytes(data)


@dataclass(frozen=True, slots=True)
class Heartbeat:
    """A HEARTBEAT to put in the log at t_s from (system_id, component_id)."""

    t_s: float
    system_id: int = 1
    component_id: int = 1
    autopilot: int = MAV_AUTOPILOT_ARDUPILOTMEGA
    vehicle_type: int = MAV_TYPE_QUADROTOR


def _encoder(system_id: int, component_id: int) -> tuple[mavlink.MAVLink, _Sink]:
    sink = _Sink()
    return mavlink.MAVLink(sink, srcSystem=system_id, srcComponent=component_id), sink


def _ms(t_s: float, boot_offset_s: float) -> int:
    return int(round((t_s - boot_offset_s) * 1000.0))


def encode(sample: object, *, system_id: int = 1, component_id: int = 1,
           boot_offset_s: float = 0.0) -> bytes:
    """One MAVLink frame (bytes) for a pdcov sample or a Heartbeat. time_boot_ms is
    (t_s - boot_offset_s) in ms (a reboot test shifts it)."""
    if isinstance(sample, GimbalSample):
        system_id, component_id = sample.system_id, sample.component_id
    if isinstance(sample, Heartbeat):
        system_id, component_id = sample.system_id, sample.component_id
    mav, sink = _encoder(system_id, component_id)
    ms = _ms(getattr(sample, "t_s", 0.0), boot_offset_s)
    if isinstance(sample, AttitudeSample):
        roll, pitch, yaw = euler_zyx_from_R(R_from_quat_wxyz(sample.q_ned_body_wxyz))
        mav.attitude_send(ms, roll, pitch, yaw, 0.0, 0.0, 0.0)
    elif isinstance(sample, PositionSample):
        rel = 0.0 if np.isnan(sample.relative_alt_m) else sample.relative_alt_m
        mav.global_position_int_send(ms, int(round(sample.lat_deg * 1e7)),
                                     int(round(sample.lon_deg * 1e7)),
                                     int(round(sample.alt_msl_m * 1000)), int(round(rel * 1000)),
                                     0, 0, 0, 0)
    elif isinstance(sample, GimbalSample):
        nan = float("nan")
        mav.gimbal_device_attitude_status_send(0, 0, ms, sample.flags, list(sample.q_wxyz),
                                               nan, nan, nan, sample.failure_flags, nan, nan,
                                               sample.device_id)
    elif isinstance(sample, HomeSample):
        mav.home_position_send(int(round(sample.lat_deg * 1e7)), int(round(sample.lon_deg * 1e7)),
                               int(round(sample.alt_msl_m * 1000)), 0, 0, 0, [1, 0, 0, 0],
                               0, 0, 0)
    elif isinstance(sample, ParamSample):
        mav.param_value_send(sample.name.encode(), sample.value, 9, 1, 0)
    elif isinstance(sample, CaptureSample):
        mav.camera_image_captured_send(ms, 0, 0, 0, 0, 0, 0, [1, 0, 0, 0], sample.image_index,
                                       1, b"")
    elif isinstance(sample, Heartbeat):
        mav.heartbeat_send(sample.vehicle_type, sample.autopilot, 0, 0, 4)
    else:
        raise TypeError(f"cannot encode {sample!r}")
    return sink.data


def tlog_bytes(samples: Iterable[object], *, boot_offset_s: float = 0.0,
               wall_clock_scale: float = 1.0) -> bytes:
    """The bytes of a tlog holding ``samples`` in time order; the wall-clock stamps are
    1.7e9 s + wall_clock_scale * t_s (a fast recording has a scale < 1)."""
    out = []
    for s in sorted(samples, key=lambda s: getattr(s, "t_s", 0.0)):
        stamp_us = int((1.7e9 + wall_clock_scale * getattr(s, "t_s", 0.0)) * 1e6)
        out.append(struct.pack(">Q", stamp_us) + encode(s, boot_offset_s=boot_offset_s))
    return b"".join(out)


def write_tlog(path: str | Path, samples: Iterable[object], *, heartbeat: bool = True,
               prefix: bytes = b"", **kwargs: float) -> Path:
    """Write a tlog of ``samples`` (pdcov sample types and Heartbeat) to ``path``: an
    autopilot HEARTBEAT first unless ``heartbeat`` is False, after ``prefix`` bytes (junk)."""
    samples = list(samples)
    if heartbeat:
        t0 = min((getattr(s, "t_s", 0.0) for s in samples), default=0.0)
        samples.insert(0, Heartbeat(t0))
    path = Path(path)
    path.write_bytes(prefix + tlog_bytes(samples, **kwargs))
    return path


@dataclass(frozen=True, slots=True)
class KnownFlight:
    """Known vehicle and gimbal states at times t_s (N,): R_ned_body (N, 3, 3), r_body_enu
    (N, 3) m, gimbal quaternions q_gimbal_wxyz (N, 4) with flags (N,) or None."""

    origin: Origin
    t_s: np.ndarray
    R_ned_body: np.ndarray
    r_body_enu: np.ndarray
    q_gimbal_wxyz: np.ndarray | None = None
    gimbal_flags: Sequence[int] | None = None


def samples_from_flight(flight: KnownFlight, *, home: bool = True) -> list[object]:
    """ATTITUDE, GLOBAL_POSITION_INT (and gimbal status, HOME_POSITION) samples of a flight."""
    geo = enu_to_geodetic(flight.r_body_enu, flight.origin)
    out: list[object] = []
    for i, t in enumerate(flight.t_s):
        out.append(AttitudeSample(float(t), tuple(quat_wxyz_from_R(flight.R_ned_body[i]))))
        out.append(PositionSample(float(t), float(geo[i, 0]), float(geo[i, 1]),
                                  float(geo[i, 2]), float(flight.r_body_enu[i, 2])))
        if flight.q_gimbal_wxyz is not None:
            out.append(GimbalSample(float(t), tuple(flight.q_gimbal_wxyz[i]),
                                    int(flight.gimbal_flags[i]), 0, 1, 1, 1))
    if home:
        out.append(HomeSample(float(flight.t_s[0]), flight.origin.lat_deg, flight.origin.lon_deg,
                              flight.origin.ground_alt_msl_m, "HOME_POSITION"))
    return out

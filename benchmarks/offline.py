"""The offline commands, timed end to end in a child process: ``pdcov evaluate`` on a
scenario's flight (as a pose CSV and as a MAVLink telemetry log) and ``pdcov optimise``.

The flight files are written into a temporary folder at benchmark time, never committed.
"""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from pymavlink.dialects.v20 import common as mavlink

from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.core.rotations import euler_zyx_from_R_many
from pdcov.telemetry.pose_csv import POSE_CSV_COLUMNS
from tests.support.scenarios import ORIGIN_LAT_DEG, ORIGIN_LON_DEG, Scenario

TELEMETRY_RATE_HZ = 10.0  # ATTITUDE and GLOBAL_POSITION_INT, a usual stream rate
MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_ARDUPILOTMEGA = 2, 3

# Runs the pdcov console script in this child, pinned to one CPU (the target is "on one
# core"; OpenCV would otherwise use every core), and reports its peak resident memory.
# VmHWM, not getrusage's ru_maxrss: Linux carries ru_maxrss across fork and exec, so a child
# of the (large) benchmark process would report the parent's peak.
_CHILD = ("import os, sys\n"
          "os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})\n"
          "from pdcov.cli import main\n"
          "rc = main(sys.argv[1:])\n"
          "hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM:')]\n"
          "print('peak_rss_kib', hwm[0].split()[1], file=sys.stderr)\n"
          "sys.exit(rc)\n")


@dataclass(frozen=True)
class CommandRun:
    """Wall time (s) and peak resident memory (bytes) of one pdcov command."""

    wall_s: float
    peak_rss_bytes: int
    stdout: str


def run_pdcov(args: list[str]) -> CommandRun:
    """Run ``pdcov ARGS`` in a child Python; raises RuntimeError with its output on failure."""
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", _CHILD, *args], capture_output=True,
                          text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"pdcov {' '.join(args)} failed ({proc.returncode}):\n"
                           f"{proc.stdout}\n{proc.stderr}")
    kib = [int(line.split()[1]) for line in proc.stderr.splitlines()
           if line.startswith("peak_rss_kib ")]
    return CommandRun(wall, kib[-1] * 1024 if kib else 0, proc.stdout)


def write_mission(path: Path, scenario: Scenario) -> Path:
    path.write_text(yaml.safe_dump(scenario.mission_doc(), sort_keys=False))
    return path


def write_pose_csv(path: Path, scenario: Scenario) -> Path:
    """The scenario's camera poses as a pose CSV (t_s, ENU centre, R_enu_cam quaternion)."""
    rows = [[p.t_s, *p.r_cam_enu, *p.q_enu_cam_wxyz] for p in scenario.poses()]
    np.savetxt(path, np.array(rows), delimiter=",", fmt="%.9g",
               header=",".join(POSE_CSV_COLUMNS), comments="")
    return path


def write_tlog(path: Path, scenario: Scenario) -> Path:
    """The scenario's flight as the telemetry log a ground station records: HEARTBEAT and
    HOME_POSITION, then ATTITUDE and GLOBAL_POSITION_INT at ``TELEMETRY_RATE_HZ``, each
    record an 8-byte big-endian microsecond stamp and a MAVLink 2 frame."""
    flight = scenario.flight(TELEMETRY_RATE_HZ)
    keep = flight.t_s <= scenario.duration_s + 1.0
    t_s = flight.t_s[keep]
    rpy = euler_zyx_from_R_many(flight.R_ned_body[keep])
    geo = enu_to_geodetic(flight.r_body_enu[keep], Origin(ORIGIN_LAT_DEG, ORIGIN_LON_DEG, 0.0))
    sink = _Sink()
    mav = mavlink.MAVLink(sink, srcSystem=1, srcComponent=1)
    records = []

    def record(t: float, send: object, *fields: object) -> None:
        send(*fields)  # type: ignore[operator]
        records.append(struct.pack(">Q", int((1.7e9 + t) * 1e6)) + sink.take())

    record(0.0, mav.heartbeat_send, MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4)
    record(0.0, mav.home_position_send, int(round(ORIGIN_LAT_DEG * 1e7)),
           int(round(ORIGIN_LON_DEG * 1e7)), 0, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0)
    for t, (roll, pitch, yaw), (lat, lon, alt) in zip(t_s, rpy, geo, strict=True):
        ms = int(round(t * 1000))
        record(t, mav.attitude_send, ms, roll, pitch, yaw, 0.0, 0.0, 0.0)
        record(t, mav.global_position_int_send, ms, int(round(lat * 1e7)),
               int(round(lon * 1e7)), int(round(alt * 1000)), int(round(alt * 1000)),
               0, 0, 0, 0)
    path.write_bytes(b"".join(records))
    return path


class _Sink:
    """The file-like object pymavlink writes each frame to."""

    def __init__(self) -> None:
        self._data = bytearray()

    def write(self, data: bytes) -> None:
        self._data += data

    def take(self) -> bytes:
        out = bytes(self._data)
        self._data.clear()
        return out


def evaluate_run(folder: Path, scenario: Scenario, source: str) -> CommandRun:
    """``pdcov evaluate`` on the scenario's flight from a pose CSV (``source`` 'csv') or a
    tlog ('tlog'), the files written into ``folder`` first (not timed)."""
    mission = write_mission(folder / "mission.yaml", scenario)
    if source == "csv":
        flight = ["--poses", str(write_pose_csv(folder / "poses.csv", scenario))]
    else:
        flight = ["--log", str(write_tlog(folder / "flight.tlog", scenario))]
    return run_pdcov(["evaluate", "--config", str(mission), *flight, "--out",
                      str(folder / f"run_{source}"), "--no-progress"])


@dataclass(frozen=True)
class PlannerRun:
    """``pdcov optimise``: plans scored and the seconds the sweep took (its own report)."""

    plans: int
    sweep_s: float
    command: CommandRun

    @property
    def plans_per_min(self) -> float:
        return 60.0 * self.plans / self.sweep_s


def optimise_run(folder: Path, scenario: Scenario, altitudes_m: list[float],
                 speeds_mps: list[float]) -> PlannerRun:
    """``pdcov optimise`` over lawnmower and spiral plans on one core (--processes 1)."""
    mission = write_mission(folder / "mission.yaml", scenario)
    out = folder / "optimise"
    run = run_pdcov(["optimise", "--config", str(mission), "--target-pd", "0.8",
                     "--processes", "1", "--patterns", "lawnmower", "spiral",
                     "--altitudes-m", *map(str, altitudes_m),
                     "--speeds-mps", *map(str, speeds_mps), "--out", str(out)])
    doc = json.loads((out / "optimise.json").read_text())
    return PlannerRun(int(doc["scored"]), float(doc["elapsed_s"]), run)

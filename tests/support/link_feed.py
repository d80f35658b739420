"""The daemon's MAVLink read path in memory, for fuzzing: bytes -> pymavlink's parser (robust
parsing, as mavlink_socket opens links) -> the daemon's decisions (``ServiceCore``, the object
the asyncio shell drives), with no socket, Zenoh or clock; and a hovering vehicle's messages
to mutate."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.core.grid import CoverageGrid
from pdcov.flight.frame_decision import Framing
from pdcov.flight.log_frames import LogPoses, poses_from_log
from pdcov.service.core import ServiceCore
from pdcov.service.coverage import LiveCoverage
from pdcov.service.link_setup import LinkReport
from pdcov.service.settings import ServeConfig, load_serve_config
from pdcov.telemetry.frame_policy import below_min_height
from tests.support.harness import small_mission

LAT_DEG, LON_DEG, GROUND_M = 47.397742, 8.545594, 488.0
MISSION = small_mission(vehicle_id="fuzz", mount={"type": "gimbal", "attitude_frame": "flags"},
                        coverage={"min_revisit_s": 1.0})
FIXED = {"type": "fixed", "roll_deg": 0, "pitch_deg": -90, "yaw_deg": 0}


def serve_config(tmp: Path, *, gimbal: bool = True, **sections: object) -> ServeConfig:
    """The daemon's config of MISSION (gimbal or fixed mount), ``sections`` replaced."""
    doc = dict(MISSION, mount=MISSION["mount"] if gimbal else FIXED, **sections)
    doc["service"] = {"state_dir": str(tmp / "state"), "record": False}
    path = tmp / ("gimbal.yaml" if gimbal else "fixed.yaml")
    path.write_text(yaml.safe_dump(doc))
    return load_serve_config(path)


class LinkFeed:
    """One daemon's decisions fed raw bytes. ``feed`` parses them (pymavlink, robust) and
    hands the messages to the core as the shell does on a readable link, then the end of
    the loop pass and a tick; ``now_s`` is stepped by the caller."""

    def __init__(self, cfg: ServeConfig) -> None:
        self.cfg = cfg
        self.core = ServiceCore(cfg, cfg.mission.new_mission_grid(), 0.0, mission_hash="fuzz")
        self.parser = mavlink.MAVLink(None)
        self.parser.robust_parsing = True
        self.messages = 0
        self.now_s = 0.0

    @property
    def live(self) -> LiveCoverage:
        return self.core.coverage

    def feed(self, data: bytes, now_s: float) -> None:
        msgs = self.parser.parse_buffer(data) or []
        self.messages += len(msgs)
        self.core.receive_mavlink(msgs, now_s)
        self.core.process()
        self.tick(now_s)

    def tick(self, now_s: float) -> None:
        """The shell's timer (no links, Zenoh or files: what the core says to do is
        dropped)."""
        self.now_s = now_s
        self.core.tick(now_s, 0.0)
        self.core.actions()

    def status(self) -> dict:
        fields, _line = self.core.status(self.now_s, LinkReport())
        self.core.actions()
        return fields


def offline_of(cfg: ServeConfig, tlog: Path) -> tuple[LogPoses, CoverageGrid]:
    """``pdcov evaluate`` of the same bytes as a tlog: its poses with the daemon's mission,
    and the grid built from them as the daemon builds it (frames below min_height_m not
    added)."""
    m = cfg.mission
    cam = m.first_camera
    lp = poses_from_log(tlog, Framing(cam.mount, cam.frame_rate_hz, max_gap_s=m.max_gap_s,
                                      estimator_status=m.estimator_status),
                        origin_lat_deg=m.origin_lat_deg, origin_lon_deg=m.origin_lon_deg,
                        ground_alt_msl_m=m.ground_alt_msl_m)
    grid = m.new_mission_grid()
    for p in lp.poses:
        if not below_min_height(p.r_cam_enu[2], m.min_height_m):
            grid.update(p)
    return lp, grid


@dataclass(frozen=True, slots=True)
class Hover:
    """A vehicle hovering 12 m over the middle of the domain: which messages at which
    autopilot time (ms) from system 1, component 1 (the gimbal too, as ArduPilot sends).
    gnss_acc_mm: (h_acc, v_acc) of a GPS_RAW_INT (3D fix) sent at 2 Hz (None: none).
    boot_unix_us: the UTC (us since 1970) of time_boot_ms 0, in a SYSTEM_TIME a second
    from 1 s on, the first with time_unix_usec 0 (not known yet); None: no SYSTEM_TIME."""

    seconds: float = 4.0
    rate_hz: float = 10.0
    gnss_acc_mm: tuple[int, int] | None = None
    boot_unix_us: int | None = None

    def messages(self) -> list[mavlink.MAVLink_message]:
        mav = mavlink.MAVLink(None)  # encodes fields only; link_feed.pack sets the ids
        lat_e7 = round((LAT_DEG + 15 / 111_320.0) * 1e7)
        lon_e7 = round((LON_DEG + 15 / (111_320.0 * math.cos(math.radians(LAT_DEG)))) * 1e7)
        out = [mav.heartbeat_encode(2, 3, 128 | 1, 4, 4),
               mav.home_position_encode(round(LAT_DEG * 1e7), round(LON_DEG * 1e7),
                                        round(GROUND_M * 1000), 0, 0, 0, [1, 0, 0, 0], 0, 0, 0)]
        for k in range(int(self.seconds * self.rate_hz)):
            ms = 1000 + round(k * 1000 / self.rate_hz)
            if k % 10 == 0:
                out.append(mav.heartbeat_encode(2, 3, 128 | 1, 4, 4))
                if self.boot_unix_us is not None:
                    out.append(mav.system_time_encode(
                        k and self.boot_unix_us + ms * 1000, ms))
            out.append(mav.attitude_encode(ms, 0.01, -0.02, 0.3, 0, 0, 0))
            if self.gnss_acc_mm is not None and k % 5 == 0:
                out.append(mav.gps_raw_int_encode(ms * 1000, 3, lat_e7, lon_e7,
                                                  round((GROUND_M + 12) * 1000), 70, 110, 0,
                                                  65535, 14, 0, *self.gnss_acc_mm, 0, 0, 0))
            out.append(mav.global_position_int_encode(ms, lat_e7, lon_e7,
                                                      round((GROUND_M + 12) * 1000), 12_000,
                                                      0, 0, 0, 0))
            # Pitch -90 deg (camera down), earth frame: flags ROLL_LOCK|PITCH_LOCK|YAW_LOCK.
            c = math.sqrt(0.5)
            out.append(mav.gimbal_device_attitude_status_encode(0, 0, ms, 4 | 8 | 16,
                                                                [c, 0.0, -c, 0.0], 0, 0, 0, 0))
        return out


def pack(msg: mavlink.MAVLink_message, system_id: int = 1, component_id: int = 1,
         seq: int = 0) -> bytes:
    """The MAVLink 2 frame of ``msg`` sent by (system_id, component_id): the autopilot's
    own ids by default."""
    mav = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
    mav.seq = seq & 0xFF
    return bytes(msg.pack(mav, force_mavlink1=False))


class Frames:
    """MAVLink frames in sending order (``out``), numbered as one link sends them."""

    def __init__(self) -> None:
        self.out: list[bytes] = []

    def send(self, msg: mavlink.MAVLink_message, component: int = 1) -> None:
        """``msg`` as sent by the autopilot's system, from ``component``."""
        self.out.append(pack(msg, component_id=component, seq=len(self.out)))


def feed_tlog(cfg: ServeConfig, tlog: Path) -> LinkFeed:
    """A daemon's decisions fed every message of ``tlog`` as it arrived (1 ms apart), then
    a tick far later (every frame decided)."""
    from pymavlink import mavutil

    feed = LinkFeed(cfg)
    log = mavutil.mavlink_connection(str(tlog), dialect="common")
    i = 0
    while (msg := log.recv_msg()) is not None:
        feed.feed(bytes(msg.get_msgbuf()), 0.001 * i)
        i += 1
    feed.tick(1e4)
    return feed


def grid_is_sane(live: LiveCoverage) -> None:
    """No NaN, +inf or positive log-miss sum, no negative count: what a fuzzed link must
    never write into the grid."""
    g = live.grid
    for name in ("log_miss_d", "log_miss_fa"):
        a = getattr(g, name)
        assert np.isfinite(a).all(), f"{name}: non-finite values"
        assert (a <= 0).all(), f"{name}: positive values"
    assert (g.n_obs >= 0).all()


def without_epoch(items: list[dict]) -> list[dict]:
    """Detections or candidates with their uid's epoch left out ("uav7.*.3"): the daemon's
    epoch is its state directory's, ``pdcov evaluate``'s the log's SHA-256."""
    def blank(uid: str) -> str:
        vehicle, _epoch, cid = uid.rsplit(".", 2)
        return f"{vehicle}.*.{cid}"
    return [{**x, "uid": blank(x["uid"])} for x in items]

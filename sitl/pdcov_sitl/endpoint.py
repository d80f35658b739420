"""The autopilot's MAVLink endpoint, the shell the fly loop uses: it owns the link
(``link.py``), the tlog and the fault injector (``faults.py``), and feeds the protocol cores
(``protocol.py``: the stream schedule, the answers to ground stations) what it reads.

Times are simulated seconds ``now_s``; the wall clock only paces reads of the link and the
mission protocol's retries, and sets the first MAVLink 2 signing timestamp.
"""

from __future__ import annotations

import math
import random
import struct
import sys
import time
from pathlib import Path
from typing import BinaryIO

from pymavlink.dialects.v20 import common as mavlink2

from .camera import CAMERA_COMPONENT, ZoomCamera
from .faults import FaultInjector, FaultSpec, GimbalHealth
from .link import open_link
from .protocol import AUTOPILOT_COMPONENT, Autopilot, AutopilotProtocol, StreamSchedule

__all__ = ["TLOG_EPOCH_UNIX_S", "AutopilotEndpoint", "sign_with"]

TLOG_EPOCH_UNIX_S = 1_767_225_600.0
"""Unix time of simulated time 0 in the tlog and SYSTEM_TIME: 2026-01-01T00:00:00Z, fixed
so that the same seed writes the same bytes."""
READ_PERIOD_S = 0.002
"""``poll`` reads the link at most this often (wall clock): answers wait at most 2 ms."""
SIGNING_EPOCH_UNIX_S = 1_420_070_400
"""MAVLink 2 signing timestamps count 10 us units from 2015-01-01T00:00:00Z."""


def sign_with(mav: mavlink2.MAVLink, key: bytes) -> None:
    """Sign what ``mav`` packs and check what it parses with ``key`` (32 bytes): unsigned
    and wrongly signed messages then parse as BAD_DATA. The first timestamp is the wall
    clock's, as an autopilot with a GPS time does: a receiver refuses a stream whose
    timestamps lie more than a minute behind its own (replay protection)."""
    mav.signing.secret_key = key
    mav.signing.sign_outgoing = True
    mav.signing.allow_unsigned_callback = None
    mav.signing.timestamp = int((max(time.time(), SIGNING_EPOCH_UNIX_S)
                                 - SIGNING_EPOCH_UNIX_S) * 100_000)


class AutopilotEndpoint:
    """The vehicle's MAVLink endpoint, as the fly loop (and ``--wait-mission``) uses it.

    url: link URL (``link.py``). system_id: our MAVLink system id; we send as component 1
    unless told otherwise. autopilot: "ardupilot" or "px4" (mission requests, capabilities).
    params: parameter name -> value, answered in this order. streams: message name ->
    default rate in Hz (0: off until a ground station asks); only these can be set or
    requested. faults: link and autopilot faults, or None. seed: jitter and faults.
    tlog_path: where to record every message we send (None: no tlog). signing_key: 32
    bytes: sign every message sent and ignore received ones not signed with it (MAVLink 2
    signing, as ArduPilot with a key set); None: no signing.

    All times ``now_s`` are simulated seconds (non-decreasing). Build messages with
    ``endpoint.mav.X_encode(...)`` and pass them to ``send``; put ``time_boot_ms(now_s)`` in
    their time fields and ``unix_time_us(now_s)`` in SYSTEM_TIME. Autopilot faults for the
    fly loop: ``gps_offset_ned_m(now_s)`` (add to reported positions), ``gimbal_health``.
    """

    def __init__(self, url: str, *, system_id: int, autopilot: Autopilot,
                 params: dict[str, float], streams: dict[str, float],
                 faults: FaultSpec | None, seed: int, tlog_path: Path | None,
                 epoch_unix_s: float = TLOG_EPOCH_UNIX_S, signing_key: bytes | None = None):
        self._signing_key = signing_key
        self.mav = mavlink2.MAVLink(None, srcSystem=system_id, srcComponent=AUTOPILOT_COMPONENT)
        self._packers = {AUTOPILOT_COMPONENT: self.mav}
        self._parser = mavlink2.MAVLink(None, srcSystem=system_id)
        self._parser.robust_parsing = True
        if signing_key is not None:
            sign_with(self.mav, signing_key)
            sign_with(self._parser, signing_key)
        self.schedule = StreamSchedule(streams, random.Random(f"{seed}:streams"))
        self.protocol = AutopilotProtocol(self.mav, system_id=system_id, autopilot=autopilot,
                                          params=params, schedule=self.schedule)
        self.faults = FaultSpec() if faults is None else faults
        self._injector = FaultInjector(self.faults, seed)
        self._reboots = sorted(self.faults.reboots, key=lambda w: w.start_s)
        self._epoch_unix_s = epoch_unix_s
        self._boot_s = 0.0
        self._down_until_s = -math.inf
        self.n_sent = 0
        self.n_received = 0
        self.camera: ZoomCamera | None = None  # fly.py sets it for a zoom mission
        self._next_read_wall_s = -math.inf
        self._tlog: BinaryIO | None = None
        self.link = open_link(url)
        if url.startswith("pty") or url.endswith(":0"):  # where to connect is ours to say
            print(f"pdcov-sitl: MAVLink on {self.link.describe()}", file=sys.stderr,
                  flush=True)
        try:
            self._tlog = open(tlog_path, "wb") if tlog_path is not None else None
        except OSError:
            self.link.close()
            raise

    @property
    def mission(self) -> list | None:
        """Mission items (pdcov.core.mission.MissionItem) of the last completed upload over
        MAVLink, None before any. ArduPilot-like: item 0 is home, as ground stations send."""
        return self.protocol.missions.mission

    def time_boot_ms(self, now_s: float) -> int:
        return max(0, int((now_s - self._boot_s) * 1000.0))

    def time_boot_s(self, now_s: float) -> float:
        """The autopilot's boot clock at simulated time ``now_s`` (s, not truncated to the
        millisecond as time_boot_ms is)."""
        return max(0.0, now_s - self._boot_s)

    def unix_time_us(self, now_s: float) -> int:
        return round((self._epoch_unix_s + now_s) * 1e6)

    def is_down(self, now_s: float) -> bool:
        """Rebooting: nothing is sent or answered."""
        self._apply_reboot_faults(now_s)
        return now_s < self._down_until_s

    def gps_offset_ned_m(self, now_s: float) -> tuple[float, float, float]:
        return self.faults.gps_offset_ned_m(now_s)

    def gps_glitching(self, now_s: float) -> bool:
        return self.faults.gps_glitching(now_s)

    def gimbal_health(self, now_s: float) -> GimbalHealth:
        return self.faults.gimbal_health(now_s)

    def _apply_reboot_faults(self, now_s: float) -> None:
        while self._reboots and now_s >= self._reboots[0].start_s:
            w = self._reboots.pop(0)
            self.reboot(w.start_s, down_s=w.duration_s)

    def reboot(self, now_s: float, down_s: float = 0.0) -> None:
        """The autopilot restarts at ``now_s``: time_boot_ms counts from 0 again, rates set
        by ground stations are forgotten (streams return to their defaults), and for
        ``down_s`` seconds nothing is sent or answered. Parameters and mission persist."""
        self._boot_s = now_s
        self._down_until_s = now_s + down_s
        self.schedule.reset()

    def due(self, now_s: float) -> list[str]:
        """Stream names whose send time has come (jitter applied); [] while rebooting."""
        if self.is_down(now_s):
            return []
        return self.schedule.due(now_s)

    def send(self, msg: mavlink2.MAVLink_message, now_s: float,
             component_id: int = AUTOPILOT_COMPONENT) -> None:
        """Pack ``msg`` as ``component_id`` of our system, record it in the tlog (what the
        autopilot sent), then put it through the link faults onto the wire."""
        if self.is_down(now_s):
            return
        nan_field = self._injector.nan_field(msg.get_type(), now_s)
        if nan_field is not None:
            setattr(msg, nan_field, math.nan)
        packer = self._packers.get(component_id)
        if packer is None:
            packer = mavlink2.MAVLink(None, srcSystem=self.mav.srcSystem,
                                      srcComponent=component_id)
            if self._signing_key is not None:
                sign_with(packer, self._signing_key)
            self._packers[component_id] = packer
        packet = msg.pack(packer)
        packer.seq = (packer.seq + 1) % 256
        self.n_sent += 1
        if self._tlog is not None:
            self._tlog.write(struct.pack(">Q", self.unix_time_us(now_s)) + packet)
        for datagram in self._injector.transmit(packet, now_s):
            self.link.write(datagram)

    def poll(self, now_s: float) -> None:
        """Read what ground stations sent and answer it (commands, parameters, missions)."""
        wall_s = time.monotonic()
        down = self.is_down(now_s)
        data = b""
        if wall_s >= self._next_read_wall_s:  # at --speed 0 steps come every few µs
            self._next_read_wall_s = wall_s + READ_PERIOD_S
            data = self.link.read()
        if data and not down:
            for msg in self._parser.parse_buffer(data) or []:
                if msg.get_type() == "BAD_DATA" or not self._injector.receive_ok(now_s):
                    continue
                self.n_received += 1
                for reply in self.protocol.receive(msg, now_s, wall_s):
                    self.send(reply, now_s)
                if self.camera is not None:  # a camera component on the same link
                    for reply in self.camera.receive(msg, self.time_boot_ms(now_s)):
                        self.send(reply, now_s, component_id=CAMERA_COMPONENT)
        if not down:
            for msg in self.protocol.poll(wall_s):
                self.send(msg, now_s)

    def close(self) -> None:
        try:
            if self._tlog is not None:
                self._tlog.close()
        finally:
            self.link.close()

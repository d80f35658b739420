"""An autopilot stand-in on a UDP socket for end-to-end tests of the daemon's re-tasking:
an ArduCopter-like HEARTBEAT twice a second to the daemon's ``udpin`` port, the vehicle's
side of a mission upload (MISSION_REQUEST_INT per item, then MISSION_ACK accepted), and a
record of every message type and STATUSTEXT the daemon sent."""

from __future__ import annotations

import socket
import threading
import time
from collections import Counter

from pymavlink.dialects.v20 import ardupilotmega as mavlink


class AutopilotStandIn:
    def __init__(self, daemon_port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.1)
        self.addr = ("127.0.0.1", daemon_port)
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.parser = mavlink.MAVLink(None)
        self.received: Counter[str] = Counter()
        self.texts: list[tuple[int, str]] = []  # (severity, text) of STATUSTEXT
        self.missions: list[int] = []  # item counts of the uploads accepted
        self._count = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _send(self, msg) -> None:
        self.sock.sendto(msg.pack(self.mav), self.addr)

    def _run(self) -> None:
        next_hb = 0.0
        while not self._stop.is_set():
            if time.monotonic() >= next_hb:
                next_hb = time.monotonic() + 0.5
                self._send(self.mav.heartbeat_encode(
                    mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 3, 4))
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            for msg in self.parser.parse_buffer(data) or []:
                self._answer(msg)

    def _answer(self, msg) -> None:
        t = msg.get_type()
        self.received[t] += 1
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if t == "STATUSTEXT":
            self.texts.append((msg.severity, msg.text))
        elif t == "MISSION_COUNT":
            self._count = msg.count
            self._send(self.mav.mission_request_int_encode(*src, 0, 0))
        elif t == "MISSION_ITEM_INT":
            if msg.seq + 1 < self._count:
                self._send(self.mav.mission_request_int_encode(*src, msg.seq + 1, 0))
            else:
                self.missions.append(self._count)
                self._send(self.mav.mission_ack_encode(*src, mavlink.MAV_MISSION_ACCEPTED, 0))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.sock.close()

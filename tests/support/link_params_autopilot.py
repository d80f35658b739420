"""An ArduPilot parameter server on a UDP port of 127.0.0.1, for the tests of `pdcov`'s
parameter reads (commands/link_params.py)."""

from __future__ import annotations

import threading

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from pdcov.telemetry.upload import mavlink2_connection
from tests.support.evaluate_inputs import mission_doc, write_config

SYSID = 7  # not 1: the ground station must learn it from the HEARTBEAT


class Autopilot(threading.Thread):
    """An ArduPilot autopilot's parameter server on a UDP port of 127.0.0.1."""

    def __init__(self, params, drop_first=False, noisy=False):
        super().__init__(daemon=True)
        self.conn = mavlink2_connection("udpin:127.0.0.1:0", SYSID, 1)
        self.port = self.conn.port.getsockname()[1]
        # A ground station and a companion computer sharing the link (system 250).
        self.other = mavlink2.MAVLink(self.conn, srcSystem=250, srcComponent=190)
        self.params = dict(params)
        self.drop_first = drop_first
        self.noisy = noisy
        self.requests: dict[str, int] = {}
        self.stop = threading.Event()

    def run(self):
        while not self.stop.is_set():
            msg = self.conn.recv_match(blocking=True, timeout=0.05)
            if msg is None:
                continue
            if msg.get_type() == "HEARTBEAT":
                if self.noisy:
                    self.other.heartbeat_send(mavlink2.MAV_TYPE_GCS,
                                              mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                self.conn.mav.heartbeat_send(mavlink2.MAV_TYPE_QUADROTOR,
                                             mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0,
                                             mavlink2.MAV_STATE_STANDBY)
            elif (msg.get_type() == "PARAM_REQUEST_READ" and msg.target_system == SYSID
                  and msg.param_index == -1):
                self._answer(msg.param_id)
        self.conn.close()

    def _answer(self, name):
        self.requests[name] = self.requests.get(name, 0) + 1
        if self.drop_first and self.requests[name] == 1:
            return  # lost on the link: the ground station must ask again
        if self.noisy:
            self.conn.mav.attitude_send(0, 0.1, -0.3, 1.0, 0, 0, 0)
            self.other.param_value_send(name.encode(), 99.0,
                                        mavlink2.MAV_PARAM_TYPE_REAL32, 1, 0)
        if name in self.params:
            names = sorted(self.params)
            self.conn.mav.param_value_send(name.encode(), float(self.params[name]),
                                           mavlink2.MAV_PARAM_TYPE_REAL32, len(names),
                                           names.index(name))


@pytest.fixture
def autopilot():
    started = []

    def make(params, **kw):
        peer = Autopilot(params, **kw)
        peer.start()
        started.append(peer)
        return peer
    yield make
    for peer in started:
        peer.stop.set()
        peer.join(timeout=2)


def gimbal_config(tmp_path, **mount):
    return write_config(tmp_path, mission_doc(mount={"type": "gimbal", **mount}))

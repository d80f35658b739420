"""The daemon's re-tasking decisions driven in memory: ``ServiceCore`` of link_feed's
MISSION with an operator key, a scripted autopilot on a fake link, and the exchange of a
request with it (tests/unit/test_retask.py, tests/unit/test_retask_signed.py)."""

from __future__ import annotations

import math

import yaml
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.core.mission import MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT, MissionItem
from pdcov.service.actions import Actions
from pdcov.service.core import ServiceCore
from pdcov.service.settings import load_serve_config
from tests.support.link_feed import MISSION, Hover, pack
from tests.support.retask_keys import UNIX_S, write_pub

WP = MissionItem(MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT, param4=math.nan,
                 lat_deg=47.3978, lon_deg=8.5457, z_m=10.0)
ITEMS = (WP, MissionItem(MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT,
                         lat_deg=47.3979, lon_deg=8.5458, z_m=10.0))
FAR = MissionItem(MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT, lat_deg=47.397742 + 0.9,
                  lon_deg=8.5457, z_m=10.0)  # 100 km north of the mission


class Autopilot:
    """ArduCopter's side of the mission protocol on the daemon's link: asks for every item
    with MISSION_REQUEST (as ArduCopter 4.7 does), then acknowledges with ``result``."""

    def __init__(self, result: int = mavlink.MAV_MISSION_ACCEPTED) -> None:
        self.mav = mavlink.MAVLink(None)
        self.result = result
        self.count = 0
        self.items: dict[int, mavlink.MAVLink_mission_item_int_message] = {}
        self.sent: list[mavlink.MAVLink_message] = []

    def answer(self, msgs: list) -> bytes:
        """What the autopilot sends back to the daemon's messages."""
        out = b""
        for m in msgs:
            self.sent.append(m)
            if m.get_type() == "MISSION_COUNT":
                self.count = m.count
                out += pack(self.mav.mission_request_encode(1, 191, 0, 0))
            elif m.get_type() == "MISSION_ITEM_INT":
                self.items[m.seq] = m
                nxt = m.seq + 1
                out += pack(self.mav.mission_request_encode(1, 191, nxt, 0) if nxt < self.count
                            else self.mav.mission_ack_encode(1, 191, self.result, 0))
        return out


def core_with(tmp_path, nonces=None, **service) -> ServiceCore:
    write_pub(tmp_path / "keys")
    if service.get("retask"):
        service.setdefault("retask_operator_keys", ["keys/operator.pub"])
    doc = dict(MISSION, service={"state_dir": str(tmp_path / "state"), "record": False,
                                 **service})
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(doc))
    cfg = load_serve_config(tmp_path / "m.yaml")
    return ServiceCore(cfg, cfg.mission.new_mission_grid(), 0.0, mission_hash="retask",
                       nonces=nonces)


def feed(core: ServiceCore, data: bytes, now_s: float) -> Actions:
    """The shell's part: a readable link's messages, the end of the pass, a tick."""
    parser = mavlink.MAVLink(None)
    core.receive_mavlink(parser.parse_buffer(data) or [], now_s)
    core.process()
    core.tick(now_s, 0.0)
    return core.actions()


def heard(core: ServiceCore) -> None:
    feed(core, b"".join(pack(m) for m in Hover(seconds=0.5).messages()), 1.0)


KEY_EXPR = "pdcov/fuzz/retask"


def fly(core: ServiceCore, autopilot: Autopilot, payload: bytes, session: str | None,
        now_s: float = 2.0, key_expr: str = KEY_EXPR, unix_s: float = UNIX_S
        ) -> tuple[list, list]:
    """Request, then the exchange until nothing more is sent: (replies, logs); the
    messages the autopilot got are in ``autopilot.sent``."""
    replies, logs = [], []
    core.receive_retask(7, payload, key_expr, session, now_s, unix_s)
    a = core.actions()
    replies += a.replies
    logs += a.logs
    autopilot.sent += [m for m in a.send if m.get_type() == "STATUSTEXT"]
    msgs = [m for m in a.send if m.get_type().startswith("MISSION")]
    for _ in range(50):
        if not msgs:
            break
        now_s += 0.05
        a = feed(core, autopilot.answer(msgs), now_s)
        replies += a.replies
        logs += a.logs
        autopilot.sent += [m for m in a.send if m.get_type() == "STATUSTEXT"
                           and m.severity == 5]
        msgs = [m for m in a.send if m.get_type().startswith("MISSION")]
    return replies, logs

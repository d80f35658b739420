"""The vehicle side of the MAVLink mission protocol (mavlink.io/en/services/mission.html),
as a state machine with no I/O: messages and the time in, messages to send out.

Upload: MISSION_COUNT -> one MISSION_REQUEST_INT per item (MISSION_REQUEST for an
ArduPilot-like vehicle, as ArduCopter 4.7 asks) -> MISSION_ITEM_INT or MISSION_ITEM ->
MISSION_ACK. A request unanswered for ``retry_s`` is resent, at most ``max_retries`` times;
then the upload is abandoned with MISSION_ACK MAV_MISSION_OPERATION_CANCELLED.
Download: MISSION_REQUEST_LIST -> MISSION_COUNT -> the items asked for -> the client's ACK.
Mission types other than the mission (fence, rally) are read back empty and refused on upload.

Time here is the ground station's clock (the endpoint passes the monotonic wall clock):
the client's own timeouts run on wall time even when the simulation runs faster.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink2

from pdcov.core.mission import MissionItem, mission_item_int_params56, mission_item_int_xy

MAV_MISSION_TYPE_MISSION = 0


class MissionServer:
    """Holds the vehicle's mission and serves uploads and downloads.

    ``mission`` is the list of items of the last completed upload (for an ArduPilot-like
    vehicle item 0 is home, as ground stations send it), None before any. ``receive`` and
    ``poll`` return the messages to send (addressed to the client)."""

    def __init__(self, mav: mavlink2.MAVLink, *, request_int: bool, retry_s: float = 1.5,
                 max_retries: int = 5):
        self._mav = mav
        self._request_int = request_int
        self._retry_s = retry_s
        self._max_retries = max_retries
        self.mission: list[MissionItem] | None = None
        self._client: tuple[int, int] | None = None  # uploading ground station
        self._items: list[MissionItem] = []
        self._count = 0
        self._deadline = 0.0
        self._retries = 0

    @property
    def uploading(self) -> bool:
        return self._client is not None

    def _ack(self, client: tuple[int, int], result: int, mission_type: int
             ) -> mavlink2.MAVLink_message:
        return self._mav.mission_ack_encode(*client, result, mission_type)

    def _request(self, client: tuple[int, int], wall_s: float
                 ) -> list[mavlink2.MAVLink_message]:
        self._deadline = wall_s + self._retry_s
        seq = len(self._items)
        if self._request_int:
            return [self._mav.mission_request_int_encode(*client, seq,
                                                         MAV_MISSION_TYPE_MISSION)]
        return [self._mav.mission_request_encode(*client, seq, MAV_MISSION_TYPE_MISSION)]

    def receive(self, msg: mavlink2.MAVLink_message, wall_s: float
                ) -> list[mavlink2.MAVLink_message]:
        """Handle one message addressed to this vehicle; returns the replies."""
        kind = msg.get_type()
        client = (msg.get_srcSystem(), msg.get_srcComponent())
        mission_type = getattr(msg, "mission_type", MAV_MISSION_TYPE_MISSION)
        if kind == "MISSION_COUNT":
            if mission_type != MAV_MISSION_TYPE_MISSION:
                return [self._ack(client, mavlink2.MAV_MISSION_UNSUPPORTED, mission_type)]
            if self._client not in (None, client):
                return [self._ack(client, mavlink2.MAV_MISSION_DENIED, mission_type)]
            if msg.count == 0:
                self._client = None
                self.mission = []
                return [self._ack(client, mavlink2.MAV_MISSION_ACCEPTED, mission_type)]
            self._client, self._count, self._items, self._retries = client, msg.count, [], 0
            return self._request(client, wall_s)
        if kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            if client != self._client or mission_type != MAV_MISSION_TYPE_MISSION:
                return []
            if msg.seq != len(self._items):  # a resend of one we have, or one too early
                return self._request(client, wall_s) if msg.seq > len(self._items) else []
            self._items.append(_item_from_message(msg))
            self._retries = 0
            if len(self._items) < self._count:
                return self._request(client, wall_s)
            self.mission, self._client = self._items, None
            return [self._ack(client, mavlink2.MAV_MISSION_ACCEPTED, mission_type)]
        if kind == "MISSION_REQUEST_LIST":
            n = len(self.mission or []) if mission_type == MAV_MISSION_TYPE_MISSION else 0
            return [self._mav.mission_count_encode(*client, n, mission_type)]
        if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            items = self.mission or []
            if mission_type != MAV_MISSION_TYPE_MISSION or not 0 <= msg.seq < len(items):
                return [self._ack(client, mavlink2.MAV_MISSION_INVALID_SEQUENCE, mission_type)]
            return [_item_message(self._mav, client, msg.seq, items[msg.seq],
                                  as_int=kind == "MISSION_REQUEST_INT")]
        if kind == "MISSION_CLEAR_ALL":
            if mission_type == MAV_MISSION_TYPE_MISSION:
                self.mission = []
            return [self._ack(client, mavlink2.MAV_MISSION_ACCEPTED, mission_type)]
        return []

    def poll(self, wall_s: float) -> list[mavlink2.MAVLink_message]:
        """Resend the pending request after ``retry_s`` of silence; give up after
        ``max_retries`` resends."""
        if self._client is None or wall_s < self._deadline:
            return []
        if self._retries >= self._max_retries:
            client, self._client = self._client, None
            return [self._ack(client, mavlink2.MAV_MISSION_OPERATION_CANCELLED,
                              MAV_MISSION_TYPE_MISSION)]
        self._retries += 1
        return self._request(self._client, wall_s)


def _item_from_message(msg: mavlink2.MAVLink_message) -> MissionItem:
    if msg.get_type() == "MISSION_ITEM_INT":
        lat_deg, lon_deg = mission_item_int_params56(msg.frame, msg.x, msg.y)
    else:
        lat_deg, lon_deg = float(msg.x), float(msg.y)
    return MissionItem(msg.command, msg.frame, msg.param1, msg.param2, msg.param3,
                       msg.param4, lat_deg, lon_deg, float(msg.z), bool(msg.autocontinue))


def _item_message(mav: mavlink2.MAVLink, client: tuple[int, int], seq: int, it: MissionItem,
                  *, as_int: bool) -> mavlink2.MAVLink_message:
    args = (*client, seq, it.frame, it.command, int(seq == 0), int(it.autocontinue),
            it.param1, it.param2, it.param3, it.param4)
    if as_int:
        return mav.mission_item_int_encode(*args, *mission_item_int_xy(it), it.z_m,
                                           MAV_MISSION_TYPE_MISSION)
    return mav.mission_item_encode(*args, it.lat_deg, it.lon_deg, it.z_m,
                                   MAV_MISSION_TYPE_MISSION)

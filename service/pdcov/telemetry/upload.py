"""Mission upload to a vehicle over the MAVLink mission protocol (mavlink.io/en/services/
mission.html): MISSION_COUNT, then one MISSION_ITEM_INT per MISSION_REQUEST_INT or older
MISSION_REQUEST, until the vehicle's MISSION_ACK.

Items are always MISSION_ITEM_INT (latitude and longitude in degE7), as QGroundControl
sends them: the float MISSION_ITEM carries float32 degrees, which moves a waypoint by up to
half a metre (-35.36308075 becomes -35.3630784). ArduCopter 4.7 asks with MISSION_REQUEST
and accepts MISSION_ITEM_INT in answer.

``MissionUpload`` (telemetry/mission_upload.py) is the ground-station side as a state
machine with no I/O; ``upload_mission`` is the adapter that runs it over a pymavlink
connection (UDP, TCP or serial). The daemon runs the same machine over its own link
(service/retask.py).
"""

from __future__ import annotations

import time

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from pdcov.core.mission import Firmware, MissionItem
from pdcov.errors import PdcovError, TelemetryError
from pdcov.telemetry.link_params import wait_autopilot_heartbeat
from pdcov.telemetry.link_url import pymavlink_device
from pdcov.telemetry.mission_upload import MissionUpload, UploadResult, with_home


class UploadError(PdcovError):
    """The link could not be opened or no vehicle answered."""


def mavlink2_connection(url: str, source_system: int, source_component: int
                        ) -> mavutil.mavfile:
    """A pymavlink connection that speaks MAVLink 2 (common dialect), whatever dialect
    pymavlink's global default is; URLs of telemetry/link_url.py. One attempt: pymavlink's
    retries would print "Connection refused sleeping" to stdout; UploadError says why."""
    device, baud = pymavlink_device(url)
    try:
        conn = mavutil.mavlink_connection(device, source_system=source_system,
                                          source_component=source_component, retries=0,
                                          **({"baud": baud} if baud else {}))
    except OSError as exc:
        raise UploadError(f"cannot open {url}: {exc}") from None
    conn.mav = mavlink2.MAVLink(conn, srcSystem=source_system, srcComponent=source_component)
    conn.mav.robust_parsing = True
    conn.WIRE_PROTOCOL_VERSION = "2.0"
    conn.first_byte = False  # keep pymavlink from switching the dialect on the first byte
    return conn


def upload_mission(items: tuple[MissionItem, ...], url: str, home: MissionItem,
                   timeout_s: float = 10.0, retry_s: float = 1.5,
                   source_system: int = 255, source_component: int = 190) -> UploadResult:
    """Upload ``items`` to the first vehicle heard on ``url``; ArduPilot vehicles get
    ``home`` as item 0 first (ArduPilot keeps home at seq 0, PX4 does not).

    Waits for the autopilot's HEARTBEAT as ``link_params.wait_autopilot_heartbeat`` does
    (sending ours each second, as a udpout: link needs; ignoring ground stations and
    components that are no autopilot, such as a gimbal or camera).
    Raises UploadError when no vehicle answers within ``timeout_s``, and, before sending
    anything, when the HEARTBEAT's firmware would refuse items (``Firmware.refused_items``:
    e.g. terrain-frame waypoints to PX4)."""
    conn = mavlink2_connection(url, source_system, source_component)
    try:
        try:
            vehicle = wait_autopilot_heartbeat(conn, timeout_s)
        except TelemetryError as exc:
            raise UploadError(f"no vehicle HEARTBEAT on {url} to upload to: {exc}") from None
        firmware = Firmware.of_mav_autopilot(vehicle.autopilot)
        refused = firmware.refused_items(items) if firmware else []
        if refused:
            raise UploadError(f"the vehicle on {url} runs {firmware}, whose mission would "
                              f"refuse {'; '.join(refused)}; nothing was sent")
        items = with_home(items, home, vehicle.autopilot)
        upload = MissionUpload(items, vehicle.get_srcSystem(), vehicle.get_srcComponent(),
                               conn.mav, retry_s=retry_s)
        for m in upload.start(time.monotonic()):
            conn.mav.send(m)
        while upload.result is None:
            msg = conn.recv_match(type=["MISSION_REQUEST_INT", "MISSION_REQUEST",
                                        "MISSION_ACK"], blocking=True, timeout=0.1)
            now = time.monotonic()
            out = upload.receive(msg, now) if msg is not None else []
            for m in out + upload.poll(now):
                conn.mav.send(m)
        return upload.result
    finally:
        conn.close()

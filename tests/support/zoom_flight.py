"""A hover whose camera zooms half-way, as MAVLink: the autopilot (component 1) sends
HEARTBEAT, ATTITUDE and GLOBAL_POSITION_INT at 10 Hz, a MAVLink camera (component 100,
MAV_TYPE_CAMERA) its HEARTBEAT and CAMERA_FOV_STATUS at 10 Hz in the same boot clock. The
camera looks straight down (fixed mount, pitch -90 deg) from 60 m and narrows its horizontal
field of view from 66 to 28 deg between 10.1 and 10.9 s (within the lens's speed)."""

from __future__ import annotations

import math
import struct
from pathlib import Path
from typing import Any

import yaml
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from tests.support.link_feed import GROUND_M, LAT_DEG, LON_DEG, Frames

WIDE_DEG, NARROW_DEG = 66.0, 28.0
HEIGHT_M = 60.0
SECONDS = 20.0
RATE_HZ = 0.5
WIDTH_PX, HEIGHT_PX = 320, 240
ZOOM_START_S, ZOOM_END_S = 10.1, 10.9
CENTRE_ENU_M = (40.0, 40.0)
MAV_TYPE_CAMERA = 30
FIRST_REPORT_S = 1.0


def hfov_deg(t_s: float) -> float:
    """The field of view the camera reports at time t_s (s)."""
    if t_s <= ZOOM_START_S:
        return WIDE_DEG
    if t_s >= ZOOM_END_S:
        return NARROW_DEG
    w = (t_s - ZOOM_START_S) / (ZOOM_END_S - ZOOM_START_S)
    return WIDE_DEG + w * (NARROW_DEG - WIDE_DEG)


def mission(zoom: str = "fov_status", **lens: Any) -> dict[str, Any]:
    f = (WIDTH_PX / 2) / math.tan(math.radians(WIDE_DEG) / 2)
    cam: dict[str, Any] = {
        "width_px": WIDTH_PX, "height_px": HEIGHT_PX,
        "K": [[f, 0.0, WIDTH_PX / 2 - 0.5], [0.0, f, HEIGHT_PX / 2 - 0.5], [0.0, 0.0, 1.0]],
        "frame_rate_hz": RATE_HZ, "zoom": zoom}
    if zoom != "none":
        cam["zoom_lens"] = {"min_hfov_deg": 20.0, **lens}
    return {"vehicle_id": "zoom",
            "origin": {"lat_deg": LAT_DEG, "lon_deg": LON_DEG, "ground_alt_msl_m": GROUND_M},
            "domain": {"polygon_enu_m": [[0, 0], [80, 0], [80, 80], [0, 80]],
                       "cell_size_m": 2.0},
            "camera": cam,
            "mount": {"type": "fixed", "roll_deg": 0, "pitch_deg": -90, "yaw_deg": 0},
            "detector": "illustrative"}


def write_mission(path: Path, doc: dict[str, Any], *, service: bool = False) -> Path:
    if service:
        doc = dict(doc, service={"state_dir": str(path.parent / "state"), "record": False})
    path.write_text(yaml.safe_dump(doc))
    return path


def frames(hfov: Any = hfov_deg, camera_component: int = 100) -> list[bytes]:
    """The flight's MAVLink frames in sending order; ``hfov(t_s)`` gives the reported field
    of view (deg)."""
    mav = mavlink.MAVLink(None)
    deg_per_m = 1.0 / 111_320.0
    lat_e7 = round((LAT_DEG + CENTRE_ENU_M[1] * deg_per_m) * 1e7)
    lon_e7 = round((LON_DEG + CENTRE_ENU_M[0] * deg_per_m / math.cos(math.radians(LAT_DEG)))
                   * 1e7)
    link = Frames()
    send = link.send

    send(mav.heartbeat_encode(2, 3, 128 | 1, 4, 4))
    for k in range(int(SECONDS * 10) + 1):
        ms = round(FIRST_REPORT_S * 1000) + 100 * k
        t_s = ms / 1000.0
        if k % 10 == 0:
            send(mav.heartbeat_encode(2, 3, 128 | 1, 4, 4))
            send(mav.heartbeat_encode(MAV_TYPE_CAMERA, 8, 0, 0, 4), camera_component)
        send(mav.attitude_encode(ms, 0.0, 0.0, 0.0, 0, 0, 0))
        send(mav.global_position_int_encode(ms, lat_e7, lon_e7,
                                            round((GROUND_M + HEIGHT_M) * 1000),
                                            round(HEIGHT_M * 1000), 0, 0, 0, 0))
        h = float(hfov(t_s))
        v = math.degrees(2 * math.atan(math.tan(math.radians(h) / 2) * HEIGHT_PX / WIDTH_PX))
        send(mav.camera_fov_status_encode(ms, lat_e7, lon_e7, 0, lat_e7, lon_e7, 0,
                                          [1, 0, 0, 0], h, v, 0), camera_component)
    return link.out


def write_tlog(path: Path, data: list[bytes]) -> Path:
    path.write_bytes(b"".join(struct.pack(">Q", 1_700_000_000_000_000 + 1000 * i) + d
                              for i, d in enumerate(data)))
    return path

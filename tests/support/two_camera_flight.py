"""A two-camera survey leg, as MAVLink: a visible camera on the autopilot's gimbal device 1
(earth-frame status from component 1, pitch -80 deg) zooming by CAMERA_FOV_STATUS from its
own component 100, and a thermal camera on a fixed mount (straight down) whose zoom table
follows CAMERA_SETTINGS.zoomLevel from component 101; a third camera (102) reports a field
of view no camera of the mission follows. The autopilot (component 1) sends HEARTBEAT,
ATTITUDE, GLOBAL_POSITION_INT and the gimbal status at 10 Hz while the vehicle flies east
at 4 m/s, 60 m up; the cameras their HEARTBEAT and reports at 10 Hz, the same boot clock.
Visible: 2 frames/s, the illustrative detector; thermal: 1.5 frames/s, its own model."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import yaml
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.core.detector import DetectorModel
from tests.support.link_feed import GROUND_M, LAT_DEG, LON_DEG, Frames

SECONDS = 20.0
HEIGHT_M = 60.0
SPEED_MPS = 4.0
START_ENU_M = (20.0, 45.0)
FIRST_MS = 1000
VISIBLE_WIDE_DEG, VISIBLE_NARROW_DEG = 60.0, 40.0
ZOOM_START_S, ZOOM_END_S = 10.0, 11.0
MAV_TYPE_CAMERA = 30


def _k(width_px: int, height_px: int, hfov_deg: float) -> list[list[float]]:
    f = (width_px / 2) / math.tan(math.radians(hfov_deg) / 2)
    return [[f, 0.0, width_px / 2 - 0.5], [0.0, f, height_px / 2 - 0.5], [0.0, 0.0, 1.0]]


def thermal_detector(looks: bool = False) -> dict[str, Any]:
    """The thermal camera's model: the illustrative bins, P_D 0.6 of the visible one's
    (and a looks section of correlation 0.3 per bin with ``looks``)."""
    doc = DetectorModel.illustrative().to_dict()
    doc["p_detect"] = [0.6 * p for p in doc["p_detect"]]
    if looks:
        doc.update(looks={"correlation": [0.3] * len(doc["p_detect"])})
    return doc


def visible_detector(looks: bool = False) -> Any:
    if not looks:
        return "illustrative"
    doc = DetectorModel.illustrative().to_dict()
    doc.update(looks={"correlation": [0.2] * len(doc["p_detect"])})
    return doc


def cameras(looks: bool = False) -> list[dict[str, Any]]:
    """The ``cameras`` entries of the mission (looks: detector models with looks
    sections)."""
    visible = {"width_px": 320, "height_px": 240, "K": _k(320, 240, VISIBLE_WIDE_DEG),
               "frame_rate_hz": 2.0, "zoom": "fov_status",
               "zoom_lens": {"min_hfov_deg": 30.0, "component_id": 100}}
    thermal = {"width_px": 160, "height_px": 128, "K": _k(160, 128, 50.0),
               "frame_rate_hz": 1.5, "zoom": "table",
               "zoom_lens": {"component_id": 101, "table_by": "zoom_level", "table": [
                   {"zoom_level": 0, "K": _k(160, 128, 50.0)},
                   {"zoom_level": 100, "K": _k(160, 128, 30.0)}]}}
    return [{"name": "visible", "camera": visible,
             "mount": {"type": "gimbal", "attitude_frame": "flags", "instance": 1},
             "detector": visible_detector(looks)},
            {"name": "thermal", "camera": thermal,
             "mount": {"type": "fixed", "roll_deg": 0, "pitch_deg": -90, "yaw_deg": 0},
             "detector": thermal_detector(looks)}]


def mission(looks: str = "independent") -> dict[str, Any]:
    return {"vehicle_id": "twocam",
            "origin": {"lat_deg": LAT_DEG, "lon_deg": LON_DEG, "ground_alt_msl_m": GROUND_M},
            "domain": {"polygon_enu_m": [[0, 0], [120, 0], [120, 90], [0, 90]],
                       "cell_size_m": 2.0},
            "coverage": {"looks": looks},
            "cameras": cameras(looks == "correlated")}


def write_mission(path: Path, doc: dict[str, Any]) -> Path:
    """The mission with the daemon's service section (state beside it, no recording)."""
    doc = dict(doc, service={"state_dir": str(path.parent / "state"), "record": False})
    path.write_text(yaml.safe_dump(doc))
    return path


def visible_hfov_deg(t_s: float) -> float:
    w = min(1.0, max(0.0, (t_s - ZOOM_START_S) / (ZOOM_END_S - ZOOM_START_S)))
    return VISIBLE_WIDE_DEG + w * (VISIBLE_NARROW_DEG - VISIBLE_WIDE_DEG)


def frames() -> list[bytes]:
    """The flight's MAVLink frames in sending order."""
    mav = mavlink.MAVLink(None)
    link = Frames()
    send = link.send

    deg_per_m = 1.0 / 111_320.0
    pitch = math.radians(-80.0)  # the gimbal, earth frame, yaw 0 (north... as the body)
    q_gimbal = [math.cos(pitch / 2), 0.0, math.sin(pitch / 2), 0.0]
    send(mav.heartbeat_encode(2, 3, 128 | 1, 4, 4))
    send(mav.home_position_encode(round(LAT_DEG * 1e7), round(LON_DEG * 1e7),
                                  round(GROUND_M * 1000), 0, 0, 0, [1, 0, 0, 0], 0, 0, 0))
    for k in range(int(SECONDS * 10) + 1):
        ms = FIRST_MS + 100 * k
        t_s = ms / 1000.0
        east = START_ENU_M[0] + SPEED_MPS * (t_s - FIRST_MS / 1000.0)
        lat_e7 = round((LAT_DEG + START_ENU_M[1] * deg_per_m) * 1e7)
        lon_e7 = round((LON_DEG + east * deg_per_m / math.cos(math.radians(LAT_DEG))) * 1e7)
        if k % 10 == 0:
            send(mav.heartbeat_encode(2, 3, 128 | 1, 4, 4))
            for comp in (100, 101, 102):
                send(mav.heartbeat_encode(MAV_TYPE_CAMERA, 8, 0, 0, 4), comp)
        send(mav.attitude_encode(ms, 0.0, 0.0, math.pi / 2, 0, 0, 0))  # heading east
        send(mav.global_position_int_encode(ms, lat_e7, lon_e7,
                                            round((GROUND_M + HEIGHT_M) * 1000),
                                            round(HEIGHT_M * 1000), 400, 0, 0, 9000))
        send(mav.gimbal_device_attitude_status_encode(0, 0, ms, 4 | 8 | 16, q_gimbal, 0, 0, 0,
                                                      0, gimbal_device_id=1))
        h = visible_hfov_deg(t_s)
        send(mav.camera_fov_status_encode(ms, lat_e7, lon_e7, 0, lat_e7, lon_e7, 0,
                                          [1, 0, 0, 0], h, 0.75 * h, 0), 100)
        send(mav.camera_settings_encode(ms, 0, 0.0 if t_s < 12.0 else 100.0, 0, 0), 101)
        send(mav.camera_fov_status_encode(ms, lat_e7, lon_e7, 0, lat_e7, lon_e7, 0,
                                          [1, 0, 0, 0], 45.0, 34.0, 0), 102)
    return link.out

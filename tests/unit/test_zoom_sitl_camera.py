"""The simulator's camera answers zoom and camera-information requests."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as mav

from pdcov_sitl.camera import CAMERA_COMPONENT, ZoomCamera


def _camera() -> tuple[ZoomCamera, mav.MAVLink]:
    m = mav.MAVLink(None, srcSystem=255, srcComponent=190)
    return ZoomCamera(m, system_id=1, width_px=320, height_px=240, wide_hfov_deg=66.0,
                      narrow_hfov_deg=22.0, zoom_rate_per_s=1.0), m


def test_the_camera_answers_zoom_and_information_requests():
    cam, m = _camera()
    zoom = m.command_long_encode(1, CAMERA_COMPONENT, mav.MAV_CMD_SET_CAMERA_ZOOM, 0,
                                 mav.ZOOM_TYPE_HORIZONTAL_FOV, 40.0, 0, 0, 0, 0, 0)
    ack, settings = cam.receive(zoom, 5000)
    assert ack.get_type() == "COMMAND_ACK" and ack.result == mav.MAV_RESULT_ACCEPTED
    assert settings.get_type() == "CAMERA_SETTINGS" and settings.zoomLevel == 0.0
    # The lens moves at 1 / s in ln f: from 66 to 40 deg takes ln(f40 / f66) s.
    f = [160 / math.tan(math.radians(h) / 2) for h in (66.0, 40.0)]
    need_s = math.log(f[1] / f[0])
    cam.step(need_s / 2)
    assert 40.0 < cam.hfov_deg < 66.0
    cam.step(need_s)
    assert cam.hfov_deg == pytest.approx(40.0)
    for msg_id, name in ((mav.MAVLINK_MSG_ID_CAMERA_FOV_STATUS, "CAMERA_FOV_STATUS"),
                         (mav.MAVLINK_MSG_ID_CAMERA_INFORMATION, "CAMERA_INFORMATION"),
                         (mav.MAVLINK_MSG_ID_CAMERA_SETTINGS, "CAMERA_SETTINGS")):
        req = m.command_long_encode(1, CAMERA_COMPONENT, mav.MAV_CMD_REQUEST_MESSAGE, 0,
                                    msg_id, 0, 0, 0, 0, 0, 0)
        ack, reply = cam.receive(req, 6000)
        assert ack.result == mav.MAV_RESULT_ACCEPTED and reply.get_type() == name
    fov = cam.message("CAMERA_FOV_STATUS", 6000)
    assert fov.hfov == pytest.approx(40.0)
    info = cam.message("CAMERA_INFORMATION", 6000)
    assert info.focal_length == pytest.approx(f[1] * 6.17 / 320)
    # Refused: outside the lens, another component, an unknown zoom type.
    wide = m.command_long_encode(1, CAMERA_COMPONENT, mav.MAV_CMD_SET_CAMERA_ZOOM, 0,
                                 mav.ZOOM_TYPE_HORIZONTAL_FOV, 90.0, 0, 0, 0, 0, 0)
    assert cam.receive(wide, 7000)[0].result == mav.MAV_RESULT_DENIED
    other = m.command_long_encode(1, 1, mav.MAV_CMD_SET_CAMERA_ZOOM, 0,
                                  mav.ZOOM_TYPE_RANGE, 50.0, 0, 0, 0, 0, 0)
    assert cam.receive(other, 7000) == []
    step = m.command_long_encode(1, CAMERA_COMPONENT, mav.MAV_CMD_SET_CAMERA_ZOOM, 0,
                                 mav.ZOOM_TYPE_STEP, 1.0, 0, 0, 0, 0, 0)
    assert cam.receive(step, 7000)[0].result == mav.MAV_RESULT_DENIED

"""The mission over ArduPilot's CMAC test field (the real logs' site), for the daemon's
tests."""

from __future__ import annotations

CMAC = {
    "vehicle_id": "uav1",
    "origin": {"lat_deg": -35.363261, "lon_deg": 149.165230},
    "domain": {"polygon_enu_m": [[-10, -10], [50, -10], [50, 50], [-10, 50]],
               "cell_size_m": 1.0},
    "camera": {"width_px": 640, "height_px": 480,
               "K": [[480.0, 0.0, 319.5], [0.0, 480.0, 239.5], [0.0, 0.0, 1.0]],
               "distortion_model": "plumb_bob",
               "distortion_coeffs": [-0.05, 0.01, 0.0, 0.0, 0.0], "frame_rate_hz": 5},
    "mount": {"type": "gimbal", "roll_limits_deg": [-30, 30], "pitch_limits_deg": [-90, 20],
              "yaw_limits_deg": [-180, 180]},
    "detector": "illustrative",
    "coverage": {"min_revisit_s": 1.0},
}

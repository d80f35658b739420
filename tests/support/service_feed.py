"""A ServeConfig over a small square and a level flight fed to the daemon's decisions in
memory, for the tests of the service's decisions and of the tile metrics."""

from __future__ import annotations

import numpy as np

from pdcov.bus.session import BusConfig
from pdcov.config.load import mission_from_dict
from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.core.rotations import quat_wxyz_from_euler_zyx
from pdcov.service.coverage import LiveCoverage
from pdcov.service.settings import LinkConfig, ServeConfig, ServiceConfig
from pdcov.telemetry.samples import AttitudeSample, PositionSample

ORIGIN = Origin(47.0, 8.0, 400.0)


SQUARE_ENU_M = ((16, 0), (48, 0), (48, 64), (16, 64))


def serve_cfg(polygon_enu_m=SQUARE_ENU_M, **service) -> ServeConfig:
    """The config of a 5 Hz nadir camera over ``polygon_enu_m`` (ENU m; 1 m cells)."""
    doc = {"origin": {"lat_deg": ORIGIN.lat_deg, "lon_deg": ORIGIN.lon_deg,
                      "ground_alt_msl_m": ORIGIN.ground_alt_msl_m},
           "domain": {"polygon_enu_m": [list(p) for p in polygon_enu_m]},
           "camera": {"width_px": 640, "height_px": 480,
                      "K": [[480.0, 0, 319.5], [0, 480.0, 239.5], [0, 0, 1]],
                      "frame_rate_hz": 5},
           "mount": {"type": "fixed", "pitch_deg": -90}, "detector": "illustrative"}
    return ServeConfig(mission_from_dict(doc), LinkConfig(),
                       BusConfig(tile_size=16, tiles_max_bytes_per_s=4096),
                       ServiceConfig(**service), None)


def feed(live, t0, t1, *, rate=10.0, skip=()):
    """Level flight north along x = 32 at 10 m, samples every 1/rate s except in ``skip``
    intervals (both streams silent)."""
    q = quat_wxyz_from_euler_zyx(0.0, 0.0, 0.0)
    for k in range(int(round((t1 - t0) * rate)) + 1):
        t = t0 + k / rate
        if any(a <= t < b for a, b in skip):
            continue
        lat, lon, alt = enu_to_geodetic(np.array([32.0, 2.0 * t, 10.0]), ORIGIN)
        live.add_sample(AttitudeSample(t, tuple(q)))
        live.add_sample(PositionSample(t, float(lat), float(lon), float(alt)))


# A county: 30 x 30 km at 1 m (9 x 10^8 cells), the square's cells at a whole offset.
SIDE_M = 30_000
X0_M, Y0_M = -14_968, -14_968  # the county's corner: the square's cells at a whole offset
COUNTY = ((X0_M, Y0_M), (X0_M + SIDE_M, Y0_M), (X0_M + SIDE_M, Y0_M + SIDE_M),
          (X0_M, Y0_M + SIDE_M))


def flown(polygon_enu_m) -> tuple[LiveCoverage, list[bytes], dict]:
    """A 4 s flight over ``polygon_enu_m``, polled every 0.25 s: the live coverage, the
    tiles messages and the last status's fields."""
    cfg = serve_cfg(polygon_enu_m)
    live = LiveCoverage(cfg, cfg.mission.new_mission_grid(), 0.0)
    tiles = []
    for k in range(16):
        feed(live, 0.25 * k, 0.25 * (k + 1))
        live.process()
        due = live.poll(0.25 * (k + 1))
        if due.tiles is not None:
            tiles.append(due.tiles)
    return live, tiles, live.status_fields(uptime_s=4.0, seq=0, link={}, checkpoint={})

"""The status the daemon publishes (bus.status, docs/protocol.md) and the last footprint.

``status_fields`` reads a ``LiveCoverage``: coverage metrics (P_D at the thresholds, mean
P_D, expected false alarms, cells), frames (used, skipped by reason, pending; times in the
autopilot clock, s), the last pose (lat/lon deg, alt m MSL, heading deg from north), the
gimbal reading, the grid (ENU m about the origin), tiles, faults, with a DEM the
terrain check (``terrain_check``), and the pins summary (``pins``: the candidates as last
published or answered on the bus).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import numpy as np

from pdcov.bus.detections import LIKELY_P_PERSON, P_PERSON_DIGITS
from pdcov.bus.faults import Fault
from pdcov.core.detections import Candidate
from pdcov.core.footprint import footprint_rings_enu
from pdcov.core.geodesy import enu_to_geodetic
from pdcov.core.mount import GimbalMount

if TYPE_CHECKING:
    from pdcov.service.coverage import LiveCoverage

__all__ = ["footprint_lonlat", "pins_summary", "status_fields"]


def footprint_lonlat(live: LiveCoverage) -> np.ndarray | None:
    """The last frame's footprint ring (M, 2) as lon/lat degrees, or None. Over terrain,
    on the level plane through the terrain where the optical axis meets it (found in two
    steps from the height under the camera): a sketch for the map, not the kernel's cells."""
    pose = live.last_pose
    if pose is None or live.origin is None:
        return None
    z_m = 0.0
    terrain = live.grid.terrain
    if terrain is not None:
        z_m = float(terrain.height_m(*pose.r_cam_enu[:2]))
        axis = pose.optical_axis_enu
        if axis[2] < -1e-6:
            hit = pose.r_cam_enu + axis * (pose.r_cam_enu[2] - z_m) / -axis[2]
            z_m = float(terrain.height_m(hit[0], hit[1]))
    ring = footprint_rings_enu(live.grid.camera, pose, live.grid.max_range_m, (z_m,)).rings[0]
    if len(ring) < 3:
        return None
    geo = enu_to_geodetic(np.column_stack([ring, np.full(len(ring), z_m)]), live.origin)
    return geo[:, [1, 0]]


def pins_summary(candidates: Iterable[Candidate]) -> dict[str, Any]:
    """The status's ``pins`` (docs/protocol.md "status"): how many candidates, how many
    with p_person >= LIKELY_P_PERSON, and the most probable one (ties: more hits, then the
    lower id) with its uid, p_person (4 digits), looks and hits; None without candidates."""
    n = likely = 0
    top: Candidate | None = None
    for c in candidates:
        n += 1
        likely += c.p_person >= LIKELY_P_PERSON
        if top is None or (c.p_person, c.hits, -c.candidate_id) > (
                top.p_person, top.hits, -top.candidate_id):
            top = c
    return {"candidates": n, "likely": likely, "top": None if top is None else {
        "uid": top.uid, "p_person": round(top.p_person, P_PERSON_DIGITS),
        "looks": top.looks, "hits": top.hits}}


def status_fields(live: LiveCoverage, *, uptime_s: float, seq: int, link: dict[str, Any],
                  checkpoint: dict[str, Any]) -> dict[str, Any]:
    """The status object's fields (bus.status, docs/protocol.md)."""
    m = live.cfg.mission
    metrics = live.metrics.summary()
    g = live.grid.geometry
    schedule = live.schedule
    pose = None
    if live.last_pose is not None and live.origin is not None:
        lat, lon, alt = enu_to_geodetic(live.last_pose.r_cam_enu, live.origin)
        R = live.last_R_ned_body
        accuracy = live.first.last_accuracy
        pose = {"lat_deg": float(lat), "lon_deg": float(lon), "alt_msl_m": float(alt),
                "heading_deg": math.degrees(math.atan2(R[1, 0], R[0, 0])) % 360.0,
                "t_s": live.last_pose.t_s,
                "gnss_h_acc_m": None if accuracy is None else accuracy.horizontal_m}
    interp = live.interpretation
    gimbal = ({"mount": "fixed", "interpretation": "fixed", "describe": "fixed mount"}
              if not isinstance(m.first_camera.mount, GimbalMount) else
              {"mount": "gimbal", "interpretation": interp.frame if interp else None,
               "describe": interp.describe() if interp else "waiting for the mount "
                                                            "parameters"})
    faults = {str(k): n for k, n in live.counters.faults.items()}  # Fault: its key
    by_camera = ({} if not m.several_cameras else  # each camera's frames
                 {"by_camera": {cam.cam.name: cam.used for cam in live.cameras}})
    check = live.terrain_check
    terrain: dict[str, Any] = {}
    if check is not None:  # only with a DEM: the statuses of a flat mission are unchanged
        faults[Fault.TERRAIN_MISMATCH.value] = check.mismatches
        terrain = {"terrain_check": check.as_dict()}
    return {
        "vehicle_id": m.vehicle_id, "seq": seq, "uptime_s": uptime_s,
        "t_s": schedule.latest_all() if schedule.latest else None,
        "thresholds": list(m.thresholds),
        "proportion_at_or_above": {str(float(t)): metrics.proportion_at_or_above(t)
                                   for t in m.thresholds},
        "mean_pd": metrics.mean_pd, "expected_false_alarms": metrics.expected_false_alarms,
        "cells_free": metrics.cells_free, "cells_observed": metrics.cells_observed,
        "frames": {"used": live.counters.used, "grid": live.grid.frames,
                   "skipped": dict(live.counters.skipped),
                   "pending": live.frames_pending, "source": str(live.frame_source),
                   "last_t_s": live.last_frame_t_s if live.last_frame_t_s > -math.inf
                   else None, **by_camera},
        "link": link, "pose": pose, "gimbal": gimbal,
        "grid": {"hash": live.grid_hash, "x0_m": g.x0_m, "y0_m": g.y0_m,
                 "cell_size_m": g.cell_size_m, "n_rows": g.n_rows, "n_cols": g.n_cols,
                 "tile_size": live.tile_size,
                 "origin": {"lat_deg": m.origin_lat_deg, "lon_deg": m.origin_lon_deg,
                            "ground_alt_msl_m": live.origin.ground_alt_msl_m
                            if live.origin else None, "how": live.origin_how}},
        "tiles_seq": live.tiles_seq - 1,
        # Changed tiles not yet sent (the bandwidth budget holds them back): with 0, a
        # watcher holding tiles_seq and frames.grid holds this grid exactly.
        "tiles_behind": live.tile_sender.behind,
        "faults": faults, "checkpoint": checkpoint, **terrain,
        "pins": pins_summary(live.detections.latest.values()),
    }

"""The mission config's ``cameras`` list: its entries' keys and names, and the rules the
cameras of one list keep together (whose zoom reports each follows, one gimbal read alike)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from pdcov.config.camera import CAMERA_SECTIONS
from pdcov.config.mission import MissionCamera
from pdcov.core.mount import GimbalMount
from pdcov.errors import ConfigError, where
from pdcov.ids import VEHICLE_ID_RULE, valid_vehicle_id
from pdcov.schema import Section, check_keys

CAMERA_ENTRY = Section.of("name", **CAMERA_SECTIONS)
"""One entry of the mission's ``cameras`` list: a name, and the camera, mount and detector
sections of the single-camera form."""


def camera_list(doc: Mapping[str, Any], src: str | None) -> list[Mapping[str, Any]]:
    """The ``cameras`` list's entries, keys checked (empty without one)."""
    listed = doc.get("cameras")
    if listed is None:
        return []
    if not isinstance(listed, list) or not listed:
        raise ConfigError(f"{where(src, 'cameras')}: expected a non-empty list of cameras "
                          f"(name, camera, mount, detector), got {listed!r}")
    both = sorted({"camera", "mount", "detector", "calibration"} & set(doc))
    if both:
        raise ConfigError(f"{where(src, both[0])}: not allowed with a cameras list (give each "
                          "camera's camera, mount and detector in its entry)")
    names = []
    for i, entry in enumerate(listed):
        check_keys(entry, CAMERA_ENTRY, src, f"cameras[{i}]")
        name = entry.get("name", f"camera{i + 1}")
        if not valid_vehicle_id(name) or name in names:
            raise ConfigError(f"{where(src, f'cameras[{i}].name')}: expected a unique name "
                              f"({VEHICLE_ID_RULE}), got {name!r}")
        names.append(name)
        for key in ("camera", "detector"):
            if key not in entry:
                raise ConfigError(f"{where(src, f'cameras[{i}].{key}')}: missing")
    return listed


MAVLINK_CAMERA_COMPONENTS = range(100, 106)
"""MAV_COMP_ID_CAMERA .. MAV_COMP_ID_CAMERA6: a MAVLink camera's own component."""


def check_camera_ids(cameras: list[MissionCamera], src: str | None) -> None:
    """In a cameras list, each zoom camera names the camera whose reports it follows
    (zoom_lens.component_id: 100-105 for a MAVLink camera, camera_device_id 0; any with an
    autopilot-attached camera, camera_device_id 1-6), no two the same; and cameras on one
    gimbal device (mount.instance) read it alike (their mounts differ at most in the lever
    arm)."""
    followed: dict[tuple[int, int], int] = {}
    gimbals: dict[int, tuple[int, GimbalMount]] = {}
    for i, cam in enumerate(cameras):
        lens_at = where(src, f"cameras[{i}].camera.zoom_lens.component_id")
        if cam.zoom is not None:
            ident = cam.zoom.camera_id
            if ident is None:
                raise ConfigError(f"{lens_at}: missing: with a cameras list each zoom camera "
                                  "names the camera component whose reports it follows "
                                  "(100-105 for a MAVLink camera)")
            if ident[1] == 0 and ident[0] not in MAVLINK_CAMERA_COMPONENTS:
                raise ConfigError(f"{lens_at}: expected a MAVLink camera component 100..105 "
                                  f"(camera_device_id 0), got {ident[0]}")
            if ident in followed:
                raise ConfigError(f"{lens_at}: component {ident[0]}, camera_device_id "
                                  f"{ident[1]} is also cameras[{followed[ident]}]'s: each "
                                  "camera follows its own reports")
            followed[ident] = i
        if isinstance(cam.mount, GimbalMount):
            bare = dataclasses.replace(cam.mount, lever_arm_frd_m=(0.0, 0.0, 0.0))
            other = gimbals.setdefault(cam.mount.instance, (i, bare))
            if other[1] != bare:
                raise ConfigError(
                    f"{where(src, f'cameras[{i}].mount')}: gimbal device "
                    f"{cam.mount.instance} (mount.instance) is also cameras[{other[0]}]'s, "
                    "with other settings: cameras on one gimbal read it alike (only "
                    "lever_arm_frd_m may differ); give this camera's gimbal its own instance")

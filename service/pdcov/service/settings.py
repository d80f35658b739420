"""The daemon's sections of the mission config, ``link`` and ``service`` (``bus`` is
bus.session's), declared once as frozen dataclasses: their fields are the keys
(``Section.of_dataclass``), so a misspelt key is refused with a suggestion before any value
is read (config.keys.mission_schema). docs/service.md lists every key.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pdcov.bus.operator_keys import OperatorPublicKey, load_public_key
from pdcov.bus.session import BusConfig, bus_config_from_dict
from pdcov.config.load import load_mission
from pdcov.config.mission import Mission, MissionCamera
from pdcov.core.grid import CoverageGrid
from pdcov.core.looks import LooksConfig
from pdcov.errors import ConfigError, where
from pdcov.flight.ground_altitude import DEFAULT_HOME_WAIT_S
from pdcov.ids import valid_system_id
from pdcov.planning.mission_bounds import RetaskLimits
from pdcov.schema import Section
from pdcov.telemetry.link_url import check_link_url

FRAME_SOURCES = ("rate", "capture", "zenoh")


@dataclass(frozen=True, slots=True)
class LinkConfig:
    """The MAVLink link. connect: pymavlink URLs (serial:/dev/ttyAMA0:921600,
    /dev/ttyAMA0,921600, udpin:0.0.0.0:14550, udpout:HOST:PORT, tcp:HOST:PORT; checked by
    telemetry/link_url.py), all used at once. system_id: the autopilot to follow (None: the
    first autopilot HEARTBEAT; the daemon sends as this system, component 191). attitude_hz /
    position_hz / gimbal_hz / estimator_hz: message rates asked with
    MAV_CMD_SET_MESSAGE_INTERVAL (estimator_hz: EKF_STATUS_REPORT from ArduPilot,
    ESTIMATOR_STATUS from others; not asked when the mission's log.estimator_status is false).
    timeout_s: silence after which the link counts as lost (and a TCP or serial link is
    reopened). reconnect_max_s: the longest wait between reopening attempts (backoff doubles
    from 0.5 s). signing_key: 32 bytes as 64 hex digits, or signing_key_file: a file holding
    them (MAVLink 2 signing). param_timeout_s: wait for the mount parameters before resolving
    the gimbal reading without the missing ones."""

    connect: tuple[str, ...] = ()
    system_id: int | None = None
    attitude_hz: float = 25.0
    position_hz: float = 10.0
    gimbal_hz: float = 20.0
    estimator_hz: float = 5.0
    timeout_s: float = 5.0
    reconnect_max_s: float = 10.0
    signing_key: str | None = None
    signing_key_file: str | None = None
    param_timeout_s: float = 5.0

    def __post_init__(self) -> None:
        if not isinstance(self.connect, tuple):
            raise ConfigError(f"link.connect: expected a list of URLs, got {self.connect!r}")
        for url in self.connect:
            check_link_url(url, "link.connect")
        if self.system_id is not None and not valid_system_id(self.system_id):
            raise ConfigError(f"link.system_id: expected 1..255, got {self.system_id!r}")
        for name in ("attitude_hz", "position_hz", "gimbal_hz", "estimator_hz", "timeout_s",
                     "reconnect_max_s", "param_timeout_s"):
            _positive(name, getattr(self, name), "link")
        if self.signing_key is not None:
            key = self.signing_key
            if not (isinstance(key, str) and len(key) == 64
                    and all(c in "0123456789abcdefABCDEF" for c in key)):
                raise ConfigError("link.signing_key: expected 64 hex digits (32 bytes)")

    def signing_key_bytes(self, base_dir: Path) -> bytes | None:
        """The signing key, from signing_key or the file signing_key_file names."""
        if self.signing_key is not None:
            return bytes.fromhex(self.signing_key)
        if self.signing_key_file is None:
            return None
        path = base_dir / self.signing_key_file
        try:
            text = path.read_text().strip()
            return bytes.fromhex(text) if len(text) == 64 else None
        except (OSError, ValueError):
            return None


@dataclass(frozen=True, slots=True)
class ServiceConfig:
    """What the daemon does. state_dir: checkpoints and recordings. checkpoint_period_s:
    at most this much coverage is lost to a crash. frame_source: 'rate' (frames every
    1/camera.frame_rate_hz s of the autopilot clock), 'capture' (CAMERA_IMAGE_CAPTURED /
    CAMERA_FEEDBACK times) or 'zenoh' (times an onboard detector publishes on
    pdcov/<id>/frames); None = the config's log.frame_source. reorder_s: how long a frame
    waits for late samples before a gap is final. target_pd: the P_D whose proportion
    NAMED_VALUE_FLOAT 'PDCOV' carries (None = the largest threshold). named_value_float /
    statustext: send them (to the GCS through the autopilot). record_max_bytes: one
    recording file's size; record_keep_bytes: all recordings together (oldest removed).
    home_wait_s: autopilot seconds to wait for HOME_POSITION before taking the ground
    altitude from the first position (when origin.ground_alt_msl_m is not set).
    retask: upload the missions ground stations send on pdcov/<id>/retask to the autopilot
    (default false: every request is refused and logged); retask_operator_keys: the
    operator public keys (PEM files, relative to the config's folder) whose signed requests
    are obeyed (required with retask); retask_window_s: how far a request's issue time may
    be from this computer's UTC clock, s; retask_limits: where a mission may send the
    aircraft (planning/mission_bounds.py)."""

    state_dir: str = "/var/lib/pdcov"
    checkpoint_period_s: float = 10.0
    frame_source: str | None = None
    reorder_s: float = 0.2
    target_pd: float | None = None
    named_value_float: bool = True
    statustext: bool = True
    record: bool = True
    record_max_bytes: int = 256 << 20
    record_keep_bytes: int = 4 << 30
    home_wait_s: float = DEFAULT_HOME_WAIT_S
    retask: bool = False
    retask_operator_keys: tuple[str, ...] = ()
    retask_window_s: float = 120.0
    retask_limits: RetaskLimits = RetaskLimits()

    def __post_init__(self) -> None:
        if isinstance(self.retask_operator_keys, str) or not all(
                isinstance(k, str) and k for k in self.retask_operator_keys):
            raise ConfigError("service.retask_operator_keys: expected a list of public key "
                              "files (`pdcov keys new` writes operator.pub), got "
                              f"{self.retask_operator_keys!r}"[:300])
        if self.retask is True and not self.retask_operator_keys:
            raise ConfigError("service.retask_operator_keys: service.retask is true but no "
                              "operator key is listed: list the operator.pub of each "
                              "operator who may re-task (`pdcov keys new`)")
        if not isinstance(self.retask_limits, RetaskLimits):
            raise ConfigError("service.retask_limits: expected a mapping")
        for name in ("checkpoint_period_s", "home_wait_s", "retask_window_s"):
            _positive(name, getattr(self, name), "service")
        if not (isinstance(self.reorder_s, (int, float)) and 0 <= self.reorder_s <= 10):
            raise ConfigError(f"service.reorder_s: expected 0..10 s, got {self.reorder_s!r}")
        if self.frame_source is not None and self.frame_source not in FRAME_SOURCES:
            raise ConfigError(f"service.frame_source: expected one of "
                              f"{', '.join(FRAME_SOURCES)}, got {self.frame_source!r}")
        if self.target_pd is not None and not (isinstance(self.target_pd, (int, float))
                                               and 0 < self.target_pd <= 1):
            raise ConfigError(f"service.target_pd: expected a probability in (0, 1], got "
                              f"{self.target_pd!r}")
        for name in ("named_value_float", "statustext", "record", "retask"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"service.{name}: expected true or false")
        for name in ("record_max_bytes", "record_keep_bytes"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1 << 16):
                raise ConfigError(f"service.{name}: expected bytes >= 65536, got {v!r}")


def _positive(name: str, v: Any, section: str) -> None:
    if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
        raise ConfigError(f"{section}.{name}: expected a number > 0, got {v!r}")


SECTIONS = {"link": Section.of_dataclass(LinkConfig),
            "service": Section.of_dataclass(ServiceConfig),
            "bus": Section.of_dataclass(BusConfig)}


@dataclass(frozen=True, slots=True)
class ServeConfig:
    """Everything ``pdcov serve`` runs on: the mission and the daemon's three sections."""

    mission: Mission
    link: LinkConfig
    bus: BusConfig
    service: ServiceConfig
    base_dir: Path
    operator_keys: tuple[OperatorPublicKey, ...] = ()
    """The keys of service.retask_operator_keys, read."""

    @property
    def frame_source(self) -> str:
        return self.service.frame_source or self.mission.frame_source

    @property
    def target_pd(self) -> float:
        return self.service.target_pd or max(self.mission.thresholds)


def _section(doc: Mapping[str, Any], key: str, cls: type, src: str | None) -> Any:
    raw = doc.get(key) or {}
    if not isinstance(raw, Mapping):
        raise ConfigError(f"{where(src, key)}: expected a mapping")
    kw = {k: tuple(v) if isinstance(v, list) and k in ("connect", "retask_operator_keys")
          else v for k, v in raw.items()}
    if isinstance(kw.get("connect"), str):
        kw["connect"] = (kw["connect"],)
    try:
        if isinstance(kw.get("retask_limits"), Mapping):
            kw["retask_limits"] = RetaskLimits.from_service(raw)
        return cls(**kw)
    except ConfigError as exc:
        raise ConfigError(f"{src}: {exc}" if src else str(exc)) from None


def load_serve_config(path: str | Path) -> ServeConfig:
    """Read the mission config with the daemon's sections checked and parsed."""
    path = Path(path)
    mission = load_mission(path, sections=SECTIONS)
    raw = mission.raw
    service = _section(raw, "service", ServiceConfig, mission.source)
    keys = tuple(load_public_key(path.parent / k, f"{mission.source}: "
                                 "service.retask_operator_keys:")
                 for k in service.retask_operator_keys)
    cfg = ServeConfig(mission, _section(raw, "link", LinkConfig, mission.source),
                      bus_config_from_dict(raw.get("bus"), mission.source), service,
                      path.parent, keys)
    mission.cameras_frame_source(cfg.frame_source, "service.frame_source"
                                 if cfg.service.frame_source else "log.frame_source")
    return cfg


def mission_hash(mission: Mission, grid: CoverageGrid) -> str:
    """What a checkpoint must match to be resumed: SHA-256 (16 hex digits) of the vehicle
    id (another vehicle's frames resumed here would count twice in the fleet), the origin,
    the grid (geometry, free mask, max range, revisit interval, and the terrain's corner
    heights when it has them, and what stands on it: heights, kinds, k), the camera (size,
    intrinsics, distortion) and the detector model (bins, P_D, P_FA, input size), and the
    looks rule when not independent (rule, viewpoint bins, the model's correlation; each
    camera's with several), and with several cameras every camera (``_camera_doc``). The
    first camera's are hashed as the one camera was before cameras lists existed."""
    first, g = mission.first_camera, grid.geometry
    cam, det = first.camera, first.detector
    doc = {"vehicle_id": mission.vehicle_id,
           "origin": [mission.origin_lat_deg, mission.origin_lon_deg, mission.ground_alt_msl_m],
           "grid": [g.x0_m, g.y0_m, g.cell_size_m, g.n_rows, g.n_cols, grid.max_range_m,
                    grid.min_revisit_s],
           "camera": [cam.width_px, cam.height_px, np.asarray(cam.K, float).tolist(),
                      cam.distortion_model, np.asarray(cam.dist_coeffs, float).tolist()],
           "detector": [list(det.bin_edges_px), list(det.p_detect), list(det.p_false_alarm),
                        det.input_size_px, det.size_metric,
                        *([] if det.fa_rate_per_mpx is None else [list(det.fa_rate_per_mpx)])]}
    if first.zoom is not None:  # none: hashed as before zoom existed
        doc["zoom"] = repr(first.zoom)
    if mission.several_cameras:  # one camera: hashed as before cameras lists existed
        doc["cameras"] = [_camera_doc(c) for c in mission.cameras]
    h = hashlib.sha256(json.dumps(doc, sort_keys=True).encode())
    for packed in grid.free.packed_rows():  # band by band: np.packbits of the whole mask
        h.update(packed.tobytes())
    if mission.looks != LooksConfig():  # independent looks: hashed as before looks existed
        rho = [None if c.detector.looks is None else c.detector.looks.correlation
               for c in mission.cameras]
        h.update(repr((str(mission.looks.rule), mission.looks.viewpoint,
                       rho if mission.several_cameras else rho[0])).encode())
    if grid.terrain is not None:  # none: the flat ground, hashed as before terrain existed
        h.update(grid.terrain.z_corner_m.tobytes())
        cover = grid.terrain.cover
        if cover is not None:  # none: open ground, hashed as before ground cover existed
            h.update(cover.height_m.tobytes() + cover.kind.tobytes()
                     + repr(cover.extinction_per_m).encode())
    return h.hexdigest()[:16]


def _camera_doc(cam: MissionCamera) -> list[Any]:
    """What a checkpoint must match of one camera of a cameras list: name, rate, size,
    intrinsics, distortion, mount, zoom, exposure and detector model."""
    c, det = cam.camera, cam.detector
    return [cam.name, cam.frame_rate_hz, c.width_px, c.height_px,
            np.asarray(c.K, float).tolist(), c.distortion_model,
            np.asarray(c.dist_coeffs, float).tolist(), repr(cam.mount), repr(cam.zoom),
            cam.exposure_s, list(det.bin_edges_px), list(det.p_detect),
            list(det.p_false_alarm), det.input_size_px, det.size_metric,
            *([] if det.fa_rate_per_mpx is None else [list(det.fa_rate_per_mpx)])]


def replace_endpoints(cfg: ServeConfig, *, connect: list[str] | None,
                      zenoh_connect: list[str] | None, zenoh_listen: list[str] | None,
                      state_dir: str | None) -> ServeConfig:
    """The config with command-line overrides (each replaces the configured list)."""
    link = cfg.link if not connect else dataclasses.replace(
        cfg.link, connect=tuple(check_link_url(u, "--connect") for u in connect))
    bus = cfg.bus.with_endpoints(tuple(zenoh_connect) if zenoh_connect else None,
                                 tuple(zenoh_listen) if zenoh_listen else None)
    service = (cfg.service if state_dir is None
               else dataclasses.replace(cfg.service, state_dir=state_dir))
    return dataclasses.replace(cfg, link=link, bus=bus, service=service)

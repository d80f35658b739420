"""``pdcov-sitl fly``: the simulation loop.

Every 1/120 s step: guidance setpoint -> controller -> JSBSim F450 step; the gimbal follows;
the endpoint sends the telemetry streams that are due (built from the true state at that
step, stamped with the autopilot's time_boot_ms) and answers ground stations; at each camera
frame the true camera pose is kept for ``truth.csv``. Simulated time is the only clock the
flight depends on, so a seed gives the same tlog and truth (no ground station talking);
``speed`` only paces the loop against the wall clock (0: as fast as possible).

Camera frames: every 1/frame_rate_hz s from the moment the attitude, position and (for a
gimbal) gimbal streams have all been sent once, which is where ``pdcov evaluate --log``
places its frames too; with a camera trigger (config ``log.frame_source: capture`` or
``camera_trigger``) a CAMERA_IMAGE_CAPTURED is sent per frame and its time_boot_ms is the
frame time.

Over terrain (``FlyOptions.ground``, the mission's DEM): home and the take-off are on the
ground at the start point (home altitude = the ground's height there), JSBSim's ground follows
the terrain under the vehicle, terrain-frame waypoints and a terrain RTL follow it, and
TERRAIN_REPORT and DISTANCE_SENSOR are sent. truth.csv stays in the mission's ENU frame
(z = 0 at origin.ground_alt_msl_m, or home's altitude when the config has none).
"""

from __future__ import annotations

import csv
import math
import random
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pdcov.atomic import atomic_write
from pdcov.bus.session import BusConfig
from pdcov.config.mission import Mission, MissionCamera
from pdcov.core.geodesy import Origin, geodetic_to_enu
from pdcov.core.mission import MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL
from pdcov.core.pose import R_ENU_NED, R_GIMBAL_CAM, CameraPose, FixedMount
from pdcov.core.rotations import R_from_quat_wxyz, quat_wxyz_from_R, slerp_quat_wxyz
from pdcov.core.zoom import FovLens, hfov_rad
from pdcov.errors import InputFileError
from pdcov.planning.plan_files import read_mission
from pdcov.telemetry.pose_csv import POSE_CSV_COLUMNS

from .camera import CAMERA_COMPONENT, ZoomCamera
from .control import Controller
from .detector import DetectorOptions, SimulatedDetector
from .detector_out import DetectionOutput
from .dynamics import F450, VehicleState
from .faults import FaultSpec
from .gimbal import GimbalConfig, GimbalModel, _Rx, _Ry, _Rz, quat_from_euler_zyx, quat_from_R
from .guidance import Guidance
from .messages import (
    GIMBAL_CLOCK_OFFSET_S,
    GIMBAL_COMPONENT,
    GIMBAL_DEVICE_STREAMS_HZ,
    GIMBAL_FAILED_FLAGS,
    GNSS_ACCURACY_M,
    STREAMS_HZ,
    TERRAIN_STREAMS_HZ,
    GimbalMode,
    MessageBuilder,
    Rangefinder,
    Snapshot,
    autopilot_params,
    camera_image_captured,
    gimbal_device_messages,
    gimbal_report,
)
from .mission import AT_CURRENT_ALTITUDE, ReturnRule, flight_plan_from_items
from .protocol import Autopilot
from .targets import Targets, write_targets
from .terrain import GroundModel, LocalGround

POLL_EVERY_STEPS = 4
MAX_FLIGHT_S = 3 * 3600.0


@dataclass(frozen=True, slots=True)
class FlyOptions:
    """What ``pdcov-sitl fly`` was asked (cli.py validates and builds it)."""

    mission: Mission
    plan_path: Path | None
    out_dir: Path
    connect: str = "udpout:127.0.0.1:14550"
    speed: float = 1.0
    seed: int = 0
    gimbal_mode: GimbalMode = "ardupilot-device"
    gimbal_axes: int = 3
    faults: FaultSpec | None = None
    wind_mps: float = 0.0
    wind_from_deg: float = 270.0
    autopilot: Autopilot = "ardupilot"
    system_id: int = 1
    wait_mission: bool = False
    camera_trigger: bool = False
    signing_key: bytes | None = None
    ground: GroundModel | None = None
    """The world's ground (the mission's DEM); None: level at the origin's altitude."""
    rangefinder: Rangefinder = Rangefinder()
    gnss_accuracy_m: float = GNSS_ACCURACY_M
    """The GPS receiver's 1-sigma horizontal error per axis (m), GPS_RAW_INT's h_acc."""
    people: People | None = None
    """People on the ground and the simulated detector looking for them; None: none."""


@dataclass(frozen=True, slots=True)
class People:
    """``--targets``: the people (ENU about the mission's origin), the simulated detector's
    options, and the bus its boxes are published on (the mission's ``bus`` section)."""

    targets: Targets
    detector: DetectorOptions
    bus: BusConfig


@dataclass(frozen=True, slots=True)
class FlightResult:
    """What a flight did: simulated and wall seconds, frames, messages sent, paths."""

    sim_s: float
    wall_s: float
    frames: int
    messages: int
    tlog: Path
    truth: Path
    boxes: int = 0
    """Boxes the simulated detector reported (``--targets``)."""


def _gimbal_config(mode: str, axes: int, mount: FixedMount | object) -> GimbalConfig:
    """The simulated mount for a gimbal mode; a servo mount takes its limits from the
    config's gimbal mount where given (else ArduPilot's defaults) and reports them as
    MNT1_*_MIN/MAX."""
    if mode == "fixed":
        R = (mount.R_body_gimbal if isinstance(mount, FixedMount)
             else FixedMount().R_body_gimbal)
        return GimbalConfig(mode="fixed", R_body_gimbal=R)
    if mode == "ardupilot-servo":
        limits = GimbalConfig().limits_rad
        limits = tuple(
            (math.radians(conf[0]), math.radians(conf[1])) if conf is not None else default
            for conf, default in zip((getattr(mount, "roll_limits_deg", None),
                                      getattr(mount, "pitch_limits_deg", None),
                                      getattr(mount, "yaw_limits_deg", None)), limits,
                                     strict=True))
        # A digital servo: ~0.1 s per 60 deg, a small lag behind the demand.
        return GimbalConfig(mode="servo", tau_s=0.02, rate_limit_rps=math.radians(360),
                            limits_rad=limits)
    return GimbalConfig(mode="stabilised", axes=axes)


def _R_ned_body(s: VehicleState) -> np.ndarray:
    return _Rz(s.yaw_rad) @ _Ry(s.pitch_rad) @ _Rx(s.roll_rad)


@dataclass(frozen=True, slots=True)
class _Sample:
    """The true pose at one step: time, position (lat, lon, alt), attitudes."""

    t_s: float
    lat_deg: float
    lon_deg: float
    alt_msl_m: float
    q_ned_body: np.ndarray
    q_ned_gimbal: np.ndarray


def _sample(s: VehicleState, gimbal: GimbalModel) -> _Sample:
    R_body = _R_ned_body(s)
    return _Sample(s.t_s, s.lat_deg, s.lon_deg, s.alt_msl_m,
                   np.array(quat_from_euler_zyx(s.roll_rad, s.pitch_rad, s.yaw_rad)),
                   np.array(quat_from_R(gimbal.R_ned_gimbal(R_body))))


def _wait_for_mission(endpoint, vehicle: F450, gimbal: GimbalModel, send_due, speed: float
                      ) -> list:
    """Sit on the ground, sending telemetry, until a mission is uploaded over MAVLink; its
    items (home dropped)."""
    wall0 = time.monotonic()
    while endpoint.mission is None:
        s = vehicle.state()
        endpoint.poll(s.t_s)
        send_due(s, None)
        vehicle.set_motors(0.0, 0.0, 0.0, 0.0)
        gimbal.step(vehicle.dt_s, s.roll_rad, s.pitch_rad, s.yaw_rad)
        vehicle.step()
        lag = s.t_s / max(speed, 1.0) - (time.monotonic() - wall0)
        if lag > 0:
            time.sleep(lag)
    items = list(endpoint.mission)
    if items and items[0].command == MAV_CMD_NAV_WAYPOINT and items[0].frame == MAV_FRAME_GLOBAL:
        items = items[1:]  # ArduPilot-style: item 0 is home
    return items


def fly(opts: FlyOptions) -> FlightResult:
    """Fly the plan from take-off to landing; write DIR/flight.tlog and DIR/truth.csv."""
    from .endpoint import AutopilotEndpoint

    m = opts.mission
    ground = None
    if opts.ground is not None:
        try:
            ground = LocalGround(opts.ground, m.origin_lat_deg, m.origin_lon_deg)
        except ValueError as exc:
            raise InputFileError(f"{m.source or 'mission config'}: terrain: {exc}") from None
        home_alt = ground.home_alt_msl_m
    else:
        home_alt = m.ground_alt_msl_m if m.ground_alt_msl_m is not None else 0.0
    home = Origin(m.origin_lat_deg, m.origin_lon_deg, home_alt)
    origin = m.origin(home_alt if m.ground_alt_msl_m is None else None)
    mission = read_mission(opts.plan_path) if opts.plan_path is not None else None
    opts.out_dir.mkdir(parents=True, exist_ok=True)
    tlog, truth = opts.out_dir / "flight.tlog", opts.out_dir / "truth.csv"

    rng = random.Random(f"{opts.seed}:wind")
    wind_to = math.radians(opts.wind_from_deg + 180.0)
    wind = (opts.wind_mps * math.cos(wind_to), opts.wind_mps * math.sin(wind_to), 0.0)
    vehicle = F450(home.lat_deg, home.lon_deg, home_alt, heading_rad=0.0,
                   wind_ned_mps=wind, turbulence_mps=opts.wind_mps,
                   seed=rng.randrange(2**31), ground=opts.ground)
    controller = Controller(vehicle.dt_s)
    cam = m.first_camera  # the simulator flies one camera
    gcfg = _gimbal_config(opts.gimbal_mode, opts.gimbal_axes, cam.mount)
    gimbal = GimbalModel(gcfg, seed=opts.seed)
    lever = np.asarray(getattr(cam.mount, "lever_arm_frd_m", (0.0, 0.0, 0.0)), float)
    limits_deg = tuple((math.degrees(lo), math.degrees(hi)) for lo, hi in gcfg.limits_rad)
    has_gimbal = opts.gimbal_mode != "fixed"
    device = opts.gimbal_mode == "device-earth"
    streams = dict(STREAMS_HZ[opts.autopilot])
    if not has_gimbal or device:
        streams.pop("GIMBAL_DEVICE_ATTITUDE_STATUS")
    if ground is not None:
        streams.update(TERRAIN_STREAMS_HZ[opts.autopilot])
    endpoint = AutopilotEndpoint(
        opts.connect, system_id=opts.system_id, autopilot=opts.autopilot,
        params=autopilot_params(opts.autopilot, opts.gimbal_mode, opts.system_id, limits_deg,
                                opts.rangefinder if ground is not None else None),
        streams=streams, faults=opts.faults, seed=opts.seed, tlog_path=tlog,
        signing_key=opts.signing_key)
    endpoint.camera = _zoom_camera(cam, endpoint, opts.seed)
    detect = None
    try:
        if opts.people is not None:
            detect = _detection_loop(opts.people, m, origin, opts)
        return _run(opts, endpoint, vehicle, controller, gimbal, mission, home, origin,
                    ground, lever, has_gimbal, device, tlog, truth, detect)
    finally:
        endpoint.close()
        if detect is not None:
            detect.output.close()


def _zoom_camera(cam: MissionCamera, endpoint, seed: int) -> ZoomCamera | None:
    """The camera component of a camera that zooms by its field of view (camera.zoom
    fov_status): from the configured K's field of view (the widest) to
    camera.zoom_lens.min_hfov_deg; None otherwise."""
    if cam.zoom is None or not isinstance(cam.zoom.lens, FovLens):
        return None
    lens = cam.zoom.lens
    return ZoomCamera(endpoint.mav, system_id=endpoint.mav.srcSystem,
                      width_px=cam.camera.width_px, height_px=cam.camera.height_px,
                      wide_hfov_deg=math.degrees(hfov_rad(lens.wide)),
                      narrow_hfov_deg=math.degrees(lens.min_hfov_rad),
                      zoom_rate_per_s=0.5 * lens.max_rate_per_s, seed=seed)


@dataclass(frozen=True, slots=True)
class _DetectionLoop:
    """The simulated detector and where its boxes go (``--targets``)."""

    detector: SimulatedDetector
    output: DetectionOutput


def _detection_loop(people: People, m: Mission, origin: Origin, opts: FlyOptions
                    ) -> _DetectionLoop:
    """Write targets.csv; the detector (seeded by --seed) and its outputs (detections.csv,
    the Zenoh session)."""
    write_targets(opts.out_dir / "targets.csv", people.targets, origin)
    detector = SimulatedDetector(m.new_grid(m.first_camera), people.targets, people.detector,
                                 opts.seed)
    return _DetectionLoop(detector, DetectionOutput(people.bus, m.vehicle_id,
                                                    opts.out_dir / "detections.csv"))


def _guidance(opts: FlyOptions, items: list, source: str, default_speed_mps: float,
              home: Origin, ground: LocalGround | None, params: dict[str, float],
              start_s: float) -> Guidance:
    """The guidance along the mission's legs from ``start_s``, made when the flight starts:
    the return by the RTL parameters then in force (ArduPilot-like; PX4-like: at the last
    waypoint's altitude)."""
    rtl = ReturnRule.from_params(params) if opts.autopilot == "ardupilot" \
        else AT_CURRENT_ALTITUDE
    plan = flight_plan_from_items(items, home, source, default_speed_mps, ground=ground,
                                  rtl=rtl)
    try:
        return Guidance(plan, ground=ground, start_s=start_s)
    except ValueError as exc:
        raise InputFileError(f"{source}: {exc}") from None


def _run(opts, endpoint, vehicle, controller, gimbal, mission, home, origin, ground, lever,
         has_gimbal, device, tlog, truth, detect: _DetectionLoop | None) -> FlightResult:
    from .protocol import StreamSchedule

    mode = opts.gimbal_mode
    builder = MessageBuilder(endpoint.mav, opts.autopilot,
                             (home.lat_deg, home.lon_deg, home.ground_alt_msl_m), opts.seed,
                             ground=opts.ground, rangefinder=opts.rangefinder,
                             gnss_accuracy_m=opts.gnss_accuracy_m)
    device_schedule = (StreamSchedule(GIMBAL_DEVICE_STREAMS_HZ,
                                      random.Random(f"{opts.seed}:gimbal-device"))
                       if device else None)
    need = {"ATTITUDE", "GLOBAL_POSITION_INT"} | ({"GIMBAL_DEVICE_ATTITUDE_STATUS"}
                                                   if has_gimbal else set())
    frame_rate_hz = opts.mission.first_camera.frame_rate_hz  # the one camera flown
    first_sent: dict[str, float] = {}
    trigger = opts.camera_trigger or opts.mission.frame_source == "capture"
    guidance_box: list[Guidance | None] = [None]

    def phase_armed(t_s: float) -> tuple[str, bool]:
        g = guidance_box[0]
        if g is None or g.leg is None or g.done:
            return "ground", False
        return g.leg.kind, True

    def send_due(s: VehicleState, _unused) -> None:
        t = s.t_s
        # A MAVLink gimbal boots faster than the autopilot: its reports start first (and
        # the first frame then waits for the autopilot's attitude and position only).
        gimbal_up = device_schedule is None or "GIMBAL_DEVICE_ATTITUDE_STATUS" in first_sent
        names = endpoint.due(t) if gimbal_up else []
        device_names = (device_schedule.due(t)
                        if device_schedule is not None and not endpoint.is_down(t) else [])
        if not names and not device_names:
            return
        health = endpoint.gimbal_health(t)
        report = None
        wanted = "GIMBAL_DEVICE_ATTITUDE_STATUS" in names + device_names
        if has_gimbal and wanted and health.value != "silent":
            report = gimbal_report(mode, gimbal.R_ned_gimbal(_R_ned_body(s)), gimbal.demand,
                                   gimbal.angles)
        failure = GIMBAL_FAILED_FLAGS if health.value == "failed" else 0
        boot_ms = endpoint.time_boot_ms(t)
        if names:
            phase, armed = phase_armed(t)
            snap = Snapshot(s, boot_ms, endpoint.unix_time_us(t), endpoint.gps_offset_ned_m(t),
                            phase, armed, report[0] if report and not device else None,
                            report[1] if report else 0, failure,
                            report[2] if report else 0.0, 1.0 - t / 1500.0,
                            endpoint.gps_glitching(t))
            for name in names:
                msg = builder.build(name, snap)
                if msg is not None:
                    endpoint.send(msg, t)
                    if name in need and name not in first_sent and not endpoint.is_down(t):
                        first_sent[name] = boot_ms / 1000.0
        dev_ms = int((t + GIMBAL_CLOCK_OFFSET_S) * 1000)
        for name in device_names:
            if name != "HEARTBEAT" and report is None:
                continue
            q = report[0] if report and report[0] is not None else (1.0, 0.0, 0.0, 0.0)
            msg = gimbal_device_messages(endpoint.mav, name, dev_ms, q, failure,
                                         report[2] if report else 0.0)
            endpoint.send(msg, t, component_id=GIMBAL_COMPONENT)
            if name != "HEARTBEAT" and name not in first_sent:
                first_sent[name] = boot_ms / 1000.0

    wall0 = time.monotonic()
    if mission is None:
        items = _wait_for_mission(endpoint, vehicle, gimbal, send_due, opts.speed)
        source, speed = "the uploaded mission", 5.0
    else:
        items, source = list(mission.items), str(opts.plan_path)
        speed = 5.0 if math.isnan(mission.default_speed_mps) else mission.default_speed_mps
    guidance = _guidance(opts, items, source, speed, home, ground, endpoint.protocol.params,
                         vehicle.t_s + 1.0)
    guidance_box[0] = guidance
    dt = vehicle.dt_s
    frames: list[tuple[float, _Sample, _Sample]] = []
    next_frame_s = first_frame_s = math.inf
    before: _Sample | None = None
    frame_index = 0
    k = 0
    landed_s = math.inf
    zoom_done: tuple[int, float] | None = None  # the mission's last zoom command carried out
    while True:
        s = vehicle.state()
        t = s.t_s
        sp = guidance.setpoint(t)
        if guidance.done and landed_s == math.inf:
            landed_s = t
        if t > landed_s + 2.0 or t > MAX_FLIGHT_S:
            break
        if k % POLL_EVERY_STEPS == 0:
            endpoint.poll(t)
        send_due(s, None)
        if next_frame_s == math.inf and need <= first_sent.keys():
            # As pdcov evaluate places them: t0 + k / rate from where all streams cover.
            next_frame_s = first_frame_s = max(first_sent[n] for n in need)
        # Camera frames in (t - dt, t]: interpolate the true pose from the previous step.
        if before is not None and next_frame_s <= t + 1e-9:
            after = _sample(s, gimbal)
            while next_frame_s <= t + 1e-9:
                frames.append((next_frame_s, before, after))
                if trigger:
                    _send_capture(endpoint, builder, before, after, next_frame_s, frame_index,
                                  home, t)
                if detect is not None:
                    pose = _true_pose(next_frame_s, before, after, origin, lever)
                    detect.output.frame(round(endpoint.time_boot_s(next_frame_s), 3),
                                        detect.detector.frame(pose, next_frame_s))
                frame_index += 1
                next_frame_s = first_frame_s + frame_index / frame_rate_hz
            before = None
        if next_frame_s <= t + dt + 1e-9:
            before = _sample(s, gimbal)
        vehicle.set_motors(*controller.update(sp, s.r_ned_m, s.v_ned_mps, s.roll_rad,
                                              s.pitch_rad, s.yaw_rad, s.p_rps, s.q_rps,
                                              s.r_rps))
        gimbal.step(dt, s.roll_rad, s.pitch_rad, s.yaw_rad)
        if guidance.leg is not None:
            gimbal.command(guidance.leg.gimbal_pitch_rad, guidance.leg.gimbal_yaw_rad,
                           guidance.leg.gimbal_earth_yaw)
        camera = endpoint.camera
        if camera is not None:
            if guidance.leg is not None and guidance.leg.camera_zoom is not None \
                    and guidance.leg.camera_zoom != zoom_done:
                zoom_done = guidance.leg.camera_zoom
                camera.zoom(*zoom_done)
            camera.step(dt)
            if not endpoint.is_down(t):
                for msg in camera.due(t, endpoint.time_boot_ms(t)):
                    endpoint.send(msg, t, component_id=CAMERA_COMPONENT)
        vehicle.step()
        k += 1
        if opts.speed > 0:
            lag = t / opts.speed - (time.monotonic() - wall0)
            if lag > 0.002:
                time.sleep(lag)
    n = _write_truth(truth, frames, origin, lever)
    return FlightResult(vehicle.t_s, time.monotonic() - wall0, n, endpoint.n_sent, tlog, truth,
                        detect.output.boxes if detect is not None else 0)


def _interpolate(t_s: float, a: _Sample, b: _Sample
                 ) -> tuple[float, float, float, np.ndarray, np.ndarray]:
    w = 0.0 if b.t_s == a.t_s else (t_s - a.t_s) / (b.t_s - a.t_s)
    lat = a.lat_deg + w * (b.lat_deg - a.lat_deg)
    lon = a.lon_deg + w * (b.lon_deg - a.lon_deg)
    alt = a.alt_msl_m + w * (b.alt_msl_m - a.alt_msl_m)
    q = slerp_quat_wxyz(np.stack([a.q_ned_body, a.q_ned_gimbal]),
                        np.stack([b.q_ned_body, b.q_ned_gimbal]), np.array([w, w]))
    return lat, lon, alt, q[0], q[1]


def _send_capture(endpoint, builder: MessageBuilder, a: _Sample, b: _Sample, t_frame: float,
                  index: int, home: Origin, now_s: float) -> None:
    lat, lon, alt, _qb, qg = _interpolate(t_frame, a, b)
    ms = int(round(t_frame * 1000))
    msg = camera_image_captured(endpoint.mav, ms, endpoint.unix_time_us(t_frame), lat, lon,
                                alt, alt - home.ground_alt_msl_m, tuple(qg), index)
    endpoint.send(msg, now_s)


def _true_pose(t_s: float, a: _Sample, b: _Sample, origin: Origin, lever_frd_m: np.ndarray
               ) -> CameraPose:
    """The true camera pose at ``t_s`` between the steps ``a`` and ``b`` (ENU about
    ``origin``, the camera centre at the lever arm from the body's)."""
    lat, lon, alt, q_body, q_gimbal = _interpolate(t_s, a, b)
    R_ned_body = R_from_quat_wxyz(q_body)
    r_body = geodetic_to_enu(np.array(lat), np.array(lon), np.array(alt), origin)
    r_cam = r_body.reshape(3) + R_ENU_NED @ R_ned_body @ lever_frd_m
    return CameraPose(R_ENU_NED @ R_from_quat_wxyz(q_gimbal) @ R_GIMBAL_CAM, r_cam, t_s)


def _write_truth(path: Path, frames: list[tuple[float, _Sample, _Sample]], origin: Origin,
                 lever_frd_m: np.ndarray) -> int:
    """truth.csv in pdcov's pose CSV format: t_s, camera centre ENU m, q of R_enu_cam."""
    rows = []
    for t_s, a, b in frames:
        pose = _true_pose(t_s, a, b, origin, lever_frd_m)
        q = quat_wxyz_from_R(pose.R_enu_cam)
        rows.append([repr(float(t_s)), *map(repr, map(float, pose.r_cam_enu)),
                     *map(repr, map(float, q))])
    with atomic_write(path, "w", newline="") as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(POSE_CSV_COLUMNS)
        writer.writerows(rows)
    return len(rows)

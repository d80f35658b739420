"""What a gimbal's attitude report means, and whether to trust it.

GIMBAL_DEVICE_ATTITUDE_STATUS (MAVLink gimbal protocol v2) carries a quaternion whose frame
its flags give (``pose.gimbal_frame_from_flags``). A gimbal that measures its attitude
(Gremsy, Siyi, ...) honours that: interpretation ``flags``. An ArduPilot servo mount
(MNT1_TYPE 1) does not: AP_Mount_Servo::get_attitude_quaternion reports the body-frame servo
demand (earth-frame target minus the vehicle's roll and pitch, body yaw) although the flags
claim roll and pitch locked to the horizon: interpretation ``body``, which composes the
demand with the vehicle attitude through the servos' axis order and clips it to the mount's
angle limits. ``auto`` picks one from the autopilot's mount-type parameter. See
docs/autopilots.md for the measured error of each on a real flight.

Frames: the gimbal frame is x along the optical axis, y right, z down; R_ned_gimbal maps it
into NED; R_ned_body is the vehicle attitude (FRD -> NED).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from pdcov.core.mount import AXES, GimbalMount, R_body_gimbal_from_servos, servo_angles
from pdcov.core.pose import (
    GIMBAL_FLAG_RETRACT,
    GIMBAL_FLAG_YAW_IN_EARTH_FRAME,
    GIMBAL_FLAG_YAW_IN_VEHICLE_FRAME,
    GIMBAL_FLAG_YAW_LOCK,
)
from pdcov.core.rotations import R_from_quat_wxyz, quat_norm

QUAT_NORM_TOL = 1e-3
"""A gimbal quaternion whose norm is off 1 by more than this is not a rotation report."""

# GIMBAL_DEVICE_ERROR_FLAGS (common.xml) that make the reported attitude itself doubtful:
# encoder, power, motor, software, comms error, calibration running. AT_*_LIMIT (1, 2, 4)
# and NO_MANAGER (512) say the gimbal cannot follow its target, not that its report is wrong.
GIMBAL_ERROR_UNTRUSTED = 8 | 16 | 32 | 64 | 128 | 256

# ArduPilot MNTx_TYPE values whose GIMBAL_DEVICE_ATTITUDE_STATUS is a body-frame servo demand
# (AP_Mount_Params.cpp: 1 = Servo). 7 = BrushlessPWM reports the earth-frame roll/pitch target
# with body yaw, which is what its flags (yaw in vehicle frame) say.
ARDUPILOT_SERVO_MOUNT_TYPES = {1: "Servo"}
# Mount types whose report is an earth-frame demand, not a measured attitude (ArduCopter 4.7
# SITL: ../shared/ardupilot-sitl/README.md); read as the flags say, but said as what it is.
ARDUPILOT_EARTH_DEMAND_MOUNT_TYPES = {7: "BrushlessPWM"}


@dataclass(frozen=True, slots=True)
class GimbalInterpretation:
    """The interpretation in force: 'flags' or 'body', the servo limits (radians, rows
    roll/pitch/yaw, columns min/max; +-inf = none), and why it was chosen (for summaries)."""

    frame: str
    reason: str
    limits_rad: np.ndarray = field(default_factory=lambda: np.tile([-np.inf, np.inf], (3, 1)))
    limits_reason: str = "no servo limits"
    axis_order: tuple[str, str, str] = ("yaw", "roll", "pitch")
    limit_tolerance_rad: float = math.radians(0.5)

    def describe(self) -> str:
        if self.frame == "flags":
            return f"gimbal attitude read as its flags say ('flags': {self.reason})"
        order = "-".join(self.axis_order)
        return (f"gimbal attitude read as a body-frame servo demand ('body': {self.reason}); "
                f"servo axes {order}, {self.limits_reason}")


def limit_param_names(instance: int) -> tuple[tuple[str, str], ...]:
    """(min, max) ArduPilot 4.3+ limit parameters of mount ``instance``, per axis of AXES, in
    degrees (AP_Mount_Params.cpp: MNTn_{ROLL,PITCH,YAW}_{MIN,MAX})."""
    return tuple((f"MNT{instance}_{a.upper()}_MIN", f"MNT{instance}_{a.upper()}_MAX")
                 for a in AXES)


# Older firmware (e.g. ArduCopter 3.4, up to 4.2): one mount, limits in centidegrees.
LEGACY_LIMIT_PARAMS = (("MNT_ANGMIN_ROL", "MNT_ANGMAX_ROL"), ("MNT_ANGMIN_TIL", "MNT_ANGMAX_TIL"),
                       ("MNT_ANGMIN_PAN", "MNT_ANGMAX_PAN"))


def mount_param_names(instance: int) -> tuple[str, ...]:
    """ArduPilot 4.3+ parameters of mount ``instance`` that ``resolve_interpretation`` reads:
    MNTn_TYPE and the limits. While MNTn_TYPE is 0 (no mount) ArduPilot hides the others
    (AP_PARAM_FLAG_ENABLE), so a live read of them goes unanswered."""
    return (f"MNT{instance}_TYPE", *(n for pair in limit_param_names(instance) for n in pair))


def legacy_mount_param_names(instance: int) -> tuple[str, ...]:
    """The same for ArduPilot up to 4.2 (MNT_TYPE, MNT_ANGMIN/ANGMAX_ROL/TIL/PAN); () for
    instance > 1, which those versions did not have."""
    if instance != 1:
        return ()
    return ("MNT_TYPE", *(n for pair in LEGACY_LIMIT_PARAMS for n in pair))


# ArduPilot 4.3+ has up to two mounts (HAL_MOUNT_MAX_INSTANCES), each with MNTn_TYPE.
MOUNT_TYPE_PARAMS = ("MNT1_TYPE", "MNT2_TYPE")


def mount_params_to_read(instance: int) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(names, legacy): the one list of mount parameters every reader asks the autopilot
    for (the daemon, ``pdcov mount-check``), the ones ``resolve_interpretation`` decides by:
    the 4.3+ names of mount ``instance`` with both mounts' MNTn_TYPE, and the names of 4.2
    and older (``legacy_mount_param_names``). A log's parameters (tlog PARAM_VALUE,
    DataFlash PARM, ULog) hold whichever the firmware had; ``resolve_interpretation``
    reads either."""
    return (tuple(dict.fromkeys((*mount_param_names(instance), *MOUNT_TYPE_PARAMS))),
            legacy_mount_param_names(instance))


def mount_params_complete(values: Mapping[str, float], instance: int) -> bool:
    """Whether ``values`` hold every mount parameter of one firmware generation (then no
    more need to be waited for)."""
    names, legacy = mount_params_to_read(instance)
    return (all(n in values for n in names)
            or (bool(legacy) and all(n in values for n in legacy)))


def _param_limits(params: Mapping[str, float], n: int) -> tuple[np.ndarray, str] | None:
    names = limit_param_names(n)
    if all(lo in params and hi in params for lo, hi in names):
        return (np.radians([[params[lo], params[hi]] for lo, hi in names]),
                f"limits from MNT{n}_*_MIN/MAX")
    if n == 1 and all(lo in params and hi in params for lo, hi in LEGACY_LIMIT_PARAMS):
        return (np.radians([[params[lo] / 100, params[hi] / 100]
                            for lo, hi in LEGACY_LIMIT_PARAMS]),
                "limits from MNT_ANGMIN/ANGMAX_*")
    return None


def mount_type_param(params: Mapping[str, float], instance: int = 1) -> tuple[str, int] | None:
    """(name, value) of the autopilot's mount-type parameter, if the parameters hold it."""
    for name in (f"MNT{instance}_TYPE", "MNT_TYPE" if instance == 1 else ""):
        if name in params:
            return name, int(params[name])
    return None


def resolve_interpretation(mount: GimbalMount, params: Mapping[str, float],
                           params_origin: str = "the log") -> GimbalInterpretation:
    """Decide the interpretation in force from the config and the autopilot's parameters
    (MNTn_TYPE, MNTn_*_MIN/MAX; ArduPilot names), saying how it was decided."""
    if mount.attitude_frame == "auto":
        found = mount_type_param(params, mount.instance)
        if found is None:
            frame = mount.auto_fallback
            reason = (f"auto: {params_origin} has no MNT{mount.instance}_TYPE parameter, "
                      f"so mount.auto_fallback={frame!r} decides")
        else:
            name, value = found
            servo = ARDUPILOT_SERVO_MOUNT_TYPES.get(value)
            demand = ARDUPILOT_EARTH_DEMAND_MOUNT_TYPES.get(value)
            frame = "body" if servo else "flags"
            kind = (f"{servo} mount reports its servo demand" if servo
                    else f"{demand} mount reports its earth-frame demand, not a measured "
                         "attitude" if demand
                    else "the gimbal reports its attitude")
            reason = f"auto: {name}={value} in {params_origin}, {kind}"
    else:
        frame, reason = mount.attitude_frame, "configured"
    configured = [mount.roll_limits_deg, mount.pitch_limits_deg, mount.yaw_limits_deg]
    from_params = _param_limits(params, mount.instance)
    limits = np.tile([-np.inf, np.inf], (3, 1))
    sources = []
    for i, axis in enumerate(AXES):
        conf = configured[i]
        if conf is not None:
            limits[i] = np.radians(conf)
            sources.append(f"{axis} configured")
        elif from_params is not None:
            limits[i] = from_params[0][i]
            sources.append(f"{axis} {from_params[1]}")
    limits_reason = ("limits " + ", ".join(sources) + " "
                     + " ".join(f"{a} [{np.degrees(lo):.0f}, {np.degrees(hi):.0f}] deg"
                                for a, (lo, hi) in zip(AXES, limits, strict=True))
                     if sources else "no servo limits known")
    return GimbalInterpretation(frame, reason, limits, limits_reason, mount.servo_axis_order,
                                math.radians(mount.limit_tolerance_deg))


@dataclass(frozen=True, slots=True)
class GimbalAttitudes:
    """Interpreted gimbal attitudes for N reports: R_ned_gimbal (N, 3, 3), trusted (N,) and
    the reason a report is not trusted ('' when it is); ``usable`` is False where no
    rotation can be formed at all (NaN quaternion), whatever the untrusted policy;
    ``at_limit`` marks body-frame demands at a servo limit (clipped by the autopilot)."""

    R_ned_gimbal: np.ndarray
    trusted: np.ndarray
    reasons: np.ndarray
    usable: np.ndarray
    at_limit: np.ndarray


_AT_LIMIT_RAD = math.radians(0.05)


def earth_frame_mask(flags: np.ndarray) -> np.ndarray:
    """Vectorised ``pose.gimbal_frame_from_flags``: True where a report's quaternion is in the
    earth frame (NED), False where in the vehicle frame (NED turned by the heading).

    common.xml GIMBAL_DEVICE_ATTITUDE_STATUS: YAW_IN_EARTH_FRAME or YAW_IN_VEHICLE_FRAME
    decide; with neither, YAW_LOCK means earth frame."""
    flags = np.asarray(flags, np.int64)
    return ((flags & GIMBAL_FLAG_YAW_IN_EARTH_FRAME) != 0) | (
        ((flags & GIMBAL_FLAG_YAW_IN_VEHICLE_FRAME) == 0)
        & ((flags & GIMBAL_FLAG_YAW_LOCK) != 0))


def interpret_gimbal(q_wxyz: np.ndarray, flags: np.ndarray, failure_flags: np.ndarray,
                     R_ned_body: np.ndarray, interp: GimbalInterpretation) -> GimbalAttitudes:
    """Gimbal attitudes in NED for N reports (vectorised; N = 1 for a single report).

    q_wxyz (N, 4) as sent, flags and failure_flags (N,) as sent, R_ned_body (N, 3, 3) the
    vehicle attitude at the same instants.
    """
    q = np.asarray(q_wxyz, float).reshape(-1, 4)
    flags = np.asarray(flags, np.int64).reshape(-1)
    failure = np.asarray(failure_flags, np.int64).reshape(-1)
    R_ned_body = np.asarray(R_ned_body, float).reshape(-1, 3, 3)
    n = len(q)
    norm = quat_norm(q)
    usable = np.isfinite(norm) & (norm > 0.5)
    q_unit = np.where(usable[:, None], q / np.where(usable, norm, 1.0)[:, None], [1, 0, 0, 0])
    R_ref = R_from_quat_wxyz(q_unit).reshape(n, 3, 3)
    reasons = np.full(n, "", dtype=object)

    def distrust(mask: np.ndarray, why: str) -> None:
        reasons[mask & (reasons == "")] = why

    distrust(~usable, "gimbal quaternion missing or NaN")
    distrust(np.abs(norm - 1.0) > QUAT_NORM_TOL, "gimbal quaternion not unit")
    distrust((failure & GIMBAL_ERROR_UNTRUSTED) != 0, "gimbal failure flags")
    distrust((flags & GIMBAL_FLAG_RETRACT) != 0, "gimbal retracted")

    at_limit = np.zeros(n, bool)
    if interp.frame == "body":
        angles = servo_angles(R_ref, interp.limits_rad)
        clipped = np.clip(angles, interp.limits_rad[:, 0], interp.limits_rad[:, 1])
        over = np.abs(angles - clipped) > interp.limit_tolerance_rad
        # A yaw range of a full turn has no stop; float32 quaternions put a clipped demand
        # within ~1e-4 rad of its limit.
        stops = np.isfinite(interp.limits_rad) & (np.ptp(interp.limits_rad, axis=1) <
                                                   2 * np.pi - 1e-6)[:, None]
        near = np.abs(angles[:, :, None] - interp.limits_rad[None]) < _AT_LIMIT_RAD
        at_limit = usable & np.any(near & stops[None], axis=(1, 2))
        for i, axis in enumerate(AXES):
            distrust(over[:, i] & usable, f"servo at {axis} limit")
        R_ned_gimbal = R_ned_body @ R_body_gimbal_from_servos(clipped, interp.axis_order)
    else:
        earth = earth_frame_mask(flags)
        # A vehicle-frame report is turned by the heading: Rz(heading) @ R_ref, written out
        # (it mixes the first two rows).
        heading = np.arctan2(R_ned_body[:, 1, 0], R_ned_body[:, 0, 0])
        c, s = np.cos(heading)[:, None], np.sin(heading)[:, None]
        row0, row1 = R_ref[:, 0], R_ref[:, 1]
        turned = np.stack([c * row0 - s * row1, s * row0 + c * row1, R_ref[:, 2]], axis=1)
        R_ned_gimbal = np.where(earth[:, None, None], R_ref, turned)
    return GimbalAttitudes(R_ned_gimbal, reasons == "", reasons, usable, at_limit)


@dataclass(frozen=True, slots=True)
class GimbalVerdict:
    """One report interpreted: R_ned_gimbal (3, 3), trusted, and why not ('' if trusted)."""

    R_ned_gimbal: np.ndarray
    trusted: bool
    reason: str


def gimbal_attitude(q_wxyz: np.ndarray, flags: int, failure_flags: int,
                    R_ned_body: np.ndarray, interp: GimbalInterpretation) -> GimbalVerdict:
    """One gimbal report + the vehicle attitude -> R_ned_gimbal and a trust verdict.
    Raises ValueError when the quaternion is NaN or zero (no rotation to report)."""
    out = interpret_gimbal(np.asarray(q_wxyz)[None], np.asarray([flags], np.int64),
                           np.asarray([failure_flags], np.int64),
                           np.asarray(R_ned_body)[None], interp)
    if not out.usable[0]:
        raise ValueError(f"gimbal quaternion {q_wxyz!r} is not a rotation")
    return GimbalVerdict(out.R_ned_gimbal[0], bool(out.trusted[0]), str(out.reasons[0]))


def preferred_gimbal_source(flags_seen: Mapping[tuple[int, int, int], int],
                            autopilot_component: int = 1,
                            instance: int = 1) -> tuple[int, int, int]:
    """Which gimbal status source to follow among (system, component, gimbal_device_id) keys,
    given the OR of the flags each sent: the gimbal device's own report when it carries a
    YAW_IN_* flag (it knows its frame; gimbal protocol v2), else the autopilot's report for
    mount ``instance`` (gimbal_device_id 1..6 = a gimbal the autopilot reports on behalf of),
    else the autopilot's other reports, else the first key."""
    yaw_in = GIMBAL_FLAG_YAW_IN_VEHICLE_FRAME | GIMBAL_FLAG_YAW_IN_EARTH_FRAME
    keys = sorted(flags_seen)
    ranked = ([k for k in keys if k[1] != autopilot_component and flags_seen[k] & yaw_in]
              + [k for k in keys if k[1] == autopilot_component and k[2] == instance]
              + [k for k in keys if k[1] == autopilot_component] + keys)
    return ranked[0]

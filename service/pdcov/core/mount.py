"""The physical gimbal mount: its servo axes, angle limits and lever arm, and how its servos
turn a body-frame demand into angles. Planning flies it; telemetry/gimbal.py reads its reports.

Frames: the gimbal frame is x along the optical axis, y right, z down; R_body_demand maps it
into the vehicle body (FRD).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from pdcov.core.rotations import euler_zyx_from_R_many
from pdcov.errors import ConfigError, where
from pdcov.schema import Section, check_keys

ATTITUDE_FRAMES = ("flags", "body", "auto")
UNTRUSTED_POLICIES = ("skip", "use")
AXES = ("roll", "pitch", "yaw")


def _limits(doc: Mapping, key: str, source: str | None) -> tuple[float, float] | None:
    value = doc.get(key)
    if value is None:
        return None
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ConfigError(f"{where(source, 'mount.' + key)}: expected [min_deg, max_deg], "
                          f"got {value!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and -360.0 <= lo <= hi <= 360.0):
        raise ConfigError(f"{where(source, 'mount.' + key)}: expected finite "
                          f"-360 <= min <= max <= 360 degrees, got {value!r}")
    return (lo, hi)


@dataclass(frozen=True, slots=True)
class GimbalMount:
    """A camera on a gimbal that reports its attitude (mission config ``mount: {type: gimbal}``).

    attitude_frame: 'flags' | 'body' | 'auto' (see module docstring). auto_fallback: what
    'auto' uses when the log or link gives no mount-type parameter. servo_axis_order: the
    servos from the body outwards in: the default ('yaw', 'roll', 'pitch') = R_body_gimbal =
    Rz(yaw) Rx(roll) Ry(pitch), the common 3-axis build (camera on the tilt axis), and the
    one in which ArduPilot's roll/pitch compensation is exact (docs/autopilots.md).
    *_limits_deg: servo angle limits [min, max] in degrees; None = the autopilot's
    MNTn_*_MIN/MAX parameters where known, else unlimited. limit_tolerance_deg: a demand
    further than this past a limit makes the frame untrusted (a demand exactly at a limit,
    as the 4.7 servo backend reports it clipped, is counted but trusted: the servo is there).
    untrusted: 'skip' or 'use' untrusted frames. lever_arm_frd_m: camera centre from the
    vehicle reference point, FRD m. instance: n of MNTn_* and the autopilot's
    gimbal_device_id.
    """

    attitude_frame: str = "auto"
    auto_fallback: str = "flags"
    servo_axis_order: tuple[str, str, str] = ("yaw", "roll", "pitch")
    roll_limits_deg: tuple[float, float] | None = None
    pitch_limits_deg: tuple[float, float] | None = None
    yaw_limits_deg: tuple[float, float] | None = None
    limit_tolerance_deg: float = 0.5
    untrusted: str = "skip"
    lever_arm_frd_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    instance: int = 1

    def __post_init__(self) -> None:
        if self.attitude_frame not in ATTITUDE_FRAMES:
            raise ConfigError(f"mount.attitude_frame: expected one of {ATTITUDE_FRAMES}, "
                              f"got {self.attitude_frame!r}")
        if self.auto_fallback not in ("flags", "body"):
            raise ConfigError(f"mount.auto_fallback: expected 'flags' or 'body', "
                              f"got {self.auto_fallback!r}")
        if sorted(self.servo_axis_order) != sorted(AXES):
            raise ConfigError(f"mount.servo_axis_order: expected a permutation of {AXES}, "
                              f"got {self.servo_axis_order!r}")
        if self.untrusted not in UNTRUSTED_POLICIES:
            raise ConfigError(f"mount.untrusted: expected one of {UNTRUSTED_POLICIES}, "
                              f"got {self.untrusted!r}")
        if not (math.isfinite(self.limit_tolerance_deg) and self.limit_tolerance_deg >= 0):
            raise ConfigError("mount.limit_tolerance_deg: expected a finite value >= 0")
        if len(self.lever_arm_frd_m) != 3 or not np.all(np.isfinite(self.lever_arm_frd_m)):
            raise ConfigError("mount.lever_arm_frd_m: expected 3 finite numbers (metres)")
        if not 1 <= self.instance <= 6:
            raise ConfigError(f"mount.instance: expected 1..6, got {self.instance!r}")

    @classmethod
    def from_config(cls, doc: Mapping, source: str | None = None) -> GimbalMount:
        """From the mission config's ``mount`` mapping (``type: gimbal``); errors name
        ``source`` (the file) and the key."""
        if not isinstance(doc, Mapping):
            raise ConfigError(f"{where(source, 'mount')}: expected a mapping, got {doc!r}")
        check_keys(dict(doc), GIMBAL_MOUNT_CONFIG, source, "mount")
        if doc.get("type", "gimbal") != "gimbal":
            raise ConfigError(f"{where(source, 'mount.type')}: expected 'gimbal', "
                              f"got {doc.get('type')!r}")
        kwargs: dict = {}
        for key in ("attitude_frame", "auto_fallback", "untrusted"):
            if key in doc:
                kwargs[key] = str(doc[key])
        order = doc.get("servo_axis_order")
        if order is not None:
            parts = order.split("_") if isinstance(order, str) else list(order)
            if sorted(parts) != sorted(AXES):
                raise ConfigError(f"{where(source, 'mount.servo_axis_order')}: expected the "
                                  f"three axes outer to inner, e.g. yaw_pitch_roll, got {order!r}")
            kwargs["servo_axis_order"] = tuple(parts)
        for key in ("roll_limits_deg", "pitch_limits_deg", "yaw_limits_deg"):
            kwargs[key] = _limits(doc, key, source)
        try:
            if "limit_tolerance_deg" in doc:
                kwargs["limit_tolerance_deg"] = float(doc["limit_tolerance_deg"])
            if "lever_arm_frd_m" in doc:
                arm = tuple(float(v) for v in doc["lever_arm_frd_m"])
                kwargs["lever_arm_frd_m"] = arm
            if "instance" in doc:
                kwargs["instance"] = int(doc["instance"])
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{where(source, 'mount')}: {exc}") from None
        try:
            return cls(**kwargs)
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}" if source else str(exc)) from None


# The mission config's ``mount`` keys for a gimbal: the fields of GimbalMount, and its type.
GIMBAL_MOUNT_CONFIG = Section.of_dataclass(GimbalMount, type=None)


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def axis_R(axis: str, angle: np.ndarray) -> np.ndarray:
    """Rotations (..., 3, 3) by ``angle`` (rad, any shape) about one axis: roll = x, pitch = y,
    yaw = z of the frame it turns."""
    c, s = np.cos(angle), np.sin(angle)
    z, o = np.zeros_like(angle), np.ones_like(angle)
    rows = {"roll": [[o, z, z], [z, c, -s], [z, s, c]],
            "pitch": [[c, z, s], [z, o, z], [-s, z, c]],
            "yaw": [[c, -s, z], [s, c, z], [z, z, o]]}[axis]
    return np.moveaxis(np.array(rows), (0, 1), (-2, -1))


def servo_angles(R_body_demand: np.ndarray, limits_rad: np.ndarray) -> np.ndarray:
    """Servo demand angles (N, 3: roll, pitch, yaw rad) of body-frame demands (N, 3, 3).

    ArduPilot builds the reported quaternion from z-y-x Euler angles (Quaternion::from_euler)
    that may lie outside [-90, 90] deg of pitch (e.g. -110 deg when nose-up with the camera
    at nadir). Both Euler branches give the same rotation; the one closer to the servo limits
    is taken (at pitch +-90 deg roll is 0 and yaw takes the rest, rotations.py).
    """
    a = euler_zyx_from_R_many(R_body_demand)
    b = np.stack([_wrap(a[:, 0] + np.pi), _wrap(-np.pi - a[:, 1]), _wrap(a[:, 2] + np.pi)],
                 axis=1)
    def excess(x: np.ndarray) -> np.ndarray:
        return (np.clip(limits_rad[:, 0] - x, 0, None) + np.clip(x - limits_rad[:, 1], 0, None)
                ).sum(axis=1)
    return np.where((excess(b) < excess(a) - 1e-9)[:, None], b, a)


def R_body_gimbal_from_servos(angles_rad: np.ndarray, axis_order: tuple[str, str, str]
                              ) -> np.ndarray:
    """The camera's rotation on the body (N, 3, 3) from servo angles (N, 3: roll, pitch, yaw
    rad), composing the servos from the body outwards in (``GimbalMount.servo_axis_order``)."""
    idx = {a: i for i, a in enumerate(AXES)}
    R_body_gimbal = np.broadcast_to(np.eye(3), (len(angles_rad), 3, 3))
    for axis in axis_order:  # outermost servo first
        R_body_gimbal = R_body_gimbal @ axis_R(axis, angles_rad[:, idx[axis]])
    return R_body_gimbal

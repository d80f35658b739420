"""Short known flights as pdcov's samples (a drifting attitude, positions, home, a gimbal),
for the tests of the telemetry log readers."""

from __future__ import annotations

from pdcov.core.rotations import quat_wxyz_from_euler_zyx
from pdcov.telemetry.samples import AttitudeSample, GimbalSample, HomeSample, PositionSample

LAT, LON, ALT = -35.363261, 149.165230, 584.0


def flight(t0: float = 1.0, n: int = 50, dt: float = 0.1, sysid: int = 1) -> list[object]:
    out: list[object] = []
    for k in range(n):
        t = t0 + k * dt
        q = tuple(quat_wxyz_from_euler_zyx(0.01 * k, -0.02 * k, 0.03 * k))
        out.append(AttitudeSample(t, q))
        out.append(PositionSample(t, LAT + 1e-6 * k, LON, ALT + 10.0, 10.0))
    out.append(HomeSample(t0, LAT, LON, ALT, "HOME_POSITION"))
    return out


def gimbal_flight() -> list[object]:
    samples = flight()
    q = tuple(quat_wxyz_from_euler_zyx(0, -1.0, 0))
    samples += [GimbalSample(1.0 + 0.1 * k, q, 44, 0, 1, 1, 1) for k in range(50)]
    return samples

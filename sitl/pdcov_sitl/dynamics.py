"""The JSBSim F450 quadcopter: load, step at 120 Hz, per-motor commands, wind, state.

JSBSim ships aircraft/F450 (DESIGN.md "Facts measured here"): four DJI E305 motors with
9450 propellers in an X, no autopilot of its own (its rate loop is disengaged). We drive the
motors through the external inputs ``fcs/cmd{FR,AL,FL,AR}_ext_nd`` (0..1), which JSBSim sums
into the ESC commands ``fcs/throttle-pos-norm[0..3]``.

Frames: NED for positions and velocities about the start point (flat earth, for control
only; the true position is the geodetic one), body FRD for rates, attitude z-y-x Euler
angles body -> NED. Units SI and radians.

The ground: JSBSim's terrain elevation (``position/terrain-elevation-asl-ft``, where its
ground reactions put the gear's contact) is the world's ground height under the vehicle
(``terrain.GroundModel``), updated every step within ``GROUND_NEAR_M`` of it and every
``GROUND_EVERY_STEPS`` steps above (only ``height_agl_m`` depends on it up there).
"""

from __future__ import annotations

import contextlib
import math
import os
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .terrain import GroundModel

FT_M = 0.3048
STEP_HZ = 120.0
WGS84_A_M = 6378137.0
WGS84_E2 = 6.69437999014e-3
GROUND_NEAR_M = 10.0
GROUND_EVERY_STEPS = 12
MOTORS = ("FR", "AL", "FL", "AR")
"""Motor order of ``set_motors``: front right, aft left, front left, aft right (JSBSim
F450 engines 0..3; FR and AL spin one way, FL and AR the other)."""


def local_scales(lat_deg: float) -> tuple[float, float]:
    """Metres per radian of latitude (meridian radius) and of longitude (parallel radius)
    at ``lat_deg`` on WGS84: the flat-earth NED frame about a point, good to ~1e-5 over a
    few hundred metres."""
    s2 = math.sin(math.radians(lat_deg)) ** 2
    w = math.sqrt(1.0 - WGS84_E2 * s2)
    return (WGS84_A_M * (1.0 - WGS84_E2) / w**3,
            WGS84_A_M / w * math.cos(math.radians(lat_deg)))


@dataclass(frozen=True, slots=True)
class VehicleState:
    """The true vehicle state at one instant.

    t_s: simulated seconds since start. lat_deg/lon_deg geodetic, alt_msl_m above the WGS84
    ellipsoid (taken as MSL). r_ned_m: NED metres about the start point (flat earth).
    v_ned_mps: velocity in NED. roll/pitch/yaw_rad: z-y-x Euler angles body FRD -> NED.
    p/q/r_rps: body rates (FRD) rad/s. height_agl_m: height of the CG above the ground.
    """

    t_s: float
    lat_deg: float
    lon_deg: float
    alt_msl_m: float
    r_ned_m: tuple[float, float, float]
    v_ned_mps: tuple[float, float, float]
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    p_rps: float
    q_rps: float
    r_rps: float
    height_agl_m: float


@contextlib.contextmanager
def _quiet_stdout():
    """JSBSim prints its banner, an "incompatible CFG file" warning and "failed to tie
    property" lines on load (harmless, DESIGN.md); keep them off our stdout."""
    fd = os.dup(1)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            yield
    finally:
        os.dup2(fd, 1)
        os.close(fd)


class F450:
    """The F450 in JSBSim, standing on the ground at (lat_deg, lon_deg) whose altitude is
    ground_alt_msl_m, nose towards heading_rad (from north, clockwise). ground: the world's
    ground heights (None: level at ground_alt_msl_m everywhere).

    wind_ned_mps: steady wind (where the air goes) in NED; turbulence_mps > 0 adds JSBSim's
    MIL-spec (Tustin) turbulence of that wind speed at 20 ft. seed: JSBSim's random seed
    (turbulence), so that runs are repeatable.
    """

    def __init__(self, lat_deg: float, lon_deg: float, ground_alt_msl_m: float,
                 heading_rad: float = 0.0, wind_ned_mps: tuple[float, float, float] = (0, 0, 0),
                 turbulence_mps: float = 0.0, seed: int = 0,
                 ground: GroundModel | None = None) -> None:
        import jsbsim

        with _quiet_stdout():
            fdm = jsbsim.FGFDMExec(jsbsim.get_default_root_dir())
            fdm.set_debug_level(0)
            if not fdm.load_model("F450"):
                raise RuntimeError("JSBSim could not load aircraft/F450")
        fdm.set_dt(1.0 / STEP_HZ)
        fdm["simulation/randomseed"] = int(seed) % (2**31)
        fdm["ic/lat-geod-deg"] = lat_deg
        fdm["ic/long-gc-deg"] = lon_deg
        fdm["ic/terrain-elevation-ft"] = ground_alt_msl_m / FT_M
        fdm["ic/h-agl-ft"] = 0.15 / FT_M  # the gear's rest height
        fdm["ic/psi-true-deg"] = math.degrees(heading_rad)
        for i in range(4):
            fdm[f"fcs/throttle-cmd-norm[{i}]"] = 0.0
        with _quiet_stdout():
            fdm.run_ic()
        # After run_ic, which resets the winds (set before it, they were silently lost).
        fdm["atmosphere/wind-north-fps"] = wind_ned_mps[0] / FT_M
        fdm["atmosphere/wind-east-fps"] = wind_ned_mps[1] / FT_M
        fdm["atmosphere/wind-down-fps"] = wind_ned_mps[2] / FT_M
        fdm["atmosphere/turb-type"] = 3 if turbulence_mps > 0 else 0  # 3: MIL-spec, Tustin
        if turbulence_mps > 0:
            fdm["atmosphere/turbulence/milspec/windspeed_at_20ft_AGL-fps"] = \
                turbulence_mps / FT_M
            fdm["atmosphere/turbulence/milspec/severity"] = 3  # light to moderate
        self._fdm = fdm
        self._get = fdm.get_property_value
        self._set = fdm.set_property_value
        self._motor_props = tuple(f"fcs/cmd{m}_ext_nd" for m in MOTORS)
        self._lat0_rad = math.radians(lat_deg)
        self._lon0_rad = math.radians(lon_deg)
        self.m_per_rad_north, self.m_per_rad_east = local_scales(lat_deg)
        self._ground_alt_msl_m = ground_alt_msl_m
        self._ground = ground
        self._steps = 0
        self.t_s = 0.0
        self.dt_s = 1.0 / STEP_HZ

    def set_motors(self, fr: float, al: float, fl: float, ar: float) -> None:
        """ESC commands 0..1 per motor (order MOTORS); JSBSim clips to [0, 1]."""
        s, p = self._set, self._motor_props
        s(p[0], fr)
        s(p[1], al)
        s(p[2], fl)
        s(p[3], ar)

    def step(self) -> None:
        """Advance one 1/120 s step."""
        if self._ground is not None:
            self._follow_ground(self._ground)
        self._fdm.run()
        self.t_s += self.dt_s

    def _follow_ground(self, ground: GroundModel) -> None:
        """Set JSBSim's terrain elevation to the ground under the vehicle (kept where the
        ground model has no height)."""
        self._steps += 1
        g = self._get
        if (g("position/h-agl-ft") * FT_M > GROUND_NEAR_M
                and self._steps % GROUND_EVERY_STEPS):
            return
        h = float(ground.height_msl_m(math.degrees(g("position/lat-geod-rad")),
                                      math.degrees(g("position/long-gc-rad"))))
        if math.isfinite(h):
            self._set("position/terrain-elevation-asl-ft", h / FT_M)

    def state(self) -> VehicleState:
        g = self._get
        lat_rad = g("position/lat-geod-rad")
        lon_rad = g("position/long-gc-rad")
        alt_m = g("position/geod-alt-ft") * FT_M
        n = (lat_rad - self._lat0_rad) * self.m_per_rad_north
        e = (lon_rad - self._lon0_rad) * self.m_per_rad_east
        d = self._ground_alt_msl_m - alt_m
        return VehicleState(
            self.t_s, math.degrees(lat_rad), math.degrees(lon_rad), alt_m, (n, e, d),
            (g("velocities/v-north-fps") * FT_M, g("velocities/v-east-fps") * FT_M,
             g("velocities/v-down-fps") * FT_M),
            g("attitude/phi-rad"), g("attitude/theta-rad"), g("attitude/psi-rad"),
            g("velocities/p-rad_sec"), g("velocities/q-rad_sec"), g("velocities/r-rad_sec"),
            g("position/h-agl-ft") * FT_M)

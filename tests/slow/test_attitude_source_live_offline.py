"""ATTITUDE and ATTITUDE_QUATERNION together (ArduPilot sends both): the daemon takes the
quaternion until the first ATTITUDE arrives, ATTITUDE from then on (LinkProtocol.receive),
and the tlog reader applies the same rule in log order. A link opened between the two
messages of one attitude (a serial device read late, a backlog) starts with a
GLOBAL_POSITION_INT and an ATTITUDE_QUATERNION before any ATTITUDE: the first frame then
lies at the quaternion's time, live and offline alike. The tlog reader used to drop every
quaternion of a log holding any ATTITUDE, so its frames started at the first ATTITUDE's
time (25 ms later) and no frame matched the daemon's grid."""

from __future__ import annotations

import math
import random
import struct
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.core.rotations import quat_wxyz_from_euler_zyx
from pdcov.telemetry.logs import read_flight_log
from tests.support.blur_detector import blur_detector
from tests.support.link_feed import (
    GROUND_M,
    LAT_DEG,
    LON_DEG,
    MISSION,
    LinkFeed,
    offline_of,
    pack,
    serve_config,
)


def flying_north(seconds: float = 6.0) -> list[mavlink.MAVLink_message]:
    """A vehicle 12 m up flying north at 4 m/s over the domain while turning, the messages in
    the simulator's order: ATTITUDE 20 Hz at 16 + 50 k ms, ATTITUDE_QUATERNION 20 Hz at
    41 + 50 k ms, GLOBAL_POSITION_INT 10 Hz with every other ATTITUDE; a HEARTBEAT each
    second. The stream begins as a link opened just after an ATTITUDE: with the
    GLOBAL_POSITION_INT of 1016 ms, then the quaternion of 1041 ms."""
    mav = mavlink.MAVLink(None)
    east_m, deg_per_m = 15.0, 1.0 / 111_320.0

    def yaw_rad(ms: int) -> float:
        return 0.3 + 0.5 * (ms / 1000.0 - 1.0)

    def position(ms: int) -> mavlink.MAVLink_message:
        north_m = 2.0 + 4.0 * (ms / 1000.0 - 1.0)
        return mav.global_position_int_encode(
            ms, round((LAT_DEG + north_m * deg_per_m) * 1e7),
            round((LON_DEG + east_m * deg_per_m / math.cos(math.radians(LAT_DEG))) * 1e7),
            round((GROUND_M + 12) * 1000), 12_000, 0, 0, 0, 0)

    out = [position(1016)]
    for k in range(int(seconds * 20)):
        q_ms, a_ms = 1041 + 50 * k, 1066 + 50 * k
        q = quat_wxyz_from_euler_zyx(0.05, -0.1, yaw_rad(q_ms)).reshape(4)
        out.append(mav.attitude_quaternion_encode(q_ms, *map(float, q), 0, 0, 0))
        if k % 20 == 5:
            out.append(mav.heartbeat_encode(2, 3, 128 | 1, 4, 4))
        out.append(mav.attitude_encode(a_ms, 0.05, -0.1, yaw_rad(a_ms), 0, 0, 0))
        if k % 2 == 1:
            out.append(position(a_ms))
    return out


def chunkings(data: list[bytes]) -> dict[str, list[bytes]]:
    """The same bytes as one backlog read, message by message, and cut at random places
    (inside messages too)."""
    whole = b"".join(data)
    rng = random.Random(7)
    cuts = sorted(rng.sample(range(1, len(whole)), 60))
    return {"one read": [whole], "per message": data,
            "random cuts": [whole[a:b] for a, b in zip([0, *cuts], [*cuts, len(whole)],
                                                       strict=True)]}


@pytest.mark.parametrize("how", ["one read", "per message", "random cuts"])
def test_link_starting_with_a_quaternion_gives_the_offline_grid(tmp_path: Path,
                                                                 how: str) -> None:
    msgs = flying_north()
    data = [pack(m, seq=i) for i, m in enumerate(msgs)]
    tlog = tmp_path / "late.tlog"
    tlog.write_bytes(b"".join(struct.pack(">Q", 1_700_000_000_000_000 + 1000 * i) + d
                              for i, d in enumerate(data)))
    cfg = serve_config(tmp_path, gimbal=False)

    # Offline: the quaternion before the first ATTITUDE is an attitude sample, the later
    # quaternions are not.
    att_t = read_flight_log(tlog).attitude.t_s
    assert att_t[0] == pytest.approx(1.041) and att_t[1] == pytest.approx(1.066)
    assert np.allclose(np.diff(att_t[1:]), 0.05)
    lp, off = offline_of(cfg, tlog)

    feed = LinkFeed(cfg)
    for i, chunk in enumerate(chunkings(data)[how]):
        feed.feed(chunk, 0.01 * i)
    feed.tick(10.0)
    live = feed.live
    assert live.t0_s == pytest.approx(1.041)  # max(first attitude, first position)
    assert lp.poses[0].t_s == live.t0_s
    assert live.grid.frames == off.frames == len(lp.poses) > 20
    for key in ("log_miss_d", "log_miss_fa", "n_obs"):
        np.testing.assert_array_equal(getattr(live.grid, key), getattr(off, key), err_msg=key)


def test_another_component_s_attitude_and_position_are_not_the_vehicle_s(tmp_path: Path
                                                                         ) -> None:
    """A companion computer or OSD of the same system (component 197) sending ATTITUDE and
    GLOBAL_POSITION_INT of its own (here yawed 90 deg and 40 m off) changes nothing: live and
    offline take the autopilot's, and both give the grid of the autopilot's messages alone."""
    msgs = flying_north()
    own = [pack(m, seq=i) for i, m in enumerate(msgs)]
    mav = mavlink.MAVLink(None)
    mixed: list[bytes] = []
    for i, m in enumerate(msgs):
        mixed.append(own[i])
        if m.get_type() == "ATTITUDE":
            other = mav.attitude_encode(m.time_boot_ms + 5, 0.0, 0.0, m.yaw + 1.57, 0, 0, 0)
            mixed.append(pack(other, component_id=197, seq=i))
        elif m.get_type() == "GLOBAL_POSITION_INT":
            other = mav.global_position_int_encode(m.time_boot_ms + 5, m.lat + 3600, m.lon,
                                                   m.alt, m.relative_alt, 0, 0, 0, 0)
            mixed.append(pack(other, component_id=197, seq=i))
    cfg = serve_config(tmp_path, gimbal=False)
    grids = {}
    for name, data in (("own", own), ("mixed", mixed)):
        _lp, off = offline_of(cfg, write_tlog(tmp_path / f"{name}.tlog", data))
        live = live_grid(cfg, data)
        assert live.frames == off.frames > 20, name
        for key in ("log_miss_d", "log_miss_fa", "n_obs"):
            np.testing.assert_array_equal(getattr(live, key), getattr(off, key),
                                          err_msg=f"{name} {key}")
        grids[name] = live
    for key in ("log_miss_d", "log_miss_fa", "n_obs"):
        np.testing.assert_array_equal(getattr(grids["mixed"], key), getattr(grids["own"], key),
                                      err_msg=key)


# P_D falls with the blur (0-1, 1-2, 2-4, 4-8 px) in each size bin.
BLUR_MODEL = blur_detector((0.0, 1.0, 2.0, 4.0, 8.0), (1.0, 0.8, 0.5, 0.2)).to_dict()


def write_tlog(path: Path, data: list[bytes]) -> Path:
    """The messages as a tlog, 1 ms apart in its timestamps."""
    path.write_bytes(b"".join(struct.pack(">Q", 1_700_000_000_000_000 + 1000 * i) + d
                              for i, d in enumerate(data)))
    return path


def live_grid(cfg, data: list[bytes]):
    """The daemon's grid of the messages fed one by one, 10 ms apart."""
    feed = LinkFeed(cfg)
    for i, d in enumerate(data):
        feed.feed(d, 0.01 * i)
    feed.tick(10.0)
    return feed.live.grid


def test_live_grid_with_motion_blur_is_the_offline_grid(tmp_path: Path) -> None:
    """With camera.exposure_s and a detector model with blur bins, the daemon's grid (the
    camera's velocity and angular rate from the telemetry it has when each frame is due)
    equals evaluate's of the same bytes, cell for cell; blur applied to every frame, and it
    cost detection against the same flight without exposure_s."""
    data = [pack(m, seq=i) for i, m in enumerate(flying_north())]
    tlog = write_tlog(tmp_path / "f.tlog", data)
    camera = {**MISSION["camera"], "exposure_s": 0.02}
    cfg = serve_config(tmp_path, gimbal=False, camera=camera, detector=BLUR_MODEL)
    lp, off = offline_of(cfg, tlog)
    live = live_grid(cfg, data)
    assert live.frames == off.frames == len(lp.poses) > 20
    # All but the first frame, at the first attitude sample: no sample before it gives its
    # rate, so its P_D is by size only.
    assert live.frames_blurred == off.frames_blurred == live.frames - 1
    assert not lp.poses[0].has_motion and all(p.has_motion for p in lp.poses[1:])
    for key in ("log_miss_d", "log_miss_fa", "n_obs", "limiting"):
        np.testing.assert_array_equal(getattr(live, key), getattr(off, key), err_msg=key)
    # 4 m/s at 12 m with f = 480 px over 20 ms: 3.2 px of blur, and the yaw rate's on top.
    assert all(np.linalg.norm(p.v_cam_enu_m_s[:2]) == pytest.approx(4.0, abs=0.15)
               for p in lp.poses[1:])
    # Yaw (clockwise from north) grows at 0.5 rad/s: a turn of -0.5 rad/s about ENU up.
    assert all(p.omega_enu_rad_s[2] == pytest.approx(-0.5, abs=0.02) for p in lp.poses[1:])
    sharp = serve_config(tmp_path, gimbal=False, detector=BLUR_MODEL)
    _, ref = offline_of(sharp, tlog)
    assert np.array_equal(ref.n_obs, off.n_obs)
    assert (off.log_miss_d >= ref.log_miss_d).all() and off.pd.mean() < 0.9 * ref.pd.mean()

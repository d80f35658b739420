"""PoseTracker.frames_at gives a frame the same bits whether it is asked alone (live: one or
two frames per call, samples fed as they come, history cut) or among thousands (offline):
what makes ``pdcov serve`` equal ``pdcov evaluate`` cell for cell."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pdcov.core.geodesy import Origin
from pdcov.core.mount import GimbalMount
from pdcov.core.pose import (
    GIMBAL_FLAG_YAW_IN_EARTH_FRAME,
    GIMBAL_FLAG_YAW_IN_VEHICLE_FRAME,
    FixedMount,
)
from pdcov.core.rotations import R_from_euler_zyx_many, quat_wxyz_from_euler_zyx
from pdcov.telemetry.pose_tracker import FrameBatch, PoseTracker
from tests.support.mavlink_fixtures import KnownFlight, samples_from_flight

ORIGIN = Origin(-35.363261, 149.165230, 584.0)
RATE_HZ = 20.0


def flight(n: int = 400) -> KnownFlight:
    """A turning, climbing flight with a moving gimbal whose frame flips between vehicle and
    earth every 50 reports (so interpolation meets both, and a change of frame)."""
    t = 1.0 + np.arange(n) / RATE_HZ
    s = np.linspace(0, 1, n)
    R = R_from_euler_zyx_many(0.2 * np.sin(6 * s), -0.3 * s, 6.0 * s - 3.0)
    r = np.stack([40 * s, 10 * np.sin(3 * s), 10 + 2 * s], axis=1)
    q_g = quat_wxyz_from_euler_zyx(0.05 * np.cos(5 * s), -1.2 - 0.3 * s, 0.4 * s)
    q_g[::7] *= 1.0 + 1e-4  # a few slightly non-unit reports, carried as sent
    flags = [GIMBAL_FLAG_YAW_IN_VEHICLE_FRAME if (i // 50) % 2 else
             GIMBAL_FLAG_YAW_IN_EARTH_FRAME for i in range(n)]
    return KnownFlight(ORIGIN, t, R, r, q_g, flags)


MOUNTS = [FixedMount(pitch_rad=-1.2, lever_arm_frd_m=(0.1, 0.0, 0.05)),
          GimbalMount(attitude_frame="flags"), GimbalMount(attitude_frame="body")]


def feed(tracker: PoseTracker, samples: list) -> None:
    for s in samples:
        {"AttitudeSample": tracker.add_attitude, "PositionSample": tracker.add_position,
         "GimbalSample": tracker.add_gimbal}[type(s).__name__](s)


def assert_rows_equal(batch: FrameBatch, i: int, alone: FrameBatch) -> None:
    """Frame ``i`` of ``batch`` equals ``alone``: its skip reason, and when valid every
    field (a skipped frame's pose is not defined)."""
    assert alone.skip_reason[0] == batch.skip_reason[i]
    if not batch.valid[i]:
        return
    for name in FrameBatch.__slots__:
        a, b = getattr(alone, name), getattr(batch, name)[i:i + 1]
        if a.dtype == object:
            assert list(a) == list(b), name
        else:
            np.testing.assert_array_equal(a, b, err_msg=name)


@pytest.mark.parametrize("mount", MOUNTS, ids=["fixed", "flags", "body"])
def test_live_one_frame_at_a_time_equals_the_whole_log_bitwise(mount: object) -> None:
    f = flight()
    samples = sorted(samples_from_flight(f, home=False), key=lambda s: s.t_s)
    whole = PoseTracker(ORIGIN, mount)  # type: ignore[arg-type]
    feed(whole, samples)
    t = np.arange(f.t_s[0] - 0.3, f.t_s[-1] + 0.3, 0.2 / 3)  # off the samples, and outside
    offline = whole.frames_at(t)
    assert offline.valid.sum() > 250 and (~offline.valid).sum() >= 8

    live = PoseTracker(ORIGIN, mount, history_s=3.0)  # type: ignore[arg-type]
    k = 0
    for s in samples:
        feed(live, [s])
        # Decided as LiveCoverage does: once every stream has a sample at or after it.
        while k < len(t) and t[k] < s.t_s - 1.0 / RATE_HZ:
            assert_rows_equal(offline, k, live.frames_at(t[k:k + 1]))
            k += 1
    assert k > 250


def test_late_and_repeated_samples_merge_as_sorted() -> None:
    """Samples out of order (a reordered link, some arriving after later ones were merged)
    or repeated give the frames of the same samples fed in order: the in-order fast path of
    the merge and the general one agree."""
    mount = GimbalMount(attitude_frame="flags")
    samples = sorted(samples_from_flight(flight(200), home=False), key=lambda s: s.t_s)
    ordered = PoseTracker(ORIGIN, mount)
    feed(ordered, samples)
    shuffled = PoseTracker(ORIGIN, mount)
    rng = np.random.default_rng(0)
    held: list = []  # samples that arrive after the next chunk was merged
    for chunk in np.array_split(np.arange(len(samples)), 40):
        late = [samples[i] for i in rng.permutation(chunk)]
        repeat = dataclasses.replace(late[-1])  # an identical copy, later
        feed(shuffled, [*late[2:], *held, repeat])
        held = late[:2]
        shuffled.frames_at(np.array([late[0].t_s]))  # merge now, chunk by chunk
    feed(shuffled, held)
    t = np.linspace(samples[0].t_s, samples[-1].t_s, 123)
    a, b = ordered.frames_at(t), shuffled.frames_at(t)
    for name in FrameBatch.__slots__:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)

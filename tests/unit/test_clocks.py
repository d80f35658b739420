"""The clock rule shared by the tlog reader and the daemon (telemetry/clocks.py), and the
position-jump rule of the PoseTracker, stepped in memory."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pdcov.core.geodesy import Origin
from pdcov.core.pose import FixedMount
from pdcov.telemetry.clocks import COMPONENT_CLOCK_WINDOW_S, ComponentClock, VehicleClock
from pdcov.telemetry.pose_tracker import PoseTracker
from pdcov.telemetry.sample_gate import position_jump
from pdcov.telemetry.samples import AttitudeSample, PositionSample

OFFSET_S = -1.234  # autopilot time = gimbal time + OFFSET_S


def test_freshest_reference_wins_over_stale_ones():
    c = ComponentClock()
    # Autopilot's latest time 30, 20, 0, 10 ms old when the gimbal's reports arrive.
    ages = [0.030, 0.020, 0.0, 0.010]
    out = []
    for k, age in enumerate(ages):
        t_ap = 10.0 + 0.05 * k
        out.append(c.to_autopilot_s(t_ap - OFFSET_S, t_ap - age))
    assert out[0] == pytest.approx(10.0 - 0.030)   # only a stale reference yet
    assert out[2] == pytest.approx(10.1)            # a fresh one: exact from here on
    assert out[3] == pytest.approx(10.15)
    assert c.offset_s == pytest.approx(OFFSET_S)
    # A median would stay 15 ms early.
    assert float(np.median([-a for a in ages])) == pytest.approx(-0.015)


def test_nothing_before_the_first_autopilot_time():
    v = VehicleClock(1)
    assert math.isnan(v.time_s(154, 5.0))
    assert math.isnan(v.time_s(1, None))
    assert v.time_s(1, 3.0) == 3.0
    assert v.time_s(154, 4.234) == pytest.approx(3.0)
    assert v.time_s(1, None) == 3.0  # no boot time: the autopilot's latest


def test_a_delayed_report_counts_for_the_window_only():
    c = ComponentClock()
    t = 0.0
    for _ in range(10):
        c.to_autopilot_s(t - OFFSET_S, t)
        t += 0.1
    late = c.to_autopilot_s(t - OFFSET_S - 0.2, t)  # held back 200 ms on the way
    assert late == pytest.approx(t)  # never before the autopilot's time at arrival
    assert c.offset_s == pytest.approx(OFFSET_S + 0.2)
    while t < 1.0 + COMPONENT_CLOCK_WINDOW_S + 0.5:
        t += 0.1
        c.to_autopilot_s(t - OFFSET_S, t - 0.005)
    assert c.offset_s == pytest.approx(OFFSET_S - 0.005)


def test_component_reboot_restarts_the_window():
    c = ComponentClock()
    for k in range(20):
        c.to_autopilot_s(100.0 + 0.05 * k, 50.0 + 0.05 * k)
    assert c.offset_s == pytest.approx(-50.0)
    # The gimbal reboots at autopilot time 51.0: its clock counts from 0 again.
    t = c.to_autopilot_s(0.5, 51.5)
    assert t == pytest.approx(51.5)
    assert c.offset_s == pytest.approx(51.0 - c.clock.offset_s)


def test_autopilot_reboot_is_taken_at_once_and_a_silent_autopilot_changes_nothing():
    v = VehicleClock(1)
    for k in range(80):
        v.time_s(1, 0.05 * k)
        v.time_s(154, 0.05 * k - OFFSET_S)
    before = v.components[154].offset_s
    # The autopilot is silent for 2 s while the gimbal goes on: its reference is stale.
    for k in range(40):
        assert v.time_s(154, 4.0 + 0.05 * k - OFFSET_S) == pytest.approx(4.0 + 0.05 * k)
    assert v.components[154].offset_s == pytest.approx(before)
    # It comes back rebooted (time_boot_ms from 0): its clock is shifted forward; the
    # gimbal's offset follows with the first report.
    t_ap = v.time_s(1, 0.1)
    assert v.autopilot.restarts_t_s
    assert v.time_s(154, 6.1 - OFFSET_S) == pytest.approx(t_ap)


def _tracker(positions):
    tr = PoseTracker(Origin(47.0, 8.0, 400.0), FixedMount())
    for t, north_m in positions:
        tr.add_attitude(AttitudeSample(t, (1.0, 0.0, 0.0, 0.0)))
        tr.add_position(PositionSample(t, 47.0 + north_m / 111_195.0, 8.0, 410.0))
    return tr


def test_a_frame_across_a_position_jump_is_skipped():
    # 5 m/s north, a 20 m jump between 1.0 and 1.1 s, the jump back between 2.0 and 2.1 s.
    pos = [(0.1 * k, 0.5 * k + (20.0 if 11 <= k <= 20 else 0.0)) for k in range(31)]
    tr = _tracker(pos)
    b = tr.frames_at(np.array([0.55, 1.05, 1.55, 2.05, 2.55]))
    assert list(b.skip_reason) == ["", "position jump", "", "position jump", ""]
    a, j = (PositionSample(t, 47.0 + n / 111_195.0, 8.0, 410.0) for t, n in pos[10:12])
    assert position_jump(a, j)
    assert not position_jump(*(PositionSample(t, 47.0 + n / 111_195.0, 8.0, 410.0)
                               for t, n in pos[0:2]))

"""One code path for a .tlog: the daemon fed the log's bytes as a link delivers them and
``pdcov evaluate`` of the same file go through the same protocol object
(telemetry/link_protocol.LinkProtocol: which autopilot, the clocks, the attitude source, the
autopilot-only samples), the same sample gate (telemetry/sample_gate.SampleGate), the same
ground altitude (flight/ground_altitude.GroundAltitude) and the same frame decision
(flight/frame_decision.decide_frames: the tracker's frames, flight/frame_selection's trust
policy, quaternion rebuild and min height, the frames not used counted), shown by counting
their calls in both: the same messages received, the same samples admitted or refused in
the same order, the same ground altitude, the same frames decided, used and marked low, the
same frames skipped and bad telemetry counted, the same grid."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
import yaml
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.cli import main
from pdcov.flight import camera_frames, frame_decision, log_frames
from pdcov.flight.ground_altitude import GroundAltitude
from pdcov.service.settings import load_serve_config
from pdcov.telemetry.link_protocol import LinkProtocol
from pdcov.telemetry.sample_gate import SampleGate
from tests.support.link_feed import (
    GROUND_M,
    LAT_DEG,
    LON_DEG,
    Hover,
    feed_tlog,
    pack,
    serve_config,
)

GATE_KEYS = ("untimed_samples", "nan_samples", "invalid_samples", "position_jumps",
             "gimbal_failures")


def hover_with_bad_telemetry(tmp_path: Path) -> Path:
    """Hover's messages as a tlog, with a position 2 km off (a jump: counted, kept), a
    gimbal report of failure flags, a gimbal report whose quaternion is no rotation and no
    attitude from 2.5 to 4 s (a gap: its frames skipped)."""
    mav = mavlink.MAVLink(None)
    msgs = [m for m in Hover(seconds=6.0).messages()
            if not (m.get_type() == "ATTITUDE" and 2500 < m.time_boot_ms < 4000)]
    bad = [mav.gimbal_device_attitude_status_encode(0, 0, 2005, 4 | 8 | 16, [0.0] * 4,
                                                    0, 0, 0, 0),
           mav.gimbal_device_attitude_status_encode(0, 0, 2105, 4 | 8 | 16,
                                                    [0.7071, 0.0, -0.7071, 0.0], 0, 0, 0, 1)]
    jump = next(m for m in reversed(msgs) if m.get_type() == "GLOBAL_POSITION_INT")
    far = mav.global_position_int_encode(jump.time_boot_ms + 5, jump.lat + 180_000, jump.lon,
                                         jump.alt, jump.relative_alt, 0, 0, 0, 0)
    all_msgs = [*msgs[:30], *bad, *msgs[30:], far]
    data = [pack(m, seq=i) for i, m in enumerate(all_msgs)]
    tlog = tmp_path / "hover.tlog"
    tlog.write_bytes(b"".join(struct.pack(">Q", 1_700_000_000_000_000 + 1000 * i) + d
                              for i, d in enumerate(data)))
    return tlog


class Calls:
    """Every LinkProtocol.receive (protocol object, message type), SampleGate.admit
    (gate object, sample type, t_s, admitted), GroundAltitude.ground_alt (object, the
    answer) and decide_frames (the frame times decided; the daemon's flight/camera_frames
    and evaluate's flight/log_frames both import it) with the select_frames it makes (the
    used frames' times and low marks) call, in order."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.reset()
        receive, admit = LinkProtocol.receive, SampleGate.admit
        ground_alt = GroundAltitude.ground_alt
        decide, select = frame_decision.decide_frames, frame_decision.select_frames

        def counted_receive(proto, msg, now_s):
            self.received.append((id(proto), msg.get_type()))
            return receive(proto, msg, now_s)

        def counted_admit(gate, sample):
            ok = admit(gate, sample)
            self.admitted.append((id(gate), type(sample).__name__, sample.t_s, ok))
            return ok

        def counted_ground_alt(ground, newest_t_s, **kw):
            alt, how = ground_alt(ground, newest_t_s, **kw)
            self.grounds.append((id(ground), alt, how))
            return alt, how

        def counted_decide(tracker, t_s, framing, counts, **kw):
            self.decided += [float(t) for t in t_s]
            self.decisions += 1
            return decide(tracker, t_s, framing, counts, **kw)

        def counted_select(b, mount, zoom, min_height_m):
            sel = select(b, mount, zoom, min_height_m)
            self.selected += [(p.t_s, bool(low)) for p, low in zip(sel.poses, sel.low,
                                                                    strict=True)]
            return sel

        monkeypatch.setattr(LinkProtocol, "receive", counted_receive)
        monkeypatch.setattr(SampleGate, "admit", counted_admit)
        monkeypatch.setattr(GroundAltitude, "ground_alt", counted_ground_alt)
        assert camera_frames.decide_frames is log_frames.decide_frames is decide
        monkeypatch.setattr(camera_frames, "decide_frames", counted_decide)
        monkeypatch.setattr(log_frames, "decide_frames", counted_decide)
        monkeypatch.setattr(frame_decision, "select_frames", counted_select)

    def reset(self) -> None:
        self.received: list[tuple[int, str]] = []
        self.admitted: list[tuple[int, str, float, bool]] = []
        self.grounds: list[tuple[int, float | None, str]] = []
        self.decided: list[float] = []
        self.selected: list[tuple[float, bool]] = []
        self.decisions = 0

    def stream(self) -> list[tuple[str, float, bool]]:
        """What the gate saw, whichever object it was."""
        return [(kind, t_s, ok) for _g, kind, t_s, ok in self.admitted]

    def ground(self) -> tuple[int, float | None, str]:
        """How many GroundAltitude objects were asked, and the first answer."""
        answers = [(alt, how) for _g, alt, how in self.grounds if alt is not None]
        return len({g for g, *_r in self.grounds}), *answers[0]


@pytest.mark.parametrize("gimbal", [True, False], ids=["gimbal", "fixed"])
def test_the_daemon_and_evaluate_go_through_one_protocol_object_and_gate(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, gimbal: bool) -> None:
    tlog = hover_with_bad_telemetry(tmp_path)
    cfg = serve_config(tmp_path, gimbal=gimbal)
    calls = Calls(monkeypatch)

    feed = feed_tlog(cfg, tlog)  # the daemon, over a link
    live_received, live_stream = list(calls.received), calls.stream()
    live_protocols = {p for p, _t in calls.received}
    live_gates = {g for g, *_r in calls.admitted}
    live_ground = calls.ground()
    live_decided, live_decisions = list(calls.decided), calls.decisions
    live_selected = list(calls.selected)
    status = feed.status()
    faults = status["faults"]
    calls.reset()

    out, config = tmp_path / "run", tmp_path / ("gimbal.yaml" if gimbal else "fixed.yaml")
    assert main(["evaluate", "--config", str(config), "--log", str(tlog), "--out", str(out),
                 "--no-progress"]) == 0
    off_protocols = {p for p, _t in calls.received}

    # One protocol object and one gate each, receiving every message alike, in log order.
    assert len(live_protocols) == len(live_gates) == len(off_protocols) == 1
    assert [t for _p, t in calls.received] == [t for _p, t in live_received]
    assert len(live_received) > 100
    # The same samples, admitted or refused alike, in the same order.
    assert calls.stream() == live_stream
    assert sum(not ok for *_r, ok in live_stream) >= 1
    # One GroundAltitude each, giving the same ground altitude.
    assert calls.ground() == live_ground
    assert live_ground[0] == 1
    # The same frames decided (batches as decidable live, chunks of the whole log offline)
    # and used.
    assert calls.decisions == 1 and live_decisions >= (1 if gimbal else 2)
    assert calls.decided == live_decided
    assert calls.selected == live_selected
    assert len(live_selected) >= 20
    # The same frames skipped and bad telemetry counted, in the daemon's status and
    # evaluate's metrics.
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames_skipped"] == status["frames"]["skipped"]
    assert sum(metrics["frames_skipped"].values()) >= 1
    counted = metrics["telemetry_faults"]
    assert counted.get("position_jumps") == faults.get("position_jumps") == 1
    assert counted.get("gimbal_failures") == faults.get("gimbal_failures") == 1
    assert counted.get("nan_samples") == faults.get("nan_samples") == 1
    for key in (*GATE_KEYS, "frames_untrusted", "frames_without_estimator_status"):
        assert counted.get(key, 0) == faults.get(key, 0), key
    # And the same grid.
    with np.load(out / "grid.npz") as g:
        np.testing.assert_array_equal(g["n_obs"], feed.live.grid.n_obs)


def hover_with_home_moved(tmp_path: Path) -> Path:
    """Hover's messages as a tlog (8 s) whose autopilot arms at 3 s, with its home at
    GROUND_M sent at 1.5 s and moved 13 m down at 5.5 s (after arming)."""
    mav = mavlink.MAVLink(None)
    home_at = {1500: GROUND_M, 5500: GROUND_M - 13.0}
    out = []
    for m in Hover(seconds=8.0).messages()[2:]:  # its armed HEARTBEAT and home replaced
        if m.get_type() == "HEARTBEAT":
            armed = bool(out) and out[-1].time_boot_ms >= 2900
            m = mav.heartbeat_encode(2, 3, (128 if armed else 0) | 1, 4, 4)
        out.append(m)
        alt_m = home_at.pop(getattr(m, "time_boot_ms", -1), None) \
            if m.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS" else None
        if alt_m is not None:
            out.append(mav.home_position_encode(round(LAT_DEG * 1e7), round(LON_DEG * 1e7),
                                                round(alt_m * 1000), 0, 0, 0, [1, 0, 0, 0],
                                                0, 0, 0))
    assert not home_at
    tlog = tmp_path / "moved.tlog"
    tlog.write_bytes(b"".join(struct.pack(">Q", 1_700_000_000_000_000 + 1000 * i)
                              + pack(m, seq=i) for i, m in enumerate(out)))
    return tlog


def test_a_home_moved_after_arming_gives_the_daemon_and_evaluate_the_home_at_arming(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Without origin.ground_alt_msl_m both take the home in force at arming (once,
    GroundAltitude's rule), not the log's last home (what evaluate took before)."""
    tlog = hover_with_home_moved(tmp_path)
    cfg = serve_config(tmp_path, gimbal=False, origin={"lat_deg": LAT_DEG, "lon_deg": LON_DEG})
    assert cfg.mission.ground_alt_msl_m is None
    calls = Calls(monkeypatch)
    feed = feed_tlog(cfg, tlog)
    live_ground = calls.ground()
    assert feed.live.origin is not None
    assert feed.live.origin.ground_alt_msl_m == GROUND_M
    calls.reset()
    out = tmp_path / "run"
    assert main(["evaluate", "--config", str(tmp_path / "fixed.yaml"), "--log", str(tlog),
                 "--out", str(out), "--no-progress"]) == 0
    assert calls.ground() == live_ground == (1, GROUND_M,
                                             "the autopilot's home at arming (HOME_POSITION)")
    assert (f"ground {GROUND_M:.2f} m MSL (the autopilot's home at arming"
            in capsys.readouterr().out)
    with np.load(out / "grid.npz") as g:
        assert g["frames"] == feed.live.grid.frames >= 30
        np.testing.assert_array_equal(g["n_obs"], feed.live.grid.n_obs)
        np.testing.assert_array_equal(g["log_miss_d"], feed.live.grid.log_miss_d)


def test_a_parameter_read_before_the_autopilots_first_time_is_used_by_both(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A PARAM_VALUE the autopilot answers before its first timed message (as real
    ArduCopter does when the daemon asks at once): counted untimed by both, and its value
    used by both -- the daemon's LinkProtocol keeps it, so evaluate's reader must too (it
    once dropped it, read the gimbal by its flags, and gave another grid)."""
    mav = mavlink.MAVLink(None)
    msgs = Hover(seconds=4.0).messages()
    servo = mav.param_value_encode(b"MNT1_TYPE", 1.0, 9, 900, 0)  # servo: a body-frame gimbal
    out = [*msgs[:2], servo, *msgs[2:]]
    assert out[3].get_type() == "HEARTBEAT" and out[4].get_type() == "ATTITUDE"
    tlog = tmp_path / "param_first.tlog"
    tlog.write_bytes(b"".join(struct.pack(">Q", 1_700_000_000_000_000 + 1000 * i)
                              + pack(m, seq=i) for i, m in enumerate(out)))
    path = tmp_path / "gimbal.yaml"
    serve_config(tmp_path)
    doc = yaml.safe_load(path.read_text())
    doc["mount"]["attitude_frame"] = "auto"  # MNT1_TYPE decides how the gimbal is read
    path.write_text(yaml.safe_dump(doc))
    feed = feed_tlog(load_serve_config(path), tlog)
    assert feed.core.protocol.params["MNT1_TYPE"] == 1.0
    out_dir = tmp_path / "run"
    assert main(["evaluate", "--config", str(tmp_path / "gimbal.yaml"), "--log", str(tlog),
                 "--out", str(out_dir), "--no-progress"]) == 0
    assert "has no MNT1_TYPE" not in capsys.readouterr().out
    faults = json.loads((out_dir / "metrics.json").read_text())["telemetry_faults"]
    assert faults["untimed_samples"] == feed.live.counters.faults["untimed_samples"] >= 1
    with np.load(out_dir / "grid.npz") as g:
        assert g["frames"] == feed.live.grid.frames >= 20
        np.testing.assert_array_equal(g["log_miss_d"], feed.live.grid.log_miss_d)

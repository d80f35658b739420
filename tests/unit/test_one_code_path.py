"""One code path for a .tlog: the daemon fed the log's bytes as a link delivers them and
``pdcov evaluate`` of the same file go through the same protocol object
(telemetry/link_protocol.LinkProtocol: which autopilot, the clocks, the attitude source, the
autopilot-only samples), the same sample gate (telemetry/sample_gate.SampleGate) and the
same frame selection (telemetry/frame_selection.select_frames: trust policy, quaternion
rebuild, min height), shown by counting their calls in both: the same messages received,
the same samples admitted or refused in the same order, the same frames used and marked
low, the same bad telemetry counted, the same grid."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.cli import main
from pdcov.flight import camera_frames
from pdcov.telemetry import frame_selection, log_poses
from pdcov.telemetry.link_protocol import LinkProtocol
from pdcov.telemetry.sample_gate import SampleGate
from tests.support.link_feed import Hover, feed_tlog, pack, serve_config

GATE_KEYS = ("untimed_samples", "nan_samples", "invalid_samples", "position_jumps",
             "gimbal_failures")


def hover_with_bad_telemetry(tmp_path: Path) -> Path:
    """Hover's messages as a tlog, with a position 2 km off (a jump: counted, kept), a
    gimbal report of failure flags and a gimbal report whose quaternion is no rotation."""
    mav = mavlink.MAVLink(None)
    msgs = Hover(seconds=4.0).messages()
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
    (gate object, sample type, t_s, admitted) and select_frames (the used frames' times and
    low marks; the daemon's flight/camera_frames and evaluate's log_poses both import it)
    call, in order."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.received: list[tuple[int, str]] = []
        self.admitted: list[tuple[int, str, float, bool]] = []
        self.selected: list[tuple[float, bool]] = []
        self.selections = 0
        receive, admit = LinkProtocol.receive, SampleGate.admit
        select = frame_selection.select_frames

        def counted_receive(proto, msg, now_s):
            self.received.append((id(proto), msg.get_type()))
            return receive(proto, msg, now_s)

        def counted_admit(gate, sample):
            ok = admit(gate, sample)
            self.admitted.append((id(gate), type(sample).__name__, sample.t_s, ok))
            return ok

        def counted_select(b, mount, zoom, min_height_m):
            sel = select(b, mount, zoom, min_height_m)
            self.selections += 1
            self.selected += [(p.t_s, bool(low)) for p, low in zip(sel.poses, sel.low,
                                                                    strict=True)]
            return sel

        monkeypatch.setattr(LinkProtocol, "receive", counted_receive)
        monkeypatch.setattr(SampleGate, "admit", counted_admit)
        assert camera_frames.select_frames is log_poses.select_frames is select
        monkeypatch.setattr(camera_frames, "select_frames", counted_select)
        monkeypatch.setattr(log_poses, "select_frames", counted_select)

    def reset(self) -> None:
        self.received, self.admitted, self.selected, self.selections = [], [], [], 0

    def stream(self) -> list[tuple[str, float, bool]]:
        """What the gate saw, whichever object it was."""
        return [(kind, t_s, ok) for _g, kind, t_s, ok in self.admitted]


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
    live_selected, live_selections = list(calls.selected), calls.selections
    faults = feed.status()["faults"]
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
    # The same frames used (batches as decided live, the whole log at once offline).
    assert calls.selections == 1 and live_selections >= (1 if gimbal else 2)
    assert calls.selected == live_selected
    assert len(live_selected) >= 20
    # The same bad telemetry counted, in the daemon's status and evaluate's metrics.
    metrics = json.loads((out / "metrics.json").read_text())
    counted = metrics["telemetry_faults"]
    assert counted.get("position_jumps") == faults.get("position_jumps") == 1
    assert counted.get("gimbal_failures") == faults.get("gimbal_failures") == 1
    assert counted.get("nan_samples") == faults.get("nan_samples") == 1
    for key in GATE_KEYS:
        assert counted.get(key, 0) == faults.get(key, 0), key
    # And the same grid.
    with np.load(out / "grid.npz") as g:
        np.testing.assert_array_equal(g["n_obs"], feed.live.grid.n_obs)

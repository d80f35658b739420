"""`pdcov serve` against a hostile or mistaken participant (issue 23, docs/reliability.md
"Security"): it answers MAVLink only to the autopilot's addresses, rate-limits snapshot
replies per requester, stamps its publications with its own Zenoh source, and resumes a
checkpoint only under the vehicle id that wrote it."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np
import pytest

from pdcov.core.pose import CameraPose
from pdcov.errors import ConfigError
from pdcov.service.checkpoint import CHECKPOINT_NAME
from pdcov.service.daemon import Daemon
from pdcov.service.mavlink_socket import ReplyPeers
from pdcov.service.query_limit import QueryLimiter, QueryLimits, QueryRefusal
from pdcov.service.settings import load_serve_config
from pdcov.telemetry.link_protocol import LinkProtocol
from tests.support.link_feed import pack

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from tests.support.security_config import config

# --- 4. a checkpoint resumes only under its own vehicle id -------------------------------------

def test_a_checkpoint_resumes_under_its_vehicle_id_only(tmp_path, caplog) -> None:
    state = tmp_path / "state"
    first = Daemon(load_serve_config(config(tmp_path, "uav1", state=state)))
    for k in range(3):
        first.live.grid.update(CameraPose(np.diag([1.0, -1.0, -1.0]),
                                          np.array([10.0 + 4 * k, 15.0, 12.0]), float(k)))
    first.effects.checkpoint()
    saved = first.live.grid.frames
    assert saved == 3
    again = Daemon(load_serve_config(config(tmp_path, "uav1", state=state)))
    assert again.live.grid.frames == saved and again.core.checkpoint.describe()["resumed"]
    # The same mission flown as uav2 with the same state directory (a copied config):
    # uav1's frames must not be counted again under uav2.
    with caplog.at_level(logging.WARNING, logger="pdcov.serve"):
        other = Daemon(load_serve_config(config(tmp_path, "uav2", state=state)))
    assert other.live.grid.frames == 0 and not other.live.grid.n_obs.any()
    info = other.core.checkpoint.describe()
    assert not info["resumed"] and info["set_aside"] is not None
    aside = Path(info["set_aside"])
    assert aside.is_dir() and not (state / CHECKPOINT_NAME).exists()
    line = caplog.records[-1].getMessage()
    assert "set aside" in line and "vehicle 'uav1'" in line, line
    # The file set aside is uav1's, whole: renamed back it resumes under uav1.
    aside.replace(state / CHECKPOINT_NAME)
    assert Daemon(load_serve_config(config(tmp_path, "uav1", state=state))
                  ).live.grid.frames == saved


# --- 3. every status and tiles put carries the daemon session's source ------------------------


# --- 1. MAVLink replies go to the autopilot's addresses only ----------------------------------

def test_reply_peers_are_bounded_and_the_latest_heard_stay() -> None:
    peers = ReplyPeers(limit=4)
    for port in range(1000):  # senders forging the autopilot's ids, each from its own port
        peers.heard(("127.0.0.1", 20000 + port))
    peers.heard(("127.0.0.1", 14555))  # the autopilot, heard again: kept, newest
    assert peers.addresses == (("127.0.0.1", 20997), ("127.0.0.1", 20998),
                               ("127.0.0.1", 20999), ("127.0.0.1", 14555))
    peers.heard(("127.0.0.1", 20997))  # heard again: moved to the newest, nothing dropped
    assert peers.addresses[0] == ("127.0.0.1", 20998) and len(peers.addresses) == 4


def test_from_autopilot_is_the_followed_autopilots_own_messages_only() -> None:
    proto = LinkProtocol(mavlink.MAVLink(None), system_id=1, intervals={}, param_names=(),
                         param_timeout_s=5.0)
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True

    def received(msg, sysid: int, compid: int):
        [m] = parser.parse_buffer(pack(msg, sysid, compid))
        return m

    mav = mavlink.MAVLink(None)
    beat = mav.heartbeat_encode(2, 3, 0, 0, 4)
    other = received(beat, 7, 1)  # another autopilot, before and after: never
    assert not proto.from_autopilot(other)
    first = received(beat, 1, 1)
    assert not proto.from_autopilot(first)  # not followed until LinkProtocol has seen it
    proto.receive(first, 0.0)
    assert proto.from_autopilot(first) and proto.from_autopilot(
        received(mav.attitude_encode(1000, 0, 0, 0, 0, 0, 0), 1, 1))
    assert not proto.from_autopilot(other)
    assert not proto.from_autopilot(received(beat, 1, 154))  # the vehicle's gimbal
    junk = parser.parse_buffer(b"\xfd\x09" + bytes(20)) or []
    assert junk and all(m.get_type() == "BAD_DATA" and not proto.from_autopilot(m)
                        for m in junk)


# --- 2. snapshot replies rate-limited per requester -------------------------------------------

LIMITS = QueryLimits(per_requester_hz=2.0, burst=3, max_bytes_per_s=10_000, max_requesters=4)


def test_each_requester_gets_its_burst_then_its_rate() -> None:
    q = QueryLimiter(LIMITS)
    answered = [q.admit("a", 0.0) is None for _ in range(5)]
    assert answered == [True, True, True, False, False]
    assert q.admit("b", 0.0) is None  # another requester has its own bucket
    assert q.admit("a", 0.49) is QueryRefusal.REQUESTER_RATE  # 0.98 of a reply refilled
    assert q.admit("a", 0.5) is None and q.admit("a", 0.5) is not None
    # 10 s later the bucket is full again, not fuller: the burst, no more.
    assert [q.admit("a", 10.5) is None for _ in range(4)] == [True, True, True, False]
    assert q.refused[QueryRefusal.REQUESTER_RATE] == 5


def test_anonymous_queries_share_one_bucket_and_so_do_newcomers_past_the_bound() -> None:
    q = QueryLimiter(LIMITS)
    assert [q.admit(None, 0.0) is None for _ in range(4)] == [True, True, True, False]
    for k in range(3):  # with the anonymous bucket: 4 = max_requesters
        assert q.admit(f"zid{k}", 0.0) is None
    assert q.admit("late", 0.0) is QueryRefusal.REQUESTER_RATE  # the anonymous bucket, empty
    # Once a requester's bucket is full again it is forgotten: room for a newcomer.
    assert q.admit("later", 5.0) is None and q.admit("later", 5.0) is None
    assert len(q._buckets) <= LIMITS.max_requesters


def test_all_replies_together_are_capped_in_bytes_per_second() -> None:
    q = QueryLimiter(LIMITS)
    t = 0.0
    sent = 0
    for k in range(400):  # 20 requesters, each within its own rate, 6 kB snapshots
        t = k * 0.025
        if q.admit(f"zid{k % 20}", t) is None:
            q.sent(6_000)
            sent += 6_000
    # 10 s at 10 kB/s plus the first second's worth and one snapshot of debt.
    assert sent <= 10_000 * t + 10_000 + 6_000, sent
    assert sent >= 10_000 * t - 6_000, sent
    assert q.refused[QueryRefusal.BYTE_RATE] > 0
    # One snapshot larger than a second's worth still goes when the bucket holds bytes.
    big = QueryLimiter(LIMITS)
    assert big.admit("a", 0.0) is None
    big.sent(50_000)
    assert big.admit("b", 1.0) is QueryRefusal.BYTE_RATE
    assert big.admit("b", 4.1) is None


def test_limits_are_checked_when_built() -> None:
    with pytest.raises(ConfigError, match="per_requester_hz"):
        QueryLimits(per_requester_hz=0.0)
    with pytest.raises(ConfigError, match="burst"):
        QueryLimits(burst=0)
    assert "2 snapshot/s per requester (burst 3)" in LIMITS.reason(QueryRefusal.REQUESTER_RATE)

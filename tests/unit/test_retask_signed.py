"""Command authority in memory: who may re-task (signature, key, time, nonce across a
restart, vehicle, key expression), where to (service.retask_limits, the same rule on the
ground), the pilot's STATUSTEXT, the status's last re-task, and ``pdcov keys new``.
Real Zenoh and a daemon: tests/system/test_retask_signed_e2e.py."""

from __future__ import annotations

import base64
import json
import re
import stat

import pytest
from shapely.geometry import Polygon

from pdcov.bus.operator_keys import load_private_key, load_public_key
from pdcov.bus.retask import decode_retask_reply
from pdcov.cli import main as pdcov_main
from pdcov.core.geodesy import Origin
from pdcov.core.mission import (
    MAV_CMD_DO_CHANGE_SPEED,
    MAV_CMD_NAV_TAKEOFF,
    MAV_CMD_NAV_WAYPOINT,
    MAV_FRAME_GLOBAL,
    MAV_FRAME_GLOBAL_RELATIVE_ALT,
    MAV_FRAME_GLOBAL_TERRAIN_ALT,
    MAV_FRAME_MISSION,
    MissionItem,
)
from pdcov.errors import ConfigError
from pdcov.ground.retask import RetaskNotSent, signed_request
from pdcov.planning.mission_bounds import RetaskLimits, check_mission_bounds
from pdcov.service.link_setup import LinkReport
from pdcov.service.retask_auth import NonceBook, RetaskRefusal
from tests.support.retask_harness import FAR, ITEMS, WP, Autopilot, core_with, fly, heard
from tests.support.retask_keys import KEY, OTHER, UNIX_S, signed


def reason(core, payload: bytes, **kw) -> str:
    replies, _ = fly(core, Autopilot(), payload, "ab12", **kw)
    r = decode_retask_reply(replies[0][1])
    return r.reason if not r.accepted else "ACCEPTED"


def _forged(payload: bytes) -> bytes:
    """The envelope with one bit of its signed body changed (a waypoint moved)."""
    doc = json.loads(payload)
    body = base64.b64decode(doc["body"]).replace(b'"z_m":10.0', b'"z_m":11.0', 1)
    doc["body"] = base64.b64encode(body).decode()
    return json.dumps(doc).encode()


def _unsigned_v1() -> bytes:
    return json.dumps({"schema": "pdcov.retask", "version": 1, "vehicle_id": "fuzz",
                       "plan_hash": "0" * 16, "description": "", "items": []}).encode()


@pytest.mark.parametrize(("make", "kw", "expected"), [
    (lambda: signed(ITEMS), {}, "ACCEPTED"),
    (lambda: _forged(signed(ITEMS)), {}, RetaskRefusal.BAD_SIGNATURE),
    (lambda: signed(ITEMS, key=OTHER), {}, RetaskRefusal.UNKNOWN_KEY),
    (_unsigned_v1, {}, RetaskRefusal.UNSIGNED),
    (lambda: signed(ITEMS, unix_s=UNIX_S - 121), {}, RetaskRefusal.STALE),
    (lambda: signed(ITEMS, unix_s=UNIX_S + 121), {}, RetaskRefusal.STALE),
    (lambda: signed(ITEMS, unix_s=UNIX_S - 119), {}, "ACCEPTED"),
    (lambda: signed(ITEMS, vehicle_id="uav9"), {}, RetaskRefusal.WRONG_VEHICLE),
    (lambda: signed(ITEMS), {"key_expr": "pdcov/**"}, RetaskRefusal.WILDCARD),
    (lambda: signed(ITEMS), {"key_expr": "pdcov/fuzz/*"}, RetaskRefusal.WILDCARD),
    (lambda: signed(ITEMS), {"key_expr": "pdcov/fuzz/ret$*"}, RetaskRefusal.WILDCARD),
    (lambda: b"{}", {}, RetaskRefusal.BAD_REQUEST),
])
def test_only_a_listed_keys_fresh_signature_on_the_exact_key(tmp_path, make, kw, expected
                                                              ) -> None:
    core = core_with(tmp_path, retask=True)
    heard(core)
    assert reason(core, make(), **kw) == expected


def test_replay_refused_also_after_a_restart(tmp_path) -> None:
    core = core_with(tmp_path, retask=True)
    heard(core)
    payload = signed(ITEMS)
    assert reason(core, payload) == "ACCEPTED"
    assert reason(core, payload, now_s=5.0) == RetaskRefusal.REPLAYED
    saved = core.actions().nonces or core.retasker.nonces.to_bytes()
    st, _ = core.status(6.0, LinkReport())
    assert st["faults"]["retask_refused_replayed"] == 1
    # A new daemon reading back the nonces the shell wrote: still refused.
    again = core_with(tmp_path, nonces=NonceBook.from_bytes(saved), retask=True)
    heard(again)
    assert reason(again, payload) == RetaskRefusal.REPLAYED
    # Once the window is over the nonce is forgotten, and the request is stale anyway.
    assert reason(again, payload, unix_s=UNIX_S + 200) == RetaskRefusal.STALE
    assert len(again.retasker.nonces) == 0


def test_a_forged_or_unknown_request_uses_no_nonce(tmp_path) -> None:
    core = core_with(tmp_path, retask=True)
    heard(core)
    payload = signed(ITEMS)
    assert reason(core, _forged(payload)) == RetaskRefusal.BAD_SIGNATURE
    assert len(core.retasker.nonces) == 0
    assert reason(core, payload) == "ACCEPTED"


def _at(z_m: float, frame: int = MAV_FRAME_GLOBAL_RELATIVE_ALT) -> MissionItem:
    return MissionItem(MAV_CMD_NAV_WAYPOINT, frame, lat_deg=WP.lat_deg, lon_deg=WP.lon_deg,
                       z_m=z_m)


@pytest.mark.parametrize(("items", "match"), [
    ((WP, FAR), r"item 1: \d+ m outside the domain grown by 100 m"),
    ((_at(20000.0),), "item 0: 20000.0 m above home, the limits are 2 to 120 m"),
    ((_at(-1000.0),), "item 0: -1000.0 m above home"),
    ((_at(488.0 + 5000.0, MAV_FRAME_GLOBAL),), "item 0: 5000.0 m above home"),
    ((_at(500.0, MAV_FRAME_GLOBAL_TERRAIN_ALT),), "item 0: 500.0 m above the terrain"),
    ((MissionItem(MAV_CMD_DO_CHANGE_SPEED, MAV_FRAME_MISSION, 1.0, 1e7, -1.0), WP),
     "item 0: speed 1e\\+07 m/s, the limit is 15 m/s"),
    ((MissionItem(MAV_CMD_NAV_TAKEOFF, MAV_FRAME_GLOBAL_RELATIVE_ALT, z_m=5000.0),),
     "item 0: 5000.0 m above home"),
    ((WP,) * 1000, "1000 items, the limit is 999"),
])
def test_out_of_bounds_never_reaches_the_autopilot(tmp_path, items, match) -> None:
    core = core_with(tmp_path, retask=True, retask_limits={"max_items": 999})
    heard(core)
    ap = Autopilot()
    replies, logs = fly(core, ap, signed(items), "ab12")
    r = decode_retask_reply(replies[0][1])
    assert r.reason == RetaskRefusal.OUT_OF_BOUNDS and not ap.sent
    assert re.search(match, r.detail), r.detail
    assert any("PDCOV_OUT_OF_BOUNDS" in text for _, text in logs)


def test_bounds_rule_frames_and_in_bounds_items() -> None:
    home = Origin(47.397742, 8.545594, 488.0)
    square = Polygon([(0, 0), (30, 0), (30, 30), (0, 30)])
    ok = (MissionItem(MAV_CMD_NAV_TAKEOFF, MAV_FRAME_GLOBAL_RELATIVE_ALT, z_m=10.0), WP,
          _at(488.0 + 30.0, MAV_FRAME_GLOBAL), _at(15.0, MAV_FRAME_GLOBAL_TERRAIN_ALT),
          MissionItem(MAV_CMD_DO_CHANGE_SPEED, MAV_FRAME_MISSION, 1.0, 15.0, -1.0))
    assert check_mission_bounds(ok, square, home, RetaskLimits()).ok
    v = check_mission_bounds((FAR,) * 8, square, home, RetaskLimits())
    assert v.n_out == 8 and len(v.reasons) == 5 and v.text().endswith("and 3 more")


def test_accepted_upload_tells_the_pilot_and_the_status(tmp_path) -> None:
    core = core_with(tmp_path, retask=True)
    heard(core)
    ap = Autopilot()
    replies, _ = fly(core, ap, signed(ITEMS), "ab12")
    assert decode_retask_reply(replies[0][1]).accepted
    notices = [m for m in ap.sent if m.get_type() == "STATUSTEXT"]
    assert len(notices) == 1 and notices[0].severity == 5  # MAV_SEVERITY_NOTICE
    text = notices[0].text
    assert text == f"pdcov: mission 3 items key {KEY.id[:8]} ok" and len(text) <= 50
    st, _ = core.status(9.0, LinkReport())
    last = st["retask"]["last"]
    assert last["key_id"] == KEY.id and last["items"] == 3 and last["accepted"]
    assert last["result"] == "MAV_MISSION_ACCEPTED" and last["started_unix_s"] == UNIX_S


def test_ground_refuses_without_a_key_or_out_of_bounds(tmp_path) -> None:
    core = core_with(tmp_path, retask=True)
    mission, home = core.cfg.mission, core.cfg.mission.origin()
    with pytest.raises(RetaskNotSent, match="no operator key"):
        signed_request(None, "fuzz", ITEMS, "", mission, home, UNIX_S, "0" * 32)
    with pytest.raises(RetaskNotSent, match="item 0: 20000.0 m above home"):
        signed_request(KEY, "fuzz", (_at(20000.0),), "", mission, home, UNIX_S, "0" * 32)
    heard(core)
    assert reason(core, signed_request(KEY, "fuzz", ITEMS, "", mission, home, UNIX_S,
                                       "1" * 32)) == "ACCEPTED"


def test_keys_new_writes_a_private_key_only_its_owner_reads(tmp_path, capsys) -> None:
    assert pdcov_main(["keys", "new", "--out", str(tmp_path / "k")]) == 0
    private, public = tmp_path / "k" / "operator.key", tmp_path / "k" / "operator.pub"
    assert stat.S_IMODE(private.stat().st_mode) == 0o600
    key = load_private_key(private)
    assert load_public_key(public).id == key.id and key.id in capsys.readouterr().out
    assert pdcov_main(["keys", "new", "--out", str(tmp_path / "k")]) == 2
    assert "exists; not overwritten" in capsys.readouterr().err
    assert load_private_key(private).id == key.id
    with pytest.raises(ConfigError, match="not an unencrypted PEM private key"):
        load_private_key(public)

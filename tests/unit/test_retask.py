"""Re-tasking in memory: the request payload's strict decoder, the daemon's decisions
(``ServiceCore`` with its ``Retasker``) against a scripted autopilot on a fake link, the
ground station's proposal (the same re-fly as ``pdcov refly``) and the web map's CSRF rule.
Real Zenoh and the real ArduCopter: tests/simulators/test_retask_e2e.py."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.bus.errors import BusPayloadError
from pdcov.bus.grid_state import GridState, grid_hash
from pdcov.bus.retask import (
    MAX_RETASK_ITEMS,
    decode_retask_body,
    decode_retask_reply,
    open_envelope,
    plan_hash,
)
from pdcov.ground.retask import ReflyInputs, propose_refly
from pdcov.ground.web_auth import post_allowed
from pdcov.planning.refly import ReflySettings, independent_grid, refly_of_grid
from pdcov.planning.scenario import scenario_of
from pdcov.service.link_setup import LinkReport
from pdcov.service.retask import RetaskRefusal
from pdcov.service.settings import load_serve_config
from tests.support.link_feed import MISSION, Hover, pack
from tests.support.retask_harness import ITEMS, KEY_EXPR, WP, Autopilot, core_with, feed, fly, heard
from tests.support.retask_keys import KEY, UNIX_S, signed


def _body_doc() -> dict:
    return json.loads(open_envelope(signed(ITEMS, description="two waypoints")).body)


def _doc(**change) -> bytes:
    doc = _body_doc()
    doc.update(change)
    return json.dumps(doc).encode()


def test_request_round_trip_keeps_nan_and_hash() -> None:
    env = open_envelope(signed(ITEMS, description="two waypoints"))
    assert env.key_id == KEY.id and len(env.signature) == 64
    req = decode_retask_body(env.body)
    assert req.plan_hash == plan_hash(ITEMS) and req.key_id == KEY.id
    assert req.issued_unix_s == UNIX_S and len(req.nonce) == 32
    assert math.isnan(req.items[0].param4) and req.items[1].param4 == 0.0
    assert req.items[0].lat_deg == WP.lat_deg and req.description == "two waypoints"


@pytest.mark.parametrize(("payload", "match"), [
    (b"\xff", "not UTF-8 JSON"),
    (_doc(version=1), "version 1"),
    (_doc(vehicle_id="no/slash"), "vehicle_id"),
    (_doc(nonce="short"), "nonce"),
    (_doc(plan_hash="0" * 16), "the items hash to"),
    (_doc(items=[]), "at least one mission item"),
])
def test_bad_requests_refused_with_the_field(payload: bytes, match: str) -> None:
    with pytest.raises(BusPayloadError, match=match):
        decode_retask_body(payload, "pdcov/fuzz/retask")


def _with_item(**change) -> bytes:
    doc = _body_doc()
    doc["items"][0].update(change)
    doc["plan_hash"] = "0" * 16  # the item refusal comes before the hash check
    return json.dumps(doc).encode()


@pytest.mark.parametrize(("change", "match"), [
    ({"command": 176}, r"items\[0\]\.command: 176 is not one a coverage plan uses"),  # SET_MODE
    ({"command": 400}, "command: 400"),  # ARM_DISARM
    ({"frame": 1}, r"items\[0\]\.frame: 1"),
    ({"lat_deg": 91}, r"items\[0\]\.lat_deg"),
    ({"params": [0, 0, 0]}, "params: expected 4 numbers"),
    ({"params": [1e9, 0, 0, 0]}, "params"),
    ({"autocontinue": 1}, "autocontinue"),
])
def test_items_outside_a_coverage_plan_refused(change: dict, match: str) -> None:
    with pytest.raises(BusPayloadError, match=match):
        decode_retask_body(_with_item(**change))


def test_item_count_and_non_finite_bounded() -> None:
    doc = _body_doc()
    doc["items"] = doc["items"][:1] * (MAX_RETASK_ITEMS + 1)
    with pytest.raises(BusPayloadError, match="more than 1000") as e:
        decode_retask_body(json.dumps(doc).encode())
    assert e.value.reason == "over a bound"
    with pytest.raises(BusPayloadError, match="non-finite"):
        decode_retask_body(_doc().replace(b'"z_m": 10.0', b'"z_m": NaN', 1))


# --- the daemon's decisions against a scripted autopilot ----------------------------------

def test_accepted_upload_is_replied_and_never_arms_or_changes_mode(tmp_path) -> None:
    core = core_with(tmp_path, retask=True)
    heard(core)
    ap = Autopilot()
    replies, logs = fly(core, ap, signed(ITEMS, description="two"), "ab12")
    assert [t for t, _ in replies] == [7]
    reply = decode_retask_reply(replies[0][1], vehicle_id="fuzz")
    assert reply.accepted and reply.reason == "MAV_MISSION_ACCEPTED"
    assert reply.items == 3 and reply.plan_hash == plan_hash(ITEMS)  # ArduPilot: home first
    assert sorted(ap.items) == [0, 1, 2]
    assert ap.items[1].x == round(WP.lat_deg * 1e7) and ap.items[1].frame == 3
    assert ap.items[0].x == round(MISSION["origin"]["lat_deg"] * 1e7)  # home: the origin
    assert {m.get_type() for m in ap.sent} == {"MISSION_COUNT", "MISSION_ITEM_INT",
                                               "STATUSTEXT"}  # the pilot's notice
    st, _ = core.status(3.0, LinkReport())
    assert st["retask"]["last"]["accepted"] is True
    assert st["retask"]["last"]["plan_hash"] == plan_hash(ITEMS)
    assert st["faults"]["retask_refused"] == 0
    assert any("uploading mission" in text for _, text in logs)


def test_every_message_the_daemon_sends_stays_off_the_controls(tmp_path) -> None:
    """Over a whole session with a re-tasking: HEARTBEAT, the stream and parameter
    requests, the coverage messages and the upload, never SET_MODE or a COMMAND_LONG
    that arms, takes off or sets a mode."""
    core = core_with(tmp_path, retask=True)
    sent = feed(core, b"".join(pack(m) for m in Hover(seconds=2.0).messages()), 1.0).send
    ap = Autopilot()
    fly(core, ap, signed(ITEMS), None)
    for t in np.arange(3.0, 12.0, 0.5):
        core.tick(float(t), 0.0)
        sent += core.actions().send
    sent += ap.sent
    assert {m.get_type() for m in sent} <= {"HEARTBEAT", "COMMAND_LONG", "PARAM_REQUEST_READ",
                                           "NAMED_VALUE_FLOAT", "STATUSTEXT",
                                           "MISSION_COUNT", "MISSION_ITEM_INT"}
    assert {m.command for m in sent if m.get_type() == "COMMAND_LONG"} <= {511, 512}


def test_refused_requests_are_answered_logged_and_counted(tmp_path) -> None:
    off = core_with(tmp_path)  # service.retask defaults to false
    heard(off)
    replies, logs = fly(off, Autopilot(), signed(ITEMS), "ab12")
    r = decode_retask_reply(replies[0][1])
    assert not r.accepted and r.reason == RetaskRefusal.DISABLED
    assert logs == [(30, "re-tasking request from session ab12 refused (PDCOV_RETASK_DISABLED): "
                         "re-tasking is off on this vehicle (service.retask: false)")]
    st, _ = off.status(3.0, LinkReport())
    assert st["faults"]["retask_refused"] == 1
    assert st["faults"]["retask_refused_disabled"] == 1
    assert st["retask"]["refused"] == {"PDCOV_RETASK_DISABLED": 1}


def test_one_upload_at_a_time_and_a_silent_autopilot_times_out(tmp_path) -> None:
    core = core_with(tmp_path, retask=True)
    core.receive_retask(1, signed(ITEMS), KEY_EXPR, None, 0.5, UNIX_S)
    assert decode_retask_reply(core.actions().replies[0][1]).reason \
        == RetaskRefusal.NO_AUTOPILOT
    heard(core)
    core.receive_retask(2, signed(ITEMS), KEY_EXPR, None, 2.0, UNIX_S)
    first = core.actions()
    assert [m.get_type() for m in first.send] == ["MISSION_COUNT"] and not first.replies
    core.receive_retask(3, signed(ITEMS[:1]), KEY_EXPR, None, 2.1, UNIX_S)
    busy = core.actions().replies
    assert [t for t, _ in busy] == [3]
    assert decode_retask_reply(busy[0][1]).reason == RetaskRefusal.BUSY
    replies = []
    for t in np.arange(2.0, 15.0, 0.25):  # nobody answers: 5 resends 1.5 s apart
        core.tick(float(t), 0.0)
        replies += core.actions().replies
    timed_out = decode_retask_reply(replies[0][1])
    assert [t for t, _ in replies] == [2]
    assert not timed_out.accepted and timed_out.reason == "TIMEOUT"


def test_autopilot_refusal_is_the_reply(tmp_path) -> None:
    core = core_with(tmp_path, retask=True)
    heard(core)
    ap = Autopilot(result=mavlink.MAV_MISSION_NO_SPACE)
    replies, _ = fly(core, ap, signed(ITEMS), None)
    r = decode_retask_reply(replies[0][1])
    assert not r.accepted and r.reason == "MAV_MISSION_NO_SPACE"


def test_upload_ignores_the_autopilot_talking_to_another_ground_station(tmp_path) -> None:
    core = core_with(tmp_path, retask=True)
    heard(core)
    core.receive_retask(1, signed(ITEMS), KEY_EXPR, None, 2.0, UNIX_S)
    core.actions()
    mav = mavlink.MAVLink(None)
    # The autopilot acknowledging QGroundControl's (255/190) upload: not ours.
    feed(core, pack(mav.mission_ack_encode(255, 190, mavlink.MAV_MISSION_ACCEPTED, 0)), 2.1)
    assert core.actions().replies == [] and core.retasker.busy


def test_retask_needs_readable_operator_keys(tmp_path) -> None:
    from pdcov.errors import ConfigError

    with pytest.raises(ConfigError, match="service.retask_operator_keys: service.retask is "
                                          "true but no operator key is listed"):
        core_with(tmp_path, retask=True, retask_operator_keys=[])
    with pytest.raises(ConfigError, match=r"retask_operator_keys: .*nokey.pub: cannot read"):
        core_with(tmp_path, retask=True, retask_operator_keys=["nokey.pub"])
    (tmp_path / "junk.pub").write_text("not a key")
    with pytest.raises(ConfigError, match=r"junk.pub: not a PEM public key"):
        core_with(tmp_path, retask=True, retask_operator_keys=["junk.pub"])
    with pytest.raises(ConfigError, match="retask_limits.max_alt: unknown key; did you mean"):
        core_with(tmp_path, retask=True, retask_limits={"max_alt": 5})
    with pytest.raises(ConfigError, match="min_alt_m < max_alt_m"):
        core_with(tmp_path, retask=True, retask_limits={"min_alt_m": 50, "max_alt_m": 10})


# --- the ground station's proposal: the same re-fly as pdcov refly --------------------

def test_proposal_is_pdcov_reflys_plan_from_where_the_vehicle_is(tmp_path) -> None:
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(dict(MISSION)))
    cfg = load_serve_config(tmp_path / "m.yaml")
    mission = cfg.mission
    sc = scenario_of(mission)
    grid = mission.new_mission_grid()
    L = np.zeros(grid.mask.shape, dtype=np.float32)
    L[:, : L.shape[1] // 2] = -5.0  # the west half seen well, the east half not at all
    settings = ReflySettings(0.8, alt_agl_m=10.0, speed_mps=3.0)
    inputs = ReflyInputs("fuzz", L, mission.origin(), (5.0, 5.0))
    p = propose_refly(inputs, sc, settings)
    cli = refly_of_grid(sc, independent_grid(sc, L), settings, (5.0, 5.0))
    assert p.description == cli.plan.description
    assert len(p.waypoints_lat_lon) == len(cli.plan.waypoints)
    assert p.gap_cells_before == cli.gaps_before.n_cells > 0
    assert plan_hash(p.items) == p.id and p.home == mission.origin()
    state = p.map_state()
    assert state["id"] == p.id and state["gaps"] and all(r[0] == r[-1] for r in state["gaps"])
    lat, lon = state["waypoints"][0]
    assert abs(lat - mission.origin_lat_deg) < 0.01 and abs(lon - mission.origin_lon_deg) < 0.01
    assert GridState.from_arrays(grid.geometry, grid.mask, L, L, np.zeros_like(L, np.int64),
                                 1).hash \
        == grid_hash(grid.geometry, grid.mask)


# --- the web map: what may change something --------------------------------------------

@pytest.mark.parametrize(("origin", "host", "ctype", "status"), [
    (None, "127.0.0.1:8080", "application/json", None),  # a script (curl, Bearer)
    ("http://127.0.0.1:8080", "127.0.0.1:8080", "application/json; charset=utf-8", None),
    ("http://evil.example", "127.0.0.1:8080", "application/json", 403),
    ("null", "127.0.0.1:8080", "application/json", 403),
    (None, "127.0.0.1:8080", "application/x-www-form-urlencoded", 403),  # a cross-site form
    (None, "127.0.0.1:8080", None, 403),
])
def test_post_needs_json_from_this_origin(origin, host, ctype, status) -> None:
    verdict = post_allowed(origin, host, ctype)
    assert (verdict is None) if status is None else verdict.status == status

"""The daemon's status stays under its 1 kB/s budget (issue 13) with full and brief
statuses (docs/protocol.md), every one readable by a version-1 receiver, and a receiver
that merges gets every field of the full status back."""

from __future__ import annotations

import copy
import json

import pytest

from pdcov.bus.status import FULL_EVERY, StatusEncoder, decode_status, merge_status
from pdcov.ground.watcher import Watcher


def flying_status(seq: int) -> dict:
    """A status as a flying daemon with a gimbal fills it (the fields of a real one, from
    pdcov serve on pdcov-sitl fly), its figures moving with ``seq``."""
    return {
        "vehicle_id": "uav-07", "seq": seq, "uptime_s": 12.345 + seq,
        "t_s": 31.2345678 + seq, "thresholds": [0.5, 0.7, 0.8],
        "proportion_at_or_above": {"0.5": 0.1234567891234 + seq * 1e-3,
                                   "0.7": 0.0987654321987, "0.8": 0.0456789123456},
        "mean_pd": 0.2345678912345678, "expected_false_alarms": 123.45678901234 + seq,
        "cells_free": 160000, "cells_observed": 23456 + seq,
        "frames": {"used": 1234 + 30 * seq, "grid": 1234 + 30 * seq,
                   "skipped": {"below min height": 61, "attitude gap": 2}, "pending": 1,
                   "source": "rate", "last_t_s": 31.2 + seq},
        "link": {"state": "connected", "url": "serial:/dev/ttyAMA0:921600",
                 "last_message_age_s": 0.004 + seq * 1e-3, "bad_messages": 3,
                 "links": [{"url": "serial:/dev/ttyAMA0:921600", "state": "connected",
                            "opens": 1, "losses": 0,
                            "last_message_age_s": 0.004 + seq * 1e-3}],
                 "system_id": 1, "component_id": 1, "autopilot": 3,
                 "messages": 51234 + 120 * seq, "other_systems": 0, "rejected": {},
                 "reboots": 0, "intervals": {"acked": [24, 30, 33, 242, 285]},
                 "home_request": "acked",
                 "params": {"MNT1_PITCH_MAX": 20.0, "MNT1_PITCH_MIN": -90.0,
                            "MNT1_ROLL_MAX": 30.0, "MNT1_ROLL_MIN": -30.0, "MNT1_TYPE": 1.0,
                            "MNT1_YAW_MAX": 180.0, "MNT1_YAW_MIN": -180.0}},
        "pose": {"lat_deg": 47.39781234567891, "lon_deg": 8.545678912345678,
                 "alt_msl_m": 548.123456789, "heading_deg": 123.456789123,
                 "t_s": 31.2345678 + seq, "gnss_h_acc_m": 0.3000001},
        "gimbal": {"mount": "gimbal", "interpretation": "body",
                   "describe": "servo mount (MNT1_TYPE 1): body-frame demand"},
        "grid": {"hash": "dacaab6c7f64e220", "x0_m": -200.0, "y0_m": -200.0,
                 "cell_size_m": 1.0, "n_rows": 400, "n_cols": 400, "tile_size": 32,
                 "origin": {"lat_deg": 47.397742, "lon_deg": 8.545594,
                            "ground_alt_msl_m": 488.0, "how": "configured"}},
        "tiles_seq": 5 * seq,
        "faults": {"reboots": 0, "link_losses": 0, "rejected_messages": 0,
                   "other_systems_messages": 0, "bad_messages": 3, "nan_samples": 0},
        "checkpoint": {"path": "/var/lib/pdcov/checkpoint.npz", "last_t_s": 20.0,
                       "resumed": False, "set_aside": None},
        "pins": {"candidates": 1234 + seq, "likely": 56,
                 "top": {"uid": "uav-07.3fa2c1.1017", "p_person": 0.9731 - seq * 1e-4,
                         "looks": 14 + seq, "hits": 9}},
    }


def test_a_minute_of_statuses_fits_the_budget():
    enc = StatusEncoder()
    sizes = [len(enc.encode(flying_status(i))) for i in range(60)]
    full = len(StatusEncoder().encode(flying_status(0)))
    assert full > 1300  # what every status cost before: over the budget by itself
    assert sum(sizes) / 60 < 1000, sizes
    assert sum(s > 1200 for s in sizes) == 60 // FULL_EVERY  # the periodic full ones


def test_the_summary_numbers_go_out_rounded_to_what_they_mean():
    doc = decode_status(StatusEncoder().encode(flying_status(0)))
    assert doc["t_s"] == 31.235 and doc["mean_pd"] == 0.234568
    assert doc["expected_false_alarms"] == 123.4568
    assert doc["proportion_at_or_above"] == {"0.5": 0.123457, "0.7": 0.098765,
                                             "0.8": 0.045679}
    assert doc["uptime_s"] == 12.345  # the daemon's own rounding (service/core.py)


def test_every_status_decodes_and_merging_restores_the_full_one():
    enc = StatusEncoder()
    merged = None
    kinds = []
    for i in range(2 * FULL_EVERY + 1):
        fields = flying_status(i)
        doc = decode_status(enc.encode(fields))  # a version-1 receiver reads both kinds
        kinds.append(doc["full"])
        merged = merge_status(merged, doc)
        want = json.loads(StatusEncoder().encode(fields))
        got = copy.deepcopy(merged)
        # Per-link ages are those of the last full status (docs/protocol.md); the
        # link's own last_message_age_s is current.
        assert got["link"]["last_message_age_s"] == want["link"]["last_message_age_s"]
        for doc_ in (got, want):
            doc_.pop("full")
            for one in doc_["link"]["links"]:
                one.pop("last_message_age_s")
        # The pins summary is the last full status's (its top uid is current).
        assert got["pins"]["top"]["uid"] == want["pins"]["top"]["uid"]
        got.pop("pins")
        want.pop("pins")
        assert got == want, i
    assert kinds[0] and kinds[FULL_EVERY] and not any(kinds[1:FULL_EVERY])


@pytest.mark.parametrize("change", [
    ("link", "intervals", {"acked": [30, 33], "refused": [285]}),
    ("gimbal", "describe", "stabilised gimbal, earth frame"),
    ("checkpoint", "error", "[Errno 28] No space left on device"),
    ("link", "reboots", 1),
])
def test_a_detail_change_goes_out_at_once(change):
    enc = StatusEncoder()
    enc.encode(flying_status(0))
    assert json.loads(enc.encode(flying_status(1)))["full"] is False
    fields = copy.deepcopy(flying_status(2))
    fields[change[0]][change[1]] = change[2]
    doc = json.loads(enc.encode(fields))
    assert doc["full"] is True and doc[change[0]][change[1]] == change[2]
    assert json.loads(enc.encode(copy.deepcopy(fields) | {"seq": 3}))["full"] is False


def test_the_pins_summary_top_goes_out_when_it_changes_and_merges_back():
    enc = StatusEncoder()
    enc.encode(flying_status(0))
    brief = decode_status(enc.encode(flying_status(1)))
    assert brief["full"] is False and "pins" not in brief
    merged = merge_status(decode_status(StatusEncoder().encode(flying_status(0))), brief)
    assert merged["pins"]["candidates"] == 1234  # the last full one's
    assert merged["pins"]["top"]["uid"] == "uav-07.3fa2c1.1017"  # the last full one's
    fields = copy.deepcopy(flying_status(2))
    fields["pins"]["top"]["uid"] = "uav-07.3fa2c1.5"  # another pin is the most likely now
    doc = decode_status(enc.encode(fields))
    assert doc["full"] is True and doc["pins"]["top"]["uid"] == "uav-07.3fa2c1.5"


@pytest.mark.parametrize(("change", "why"), [
    ({"likely": 1300}, "pins.likely: expected an integer in [0, 1234]"),
    ({"top": {"uid": "a b", "p_person": 0.5, "looks": 1, "hits": 0}}, "pins.top.uid 'a b'"),
    ({"top": {"uid": "a.b.1", "p_person": 0.5, "looks": 1, "hits": 2}},
     "pins.top.hits: expected an integer in [0, 1]"),
    ({"top": {"uid": "a.b.1", "p_person": 1.5, "looks": 1, "hits": 0}}, "pins.top.p_person"),
])
def test_a_bad_pins_summary_is_refused_naming_the_field(change, why):
    from pdcov.bus.errors import BusPayloadError

    fields = copy.deepcopy(flying_status(0))
    fields["pins"].update(change)
    with pytest.raises(BusPayloadError) as err:
        decode_status(StatusEncoder().encode(fields))
    assert why in str(err.value), str(err.value)


def test_pins_summary_counts_the_likely_and_names_the_top():
    import numpy as np

    from pdcov.core.detections import Candidate
    from pdcov.service.status import pins_summary

    def cand(i: int, p: float, hits: int) -> Candidate:
        return Candidate(i, "person", np.zeros(3), 0.5, hits, 5, 0.5, 0.01, 0.8, 1.0, 2.0,
                         f"uav1.abcdef.{i}", p)

    assert pins_summary([]) == {"candidates": 0, "likely": 0, "top": None}
    got = pins_summary([cand(0, 0.2, 1), cand(1, 0.5, 2), cand(2, 0.91234567, 3),
                        cand(3, 0.91234567, 4), cand(4, 0.49, 5)])
    assert got == {"candidates": 5, "likely": 3, "top": {
        "uid": "uav1.abcdef.3", "p_person": 0.9123, "looks": 5, "hits": 4}}


def test_checkpoint_progress_alone_waits_for_the_next_full_status():
    # Each checkpoint written moves last_t_s, written_unix_s and frames: were that a detail
    # change, every checkpoint's status would be full (1,061-1,071 B per status, over the
    # 1 kB/s budget, in benchmarks.fleet).
    enc = StatusEncoder()
    enc.encode(flying_status(0))
    fields = copy.deepcopy(flying_status(1))
    fields["checkpoint"].update(last_t_s=30.0, written_unix_s=1.8e9, frames=400)
    assert json.loads(enc.encode(fields))["full"] is False


def test_the_watcher_keeps_the_detail_and_sees_a_new_mission():
    enc = StatusEncoder()
    w = Watcher()
    for i in range(3):
        w.on_status("uav-07", decode_status(enc.encode(flying_status(i))), float(i))
    feed = w.feeds["uav-07"]
    assert feed.status["full"] is False
    assert feed.status["link"]["intervals"] == {"acked": [24, 30, 33, 242, 285]}
    assert feed.status["grid"]["origin"]["lat_deg"] == 47.397742
    assert feed.status["faults"]["nan_samples"] == 0
    assert w.report(3.0).vehicles[0].link == "connected"

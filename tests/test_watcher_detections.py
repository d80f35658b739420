"""The watcher's detections in memory (ground/watcher.py): candidates and recent detections
kept per vehicle from the pinned session only, the whole list asked for after every
snapshot, bounded with the forgotten counted; what the terminal, --once and the web map show
of them; and the recording's exports (ground/record_exports.py) written at a bounded rate,
kept when a write fails and retried."""

from __future__ import annotations

import json
import logging

from exports_fixtures import candidate, detection
from watch_fixtures import TinyPublisher

from pdcov.bus.grid_state import decode_snapshot
from pdcov.bus.status import decode_status
from pdcov.errors import OutputError
from pdcov.ground import record_exports
from pdcov.ground.record_exports import ExportRecorder
from pdcov.ground.terminal import plain_lines
from pdcov.ground.watcher import QueryCandidates, QuerySnapshot, Watcher
from pdcov.ground.web import map_state

DAEMON = "a1" * 16
ROGUE = "e7" * 16


def doc(vehicle: str, detections=(), candidates=()) -> dict:
    return {"schema": "pdcov.detections", "version": 1, "vehicle": vehicle,
            "detections": list(detections), "candidates": list(candidates)}


def pinned(watcher: Watcher | None = None) -> tuple[Watcher, TinyPublisher]:
    """A watcher following vehicle uav1, pinned to DAEMON by its snapshot reply."""
    w = watcher or Watcher()
    pub = TinyPublisher("uav1")
    pub.step(4)
    actions = w.on_status("uav1", decode_status(pub.status()), 0.0, DAEMON)
    assert actions == [QuerySnapshot("uav1")]
    w.on_snapshot_replies("uav1", [(DAEMON, decode_snapshot(pub.snapshot()))], 0.1)
    return w, pub


def test_candidates_are_asked_after_each_snapshot_and_replace_what_is_held():
    w, pub = pinned()
    feed = w.feeds["uav1"]
    assert w.candidates_due(0.2) == [QueryCandidates("uav1")]
    assert w.candidates_due(0.3) == []  # once per snapshot
    assert feed.candidates_done_at != feed.snapshots  # --once waits for the answer
    w.on_candidates_replies("uav1", [(DAEMON, doc("uav1", candidates=[
        candidate(1, 0, 0), candidate(2, 5, 5)]))], 0.4)
    assert sorted(feed.candidates) == [1, 2] and feed.candidates_done_at == feed.snapshots
    # New detections and the candidates they touched update the list.
    w.on_detections("uav1", doc("uav1", [detection(2, 5, 5)],
                                [candidate(2, 5, 5, hits=10, looks=15)]), 1.0, DAEMON)
    assert feed.candidates[2]["hits"] == 10 and len(feed.detections) == 1
    # A gap: the snapshot is taken again, and so is the whole candidate list.
    w.on_snapshot_replies("uav1", [(DAEMON, decode_snapshot(pub.snapshot()))], 2.0)
    assert w.candidates_due(2.1) == [QueryCandidates("uav1")]
    w.on_candidates_replies("uav1", [(DAEMON, doc("uav1", candidates=[candidate(2, 5, 5)]))],
                            2.2)
    assert sorted(feed.candidates) == [2]


def test_an_unanswered_candidates_query_is_asked_again():
    w, _ = pinned(Watcher(mission_retry_s=5.0))
    assert w.candidates_due(0.2)
    w.on_candidates_replies("uav1", [], 0.5)  # timeout, or an older daemon
    feed = w.feeds["uav1"]
    assert feed.candidates_done_at == feed.snapshots  # --once does not wait for more
    assert w.candidates_due(4.0) == []
    assert w.candidates_due(5.6) == [QueryCandidates("uav1")]


def test_another_sessions_detections_and_replies_are_refused_and_counted():
    w, _ = pinned()
    feed = w.feeds["uav1"]
    before = feed.claim.refused
    w.on_detections("uav1", doc("uav1", [detection(7, 1, 1)], [candidate(7, 1, 1)]), 1.0,
                    ROGUE)
    w.on_candidates_replies("uav1", [(ROGUE, doc("uav1", candidates=[candidate(8, 2, 2)])),
                                     (DAEMON, doc("uav1", candidates=[candidate(1, 0, 0)]))],
                            1.5)
    assert sorted(feed.candidates) == [1] and not feed.detections
    assert feed.claim.refused == before + 2
    assert any("also claims this vehicle" in line for line in w.report(2.0).warnings)


def test_candidates_are_bounded_weakest_forgotten_and_said():
    w, _ = pinned(Watcher(max_candidates=3, max_detections=2))
    cands = [candidate(k, k, 0, hits=h, last_t_boot_s=10.0 + k)
             for k, h in enumerate((5, 1, 7, 1, 9))]
    w.on_detections("uav1", doc("uav1", [detection(k, k, 0) for k in range(5)], cands), 1.0,
                    DAEMON)
    feed = w.feeds["uav1"]
    assert sorted(feed.candidates) == [0, 2, 4]  # the two with 1 hit went
    assert feed.candidates_dropped == 2
    assert [d["candidate"] for d in feed.detections] == [3, 4]  # the newest two
    assert any("2 weakest detection candidates forgotten" in line
               for line in w.report(1.0).warnings)


def test_terminal_once_and_map_state_show_the_candidates():
    w, _ = pinned()
    w.on_detections("uav1", doc("uav1", [detection(3, 1, 1)],
                                [candidate(3, 1, 1, hits=9, looks=14), candidate(4, 2, 2, 1, 2)]),
                    1.0, DAEMON)
    report = w.report(1.0)
    text = "\n".join(plain_lines(report))
    assert "cand" in text  # the table's column
    assert "candidates uav1: 2 (most detected: person #3: detected 9 of 14 looks" in text
    state = map_state(w, report, None, 1, None)
    (vehicle,) = state["vehicles"]
    assert [c["id"] for c in vehicle["candidates"]] == [3, 4]
    assert set(vehicle["candidates"][0]) == {
        "id", "class", "lat_deg", "lon_deg", "sigma_m", "hits", "looks", "pd", "pfa",
        "confidence", "first_t_boot_s", "last_t_boot_s"}
    json.dumps(state, allow_nan=False)


def test_recording_exports_at_a_bounded_rate(tmp_path):
    w, _ = pinned()
    rec = ExportRecorder(tmp_path / "exports", period_s=5.0)
    assert rec.poll(w, version=1, now_s=0.0)
    assert not rec.poll(w, version=2, now_s=3.0)  # within the period
    assert not rec.poll(w, version=2, now_s=3.5)
    assert rec.poll(w, version=2, now_s=5.1)
    assert not rec.poll(w, version=2, now_s=20.0)  # nothing new
    assert rec.written == 2
    files = {p.name for p in (tmp_path / "exports").iterdir()}
    assert {"detections.geojson", "caltopo.geojson", "pdcov.kml", "pdcov.kmz"} <= files


def test_a_failing_export_is_logged_once_keeps_the_last_files_and_is_retried(
        tmp_path, monkeypatch, caplog):
    w, _ = pinned()
    rec = ExportRecorder(tmp_path / "exports", period_s=1.0)
    w.on_detections("uav1", doc("uav1", [], [candidate(3, 1, 1)]), 0.5, DAEMON)
    assert rec.poll(w, 1, 0.0)
    kept = (tmp_path / "exports" / "detections.geojson").read_bytes()
    real = record_exports.write_exports

    def full_disk(*args, **kwargs):
        raise OutputError(f"{tmp_path}/exports/caltopo.geojson: cannot write (No space left "
                          "on device)")

    monkeypatch.setattr(record_exports, "write_exports", full_disk)
    w.on_detections("uav1", doc("uav1", [], [candidate(3, 1, 1, hits=10)]), 1.0, DAEMON)
    with caplog.at_level(logging.WARNING, "pdcov.watch"):
        assert not rec.poll(w, 2, 1.5)
        assert not rec.poll(w, 3, 2.6)
    assert len([r for r in caplog.records if "No space left" in r.getMessage()]) == 1
    assert rec.write_errors == 2 and "No space left" in rec.warning
    assert (tmp_path / "exports" / "detections.geojson").read_bytes() == kept
    monkeypatch.setattr(record_exports, "write_exports", real)
    assert rec.poll(w, 3, 3.7) and rec.warning is None
    doc_now = json.loads((tmp_path / "exports" / "detections.geojson").read_text())
    assert doc_now["features"][0]["properties"]["hits"] == 10


def test_malformed_detections_payloads_are_counted_by_reason_and_never_applied():
    from pdcov.bus.detections import encode_detections
    from pdcov.bus.session import BusConfig
    from pdcov.ground.live import WatchShell

    w, _ = pinned()
    recorded = []
    shell = WatchShell(w, BusConfig(), record=lambda *a: recorded.append(a))
    key = "pdcov/uav1/detections"
    good = doc("uav1", [detection(3, 1, 1)], [candidate(3, 1, 1)])
    nan = encode_detections(good).replace(b'"sigma_m":0.5', b'"sigma_m":NaN')
    other = encode_detections(doc("uav2", [], [candidate(5, 1, 1)]))  # on uav1's key
    for payload in (b"{not json", nan, other, b'{"schema": "pdcov.detections"}',
                    b"x" * (9 << 20)):
        shell._received(key, payload, DAEMON)
    assert w.refused == {"payloads: malformed": 2, "payloads: non-finite number": 1,
                         "payloads: bad field": 1, "payloads: too large": 1}
    assert not w.feeds["uav1"].candidates and not recorded
    shell._received(key, encode_detections(good), DAEMON)
    assert sorted(w.feeds["uav1"].candidates) == [3]
    assert [(vid, kind) for vid, kind, _ in recorded] == [("uav1", "detections")]

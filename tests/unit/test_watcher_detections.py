"""The watcher's pins (ground/watcher.py): candidates kept by uid per vehicle from the
pinned session only, updated in place and kept across the daemon's restart (its new
session), the whole list asked for after every snapshot, bounded with the forgotten
counted; every detection logged on disk and in detections.geojson, the latest in memory;
what the terminal, --once and the web map show of them; and the recording's exports
(ground/record_exports.py) written at a bounded rate, kept when a write fails and
retried."""

from __future__ import annotations

import json
import logging

from pdcov.bus.grid_state import decode_snapshot
from pdcov.bus.status import decode_status
from pdcov.errors import OutputError
from pdcov.ground import record_exports
from pdcov.ground.queries import QueryCandidates
from pdcov.ground.record_exports import ExportRecorder
from pdcov.ground.terminal import plain_lines
from pdcov.ground.watcher import Watcher
from pdcov.ground.web import map_state
from tests.support.exports_fixtures import candidate, detection, uid
from tests.support.watch_fixtures import PINNED_SESSION, TinyPublisher, pinned

DAEMON = PINNED_SESSION
ROGUE = "e7" * 16


def doc(vehicle: str, detections=(), candidates=()) -> dict:
    return {"schema": "pdcov.detections", "version": 2, "vehicle": vehicle,
            "detections": list(detections), "candidates": list(candidates)}


def test_candidates_are_asked_after_each_snapshot_and_update_what_is_held():
    w, pub = pinned()
    feed = w.feeds["uav1"]
    assert w.candidates_due(0.2) == [QueryCandidates("uav1")]
    assert w.candidates_due(0.3) == []  # once per snapshot
    assert feed.candidates_done_at != feed.snapshots  # --once waits for the answer
    w.on_candidates_replies("uav1", [(DAEMON, doc("uav1", candidates=[
        candidate(1, 0, 0), candidate(2, 5, 5)]))], 0.4)
    assert sorted(feed.candidates) == [uid(1), uid(2)]
    assert feed.candidates_done_at == feed.snapshots
    # New detections and the candidates they touched update the list.
    w.on_detections("uav1", doc("uav1", [detection(2, 5, 5)],
                                [candidate(2, 5, 5, hits=10, looks=15)]), 1.0, DAEMON)
    assert feed.candidates[uid(2)]["hits"] == 10 and len(feed.detections) == 1
    # A gap: the snapshot is taken again, and so is the whole candidate list, which
    # updates the pins it names (by uid) and leaves the others.
    w.on_snapshot_replies("uav1", [(DAEMON, decode_snapshot(pub.snapshot()))], 2.0)
    assert w.candidates_due(2.1) == [QueryCandidates("uav1")]
    w.on_candidates_replies("uav1", [(DAEMON, doc("uav1", candidates=[
        candidate(2, 5, 5, hits=10, looks=16, p_person=0.5)]))], 2.2)
    assert sorted(feed.candidates) == [uid(1), uid(2)]
    assert feed.candidates[uid(2)]["looks"] == 16 and feed.candidates[uid(2)]["p_person"] == 0.5
    # Puts carry only the candidates new detections touch: the list is asked again every
    # candidates_refresh_s (30 s), so a pin seen again without a hit shows its p_person fall.
    assert w.candidates_due(32.1) == []
    assert w.candidates_due(32.3) == [QueryCandidates("uav1")]
    w.on_candidates_replies("uav1", [(DAEMON, doc("uav1", candidates=[
        candidate(1, 0, 0, hits=9, looks=20, p_person=0.31)]))], 32.5)
    assert feed.candidates[uid(1)]["p_person"] == 0.31


RESTARTED = "b2" * 16


def test_pins_survive_the_daemons_restart_and_merge_by_uid():
    w, pub = pinned()
    feed = w.feeds["uav1"]
    w.on_detections("uav1", doc("uav1", [detection(1, 0, 0), detection(2, 5, 5)],
                                [candidate(1, 0, 0), candidate(2, 5, 5)]), 1.0, DAEMON)
    # The daemon restarts: a new Zenoh session answers the next snapshot query.
    w.on_snapshot_replies("uav1", [(RESTARTED, decode_snapshot(pub.snapshot()))], 5.0)
    assert feed.claim.session == RESTARTED
    assert sorted(feed.candidates) == [uid(1), uid(2)] and len(feed.detections) == 2
    # Its restored candidates merge with the pins held: the same uid is updated in place,
    # the numbering goes on (candidate 3) and nothing from before is lost.
    w.on_candidates_replies("uav1", [(RESTARTED, doc("uav1", candidates=[
        candidate(2, 5, 5, hits=9, looks=20, p_person=0.8), candidate(3, 9, 9)]))], 5.2)
    w.on_detections("uav1", doc("uav1", [detection(3, 9, 9)], [candidate(3, 9, 9)]), 6.0,
                    RESTARTED)
    assert sorted(feed.candidates) == [uid(1), uid(2), uid(3)]
    assert feed.candidates[uid(2)]["looks"] == 20 and len(feed.detections) == 3
    # The old session is now another session: what it says is refused.
    w.on_detections("uav1", doc("uav1", [], [candidate(2, 5, 5, 1, 1)]), 6.5, DAEMON)
    assert feed.candidates[uid(2)]["looks"] == 20


def test_provisional_findings_are_kept_or_dropped_by_the_pin():
    logged: list[tuple[str, list]] = []

    def log(vid, entries):
        logged.append((vid, [d["uid"] for d in entries]))

    for first, kept in ((DAEMON, True), (ROGUE, False)):
        logged.clear()
        w = Watcher(detection_log=log)
        pub = TinyPublisher("uav1")
        pub.step(4)
        w.on_status("uav1", decode_status(pub.status()), 0.0, DAEMON)
        # Before any pin, findings are taken provisionally ...
        w.on_detections("uav1", doc("uav1", [detection(7, 1, 1)], [candidate(7, 1, 1)]),
                        0.05, first)
        assert uid(7) in w.feeds["uav1"].candidates and logged == []
        # ... and the snapshot's session decides.
        w.on_snapshot_replies("uav1", [(DAEMON, decode_snapshot(pub.snapshot()))], 0.1)
        w.on_detections("uav1", doc("uav1", [detection(8, 2, 2)], [candidate(8, 2, 2)]),
                        0.2, DAEMON)
        feed = w.feeds["uav1"]
        assert (uid(7) in feed.candidates) is kept
        assert [d["uid"] for d in feed.detections] == [uid(7), uid(8)] if kept else [uid(8)]
        assert logged == ([("uav1", [uid(7)]), ("uav1", [uid(8)])] if kept
                          else [("uav1", [uid(8)])])


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
    assert sorted(feed.candidates) == [uid(1)] and not feed.detections
    assert feed.claim.refused == before + 2
    assert any("also claims this vehicle" in line for line in w.report(2.0).warnings)


def test_candidates_are_bounded_least_probable_forgotten_and_said():
    w, _ = pinned(Watcher(max_candidates=3, max_detections=2))
    cands = [candidate(k, k, 0, hits=h, last_t_boot_s=10.0 + k, p_person=p)
             for k, (h, p) in enumerate(((5, 0.9), (1, 0.9), (7, 0.2), (1, 0.1), (9, 0.9)))]
    w.on_detections("uav1", doc("uav1", [detection(k, k, 0) for k in range(5)], cands), 1.0,
                    DAEMON)
    feed = w.feeds["uav1"]
    assert sorted(feed.candidates) == [uid(0), uid(1), uid(4)]  # p_person 0.2 and 0.1 went
    assert feed.candidates_dropped == 2
    assert [d["candidate"] for d in feed.detections] == [3, 4]  # the newest two
    assert any("2 weakest detection candidates forgotten" in line
               for line in w.report(1.0).warnings)


def test_terminal_once_and_map_state_show_the_candidates():
    w, _ = pinned()
    w.on_detections("uav1", doc("uav1", [detection(3, 1, 1)],
                                [candidate(3, 1, 1, hits=9, looks=14, p_person=0.25),
                                 candidate(4, 2, 2, 1, 2)]),
                    1.0, DAEMON)
    report = w.report(1.0)
    text = "\n".join(plain_lines(report))
    assert "cand" in text  # the table's column
    assert ("pins uav1: 2, 1 with p_person >= 0.5 (most probable: person uav1.3fa2c1.4: "
            "p_person 0.973, detected 1 of 2 looks)") in " ".join(text.split())  # wrapped
    state = map_state(w, report, None, 1, None)
    (vehicle,) = state["vehicles"]
    assert [c["id"] for c in vehicle["candidates"]] == [4, 3]  # the most probable first
    assert set(vehicle["candidates"][0]) == {
        "id", "uid", "class", "lat_deg", "lon_deg", "sigma_m", "p_person", "hits", "looks",
        "pd", "pfa", "confidence", "first_t_boot_s", "last_t_boot_s", "first_time_utc",
        "last_time_utc"}
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
    assert {"detections.geojson", "caltopo.geojson", "pdcov.kml", "pdcov.kmz",
            "pdcov_atak.zip"} <= files


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
    assert sorted(w.feeds["uav1"].candidates) == [uid(3)]
    assert [(vid, kind) for vid, kind, _ in recorded] == [("uav1", "detections")]


def test_every_detection_reaches_detections_geojson_from_the_log_on_disk(tmp_path):
    rec = ExportRecorder(tmp_path / "exports", period_s=1.0)
    w, _ = pinned(Watcher(detection_log=rec.detection_log))
    pins = [candidate(c, c, 0, p_person=0.1 * (c + 1)) for c in range(4)]
    for k in range(3):  # 3 puts of 400 detections of 4 pins: 1,200 in all
        w.on_detections("uav1", doc("uav1", [
            detection(j % 4, j % 4, 0, t_boot_s=10.0 + 400 * k + j) for j in range(400)],
            pins), 1.0 + k, DAEMON)
    assert len(w.feeds["uav1"].detections) == 500  # in memory: the latest, for the views
    log = tmp_path / "uav1" / "pins-detections.jsonl"
    assert len(log.read_text().splitlines()) == 1200
    assert rec.write(w)
    features = json.loads((tmp_path / "exports" / "detections.geojson").read_text())[
        "features"]
    kinds = [f["properties"]["kind"] for f in features]
    assert kinds == ["candidate"] * 4 + ["detection"] * 1200
    dets = [f["properties"] for f in features[4:]]
    assert [d["t_boot_s"] for d in dets] == [10.0 + n for n in range(1200)]  # in order
    d = dets[1199]  # candidate 3: its pin's figures
    assert (d["uid"], d["p_person"], d["looks"], d["hits"]) == (uid(3), 0.4, 14, 9)
    assert [f["properties"]["uid"] for f in features[:4]] == [uid(3), uid(2), uid(1), uid(0)]
    kml = (tmp_path / "exports" / "pdcov.kml").read_text()
    assert kml.count("<styleUrl>#detection</styleUrl>") == 500  # the KML: the latest
    assert kml.count("<styleUrl>#candidate</styleUrl>") == 4

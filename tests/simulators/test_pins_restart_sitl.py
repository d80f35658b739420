"""Pins survive restarts of ``pdcov serve`` in a real flight (issue 35, "a restart"): the
JSBSim simulator flies the demo plan over 200 people at twice real time (``--speed 2``),
its detector's boxes published as frames v2 on Zenoh (service.frame_source: zenoh) into a
daemon reading the autopilot over UDP with a state directory. Mid-flight the daemon is stopped with
SIGTERM (exit 0) and started again on the same config and state directory; later, after at
least one detections publish since that restart, it is killed with SIGKILL and started again.

A subscriber on pdcov/sim1/detections keeps every candidate's last published position by
uid. After each restart and after landing the candidates query answers every uid ever
published, within 0.5 m of its last published position, uids unique and all of one epoch
("sim1.<epoch>.<id>"), the ids of candidates first seen after a restart above those before.

Then the pins are scored by person identity with pin_score's rules: each published detection
is matched to the simulator's box (detections.csv: t_boot_s and box, its person_id); the
share of people found (a pin holding one of their boxes within 2 m of them) is within three
Poisson-binomial sds of the mean cumulative P_D at their cells in the daemon's grid after
landing (its snapshot); no pin holds two boxes of one frame; hits <= looks on every pin.

While the daemon is down the simulator keeps flying: those frames' boxes never reach it, so
people seen only then are not found. That is fair: the prediction is the daemon's own grid,
which lacks those frames too. After SIGKILL the grid resumes from its checkpoint (written
every 0.5 s of the daemon's clock, later when the machine is busy) and so lacks the frames
the killed daemon took after it, while the candidates restored from the journal keep their
boxes: those boxes (after the resumed checkpoint's last frame, its log says when) are left
out of the score like the boxes of the frames while it was down.
"""

from __future__ import annotations

import csv
import os
import re
import signal
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from pdcov.bus.detections import decode_detections
from pdcov.bus.keys import VehicleKeys
from pdcov.core.detections import Candidate
from pdcov_sitl.pin_score import DetectionOwners, found_people, found_share, merges
from tests.support.search_demo import DEMO, PEOPLE, demo_plan
from tests.support.serve_harness import (
    candidates_query,
    fly_args,
    free_port,
    process,
    serve_args,
    serve_config,
    stop,
    watched,
)

pytest.importorskip("jsbsim")
SEED = 3
KEPT_WITHIN_M = 0.5
KEYS = VehicleKeys("sim1")
SPEED = 2.0
CHECKPOINT_PERIOD_S = 0.5
"""Half the 1 s that --speed 1 had: a SIGKILL still loses at most 1 simulated second."""


class Pins:
    """Every detections message published on pdcov/sim1/detections (decoded), and the
    candidates query."""

    def __init__(self, session) -> None:
        self.session = session
        self.lock = threading.Lock()
        self.docs: list[dict] = []
        self.sub = session.declare_subscriber(KEYS.detections, self._on)

    def _on(self, sample) -> None:
        doc = decode_detections(sample.payload.to_bytes(), vehicle_id="sim1")
        with self.lock:
            self.docs.append(doc)

    def published(self) -> tuple[int, dict[str, dict]]:
        """Messages so far, and the last published state of every candidate by uid."""
        with self.lock:
            docs = list(self.docs)
        return len(docs), {c["uid"]: c for d in docs for c in d["candidates"]}

    def detections(self, since: int = 0, until: int | None = None) -> list[dict]:
        """The detections of the messages ``since`` to ``until`` (published order)."""
        with self.lock:
            return [d for doc in self.docs[since:until] for d in doc["detections"]]

    def candidates(self) -> list[dict]:
        return candidates_query(self.session, KEYS, timeout_s=60.0)

    def wait_publish(self, after: int, timeout_s: float, what: str) -> None:
        end = time.monotonic() + timeout_s
        while self.published()[0] <= after:
            assert time.monotonic() < end, f"timed out waiting for {what}"
            time.sleep(0.05)

    def close(self) -> None:
        self.sub.undeclare()


def kept(pins: Pins, what: str, ids_before: int | None = None) -> tuple[list[dict], float]:
    """The candidates query against everything published (module docstring); the answer and
    the largest distance (m) of a published uid from its last published position."""
    _, last = pins.published()
    answer = pins.candidates()
    uids = [c["uid"] for c in answer]
    assert len(set(uids)) == len(uids), f"{what}: uids repeat"
    assert len({u.rsplit(".", 1)[0] for u in uids}) <= 1, f"{what}: epochs {set(uids)}"
    by_uid = {c["uid"]: c for c in answer}
    missing = sorted(set(last) - by_uid.keys())
    assert not missing, f"{what}: published uids missing: {missing[:10]} of {len(last)}"
    moves = [float(np.hypot(by_uid[u]["x_m"] - c["x_m"], by_uid[u]["y_m"] - c["y_m"]))
             for u, c in last.items()]
    worst = max(moves, default=0.0)
    assert worst <= KEPT_WITHIN_M, f"{what}: a published pin moved {worst:.3f} m"
    for c in answer:
        assert c["uid"] == f"sim1.{c['uid'].split('.')[1]}.{c['id']}", c["uid"]
    if ids_before is not None:
        new = [c["id"] for c in answer if c["uid"] not in last]
        assert all(i >= ids_before for i in new), f"{what}: new ids {new} reuse old ones"
    print(f"{what}: {len(answer)} candidates, {len(last)} published uids kept, "
          f"max move {worst:.4f} m")
    return answer, worst


def timed_status(sub) -> float:
    """The autopilot time (s) of the latest status that has one (a daemon just restarted
    publishes statuses without a time until its first sample)."""
    return sub.wait(lambda s: s["t_s"] is not None, 10, "a status with a time")["t_s"]


def restart_flight(tmp: Path) -> dict:
    doc = {**yaml.safe_load(DEMO.read_text()), "vehicle_id": "sim1"}
    plan = demo_plan(tmp)
    zport, mport = free_port(), free_port(socket.SOCK_DGRAM)
    cfg = serve_config(doc, tmp / "m.yaml", zenoh_port=zport, state_dir=tmp / "st",
                       frame_source="zenoh", checkpoint_period_s=CHECKPOINT_PERIOD_S)
    args = serve_args(cfg, "--connect", f"udpin:127.0.0.1:{mport}")
    out: dict = {"moves": []}
    with watched(zport) as sub:
        pins = Pins(sub.session)
        try:
            with process(args, tmp / "serve1.log") as daemon:
                sub.wait(lambda s: True, 60, "the daemon's first status")
                with process(fly_args(cfg, plan, tmp / "fly", f"udpout:127.0.0.1:{mport}",
                                      "--targets", str(PEOPLE), "--seed", str(SEED),
                                      speed=SPEED), tmp / "fly.log") as fly:
                    # 1. SIGTERM once some pins are out.
                    end = time.monotonic() + 120
                    while len(pins.published()[1]) < 10:
                        assert time.monotonic() < end and fly.poll() is None, "no pins"
                        time.sleep(0.1)
                    out["t_sigterm_s"] = timed_status(sub)
                    assert stop(daemon) == 0, (tmp / "serve1.log").read_text()[-3000:]
                    ids_before = 1 + max(c["id"] for c in pins.published()[1].values())
                    with process(args, tmp / "serve2.log") as daemon2:
                        out["moves"].append(kept(pins, "after SIGTERM")[1])
                        # 2. SIGKILL after a publish of the restarted daemon.
                        n = pins.published()[0]
                        pins.wait_publish(n, 120, "a publish after the restart")
                        assert fly.poll() is None, "the flight ended before the SIGKILL"
                        out["t_sigkill_s"] = timed_status(sub)
                        os.killpg(daemon2.pid, signal.SIGKILL)
                        daemon2.wait(timeout=20)
                    ids_before = 1 + max(c["id"] for c in pins.published()[1].values())
                    out["docs_before_sigkill"] = pins.published()[0]
                    with process(args, tmp / "serve3.log") as daemon3:
                        out["moves"].append(kept(pins, "after SIGKILL")[1])
                        log3 = (tmp / "serve3.log").read_text()
                        assert "journal lines" in log3
                        out["resumed_t_s"] = float(re.search(
                            r"resumed from .*: \d+ frames, last frame at t = (\S+) s",
                            log3).group(1))
                        assert fly.wait(timeout=400) == 0, (tmp / "fly.log").read_text()[-2000:]
                        time.sleep(5.0)  # the last frames and publishes
                        final, move = kept(pins, "after landing", ids_before)
                        out["moves"].append(move)
                        out["final"] = final
                        out["snap"] = sub.snapshot()
                        # The grid resumed from its checkpoint: the frames after it that
                        # the killed daemon took are not in it, so their boxes are not
                        # scored either (as those of the frames while it was down).
                        n = out["docs_before_sigkill"]
                        out["detections"] = [
                            d for d in pins.detections(until=n)
                            if d["t_boot_s"] <= out["resumed_t_s"]] + pins.detections(since=n)
                        assert stop(daemon3) == 0, (tmp / "serve3.log").read_text()[-3000:]
        finally:
            pins.close()
    out["fly"] = tmp / "fly"
    return out


def rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def candidate(c: dict) -> Candidate:
    return Candidate(c["id"], c["class"], np.array([c["x_m"], c["y_m"], 0.0]), c["sigma_m"],
                     c["hits"], c["looks"], c["pd"], c["pfa"], c["confidence"],
                     c["first_t_boot_s"], c["last_t_boot_s"], c["uid"], c["p_person"])


def test_pins_survive_restarts_and_score_as_predicted(tmp_path):
    out = restart_flight(tmp_path)
    people = np.array([[float(r["x_m"]), float(r["y_m"])]
                       for r in rows(out["fly"] / "targets.csv")])
    assert len(people) == PEOPLE
    by_frame: dict[float, list[dict]] = {}
    for r in rows(out["fly"] / "detections.csv"):
        by_frame.setdefault(round(float(r["t_boot_s"]), 3), []).append(r)
    frames = {t: k for k, t in enumerate(sorted(by_frame))}
    cid, frame, pid, unmatched = [], [], [], 0
    for d in out["detections"]:
        t = round(d["t_boot_s"], 3)
        left, top = d["box_px"][:2]
        same = [r for r in by_frame.get(t, []) if abs(float(r["left_px"]) - left) < 0.01
                and abs(float(r["top_px"]) - top) < 0.01]
        if len(same) != 1:
            unmatched += 1
            continue
        cid.append(d["candidate"])
        frame.append(frames[t])
        pid.append(int(same[0]["person_id"]))
    owners = DetectionOwners(np.array(cid), np.array(frame), np.array(pid))
    pins = [candidate(c) for c in out["final"]]
    found = found_people(owners, pins, people)
    snap = out["snap"]
    pd = 0.0 - np.expm1(snap.log_miss_d.astype(np.float64))
    share = found_share(found, pd[snap.geometry.cell_of(people[:, 0], people[:, 1])])
    m = merges(owners, np.array([c.candidate_id for c in pins]))
    over = [c.uid for c in pins if c.hits > c.looks]
    spreads = [float(np.ptp(people[np.unique(pid_)], axis=0).max()) for pid_ in (
        owners.person_id[(owners.candidate_id == c.candidate_id) & (owners.person_id >= 0)]
        for c in pins) if len(np.unique(pid_)) >= 2]
    sent = sum(len(v) for v in by_frame.values())
    print(f"found {share.n_found}/{share.n_people} = {share.share:.3f}; predicted "
          f"{share.predicted:.3f}, sd {share.sd:.3f}, z = {share.z:+.2f}; "
          f"{len(out['detections'])} detections published ({unmatched} unmatched; the "
          f"simulator sent {sent}), {len(pins)} pins, {m.n_pins} holding people, "
          f"{m.n_two_people} two people, {m.n_two_boxes_one_frame} two boxes of one frame; "
          f"max move {max(out['moves']):.4f} m; SIGTERM at t = {out['t_sigterm_s']:.1f} s, "
          f"SIGKILL at {out['t_sigkill_s']:.1f} s; two-people pins span (m, largest axis): "
          f"median {np.median(spreads) if spreads else 0:.2f}, max {max(spreads, default=0):.2f}")
    assert unmatched == 0
    assert len(out["detections"]) < sent  # boxes were lost while the daemon was down
    assert m.n_two_boxes_one_frame == 0
    assert not over, f"hits > looks: {over[:10]}"
    assert share.as_predicted, share

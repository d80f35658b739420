"""`pdcov demo` end to end, live, at high speed: the in-process router, the simulator(s),
the daemon(s) and the watcher as processes, all on loopback. Checks the fleet grid against
the daemons' checkpoints, a watcher that joins mid-flight, and the web map in a real
headless browser against the daemon's final status."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from pdcov.atomic import MARKER
from tests.support.checkpoint_files import read_checkpoint
from tests.support.cli_inputs import mount_tmpfs
from tests.support.demo_run import Run, demo_args


def load(path: Path) -> dict:
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def test_two_vehicle_demo_fleet_is_the_sum_and_a_late_watcher_agrees(tmp_path):
    out = tmp_path / "demo"
    # At 5x the flight lasts about 10 s of wall time, so that the late watcher (a Python
    # process and a Zenoh session to start) joins while it flies even on a loaded machine;
    # at the other tests' 20x (about 2.5 s) it sometimes came after the landing.
    demo = Run(demo_args(out, "--vehicles", "2", speed="5"), tmp_path)
    late = None
    try:
        router = demo.wait_line(r"following pdcov/\*/ \(client(?: \(auto\))?, connect \[([^],]+)\]",
                               90)[1]
        # Join when both vehicles are flying and coverage has begun.
        demo.wait_line(r"coverage ([1-9]\d?\.\d)% .*2 vehicles", 120)
        late = Run([sys.executable, "-m", "pdcov.cli", "watch", "--mode", "client",
                    "--zenoh-connect", router, "--no-multicast-scouting", "--plain",
                    "--record", str(tmp_path / "late")], tmp_path)
        late.wait_line("following", 60)
        assert demo.wait(300) == 0, "\n".join(demo.lines[-30:])
        late.p.send_signal(signal.SIGTERM)
        assert late.wait(60) == 0, "\n".join(late.lines[-30:])
    finally:
        demo.close()
        if late is not None:
            late.close()
    summary = json.loads((out / "demo.json").read_text())
    ck = {v: read_checkpoint(out / "state" / v / "checkpoint") for v in ("uav1", "uav2")}
    for name in ("log_miss_d", "log_miss_fa", "n_obs"):
        total = ck["uav1"][name] + ck["uav2"][name]
        for rec in (out / "report", tmp_path / "late"):
            np.testing.assert_array_equal(load(rec / "fleet" / "grid.npz")[name], total,
                                          err_msg=f"{rec}: {name}")
            for v in ("uav1", "uav2"):
                np.testing.assert_array_equal(load(rec / v / "grid.npz")[name], ck[v][name],
                                              err_msg=f"{rec}/{v}: {name}")
    # Real daemons: each pinned to its own session, its status agreeing with the grid
    # rebuilt from its tiles (no false alarm from the watcher's checks), the open bus named.
    said = "\n".join(late.lines)
    assert "disagrees" not in said and "claims this vehicle" not in said, said
    assert "bus not secured" in said, said
    # The late watcher started from a snapshot taken mid-flight, not from the start.
    first = load(next((tmp_path / "late" / "uav1").glob("snapshot-1.npz")))
    assert 0 < int(first["frames"]) < int(ck["uav1"]["frames"]), said
    metrics = json.loads((out / "report" / "fleet" / "metrics.json").read_text())
    for v in ("uav1", "uav2"):
        assert summary["status"][v]["frames"]["used"] > 100
    assert metrics["frames"] == int(ck["uav1"]["frames"]) + int(ck["uav2"]["frames"])
    for f in ("heatmap.png", "thresholds.png", "pd.tif"):
        assert (out / "report" / "fleet" / f).stat().st_size > 1000
    print(f"two-vehicle demo: {summary['wall_s']} s wall")


def processes_mentioning(text: str) -> list[int]:
    """Pids of live processes whose command line contains ``text``."""
    pids = []
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit():
            with contextlib.suppress(OSError):
                cmd = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode()
                state = (proc / "stat").read_text().split(") ")[-1][:1]
                if text in cmd and state != "Z":
                    pids.append(int(proc.name))
    return pids


def previous_demo(out: Path) -> dict[str, bytes]:
    """A folder as earlier demos left it (pdcov's marker, the summary, a checkpoint the
    daemon would resume, an --offline demo's files the live one does not write); returns
    its files."""
    for name, data in {MARKER: b"", "demo.json": b'{"previous": true}\n',
                       "state/uav1/checkpoint.npz": b"an earlier flight",
                       "compare.png": b"an --offline figure",
                       "spiral/metrics.json": b"{}"}.items():
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_bytes(data)
    return tree(out)


def tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def stop_leftovers(out: Path) -> None:
    """SIGKILL what a failed test left of the demo's children (their command lines name
    ``out``, a folder of this test)."""
    for pid in processes_mentioning(str(out)):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)


def test_ctrl_c_stops_every_child_and_keeps_the_previous_folder(tmp_path):
    out = tmp_path / "demo-interrupted"
    before = previous_demo(out)
    demo = Run(demo_args(out), tmp_path)
    try:
        demo.wait_line(r"coverage \d+\.\d%", 120)  # router, simulator, daemon, watcher up
        children = [p for p in processes_mentioning(str(out)) if p != demo.p.pid]
        assert len(children) == 3, children  # watcher, simulator, daemon
        demo.p.send_signal(signal.SIGINT)
        assert demo.wait(60) == 130
        assert processes_mentioning(str(out)) == []
        assert "pdcov demo: interrupted" in demo.lines[-1]
    finally:
        demo.close()
        stop_leftovers(out)
    # The children wrote into a fresh folder, removed with them: the previous one is back
    # as it was, and nothing is left beside it.
    assert tree(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo-interrupted"]


def test_finished_demo_replaces_the_previous_folder_whole(tmp_path):
    out = tmp_path / "demo"
    previous_demo(out)
    demo = Run(demo_args(out), tmp_path)
    try:
        assert demo.wait(300) == 0, "\n".join(demo.lines[-30:])
    finally:
        demo.close()
        stop_leftovers(out)
    assert demo.lines[-1] == f"replaced the previous outputs in {out}"
    files = tree(out)
    assert "compare.png" not in files and "spiral/metrics.json" not in files
    assert "previous" not in json.loads(files["demo.json"])
    ck = read_checkpoint(out / "state" / "uav1" / "checkpoint")
    assert int(ck["frames"]) > 100  # this flight's, not resumed from the earlier one
    assert {"plans/uav1.plan", "configs/uav1.yaml", "logs/serve-uav1.log",
            "report/fleet/metrics.json", MARKER} <= set(files)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo"]


def test_bad_out_is_refused_before_anything_starts(tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("not a folder")
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "notes.txt").write_text("the user's")
    cases = {afile: "is a file", afile / "demo": "afile is a file",
             theirs: "files pdcov did not write"}
    ro = tmp_path / "ro"
    try:
        mount_tmpfs(ro, "ro,size=64k")
        cases[ro / "demo"] = "is not writable"
    except pytest.skip.Exception:
        pass  # no mount rights: the other cases still run
    try:
        for out, why in cases.items():
            done = subprocess.run(demo_args(out), capture_output=True, text=True,
                                  timeout=60, cwd=tmp_path)
            assert done.returncode == 2, (out, done.stdout, done.stderr)
            assert f"argument --out: {out}" in done.stderr and why in done.stderr, done.stderr
            assert "Traceback" not in done.stderr and done.stdout == "", done.stdout
    finally:
        if ro in [p.parent for p in cases]:
            subprocess.run(["umount", str(ro)], timeout=10, check=False)
    assert (theirs / "notes.txt").read_text() == "the user's" and afile.is_file()
    assert sorted(p.name for p in theirs.iterdir()) == ["notes.txt"]


CHILD = """
import signal, sys, time
print("starting", flush=True)
if sys.argv[1] == "fail":
    print("RuntimeError: the link is down", flush=True)
    sys.exit(3)
signal.signal(signal.SIGTERM, signal.SIG_IGN)  # only SIGKILL stops it
time.sleep(60)
"""


def test_a_failed_child_is_named_with_the_end_of_its_log(tmp_path):
    """The failed demo's folder (logs too) is put back to the previous one, so the message
    must carry the log's end."""
    from pdcov.errors import PdcovError
    from pdcov.ground.demo import Children, _check_alive

    children = Children()
    try:
        p = children.start("daemon uav1", [sys.executable, "-c", CHILD, "fail"],
                           tmp_path / "serve-uav1.log")
        p.wait(timeout=30)
        with pytest.raises(PdcovError) as err:
            _check_alive(children)
    finally:
        children.stop_all()
    assert str(err.value) == ("demo: the daemon uav1 stopped (exit 3); its log ends:\n"
                              "    starting\n    RuntimeError: the link is down")


def test_second_ctrl_c_while_stopping_kills_the_children_at_once(tmp_path):
    from pdcov.ground.demo import Children

    def interrupt(_signum, _frame):
        raise KeyboardInterrupt

    children = Children()
    previous = signal.signal(signal.SIGALRM, interrupt)
    p = None
    try:
        p = children.start("simulator uav1", [sys.executable, "-c", CHILD, "stubborn"],
                           tmp_path / "sim-uav1.log")
        end = time.monotonic() + 30
        while b"starting" not in (tmp_path / "sim-uav1.log").read_bytes():
            assert time.monotonic() < end, "the child did not start"
            time.sleep(0.05)
        signal.setitimer(signal.ITIMER_REAL, 0.5)  # the second Ctrl-C, mid-grace period
        t0 = time.monotonic()
        with pytest.raises(KeyboardInterrupt):
            children.stop_all()  # SIGTERM is ignored: would wait 10 s, then SIGKILL
        assert time.monotonic() - t0 < 5 and p.poll() == -signal.SIGKILL
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
        if p is not None and p.poll() is None:
            p.kill()
            p.wait(timeout=10)

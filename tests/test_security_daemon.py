"""`pdcov serve` against a hostile or mistaken participant (issue 23, docs/reliability.md
"Security"): it answers MAVLink only to the autopilot's addresses, rate-limits snapshot
replies per requester, stamps its publications with its own Zenoh source, and resumes a
checkpoint only under the vehicle id that wrote it."""

from __future__ import annotations

import logging
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from link_feed import Hover, pack
from serve_harness import free_port, process, router, serve_args, serve_config, stop

from benchmarks.harness import small_mission
from pdcov.bus.keys import VehicleKeys
from pdcov.bus.session import BusConfig, open_session
from pdcov.core.pose import CameraPose
from pdcov.service.checkpoint import CHECKPOINT_NAME
from pdcov.service.daemon import Daemon
from pdcov.service.settings import load_serve_config

FIXED = {"type": "fixed", "roll_deg": 0, "pitch_deg": -90, "yaw_deg": 0}


def config(tmp: Path, vehicle_id: str, *, state: Path, zenoh_port: int = 7447,
           **service) -> Path:
    """A small fixed-mount mission for ``vehicle_id`` with its state in ``state``."""
    return serve_config(small_mission(vehicle_id=vehicle_id, mount=FIXED),
                        tmp / f"{vehicle_id}.yaml", zenoh_port=zenoh_port, state_dir=state,
                        **service)


# --- 4. a checkpoint resumes only under its own vehicle id -------------------------------------

def test_a_checkpoint_resumes_under_its_vehicle_id_only(tmp_path, caplog) -> None:
    state = tmp_path / "state"
    first = Daemon(load_serve_config(config(tmp_path, "uav1", state=state)))
    for k in range(3):
        first.live.grid.update(CameraPose(np.diag([1.0, -1.0, -1.0]),
                                          np.array([10.0 + 4 * k, 15.0, 12.0]), float(k)))
    first._checkpoint()
    saved = first.live.grid.frames
    assert saved == 3
    again = Daemon(load_serve_config(config(tmp_path, "uav1", state=state)))
    assert again.live.grid.frames == saved and again._checkpoint_info["resumed"]
    # The same mission flown as uav2 with the same state directory (a copied config):
    # uav1's frames must not be counted again under uav2.
    with caplog.at_level(logging.WARNING, logger="pdcov.serve"):
        other = Daemon(load_serve_config(config(tmp_path, "uav2", state=state)))
    assert other.live.grid.frames == 0 and not other.live.grid.n_obs.any()
    info = other._checkpoint_info
    assert not info["resumed"] and info["set_aside"] is not None
    aside = Path(info["set_aside"])
    assert aside.is_file() and not (state / CHECKPOINT_NAME).exists()
    line = caplog.records[-1].getMessage()
    assert "set aside" in line and "vehicle 'uav1'" in line, line
    # The file set aside is uav1's, whole: renamed back it resumes under uav1.
    aside.replace(state / CHECKPOINT_NAME)
    assert Daemon(load_serve_config(config(tmp_path, "uav1", state=state))
                  ).live.grid.frames == saved


# --- 3. every status and tiles put carries the daemon session's source ------------------------

def hover_datagrams(seconds: float = 4.0) -> list[bytes]:
    """A hovering autopilot's messages (system 1, component 1), one datagram each: the daemon
    takes frames from them, so its grid and tiles change."""
    return [pack(m) for m in Hover(seconds=seconds).messages()]


class Sources:
    """A session's subscriber to a vehicle's status and tiles: (key, source zid, sn) of each
    sample (zid and sn None for a sample without source info)."""

    def __init__(self, session, keys: VehicleKeys) -> None:
        self.lock = threading.Lock()
        self.seen: list[tuple[str, str | None, int | None]] = []
        self.subs = [session.declare_subscriber(k, self._on) for k in (keys.status, keys.tiles)]

    def _on(self, sample) -> None:
        info = sample.source_info
        with self.lock:
            self.seen.append((str(sample.key_expr), None, None) if info is None else
                             (str(sample.key_expr), str(info.source_id.zid), info.source_sn))

    def wait(self, key: str, n: int, timeout_s: float = 60.0) -> list:
        """The samples seen once ``n`` of them are on ``key``."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            with self.lock:
                seen = list(self.seen)
            if [k for k, _, _ in seen].count(key) >= n:
                return seen
            time.sleep(0.05)
        raise AssertionError(f"timed out waiting for {n} samples on {key}: {len(seen)} "
                             "samples in all")

    def close(self) -> None:
        for s in self.subs:
            s.undeclare()


@pytest.mark.e2e
@pytest.mark.parametrize("path", ["router", "peer to peer"])
def test_status_and_tiles_carry_the_daemon_session_as_source(tmp_path, path) -> None:
    zport, mport = free_port(), free_port(socket.SOCK_DGRAM)
    cfg_path = config(tmp_path, "uav1", state=tmp_path / "state", zenoh_port=zport)
    doc = yaml.safe_load(cfg_path.read_text())
    if path == "router":
        r = router(zport)
        client = BusConfig(mode="client", connect=(f"tcp/127.0.0.1:{zport}",),
                           multicast_scouting=False)
    else:  # the daemon listens, the ground station connects to it directly
        r = None
        doc["bus"].update(connect=[], listen=[f"tcp/127.0.0.1:{zport}"])
        client = BusConfig(mode="peer", connect=(f"tcp/127.0.0.1:{zport}",),
                           multicast_scouting=False)
    cfg_path.write_text(yaml.safe_dump(doc))
    keys = VehicleKeys("uav1")
    session = open_session(client)
    sources = Sources(session, keys)
    autopilot = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        with process(serve_args(cfg_path, "--connect", f"udpin:127.0.0.1:{mport}"),
                     tmp_path / "serve.log") as daemon:
            sources.wait(keys.status, 3)  # connected: now the frames, hence tiles
            for datagram in hover_datagrams():
                autopilot.sendto(datagram, ("127.0.0.1", mport))
            seen = sources.wait(keys.tiles, 1)
            replies = list(session.get(keys.snapshot, timeout=10.0))
            assert daemon.poll() is None, (tmp_path / "serve.log").read_text()[-2000:]
            assert stop(daemon) == 0
    finally:
        autopilot.close()
        sources.close()
        session.close()
        if r is not None:
            r.close()
    assert all(zid is not None for _, zid, _ in seen), "a put without source info"
    [reply] = [x for x in replies if x.ok is not None]
    daemon_zid = str(reply.replier_id.zid)
    assert {zid for _, zid, _ in seen} == {daemon_zid}
    assert daemon_zid != str(session.zid())
    for key in (keys.status, keys.tiles):  # sn 0, 1, 2, ... per publisher
        sns = [sn for k, _, sn in seen if k == key]
        assert sns == list(range(sns[0], sns[0] + len(sns))), (key, sns)

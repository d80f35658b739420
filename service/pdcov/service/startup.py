"""The daemon's start, before the event loop runs: ``ServiceCore`` with the grid resumed
from the state dir's checkpoint when it belongs to this mission (checkpoint.resume), else a
new one, and the candidates restored from the checkpoint and the journal
(candidate_store.restore); the link's signing key and the recorder the config asks for."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pdcov.errors import ConfigError
from pdcov.service.checkpoint import CHECKPOINT_NAME, resume
from pdcov.service.checkpoint_meta import CheckpointState
from pdcov.service.core import ServiceCore
from pdcov.service.recorder import TlogRecorder
from pdcov.service.settings import ServeConfig, mission_hash
from pdcov.service.state_files import StateFiles

__all__ = ["start_core", "start_recorder", "signing_key"]

log = logging.getLogger("pdcov.serve")


def start_core(cfg: ServeConfig, files: StateFiles, clock: Callable[[], float]) -> ServiceCore:
    """The core with the grid resumed from ``files``' state dir's checkpoint when it belongs
    to this mission, else a new one; ``clock``: the daemon's monotonic clock (s)."""
    m = cfg.mission
    state_dir = files.state_dir
    grid = m.new_mission_grid()
    mhash = mission_hash(m, grid)
    cameras = {c.name: m.new_grid(c) for c in m.cameras} if m.several_cameras else None
    r = resume(state_dir, mhash, grid, cameras)
    (log.warning if r.set_aside else log.info)("%s", r.message)
    state = CheckpointState(path=str(state_dir / CHECKPOINT_NAME),
                            resumed=r.grid is not None,
                            set_aside=str(r.set_aside) if r.set_aside else None)
    core = ServiceCore(cfg, r.grid or grid, clock(), mission_hash=mhash,
                       resumed=r.meta if r.grid is not None else None, checkpoint=state,
                       camera_grids=r.cameras, nonces=files.read_nonces(),
                       epoch=files.read_epoch())
    _restore_candidates(core, files, r.grid is not None, r.candidates, r.candidates_error)
    return core


def _restore_candidates(core: ServiceCore, files: StateFiles, resumed: bool, doc: Any,
                        error: str | None) -> None:
    """The candidates from the checkpoint and the journal (candidate_store.restore);
    the journal then cut to its valid lines, or set aside."""
    journal, unreadable = files.read_journal()
    r = core.restore_candidates(resumed=resumed, checkpoint=doc, checkpoint_error=error,
                                journal=journal, journal_path=str(files.journal))
    for level, text in r.logs:
        log.log(level, "%s", text)
    log.info("candidates restored: %d (%d from the checkpoint, %d updated or added by "
             "%d journal lines)", r.candidates, r.from_checkpoint, r.from_journal, r.lines)
    files.settle_journal(journal, r.keep_bytes, r.set_aside or unreadable)


def start_recorder(cfg: ServeConfig) -> TlogRecorder | None:
    """The recorder of the telemetry in the state dir's recordings/ (service.record)."""
    if not cfg.service.record:
        return None
    return TlogRecorder(Path(cfg.service.state_dir) / "recordings",
                        cfg.service.record_max_bytes, cfg.service.record_keep_bytes)


def signing_key(cfg: ServeConfig) -> bytes | None:
    """The links' MAVLink signing key (link.signing_key or _file), None without one."""
    key = cfg.link.signing_key_bytes(cfg.base_dir)
    if (cfg.link.signing_key or cfg.link.signing_key_file) and key is None:
        raise ConfigError("link.signing_key_file: cannot read 64 hex digits from "
                          f"{cfg.link.signing_key_file}")
    return key

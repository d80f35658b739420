"""Several flight logs into one map: each log evaluated by ``input_run.run_input`` (the one
flight engine), in this process, in worker processes (all cores) or on a Dask cluster, and
the grids merged with ``CoverageGrid.merge`` in log order, not completion order: the map is
the same however the logs ran, and equals evaluating them one by one and merging.

The logs must share one ENU frame: the mission's origin. Without a configured ground
altitude each log's origin takes its own home's, and logs whose origins differ are refused
(their ENU heights are above different grounds). A worker sends its grids back as snapshot
bytes (``input_run.PackedGrids``).
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Generator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from contextlib import closing
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TypeAlias, cast

from pdcov.commands.input_run import InputGrids, InputJob, InputRun, run_input, run_input_packed
from pdcov.config.mission import Mission
from pdcov.errors import ConfigError, InputFileError, PdcovError
from pdcov.extras import CLUSTER

Done: TypeAlias = Generator[tuple[int, InputRun], None, None]  # (log index, run), as done

# What --log DIR takes from a folder: the flight log formats pdcov reads (any case: an
# ArduPilot SD card names them 00000012.BIN).
LOG_SUFFIXES = (".tlog", ".bin", ".ulg")


def log_paths(given: Sequence[Path]) -> list[Path]:
    """The logs of ``--log`` values in order: a file as given, a folder as its flight logs
    (LOG_SUFFIXES) sorted by name. InputFileError naming the folder when it holds none, or
    naming the log given twice (the same file, whatever its spelling)."""
    paths: list[Path] = []
    for p in given:
        if p.is_dir():
            found = sorted((f for f in p.iterdir()
                            if f.suffix.lower() in LOG_SUFFIXES and f.is_file()),
                           key=lambda f: f.name)
            if not found:
                raise InputFileError(f"{p}: no flight log in this folder (expected "
                                     f"{', '.join(LOG_SUFFIXES)} files)")
            paths += found
        else:
            paths.append(p)
    seen: dict[Path, Path] = {}
    for p in paths:
        key = p.resolve()
        if key in seen:
            same = "" if seen[key] == p else f" (as {seen[key]})"
            raise InputFileError(f"{p}: given twice{same}: each log counts once in the map")
        seen[key] = p
    return paths


@dataclass(frozen=True, slots=True, eq=False)
class MergedLogs:
    """Logs evaluated and merged: ``grids`` the merged grids (in log order), ``runs`` each
    log's run in log order without its grids (``InputRun.grids`` None) and, after the
    first, without the prior (the first's holds it)."""

    grids: InputGrids
    runs: tuple[InputRun, ...]


def evaluate_logs(mission: Mission, jobs: Sequence[InputJob], *, workers: int,
                  dask_address: str | None = None, progress: bool = False) -> MergedLogs:
    """Evaluate ``jobs`` (one per log, in log order) under ``mission`` with ``workers``
    processes (1: in this process) or on the Dask scheduler at ``dask_address``, and merge
    them in log order (module docstring); a bar over the logs with ``progress``. Raises the
    first failing log's PdcovError, naming it, before any output is written."""
    from pdcov.planning.progress import progress as bar

    if not jobs:
        raise ValueError("no log to evaluate")
    if dask_address is not None:
        done = _on_dask(mission, jobs, dask_address)
    elif workers > 1 and len(jobs) > 1:
        done = _in_processes(mission, jobs, min(workers, len(jobs)))
    else:
        done = _here(mission, jobs)
    pending: dict[int, InputRun] = {}
    runs: list[InputRun] = []
    merged: InputGrids | None = None
    with closing(done):  # a failure cancels the logs still running
        for i, run in bar(done, desc="logs", unit="log", total=len(jobs), enabled=progress):
            pending[i] = run
            while len(runs) in pending:  # the next log in order is done: merge it
                run = pending.pop(len(runs)).unpacked(mission)
                if runs and run.origin != runs[0].origin:
                    raise _origins_differ(runs[0], run, mission)
                merged = run.loaded if merged is None else _merged(merged, run.loaded)
                # The prior is the same about the one origin: the first log's serves all.
                runs.append(replace(run, grids=None, prior=None if runs else run.prior))
    return MergedLogs(cast(InputGrids, merged), tuple(runs))


def _merged(into: InputGrids, other: InputGrids) -> InputGrids:
    """``other`` merged into ``into`` (CoverageGrid.merge of the mission grid and of each
    camera's)."""
    into.grid.merge(other.grid)
    for name, g in into.cameras.items():
        g.merge(other.cameras[name])
    return into


def _origins_differ(first: InputRun, run: InputRun, mission: Mission) -> ConfigError:
    a, b = first.origin, run.origin
    return ConfigError(
        f"{first.path} and {run.path} have different ENU origins (ground "
        f"{a.ground_alt_msl_m:.2f} and {b.ground_alt_msl_m:.2f} m MSL, each from its own "
        "home): their maps do not line up; set origin.ground_alt_msl_m in "
        f"{mission.source} to evaluate them in one frame")


def _named(exc: PdcovError, path: Path) -> PdcovError:
    """``exc`` with ``path`` in its message (a failing log among several is named)."""
    if str(path) in str(exc):
        return exc
    return type(exc)(f"{path}: {exc}")


def _here(mission: Mission, jobs: Sequence[InputJob]) -> Done:
    """(log index, run) evaluated one after the other in this process."""
    for i, job in enumerate(jobs):
        try:
            yield i, run_input(job, mission)
        except PdcovError as exc:
            raise _named(exc, job.path) from None


def _in_processes(mission: Mission, jobs: Sequence[InputJob], workers: int) -> Done:
    """(log index, run) as the worker processes finish them; the rest cancelled on the
    first failure. Each worker receives ``mission`` once (``_hold_mission``)."""
    # forkserver: a worker never inherits this process's threads (tqdm's, a BLAS pool);
    # the server imports the evaluation (input_run and the engine it imports) once, and each
    # worker forks from it ready to run.
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload([run_input_packed.__module__])
    cv_threads = max(1, (os.cpu_count() or 1) // workers)
    with ProcessPoolExecutor(workers, mp_context=context, initializer=_hold_mission,
                             initargs=(mission, cv_threads)) as pool:
        futures = {pool.submit(_run_held, job): i for i, job in enumerate(jobs)}
        try:
            for f in as_completed(futures):
                i = futures[f]
                try:
                    yield i, f.result()
                except PdcovError as exc:
                    raise _named(exc, jobs[i].path) from None
                except BrokenProcessPool:
                    raise PdcovError(f"{jobs[i].path}: the worker process evaluating it "
                                     "died (out of memory?); try fewer --jobs") from None
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


# The mission of this worker process (``_in_processes``): sent once by the pool's
# initializer rather than with each log.
_worker_mission: list[Mission] = []


def _hold_mission(mission: Mission, cv_threads: int) -> None:
    """The pool's initializer: keep ``mission`` for this worker's logs, and give OpenCV
    ``cv_threads`` threads (its share of the cores: more would only contend with the other
    workers)."""
    import cv2

    cv2.setNumThreads(cv_threads)
    _worker_mission[:] = [mission]


def _run_held(job: InputJob) -> InputRun:
    """``run_input_packed`` of ``job`` under this worker's mission."""
    return run_input_packed(job, _worker_mission[0])


def _on_dask(mission: Mission, jobs: Sequence[InputJob], address: str) -> Done:
    """(log index, run) as the Dask workers at ``address`` finish them (the logs' paths
    must be readable there: a shared file system); the rest cancelled on the first
    failure."""
    CLUSTER.require()
    from distributed import Client
    from distributed import as_completed as dask_completed

    try:
        client = Client(address, timeout="10s")
    except (OSError, TimeoutError) as exc:
        raise PdcovError(f"--dask {address}: cannot reach the Dask scheduler ({exc})"
                         ) from None
    with client:
        held = client.scatter(mission, broadcast=True, hash=False)  # once to each worker
        futures = [client.submit(run_input_packed, job, held, pure=False) for job in jobs]
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            for f in dask_completed(futures):
                i = index[f.key]
                try:
                    yield i, f.result()
                except PdcovError as exc:
                    raise _named(exc, jobs[i].path) from None
        finally:
            client.cancel(futures)

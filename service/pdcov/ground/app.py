"""``pdcov watch`` put together: the Zenoh shell, the terminal view, the web map, the
recording with its exports and the Cursor-on-Target feed, run until Ctrl-C / SIGTERM (or,
with ``once``, until one report is printed)."""

from __future__ import annotations

import asyncio
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from pdcov.bus.grid_state import grid_hash
from pdcov.bus.session import BusConfig, bus_security
from pdcov.config import DEFAULT_THRESHOLDS, Mission
from pdcov.errors import ConfigError
from pdcov.ground.cot import CotSchedule
from pdcov.ground.cot_feed import CotFeed
from pdcov.ground.fleet_report import FleetReport
from pdcov.ground.live import WatchShell
from pdcov.ground.record import Recording
from pdcov.ground.record_exports import ExportRecorder
from pdcov.ground.terminal import headline, plain_lines, render
from pdcov.ground.watcher import Watcher
from pdcov.ground.web_auth import WebAccess


@dataclass(frozen=True, slots=True)
class WatchOptions:
    """vehicle: one id or None (all). web: (host, port) or None; web_access: who may read
    the web map (ground/web_auth.py; required with web). once: print one report
    when every vehicle seen has its grid (or after wait_s) and exit. plain: one headline
    line per change instead of the live table (set when stdout is not a terminal). record:
    the recording folder (its exports in record/exports/ every exports_period_s). cot: the
    Cursor-on-Target destination URL (ground/cot_feed.py), or None."""

    bus: BusConfig
    vehicle: str | None = None
    mission: Mission | None = None
    web: tuple[str, int] | None = None
    web_access: WebAccess | None = None
    basemap: Path | None = None
    record: Path | None = None
    once: bool = False
    wait_s: float = 10.0
    plain: bool = False
    refresh_s: float = 0.5
    cot: str | None = None
    exports_period_s: float = 5.0

    def __post_init__(self) -> None:
        if (self.web is None) != (self.web_access is None):
            raise ValueError("WatchOptions: web and web_access go together")


def run_watch(opts: WatchOptions) -> int:
    """Run until interrupted; returns the exit status."""
    return asyncio.run(_main(opts))


async def _main(opts: WatchOptions) -> int:
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    config_hash = None
    if opts.mission is not None:
        grid = opts.mission.new_grid()
        config_hash = grid_hash(grid.geometry, grid.mask)
    watcher = Watcher(opts.vehicle, thresholds=(
        opts.mission.thresholds if opts.mission else DEFAULT_THRESHOLDS),
        grid_hash=config_hash, bus_warning=bus_security(opts.bus).warning)
    recording = Recording(opts.record) if opts.record else None
    exports = ExportRecorder(opts.record / "exports", period_s=opts.exports_period_s) \
        if opts.record else None
    cot = CotFeed(opts.cot, CotSchedule(), lambda: list(watcher.feeds.values())) \
        if opts.cot else None
    shell = WatchShell(watcher, opts.bus, record=recording)

    def report() -> FleetReport:
        """The watcher's report as of now, with the recording's, the exports' and the CoT
        feed's trouble, if any."""
        r = watcher.report(shell.now_s())
        trouble = tuple(w for w in (recording and recording.warning,
                                    exports and exports.warning, cot and cot.warning) if w)
        return replace(r, station=(*r.station, *trouble)) if trouble else r

    web = None
    if opts.web is not None and opts.web_access is not None:  # both or neither
        from pdcov.ground.web import WebMap, basemap_info, map_state

        basemap = basemap_info(opts.basemap)
        web = WebMap(opts.web[0], opts.web[1],
                     lambda: map_state(watcher, report(), opts.mission, shell.version,
                                       basemap, config_hash),
                     lambda: shell.version, opts.web_access, opts.basemap)
        await web.start()
        # Printed once, and only here: the token is the key to the map.
        print(f"pdcov watch: web map at {web.url}", flush=True)
    runner = asyncio.create_task(shell.run(stop))
    helpers = []
    if cot is not None:
        helpers.append(asyncio.create_task(cot.run(stop)))
    if exports is not None:
        helpers.append(asyncio.create_task(_export_loop(exports, watcher, shell, stop)))
    status = 0
    try:
        connected = asyncio.create_task(shell.connected.wait())
        await asyncio.wait({runner, connected}, return_when=asyncio.FIRST_COMPLETED)
        connected.cancel()
        if runner.done():
            runner.result()  # the session's error (ConfigError: cannot open ...)
        if opts.plain and not opts.once:
            print(f"pdcov watch: following pdcov/{opts.vehicle or '*'}/ "
                  f"({opts.bus.mode}, connect {list(opts.bus.connect)})", flush=True)
        if opts.once:
            status = await _once(watcher, report, opts, stop, runner)
        else:
            await _view(report, opts, stop, runner)
    finally:
        stop.set()
        try:
            await runner
        finally:
            await asyncio.gather(*helpers, return_exceptions=True)
            if web is not None:
                await web.stop()
            if recording is not None:
                recording.close()
                for line in recording.finish(watcher, opts.mission):
                    print(line, flush=True)
            if exports is not None:
                print(_exports_line(exports, exports.write(watcher)), flush=True)
    return status


async def _export_loop(exports: ExportRecorder, watcher: Watcher, shell: WatchShell,
                       stop: asyncio.Event) -> None:
    """Rewrite the exports while the watcher runs (ExportRecorder.poll decides when)."""
    while not stop.is_set():
        exports.poll(watcher, shell.version, shell.now_s())
        try:
            await asyncio.wait_for(stop.wait(), 1.0)
        except asyncio.TimeoutError:
            pass


def _exports_line(exports: ExportRecorder, ok: bool) -> str:
    if not ok or exports.last is None:
        return f"record: could not write the exports in {exports.out}: {exports.last_error}"
    line = f"record: wrote {', '.join(exports.last.files)} in {exports.out}"
    return "\n".join([line, *(f"record: not written: {n}" for n in exports.last.not_written)])


async def _once(watcher: Watcher, report_now: Callable[[], FleetReport], opts: WatchOptions,
                stop: asyncio.Event, runner: asyncio.Task[None]) -> int:
    deadline = time.monotonic() + opts.wait_s
    while time.monotonic() < deadline and not stop.is_set() and not runner.done():
        feeds = list(watcher.feeds.values())
        if feeds and all(f.state is not None and f.awaiting_since_s is None
                         and f.status is not None for f in feeds):
            break
        await asyncio.sleep(0.1)
    if runner.done():
        runner.result()  # raises the session's error
    report = report_now()
    print("\n".join(plain_lines(report)), flush=True)
    return 0 if report.vehicles else 1


async def _view(report_now: Callable[[], FleetReport], opts: WatchOptions,
                stop: asyncio.Event, runner: asyncio.Task[None]) -> None:
    live: Any = None
    if not opts.plain:
        from rich.console import Console
        from rich.live import Live

        live = Live(render(report_now()), console=Console(),
                    auto_refresh=False, transient=False)
        live.start()
    last_lines: tuple[str, ...] = ()
    try:
        while not stop.is_set() and not runner.done():
            report = report_now()
            if live is not None:
                live.update(render(report), refresh=True)
            else:
                lines = (headline(report), *(f"! {w}" for w in report.warnings))
                for line in lines:
                    if line not in last_lines:
                        print(f"pdcov watch: {line}", flush=True)
                last_lines = lines
            try:
                await asyncio.wait_for(stop.wait(), opts.refresh_s)
            except asyncio.TimeoutError:
                pass
        if runner.done():
            runner.result()
    finally:
        if live is not None:
            live.stop()


def parse_web_address(text: str) -> tuple[str, int]:
    """``--web HOST:PORT`` (PORT 0 picks a free one) -> (host, port); ConfigError naming
    the option otherwise."""
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ConfigError(f"--web {text!r}: expected HOST:PORT such as 127.0.0.1:8080")
    return host.strip("[]"), int(port)


def stdout_is_terminal() -> bool:
    return sys.stdout.isatty()

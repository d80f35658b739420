"""``pdcov watch`` put together: the Zenoh shell, the terminal view, the web map, the
recording with its exports, the Cursor-on-Target feed and re-tasking (``ReflyDesk``),
run until Ctrl-C / SIGTERM (or, with ``once``, until one report is printed; with ``refly``,
until the re-fly is sent or declined)."""

from __future__ import annotations

import asyncio
import errno
import secrets
import signal
import socket
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pdcov.bus.grid_state import grid_hash
from pdcov.bus.operator_keys import OperatorKey
from pdcov.bus.session import (
    BusConfig,
    bus_security,
    describe_session,
    peer_warning,
    quiet_hint,
)
from pdcov.config.mission import DEFAULT_THRESHOLDS, Mission
from pdcov.errors import ConfigError
from pdcov.ground.basemap import Basemap
from pdcov.ground.cot import CotSchedule
from pdcov.ground.cot_feed import CotFeed
from pdcov.ground.cot_tls import CotTls
from pdcov.ground.fleet_report import FleetReport
from pdcov.ground.live import WatchShell
from pdcov.ground.record import Recording
from pdcov.ground.record_exports import ExportRecorder, findings_of
from pdcov.ground.retask import (
    ReflyError,
    ReflyProposal,
    propose_refly,
    refly_inputs,
    reply_line,
    signed_request,
)
from pdcov.ground.roster import Roster, roster_of
from pdcov.ground.terminal import headline, plain_lines, render
from pdcov.ground.watcher import Watcher
from pdcov.ground.web_auth import NO_OPERATOR, WebAccess
from pdcov.planning.refly import ReflySettings
from pdcov.planning.scenario import scenario_of

QUIET_AFTER_S = 5.0
"""A session connected this long without hearing a vehicle says why that may be (a
daemon's liveliness token and status reach a watcher within about a second)."""

if TYPE_CHECKING:
    from pdcov.ground.web import PlanLayer


@dataclass(frozen=True, slots=True)
class WatchOptions:
    """vehicle: one id or None (all). web: (host, port) or None; web_access: who may read
    the web map (ground/web_auth.py; required with web). once: print one report
    when every vehicle seen has its grid (or after wait_s) and exit. plain: one headline
    line per change instead of the live table (set when stdout is not a terminal).
    basemap: the tiles under the web map (closed when the watcher ends); plans: the plans
    it draws. record: the recording folder (its exports in record/exports/ every
    exports_period_s). cot: the Cursor-on-Target destination URL (ground/cot_feed.py), or
    None; cot_tls: its checked TLS identity for tls:// (ground/cot_tls.py). operator_key:
    signs re-flies (none: they are not sent)."""

    bus: BusConfig
    vehicle: str | None = None
    mission: Mission | None = None
    web: tuple[str, int] | None = None
    web_access: WebAccess | None = None
    basemap: Basemap | None = None
    plans: tuple[PlanLayer, ...] = ()
    record: Path | None = None
    once: bool = False
    wait_s: float = 10.0
    plain: bool = False
    refresh_s: float = 0.5
    cot: str | None = None
    cot_tls: CotTls | None = None
    exports_period_s: float = 5.0
    refly: str | None = None
    refly_settings: ReflySettings | None = None
    yes: bool = False
    operator_key: OperatorKey | None = None
    memory_limit: tuple[int, str] | None = None  # bytes this process may hold, and whence

    def __post_init__(self) -> None:
        if (self.web is None) != (self.web_access is None):
            raise ValueError("WatchOptions: web and web_access go together")
        if self.refly is not None and self.mission is None:
            raise ConfigError("--refly needs --config: the mission flown (its camera, "
                              "detector and domain plan the re-fly)")


class ReflyDesk:
    """Re-tasking for the operator (terminal or web map): ``propose`` computes a re-fly
    of the merged grid's gaps (off the event loop) and holds it as ``current`` for the map;
    ``confirm`` sends the held proposal to its vehicle and returns the daemon's verdict."""

    def __init__(self, watcher: Watcher, shell: WatchShell, mission: Mission,
                 config_hash: str, settings: ReflySettings,
                 operator_key: OperatorKey | None = None) -> None:
        self.watcher, self.shell, self.mission = watcher, shell, mission
        self.operator_key = operator_key
        self.config_hash = config_hash
        self.settings = settings
        self.scenario = scenario_of(mission)
        self.current: ReflyProposal | None = None
        self.outcome: str | None = None

    async def propose(self, vehicle_id: str, target_pd: float | None = None
                      ) -> ReflyProposal:
        """ReflyError or ConfigError (no gaps, bad target) say why none can be made."""
        settings = self.settings if target_pd is None else replace(self.settings,
                                                                   target_pd=target_pd)
        inputs = refly_inputs(self.watcher, self.mission, self.config_hash, vehicle_id)
        proposal = await asyncio.get_running_loop().run_in_executor(
            None, propose_refly, inputs, self.scenario, settings)
        self.current, self.outcome = proposal, None
        return proposal

    async def confirm(self, proposal_id: str) -> tuple[bool, str]:
        """Sign and send the held proposal ``proposal_id``: (accepted by the autopilot, the
        line); RetaskNotSent without an operator key or out of bounds."""
        p = self.current
        if p is None or p.id != proposal_id:
            raise ReflyError(f"re-fly {proposal_id}: not the proposal shown (ask again)")
        payload = signed_request(self.operator_key, p.vehicle_id, p.items, p.description,
                                 self.mission, p.home, time.time(), secrets.token_hex(16))
        reply = await self.shell.retask(p.vehicle_id, payload)
        self.outcome = reply_line(p, reply)
        return reply is not None and reply.accepted, self.outcome


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
        grid = opts.mission.new_mission_grid()
        config_hash = grid_hash(grid.geometry, grid.free)
    exports = ExportRecorder(opts.record / "exports", period_s=opts.exports_period_s) \
        if opts.record else None
    watcher = Watcher(opts.vehicle, thresholds=(
        opts.mission.thresholds if opts.mission else DEFAULT_THRESHOLDS),
        grid_hash=config_hash, bus_warning=bus_security(opts.bus).warning,
        quiet_hint=quiet_hint(opts.bus),
        quiet_after_s=min(QUIET_AFTER_S, opts.wait_s) if opts.once else QUIET_AFTER_S,
        roster=roster_of(opts.mission.raw, opts.mission.source) if opts.mission else Roster(),
        detection_log=exports.detection_log if exports else None,
        memory_limit=opts.memory_limit)
    if opts.once or not opts.plain:  # else the "following ..." line below names it
        print(f"pdcov watch: zenoh session {describe_session(opts.bus)}", file=sys.stderr,
              flush=True)
    warning = peer_warning(opts.bus)
    if warning is not None:
        print(f"pdcov watch: WARNING: {warning}", file=sys.stderr, flush=True)
    recording = Recording(opts.record) if opts.record else None
    cot = CotFeed(opts.cot, CotSchedule(), lambda: list(watcher.feeds.values()),
                  tls=opts.cot_tls) if opts.cot else None
    shell = WatchShell(watcher, opts.bus, record=recording,
                       connect_timeout_s=opts.wait_s if opts.once else None)
    desk = None
    if opts.mission is not None and config_hash is not None:
        desk = ReflyDesk(watcher, shell, opts.mission, config_hash, opts.refly_settings
                         or ReflySettings(max(opts.mission.thresholds)), opts.operator_key)

    def report() -> FleetReport:
        """The watcher's report as of now, with the recording's, the exports' and the CoT
        feed's trouble, if any."""
        r = watcher.report(shell.now_s())
        trouble = tuple(w for w in (recording and recording.warning,
                                    exports and exports.warning, cot and cot.warning) if w)
        return replace(r, station=(*r.station, *trouble)) if trouble else r

    web = None
    if opts.web is not None and opts.web_access is not None:  # both or neither
        from pdcov.ground.web import WebMap, map_state

        basemap = None if opts.basemap is None else opts.basemap.info.as_json()
        web = WebMap(opts.web[0], opts.web[1],
                     lambda: map_state(watcher, report(), opts.mission, shell.version,
                                       basemap, config_hash, opts.plans,
                                       desk.current if desk else None,
                                       desk.outcome if desk else None),
                     lambda: shell.version, opts.web_access, opts.basemap, desk=desk)
        try:
            await web.start()
        except OSError as exc:
            raise ConfigError(web_bind_refusal(opts.web, exc)) from None
        # Printed once, and only here: the token is the key to the map.
        print(f"pdcov watch: web map at {web.url}", flush=True)
        print("pdcov watch: " + ("operators: the same address with ?token= the operator "
                                 "token (--web-operator-token-file); the view token may "
                                 "not command" if opts.web_access.operator_token
                                 else NO_OPERATOR), file=sys.stderr, flush=True)
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
                  f"({describe_session(opts.bus)})", flush=True)
        if opts.refly is not None and desk is not None:
            status = await _refly(desk, opts.refly, watcher, opts, stop, runner)
        elif opts.once:
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
            if opts.basemap is not None:
                opts.basemap.close()
            if recording is not None:
                recording.close()
                findings = None if exports is None else findings_of(
                    watcher, exports.detection_log)
                for line in recording.finish(watcher, opts.mission, findings):
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


async def _grids_in(watcher: Watcher, opts: WatchOptions, stop: asyncio.Event,
                    runner: asyncio.Task[None]) -> None:
    """Return once every vehicle seen has its grid, a status and the answer (or none) to
    the candidates query its grid asked for (or after wait_s)."""
    deadline = time.monotonic() + opts.wait_s
    while time.monotonic() < deadline and not stop.is_set() and not runner.done():
        feeds = list(watcher.feeds.values())
        if feeds and all(f.state is not None and f.awaiting_since_s is None
                         and f.status is not None and f.candidates_done_at == f.snapshots
                         for f in feeds):
            break
        await asyncio.sleep(0.1)
    if runner.done():
        runner.result()  # raises the session's error


async def _refly(desk: ReflyDesk, vehicle_id: str, watcher: Watcher, opts: WatchOptions,
                 stop: asyncio.Event, runner: asyncio.Task[None]) -> int:
    """``--refly``: propose, show, ask (unless ``yes``), send; 0 once the autopilot
    accepted it, 1 otherwise (declined, refused, no answer)."""
    await _grids_in(watcher, opts, stop, runner)
    proposal = await desk.propose(vehicle_id)
    for line in proposal.lines():
        print(line, flush=True)
    if not opts.yes:
        answer = await asyncio.get_running_loop().run_in_executor(
            None, input, f"send this mission to {vehicle_id}'s autopilot? [y/N] ")
        if answer.strip().lower() not in ("y", "yes"):
            print("re-fly not sent", flush=True)
            return 1
    print(f"sending mission {proposal.id} to {vehicle_id} (session "
          f"{desk.shell.session_id}) ...", flush=True)
    accepted, line = await desk.confirm(proposal.id)
    print(line, flush=True)
    return 0 if accepted else 1


async def _once(watcher: Watcher, report_now: Callable[[], FleetReport], opts: WatchOptions,
                stop: asyncio.Event, runner: asyncio.Task[None]) -> int:
    await _grids_in(watcher, opts, stop, runner)
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


def web_bind_refusal(address: tuple[str, int], exc: OSError) -> str:
    """Why the web map cannot listen at ``address`` (its bind's error) and what to do."""
    host, port = address
    shown = f"--web {f'[{host}]' if ':' in host else host}:{port}"
    if exc.errno == errno.EADDRINUSE:
        return (f"{shown}: the address is in use (another pdcov watch, or the program "
                f"`ss -ltnp 'sport = :{port}'` names, holds it): give another port, or "
                f"{host}:0 for a free one")
    if exc.errno == errno.EACCES:
        return (f"{shown}: this user may not listen on port {port} (below 1024 needs "
                "privileges): give a port from 1024 up, e.g. 8080")
    if exc.errno == errno.EADDRNOTAVAIL or isinstance(exc, socket.gaierror):
        what = "is not a name this machine resolves" if isinstance(exc, socket.gaierror) \
            else "is not an address of this machine"
        return (f"{shown}: {host} {what}: give one of its addresses, 127.0.0.1 (this "
                "machine only) or 0.0.0.0 (every interface)")
    return f"{shown}: cannot listen there ({exc.strerror or exc})"


def stdout_is_terminal() -> bool:
    return sys.stdout.isatty()

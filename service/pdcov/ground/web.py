"""The live web map (``pdcov watch --web HOST:PORT``): an aiohttp server that serves the page
and its script from the installed package (ground/web/, no CDN) and pushes the map's state
as server-sent events (``/events``; ``/state.json`` for one copy). Every path needs the
access token (ground/web_auth.py); every answer carries headers that keep the page from
being framed, sniffed or cached and its address from leaking as a Referer.

aiohttp earns its place: HTTP/1.1 parsing, streaming responses and clean shutdown are its
job, and a hand-written server on a ground-station laptop would be one more thing to get
wrong. The state holds what the page draws, in WGS84 latitude/longitude as Leaflet
(vendored in ground/web/vendor/leaflet) wants it: the fleet's P_D grid (quantised, down-sampled
to at most fleet_merge.MAX_SIDE cells a side by taking each block's maximum, kept up to date
block by block as the fleet's tiles merge: ground/fleet_merge.py; resampled onto web
Mercator: ground/map_layers.py) with the outline of its cells at the target P_D, the domain and
obstacles of the grid shown (``domain_layer``: from the mission config when it describes that
grid, else from the vehicles' mission replies), the plans given with ``--plan``, each
vehicle's track and current footprint, and the figures of the terminal view; per vehicle
``candidates`` when the watcher has them; the re-fly proposed (``refly``: waypoints and gap
rings as [lat, lon]; ``gaps``: its gap rings) with the outcome of the last one sent
(docs/ground-station.md "Web map").

Re-tasking (ground/retask.py, docs/ground-station.md "Re-tasking"): ``POST /api/refly``
{vehicle, target_pd} proposes a re-fly of the merged grid's gaps (answered with the
proposal: id, waypoints, gaps, lines), ``POST /api/refly/confirm`` {id} sends it and
answers with the daemon's verdict (ground/web_api.py). Every POST is a command: it needs
the operator token (web_auth.WebAccess.may_command: 403 to the view token), a JSON body and,
when the browser sends one, an Origin of this host (web_auth.post_allowed: CSRF).
``GET /api/whoami`` tells the page what its token may do.
"""

from __future__ import annotations

import asyncio
import base64
import json
import logging
import socket
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pdcov.config.mission import Mission
from pdcov.core.geodesy import Origin
from pdcov.core.mission import MAV_CMD_NAV_WAYPOINT
from pdcov.errors import InputFileError
from pdcov.ground.basemap import Basemap, TileRefused, read_tile
from pdcov.ground.feed import VehicleFeed
from pdcov.ground.fleet_report import FleetReport
from pdcov.ground.map_layers import (
    MAX_OUTLINE_SEGMENTS,
    NOT_FREE,
    PD_LEVELS,
    mercator_raster,
    outline_segments_xy,
    rings_lat_lon,
    segments_lat_lon,
)
from pdcov.ground.retask import ReflyProposal
from pdcov.ground.watcher import Watcher
from pdcov.ground.web_api import ReflyEndpoints, answer, state_json
from pdcov.ground.web_auth import Granted, WebAccess, post_allowed
from pdcov.planning.plan_files import read_mission

if TYPE_CHECKING:  # the desk is handed in (ground/app.py)
    from pdcov.ground.app import ReflyDesk

log = logging.getLogger("pdcov.watch")
LEAFLET = "vendor/leaflet/"
ASSETS = {"/": ("index.html", "text/html"), "/app.js": ("app.js", "text/javascript"),
          "/style.css": ("style.css", "text/css"),
          f"/{LEAFLET}leaflet.js": (f"{LEAFLET}leaflet.js", "text/javascript"),
          f"/{LEAFLET}leaflet.css": (f"{LEAFLET}leaflet.css", "text/css"),
          **{f"/{LEAFLET}images/{n}.png": (f"{LEAFLET}images/{n}.png", "image/png")
             for n in ("layers", "layers-2x", "marker-icon", "marker-icon-2x",
                       "marker-shadow")}}
# blob: images: the page turns the state's heat map into an image it made itself
# (app.js heatImage); nothing else than this server's own paths.
SECURITY_HEADERS = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self' blob:; "
                               "frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff", "X-Frame-Options": "DENY",
    "Referrer-Policy": "no-referrer", "Cache-Control": "no-store"}
COLORS = ("#e6194b", "#4363d8", "#f58231", "#911eb4", "#42d4f4", "#f032e6", "#3cb44b",
          "#9a6324")


def asset(name: str) -> bytes:
    """An asset of the page, read from the installed package."""
    return (resources.files("pdcov.ground") / "web" / name).read_bytes()


def _lat_lon(points: Any) -> list[list[float]]:
    """[lat, lon] pairs (degrees, 1e-8: a millimetre) of (lat, lon, ...) tuples."""
    return [[round(float(p[0]), 8), round(float(p[1]), 8)] for p in points]


def _ring_xy(ring: Any) -> list[list[float]]:
    return [[round(float(x), 2), round(float(y), 2)] for x, y in list(ring)]


def blocks_payload(blocks: np.ndarray, stride: int, geometry: Any, origin: Origin,
                   target: float | None) -> dict[str, Any]:
    """The heat map: P_D quantised to 0..PD_LEVELS per block of ``stride`` x ``stride`` cells
    (``blocks``: each block's maximum, -1 where none is free: fleet_merge.block_max_pd),
    NOT_FREE outside free space, resampled onto web Mercator (map_layers.mercator_raster:
    rows from the north, OFF_GRID outside the grid, ``bounds_lat_lon`` [[south, west],
    [north, east]]); ``stride`` cells per shown cell. ``outline_lat_lon``: segments
    [[lat, lon], [lat, lon]] around the shown cells at or above ``target`` (None with
    ``outline_note`` when there is no target or more than MAX_OUTLINE_SEGMENTS). Its cost
    follows the blocks (at most fleet_merge.MAX_SIDE a side), not the grid."""
    q = np.where(blocks < 0, NOT_FREE, np.rint(np.maximum(blocks, 0) * PD_LEVELS)) \
        .astype(np.uint8)
    cell_m = geometry.cell_size_m * stride
    bounds, raster = mercator_raster(q, geometry.x0_m, geometry.y0_m, cell_m, origin)
    outline, note = None, None
    if target is None:
        note = "no target P_D: no outline"
    else:
        segments = outline_segments_xy(blocks >= target, geometry.x0_m, geometry.y0_m,
                                       cell_m)
        if len(segments) > MAX_OUTLINE_SEGMENTS:
            note = (f"the outline at P_D >= {target} has {len(segments)} edges (more than "
                    f"{MAX_OUTLINE_SEGMENTS}): not drawn")
        else:
            outline = segments_lat_lon(segments, origin)
    return {"cell_size_m": cell_m, "stride": stride, "w": raster.shape[1],
            "h": raster.shape[0], "bounds_lat_lon": bounds, "pd_levels": PD_LEVELS,
            "pd_b64": base64.b64encode(raster.tobytes()).decode(),
            "outline_threshold": target, "outline_lat_lon": outline, "outline_note": note}


CANDIDATE_FIELDS = ("id", "uid", "class", "lat_deg", "lon_deg", "sigma_m", "p_person",
                    "hits", "looks", "pd", "pfa", "confidence", "first_t_boot_s",
                    "last_t_boot_s", "first_time_utc", "last_time_utc")
"""What the map shows of each candidate (the names of the detections payload)."""


def candidates_layer(feed: VehicleFeed) -> list[dict[str, Any]]:
    """The vehicle's detection candidates (pins) for the map (CANDIDATE_FIELDS), the most
    probable first (ties: by uid)."""
    return [{k: c.get(k) for k in CANDIDATE_FIELDS}
            for c in sorted(feed.candidates.values(), key=lambda c: (-c["p_person"], c["uid"]))]


def domain_layer(watcher: Watcher, grid_hash: str | None, mission: Mission | None,
                 config_grid_hash: str | None) -> tuple[dict[str, Any] | None, str | None]:
    """The domain and obstacles to draw over grid ``grid_hash`` (None: no grid yet), and a
    note for the operator. The mission config (``--config``, whose grid hash is
    ``config_grid_hash``) is drawn when it describes that grid (or no grid is shown yet);
    otherwise the mission reply of a vehicle flying that grid. A config describing another
    grid is never drawn over it: the note says so."""
    if mission is not None and (grid_hash is None or config_grid_hash == grid_hash):
        d = mission.domain
        boundary = _ring_xy(d.boundary.exterior.coords)
        obstacles = [_ring_xy(p.exterior.coords) for p in d.obstacles]
        (boundary_ll, *obstacles_ll) = rings_lat_lon([boundary, *obstacles],
                                                     mission.origin())
        return ({"source": "--config", "grid_hash": config_grid_hash,
                 "boundary": boundary, "obstacles": obstacles,
                 "boundary_lat_lon": boundary_ll, "obstacles_lat_lon": obstacles_ll}, None)
    note = None
    if mission is not None:
        note = (f"--config {mission.source or ''} describes grid {config_grid_hash}, the "
                f"vehicles fly grid {grid_hash}: it is not drawn")
    m = watcher.mission_for(grid_hash)
    if m is None:
        if grid_hash is not None:
            note = (note + "; " if note else "") + \
                f"no vehicle has sent the mission geometry of grid {grid_hash} yet"
        return None, note
    return ({"source": f"vehicle {m.vehicle_id}", "grid_hash": m.grid_hash,
             "boundary": _ring_xy(m.boundary_enu_m),
             "obstacles": [_ring_xy(r) for r in m.obstacles_enu_m],
             "boundary_lat_lon": _lat_lon((lat, lon) for lon, lat in m.boundary_lon_lat_deg),
             "obstacles_lat_lon": [_lat_lon((lat, lon) for lon, lat in r)
                                   for r in m.obstacles_lon_lat_deg]}, note)


@dataclass(frozen=True, slots=True)
class PlanLayer:
    """A plan drawn on the map (``pdcov watch --plan FILE``): where it came from and its
    waypoints as (lat_deg, lon_deg), in flying order."""

    source: str
    waypoints_lat_lon: tuple[tuple[float, float], ...]

    def as_json(self) -> dict[str, Any]:
        return {"source": self.source, "waypoints_lat_lon": _lat_lon(self.waypoints_lat_lon)}


def plan_layer(path: Path) -> PlanLayer:
    """The waypoints (MAV_CMD_NAV_WAYPOINT items) of a ``.plan`` or WPL 110 mission file;
    InputFileError when it cannot be read or has none."""
    items = read_mission(path).items
    points = tuple((it.lat_deg, it.lon_deg) for it in items
                   if it.command == MAV_CMD_NAV_WAYPOINT)
    if not points:
        raise InputFileError(f"--plan {path}: no waypoints (MAV_CMD_NAV_WAYPOINT items) in it")
    return PlanLayer(str(path), points)


def map_state(watcher: Watcher, report: FleetReport, mission: Mission | None,
              version: int, basemap: dict[str, Any] | None,
              config_grid_hash: str | None = None,
              plans: tuple[PlanLayer, ...] = (), refly: ReflyProposal | None = None,
              refly_outcome: str | None = None) -> dict[str, Any]:
    """Everything the page draws, as JSON-ready values; positions [lat_deg, lon_deg].
    config_grid_hash: the grid hash of ``mission``'s grid (see domain_layer); refly: the
    re-fly proposed, refly_outcome: the line of the last one sent."""
    blocks = watcher.fleet_blocks()
    vehicles = []
    origin = None
    for k, v in enumerate(report.vehicles):
        feed = watcher.feeds[v.vehicle_id]
        o = feed.origin()
        if o is not None and (origin is None or v.vehicle_id in report.merged[:1]):
            origin = o  # the fleet grid's frame: its first vehicle's origin
        footprint = None
        geom = (feed.footprint or {}).get("geometry")
        if isinstance(geom, dict):
            footprint = _lat_lon((lat, lon) for lon, lat in geom["coordinates"][0])
        vehicles.append({
            "id": v.vehicle_id, "color": COLORS[k % len(COLORS)], "alive": v.alive,
            "grid_ready": v.grid_ready, "link": v.link, "age_s": v.age_s,
            "frames_used": v.frames_used, "frames_skipped": v.frames_skipped,
            "proportion": {str(t): p for t, p in v.proportion_at_or_above.items()},
            "status_proportion": {str(t): p
                                  for t, p in v.status_proportion_at_or_above.items()},
            "mean_pd": v.mean_pd, "track_lat_lon": _lat_lon(feed.track_lat_lon_alt),
            "footprint_lat_lon": footprint, "candidates": candidates_layer(feed)})
    domain, note = domain_layer(watcher, watcher.fleet.grid_hash, mission, config_grid_hash)
    if origin is None and domain is not None:
        origin = (mission.origin() if domain["source"] == "--config" and mission is not None
                  else _mission_origin(watcher, domain["grid_hash"]))
    grid = None
    if blocks is not None and origin is not None:
        grid = blocks_payload(blocks.values(), blocks.stride, blocks.source.geometry, origin,
                              report.target)
    return {
        "version": version,
        "fleet": {"target": report.target, "thresholds": list(report.thresholds),
                  "proportion": {str(t): p for t, p in report.proportion_at_or_above.items()},
                  "mean_pd": report.mean_pd, "merged": list(report.merged),
                  "cells_free": report.cells_free},
        "grid": grid,
        "domain": domain,
        "domain_note": note,
        "plans": [p.as_json() for p in plans],
        "warnings": list(report.warnings),
        "roster_note": " ".join(report.notes),
        "unknown_vehicles": dict(report.unknown),
        "vehicles": vehicles,
        "origin": None if origin is None else {"lat_deg": origin.lat_deg,
                                               "lon_deg": origin.lon_deg},
        "basemap": basemap,
        "refly": None if refly is None else refly.map_state(),
        "gaps": None if refly is None else refly.map_state()["gaps"],
        "refly_outcome": refly_outcome,
        "refly_available": mission is not None,
    }


def _mission_origin(watcher: Watcher, grid_hash: str) -> Origin | None:
    m = watcher.mission_for(grid_hash)
    return None if m is None else Origin(m.origin_lat_deg, m.origin_lon_deg,
                                         m.ground_alt_msl_m or 0.0)


@dataclass(frozen=True, slots=True)
class _Built:
    """The map state as sent: its JSON, the version it was built for and when (loop s)."""

    version: int
    built_s: float
    data: bytes


class WebMap:
    """The HTTP server. ``state`` returns the current map state (called on the event loop);
    ``version`` tells whether it changed; ``access``: who may read it. The state is built
    once per version (and again after ``refresh_s`` for the message ages) and the same
    bytes go to every /state.json and /events client."""

    def __init__(self, host: str, port: int, state: Callable[[], dict[str, Any]],
                 version: Callable[[], int], access: WebAccess,
                 basemap: Basemap | None = None, period_s: float = 0.5,
                 refresh_s: float = 2.0, desk: ReflyDesk | None = None) -> None:
        self.host, self.port = host, port
        self.desk = desk
        self.access = access
        self.state, self.version = state, version
        self.basemap = basemap
        self.period_s = period_s
        self.refresh_s = refresh_s
        self._runner: Any = None
        self._closing = asyncio.Event()
        self._built: _Built | None = None
        self._build_error: str | None = None  # the last build's failure, logged once

    def current(self) -> _Built:
        """The state for the current version, built now only when none is held for it or
        the one held is ``refresh_s`` old (event loop thread)."""
        v = self.version()
        now = asyncio.get_running_loop().time()
        built = self._built
        if built is None or built.version != v or now - built.built_s >= self.refresh_s:
            try:
                data = state_json(self.state())
            except Exception as exc:  # a defect here must not end the map (logged)
                if self._build_error != repr(exc):
                    log.exception("web map: the state could not be built (the page keeps "
                                  "the last one and says so)")
                self._build_error = repr(exc)
                data = state_json({**(json.loads(built.data) if built else {}),
                                   "version": v, "build_error": f"{type(exc).__name__}: "
                                                                f"{exc}"})
            else:
                self._build_error = None
            built = self._built = _Built(v, now, data)
        return built

    async def start(self) -> None:
        from aiohttp import web

        @web.middleware
        async def guard(request: Any, handler: Any) -> Any:
            return await self._guard(request, handler)

        app = web.Application(middlewares=[guard])
        app.on_response_prepare.append(self._headers)
        for path in ASSETS:
            app.router.add_get(path, self._asset)
        app.router.add_get("/state.json", self._state)
        app.router.add_get("/events", self._events)
        app.router.add_get("/basemap/{z}/{x}/{y}", self._basemap)
        app.router.add_get("/api/whoami", self._whoami)
        commands = ReflyEndpoints(self.desk)  # every POST: a command (_guard)
        app.router.add_post("/api/refly", commands.refly)
        app.router.add_post("/api/refly/confirm", commands.confirm)
        self._runner = web.AppRunner(app, handle_signals=False, shutdown_timeout=1.0)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.host, self.port)
        try:
            await site.start()
        except OSError:  # the address taken or not this machine's: app.web_bind_refusal
            await self._runner.cleanup()
            self._runner = None
            raise
        sockets = getattr(site._server, "sockets", None) or []  # the bound port when 0
        if sockets:
            self.port = sockets[0].getsockname()[1]

    async def stop(self) -> None:
        self._closing.set()
        if self._runner is not None:
            await self._runner.cleanup()

    @property
    def url(self) -> str:
        """The address to open, token included; bound to every address (0.0.0.0, ::):
        this machine's host name."""
        host = socket.gethostname() if self.host in ("0.0.0.0", "::", "") else self.host
        host = f"[{host}]" if ":" in host else host
        return f"http://{host}:{self.port}/?token={self.access.token}"

    @property
    def cookie_name(self) -> str:
        """Named for the port: cookies are per host, not per port, and two maps on one
        machine must not overwrite each other's."""
        return f"pdcov_watch_token_{self.port}"

    async def _guard(self, request: Any, handler: Any) -> Any:
        """Every request: serve only what WebAccess grants (a refusal is plain text); the
        answer to a valid ``?token=`` sets the cookie."""
        from aiohttp import web

        verdict = self.access.check(request.headers.get("Host"), request.query.get("token"),
                                    request.cookies.get(self.cookie_name),
                                    request.headers.get("Authorization"))
        if not isinstance(verdict, Granted):
            headers = {"WWW-Authenticate": 'Bearer realm="pdcov watch"'} \
                if verdict.status == 401 else {}
            return web.Response(status=verdict.status, text=verdict.text, headers=headers)
        if request.method not in ("GET", "HEAD"):  # changes something: a command
            refused = self.access.may_command(verdict.role) or post_allowed(
                request.headers.get("Origin"), request.headers.get("Host"),
                request.headers.get("Content-Type"))
            if refused is not None:
                return web.Response(status=refused.status, text=refused.text)
        request["pdcov_role"] = verdict.role
        response = await handler(request)
        if verdict.set_cookie and not response.prepared:  # a stream has sent its headers
            # No Max-Age: a session cookie, gone when the browser closes. No Secure flag:
            # the map is served over plain HTTP (docs/ground-station.md, TLS by a proxy).
            response.set_cookie(self.cookie_name, self.access.token_of(verdict.role), path="/",
                                httponly=True, samesite="Strict")
        return response

    async def _headers(self, request: Any, response: Any) -> None:
        """Before any answer's headers go out (streams and refusals too)."""
        response.headers.update(SECURITY_HEADERS)

    async def _asset(self, request: Any) -> Any:
        from aiohttp import web

        name, ctype = ASSETS[request.path]
        return web.Response(body=asset(name), content_type=ctype)

    async def _state(self, request: Any) -> Any:
        from aiohttp import web

        return web.Response(body=self.current().data, content_type="application/json")

    async def _events(self, request: Any) -> Any:
        from aiohttp import web

        resp = web.StreamResponse(headers={"Content-Type": "text/event-stream"})
        await resp.prepare(request)
        sent: _Built | None = None
        try:
            while not self._closing.is_set():
                # A change, or once every refresh_s for the ages of the last messages.
                built = self.current()
                if built is not sent:
                    await resp.write(b"data: " + built.data + b"\n\n")
                    sent = built
                try:
                    await asyncio.wait_for(self._closing.wait(), self.period_s)
                except asyncio.TimeoutError:
                    pass
        except (ConnectionResetError, asyncio.CancelledError):
            pass
        return resp

    async def _whoami(self, request: Any) -> Any:
        """GET /api/whoami: what this request's token may do, for the page to show or hide
        its commands: {role, may_command, why (null when it may)}."""
        role = request["pdcov_role"]
        refused = self.access.may_command(role)
        return answer(200, {"role": role.value, "may_command": refused is None,
                            "why": None if refused is None else
                            refused.text.removeprefix("pdcov watch: ").strip()})

    async def _basemap(self, request: Any) -> Any:
        """/basemap/{z}/{x}/{y}[.ext] (y from the north): the tile, 404 when the set has none."""
        from aiohttp import web

        z, x, y = (request.match_info[k] for k in ("z", "x", "y"))
        stem, dot, ext = y.partition(".")
        found = None
        if self.basemap is not None and all(s.isascii() and s.isdigit() and len(s) < 12
                                            for s in (z, x, stem)):
            try:
                found = await read_tile(self.basemap, int(z), int(x), int(stem), ext or None)
            except TileRefused as exc:  # basemap.read_tile: bounded, off the event loop
                return web.Response(status=exc.http_status, text=str(exc))
        if found is None:
            raise web.HTTPNotFound()
        data, ctype = found
        return web.Response(body=data, content_type=ctype)

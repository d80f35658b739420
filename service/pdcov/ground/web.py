"""The live web map (``pdcov watch --web HOST:PORT``): an aiohttp server that serves the page
and its script from the installed package (ground/web/, no CDN) and pushes the map's state
as server-sent events (``/events``; ``/state.json`` for one copy). Every path needs the
access token (ground/web_auth.py); every answer carries headers that keep the page from
being framed, sniffed or cached and its address from leaking as a Referer.

aiohttp earns its place: HTTP/1.1 parsing, streaming responses and clean shutdown are its
job, and a hand-written server on a ground-station laptop would be one more thing to get
wrong. The state holds the fleet's P_D grid (quantised to 0..255, down-sampled to at most
MAX_SIDE cells a side by taking each block's maximum), the domain and obstacles of the grid
shown (``domain_layer``: from the mission config when it describes that grid, else from the
vehicles' mission replies), each vehicle's track and current footprint in ENU metres, the
figures of the terminal view, and the re-fly proposed (``refly``: waypoints and gap rings as
[lat, lon]; ``gaps``: its gap rings) with the outcome of the last one sent.

Re-tasking (ground/retask.py, docs/ground-station.md "Re-tasking"): ``POST /api/refly``
{vehicle, target_pd} proposes a re-fly of the merged grid's gaps (answered with the
proposal: id, waypoints, gaps, lines), ``POST /api/refly/confirm`` {id} sends it and
answers with the daemon's verdict. Both need the token, a JSON body and, when the browser
sends one, an Origin of this host (web_auth.post_allowed: CSRF).
"""

from __future__ import annotations

import asyncio
import base64
import json
import logging
import math
import socket
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pdcov.bus.json_doc import finite_or_null
from pdcov.config import Mission
from pdcov.core.geodesy import Origin, geodetic_to_enu
from pdcov.errors import PdcovError
from pdcov.ground.feed import VehicleFeed
from pdcov.ground.fleet_report import FleetReport
from pdcov.ground.retask import ReflyProposal
from pdcov.ground.watcher import Watcher
from pdcov.ground.web_auth import Granted, WebAccess, post_allowed

if TYPE_CHECKING:  # the desk is handed in (ground/app.py)
    from pdcov.ground.app import ReflyDesk

log = logging.getLogger("pdcov.watch")
MAX_SIDE = 400
ASSETS = {"/": ("index.html", "text/html"), "/app.js": ("app.js", "text/javascript"),
          "/style.css": ("style.css", "text/css")}
SECURITY_HEADERS = {
    "Content-Security-Policy": "default-src 'self'; frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff", "X-Frame-Options": "DENY",
    "Referrer-Policy": "no-referrer", "Cache-Control": "no-store"}
COLORS = ("#e6194b", "#4363d8", "#f58231", "#911eb4", "#42d4f4", "#f032e6", "#3cb44b",
          "#9a6324")


def asset(name: str) -> bytes:
    """An asset of the page, read from the installed package."""
    return (resources.files("pdcov.ground") / "web" / name).read_bytes()


def _origin(feed: VehicleFeed) -> Origin | None:
    o = ((feed.status or {}).get("grid") or {}).get("origin") or {}
    try:
        return Origin(float(o["lat_deg"]), float(o["lon_deg"]),
                      float(o.get("ground_alt_msl_m") or 0.0))
    except (KeyError, TypeError, ValueError):
        return None


def _enu_xy(lat_lon: list[tuple[float, float]], origin: Origin) -> list[list[float]]:
    if not lat_lon:
        return []
    a = np.asarray(lat_lon, dtype=float)
    r = geodetic_to_enu(a[:, 0], a[:, 1], origin.ground_alt_msl_m, origin)
    return [[round(float(x), 2), round(float(y), 2)] for x, y in r[:, :2]]


def _ring_xy(ring: Any) -> list[list[float]]:
    return [[round(float(x), 2), round(float(y), 2)] for x, y in list(ring)]


def grid_payload(pd: np.ndarray, mask: np.ndarray, geometry: Any) -> dict[str, Any]:
    """The heat map: P_D quantised to 0..254 per (block of) cells, 255 outside free space;
    rows from south (row 0) to north; ``stride`` cells per shown cell."""
    n_rows, n_cols = mask.shape
    stride = max(1, math.ceil(max(n_rows, n_cols) / MAX_SIDE))
    h, w = math.ceil(n_rows / stride), math.ceil(n_cols / stride)
    q = np.where(mask, np.rint(np.clip(pd, 0.0, 1.0) * 254.0), -1.0)
    padded = np.full((h * stride, w * stride), -1.0)
    padded[:n_rows, :n_cols] = q
    blocks = padded.reshape(h, stride, w, stride).max(axis=(1, 3))
    data = np.where(blocks < 0, 255, blocks).astype(np.uint8)
    return {"x0_m": geometry.x0_m, "y0_m": geometry.y0_m,
            "cell_size_m": geometry.cell_size_m * stride, "w": w, "h": h, "stride": stride,
            "pd_b64": base64.b64encode(data.tobytes()).decode()}


def domain_layer(watcher: Watcher, grid_hash: str | None, mission: Mission | None,
                 config_grid_hash: str | None) -> tuple[dict[str, Any] | None, str | None]:
    """The domain and obstacles to draw over grid ``grid_hash`` (None: no grid yet), and a
    note for the operator. The mission config (``--config``, whose grid hash is
    ``config_grid_hash``) is drawn when it describes that grid (or no grid is shown yet);
    otherwise the mission reply of a vehicle flying that grid. A config describing another
    grid is never drawn over it: the note says so."""
    if mission is not None and (grid_hash is None or config_grid_hash == grid_hash):
        d = mission.domain
        return ({"source": "--config", "grid_hash": config_grid_hash,
                 "boundary": _ring_xy(d.boundary.exterior.coords),
                 "obstacles": [_ring_xy(p.exterior.coords) for p in d.obstacles]}, None)
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
             "obstacles": [_ring_xy(r) for r in m.obstacles_enu_m]}, note)


def map_state(watcher: Watcher, report: FleetReport, mission: Mission | None,
              version: int, basemap: dict[str, Any] | None,
              config_grid_hash: str | None = None, refly: ReflyProposal | None = None,
              refly_outcome: str | None = None) -> dict[str, Any]:
    """Everything the page draws, as JSON-ready values. config_grid_hash: the grid hash
    of ``mission``'s grid (see domain_layer); refly: the re-fly proposed, refly_outcome:
    the line of the last one sent."""
    merged, _ = watcher.fleet_state()
    vehicles = []
    origin = None
    for k, v in enumerate(report.vehicles):
        feed = watcher.feeds[v.vehicle_id]
        o = _origin(feed)
        origin = origin or o
        footprint = None
        geom = (feed.footprint or {}).get("geometry")
        if o is not None and isinstance(geom, dict):
            footprint = _enu_xy([(lat, lon) for lon, lat in geom["coordinates"][0]], o)
        track = _enu_xy([(lat, lon) for lat, lon, _ in feed.track_lat_lon_alt], o) if o \
            else []
        vehicles.append({
            "id": v.vehicle_id, "color": COLORS[k % len(COLORS)], "alive": v.alive,
            "grid_ready": v.grid_ready, "link": v.link, "age_s": v.age_s,
            "frames_used": v.frames_used, "frames_skipped": v.frames_skipped,
            "proportion": {str(t): p for t, p in v.proportion_at_or_above.items()},
            "status_proportion": {str(t): p
                                  for t, p in v.status_proportion_at_or_above.items()},
            "mean_pd": v.mean_pd, "track": track, "footprint": footprint})
    domain, note = domain_layer(watcher, None if merged is None else merged.hash, mission,
                                config_grid_hash)
    if origin is None and domain is not None:
        origin = (mission.origin() if domain["source"] == "--config" and mission is not None
                  else _mission_origin(watcher, domain["grid_hash"]))
    return {
        "version": version,
        "fleet": {"target": report.target, "thresholds": list(report.thresholds),
                  "proportion": {str(t): p for t, p in report.proportion_at_or_above.items()},
                  "mean_pd": report.mean_pd, "merged": list(report.merged),
                  "cells_free": report.cells_free},
        "grid": None if merged is None else grid_payload(merged.pd, merged.mask,
                                                         merged.geometry),
        "domain": domain,
        "domain_note": note,
        "warnings": list(report.warnings),
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


def basemap_info(folder: Path | None) -> dict[str, Any] | None:
    """The zoom levels and image type of an XYZ tile folder ({z}/{x}/{y}.png|jpg)."""
    if folder is None:
        return None
    zooms = sorted(int(p.name) for p in folder.iterdir() if p.is_dir() and p.name.isdigit())
    ext = "png"
    for z in zooms:
        found = next(iter(sorted((folder / str(z)).glob("*/*.*"))), None)
        if found is not None:
            ext = found.suffix.lstrip(".")
            break
    return {"zooms": zooms, "ext": ext}


def state_json(state: dict[str, Any]) -> bytes:
    """The page's data as strict JSON: every non-finite number (NaN, ±inf) becomes null,
    so that the page's ``JSON.parse`` never meets ``Infinity``."""
    return json.dumps(finite_or_null(state), separators=(",", ":"), allow_nan=False).encode()


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
                 basemap_dir: Path | None = None, period_s: float = 0.5,
                 refresh_s: float = 2.0, desk: ReflyDesk | None = None) -> None:
        self.host, self.port = host, port
        self.desk = desk
        self.access = access
        self.state, self.version = state, version
        self.basemap_dir = basemap_dir
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
        app.router.add_post("/api/refly", self._refly)
        app.router.add_post("/api/refly/confirm", self._refly_confirm)
        self._runner = web.AppRunner(app, handle_signals=False, shutdown_timeout=1.0)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.host, self.port)
        await site.start()
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
        if request.method not in ("GET", "HEAD"):
            refused = post_allowed(request.headers.get("Origin"), request.headers.get("Host"),
                                   request.headers.get("Content-Type"))
            if refused is not None:
                return web.Response(status=refused.status, text=refused.text)
        response = await handler(request)
        if verdict.set_cookie and not response.prepared:  # a stream has sent its headers
            # No Max-Age: a session cookie, gone when the browser closes. No Secure flag:
            # the map is served over plain HTTP (docs/ground-station.md, TLS by a proxy).
            response.set_cookie(self.cookie_name, self.access.token, path="/",
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

    async def _json_body(self, request: Any) -> dict[str, Any]:
        from aiohttp import web

        try:
            body = await request.json()
        except ValueError:
            body = None
        if not isinstance(body, dict):
            raise web.HTTPBadRequest(text="expected a JSON object\n")
        return body

    def _answer(self, status: int, doc: dict[str, Any]) -> Any:
        from aiohttp import web

        return web.Response(status=status, body=state_json(doc),
                            content_type="application/json")

    async def _refly(self, request: Any) -> Any:
        """POST /api/refly {vehicle, target_pd (optional)}: a re-fly proposal."""
        body = await self._json_body(request)
        if self.desk is None:
            return self._answer(409, {"error": "re-tasking needs the mission flown: start "
                                               "pdcov watch with --config"})
        vehicle, target = body.get("vehicle"), body.get("target_pd")
        if not isinstance(vehicle, str) or not (
                target is None or (isinstance(target, (int, float))
                                   and not isinstance(target, bool) and 0 < target < 1)):
            return self._answer(400, {"error": "expected {vehicle: id, target_pd: a "
                                               "probability in (0, 1) or null}"})
        try:
            proposal = await self.desk.propose(vehicle, target)
        except PdcovError as exc:  # no grid yet, no gaps, another grid: say so
            return self._answer(409, {"error": str(exc)})
        return self._answer(200, proposal.map_state())

    async def _refly_confirm(self, request: Any) -> Any:
        """POST /api/refly/confirm {id}: send the proposal shown; the daemon's verdict."""
        body = await self._json_body(request)
        if self.desk is None:
            return self._answer(409, {"error": "re-tasking needs --config"})
        proposal_id = body.get("id")
        if not isinstance(proposal_id, str):
            return self._answer(400, {"error": "expected {id: the proposal's id}"})
        try:
            accepted, line = await self.desk.confirm(proposal_id)
        except PdcovError as exc:
            return self._answer(409, {"error": str(exc)})
        log.warning("web map: %s", line)
        return self._answer(200, {"id": proposal_id, "accepted": accepted, "line": line})

    async def _basemap(self, request: Any) -> Any:
        from aiohttp import web

        z, x, y = (request.match_info[k] for k in ("z", "x", "y"))
        stem, _, ext = y.partition(".")
        if self.basemap_dir is None or not all(s.isdigit() for s in (z, x, stem)) \
                or ext not in ("png", "jpg", "jpeg", "webp"):
            raise web.HTTPNotFound()
        path = self.basemap_dir / z / x / f"{stem}.{ext}"
        if not path.is_file():
            raise web.HTTPNotFound()
        return web.FileResponse(path)

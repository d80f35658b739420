"""The web map's JSON answers (``pdcov watch --web``): the state's strict JSON, and the
re-fly command endpoints (``POST /api/refly``, ``POST /api/refly/confirm``), which
ground/web.py routes only to a request its guard let command (web_auth.WebAccess)."""

from __future__ import annotations

import json
import logging
from typing import TYPE_CHECKING, Any

from pdcov.bus.json_doc import finite_or_null
from pdcov.errors import PdcovError

if TYPE_CHECKING:  # the desk is handed in (ground/app.py)
    from pdcov.ground.app import ReflyDesk

log = logging.getLogger("pdcov.watch")


def state_json(state: dict[str, Any]) -> bytes:
    """The page's data as strict JSON: every non-finite number (NaN, ±inf) becomes null,
    so that the page's ``JSON.parse`` never meets ``Infinity``."""
    return json.dumps(finite_or_null(state), separators=(",", ":"), allow_nan=False).encode()


def answer(status: int, doc: dict[str, Any]) -> Any:
    """A JSON response (strict: state_json)."""
    from aiohttp import web

    return web.Response(status=status, body=state_json(doc), content_type="application/json")


async def json_body(request: Any) -> dict[str, Any]:
    """The request's JSON object; 400 for anything else."""
    from aiohttp import web

    try:
        body = await request.json()
    except ValueError:
        body = None
    if not isinstance(body, dict):
        raise web.HTTPBadRequest(text="expected a JSON object\n")
    return body


class ReflyEndpoints:
    """The re-tasking commands over the desk (None: no mission config, 409)."""

    def __init__(self, desk: ReflyDesk | None) -> None:
        self.desk = desk

    async def refly(self, request: Any) -> Any:
        """POST /api/refly {vehicle, target_pd (optional)}: a re-fly proposal."""
        body = await json_body(request)
        if self.desk is None:
            return answer(409, {"error": "re-tasking needs the mission flown: start "
                                               "pdcov watch with --config"})
        vehicle, target = body.get("vehicle"), body.get("target_pd")
        if not isinstance(vehicle, str) or not (
                target is None or (isinstance(target, (int, float))
                                   and not isinstance(target, bool) and 0 < target < 1)):
            return answer(400, {"error": "expected {vehicle: id, target_pd: a "
                                               "probability in (0, 1) or null}"})
        try:
            proposal = await self.desk.propose(vehicle, target)
        except PdcovError as exc:  # no grid yet, no gaps, another grid: say so
            return answer(409, {"error": str(exc)})
        return answer(200, proposal.map_state())

    async def confirm(self, request: Any) -> Any:
        """POST /api/refly/confirm {id}: send the proposal shown; the daemon's verdict."""
        body = await json_body(request)
        if self.desk is None:
            return answer(409, {"error": "re-tasking needs --config"})
        proposal_id = body.get("id")
        if not isinstance(proposal_id, str):
            return answer(400, {"error": "expected {id: the proposal's id}"})
        try:
            accepted, line = await self.desk.confirm(proposal_id)
        except PdcovError as exc:
            return answer(409, {"error": str(exc)})
        log.warning("web map: %s", line)
        return answer(200, {"id": proposal_id, "accepted": accepted, "line": line})

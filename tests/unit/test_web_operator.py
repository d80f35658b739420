"""Who may command from the web map (ground/web_auth.py): the view token reads, the
operator token (--web-operator-token-file) reads and commands; every command endpoint (every
route that is not a GET) answers 403 to the view token and 401 without a token; without an
operator token no one commands; the page asks /api/whoami and shows commands only then."""

from __future__ import annotations

import http.client
import json

import pytest

from pdcov.errors import ConfigError
from pdcov.ground.web_auth import NO_OPERATOR, Granted, Refusal, Role, WebAccess, web_access
from tests.support.operator_access import BOTH, NAMES, OPERATOR, VIEW, VIEW_ONLY
from tests.support.watch_fixtures import ThreadedWebMap


def test_each_token_grants_its_role_by_query_cookie_or_bearer():
    for token, role in ((VIEW, Role.VIEWER), (OPERATOR, Role.OPERATOR)):
        assert BOTH.check("127.0.0.1", token, None, None) == Granted(True, role)
        assert BOTH.check("127.0.0.1", None, token, None) == Granted(False, role)
        assert BOTH.check("127.0.0.1", None, None, f"Bearer {token}") == Granted(False, role)
        assert BOTH.token_of(role) == token
    for wrong in (OPERATOR[:-1], OPERATOR + "x", "", VIEW.upper()):
        assert isinstance(BOTH.check("127.0.0.1", wrong, None, None), Refusal)
    # The operator's address in a browser holding the view cookie: the operator's.
    assert BOTH.check("127.0.0.1", OPERATOR, VIEW, None) == Granted(True, Role.OPERATOR)
    assert BOTH.check("127.0.0.1", VIEW, VIEW, None) == Granted(False, Role.VIEWER)
    assert VIEW_ONLY.check("127.0.0.1", OPERATOR, None, None).status == 401
    assert VIEW_ONLY.token_of(Role.OPERATOR) == VIEW  # no operator token: nothing to set


def test_only_the_operator_may_command():
    assert BOTH.may_command(Role.OPERATOR) is None
    refused = BOTH.may_command(Role.VIEWER)
    assert refused is not None and refused.status == 403 and "view token" in refused.text
    refused = VIEW_ONLY.may_command(Role.VIEWER)
    assert refused is not None and refused.status == 403 and NO_OPERATOR in refused.text


def test_the_same_token_twice_and_a_bad_operator_token_file_are_refused(tmp_path):
    with pytest.raises(ConfigError, match="operator token is its view token"):
        WebAccess(VIEW, NAMES, VIEW)
    with pytest.raises(ConfigError, match="operator token"):
        WebAccess(VIEW, NAMES, "short")
    view, op = tmp_path / "view", tmp_path / "op"
    view.write_text(VIEW)
    op.write_text(VIEW + "\n")
    view.chmod(0o600)
    op.chmod(0o600)
    with pytest.raises(ConfigError, match="a token of its own"):
        web_access("127.0.0.1", view, [], {}, "h", op)
    op.write_text(OPERATOR)
    assert web_access("127.0.0.1", view, [], {}, "groundstation", op) == BOTH
    op.chmod(0o644)
    with pytest.raises(ConfigError, match="--web-operator-token-file .* too open"):
        web_access("127.0.0.1", view, [], {}, "h", op)


class Desk:
    """A re-tasking desk that counts what reached it."""

    def __init__(self) -> None:
        self.calls: list[str] = []

    async def propose(self, vehicle, target):
        self.calls.append("propose")

        class Proposal:
            @staticmethod
            def map_state():
                return {"id": "p1", "vehicle": vehicle, "lines": []}
        return Proposal()

    async def confirm(self, proposal_id):
        self.calls.append("confirm")
        return True, "sent"


BODIES = {"/api/refly": {"vehicle": "uav1", "target_pd": 0.8}, "/api/refly/confirm": {"id": "p1"}}


def request(port: int, method: str, path: str, token: str | None, body=None):
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    headers = {"Content-Type": "application/json", "Origin": f"http://127.0.0.1:{port}"}
    if token is not None:
        headers["Authorization"] = f"Bearer {token}"
    try:
        c.request(method, path, body=None if body is None else json.dumps(body),
                  headers=headers)
        r = c.getresponse()
        return r.status, r.read()
    finally:
        c.close()


@pytest.mark.parametrize("access", [BOTH, VIEW_ONLY], ids=["operator token", "view only"])
def test_every_command_endpoint_needs_the_operator_token(access):
    desk = Desk()
    s = ThreadedWebMap(lambda: {"version": 7, "vehicles": [], "grid": None}, access, desk=desk)
    try:
        routes = {(r.method, r.resource.canonical) for r in s.web._runner.app.router.routes()}
        commands = sorted(path for method, path in routes if method not in ("GET", "HEAD"))
        assert commands == sorted(BODIES)  # a new command endpoint needs a body here
        port = s.web.port
        for path in commands:
            assert request(port, "POST", path, None, BODIES[path])[0] == 401
            assert request(port, "POST", path, VIEW, BODIES[path])[0] == 403
            assert request(port, "POST", path, OPERATOR, BODIES[path])[0] == (
                200 if access is BOTH else 401)
        assert desk.calls == (["propose", "confirm"] if access is BOTH else [])
        status, body = request(port, "GET", "/api/whoami", VIEW)
        why = ("the view token may not command: open the map with the operator token"
           if access is BOTH else NO_OPERATOR)
        assert status == 200 and json.loads(body) == {"role": "viewer", "may_command": False,
                                                      "why": why}
        if access is BOTH:
            status, body = request(port, "GET", "/api/whoami", OPERATOR)
            assert json.loads(body) == {"role": "operator", "may_command": True, "why": None}
        assert request(port, "GET", "/api/whoami", None)[0] == 401
        assert request(port, "GET", "/state.json", VIEW)[0] == 200  # the viewer reads
    finally:
        s.close()

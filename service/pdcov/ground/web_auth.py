"""Who may read the web map (``pdcov watch --web``): a secret token, as Jupyter does it.

The token (``secrets.token_urlsafe``, 256 bits) is made at start unless given in a file
(``--web-token-file``, refused when group or others may read it, as ssh refuses a private
key) or in the environment (``PDCOV_WEB_TOKEN``); never on the command line, which every
local user sees in ``ps``. It is printed once, in the address to open. A request carries
it as ``?token=`` (the first page load; the server answers with an HttpOnly,
SameSite=Strict cookie and the page removes it from the address bar), as that cookie, or
as ``Authorization: Bearer`` (scripts). Every path needs it, loopback included: other
users of the machine can connect to loopback too.

The Host header is checked as well (DNS rebinding): the token alone already stops a
rebinding page, which cannot know it and is sent no cookie for its own name, but a name
the operator never meant to serve is refused before the token is looked at. Allowed: any
IP address literal (a rebinding attack needs a name), ``localhost``, this machine's host
name (and ``NAME.local``), the name bound with ``--web`` and names given with
``--web-allow-host``.

Requests that change something (POST: the re-tasking endpoints) must also be what no other
site can make a browser send (CSRF): a JSON body (``Content-Type: application/json``, which
a cross-site form cannot send and a cross-site script can only after a CORS preflight this
server never grants) and, when the browser names the page's origin, an ``Origin`` of this
host (``post_allowed``). The cookie's SameSite=Strict already keeps it off cross-site
requests; these keep a request that carries the token in its address from being forged.

Two tokens, two roles (``Role``): the view token (``--web-token-file``, or made at start)
reads everything; the operator token (``--web-operator-token-file``) reads and commands.
Every request that is not a GET or HEAD is a command (today the re-tasking endpoints) and
answers 403 to the view token; without an operator token no one commands from the web map
(``WebAccess.may_command``). The two must differ; both are compared in constant time.

``WebAccess.check``, ``WebAccess.may_command`` and ``post_allowed`` are the decisions,
pure; reading the token files and the environment are the edges.
"""

from __future__ import annotations

import hmac
import ipaddress
import re
import secrets
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

from pdcov.errors import ConfigError
from pdcov.ground.secret_file import read_secret_file

TOKEN_ENV = "PDCOV_WEB_TOKEN"
MIN_TOKEN_CHARS = 16
_TOKEN_RE = re.compile(r"[A-Za-z0-9_.~-]+")  # URL- and cookie-safe, no quoting needed
_HINT = ("open the address pdcov watch printed when it started "
         "(http://HOST:PORT/?token=...)")


class Role(Enum):
    """What a token may do: read the map, or read it and command (re-task a vehicle)."""

    VIEWER = "viewer"
    OPERATOR = "operator"


NO_OPERATOR = ("no operator token (--web-operator-token-file): no one can command from this "
               "web map")


@dataclass(frozen=True, slots=True)
class Refusal:
    """An HTTP status (401: no valid token; 403: a Host this map does not serve) and the
    short plain-text explanation sent with it."""

    status: int
    text: str


@dataclass(frozen=True, slots=True)
class Granted:
    """The request may be served, with the rights of ``role``; ``set_cookie``: it came with a
    valid ``?token=`` and no valid cookie, so the answer sets the cookie (to ``role``'s
    token)."""

    set_cookie: bool
    role: Role = Role.VIEWER


@dataclass(frozen=True, slots=True)
class WebAccess:
    """token: the view token (validated: ``check_token``). hosts: the host names (lower
    case) served besides IP literals (``served_names``). operator_token: the token that may
    command too, or None (no one may)."""

    token: str
    hosts: frozenset[str]
    operator_token: str | None = None

    def __post_init__(self) -> None:
        check_token(self.token, "the web map token")
        if self.operator_token is not None:
            check_token(self.operator_token, "the web map's operator token")
            if hmac.compare_digest(self.operator_token.encode(), self.token.encode()):
                raise ConfigError("the web map's operator token is its view token: give "
                                  "--web-operator-token-file a token of its own")

    def token_of(self, role: Role) -> str:
        """The token that grants ``role`` (the cookie set for it)."""
        return self.operator_token if role is Role.OPERATOR and self.operator_token \
            else self.token

    def may_command(self, role: Role) -> Refusal | None:
        """Whether a request granted ``role`` may change anything (module docstring): None,
        else a 403 saying why."""
        if role is Role.OPERATOR:
            return None
        why = NO_OPERATOR if self.operator_token is None else \
            "the view token may not command: open the map with the operator token"
        return Refusal(403, f"pdcov watch: {why}\n")

    def check(self, host_header: str | None, query_token: str | None,
              cookie_token: str | None, authorization: str | None) -> Granted | Refusal:
        """Whether a request may be served, from its Host header, its ``?token=``, its
        cookie and its Authorization header (each None when absent)."""
        if not host_allowed(host_header, self.hosts):
            return Refusal(403, f"pdcov watch: Host {host_header!r} is not a name of this web "
                                "map (DNS rebinding?). Use the address pdcov watch printed, "
                                "or start it with --web-allow-host NAME.\n")
        bearer = None
        if authorization is not None and authorization[:7].lower() == "bearer ":
            bearer = authorization[7:].strip()
        # A valid ?token= wins over the cookie (the operator's address opened in a browser
        # that holds the view cookie makes it the operator's); the cookie is set when it
        # does not already grant that role.
        query_role, cookie_role = self._role(query_token), self._role(cookie_token)
        if query_role is not None:
            return Granted(cookie_role is not query_role, query_role)
        for role in (cookie_role, self._role(bearer)):
            if role is not None:
                return Granted(False, role)
        if (query_token, cookie_token, bearer) == (None, None, None):
            return Refusal(401, f"pdcov watch: this web map needs its access token: {_HINT}.\n")
        return Refusal(401, f"pdcov watch: wrong or expired access token: {_HINT} (a new "
                            "token is made at each start unless --web-token-file gives one).\n")

    def _role(self, presented: str | None) -> Role | None:
        """The role ``presented`` grants, None for no token or a wrong one. Both tokens
        are compared, each in constant time."""
        if presented is None:
            return None
        # Bytes: compare_digest refuses non-ASCII str, and a visitor chooses what is sent.
        given = presented.encode("utf-8", "replace")
        viewer = hmac.compare_digest(given, self.token.encode())
        operator = hmac.compare_digest(given, (self.operator_token or "").encode()) \
            and self.operator_token is not None
        return Role.OPERATOR if operator else Role.VIEWER if viewer else None


def post_allowed(origin: str | None, host_header: str | None,
                 content_type: str | None) -> Refusal | None:
    """Whether a state-changing request (POST) may go on (module docstring): None, else a
    403 naming what is wrong. ``origin``: its Origin header (None: absent, as from a
    script; "null" from a sandboxed page is refused)."""
    if (content_type or "").split(";")[0].strip().lower() != "application/json":
        return Refusal(403, "pdcov watch: expected a JSON body (Content-Type: "
                            "application/json)\n")
    if origin is not None:
        netloc = origin.split("://", 1)[-1].rstrip("/").lower()
        if origin.lower() == "null" or host_header is None \
                or netloc != host_header.strip().lower():
            return Refusal(403, f"pdcov watch: a request from another site ({origin[:80]}) "
                                "may not change anything here\n")
    return None


def host_allowed(host_header: str | None, names: Iterable[str]) -> bool:
    """Whether a Host header (``name``, ``name:port``, ``[v6]:port``) is an IP literal or
    one of ``names`` (lower case); None (HTTP/1.0, no Host) is allowed: a browser always
    sends one, so a request without it is not a rebinding page's."""
    if host_header is None:
        return True
    h = host_header.strip().lower()
    if h.startswith("["):
        name = h[1:h.find("]")] if "]" in h else h
    else:
        name = h.rsplit(":", 1)[0] if h.count(":") == 1 else h
    name = name.rstrip(".")
    try:
        ipaddress.ip_address(name)
        return True
    except ValueError:
        return name in names


def served_names(bound_host: str, hostname: str, extra: Iterable[str] = ()) -> frozenset[str]:
    """The host names a map bound to ``bound_host`` on a machine called ``hostname``
    answers to: localhost, the host name and NAME.local (mDNS), the bound name, ``extra``."""
    names = {"localhost", bound_host, hostname, f"{hostname}.local", *extra}
    return frozenset(n.strip().lower().rstrip(".") for n in names if n.strip())


def web_access(bound_host: str, token_file: Path | None, allow_hosts: Iterable[str],
               environ: Mapping[str, str], hostname: str,
               operator_token_file: Path | None = None) -> WebAccess:
    """Who may read a map bound to ``bound_host`` on a machine called ``hostname``: the
    token of ``token_file`` (``--web-token-file``), else of ``environ[TOKEN_ENV]``, else a
    new random one; the names ``served_names`` gives; who may command: the token of
    ``operator_token_file`` (``--web-operator-token-file``), else no one. ConfigError for a
    bad token file or token, or the same token twice."""
    if token_file is not None:
        token = read_token_file(token_file)
    elif environ.get(TOKEN_ENV):
        token = check_token(environ[TOKEN_ENV].strip(), TOKEN_ENV)
    else:
        token = secrets.token_urlsafe(32)
    operator = None if operator_token_file is None else read_token_file(
        operator_token_file, "--web-operator-token-file")
    return WebAccess(token, served_names(bound_host, hostname, allow_hosts), operator)


def check_token(token: str, where: str) -> str:
    """``token`` when it is usable (at least MIN_TOKEN_CHARS of A-Z a-z 0-9 _ . ~ -),
    else ConfigError naming ``where``."""
    if len(token) < MIN_TOKEN_CHARS or not _TOKEN_RE.fullmatch(token):
        raise ConfigError(f"{where}: expected a token of at least {MIN_TOKEN_CHARS} "
                          "characters A-Z a-z 0-9 _ . ~ - (e.g. python3 -c 'import secrets; "
                          f"print(secrets.token_urlsafe(32))'), got {len(token)} characters"
                          + ("" if _TOKEN_RE.fullmatch(token) or not token
                             else " with others among them"))
    return token


def read_token_file(path: Path, flag: str = "--web-token-file") -> str:
    """The token in ``path`` (surrounding white space stripped). ConfigError when the file
    is not a secret file (ground/secret_file.py) or not a usable token; ``flag`` names it
    in errors."""
    return check_token(read_secret_file(path, flag).strip(), f"{flag} {path}")

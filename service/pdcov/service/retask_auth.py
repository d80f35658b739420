"""Who may re-task this vehicle, with no I/O: a request is taken only when it came on the
exact key ``pdcov/<id>/retask`` (not through a wildcard), is signed by an operator key the
mission lists (``service.retask_operator_keys``), was issued within ``window_s`` of the
daemon's UTC clock (either way), names this vehicle, and carries a nonce not seen before
(docs/protocol.md "retask").

The nonces seen are kept with their expiry (issued + window: a request older is refused as
stale anyway) in a ``NonceBook``, which the shell writes to service.state_dir whenever it
changes (``changed``) and reads back at start: a replay after a restart is refused too.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass

from pdcov.bus.errors import BusPayloadError
from pdcov.bus.operator_keys import OperatorPublicKey
from pdcov.bus.retask import RetaskRequest, UnsignedRequest, decode_retask_body, open_envelope
from pdcov.telemetry.frame_policy import TextEnum

MAX_NONCES = 4096
"""Nonces held unexpired at most (a request beyond: refused as BUSY until some expire)."""
NONCES_SCHEMA = "pdcov.retask_nonces"


class RetaskRefusal(TextEnum):
    """Why the daemon refused a request without asking the autopilot (the reply's
    ``reason``; docs/protocol.md "retask")."""

    DISABLED = "PDCOV_RETASK_DISABLED"
    """service.retask is false (the default)."""
    WILDCARD = "PDCOV_WILDCARD"
    """The query's key expression is not exactly pdcov/<id>/retask."""
    UNSIGNED = "PDCOV_UNSIGNED"
    """No signature (a version 1 request)."""
    BAD_REQUEST = "PDCOV_BAD_REQUEST"
    """The payload does not decode (bus/retask.py)."""
    UNKNOWN_KEY = "PDCOV_UNKNOWN_KEY"
    """Signed by a key not on service.retask_operator_keys."""
    BAD_SIGNATURE = "PDCOV_BAD_SIGNATURE"
    """The signature does not verify over the body with the key it names."""
    WRONG_VEHICLE = "PDCOV_WRONG_VEHICLE"
    """The signed body names another vehicle."""
    STALE = "PDCOV_STALE"
    """Issued outside the time window of the daemon's clock (either way)."""
    REPLAYED = "PDCOV_REPLAYED"
    """Its nonce was seen before."""
    OUT_OF_BOUNDS = "PDCOV_OUT_OF_BOUNDS"
    """An item outside service.retask_limits (planning/mission_bounds.py)."""
    NO_AUTOPILOT = "PDCOV_NO_AUTOPILOT"
    """No autopilot heard on the link yet."""
    BUSY = "PDCOV_UPLOAD_IN_PROGRESS"
    """An upload is running (one at a time), or too many nonces are held."""


class NonceBook:
    """The nonces seen, each with its expiry (UTC s)."""

    def __init__(self, expiry_unix_s: Mapping[str, float] | None = None) -> None:
        self._expiry = dict(expiry_unix_s or {})
        self.changed = False

    def __contains__(self, nonce: str) -> bool:
        return nonce in self._expiry

    def __len__(self) -> int:
        return len(self._expiry)

    def prune(self, unix_s: float) -> None:
        """Forget the nonces expired at ``unix_s``."""
        old = [n for n, t in self._expiry.items() if t < unix_s]
        for n in old:
            del self._expiry[n]
        self.changed |= bool(old)

    def add(self, nonce: str, expiry_unix_s: float) -> None:
        self._expiry[nonce] = expiry_unix_s
        self.changed = True

    def to_bytes(self) -> bytes:
        """The book as the shell writes it (JSON {schema, nonces {nonce: expiry}})."""
        self.changed = False
        return json.dumps({"schema": NONCES_SCHEMA, "nonces": self._expiry},
                          separators=(",", ":")).encode()

    @classmethod
    def from_bytes(cls, data: bytes) -> NonceBook:
        """The book the shell read; ValueError when it is not one."""
        doc = json.loads(data.decode("utf-8"))
        if not isinstance(doc, dict) or doc.get("schema") != NONCES_SCHEMA \
                or not isinstance(doc.get("nonces"), dict):
            raise ValueError(f"not a {NONCES_SCHEMA} document")
        nonces = doc["nonces"]
        if len(nonces) > MAX_NONCES or not all(
                isinstance(n, str) and isinstance(t, (int, float)) for n, t in nonces.items()):
            raise ValueError(f"nonces: expected at most {MAX_NONCES} nonce: expiry pairs")
        return cls({n: float(t) for n, t in nonces.items()})


@dataclass(frozen=True, slots=True)
class Refused:
    """A request refused: why, and the detail for the reply and the log."""

    reason: RetaskRefusal
    detail: str
    plan_hash: str | None = None


@dataclass(frozen=True, slots=True)
class RetaskAuthority:
    """The signature, time, nonce, vehicle and key-expression rules (module docstring).
    ``keys``: {key id: key}; ``window_s``: the time window, s."""

    vehicle_id: str
    keys: Mapping[str, OperatorPublicKey]
    window_s: float

    @property
    def key_expr(self) -> str:
        return f"pdcov/{self.vehicle_id}/retask"

    def admit(self, payload: bytes, key_expr: str, unix_s: float, nonces: NonceBook
              ) -> RetaskRequest | Refused:
        """The request, its nonce entered in ``nonces``, or why not. ``key_expr``: the
        query's own key expression; ``unix_s``: the daemon's UTC clock."""
        if key_expr != self.key_expr:
            return Refused(RetaskRefusal.WILDCARD, f"the query's key expression {key_expr!r} "
                           f"is not exactly {self.key_expr!r} (a wildcard)")
        try:
            env = open_envelope(payload, self.key_expr)
        except UnsignedRequest as exc:
            return Refused(RetaskRefusal.UNSIGNED, str(exc))
        except BusPayloadError as exc:
            return Refused(RetaskRefusal.BAD_REQUEST, str(exc))
        key = self.keys.get(env.key_id)
        if key is None:
            return Refused(RetaskRefusal.UNKNOWN_KEY, f"key {env.key_id} is not on "
                           "service.retask_operator_keys")
        if not key.verifies(env.signature, env.body):
            return Refused(RetaskRefusal.BAD_SIGNATURE, f"the signature does not verify "
                           f"with key {env.key_id}")
        try:
            req = decode_retask_body(env.body, self.key_expr)
        except BusPayloadError as exc:
            return Refused(RetaskRefusal.BAD_REQUEST, str(exc))
        return self._judge(req, env.key_id, unix_s, nonces)

    def _judge(self, req: RetaskRequest, key_id: str, unix_s: float, nonces: NonceBook
               ) -> RetaskRequest | Refused:
        nonces.prune(unix_s)
        if req.key_id != key_id:
            return Refused(RetaskRefusal.BAD_SIGNATURE, f"the body names key {req.key_id}, "
                           f"the envelope {key_id}", req.plan_hash)
        if req.vehicle_id != self.vehicle_id:
            return Refused(RetaskRefusal.WRONG_VEHICLE, f"signed for vehicle "
                           f"{req.vehicle_id!r}, this is {self.vehicle_id!r}", req.plan_hash)
        age_s = unix_s - req.issued_unix_s
        if abs(age_s) > self.window_s:
            when = f"{age_s:.0f} s ago" if age_s > 0 else f"{-age_s:.0f} s in the future"
            return Refused(RetaskRefusal.STALE, f"issued {when}, the window is "
                           f"±{self.window_s:g} s of the vehicle's clock", req.plan_hash)
        if req.nonce in nonces:
            return Refused(RetaskRefusal.REPLAYED, f"nonce {req.nonce} was seen before",
                           req.plan_hash)
        if len(nonces) >= MAX_NONCES:
            return Refused(RetaskRefusal.BUSY, f"{MAX_NONCES} requests in the last "
                           f"{self.window_s:g} s: wait", req.plan_hash)
        nonces.add(req.nonce, req.issued_unix_s + self.window_s)
        return req

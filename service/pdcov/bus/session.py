"""The mission config's ``bus`` section and the Zenoh session it opens.

``bus`` (docs/protocol.md "Session"): mode auto | peer | client | router (default auto:
a client when it connects somewhere and listens nowhere, else a peer; see
``resolve_mode``), connect and
listen endpoint lists (``tcp/10.0.0.2:7447``, ``tls/...``, ``quic/...``; the session listens
on the configured ones only, none by default), multicast_scouting (default true; false keeps
a session from announcing itself on the LAN), config_file (a Zenoh JSON5 config read first,
relative to the mission config's folder), zenoh (a mapping of Zenoh config paths to
values, inserted last: TLS certificates, access_control, anything Zenoh takes), and the
publishing options status_period_s, tiles_period_s, tile_size, tiles_max_bytes_per_s.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from enum import Enum
from pathlib import Path
from typing import Any

from pdcov.errors import ConfigError, where
from pdcov.schema import Section, check_keys

MODES = ("auto", "peer", "client", "router")
_ZENOH_DEFAULT_LISTEN = '{"router":["tcp/[::]:7447"],"peer":["tcp/[::]:0"]}'
"""zenoh.Config().get_json("listen/endpoints") of Zenoh 1.x: a config that leaves it so
names no listen endpoint of its own."""


@dataclass(frozen=True, slots=True)
class BusConfig:
    """How the daemon talks Zenoh: session (mode, endpoints, scouting, extra Zenoh config)
    and publishing (status every status_period_s s, changed tiles every tiles_period_s s in
    tiles of tile_size cells, at most tiles_max_bytes_per_s bytes/s of tiles on average)."""

    mode: str = "auto"
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    multicast_scouting: bool = True
    config_file: str | None = None
    zenoh: Mapping[str, Any] = field(default_factory=dict)
    status_period_s: float = 1.0
    tiles_period_s: float = 0.2
    tile_size: int = 32
    tiles_max_bytes_per_s: int = 65536

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ConfigError(f"bus.mode: expected one of {', '.join(MODES)}, got "
                              f"{self.mode!r}")
        for name in ("status_period_s", "tiles_period_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f"bus.{name}: expected seconds > 0, got {v!r}")
        if not (isinstance(self.tile_size, int) and 4 <= self.tile_size <= 1024):
            raise ConfigError(f"bus.tile_size: expected cells 4..1024, got {self.tile_size!r}")
        if not (isinstance(self.tiles_max_bytes_per_s, int)
                and self.tiles_max_bytes_per_s >= 1024):
            raise ConfigError(f"bus.tiles_max_bytes_per_s: expected bytes/s >= 1024, got "
                              f"{self.tiles_max_bytes_per_s!r}")
        for name in ("connect", "listen"):
            for e in getattr(self, name):
                check_endpoint(e, f"bus.{name}", listen=name == "listen")

    def with_endpoints(self, connect: tuple[str, ...] | None,
                       listen: tuple[str, ...] | None) -> BusConfig:
        """The config with command-line endpoints (checked, and named by their options)
        in place of the configured ones."""
        for option, given in (("--zenoh-connect", connect), ("--zenoh-listen", listen)):
            for e in given or ():
                check_endpoint(e, option, listen=option == "--zenoh-listen")
        return replace(self, connect=self.connect if connect is None else tuple(connect),
                       listen=self.listen if listen is None else tuple(listen))


IP_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws")
"""Zenoh's link protocols addressed HOST:PORT."""
OTHER_PROTOCOLS = ("unixsock-stream", "unixsock-seqpacket", "unixpipe", "serial", "vsock")


def check_endpoint(endpoint: object, what: str, *, listen: bool) -> None:
    """ConfigError naming ``what`` (option or config key) when ``endpoint`` is not
    PROTOCOL/ADDRESS of a Zenoh link protocol, with HOST:PORT for the IP ones (port 0 to
    listen on a free one; an IPv6 host in brackets); checked before Zenoh sees it."""
    example = "tcp/192.168.1.10:7447"
    if not isinstance(endpoint, str):
        raise ConfigError(f"{what}: expected an endpoint such as {example}, got {endpoint!r}")
    proto, _, rest = endpoint.partition("/")
    address = rest.split("?", 1)[0].split("#", 1)[0]
    if proto in OTHER_PROTOCOLS and address:
        return
    if proto not in IP_PROTOCOLS:
        raise ConfigError(f"{what}: endpoint {endpoint!r}: expected PROTOCOL/ADDRESS such as "
                          f"{example}, the protocol one of {', '.join(IP_PROTOCOLS)} (or "
                          f"{', '.join(OTHER_PROTOCOLS)})")
    host, _, port = address.rpartition(":")
    lowest = 0 if listen else 1
    bracketed = host.startswith("[") and host.endswith("]")
    if (not host or (":" in host and not bracketed) or any(c.isspace() for c in host)
            or not port.isdigit() or not lowest <= int(port) <= 65535):
        raise ConfigError(f"{what}: endpoint {endpoint!r}: expected {proto}/HOST:PORT with a "
                          f"port in {lowest}..65535 (IPv6: {proto}/[::1]:7447)")


def bus_config_from_dict(doc: Any, source: str | None = None) -> BusConfig:
    """Validate the ``bus`` section (a mapping, or None for the defaults)."""
    if doc is None:
        return BusConfig()
    if not isinstance(doc, Mapping):
        raise ConfigError(f"{where(source, 'bus')}: expected a mapping")
    # The keys are BusConfig's fields (the daemon's schema reads the same dataclass).
    check_keys(dict(doc), Section.of_dataclass(BusConfig), source, "bus")
    kw = dict(doc)
    for name in ("connect", "listen"):
        if name in kw:
            v = kw[name]
            if isinstance(v, str):
                v = [v]
            if not isinstance(v, list) or not all(isinstance(e, str) for e in v):
                raise ConfigError(f"{where(source, 'bus.' + name)}: expected a list of "
                                  "endpoints such as tcp/192.168.1.10:7447")
            kw[name] = tuple(v)
    if "multicast_scouting" in kw and not isinstance(kw["multicast_scouting"], bool):
        raise ConfigError(f"{where(source, 'bus.multicast_scouting')}: expected true or false")
    if "zenoh" in kw and not isinstance(kw["zenoh"], Mapping):
        raise ConfigError(f"{where(source, 'bus.zenoh')}: expected a mapping of Zenoh config "
                          "paths (e.g. transport/link/tls/root_ca_certificate) to values")
    if isinstance(kw.get("config_file"), str) and source is not None:
        # As the mission's other files: relative to the config file's folder.
        kw["config_file"] = str(Path(source).parent / kw["config_file"])
    try:
        return BusConfig(**kw)
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}" if source else str(exc)) from None


def resolve_mode(mode: str, connect: list[str], listen: list[str]) -> str:
    """The Zenoh mode a session of ``bus.mode`` opens in, given its effective connect and
    listen endpoints: ``auto`` is a client when it connects somewhere and listens nowhere,
    else a peer; any other mode is itself.

    Why (Zenoh >= 1.9, "regions"): a router puts the peers connected to it in one
    peer-to-peer region, whose members must reach each other directly (the router only
    tells them each other's listen endpoints by gossip, and no longer brokers between them:
    routing/router/peers_failover_brokering was removed in 1.9). Two peers that only
    connect to a router and listen nowhere therefore exchange nothing, through one router
    or several. A client is in a region of its own that the router brokers, so it reaches
    everyone; a peer that listens is reached by the other peers. Without endpoints a peer
    finds others by multicast scouting (one LAN, no router)."""
    if mode != "auto":
        return mode
    return "client" if connect and not listen else "peer"


def _endpoints(conf: Any, name: str, mode: str | None = None) -> list[str]:
    """The ``connect`` or ``listen`` endpoints of a zenoh.Config for a session of ``mode``
    (Zenoh accepts a list, or a list per mode; None or auto: the config's own mode, else
    peer)."""
    listed = json.loads(conf.get_json(f"{name}/endpoints") or "[]")
    if isinstance(listed, dict):
        if mode in (None, "auto"):
            mode = json.loads(conf.get_json("mode") or '"peer"')
        listed = listed.get(mode, [])
    return [e for e in listed if isinstance(e, str)] if isinstance(listed, list) else [listed]


def session_mode(bus: BusConfig) -> str:
    """The mode ``bus``'s session opens in (resolve_mode on its effective endpoints)."""
    return str(json.loads(zenoh_config(bus).get_json("mode")))


def peer_warning(bus: BusConfig) -> str | None:
    """What to tell the operator when ``bus`` opens a peer that connects somewhere and
    listens nowhere (resolve_mode: through a router it reaches clients and listening peers
    only), else None."""
    conf = zenoh_config(bus)
    connect, listen = _endpoints(conf, "connect"), _endpoints(conf, "listen")
    if json.loads(conf.get_json("mode")) != "peer" or not connect or listen:
        return None
    return (f"bus.mode peer connecting to {', '.join(connect)} and listening nowhere: "
            "through a router this session reaches only clients and peers that listen, "
            "not another peer that listens nowhere (Zenoh >= 1.9); use mode auto or client, "
            "or listen on an endpoint the other side can reach")


def describe_session(bus: BusConfig) -> str:
    """One line for a startup log: mode as opened (and as configured when auto), endpoints
    and multicast scouting, e.g. ``client (auto), connect [tcp/10.0.0.2:7447], listen [],
    multicast scouting off``."""
    conf = zenoh_config(bus)
    mode = json.loads(conf.get_json("mode"))
    return (f"{mode}{' (auto)' if bus.mode == 'auto' else ''}, connect "
            f"[{', '.join(_endpoints(conf, 'connect'))}], listen "
            f"[{', '.join(_endpoints(conf, 'listen'))}], multicast scouting "
            f"{'on' if bus.multicast_scouting else 'off'}")


def quiet_hint(bus: BusConfig) -> str:
    """Why a watcher on ``bus`` may hear no vehicle: what its session does and what the
    daemons must do to be heard (docs/ground-station.md "Topologies")."""
    conf = zenoh_config(bus)
    mode = json.loads(conf.get_json("mode"))
    connect = _endpoints(conf, "connect")
    session = f"this session: {describe_session(bus)}"
    if mode == "client":
        return (f"{session}: is a daemon running with the same router (or a router linked "
                "to it) in its bus.connect, and the --vehicle id right?")
    if connect:
        return (f"{session}: a daemon that is a peer listening nowhere is not heard through "
                "a router; use --mode client (the default with --zenoh-connect) or "
                "--zenoh-listen")
    if bus.multicast_scouting:
        return (f"{session}: multicast scouting finds daemons on this LAN only, and only "
                "those that listen (bus.listen); give --zenoh-connect ROUTER or the "
                "daemon's endpoint otherwise")
    return (f"{session}: with no endpoint and multicast scouting off, only a daemon that "
            "connects to this session's --zenoh-listen endpoint is heard")


def zenoh_config(bus: BusConfig, connect_timeout_s: float | None = None):  # -> zenoh.Config
    """The zenoh.Config for ``bus``: the config file (if any), then endpoints, mode
    (resolve_mode) and scouting, then each ``bus.zenoh`` path. The session listens on
    ``bus.listen`` only (or on the config file's listen endpoints when it names some and
    ``bus.listen`` is empty): never on Zenoh's default. ``connect_timeout_s``: how long a
    client's open waits for a router (None: until one answers). Zenoh's own errors become
    ConfigError."""
    import zenoh

    doing = "the defaults"
    try:
        if bus.config_file:
            doing = f"the config file {bus.config_file} (--zenoh-config, bus.config_file)"
        conf = zenoh.Config.from_file(bus.config_file) if bus.config_file else zenoh.Config()
        doing = "the endpoints, mode and scouting"
        if bus.connect:
            conf.insert_json5("connect/endpoints", json.dumps(list(bus.connect)))
        if bus.listen or conf.get_json("listen/endpoints") == _ZENOH_DEFAULT_LISTEN:
            # Only where configured: Zenoh's default listens in peer mode on a random TCP
            # port of every interface, in plain text, where peers reach it past a
            # router's access control (docs/protocol.md "Session").
            conf.insert_json5("listen/endpoints", json.dumps(list(bus.listen)))
        mode = resolve_mode(bus.mode, _endpoints(conf, "connect", bus.mode),
                            _endpoints(conf, "listen", bus.mode))
        conf.insert_json5("mode", json.dumps(mode))
        if mode == "client" and connect_timeout_s is not None:
            # A client's open waits for a router (Zenoh >= 1.9: connect/timeout_ms -1);
            # bounded here, it fails instead and the caller tries again.
            conf.insert_json5("connect/timeout_ms", json.dumps(int(connect_timeout_s * 1000)))
        if not bus.multicast_scouting:
            conf.insert_json5("scouting/multicast/enabled", "false")
        for path, value in bus.zenoh.items():
            doing = f"bus.zenoh {path}: {json.dumps(value)}"
            conf.insert_json5(str(path), json.dumps(value))
    except Exception as exc:  # noqa: BLE001 - zenoh raises its own ZError for any bad value
        raise ConfigError(f"bus: Zenoh refuses the session config, at {doing}: "
                          f"{zenoh_text(exc)} (the keys and values Zenoh takes: its "
                          "DEFAULT_CONFIG.json5)") from None
    return conf


def open_session(bus: BusConfig, connect_timeout_s: float | None = None):  # -> zenoh.Session
    """Open a Zenoh session for ``bus`` (close it with ``.close()`` before exiting). A
    client's open waits for one of its connect endpoints to answer, at most
    ``connect_timeout_s`` (None: for ever); once open, a client or peer rejoins a router
    that restarts by itself."""
    import zenoh

    conf = zenoh_config(bus, connect_timeout_s)
    try:
        return zenoh.open(conf)
    except Exception as exc:  # noqa: BLE001 - zenoh raises its own ZError
        raise ConfigError(open_refusal(bus, zenoh_text(exc))) from None


def zenoh_text(exc: BaseException) -> str:
    """A Zenoh error's text without the Rust source locations and debug wrappers it
    carries (``Str("unknown key")``, ``Json5Err(Message { msg: "..." ...})``,
    ``Error("...", line: 1, ...)``)."""
    text = re.sub(r"\s*at /\S+\.rs:\d+\.?", "", str(exc)).strip()
    inner = re.search(r'(?:^Str\(|msg: |Error\()"((?:[^"\\]|\\.)*)"', text)
    if inner is None:
        return text
    try:
        return str(json.loads(f'"{inner.group(1)}"'))
    except ValueError:  # an escape JSON does not share with Rust's Debug
        return inner.group(1)


def open_refusal(bus: BusConfig, reason: str) -> str:
    """One line for a session that did not open (``reason``: zenoh_text of Zenoh's error):
    what failed, on which endpoints, and what to do."""
    connect = _endpoints(zenoh_config(bus), "connect")
    opening = f"bus: cannot open the Zenoh session ({describe_session(bus)})"
    if "Unable to connect" in reason and connect:
        how = "no answer in time" if "Timeout" in reason else "refused or unreachable"
        tls = ("; with tls/ or quic/, the certificates (--zenoh-config)"
               if any(e.startswith(("tls/", "quic/")) for e in connect) else "")
        return (f"{opening}: nothing answers at {', '.join(connect)} ({how}): check that "
                f"the router (zenohd) or the daemon listening there runs, the address, the "
                f"port and the firewall{tls}; or give another --zenoh-connect")
    failed = re.search(r"listener bound to (\S+?):? \[.*?: ([^\[\]]+?)(?: \(os error \d+\))?\]",
                       reason)
    if failed is not None:
        return (f"{opening}: cannot listen on {failed.group(1)}: {failed.group(2)}: give "
                "an address of this machine and a port nothing else holds (--zenoh-listen)")
    return f"{opening}: {reason}"


class BusSecurity(Enum):
    """What this session's own config says about who else can write on the bus (the
    router's access control, if any, is not visible from here)."""

    OPEN = "open"  # a plain-text link or scouting: any participant, any key
    TLS = "tls"  # every link TLS/QUIC, but this side does not require client certificates
    MUTUAL_TLS = "mutual-tls"  # every link TLS/QUIC with certificates on both sides

    @property
    def warning(self) -> str | None:
        """The line the ground station shows all the time, or None when secured."""
        if self is BusSecurity.OPEN:
            return ("bus not secured (plain links, no certificates): anyone who reaches it "
                    "can publish coverage as any vehicle; use mutual TLS with access control "
                    "(docs/ground-station.md \"Securing the bus\")")
        if self is BusSecurity.TLS:
            return ("bus encrypted but sessions not authenticated (TLS without client "
                    "certificates): anyone who reaches the router can publish coverage "
                    "unless its access control stops them (docs/ground-station.md "
                    "\"Securing the bus\")")
        return None


_SECURE_PROTOCOLS = ("tls/", "quic/")


def bus_security(bus: BusConfig) -> BusSecurity:
    """How far ``bus``'s session keeps others out: MUTUAL_TLS when every connect and listen
    endpoint is TLS or QUIC, multicast scouting is off and the Zenoh config enables mTLS;
    TLS without the mTLS setting; OPEN otherwise (a plain endpoint, or none at all with
    multicast scouting, which finds peers over plain TCP)."""
    conf = zenoh_config(bus)
    endpoints = _endpoints(conf, "connect") + _endpoints(conf, "listen")
    scouting = json.loads(conf.get_json("scouting/multicast/enabled") or "null")
    if (not endpoints or scouting is not False
            or not all(isinstance(e, str) and e.startswith(_SECURE_PROTOCOLS)
                       for e in endpoints)):
        return BusSecurity.OPEN
    mtls = json.loads(conf.get_json("transport/link/tls/enable_mtls") or "null")
    return BusSecurity.MUTUAL_TLS if mtls is True else BusSecurity.TLS

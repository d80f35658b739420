"""MAVLink link URLs: the forms pdcov takes, checked before anything is opened (a malformed
one is refused in one line, not retried for ever), and what pymavlink opens for each.

    udpin:HOST:PORT, udp:HOST:PORT    listen for the autopilot on HOST:PORT
    udpout:HOST:PORT                  send to HOST:PORT (the autopilot listens)
    tcp:HOST:PORT                     connect to a TCP server (SITL, a telemetry bridge)
    serial:DEVICE:BAUD, DEVICE,BAUD   a serial port (DEVICE an absolute path), or DEVICE
                                      alone at pymavlink's 115200 baud

The tools that open the link through pymavlink alone (``pdcov upload``, ``pdcov
mount-check``) also take tcpin:HOST:PORT and udpbcast:HOST:PORT (TOOL_SCHEMES); the daemon,
which reads its sockets itself, does not (DAEMON_SCHEMES). HOST is a name or an IPv4
address (pymavlink splits at ':'), PORT 1..65535 (0 too to listen: any free port).
"""

from __future__ import annotations

from pdcov.errors import ConfigError

__all__ = ["DAEMON_SCHEMES", "TOOL_SCHEMES", "check_link_url", "link_url_problem",
           "pymavlink_device"]

DAEMON_SCHEMES = ("udpin", "udp", "udpout", "tcp")
TOOL_SCHEMES = (*DAEMON_SCHEMES, "tcpin", "udpbcast")
_LISTENING = ("udpin", "udp", "tcpin")
"""Schemes that listen: port 0 is any free one (what the tests use)."""
_SERIAL = "serial:"


def _forms(schemes: tuple[str, ...]) -> str:
    return (", ".join(f"{s}:HOST:PORT" for s in schemes)
            + ", serial:/dev/DEVICE:BAUD, /dev/DEVICE,BAUD or /dev/DEVICE")


def _is_device(path: str) -> bool:
    return path.startswith("/") and len(path) > 1 and not any(c.isspace() for c in path)


def link_url_problem(url: str, schemes: tuple[str, ...] = DAEMON_SCHEMES) -> str | None:
    """Why ``url`` is not a link URL of ``schemes`` or a serial device (one line naming
    it and the forms taken), or None when it is one."""
    scheme, sep, address = url.partition(":")
    if sep and scheme in schemes:
        host, _, port = address.rpartition(":")
        lowest = 0 if scheme in _LISTENING else 1
        if (not host or ":" in host or any(c.isspace() for c in host)
                or not port.isdigit() or not lowest <= int(port) < 65536):
            return f"expected {scheme}:HOST:PORT with a port in {lowest}..65535, got {url!r}"
        return None
    if url.startswith(_SERIAL):
        device, baud = pymavlink_device(url)
        if _is_device(device) and (baud is None or baud > 0):
            return None
        return (f"expected serial:/dev/DEVICE:BAUD (an absolute path, a baud rate such as "
                f"921600), got {url!r}")
    device, baud = pymavlink_device(url)
    if _is_device(device) and (baud is None or baud > 0) and "," not in device:
        return None
    return f"unknown connection {url!r}: expected one of {_forms(schemes)}"


def check_link_url(url: str, what: str, schemes: tuple[str, ...] = DAEMON_SCHEMES) -> str:
    """``url`` when link_url_problem finds none, else ConfigError naming ``what`` (the option
    or config key it came from)."""
    problem = link_url_problem(url, schemes) if isinstance(url, str) else \
        f"expected a URL, got {url!r}"
    if problem is not None:
        raise ConfigError(f"{what}: {problem}")
    return url


def pymavlink_device(url: str) -> tuple[str, int | None]:
    """(device or URL for mavutil, baud or None) of a checked URL: ``serial:/dev/x:921600``
    and ``/dev/x,921600`` name a serial device and its baud rate."""
    if url.startswith(_SERIAL):
        dev, _, baud = url[len(_SERIAL):].rpartition(":")
        if dev and baud.isdigit():
            return dev, int(baud)
        return url[len(_SERIAL):], None
    if "," in url and url.split(":", 1)[0] not in TOOL_SCHEMES:
        dev, _, baud = url.rpartition(",")
        if baud.isdigit():
            return dev, int(baud)
    return url, None

"""sd_notify(3) without libsystemd: READY/WATCHDOG/STATUS/STOPPING datagrams to $NOTIFY_SOCKET.

systemd sets NOTIFY_SOCKET for a Type=notify unit (an abstract socket when it starts with '@')
and WATCHDOG_USEC (with WATCHDOG_PID) when WatchdogSec= is set. Outside systemd both are unset
and every call is a no-op, so the daemon calls these unconditionally.
"""

from __future__ import annotations

import logging
import os
import socket  # the notify socket: an I/O edge of the daemon
from collections.abc import Mapping

log = logging.getLogger(__name__)


class SystemdNotifier:
    """Sends sd_notify messages; never raises (a failed send is logged and returns False)."""

    def __init__(self, environ: Mapping[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        path = env.get("NOTIFY_SOCKET", "")
        # '@name' is Linux's abstract namespace: the address starts with a NUL byte.
        self._address = "\0" + path[1:] if path.startswith("@") else path
        usec = env.get("WATCHDOG_USEC", "")
        pid = env.get("WATCHDOG_PID", "")
        ours = not pid or pid == str(os.getpid())
        # sd_watchdog_enabled(3): ping at half the timeout so one late tick is not fatal.
        self.watchdog_interval_s: float | None = (
            int(usec) / 2e6 if usec.isdigit() and int(usec) > 0 and ours else None
        )
        self._sock: socket.socket | None = None

    @property
    def enabled(self) -> bool:
        return bool(self._address)

    def notify(self, **fields: str) -> bool:
        """Send KEY=value lines (``notify(READY="1", STATUS="...")``); newlines in a value
        become spaces, as the protocol is one assignment per line."""
        if not self._address or not fields:
            return False
        text = "\n".join(f"{k}={' '.join(str(v).splitlines())}" for k, v in fields.items())
        try:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            self._sock.sendto(text.encode(), socket.MSG_DONTWAIT, self._address)
        except OSError as exc:
            log.warning("sd_notify to %r failed: %s", self._address.replace("\0", "@"), exc)
            return False
        return True

    def ready(self, status: str | None = None) -> bool:
        return self.notify(READY="1", **({"STATUS": status} if status else {}))

    def watchdog(self) -> bool:
        return self.notify(WATCHDOG="1")

    def status(self, text: str) -> bool:
        return self.notify(STATUS=text)

    def stopping(self, status: str | None = None) -> bool:
        return self.notify(STOPPING="1", **({"STATUS": status} if status else {}))

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

"""A plain HTTP GET of the web map (status, headers, cookies, body) and its token, for the
tests of its access rules."""

from __future__ import annotations

import http.client

TOKEN = "s3cret-Token_of.the~map-0123456789"


def get(port: int, path: str, headers: dict[str, str] | None = None,
        ) -> tuple[int, dict[str, str], list[str], bytes]:
    """status, headers (last of each name), every Set-Cookie, body (the first chunk of an
    event stream)."""
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        c.request("GET", path, headers=headers or {})
        r = c.getresponse()
        stream = r.getheader("Content-Type", "").startswith("text/event-stream")
        body = r.read1(65536) if stream else r.read()
        while stream and not body.endswith(b"\n\n"):
            body += r.read1(65536)
        return r.status, dict(r.getheaders()), r.headers.get_all("Set-Cookie") or [], body
    finally:
        c.close()

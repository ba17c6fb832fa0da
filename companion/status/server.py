"""The live status page's web server (aiohttp), run in the companion's own event loop (docs/design.md,
"The status page").

Read-only by construction: three GET routes (the page, its script, the event stream), nothing that reaches the
vehicle. Bound to loopback unless told otherwise; any other address needs a token, and then every request must
carry it (``Authorization: Bearer``, ``?token=`` or the cookie the page gets with it), or it gets 401 and nothing
else.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import ipaddress
import logging
import socket
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from aiohttp import web

from companion.status.hub import StatusHub
from planner.errors import FuseplanError

log = logging.getLogger(__name__)
DEFAULT_HOST = "127.0.0.1"
COOKIE = "fuseplan_status"
SHUTDOWN_S = 1.0  # how long a stopping server waits for a browser that stopped reading
_HEADERS = {
    "Cache-Control": "no-store",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",  # the token may be in the page's address
    "Content-Security-Policy": "default-src 'none'; script-src 'self'; style-src 'self'; connect-src 'self'; "
                               "img-src 'self' data:; frame-ancestors 'none'; base-uri 'none'; form-action 'none'",
}
_FILES = {"/": ("page.html", "text/html"), "/page.js": ("page.js", "text/javascript"),
          "/page.css": ("page.css", "text/css")}


@dataclass(frozen=True)
class Bind:
    """Where the page is served: ``host`` and ``port`` (0: any free port)."""

    host: str
    port: int

    @classmethod
    def parse(cls, text: str) -> Bind:
        """``PORT``, ``HOST:PORT`` or ``[IPv6]:PORT``; the host defaults to loopback."""
        host, sep, port = text.rpartition(":")
        host = host.strip("[]") if sep else DEFAULT_HOST
        try:
            number = int(port)
        except ValueError:
            number = -1
        if not 0 <= number <= 65535 or (sep and not host):
            raise FuseplanError(f"--status-page {text!r}: expected PORT or HOST:PORT (e.g. 8765 or 0.0.0.0:8765)")
        return cls(host, number)

    def check_free(self) -> None:
        """Fail now, in one line, if the address cannot be listened on (before a flight is planned for it); the
        server binds again when it starts."""
        if self.port == 0:
            return
        try:
            infos = socket.getaddrinfo(self.host, self.port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
            with socket.socket(infos[0][0], socket.SOCK_STREAM) as probe:
                probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server does
                probe.bind(infos[0][4])
        except OSError as e:
            raise self.cannot_listen(e) from e

    def cannot_listen(self, e: OSError) -> FuseplanError:
        return FuseplanError(f"--status-page {self.host}:{self.port}: cannot listen: {e.strerror or e}")

    @property
    def loopback(self) -> bool:
        if self.host == "localhost":
            return True
        try:
            return ipaddress.ip_address(self.host).is_loopback
        except ValueError:  # a host name: it may resolve to anything
            return False


def read_token(path: Path | None, bind: Bind) -> str | None:
    """The token in ``path`` (its first line, at least 16 characters); required when ``bind`` is not loopback."""
    if path is None:
        if not bind.loopback:
            raise FuseplanError(f"--status-page {bind.host}:{bind.port} is reachable from other machines: give "
                                "--status-token FILE (a file holding a secret of 16 characters or more)")
        return None
    try:
        lines = path.read_text().strip().splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise FuseplanError(f"{path}: cannot read the status token: {getattr(e, 'strerror', None) or e}") from e
    token = lines[0].strip() if lines else ""
    if len(token) < 16:
        raise FuseplanError(f"{path}: the status token must be 16 characters or more on its first line")
    return token


def _authorised(request: web.Request, token: str) -> bool:
    offered = [request.query.get("token", ""), request.cookies.get(COOKIE, "")]
    auth = request.headers.get("Authorization", "")
    if auth.startswith("Bearer "):
        offered.append(auth[7:])
    ok = False
    for candidate in offered:  # every candidate compared, in constant time
        ok |= hmac.compare_digest(candidate.encode(), token.encode())
    return ok


def make_app(hub: StatusHub, token: str | None = None) -> web.Application:
    """The page (``/``, ``/page.js``, ``/page.css``) and its event stream (``/events``), GET only."""

    @web.middleware
    async def guard(request: web.Request, handler: object) -> web.StreamResponse:
        if token is not None and not _authorised(request, token):
            return web.Response(status=401, text="401: this status page needs its token\n",
                                headers={**_HEADERS, "WWW-Authenticate": 'Bearer realm="fuseplan status"'})
        if request.method not in ("GET", "HEAD"):
            return web.Response(status=405, text="405: this page is read-only\n",
                                headers={**_HEADERS, "Allow": "GET, HEAD"})
        resp = await handler(request)  # type: ignore[operator]
        if not resp.prepared:  # the event stream has sent its headers already, and set the cookie itself
            remember_token(request, resp)
        return resp

    def remember_token(request: web.Request, resp: web.StreamResponse) -> None:
        """A request authorised by ``?token=`` leaves the cookie, so the page's own requests carry it (before
        the response's headers go out: aiohttp turns cookies into headers then)."""
        if token is not None and request.query.get("token"):
            resp.set_cookie(COOKIE, token, httponly=True, samesite="Strict")

    async def static(request: web.Request) -> web.Response:
        name, kind = _FILES[request.path]
        body = resources.files("companion.status").joinpath(name).read_bytes()
        return web.Response(body=body, content_type=kind, headers=_HEADERS)

    async def events(request: web.Request) -> web.StreamResponse:
        resp = web.StreamResponse(headers={**_HEADERS, "Content-Type": "text/event-stream",
                                           "X-Accel-Buffering": "no"})
        remember_token(request, resp)
        await resp.prepare(request)
        with contextlib.suppress(ConnectionError):  # the browser went away: its reader ends here, nothing else
            async for chunk in hub.read():
                await resp.write(chunk)
        return resp

    app = web.Application(middlewares=[guard])
    for path in _FILES:
        app.router.add_get(path, static)
    app.router.add_get("/events", events)
    return app


class StatusServer:
    """``async with StatusServer(hub, bind, token) as server:`` serves the page at ``server.url`` until the block
    ends; then the hub closes and browsers that stopped reading are cut after :data:`SHUTDOWN_S`."""

    def __init__(self, hub: StatusHub, bind: Bind, token: str | None = None) -> None:
        if token is None and not bind.loopback:
            raise FuseplanError(f"{bind.host}: serving beyond loopback needs a token")
        self.hub, self.bind, self.token = hub, bind, token
        self._runner: web.AppRunner | None = None
        self.port = bind.port

    @property
    def url(self) -> str:
        host = f"[{self.bind.host}]" if ":" in self.bind.host else self.bind.host
        return f"http://{host}:{self.port}/"

    async def __aenter__(self) -> StatusServer:
        self.hub.bind(asyncio.get_running_loop())
        self._runner = web.AppRunner(make_app(self.hub, self.token), access_log=None,
                                     handle_signals=False, shutdown_timeout=SHUTDOWN_S)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.bind.host, self.bind.port)
        try:
            await site.start()
        except OSError as e:
            await self._runner.cleanup()
            raise self.bind.cannot_listen(e) from e
        sockets = self._runner.addresses
        self.port = int(sockets[0][1]) if sockets else self.bind.port
        log.info("status page on %s", self.url)
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.hub.close()
        if self._runner is not None:
            await self._runner.cleanup()

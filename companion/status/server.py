"""The live status page's web server: a small HTTP/1.1 server on asyncio streams, run in the companion's own
event loop (docs/design.md, "The status page").

Read-only by construction: GET and HEAD on four paths (the page, its script and style, the event stream), nothing
that reaches the vehicle. Bound to loopback unless told otherwise; any other address needs a token, and then every
request must carry it (``Authorization: Bearer``, ``?token=`` or the cookie the page gets with it), or it gets 401
and nothing else.

The page shares the flight's process, loop and file descriptors, so whoever can reach its port must not be able to
take from the flight what it needs. Hence these limits (each held by a test in
tests/companion/status/test_server_limits.py, named below where it is not obvious which):

- At most :data:`MAX_CONNECTIONS` connections at once, event streams and requests being read alike; one more is
  accepted and closed at once, unread, and counted in :attr:`StatusServer.refused` (one warning, not one per
  connection). The page never holds more file descriptors than that and its listening sockets: 300 connections
  to a companion limited to 256 descriptors used to abort its flight ("Too many open files").
- At most :data:`MAX_PENDING` of them still reading their request head, which is all a connection without the
  token ever gets, so silent connections cannot take the event streams' slots. While that budget is full, new
  connections wait in the kernel's queue (no descriptor, nothing read), and the one that has waited longest for
  its head is cut once it has had :data:`PENDING_GRACE_S` (a browser sends its head in the packet after the
  handshake), counted in :attr:`StatusServer.timed_out` with one warning
  (``test_silent_connections_cannot_take_the_slots_of_browsers``).
- :data:`HEAD_TIMEOUT_S` to send the whole request line and headers, at most :data:`MAX_HEAD_BYTES` of them; a
  connection that sends less in that time (a port scan, a slow loris) is closed and counted in
  :attr:`StatusServer.timed_out`, one that sends more gets 431.
- Every answer closes its connection (no keep-alive) except an authorised event stream, the only thing that stays:
  without the token, a connection costs one short read and a 401. Answers other than the stream are given
  :data:`ANSWER_TIMEOUT_S` to be taken, then cut.
- A stream whose browser takes nothing for :data:`STREAM_STALL_S` (its socket buffers full) is cut and counted in
  :attr:`StatusServer.stalled`; a browser that is still there reconnects (EventSource does) and gets the ``reset``
  and the whole flight again, so nothing is lost
  (``test_a_stream_that_takes_nothing_is_cut_and_its_slot_comes_back``). Every accepted socket has
  ``SO_KEEPALIVE`` and, on Linux, ``TCP_USER_TIMEOUT`` of :data:`USER_TIMEOUT_S`: the kernel drops a connection
  whose data goes unacknowledged that long (a phone that left the Wi-Fi without a FIN)
  (``test_accepted_connections_have_keepalive_and_a_user_timeout``).
- The request is decoded as Latin-1, which cannot fail (every byte is a character); a malformed one gets 400, and
  so does a head with a CR, LF or NUL inside a line (split on CRLF: nothing for a proxy in front to read
  differently); a head that ends in bare LFs gets its 400 at once rather than waiting for the CRLF that never comes
  (``test_bare_line_ends_and_nul_in_a_head_get_400_at_once``).
- ``Host`` must name this page (a DNS-rebinding page names its own domain): on a loopback bind only 127.0.0.1,
  localhost, ::1, the bind address and the names the caller allows (:attr:`Bind.allowed_hosts`, from
  ``--status-host NAME``: a reverse proxy's on this machine); elsewhere also the address the connection arrived at
  (for a bind to 0.0.0.0 or ::) and the machine's host name (``name``, ``name.local``; no DNS lookup)
  (``test_status_host_names_from_the_command_line_are_served``). With any port or none: a reverse proxy may
  forward another. Anything else gets 421 (Misdirected Request: not this server's name) and nothing more. Without
  ``Host``, HTTP/1.1 is a 400 (RFC 9112 §3.2); HTTP/1.0 is served on a loopback bind (no browser sends a request
  without one, so it cannot be a rebinding page) and refused (421) elsewhere, where nothing legitimate needs it.
- Every answer, 4xx included, carries ``Cache-Control: no-store`` and the headers of :data:`_HEADERS`.
- Nothing the page does raises into the flight's loop. An accept that fails for that one connection (ECONNABORTED,
  EPROTO, EHOSTUNREACH...: it went before it was accepted) is skipped. Any other failure pauses accepting for
  :data:`ACCEPT_RETRY_S` and is logged at most every :data:`WARN_EVERY_S`: out of descriptors (EMFILE, ENFILE),
  which frees up in time, and anything else, which may fail again on every call and would otherwise spin a core
  the flight needs (``test_an_accept_without_descriptors_is_logged_once_and_the_page_recovers``,
  ``test_a_listening_socket_that_fails_is_warned_once_and_accepting_goes_on``). Anything unexpected in a
  connection ends that one connection, logged likewise. (asyncio's own accept loop, which aiohttp used here
  before, logs a traceback for each of up to its backlog retries on EMFILE: 6 800 tracebacks, 2.8 MB of stderr in
  the 6 s of flight that were left, measured with 300 connections under a 256-descriptor limit.)
- Stopping cancels at once the connections still sending their head or being answered; event streams end after
  what they were sent, or are cut after :data:`SHUTDOWN_S`
  (``test_stopping_waits_for_no_connection_sending_its_head``).

The server is its own (this module, over asyncio streams) rather than aiohttp's because aiohttp has no
request-head timeout, answers its parser's 400s outside any middleware (so without ``no-store``), keeps a
connection it answered 401 alive, and accepts through asyncio's accept loop (above).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import hmac
import ipaddress
import json
import logging
import re
import socket
import time
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from http import HTTPStatus
from importlib import resources
from pathlib import Path
from urllib.parse import parse_qsl, quote, unquote_to_bytes

from companion.mavlink.signing import read_secret
from companion.mission.events import Event
from companion.status.hub import StatusHub
from planner.errors import FuseplanError

log = logging.getLogger(__name__)
DEFAULT_HOST = "127.0.0.1"
COOKIE = "fuseplan_status"
MAX_CONNECTIONS = 64  # open at once: 50 browsers' streams and their page loads fit (the flight test's load)
MAX_PENDING = 16  # of them still reading their request head (all a connection without the token ever gets)
HEAD_TIMEOUT_S = 5.0  # to send the request line and headers (a browser sends them in one packet)
PENDING_GRACE_S = 1.0  # the head timeout of the longest waiting connection while MAX_PENDING are waiting
MAX_HEAD_BYTES = 8 * 1024  # request line and headers (a browser's are under 2 kB, the page's cookie included)
ANSWER_TIMEOUT_S = 10.0  # to take an answer that is not the event stream (the page and its files are 21 kB)
STREAM_STALL_S = 30.0  # an event stream whose browser takes nothing this long is cut (it reconnects if it is there)
USER_TIMEOUT_S = 30.0  # TCP_USER_TIMEOUT: the kernel drops a connection whose data goes unacknowledged this long
SHUTDOWN_S = 1.0  # how long a stopping server waits for a browser that stopped reading
ACCEPT_RETRY_S = 1.0  # accepting pauses this long after an accept that failed (out of descriptors or memory)
WARN_EVERY_S = 30.0  # at most one warning of each kind this often; the next says how many were left out
BACKLOG = 128  # connections the kernel queues for the page while it is not accepting
LOOPBACK_NAMES = ("127.0.0.1", "localhost", "::1")
_HEADERS = {
    "Cache-Control": "no-store",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",  # the token may be in the page's address
    "Content-Security-Policy": "default-src 'none'; script-src 'self'; style-src 'self'; connect-src 'self'; "
                               "img-src 'self' data:; frame-ancestors 'none'; base-uri 'none'; form-action 'none'",
}
_FILES = {"/": ("page.html", "text/html; charset=utf-8"), "/page.js": ("page.js", "text/javascript; charset=utf-8"),
          "/page.css": ("page.css", "text/css; charset=utf-8")}
_EVENTS = "/events"


def page_file(body: bytes, name: str) -> bytes:
    """A file of the page as served: page.js after the event catalogue's tones, which it reads as ``EVENT_TONES``
    (companion.mission.events: the page names no list of events of its own)."""
    if name != "page.js":
        return body
    tones = json.dumps({e.value: e.tone.value for e in Event}, separators=(",", ":"))
    return f"const EVENT_TONES = Object.freeze({tones});\n".encode() + body


_TCHAR = frozenset("!#$%&'*+-.^_`|~0123456789ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz")  # RFC 9110 token
_OUT_OF_RESOURCES = {errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM}
# accept() failing for the one connection it was taking, which went or broke before it was accepted (Linux's
# accept(2) lists the network errors it passes on; EPERM: a firewall rule refused it)
_ONE_CONNECTION = {getattr(errno, name) for name in ("ECONNABORTED", "ECONNRESET", "EPROTO", "ENOPROTOOPT",
                                                     "EHOSTDOWN", "ENONET", "EHOSTUNREACH", "EOPNOTSUPP",
                                                     "ENETUNREACH", "ENETDOWN", "EPERM") if hasattr(errno, name)}
_BAD_IN_A_LINE = ("\r", "\n", "\x00")
_HOST_NAME = re.compile(r"[a-z0-9_-]+(\.[a-z0-9_-]+)*")  # as host_name() spells one: lower case, no trailing dot


@dataclass(frozen=True)
class Limits:
    """What one server lets its connections take (the module docstring says why each): the module's constants
    unless given (tests make them small)."""

    max_connections: int = MAX_CONNECTIONS
    max_pending: int = MAX_PENDING
    head_timeout_s: float = HEAD_TIMEOUT_S
    pending_grace_s: float = PENDING_GRACE_S
    stream_stall_s: float = STREAM_STALL_S


@dataclass(frozen=True)
class Bind:
    """Where the page is served: ``host`` and ``port`` (0: any free port), and the other names browsers may reach it
    by (``allowed_hosts``: a name the machine has in DNS, a reverse proxy's), as :func:`host_name` spells them."""

    host: str
    port: int
    allowed_hosts: tuple[str, ...] = ()

    @classmethod
    def parse(cls, text: str, allowed_hosts: Iterable[str] = ()) -> Bind:
        """``PORT``, ``HOST:PORT`` or ``[IPv6]:PORT``; the host defaults to loopback. ``allowed_hosts``: names or
        addresses (``--status-host``), each with a port or none."""
        host, sep, port = text.rpartition(":")
        host = host.strip("[]") if sep else DEFAULT_HOST
        try:
            number = int(port)
        except ValueError:
            number = -1
        if not 0 <= number <= 65535 or (sep and not host):
            raise FuseplanError(f"--status-page {text!r}: expected PORT or HOST:PORT (e.g. 8765 or 0.0.0.0:8765)")
        names = []
        for given in allowed_hosts:
            name = host_name(given)
            if name is None or not (_HOST_NAME.fullmatch(name) or _is_address(name)):
                raise FuseplanError(f"--status-host {given!r}: expected a host name or address (e.g. "
                                    "companion.example.org)")
            names.append(name)
        return cls(host, number, tuple(dict.fromkeys(names)))

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


def read_token(path: Path | None, bind: Bind, insecure: bool = False) -> str | None:
    """The token in ``path`` (its first line, at least 16 characters); required when ``bind`` is not loopback.
    The file is read as every secret is (:func:`~companion.mavlink.signing.read_secret`: a regular file, small,
    and refused when other users may read it, unless ``insecure``)."""
    if path is None:
        if not bind.loopback:
            raise FuseplanError(f"--status-page {bind.host}:{bind.port} is reachable from other machines: give "
                                "--status-token FILE (a file holding a secret of 16 characters or more)")
        return None
    try:
        lines = read_secret(path, "status token", insecure).decode("utf-8-sig").strip().splitlines()
    except UnicodeDecodeError as e:
        raise FuseplanError(f"{path}: cannot read the status token: not UTF-8 text ({e.reason})") from e
    token = lines[0].strip() if lines else ""
    if len(token) < 16:
        raise FuseplanError(f"{path}: the status token must be 16 characters or more on its first line")
    return token


def host_name(text: str) -> str | None:
    """The name a ``Host`` header's value gives, without its port or brackets, in one spelling per address
    (lower case, no trailing dot, IPv6 compressed, IPv4-mapped IPv6 as IPv4); None when it is malformed."""
    text = text.strip().lower()
    if text.startswith("["):
        name, sep, port = text[1:].partition("]")
        if not sep or (port and not (port[0] == ":" and port[1:].isdigit())):
            return None
    elif text.count(":") == 1:
        name, port = text.split(":")
        if port and not port.isdigit():
            return None
    else:  # a name, an IPv4 address, or an IPv6 address without its brackets
        name = text
    name = name.rstrip(".")
    if not name:
        return None
    try:
        ip = ipaddress.ip_address(name.partition("%")[0])
    except ValueError:
        return name
    return str(getattr(ip, "ipv4_mapped", None) or ip)


def _is_address(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def machine_names() -> set[str]:
    """This machine's host name as a browser on the network may spell it: ``name``, ``name.local`` (mDNS) and the
    full name if it has dots (from the kernel, no DNS lookup: the field has no DNS server)."""
    full = socket.gethostname().lower().rstrip(".")
    first = full.split(".")[0]
    return {n for n in (full, first, f"{first}.local") if n}


@dataclass(frozen=True)
class Request:
    """A request's head, decoded as Latin-1 (every byte is a character: decoding cannot fail, and encoding back
    to Latin-1 gives the bytes that were sent). Header names are in lower case, each with all its values."""

    method: str
    path: str
    query: str
    version: str
    headers: dict[str, list[str]] = field(default_factory=dict)

    @classmethod
    def parse(cls, head: bytes) -> Request | None:
        """The request in ``head`` (up to and with its blank line), or None when it is not an HTTP/1.x request
        for a path on this server: also when a line ends in a bare LF, or holds a CR, LF or NUL of its own."""
        text = head.decode("latin-1")
        if not text.endswith("\r\n\r\n"):
            return None
        lines = text[:-4].split("\r\n")
        if any(bad in line for line in lines for bad in _BAD_IN_A_LINE):
            return None
        parts = lines[0].split(" ")
        if len(parts) != 3:
            return None
        method, target, version = parts
        if not method or not set(method) <= _TCHAR or version not in ("HTTP/1.0", "HTTP/1.1") \
                or not target.startswith("/"):
            return None
        headers: dict[str, list[str]] = {}
        for line in lines[1:]:
            name, sep, value = line.partition(":")
            if not sep or not name or not set(name) <= _TCHAR:  # folded lines too: they begin with a space
                return None
            headers.setdefault(name.lower(), []).append(value.strip(" \t"))
        path, _, query = target.partition("?")
        return cls(method, path, query, version, headers)

    def offered_tokens(self) -> dict[str, list[bytes]]:
        """Every token this request offers, as bytes, by where it came: ``query`` (``?token=``), ``bearer``
        (``Authorization: Bearer``), ``cookie`` (the page's cookie, which holds it percent-encoded)."""
        query = [v.encode("latin-1") for k, v in parse_qsl(self.query, keep_blank_values=True, encoding="latin-1")
                 if k == "token"]
        bearer = []
        for value in self.headers.get("authorization", ()):
            scheme, _, credentials = value.partition(" ")
            if scheme.lower() == "bearer":
                bearer.append(credentials.strip().encode("latin-1"))
        cookie = []
        for value in self.headers.get("cookie", ()):
            for pair in value.split(";"):
                name, _, text = pair.strip().partition("=")
                if name == COOKIE:
                    cookie.append(unquote_to_bytes(text.strip().strip('"').encode("latin-1")))
        return {"query": query, "bearer": bearer, "cookie": cookie}


@dataclass(frozen=True)
class Answer:
    """What a request gets: a status, headers and a body, or (``stream``) the event stream."""

    status: int
    body: bytes = b""
    headers: dict[str, str] = field(default_factory=dict)
    stream: bool = False

    @classmethod
    def text(cls, status: int, text: str, **headers: str) -> Answer:
        """A short plain-text answer (header names with ``_`` for ``-``)."""
        return cls(status, text.encode(), {k.replace("_", "-"): v for k, v in headers.items()})

    def head(self, chunked: bool = False) -> bytes:
        """The status line and headers: :data:`_HEADERS` on every one, ``Connection: close`` on every one (the
        event stream ends with its connection too)."""
        headers = {**_HEADERS, "Content-Type": "text/plain; charset=utf-8", **self.headers, "Connection": "close"}
        if self.stream:
            headers.update({"Content-Type": "text/event-stream", "X-Accel-Buffering": "no"})
            if chunked:
                headers["Transfer-Encoding"] = "chunked"
        else:
            headers["Content-Length"] = str(len(self.body))
        lines = [f"HTTP/1.1 {self.status} {HTTPStatus(self.status).phrase}"]
        lines += [f"{k}: {v}" for k, v in headers.items()]
        return ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1")


class _Warnings:
    """At most one log line of each kind every :data:`WARN_EVERY_S`; the next one says how many were left out."""

    def __init__(self) -> None:
        self._last: dict[str, float] = {}
        self._unsaid: Counter[str] = Counter()

    def __call__(self, kind: str, message: str, *args: object, exc_info: bool = False) -> None:
        now = time.monotonic()
        if kind in self._last and now - self._last[kind] < WARN_EVERY_S:
            self._unsaid[kind] += 1
            return
        self._last[kind] = now
        left_out = self._unsaid.pop(kind, 0)
        suffix = f" ({left_out} more like it in the last {WARN_EVERY_S:.0f} s)" if left_out else ""
        log.warning(message + suffix, *args, exc_info=exc_info)


class StatusServer:
    """``async with StatusServer(hub, bind, token) as server:`` serves the page at ``server.url`` until the block
    ends; then the hub closes, connections that are not event streams are cut at once and streams that stopped
    reading after :data:`SHUTDOWN_S`.

    ``Host`` may give the names the module docstring lists and ``bind.allowed_hosts``. What the ``limits`` did is
    counted: ``refused`` (closed unread at the limit), ``timed_out`` (no full head in time), ``stalled`` (a stream
    that took nothing), ``accept_errors`` (accepting paused).
    """

    def __init__(self, hub: StatusHub, bind: Bind, token: str | None = None, *, limits: Limits = Limits()) -> None:
        if token is None and not bind.loopback:
            raise FuseplanError(f"{bind.host}: serving beyond loopback needs a token")
        self.hub, self.bind, self.token, self.limits = hub, bind, token, limits
        names = {*LOOPBACK_NAMES, bind.host, *bind.allowed_hosts, *(() if bind.loopback else machine_names())}
        self.hosts = frozenset(n for n in map(host_name, names) if n)
        self.port = bind.port
        self.addresses: list[tuple] = []  # where it listens, as getsockname() gives them
        self.refused = self.timed_out = self.stalled = self.accept_errors = 0
        self._files: dict[str, Answer] = {}
        self._listeners: list[socket.socket] = []
        self._acceptors: list[asyncio.Task] = []
        self._connections: set[asyncio.Task] = set()
        self._pending: dict[asyncio.Task, float] = {}  # still reading their head: since when (oldest first)
        self._streams: set[asyncio.Task] = set()
        self._room = asyncio.Event()  # set when a connection stops reading its head
        self._warn = _Warnings()

    @property
    def url(self) -> str:
        host = f"[{self.bind.host}]" if ":" in self.bind.host else self.bind.host
        return f"http://{host}:{self.port}/"

    @property
    def connections(self) -> int:
        """Connections open now (streams and requests being read or answered)."""
        return len(self._connections)

    @property
    def pending(self) -> int:
        """Connections still reading their request head."""
        return len(self._pending)

    async def __aenter__(self) -> StatusServer:
        self.hub.bind(asyncio.get_running_loop())
        package = resources.files("companion.status")
        self._files = {path: Answer(200, page_file(package.joinpath(name).read_bytes(), name), {"Content-Type": kind})
                       for path, (name, kind) in _FILES.items()}
        try:
            self._listeners = self._listen()
        except OSError as e:
            raise self.bind.cannot_listen(e) from e
        self.addresses = [s.getsockname() for s in self._listeners]
        self.port = int(self.addresses[0][1])
        self._acceptors = [asyncio.create_task(self._accept(s), name="status-page accept") for s in self._listeners]
        log.info("status page on %s", self.url)
        return self

    def _listen(self) -> list[socket.socket]:
        """A listening socket on each address ``bind.host`` has (all on the port the first one got, for port 0),
        IPv6 ones IPv6 only when IPv4 ones are there too (as asyncio's servers do)."""
        infos = socket.getaddrinfo(self.bind.host, self.bind.port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
        unique = list(dict.fromkeys((family, address) for family, _t, _p, _c, address in infos))
        families = {family for family, _a in unique}
        sockets: list[socket.socket] = []
        try:
            for family, address in unique:
                sock = socket.socket(family, socket.SOCK_STREAM)
                sockets.append(sock)
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                if family == socket.AF_INET6 and socket.AF_INET in families:
                    sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
                port = sockets[0].getsockname()[1] if len(sockets) > 1 else address[1]
                sock.bind((address[0], port, *address[2:]))
                sock.listen(BACKLOG)
                sock.setblocking(False)
        except OSError:
            for sock in sockets:
                sock.close()
            raise
        return sockets

    async def __aexit__(self, *exc: object) -> None:
        self.hub.close()
        for task in [*self._acceptors, *(self._connections - self._streams)]:
            task.cancel()  # reading a head or being answered: nothing there that a browser would miss
        try:
            if self._streams:  # they end after what they were sent, unless their browser stopped reading
                await asyncio.wait(set(self._streams), timeout=SHUTDOWN_S)
        finally:
            left = [*self._acceptors, *self._connections]
            for task in left:
                task.cancel()
            try:
                await asyncio.gather(*left, return_exceptions=True)
            finally:
                for sock in self._listeners:
                    sock.close()

    async def _accept(self, listener: socket.socket) -> None:
        """Accept connections on ``listener`` for as long as the server runs: while :attr:`Limits.max_pending` are
        reading their head, none (they wait in the kernel's queue); beyond :attr:`Limits.max_connections`, none
        read. No error ends the loop or reaches the flight's."""
        loop = asyncio.get_running_loop()
        while True:
            try:
                await self._pending_room()
                conn, _peer = await loop.sock_accept(listener)
                if len(self._connections) >= self.limits.max_connections:
                    conn.close()
                    self.refused += 1
                    self._warn("limit", "status page: %d connections open, its limit: closing new ones unread (%d "
                               "so far); the flight goes on", self.limits.max_connections, self.refused)
                    await asyncio.sleep(0)  # a flood of them takes turns with the flight
                    continue
                self._admit(conn)
            except OSError as e:
                if e.errno in _ONE_CONNECTION:
                    log.debug("status page: a connection failed before it was accepted (%s)", e.strerror or e)
                    continue
                self.accept_errors += 1
                kind = "out of resources" if e.errno in _OUT_OF_RESOURCES else "error"
                self._warn(f"accept {kind}", "status page: cannot accept a connection (%s): accepting again in %g s;"
                           " the flight goes on", e.strerror or e, ACCEPT_RETRY_S)
                await asyncio.sleep(ACCEPT_RETRY_S)
            except Exception:  # a bug here: accepting pauses, the flight goes on
                self.accept_errors += 1
                self._warn("accept bug", "status page: unexpected error accepting a connection: accepting again in "
                           "%g s; the flight goes on", ACCEPT_RETRY_S, exc_info=True)
                await asyncio.sleep(ACCEPT_RETRY_S)

    async def _pending_room(self) -> None:
        """Return once there is room for one more connection to read its head: while :attr:`Limits.max_pending`
        are reading theirs, wait for one to finish, cutting the longest waiting once it has had
        :attr:`Limits.pending_grace_s`. (With more than one listening address, each may take the last slot: the
        budget is then exceeded by one per further address, at most.)"""
        while len(self._pending) >= self.limits.max_pending:
            oldest, since = next(iter(self._pending.items()))
            wait = since + self.limits.pending_grace_s - time.monotonic()
            if wait <= 0:
                self._head_read(oldest)
                oldest.cancel()
                self.timed_out += 1
                self._warn("pending", "status page: %d connections reading their request, its limit: cutting the "
                           "longest waiting after %g s (%d cut so far); the flight goes on", self.limits.max_pending,
                           self.limits.pending_grace_s, self.timed_out)
                await asyncio.wait({oldest}, timeout=SHUTDOWN_S)  # its slot free before the next one is counted
                continue
            self._room.clear()
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(wait):
                    await self._room.wait()

    def _admit(self, conn: socket.socket) -> None:
        """Serve ``conn`` in a task of its own, counted as reading its head until it has."""
        try:
            _keep_alive(conn)
            task = asyncio.create_task(self._serve(conn), name="status-page connection")
        except BaseException:
            conn.close()
            raise
        self._connections.add(task)
        self._pending[task] = time.monotonic()
        task.add_done_callback(self._gone)
        task.add_done_callback(lambda _task: conn.close())  # also when it was cancelled before it started

    def _head_read(self, task: asyncio.Task) -> None:
        if self._pending.pop(task, None) is not None:
            self._room.set()

    def _gone(self, task: asyncio.Task) -> None:
        self._head_read(task)
        self._connections.discard(task)
        self._streams.discard(task)

    async def _serve(self, conn: socket.socket) -> None:
        """One connection: its head read within :attr:`Limits.head_timeout_s` and :data:`MAX_HEAD_BYTES`, then one
        answer and the connection closed, or the event stream for as long as the hub and the browser last. Every
        error ends this connection and nothing else."""
        me = asyncio.current_task()
        assert me is not None  # _admit made this task
        writer: asyncio.StreamWriter | None = None
        try:
            reader, writer = await asyncio.open_connection(sock=conn, limit=MAX_HEAD_BYTES)
            try:
                async with asyncio.timeout(self.limits.head_timeout_s):
                    head = await _read_head(reader)
            except TimeoutError:
                self.timed_out += 1
                log.debug("status page: a connection sent no request in %g s; closed", self.limits.head_timeout_s)
                return
            except asyncio.IncompleteReadError:  # closed before its request was whole
                return
            except asyncio.LimitOverrunError:
                answer, request = Answer.text(431, "431: request head too large\n"), None
            else:
                request = Request.parse(head)
                local = writer.get_extra_info("sockname")
                answer = self._answer(request, host_name(str(local[0])) if local else None)
            finally:
                self._head_read(me)
            if answer.stream and request is not None and request.method == "GET":
                self._streams.add(me)
                await self._stream(writer, answer, chunked=request.version == "HTTP/1.1")
            else:
                async with asyncio.timeout(ANSWER_TIMEOUT_S):
                    writer.write(answer.head() + (b"" if request and request.method == "HEAD" else answer.body))
                    await writer.drain()
                    writer.close()
                    await writer.wait_closed()
        except OSError:  # the browser went away, or did not take its answer in time (TimeoutError)
            pass
        except Exception:  # a bug here: that one connection ends, the flight does not
            self._warn("bug", "status page: unexpected error serving a connection; the flight goes on",
                       exc_info=True)
        finally:
            if writer is not None:
                writer.transport.abort()  # at once, whatever it still holds (nothing, after a clean close)

    def _answer(self, request: Request | None, local: str | None) -> Answer:
        """What ``request`` gets, checked in this order: well formed (400), ``Host`` (400, 421), the token (401),
        the method (405), the path (404)."""
        if request is None:
            return Answer.text(400, "400: not an HTTP/1.x request for a path on this server\n")
        hosts = request.headers.get("host", [])
        if len(hosts) > 1 or (not hosts and request.version == "HTTP/1.1"):
            return Answer.text(400, "400: one Host header, please\n")
        if hosts:
            name = host_name(hosts[0])
            if name is None:
                return Answer.text(400, "400: malformed Host header\n")
            if name not in self.hosts and name != local:
                return Answer.text(421, "421: this page answers only to its own names and addresses\n")
        elif not self.bind.loopback:
            return Answer.text(421, "421: this page needs a Host header\n")
        extra: dict[str, str] = {}
        if self.token is not None:
            offered = request.offered_tokens()
            secret = self.token.encode()
            matched = {where for where, tokens in offered.items() for t in tokens if hmac.compare_digest(t, secret)}
            if not matched:
                return Answer.text(401, "401: this status page needs its token\n",
                                   WWW_Authenticate='Bearer realm="fuseplan status"')
            if "query" in matched:  # the page's own requests carry it from now on
                extra["Set-Cookie"] = f"{COOKIE}={quote(self.token, safe='')}; Path=/; HttpOnly; SameSite=Strict"
        if request.method not in ("GET", "HEAD"):
            return Answer.text(405, "405: this page is read-only\n", Allow="GET, HEAD")
        if request.path == _EVENTS:
            return Answer(200, headers=extra, stream=True)
        found = self._files.get(request.path)
        if found is None:
            return Answer.text(404, "404: not here\n")
        return Answer(200, found.body, {**found.headers, **extra})

    async def _stream(self, writer: asyncio.StreamWriter, answer: Answer, chunked: bool) -> None:
        """The hub's records to one browser until the hub closes or the browser goes; a write waits only in this
        task (asyncio's drain: the transport's buffer holds at most its high-water mark, 64 kB), and at most
        :attr:`Limits.stream_stall_s` (then the stream is cut: a browser that is still there reconnects)."""
        writer.write(answer.head(chunked))
        async with contextlib.aclosing(self.hub.read()) as chunks:
            async for data in chunks:
                if data:  # an empty chunk would end the chunked body
                    writer.write(b"%x\r\n%s\r\n" % (len(data), data) if chunked else data)
                try:
                    async with asyncio.timeout(self.limits.stream_stall_s):
                        await writer.drain()
                except TimeoutError:
                    self.stalled += 1
                    log.debug("status page: a browser took nothing of its stream in %g s; cut",
                              self.limits.stream_stall_s)
                    return
        if chunked:
            writer.write(b"0\r\n\r\n")
        writer.close()
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(writer.wait_closed(), SHUTDOWN_S)


async def _read_head(reader: asyncio.StreamReader) -> bytes:
    """The request line and headers, line by line up to the first empty one, which may end in a bare LF (then
    :meth:`Request.parse` refuses the head at once, where waiting for a CRLF CRLF would wait for the timeout).
    Raises :class:`asyncio.LimitOverrunError` beyond :data:`MAX_HEAD_BYTES` (the reader's limit holds one line)."""
    lines: list[bytes] = []
    size = 0
    while not lines or lines[-1] not in (b"\r\n", b"\n"):
        lines.append(await reader.readuntil(b"\n"))
        size += len(lines[-1])
        if size > MAX_HEAD_BYTES:
            raise asyncio.LimitOverrunError("request head too large", size)
    return b"".join(lines)


def _keep_alive(conn: socket.socket) -> None:
    """``SO_KEEPALIVE`` and, on Linux, ``TCP_USER_TIMEOUT`` of :data:`USER_TIMEOUT_S` on an accepted socket, as far
    as the platform has them (a browser is served without)."""
    with contextlib.suppress(OSError):
        conn.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
        if hasattr(socket, "TCP_USER_TIMEOUT"):
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_USER_TIMEOUT, int(USER_TIMEOUT_S * 1000))

"""The status page's limits over real sockets on 127.0.0.1 (companion/status/server.py's docstring lists them):
connections beyond the limit closed unread, silent connections held to their own small budget, a request head that
does not come in time closed, a stream that takes nothing cut, bytes that are not UTF-8 answered 401 or 400 and
never 500, bare line ends and NUL answered 400 at once, a foreign ``Host`` refused and the ``--status-host`` names
served, ``no-store`` on every answer, an accept that fails logged once while the page, and the loop, go on, and
stopping that waits for no request head."""

from __future__ import annotations

import asyncio
import logging
import os
import resource
import socket
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from demo_flight import Companion

from companion.cli import main
from companion.mission.events import EventLog
from companion.status import Bind, Limits, StatusHub, StatusServer, serve_flight
from companion.status.hub import sse
from companion.status.server import COOKIE, USER_TIMEOUT_S
from planner.errors import FuseplanError

TOKEN = "s3cret-token-for-tests-0123456789"


async def _ask(port: int, data: bytes, timeout: float = 5.0) -> tuple[int, dict[str, str], bytes]:
    """Send ``data`` as it is and read the answer to its end (the server closes every connection but a stream's):
    (status, headers with lower-case names, body)."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(data)
        raw = await asyncio.wait_for(reader.read(), timeout)
    finally:
        writer.close()
        await writer.wait_closed()
    head, _, body = raw.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    headers = {k.strip().lower(): v.strip() for k, _, v in (line.partition(":") for line in lines[1:])}
    return int(lines[0].split()[1]), headers, body


def _get(path: str = "/", host: str | None = "127.0.0.1", *extra: bytes, method: str = "GET",
         version: str = "HTTP/1.1") -> bytes:
    """A request head: ``path`` and ``host`` (None: no Host header) as Latin-1 (``\\xff`` is the byte 0xff),
    ``extra`` header lines as raw bytes (anything, UTF-8 or not)."""
    lines = [f"{method} {path} {version}".encode("latin-1")]
    if host is not None:
        lines.append(f"Host: {host}".encode("latin-1"))
    return b"\r\n".join([*lines, *extra, b"", b""])


async def _closed_within(reader: asyncio.StreamReader, timeout: float) -> bytes:
    """What the server sent before it closed the connection (a reset counts as closed with nothing sent)."""
    try:
        return await asyncio.wait_for(reader.read(), timeout)
    except ConnectionResetError:
        return b""


async def _until(condition: Callable[[], bool], timeout: float = 5.0) -> None:
    end = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < end, "timed out waiting"
        await asyncio.sleep(0.01)


def _no_tracebacks(caplog: pytest.LogCaptureFixture) -> None:
    assert not [r for r in caplog.records if r.exc_info or r.levelno >= logging.ERROR], caplog.text


def _own_socket(match: Callable[[socket.socket], bool]) -> socket.socket:
    """A TCP socket of this process (the server runs in it) that ``match`` picks, as a duplicate of its descriptor
    (the caller closes it)."""
    for fd in os.listdir("/proc/self/fd"):
        try:
            if not os.readlink(f"/proc/self/fd/{fd}").startswith("socket:"):
                continue
            sock = socket.fromfd(int(fd), socket.AF_INET, socket.SOCK_STREAM)
        except OSError:
            continue
        try:
            if match(sock):
                return sock
        except OSError:  # not connected, not TCP, not IPv4
            pass
        sock.close()
    raise AssertionError("no such socket in this process")


def _server_end(client: socket.socket) -> socket.socket:
    """The server's end of ``client``'s connection."""
    want = (client.getpeername(), client.getsockname())
    return _own_socket(lambda s: (s.getsockname(), s.getpeername()) == want)


def _stalled_client(port: int) -> socket.socket:
    """A client that asks for the event stream and does not read (a 4 KiB receive buffer)."""
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(("127.0.0.1", port))
    sock.sendall(_get("/events"))
    return sock


async def _open_stream(port: int) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    """An event stream (HTTP/1.0: not chunked), its head and its ``reset`` read."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(_get("/events", version="HTTP/1.0"))
    assert (await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), 5.0)).startswith(b"HTTP/1.1 200")
    assert await asyncio.wait_for(reader.readuntil(b"\n\n"), 5.0) == b"event: reset\ndata: {}\n\n"
    return reader, writer


async def _close_all(writers: list[asyncio.StreamWriter]) -> None:
    for w in writers:
        w.close()
    await asyncio.gather(*(w.wait_closed() for w in writers), return_exceptions=True)


@pytest.mark.asyncio
async def test_connections_beyond_the_limit_are_closed_unread_and_the_page_goes_on(
        caplog: pytest.LogCaptureFixture) -> None:
    """Eight connections allowed: an event stream and seven that send nothing fill them; twelve more are each
    closed at once (well before the 5 s head timeout), unanswered, with one warning for all of them; the stream
    still gets its records, and once slots are free a request is answered again."""
    hub = StatusHub()
    async with StatusServer(hub, Bind.parse("0"), limits=Limits(max_connections=8, head_timeout_s=5.0)) as server:
        port = server.port
        stream_r, stream_w = await asyncio.open_connection("127.0.0.1", port)
        stream_w.write(_get("/events", version="HTTP/1.0"))
        assert (await stream_r.readuntil(b"\r\n\r\n")).startswith(b"HTTP/1.1 200")
        assert await stream_r.readuntil(b"\n\n") == b"event: reset\ndata: {}\n\n"
        idle = [await asyncio.open_connection("127.0.0.1", port) for _ in range(7)]
        await _until(lambda: server.connections == 8)
        extra = []
        for n in range(12):
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            if n % 2:
                writer.write(b"GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\n")  # half a request: not read
            extra.append((reader, writer))
        start = time.monotonic()
        got = await asyncio.gather(*(_closed_within(r, 2.0) for r, _w in extra))
        elapsed = time.monotonic() - start
        assert got == [b""] * 12 and elapsed < 1.0, (got, elapsed)
        assert server.refused == 12 and server.connections == 8
        hub.publish({"event": "position", "n": 1})
        assert b'"n":1' in await asyncio.wait_for(stream_r.readuntil(b"\n\n"), 2.0)
        for _r, w in idle + extra:
            w.close()
        await _until(lambda: server.connections == 1)
        status, headers, body = await _ask(port, _get("/"))
        assert status == 200 and b"<svg" in body
        stream_w.close()
        await asyncio.gather(*(w.wait_closed() for _r, w in [*idle, *extra, (stream_r, stream_w)]),
                             return_exceptions=True)
    warnings = [r for r in caplog.records if "its limit" in r.getMessage()]
    assert len(warnings) == 1 and warnings[0].levelno == logging.WARNING, caplog.text
    _no_tracebacks(caplog)


@pytest.mark.asyncio
async def test_a_request_head_that_does_not_come_in_time_is_closed(caplog: pytest.LogCaptureFixture) -> None:
    """A connection that sends nothing and a slow loris that drips its headers a byte every 50 ms are both closed
    after the head timeout (a total, not an idle time), unanswered; a head larger than the cap gets 431."""
    async with StatusServer(StatusHub(), Bind.parse("0"), limits=Limits(head_timeout_s=0.5)) as server:
        port = server.port
        silent_r, silent_w = await asyncio.open_connection("127.0.0.1", port)
        loris_r, loris_w = await asyncio.open_connection("127.0.0.1", port)
        loris_w.write(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")

        async def drip() -> None:
            with pytest.raises(ConnectionError):
                for _ in range(100):
                    loris_w.write(b"X")
                    await loris_w.drain()
                    await asyncio.sleep(0.05)

        dripping = asyncio.create_task(drip())
        start = time.monotonic()
        got = await asyncio.gather(_closed_within(silent_r, 3.0), _closed_within(loris_r, 3.0))
        elapsed = time.monotonic() - start
        assert got == [b"", b""] and 0.4 < elapsed < 1.5, (got, elapsed)
        await asyncio.wait_for(dripping, 5.0)
        assert server.timed_out == 2
        await _until(lambda: server.connections == 0)
        status, headers, _ = await _ask(port, _get("/", "127.0.0.1", b"X-Big: " + b"a" * 9000))
        assert status == 431 and headers["cache-control"] == "no-store" and headers["connection"] == "close"
        for w in (silent_w, loris_w):
            w.close()
            await asyncio.gather(w.wait_closed(), return_exceptions=True)
    _no_tracebacks(caplog)


@pytest.mark.asyncio
async def test_bytes_that_are_not_utf8_get_401_or_400_and_never_500(caplog: pytest.LogCaptureFixture) -> None:
    """On a page with a token: non-UTF-8 Authorization, Cookie, query and header values without the token are a
    401, a malformed head a 400, and none shows the page; with the token beside them the page is served."""
    hub = StatusHub()
    hub.publish({"event": "scene", "name": "secret-map"})
    async with StatusServer(hub, Bind.parse("0"), TOKEN) as server:
        port = server.port
        junk = [b"Authorization: Bearer \xff", b"Authorization: \xff\xfe \xff", b"Authorization: Bearer",
                f"Cookie: {COOKIE}=\xff\xfe".encode("latin-1"), b"Cookie: \xff=\xff; ;;=",
                f"Cookie: {COOKIE}=%ff%".encode(), b"User-Agent: \xc3\x28\xa0\xa1", b"X-Anything: \x01\x7f\x80"]
        for path in ("/", "/events", "/page.js", "/nothing"):
            for line in junk:
                status, headers, body = await _ask(port, _get(path, "127.0.0.1", line))
                assert status == 401, (path, line, status)
                assert b"secret-map" not in body and b"<html" not in body
            for query in ("?token=%ff%fe", "?token=\xff", "?token=%", "?%zz=%zz&token"):
                status, _, _ = await _ask(port, _get(path + query))
                assert status == 401, (path, query, status)
        malformed = [b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\xff\xfe: x\r\n\r\n", b"\xff\xfe\xfd\r\n\r\n",
                     b"GET /\xff HTTP/9.9\r\n\r\n", b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n folded\r\n\r\n",
                     b"GET / HTTP/1.1\r\nHost: [::1\r\n\r\n", b"GET / HTTP/1.1\r\nHost: a:b:c:\xff\r\n\r\n",
                     b"GET http://127.0.0.1/ HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"]
        for raw in malformed:
            status, headers, body = await _ask(port, raw)
            assert status in (400, 421), (raw, status)
            assert headers["cache-control"] == "no-store" and b"secret-map" not in body
        # the token, by header, beside junk: served
        status, _, body = await _ask(port, _get("/", "127.0.0.1", b"Cookie: \xff=\xff",
                                                f"Authorization: Bearer {TOKEN}".encode(), b"X-Junk: \xff"))
        assert status == 200 and b"<svg" in body
        status, headers, body = await _ask(port, _get(f"/?token={TOKEN}", "127.0.0.1", b"Cookie: \xfe"))
        assert status == 200 and f"{COOKIE}={TOKEN}" in headers["set-cookie"]
    _no_tracebacks(caplog)


@pytest.mark.asyncio
async def test_a_foreign_host_is_refused(caplog: pytest.LogCaptureFixture) -> None:
    """A DNS-rebinding page names its own domain in Host: on a loopback bind only loopback names are served
    (any port, with or without it); anything else gets 421 and nothing of the page."""
    hub = StatusHub()
    hub.publish({"event": "scene", "name": "secret-map"})
    async with StatusServer(hub, Bind.parse("0")) as server:
        port = server.port
        for host in ("127.0.0.1", "localhost", "LocalHost.", "[::1]", "::1", "[0:0:0:0:0:0:0:1]"):
            for with_port in (True, False):
                value = f"{host}:{port}" if with_port and host != "::1" else host
                status, _, body = await _ask(port, _get("/", value))
                assert status == 200 and b"<svg" in body, value
        for value in ("evil.example", f"evil.example:{port}", "127.0.0.1.evil.example", "localhost.evil.example",
                      "10.0.0.7", "0.0.0.0", socket.gethostname()):
            for path in ("/", "/events", "/page.js"):
                status, headers, body = await _ask(port, _get(path, value))
                assert status == 421 and b"secret-map" not in body and b"<" not in body, (value, path)
                assert headers["cache-control"] == "no-store"
        # no Host: HTTP/1.1 must send one (400); HTTP/1.0 on loopback is served; two Hosts are a 400
        assert (await _ask(port, _get("/", None)))[0] == 400
        assert (await _ask(port, _get("/", None, version="HTTP/1.0")))[0] == 200
        assert (await _ask(port, _get("/", "127.0.0.1", b"Host: evil.example")))[0] == 400
    _no_tracebacks(caplog)


@pytest.mark.asyncio
async def test_beyond_loopback_the_host_is_the_machines_or_one_given() -> None:
    """Bound to 0.0.0.0 (with its token; reached here over 127.0.0.1): the address the connection arrived at, the
    machine's host name, its .local name and the names the caller allows are served; others get 421, even with
    the token; HTTP/1.0 without a Host is refused."""
    auth = f"Authorization: Bearer {TOKEN}".encode()
    name = socket.gethostname().split(".")[0]
    async with StatusServer(StatusHub(), Bind.parse("0.0.0.0:0", ["Status.Example.ORG"]), TOKEN) as server:
        port = server.port
        for host in ("127.0.0.1", "0.0.0.0", name, f"{name}.local", "status.example.org"):
            status, _, body = await _ask(port, _get("/", host, auth))
            assert status == 200 and b"<svg" in body, host
        for host in ("evil.example", "example.org", "10.0.0.7"):
            assert (await _ask(port, _get("/", host, auth)))[0] == 421, host
        assert (await _ask(port, _get("/", None, auth, version="HTTP/1.0")))[0] == 421
        assert (await _ask(port, _get("/", "127.0.0.1")))[0] == 401  # the Host is right, the token missing


@pytest.mark.asyncio
async def test_every_answer_says_no_store() -> None:
    async with StatusServer(StatusHub(), Bind.parse("0"), TOKEN) as server:
        port = server.port
        auth = f"Authorization: Bearer {TOKEN}".encode()
        cases = {200: _get("/", "127.0.0.1", auth), 404: _get("/nothing", "127.0.0.1", auth),
                 400: b"NOT HTTP\r\n\r\n", 401: _get("/"), 421: _get("/", "evil.example"),
                 405: _get("/", "127.0.0.1", auth, method="POST"),
                 431: _get("/", "127.0.0.1", b"X-Big: " + b"a" * 9000)}
        for expected, raw in cases.items():
            status, headers, _ = await _ask(port, raw)
            assert status == expected
            assert headers["cache-control"] == "no-store", (status, headers)
            assert headers["x-content-type-options"] == "nosniff" and headers["connection"] == "close"
        status, headers, body = await _ask(port, _get("/events", "127.0.0.1", auth, method="HEAD"))
        assert status == 200 and headers["content-type"] == "text/event-stream" and body == b""
        assert headers["cache-control"] == "no-store"


@pytest.mark.asyncio
async def test_an_accept_without_descriptors_is_logged_once_and_the_page_recovers(
        caplog: pytest.LogCaptureFixture) -> None:
    """With this process out of file descriptors (its soft limit lowered to the ones it holds), accept() fails with
    EMFILE: the page logs one warning, no traceback, pauses accepting and tries again each second, while the
    loop goes on; once descriptors are back, the requests that waited in the kernel's queue are answered."""
    async with StatusServer(StatusHub(), Bind.parse("0")) as server:
        port = server.port
        clients = []
        for _ in range(3):  # connected and their requests sent before the server's loop runs again
            sock = socket.create_connection(("127.0.0.1", port))
            sock.sendall(_get("/page.css"))
            sock.setblocking(False)
            clients.append(sock)
        soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
        probe = os.open(os.devnull, os.O_RDONLY)
        os.close(probe)
        ticks = 0
        resource.setrlimit(resource.RLIMIT_NOFILE, (probe, hard))  # the lowest free descriptor is the limit
        try:
            for _ in range(25):  # 2.5 s: the loop keeps its pace (a flight's work would run)
                await asyncio.sleep(0.1)
                ticks += 1
            assert 2 <= server.accept_errors <= 4 and server.connections == 0  # a try a second, not a spin
        finally:
            resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))
        loop = asyncio.get_running_loop()
        answers = []
        for sock in clients:
            with sock:
                data = b""
                while chunk := await asyncio.wait_for(loop.sock_recv(sock, 65536), 5.0):
                    data += chunk
                answers.append(data)
    assert ticks == 25 and all(a.startswith(b"HTTP/1.1 200") and b"no-store" in a for a in answers)
    warnings = [r for r in caplog.records if "cannot accept" in r.getMessage()]
    assert len(warnings) == 1 and "Too many open files" in warnings[0].getMessage(), caplog.text
    _no_tracebacks(caplog)


def test_a_record_the_hub_cannot_encode_never_reaches_the_flight(caplog: pytest.LogCaptureFixture) -> None:
    """The hub is an EventLog listener, called inside the flight's log(): a record it cannot encode is left off
    the page with a warning, and publishing goes on."""
    hub = StatusHub()
    hub.publish({"event": "odd", "by": {(1, 2): "a tuple key"}})
    hub.publish({"event": "position", "n": 1})
    assert hub.buffered_bytes == len(sse(1, {"event": "position", "n": 1}))
    assert "left off the page" in caplog.text


def test_a_record_the_hub_cannot_encode_for_any_reason_is_left_off_the_page(caplog: pytest.LogCaptureFixture) -> None:
    """Not only TypeError and ValueError: a record nested deeper than Python recurses, one whose value's __str__
    raises, and one that holds itself are each left off with a warning, and the next record is published."""
    class Unprintable:
        def __str__(self) -> str:
            raise RuntimeError("no text for this")

    deep: list = []
    inner = deep
    for _ in range(100_000):
        inner.append([])
        inner = inner[0]
    loop: dict = {"event": "loop"}
    loop["self"] = loop
    hub = StatusHub()
    for rec in ({"event": "deep", "v": deep}, {"event": "odd", "v": Unprintable()}, loop):
        hub.publish(rec)
    hub.publish({"event": "position", "n": 1})
    assert hub.buffered_bytes == len(sse(1, {"event": "position", "n": 1}))
    said = [r.getMessage() for r in caplog.records if "left off the page" in r.getMessage()]
    assert len(said) == 3 and "RecursionError" in said[0] and "no text for this" in said[1], said


@pytest.mark.asyncio
async def test_silent_connections_cannot_take_the_slots_of_browsers(caplog: pytest.LogCaptureFixture) -> None:
    """Of eight connections, four may be reading their head at once: four silent ones fill that budget, and six
    more wait in the kernel's queue, unread, never more than four being read. The longest waiting is cut after its
    0.5 s grace (the head timeout is 30 s), so a browser's request queued behind all of them is answered within two
    rounds, then its event stream at once, and the stream keeps its slot and its records while silent connections
    keep coming; one warning says so."""
    hub = StatusHub()
    hub.publish({"event": "scene", "name": "the-map"})
    limits = Limits(max_connections=8, max_pending=4, head_timeout_s=30.0, pending_grace_s=0.5)
    seen = {"pending": 0, "connections": 0}

    async def watch(server: StatusServer) -> None:
        while True:
            seen["pending"] = max(seen["pending"], server.pending)
            seen["connections"] = max(seen["connections"], server.connections)
            await asyncio.sleep(0.005)

    async with StatusServer(hub, Bind.parse("0"), limits=limits) as server:
        port = server.port
        watcher = asyncio.create_task(watch(server))
        silent = [await asyncio.open_connection("127.0.0.1", port) for _ in range(4)]
        await _until(lambda: server.pending == 4)
        queued = [await asyncio.open_connection("127.0.0.1", port) for _ in range(6)]  # connected in the kernel
        await asyncio.sleep(0.2)
        assert server.pending == server.connections == 4 and server.timed_out == 0
        start = time.monotonic()
        status, _, body = await _ask(port, _get("/"))
        answered_s = time.monotonic() - start
        assert status == 200 and b"<svg" in body and 0.4 < answered_s < 2.0, (status, answered_s)
        stream_r, stream_w = await _open_stream(port)
        assert b"the-map" in await asyncio.wait_for(stream_r.readuntil(b"\n\n"), 1.0)
        assert time.monotonic() - start < 2.5
        more = [await asyncio.open_connection("127.0.0.1", port) for _ in range(8)]
        await asyncio.sleep(1.2)  # two more rounds of silent connections cut
        hub.publish({"event": "position", "n": 1})
        assert b'"n":1' in await asyncio.wait_for(stream_r.readuntil(b"\n\n"), 1.0)
        assert server.timed_out >= 10 and server.refused == 0
        watcher.cancel()
        await asyncio.gather(watcher, return_exceptions=True)
        for r, _w in silent + queued[:4]:  # the page closed those it cut, unanswered
            assert await _closed_within(r, 1.0) == b""
        await _close_all([w for _r, w in silent + queued + more] + [stream_w])
    assert seen["pending"] == 4 and seen["connections"] <= 5, seen  # four being read and the stream, at most
    warnings = [r for r in caplog.records if "reading their request, its limit" in r.getMessage()]
    assert len(warnings) == 1 and warnings[0].levelno == logging.WARNING, caplog.text
    _no_tracebacks(caplog)


@pytest.mark.asyncio
async def test_a_stream_that_takes_nothing_is_cut_and_its_slot_comes_back(caplog: pytest.LogCaptureFixture) -> None:
    """The one slot is an event stream whose browser stops reading (a 4 KiB receive buffer) while 8 MB of records
    come: another connection is closed unread meanwhile; once the stream's buffers are full and 1 s passes
    without a write going through, it is cut, and the slot serves a new stream the reset and the pinned scene (a
    browser that was still there reconnects and has the map again)."""
    hub = StatusHub()
    hub.publish({"event": "scene", "name": "the-map"})
    async with StatusServer(hub, Bind.parse("0"), limits=Limits(max_connections=1, stream_stall_s=1.0)) as server:
        port = server.port
        with _stalled_client(port):
            await _until(lambda: hub.readers == 1)
            pad = "x" * 4000
            for n in range(2000):
                hub.publish({"event": "position", "n": n, "pad": pad})
                if n % 50 == 49:
                    await asyncio.sleep(0)  # the stream writes meanwhile, as in a flight's loop
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            assert await _closed_within(reader, 1.0) == b"" and server.refused == 1 and server.stalled == 0
            await _close_all([writer])
            start = time.monotonic()
            await _until(lambda: server.stalled == 1 and server.connections == 0, timeout=10.0)
            assert time.monotonic() - start < 3.0
            stream_r, stream_w = await _open_stream(port)
            assert b"the-map" in await asyncio.wait_for(stream_r.readuntil(b"\n\n"), 1.0)
            await _close_all([stream_w])
    _no_tracebacks(caplog)


@pytest.mark.asyncio
async def test_accepted_connections_have_keepalive_and_a_user_timeout() -> None:
    """The server's end of a browser's connection (found among this process's sockets) has SO_KEEPALIVE and, on
    Linux, TCP_USER_TIMEOUT: the kernel drops it once its data goes unacknowledged that long."""
    async with StatusServer(StatusHub(), Bind.parse("0")) as server:
        _reader, writer = await _open_stream(server.port)
        with _server_end(writer.get_extra_info("socket")) as end:
            assert end.getsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE) == 1
            if hasattr(socket, "TCP_USER_TIMEOUT"):
                assert end.getsockopt(socket.IPPROTO_TCP, socket.TCP_USER_TIMEOUT) == USER_TIMEOUT_S * 1000
        await _close_all([writer])


@pytest.mark.asyncio
async def test_bare_line_ends_and_nul_in_a_head_get_400_at_once(caplog: pytest.LogCaptureFixture) -> None:
    """A head whose lines end in a bare LF is answered 400 at once (not after the 5 s head timeout, waiting for a
    CRLF CRLF), and so is one with a bare LF, a bare CR or a NUL inside a line: never the page, whatever a proxy
    in front makes of it."""
    async with StatusServer(StatusHub(), Bind.parse("0"), TOKEN) as server:
        auth = f"Authorization: Bearer {TOKEN}".encode()
        heads = [b"GET / HTTP/1.1\nHost: 127.0.0.1\n" + auth + b"\n\n",
                 b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n" + auth + b"\n\n",
                 b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n" + auth + b"\r\n\n",
                 b"\n",
                 b"GET / HTTP/1.1\r\nHost: 127.0.0.1\nX-Smuggled: 1\r\n" + auth + b"\r\n\r\n",
                 b"GET / HTTP/1.1\r\nHost: 127.0.0.1\rX-Smuggled: 1\r\n" + auth + b"\r\n\r\n",
                 b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Nul: a\x00b\r\n" + auth + b"\r\n\r\n",
                 b"GET /\x00 HTTP/1.1\r\nHost: 127.0.0.1\r\n" + auth + b"\r\n\r\n",
                 b"GET / HTTP/1.1\r\nHost: 127.0.0.1\x00.evil.example\r\n" + auth + b"\r\n\r\n"]
        for raw in heads:
            start = time.monotonic()
            status, headers, body = await _ask(server.port, raw)
            assert status == 400 and time.monotonic() - start < 1.0, (raw, status)
            assert headers["cache-control"] == "no-store" and b"<svg" not in body
        assert (await _ask(server.port, _get("/", "127.0.0.1", auth)))[0] == 200
        assert server.timed_out == 0
    _no_tracebacks(caplog)


@pytest.mark.asyncio
async def test_a_listening_socket_that_fails_is_warned_once_and_accepting_goes_on(
        caplog: pytest.LogCaptureFixture) -> None:
    """shutdown() on the page's listening socket (through a duplicate of its descriptor) makes every accept() fail
    with EINVAL, not one connection's error nor lack of resources: one warning, no traceback, a try a second rather
    than a spin that would take a core from the flight, the accept loop alive, the stream already open still
    served, and the server stops cleanly."""
    hub = StatusHub()
    async with StatusServer(hub, Bind.parse("0")) as server:
        stream_r, stream_w = await _open_stream(server.port)
        address = server.addresses[0]
        with _own_socket(lambda s: s.getsockname() == address
                         and s.getsockopt(socket.SOL_SOCKET, socket.SO_ACCEPTCONN) == 1) as listener:
            listener.shutdown(socket.SHUT_RD)
        for _ in range(25):
            await asyncio.sleep(0.1)
        assert 2 <= server.accept_errors <= 4, server.accept_errors
        accepting = [t for t in asyncio.all_tasks() if t.get_name() == "status-page accept"]
        assert accepting and not any(t.done() for t in accepting)
        hub.publish({"event": "position", "n": 1})
        assert b'"n":1' in await asyncio.wait_for(stream_r.readuntil(b"\n\n"), 1.0)
        await _close_all([stream_w])
    warnings = [r for r in caplog.records if "cannot accept" in r.getMessage()]
    assert len(warnings) == 1 and "Invalid argument" in warnings[0].getMessage(), caplog.text
    _no_tracebacks(caplog)


@pytest.mark.asyncio
async def test_stopping_waits_for_no_connection_sending_its_head() -> None:
    """A connection halfway through its head and one that sent nothing are cut at once when the server stops
    (they held it up for 1 s before); an event stream still gets what it was sent and the end of its chunked
    body."""
    hub = StatusHub()
    async with StatusServer(hub, Bind.parse("0")) as server:
        port = server.port
        stream_r, stream_w = await asyncio.open_connection("127.0.0.1", port)
        stream_w.write(_get("/events"))  # HTTP/1.1: chunked
        await asyncio.wait_for(stream_r.readuntil(b"\r\n\r\n"), 5.0)
        half_r, half_w = await asyncio.open_connection("127.0.0.1", port)
        half_w.write(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        silent_r, silent_w = await asyncio.open_connection("127.0.0.1", port)
        await _until(lambda: server.connections == 3 and server.pending == 2)
        hub.publish({"event": "position", "n": 1})
        start = time.monotonic()
    stopped_s = time.monotonic() - start
    rest = await asyncio.wait_for(stream_r.read(), 1.0)
    assert b'"n":1' in rest and rest.endswith(b"0\r\n\r\n"), rest
    assert await _closed_within(half_r, 1.0) == b"" and await _closed_within(silent_r, 1.0) == b""
    assert stopped_s < 0.5, stopped_s  # SHUTDOWN_S is 1 s
    await _close_all([stream_w, half_w, silent_w])


def _report_dir(tmp_path: Path) -> Path:
    d = tmp_path / "report"
    d.mkdir()
    (d / "events.jsonl").write_text('{"t": 0.0, "event": "scene", "name": "the-map"}\n')
    return d


def test_status_host_goes_with_a_page_and_must_name_a_host(rescue_static: Path, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    d = _report_dir(tmp_path)
    assert main(["report", str(d), "--status-host", "status.example.org"]) == 2
    assert "--status-host goes with --serve" in capsys.readouterr().err
    code = main(["fly", str(rescue_static), "--sim", "--status-host", "status.example.org", "--report",
                 str(tmp_path / "r")])
    err = capsys.readouterr()
    assert code == 2 and "--status-host goes with --status-page" in err.err and "planning" not in err.out
    for bad in ("http://status.example.org/", "", "[::1", "host:port"):
        assert main(["report", str(d), "--serve", "0", "--status-host", bad]) == 2, bad
        assert f"--status-host {bad!r}: expected a host name" in capsys.readouterr().err
    with pytest.raises(FuseplanError, match="--status-host 'a:b:c'"):
        Bind.parse("0", ["a:b:c"])
    assert Bind.parse("0", ["Status.Example.ORG.", "status.example.org:443", "[::FFFF:10.1.2.3]"]).allowed_hosts == \
        ("status.example.org", "10.1.2.3")


@pytest.mark.asyncio
async def test_status_host_names_from_the_command_line_are_served(tmp_path: Path) -> None:
    """`fuseplan report DIR --serve 127.0.0.1:0 --status-host ...` (a child process): the names given are served
    (any port, any case), a loopback name too, anything else gets 421. During a flight the same names reach
    serve_flight through its Bind."""
    d = _report_dir(tmp_path)
    with Companion(tmp_path, "report", str(d), "--serve", "127.0.0.1:0", "--status-host", "Status.Example.ORG",
                   "--status-host", "10.1.2.3") as companion:
        port = int(companion.url.rstrip("/").rsplit(":", 1)[1])
        for host in ("status.example.org", "STATUS.example.org:443", "10.1.2.3:8765", "127.0.0.1"):
            status, _, body = await _ask(port, _get("/", host))
            assert status == 200 and b"<svg" in body, host
        for host in ("evil.example", "example.org", "10.1.2.4"):
            assert (await _ask(port, _get("/", host)))[0] == 421, host
    urls: list[str] = []

    async def flight() -> int:
        port = int(urls[0].rstrip("/").rsplit(":", 1)[1])
        return (await _ask(port, _get("/", "proxy.example:8443")))[0]

    events = EventLog(None)
    assert await serve_flight(flight, events, Bind.parse("0", ["proxy.example"]), None, urls.append) == 200

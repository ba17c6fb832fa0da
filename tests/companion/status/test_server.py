"""The status page's server over real sockets on 127.0.0.1: loopback by default, a token for anything else and
then on every request (401 and nothing else without it), read-only, and a browser that stops reading costs
neither time nor memory."""

from __future__ import annotations

import asyncio
import json
import logging
import socket
import struct
import tracemalloc
from pathlib import Path

import aiohttp
import pytest

from companion.cli import main
from companion.status import Bind, StatusHub, StatusServer, read_token
from companion.status.server import COOKIE
from planner.errors import FuseplanError

TOKEN = "s3cret-token-for-tests-0123456789"
PATHS = ("/", "/page.js", "/page.css", "/events", "/nothing-here", "/events.jsonl")


def test_the_default_bind_is_loopback() -> None:
    assert Bind.parse("8765") == Bind("127.0.0.1", 8765)
    assert Bind.parse("8765").loopback and Bind.parse("localhost:1").loopback and Bind.parse("[::1]:0").loopback
    assert Bind.parse("[::1]:0").host == "::1"
    for beyond in ("0.0.0.0:8765", "192.168.1.20:80", "companion.local:8765", "[::]:8765"):
        assert not Bind.parse(beyond).loopback, beyond
    for bad in ("", "abc", "8765:", ":8765", "70000", "-1", "host:port"):
        with pytest.raises(FuseplanError, match="expected PORT or HOST:PORT"):
            Bind.parse(bad)


@pytest.mark.asyncio
async def test_a_server_with_the_default_bind_listens_on_loopback_only() -> None:
    async with StatusServer(StatusHub(), Bind.parse("0")) as server:
        assert server.addresses == [("127.0.0.1", server.port)]
        assert server.url == f"http://127.0.0.1:{server.port}/"


def test_beyond_loopback_a_token_file_is_required(tmp_path: Path) -> None:
    with pytest.raises(FuseplanError, match="--status-token FILE"):
        read_token(None, Bind.parse("0.0.0.0:8765"))
    with pytest.raises(FuseplanError, match="needs a token"):
        StatusServer(StatusHub(), Bind.parse("0.0.0.0:8765"))
    short = tmp_path / "short"
    short.write_text("abc\n")
    short.chmod(0o600)
    with pytest.raises(FuseplanError, match="16 characters"):
        read_token(short, Bind.parse("0.0.0.0:8765"))
    with pytest.raises(FuseplanError, match="file not found"):
        read_token(tmp_path / "missing", Bind.parse("8765"))
    good = tmp_path / "token"
    good.write_text(f"  {TOKEN}\nsecond line ignored\n")
    good.chmod(0o644)
    with pytest.raises(FuseplanError, match="other users have access"):  # read as every secret is
        read_token(good, Bind.parse("0.0.0.0:8765"))
    assert read_token(good, Bind.parse("0.0.0.0:8765"), insecure=True) == TOKEN
    good.chmod(0o600)
    assert read_token(good, Bind.parse("0.0.0.0:8765")) == TOKEN
    assert read_token(None, Bind.parse("8765")) is None


def test_fly_refuses_a_page_beyond_loopback_without_a_token_before_planning(
        rescue_static: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["fly", str(rescue_static), "--sim", "--status-page", "0.0.0.0:0", "--report", str(tmp_path / "r")])
    err = capsys.readouterr()
    assert code == 2 and "planning" not in err.out
    assert err.err.strip().count("\n") == 0 and "--status-token FILE" in err.err
    code = main(["fly", str(rescue_static), "--sim", "--status-token", str(tmp_path / "t"), "--report",
                 str(tmp_path / "r")])
    assert code == 2 and "--status-token goes with --status-page" in capsys.readouterr().err
    with socket.socket() as taken:  # a port already in use: refused before planning, and no report written
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code = main(["fly", str(rescue_static), "--sim", "--status-page", str(port), "--report", str(tmp_path / "r")])
    err = capsys.readouterr()
    assert code == 2 and "planning" not in err.out and f"127.0.0.1:{port}: cannot listen" in err.err
    assert not (tmp_path / "r").exists()


async def _get(session: aiohttp.ClientSession, url: str, method: str = "GET", **kw) -> tuple[int, bytes, dict]:
    async with session.request(method, url, **kw) as r:
        body = await r.content.read(4096) if r.status == 200 and url.split("?")[0].endswith("/events") \
            else await r.read()
        return r.status, body, dict(r.headers)


@pytest.mark.asyncio
async def test_a_bad_or_missing_token_gets_401_and_nothing_else() -> None:
    hub = StatusHub()
    hub.publish({"event": "scene", "name": "secret-map"})
    async with StatusServer(hub, Bind.parse("0"), TOKEN) as server, aiohttp.ClientSession() as s:
        base = server.url.rstrip("/")
        tries = [{}, {"params": {"token": "wrong"}}, {"headers": {"Authorization": "Bearer wrong"}},
                 {"headers": {"Authorization": f"Basic {TOKEN}"}}, {"headers": {"Cookie": f"{COOKIE}=wrong"}},
                 {"params": {"token": TOKEN[:-1]}}]
        for path in PATHS:
            for kw in tries:
                for method in ("GET", "POST", "HEAD"):
                    status, body, headers = await _get(s, base + path, method, **kw)
                    assert status == 401, (path, kw, method)
                    assert b"secret-map" not in body and b"<html" not in body and b"EventSource" not in body
                    assert COOKIE not in headers.get("Set-Cookie", "")
        # with the token: by query (which also sets the cookie), by header, by cookie alone
        status, body, headers = await _get(s, base + "/", params={"token": TOKEN})
        assert status == 200 and b"<svg" in body and f"{COOKIE}={TOKEN}" in headers["Set-Cookie"]
        assert "HttpOnly" in headers["Set-Cookie"] and "SameSite=Strict" in headers["Set-Cookie"]
        assert headers["Referrer-Policy"] == "no-referrer"
        status, body, _ = await _get(s, base + "/page.js", headers={"Authorization": f"Bearer {TOKEN}"})
        assert status == 200 and b"EventSource" in body
        status, body, _ = await _get(s, base + "/events", headers={"Cookie": f"{COOKIE}={TOKEN}"})
        assert status == 200 and body.startswith(b"event: reset") and b"secret-map" in body
        # read-only: nothing but GET and HEAD, even with the token
        for method in ("POST", "PUT", "DELETE", "PATCH"):
            status, _, headers = await _get(s, base + "/events", method, params={"token": TOKEN})
            assert status == 405 and headers["Allow"] == "GET, HEAD"


@pytest.mark.asyncio
async def test_the_event_stream_carries_the_records_in_order() -> None:
    hub = StatusHub()
    async with StatusServer(hub, Bind.parse("0")) as server, aiohttp.ClientSession() as s:
        async with s.get(server.url + "events") as r:
            assert r.status == 200 and r.headers["Content-Type"] == "text/event-stream"
            assert await r.content.readuntil(b"\n\n") == b"event: reset\ndata: {}\n\n"
            for n in range(20):
                hub.publish({"event": "position", "n": n})
            got = [json.loads((await r.content.readuntil(b"\n\n")).split(b"data: ")[1]) for _ in range(20)]
            assert [g["n"] for g in got] == list(range(20))


@pytest.mark.asyncio
async def test_a_browser_that_vanishes_mid_stream_is_let_go(caplog: pytest.LogCaptureFixture) -> None:
    """A connection reset in the middle of the stream (a phone leaving the Wi-Fi) ends that reader and nothing
    else: the others go on, and nothing is logged as an error."""
    hub = StatusHub()
    async with StatusServer(hub, Bind.parse("0")) as server, aiohttp.ClientSession() as s:
        gone = _stalled_client(server.port)
        gone.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))  # close → RST
        async with s.get(server.url + "events") as r:
            while hub.readers < 2:
                await asyncio.sleep(0.01)
            for n in range(2000):
                hub.publish({"event": "position", "n": n, "pad": "x" * 1000})
                if n == 100:
                    gone.close()
                if n % 20 == 19:
                    await asyncio.sleep(0.001)
            while hub.readers > 1:
                await asyncio.sleep(0.01)
            await r.content.readuntil(b"\n\n")  # the reset
            got = [json.loads((await r.content.readuntil(b"\n\n")).split(b"data: ")[1])["n"] for _ in range(2000)]
    assert got == list(range(2000))
    assert not [rec for rec in caplog.records if rec.levelno >= logging.ERROR], caplog.text


async def _count_in_order(session: aiohttp.ClientSession, url: str) -> int:
    """How many records came, each ``n`` the one after the last (kept as a count: the test measures the
    server's memory in this same process)."""
    n = 0
    async with session.get(url) as r:
        async for line in r.content:
            if line.startswith(b"data: ") and line != b"data: {}\n":  # not the reset
                assert json.loads(line[6:])["n"] == n
                n += 1
    return n


def _stalled_client(port: int) -> socket.socket:
    """A client that asks for the event stream and does not read (a 4 KiB receive buffer)."""
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(("127.0.0.1", port))
    sock.sendall(f"GET /events HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode())
    return sock


async def _records_until(sock: socket.socket, last: int) -> list[dict]:
    """Records a stalled client reads once it reads again, until the one numbered ``last`` (the body is HTTP/1.1
    chunked: undone here by hand, as this client is a bare socket)."""
    sock.setblocking(False)
    loop = asyncio.get_running_loop()
    rest = b""
    while b"\r\n\r\n" not in rest:
        rest += await loop.sock_recv(sock, 1 << 16)
    rest = rest.split(b"\r\n\r\n", 1)[1]
    parts: list[bytes] = []
    marker = f'"n":{last},'.encode()
    while True:
        while b"\r\n" in rest:
            size, _, tail = rest.partition(b"\r\n")
            n = int(size, 16)
            if len(tail) < n + 2:
                break
            parts.append(tail[:n])
            rest = tail[n + 2:]
        if parts and marker in parts[-1] and parts[-1].endswith(b"\n\n"):
            body = b"".join(parts)
            return [json.loads(x[6:]) for x in body.split(b"\n") if x.startswith(b"data: ") and x != b"data: {}"]
        rest += await loop.sock_recv(sock, 1 << 16)


@pytest.mark.asyncio
async def test_a_browser_that_stops_reading_costs_neither_time_nor_memory() -> None:
    """Five readers, one client that stops reading and one that never reads; 3000 records of ~4 kB (12 MB; the
    ring holds 250, 1 MB; the kernel's socket buffers take up to ~4 MB a connection). The readers get every record, the
    server's memory stays near its ring, the slow client, reading again, finds the oldest dropped and is told,
    and the server stops without waiting for the one that never reads."""
    hub = StatusHub(history=250)
    pad = "x" * 4000
    async with aiohttp.ClientSession() as s:
        server = StatusServer(hub, Bind.parse("0"))
        await server.__aenter__()
        slow, gone = _stalled_client(server.port), _stalled_client(server.port)
        readers = [asyncio.create_task(_count_in_order(s, server.url + "events")) for _ in range(5)]
        while hub.readers < 7:
            await asyncio.sleep(0.01)
        tracemalloc.start()
        base, _ = tracemalloc.get_traced_memory()
        for n in range(3000):
            hub.publish({"event": "position", "n": n, "pad": pad})
            if n % 5 == 4:
                await asyncio.sleep(0.001)  # the readers run meanwhile, as a flight's loop would let them
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        with slow:
            records = await asyncio.wait_for(_records_until(slow, 2999), 30)
        await asyncio.wait_for(server.__aexit__(None, None, None), 15)  # without the cut it waits 60 s for `gone`
        gone.close()
        got = await asyncio.wait_for(asyncio.gather(*readers), 15)
    assert got == [3000] * 5
    assert peak - base < 4 * 2**20, f"the server's memory grew by {(peak - base) / 2**20:.1f} MiB"
    numbers = [r["n"] for r in records if "n" in r]
    skipped = [r for r in records if r["event"] == "status_skipped"]
    assert len(skipped) == 1 and skipped[0]["records"] > 0, "the slow client should have lost the oldest records"
    assert len(numbers) + skipped[0]["records"] == 3000 and numbers[-1] == 2999
    assert numbers == sorted(numbers) and hub.skipped >= skipped[0]["records"]

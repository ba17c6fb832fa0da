"""The status hub: every reader gets every record in order; a reader that falls behind loses only the oldest
(and is told); memory is the ring's, whatever the number of readers or how slow they are."""

from __future__ import annotations

import asyncio
import json
import math
import threading
import tracemalloc

import pytest

from companion.status.hub import StatusHub, sse


def parse(chunks: list[bytes]) -> list[dict]:
    """The ``data`` records of SSE chunks (the ``reset`` event as {"event": "reset"})."""
    out = []
    for block in b"".join(chunks).decode().split("\n\n"):
        lines = block.split("\n")
        if "event: reset" in lines:
            out.append({"event": "reset"})
        out.extend(json.loads(x[6:]) for x in lines if x.startswith("data: ") and "event: reset" not in lines)
    return out


async def drain(hub: StatusHub, limit: int = 10**6) -> list[dict]:
    """Everything a reader gets until the hub closes."""
    chunks = []
    async for chunk in hub.read():
        chunks.append(chunk)
        if len(chunks) > limit:
            break
    return parse(chunks)


@pytest.mark.asyncio
async def test_readers_get_every_record_in_order_from_the_start() -> None:
    hub = StatusHub()
    hub.publish({"event": "scene", "n": 0})
    early = asyncio.create_task(drain(hub))
    await asyncio.sleep(0)
    for n in range(1, 500):
        hub.publish({"event": "position", "n": n})
        if n % 50 == 0:
            await asyncio.sleep(0)  # the reader runs meanwhile
    late = asyncio.create_task(drain(hub))  # joins after all of it
    await asyncio.sleep(0)
    hub.close()
    for got in (await early, await late):
        assert got[0] == {"event": "reset"}
        assert [r["n"] for r in got[1:]] == list(range(500))
    assert hub.readers == 0 and hub.skipped == 0


@pytest.mark.asyncio
async def test_a_reader_that_falls_behind_loses_the_oldest_and_keeps_the_map() -> None:
    hub = StatusHub(history=100)
    hub.publish({"event": "scene", "name": "map"})
    hub.publish({"event": "mission", "count": 3})
    reader = hub.read()
    assert await reader.__anext__() == b"event: reset\ndata: {}\n\n"
    first = parse([await reader.__anext__()])  # it takes what is there, then stops reading
    assert [r["event"] for r in first] == ["scene", "mission"]
    for n in range(1000):  # meanwhile the flight goes on
        hub.publish({"event": "position", "n": n})
    hub.close()
    rest = []
    async for chunk in reader:
        rest.append(chunk)
    got = parse(rest)
    assert got[0]["event"] == "status_skipped" and got[0]["records"] == 900  # 1002 published, 100 kept
    assert [r["event"] for r in got[1:3]] == ["scene", "mission"]  # pinned: re-sent, it no longer finds them
    assert [r["n"] for r in got[3:]] == list(range(900, 1000))
    assert hub.skipped == 900


@pytest.mark.asyncio
async def test_memory_is_the_rings_whatever_the_readers() -> None:
    """50 readers that never read past their first chunk, 20 000 records: the hub holds the ring and no more."""
    hub = StatusHub(history=2000)
    readers = [hub.read() for _ in range(50)]
    for r in readers:
        await r.__anext__()  # attached (the reset), then stalled
    record = {"event": "position", "x": 123.4, "y": 567.8, "z": 90.1, "gs": 18.0, "hdg": 271.5}
    tracemalloc.start()
    for _ in range(2000):
        hub.publish(record)
    base, _ = tracemalloc.get_traced_memory()
    for _ in range(20_000):
        hub.publish(record)
    now, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    ring = hub.buffered_bytes
    assert ring < 2000 * 200
    assert now - base < 64 * 1024, f"the hub grew by {now - base} bytes over 20 000 records (ring {ring} bytes)"
    assert peak - base < 64 * 1024
    hub.close()
    for r in readers:
        await r.aclose()
    assert hub.readers == 0


def test_records_go_out_as_strict_json() -> None:
    """A replan with no threat left in view has an infinite predicted separation: the log keeps Infinity, the
    browser's JSON.parse would refuse it, so the stream carries null."""
    frame = sse(7, {"event": "replan_planned", "separation_after_m": math.inf, "route": [[1.0, math.nan, 2.0]]})
    data = frame.decode().split("data: ")[1].strip()

    def refuse(name: str) -> None:
        raise ValueError(name)

    assert frame.startswith(b"id: 7\n") and frame.endswith(b"\n\n")
    assert json.loads(data, parse_constant=refuse) == {"event": "replan_planned", "separation_after_m": None,
                                                       "route": [[1.0, None, 2.0]]}


@pytest.mark.asyncio
async def test_publishing_from_another_thread_hops_onto_the_loop() -> None:
    hub = StatusHub()
    hub.bind(asyncio.get_running_loop())
    reader = asyncio.create_task(drain(hub))
    await asyncio.sleep(0)
    t = threading.Thread(target=lambda: [hub.publish({"event": "x", "n": n}) for n in range(100)])
    t.start()
    t.join()  # its records wait as callbacks on this loop
    await asyncio.sleep(0.05)
    hub.close()
    assert [r["n"] for r in (await reader)[1:]] == list(range(100))

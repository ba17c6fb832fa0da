"""Writing only what changed: MISSION_WRITE_PARTIAL_LIST as ArduPilot takes it, single MISSION_REQUEST_INTs outside
a transfer, and :meth:`MissionClient.upload_changed_verified` on top of them (docs/autopilots.md §3.8), with a
booted autopilot shared by the module. What ArduPilot does here was read in its MissionItemProtocol.cpp and is
held to SITL by these tests; the simulator must do the same."""

from __future__ import annotations

import contextlib
import statistics
import time
from collections.abc import Iterator
from dataclasses import replace

import pytest
from conformance.conftest import (
    collect,
    home_item,
    next_matching,
    numbered,
    takeoff,
    texts,
    waypoint,
)
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.mavlink.items import MISSION, MissionItem
from companion.mavlink.link import Message
from companion.mavlink.storage import mission_difference

pytestmark = pytest.mark.asyncio(loop_scope="module")

ACK_WAIT_S = 3.0  # wall seconds for an answer (30 s of the autopilot's time at speed-up 10)
RUNS = 10  # uploads timed per path


def mission(n_waypoints: int = 15, alt: float = 40.0) -> list[MissionItem]:
    """Home, take-off and ``n_waypoints`` waypoints on a square spiral: 2 + ``n_waypoints`` items."""
    wps = [waypoint(100.0 + 20.0 * i, 50.0 * (i % 4), alt) for i in range(n_waypoints)]
    return numbered([home_item(), takeoff(alt)] + wps)


def raised_tail(items: list[MissionItem], n: int, dz: float = 15.0) -> list[MissionItem]:
    """``items`` with the last ``n`` ``dz`` metres higher."""
    return items[:-n] + [replace(it, z=it.z + dz) for it in items[-n:]]


def difference(v, sent: list[MissionItem], got: list[MissionItem]) -> tuple | None:
    """The first difference between ``sent`` and the readback as the vehicle stores items (item 0 aside)."""
    return mission_difference(sent, got, home_at_zero=True, firmware=v.firmware)


@contextlib.contextmanager
def sent_by(link) -> Iterator[list[Message]]:
    """The mission-protocol messages the companion sends meanwhile (``link.send`` wrapped, then restored)."""
    sent: list[Message] = []
    send = link.send

    def recording(msg: Message) -> None:
        if msg.get_type().startswith("MISSION_"):
            sent.append(msg)
        send(msg)
    link.send = recording
    try:
        yield sent
    finally:
        del link.send  # the class's method again


def seqs(messages: list[Message], mtype: str) -> list[int]:
    return [m.seq for m in messages if m.get_type() == mtype]


def target(v) -> tuple[int, int]:
    return v.link.target_system, v.link.target_component


async def write_partial(v, items: list[MissionItem], start: int, end: int) -> tuple[list[Message], Message]:
    """MISSION_WRITE_PARTIAL_LIST(start, end), each request answered with ``items[seq]``: the requests and the
    MISSION_ACK that ended it."""
    ts, tc = target(v)
    requests: list[Message] = []
    with v.link.subscribe("MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ACK") as sub:
        v.link.send(mavlink.MAVLink_mission_write_partial_list_message(ts, tc, start, end, MISSION))
        while True:
            msg = await sub.get(ACK_WAIT_S)
            if msg.get_type() == "MISSION_ACK":
                return requests, msg
            requests.append(msg)
            v.link.send(replace(items[msg.seq], seq=msg.seq).to_message(ts, tc))


# ------------------------------------------------------------------------------------------------ the protocol
async def test_a_partial_write_requests_its_range_with_legacy_requests_and_acks_it(vehicle) -> None:
    """start..end requested one by one with the legacy MISSION_REQUEST, written in place, MISSION_ACK ACCEPTED;
    the count stays."""
    old = mission()
    await vehicle.client.upload_verified(old)
    new = raised_tail(old, 3)
    n = len(new)
    requests, ack = await write_partial(vehicle, new, n - 3, n - 1)
    assert ack.type == mavlink.MAV_MISSION_ACCEPTED
    assert {r.get_type() for r in requests} == {"MISSION_REQUEST"}
    assert sorted(set(seqs(requests, "MISSION_REQUEST"))) == [n - 3, n - 2, n - 1]
    assert difference(vehicle, new, await vehicle.client.download()) is None


async def test_a_partial_write_at_the_count_appends_one_item(vehicle) -> None:
    old = mission(5)
    await vehicle.client.upload_verified(old)
    n = len(old)
    longer = numbered(old + [waypoint(500.0, 500.0, 60.0)])
    requests, ack = await write_partial(vehicle, longer, n, n)
    assert ack.type == mavlink.MAV_MISSION_ACCEPTED and seqs(requests, "MISSION_REQUEST") == [n]
    assert difference(vehicle, longer, await vehicle.client.download()) is None


OUTSIDE = {  # (start, end) for a list of n items
    "start_past_the_count": lambda n: (n + 1, n + 1),
    "end_past_the_count": lambda n: (n - 1, n + 1),
    "end_before_start": lambda n: (3, 2),
}


@pytest.mark.parametrize("case", OUTSIDE)
async def test_a_partial_write_outside_the_list_is_an_error(vehicle, case: str) -> None:
    """start or end past the count, or end before start: MISSION_ACK MAV_MISSION_ERROR and "Flight plan update
    rejected", nothing requested, nothing written."""
    old = mission(3)
    await vehicle.client.upload_verified(old)
    first, last = OUTSIDE[case](len(old))
    ts, tc = target(vehicle)
    with vehicle.link.subscribe("MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ACK", "STATUSTEXT") as sub:
        vehicle.link.send(mavlink.MAVLink_mission_write_partial_list_message(ts, tc, first, last, MISSION))
        seen = await collect(sub, 0.5)
    assert [m.type for m in seen if m.get_type() == "MISSION_ACK"] == [mavlink.MAV_MISSION_ERROR]
    assert not [m for m in seen if m.get_type().startswith("MISSION_REQUEST")]
    assert "Flight plan update rejected" in texts(seen)
    assert difference(vehicle, old, await vehicle.client.download()) is None


async def test_during_a_partial_write_another_one_and_item_requests_are_denied(vehicle) -> None:
    """While a partial write waits for its items: a second MISSION_WRITE_PARTIAL_LIST (from the same sender too)
    and a MISSION_REQUEST_INT get MAV_MISSION_DENIED; the first write then completes. A readback must wait for the
    end of the write."""
    old = mission(5)
    await vehicle.client.upload_verified(old)
    new = raised_tail(old, 2)
    n = len(new)
    ts, tc = target(vehicle)
    with vehicle.link.subscribe("MISSION_REQUEST", "MISSION_ACK") as sub:
        vehicle.link.send(mavlink.MAVLink_mission_write_partial_list_message(ts, tc, n - 2, n - 1, MISSION))
        first = await next_matching(sub, lambda m: m.get_type() == "MISSION_REQUEST", ACK_WAIT_S)
        assert first.seq == n - 2
        vehicle.link.send(mavlink.MAVLink_mission_write_partial_list_message(ts, tc, 1, 1, MISSION))
        denied = await next_matching(sub, lambda m: m.get_type() == "MISSION_ACK", ACK_WAIT_S)
        vehicle.link.send(mavlink.MAVLink_mission_request_int_message(ts, tc, 1, MISSION))
        denied_read = await next_matching(sub, lambda m: m.get_type() == "MISSION_ACK", ACK_WAIT_S)
        assert (denied.type, denied_read.type) == (mavlink.MAV_MISSION_DENIED, mavlink.MAV_MISSION_DENIED)
        for seq in (n - 2, n - 1):
            if seq != n - 2:
                await next_matching(sub, lambda m, s=seq: m.get_type() == "MISSION_REQUEST" and m.seq == s,
                                    ACK_WAIT_S)
            vehicle.link.send(new[seq].to_message(ts, tc))
        done = await next_matching(sub, lambda m: m.get_type() == "MISSION_ACK", ACK_WAIT_S)
    assert done.type == mavlink.MAV_MISSION_ACCEPTED
    assert difference(vehicle, new, await vehicle.client.download()) is None


async def test_a_single_item_request_is_answered_outside_a_transfer(vehicle) -> None:
    """Downloads keep no state: MISSION_REQUEST_INT for one seq, without MISSION_REQUEST_LIST first, is answered
    with that MISSION_ITEM_INT; one past the end with MISSION_COUNT (the real count) and MISSION_ACK
    MAV_MISSION_INVALID_SEQUENCE."""
    items = mission(5)
    await vehicle.client.upload_verified(items)
    ts, tc = target(vehicle)
    with vehicle.link.subscribe("MISSION_ITEM_INT", "MISSION_COUNT", "MISSION_ACK") as sub:
        vehicle.link.send(mavlink.MAVLink_mission_request_int_message(ts, tc, 4, MISSION))
        got = await sub.get(ACK_WAIT_S)
        assert got.get_type() == "MISSION_ITEM_INT" and got.seq == 4
        assert difference(vehicle, items[4:5], [MissionItem.from_message(got)]) is None
        vehicle.link.send(mavlink.MAVLink_mission_request_int_message(ts, tc, len(items), MISSION))
        answers = [await sub.get(ACK_WAIT_S), await sub.get(ACK_WAIT_S)]
    assert [a.get_type() for a in answers] == ["MISSION_COUNT", "MISSION_ACK"]
    assert answers[0].count == len(items) and answers[1].type == mavlink.MAV_MISSION_INVALID_SEQUENCE


# ------------------------------------------------------------------------------------------------ the client
async def test_upload_changed_verified_writes_and_reads_back_only_the_changed_tail(vehicle) -> None:
    old = mission()
    await vehicle.client.upload_verified(old)
    new = raised_tail(old, 4)
    n = len(new)
    with (vehicle.link.subscribe("MISSION_REQUEST", "MISSION_REQUEST_INT") as asked, sent_by(vehicle.link) as sent):
        path = await vehicle.client.upload_changed_verified(new, old)
        requests = asked.drain()
    assert path == f"partial {n - 4}-{n - 1}"
    assert sorted(set(seqs(requests, "MISSION_REQUEST"))) == list(range(n - 4, n))
    assert not seqs(requests, "MISSION_REQUEST_INT")
    kinds = [m.get_type() for m in sent]
    assert "MISSION_COUNT" not in kinds and kinds.count("MISSION_WRITE_PARTIAL_LIST") == 1
    assert kinds.count("MISSION_REQUEST_LIST") == 1
    assert sorted(set(seqs(sent, "MISSION_REQUEST_INT"))) == list(range(n - 4, n))
    assert difference(vehicle, new, await vehicle.client.download()) is None

    assert await vehicle.client.upload_changed_verified(new, new) == "unchanged"


async def test_upload_changed_verified_with_another_length_uploads_the_whole_list(vehicle) -> None:
    old = mission()
    await vehicle.client.upload_verified(old)
    shorter = raised_tail(old[:-3], 2)
    with vehicle.link.subscribe("MISSION_REQUEST", "MISSION_REQUEST_INT") as asked:
        assert await vehicle.client.upload_changed_verified(shorter, old) == "whole"
        requests = asked.drain()
    assert sorted(set(seqs(requests, "MISSION_REQUEST"))) == list(range(len(shorter)))
    assert difference(vehicle, shorter, await vehicle.client.download()) is None


async def test_a_partial_write_exchanges_less_than_the_whole_upload(vehicle, measure) -> None:
    """17 items (home, take-off, 15 waypoints): the whole verified upload against a partial one that changes the
    last 10, 10 of each. The partial path sends only the 10 changed items and reads only those back: fewer
    mission-protocol messages every time. Their wall times are measured and printed, not asserted (a shared
    machine's timing is noise: ArduCopter SITL once took 26.8 ms for the partial path against 24.1 ms for the
    whole one)."""
    a = mission()
    b = raised_tail(a, 10)
    await vehicle.client.upload_verified(a)
    whole, partial, whole_sent, partial_sent = [], [], [], []
    for _ in range(RUNS):
        t0 = time.perf_counter()
        with sent_by(vehicle.link) as sent:
            await vehicle.client.upload_verified(a)
        whole.append(time.perf_counter() - t0)
        whole_sent.append(sent)
    previous = a
    for i in range(RUNS):
        nxt = b if i % 2 == 0 else a
        t0 = time.perf_counter()
        with sent_by(vehicle.link) as sent:
            assert await vehicle.client.upload_changed_verified(nxt, previous) == "partial 7-16"
        partial.append(time.perf_counter() - t0)
        partial_sent.append(sent)
        previous = nxt
    w, p = statistics.median(whole), statistics.median(partial)
    measure(f"17 items, whole upload_verified median {w * 1e3:.1f} ms (min {min(whole) * 1e3:.1f}, "
            f"max {max(whole) * 1e3:.1f}); partial 7-16 median {p * 1e3:.1f} ms (min {min(partial) * 1e3:.1f}, "
            f"max {max(partial) * 1e3:.1f}); ratio {p / w:.2f}")

    def items_written(sent: list[Message]) -> set[int]:
        return {m.seq for m in sent if m.get_type() in ("MISSION_ITEM_INT", "MISSION_ITEM")}

    assert all(items_written(s) == set(range(7, 17)) for s in partial_sent)
    assert all(items_written(s) >= set(range(1, 17)) for s in whole_sent)
    assert max(len(s) for s in partial_sent) < min(len(s) for s in whole_sent)

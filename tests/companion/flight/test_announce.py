"""companion.flight.announce: the flight's decisions as STATUSTEXT lines, read off the wire by a receiver that shares
no code with the companion's link (pymavlink's parser on a bare UDP socket, between the companion and our simulated
autopilot)."""

from __future__ import annotations

import asyncio
import json
import math
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from readback import assert_the_tlog_holds_the_flight

from companion.flight.announce import PREFIX, Announcer, line_for, with_prefix
from companion.flight.fly import FlyOptions, fly, truth_separations
from companion.flight.supervisor import DepartureRefused
from companion.mavlink.link import Link
from companion.mavlink.statustext import TEXT_BYTES, Reassembler, Severity
from companion.mission.events import EventLog
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]
DYNAMIC = ROOT / "sitl_scenarios" / "rescue_dynamic.toml"
QUICK_PLAN = ("planner.pso.n_pop=200", "planner.pso.max_iter=80")  # a feasible plan in ~2 s

# one record of each decision, with the fields its code logs (supervisor, replanning, fly)
DECISIONS = [
    ({"event": "plan_accepted", "length_m": 992.1, "min_clearance_m": 14.35, "waypoints": 8},
     "plan accepted: 992 m, clearance 14.3 m", Severity.INFO),
    ({"event": "upload_verified", "seconds": 0.41}, "mission uploaded and verified", Severity.INFO),
    ({"event": "conflict", "n": 1, "threat": "intruder-1", "in_s": 22.6, "separation_m": 11.8, "d_coll_m": 20.0},
     "conflict: intruder-1 in 23 s, sep 12 m", Severity.WARNING),
    ({"event": "hold", "mode": "GUIDED", "reason": "no safe plan within 2 s (approximate, predicted separation 9 m)",
      "pattern": {}}, "hold (GUIDED): no safe plan within 2 s", Severity.WARNING),
    ({"event": "resume", "reason": "x", "seq": 5}, "hold over: mission resumed", Severity.NOTICE),
    ({"event": "replanned", "n": 2, "threat": "adsb-c0ffee", "sep_after_m": 41.2}, "replan 2 live, sep 41 m",
     Severity.NOTICE),
    ({"event": "replan_upload_failed", "n": 2, "attempt": 1, "error": "timeout"}, "replan 2 upload failed (try 1)",
     Severity.WARNING),
    ({"event": "link_restored", "outage_s": 6.2}, "link lost 6 s, back", Severity.WARNING),
    ({"event": "finished", "completed": False, "reason": "timeout after 60 s", "reached": 3},
     "flight not completed: timeout after 60 s", Severity.WARNING),
    ({"event": "finished", "completed": True, "reason": "goal waypoint reached", "reached": 9},
     "flight complete: goal reached", Severity.INFO),
]


@pytest.mark.parametrize(("record", "text", "severity"), DECISIONS, ids=[str(k) for k in range(len(DECISIONS))])
def test_each_decision_has_one_short_line_at_its_severity(record, text, severity) -> None:
    assert line_for(record)[:2] == (text, severity)
    assert len(with_prefix(text)) <= TEXT_BYTES and with_prefix(text).startswith(PREFIX)


def test_routine_and_malformed_records_are_not_announced() -> None:
    for record in ({"event": "position", "x": 1}, {"event": "timeout", "seconds": 60.0},
                   {"event": "statustext", "text": "Mission: 3 WP"},
                   {"event": "link_lost", "age_s": 3.0}, {"event": "conflict", "threat": "x"}, {}):
        assert line_for(record) is None


def test_the_prefix_is_left_out_only_where_it_alone_would_need_a_second_chunk() -> None:
    assert with_prefix("x" * 40) == PREFIX + "x" * 40
    assert with_prefix("x" * 45) == "x" * 45
    assert with_prefix("x" * 60) == PREFIX + "x" * 60  # chunked anyway


@pytest.mark.asyncio
async def test_repeats_are_limited_and_a_refusal_is_logged_and_sent_on_the_way_out(raw_peer) -> None:
    """Over a real Link: a conflict with the same traffic predicted again is sent once per REPEAT_S, another
    threat's at once; leaving on a refusal logs plan_refused and sends it (chunked: the why is long) at ERROR."""
    events, now = EventLog(), [0.0]
    why = "the vehicle is 412 m from the route's start, beyond the 300 m the departure may fly unchecked"
    async with Link(f"udpout:127.0.0.1:{raw_peer.port}") as link:
        await raw_peer.recv_type("HEARTBEAT")
        with pytest.raises(DepartureRefused), Announcer(link, events, repeat_s=10.0, clock=lambda: now[0]) as ann:
            for t, threat in ((0.0, "a"), (4.0, "a"), (5.0, "b"), (11.0, "a")):
                now[0] = t
                events.log("conflict", n=1, threat=threat, in_s=9.0, separation_m=5.0, d_coll_m=20.0)
            raise DepartureRefused(why)
        events.log("finished", completed=True, reason="", reached=1)  # after leaving: not sent
        got, joiner = [], Reassembler()
        while len(got) < 4:
            for m in await raw_peer.recv(2.0):
                if m.get_type() == "STATUSTEXT" and (line := joiner.feed(m)) is not None:
                    got.append((m.severity, line))
    assert [r["event"] for r in events.records][-2:] == ["plan_refused", "finished"]
    assert got == ann.sent == [
        (Severity.WARNING, "fuseplan: conflict: a in 9 s, sep 5 m"),
        (Severity.WARNING, "fuseplan: conflict: b in 9 s, sep 5 m"),
        (Severity.WARNING, "fuseplan: conflict: a in 9 s, sep 5 m"),
        (Severity.ERROR, f"fuseplan: plan refused: {why}")]


class _Tap(asyncio.DatagramProtocol):
    """A UDP relay between the companion and the simulator that parses what the companion sends (the simulator
    routes nothing on: it has one port) and keeps its STATUSTEXT lines."""

    def __init__(self, target: tuple[str, int]) -> None:
        self.target, self.client, self.back = target, None, None
        self.parser = mavlink.MAVLink(None)
        self.parser.robust_parsing = True
        self.joiner, self.lines = Reassembler(), []

    def datagram_received(self, data: bytes, addr: tuple) -> None:
        self.client = addr
        for m in self.parser.parse_buffer(data) or []:
            if m.get_type() == "STATUSTEXT" and (line := self.joiner.feed(m)) is not None:
                self.lines.append((m.severity, line))
        self.back.sendto(data)


@pytest.mark.asyncio
async def test_a_replanning_flight_on_the_simulator_says_what_it_decides(tmp_path) -> None:
    """rescue_dynamic on our simulator (20x), flown through `fly --connect`: the lines on the wire are the plan
    accepted with its length and clearance, the mission verified, the conflict, the replan or hold that answered
    it, and the end, in that order and at their severities; none needs a second chunk. The flight itself is held to
    what test_replanning.py's rescue_dynamic flight asks (completed, every intruder kept at d_coll by the truth
    track), so that one could be left out of the default run in favour of this one."""
    from companion.cli import _plan_doc_for
    from companion.sim import SimAutopilot

    doc, sc = _plan_doc_for(DYNAMIC, None, list(QUICK_PLAN), None, feasible_only=True, for_flight=True)
    loop = asyncio.get_running_loop()
    async with SimAutopilot(load_scenario(DYNAMIC), "udpin:127.0.0.1:0", speedup=20.0) as sim:
        tap = _Tap(("127.0.0.1", sim.port))
        front, _ = await loop.create_datagram_endpoint(lambda: tap, local_addr=("127.0.0.1", 0))

        class Back(asyncio.DatagramProtocol):
            def datagram_received(self, data: bytes, addr: tuple) -> None:
                if tap.client is not None:
                    front.sendto(data, tap.client)

        tap.back, _ = await loop.create_datagram_endpoint(Back, remote_addr=("127.0.0.1", sim.port))
        try:
            (tmp_path / "r").mkdir()
            opts = FlyOptions(connect=f"udpout:127.0.0.1:{front.get_extra_info('sockname')[1]}", arm=True,
                              report=tmp_path / "r", flight_timeout=90.0)
            events = EventLog(tmp_path / "r" / "events.jsonl")
            flight = await fly(doc, sc, opts, events)
            events.close()
            # the simulator's truth, up to the goal (as fly --sim reports it: flight.json has none through --connect)
            seps = truth_separations(sim, sc, sim.reached_at.get(max(flight["items_reached"]), math.inf))
        finally:
            front.close()
            tap.back.close()
            await loop.shutdown_default_executor()  # fly's threads (asyncio.to_thread)
    names = [r["event"] for r in events.records]
    texts = [t for _, t in tap.lines]
    assert flight["completed"], (flight["reason"], texts)
    assert "conflict" in names, names
    intruders = {i.id for i in sc.intruders}
    assert intruders <= set(seps) and all(seps[k].separation >= sc.hazard.d_coll for k in intruders), seps
    accepted = next(r for r in events.records if r["event"] == "plan_accepted")
    assert accepted["length_m"] == round(doc["metrics"]["length_m"], 1)
    assert tap.lines[:2] == [
        (Severity.INFO, f"fuseplan: plan accepted: {doc['metrics']['length_m']:.0f} m, clearance "
                        f"{doc['metrics']['min_clearance_m']:.1f} m"),
        (Severity.INFO, "fuseplan: mission uploaded and verified")]
    first = next(k for k, t in enumerate(texts) if t.startswith("fuseplan: conflict: "))
    answer = [t for t in texts[first:] if " live, sep " in t or t.startswith("fuseplan: hold (")]
    assert answer and tap.lines[first][0] == Severity.WARNING, texts
    assert tap.lines[-1] == (Severity.INFO, "fuseplan: flight complete: goal reached")
    assert all(len(t) <= TEXT_BYTES for t in texts)
    assert len(texts) < 20, texts  # rate-limited: not one line per replanning look
    flown = json.loads((tmp_path / "r" / "flight.json").read_text())
    assert flown["completed"] and flown["tlog"] == "flight.tlog"
    assert_the_tlog_holds_the_flight(tmp_path / "r")  # the flight record: every message of the link, replans too

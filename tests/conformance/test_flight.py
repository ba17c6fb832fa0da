"""Flying: the start sequences, MISSION_ITEM_REACHED and the acceptance radius, and what happens at the end of
the mission. Two short flights per backend, each on a freshly started autopilot, recorded once and asserted on
by several tests:

* ``loiter_flight``: takeoff, three waypoints, NAV_LOITER_UNLIM (fuseplan's "loiter" end action);
* ``open_end_flight``: takeoff, two waypoints and nothing after them.

A plane takes off straight ahead (north on SITL, whose runway heading is 0), so its waypoints start 450 m north;
its legs are 250-300 m, a copter's 150 m. Positions come from GLOBAL_POSITION_INT (asked at 10 Hz of the
autopilot's time), simulated time from its ``time_boot_ms``.
"""

from __future__ import annotations

import time
from collections.abc import AsyncIterator, Callable
from contextlib import AbstractAsyncContextManager
from dataclasses import dataclass, field

import pytest
import pytest_asyncio
from conformance.conftest import (
    Vehicle,
    home_item,
    horizontal_m,
    loiter_unlim,
    numbered,
    ready,
    takeoff,
    texts,
    waypoint,
)
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.mavlink.errors import CompanionError
from companion.mavlink.items import MissionItem
from companion.mavlink.link import Message
from companion.mission.events import EventLog

pytestmark = pytest.mark.asyncio(loop_scope="module")

PLANE_ALT, COPTER_ALT = 50.0, 20.0
PLANE_ROUTE = ((450.0, 0.0, 30.0), (450.0, 250.0, 60.0), (200.0, 250.0, 30.0))  # north m, east m, param2 m
COPTER_ROUTE = ((150.0, 0.0), (150.0, 150.0), (0.0, 150.0))
PLANE_LOITER_RADIUS = 60.0
# ArduPlane flies a loiter wider than its radius (its L1 loiter law): 60 m was flown 77.3-78.6 m from the point
# on SITL at 10x (the simulator, flying the same law: 76.3-81.5 m)
PLANE_LOITER_FLOWN_M, PLANE_LOITER_FLOWN_TOLERANCE_M = 78.0, 6.0
AUTO = {True: 10, False: 3}  # custom mode, by plane
RTL_PLANE = 11
PLANE_TOLERANCE_M = 5.0  # |distance at REACHED - param2|: ArduPlane checks at 10 Hz, positions are ≤ 0.1 s old
COPTER_REACHED_M = 2.5  # WPNAV_RADIUS 2 m, and a decelerating copter's position up to 0.1 s old
FLIGHT_TIMEOUT_S = 90.0  # wall


@dataclass
class Flight:
    """What the companion saw of one flight (times in the autopilot's seconds since boot)."""

    backend: str
    items: list[MissionItem]
    events: EventLog
    start_error: CompanionError | None = None
    positions: list[tuple[float, float, float, float]] = field(default_factory=list)  # (t, lat, lon, rel alt)
    reached: list[tuple[int, float]] = field(default_factory=list)  # (seq, horizontal m from the last position)
    currents: list[int] = field(default_factory=list)  # MISSION_CURRENT.seq, each change
    modes: list[tuple[float, int, bool]] = field(default_factory=list)  # (t, custom mode, armed), each change
    statustexts: list[Message] = field(default_factory=list)
    done_at: float | None = None  # when the flight's end condition held

    @property
    def plane(self) -> bool:
        return self.backend.endswith("plane")

    @property
    def now(self) -> float:
        return self.positions[-1][0] if self.positions else 0.0

    @property
    def texts(self) -> list[str]:
        return texts(self.statustexts)

    def waypoint_seqs(self) -> list[int]:
        return [it.seq for it in self.items if it.command == mavlink.MAV_CMD_NAV_WAYPOINT and it.seq > 0]

    def after(self, t: float) -> list[tuple[float, float, float, float]]:
        return [p for p in self.positions if p[0] >= t]

    def add(self, msg: Message) -> None:
        kind = msg.get_type()
        if kind == "GLOBAL_POSITION_INT":
            self.positions.append((msg.time_boot_ms / 1000.0, msg.lat / 1e7, msg.lon / 1e7, msg.relative_alt / 1e3))
        elif kind == "MISSION_ITEM_REACHED" and msg.seq not in [s for s, _ in self.reached]:
            target = self.items[msg.seq] if msg.seq < len(self.items) else None
            last = self.positions[-1] if self.positions else None
            d = horizontal_m(last[1], last[2], target) if target is not None and last is not None else float("nan")
            self.reached.append((msg.seq, d))
        elif kind == "MISSION_CURRENT" and (not self.currents or self.currents[-1] != msg.seq):
            self.currents.append(msg.seq)
        elif kind == "HEARTBEAT":
            state = (msg.custom_mode, bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED))
            if not self.modes or self.modes[-1][1:] != state:
                self.modes.append((self.now, *state))
        elif kind == "STATUSTEXT":
            self.statustexts.append(msg)


async def fly(v: Vehicle, items: list[MissionItem], done: Callable[[Flight], bool], observe_s: float) -> Flight:
    """Upload and verify ``items``, wait until ready, start as FlightSupervisor.start does (arm=True), and record
    until ``done`` has held for ``observe_s`` seconds of the autopilot's time."""
    await v.client.upload_verified(items)
    await v.supervisor.wait_ready(60.0)
    flight = Flight(v.backend, items, v.events)
    with v.link.subscribe("GLOBAL_POSITION_INT", "MISSION_ITEM_REACHED", "MISSION_CURRENT", "HEARTBEAT",
                          "STATUSTEXT") as sub:
        try:
            await v.supervisor.start(1)
        except CompanionError as e:
            flight.start_error = e
            return flight
        deadline = time.monotonic() + FLIGHT_TIMEOUT_S
        while time.monotonic() < deadline:
            try:
                flight.add(await sub.get(0.5))
            except TimeoutError:
                continue
            if flight.done_at is None and done(flight):
                flight.done_at = flight.now
            if flight.done_at is not None and flight.now - flight.done_at >= observe_s:
                break
    return flight


def _mission(plane: bool, loiter: bool) -> list[MissionItem]:
    if plane:
        route = [waypoint(n, e, PLANE_ALT, param2=r) for n, e, r in PLANE_ROUTE]
        end = [loiter_unlim(200.0, 0.0, PLANE_ALT, radius=PLANE_LOITER_RADIUS)]
        items = [home_item(), takeoff(PLANE_ALT, pitch=10.0)] + (route if loiter else route[:2])
    else:
        route = [waypoint(n, e, COPTER_ALT) for n, e in COPTER_ROUTE[:2]]
        end = [loiter_unlim(*COPTER_ROUTE[2], COPTER_ALT)]
        items = [home_item(), takeoff(COPTER_ALT)] + route
    return numbered(items + (end if loiter else []))


async def _record(launch: Callable[[], AbstractAsyncContextManager], loiter: bool) -> Flight:
    async with launch() as v:
        await ready(v)
        items = _mission(v.plane, loiter)
        if loiter:
            loiter_seq = len(items) - 1
            return await fly(v, items, lambda f: loiter_seq in f.currents, observe_s=40.0)
        last = items[-1].seq
        return await fly(v, items, lambda f: last in [s for s, _ in f.reached], observe_s=15.0)


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def loiter_flight(launch) -> AsyncIterator[Flight]:
    yield await _record(launch, loiter=True)


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def open_end_flight(launch) -> AsyncIterator[Flight]:
    yield await _record(launch, loiter=False)


def _flown(flight: Flight) -> None:
    assert flight.start_error is None, f"start sequence refused: {flight.start_error}"
    assert flight.done_at is not None, (f"end condition not reached within {FLIGHT_TIMEOUT_S:.0f} s: reached "
                                        f"{flight.reached}, current {flight.currents}, texts {flight.texts}")


# ------------------------------------------------------------------------------------------------ start
async def test_start_sequence_arms_and_takes_off(open_end_flight, measure) -> None:
    """Plane: AUTO → arm → MISSION_START; copter: GUIDED → arm → AUTO → MISSION_START. Each step ACKed, then
    the vehicle climbs and the mission goes past the takeoff."""
    flight = open_end_flight
    assert flight.start_error is None, f"start sequence refused: {flight.start_error}"
    steps = [(r["event"], r.get("mode")) for r in flight.events.records
             if r["event"] in ("mode", "armed", "mission_start")]
    expected = [("mode", "AUTO"), ("armed", None)] if flight.plane else \
        [("mode", "GUIDED"), ("armed", None), ("mode", "AUTO")]
    assert steps == expected + [("mission_start", None)]
    assert (AUTO[flight.plane], True) in [m[1:] for m in flight.modes], f"never armed in AUTO: {flight.modes}"
    takeoff_alt = flight.items[1].z
    top = max((p[3] for p in flight.positions), default=0.0)
    measure(f"highest {top:.1f} m above home (takeoff to {takeoff_alt:g} m); current items {flight.currents}")
    assert top >= 0.9 * takeoff_alt
    assert max(flight.currents, default=0) > 1, "MISSION_CURRENT never went past the takeoff"


# ------------------------------------------------------------------------------------------------ reached
async def test_every_waypoint_is_reached_in_order(loiter_flight, open_end_flight) -> None:
    for flight in (loiter_flight, open_end_flight):
        _flown(flight)
        wanted = flight.waypoint_seqs()
        got = [s for s, _ in flight.reached if s in wanted]
        assert got == wanted, f"{'loiter' if flight is loiter_flight else 'open end'} flight"
        assert [s for s, _ in flight.reached][0] == 1, "the takeoff's MISSION_ITEM_REACHED comes first"


async def test_waypoints_are_reached_at_the_acceptance_radius(loiter_flight, open_end_flight, measure) -> None:
    """Plane: MISSION_ITEM_REACHED when the vehicle is within param2 of the waypoint (early switching: not at
    the point); copter: within WPNAV_RADIUS (2 m) — param2 is not stored."""
    for flight in (loiter_flight, open_end_flight):
        _flown(flight)
        wanted = flight.waypoint_seqs()
        for seq, d in ((s, d) for s, d in flight.reached if s in wanted):
            radius = flight.items[seq].param2
            measure(f"waypoint {seq} (param2 {radius:g}) reached {d:.1f} m from it")
            if flight.plane:
                assert abs(d - radius) <= PLANE_TOLERANCE_M, f"item {seq}: {d:.1f} m, param2 {radius:g} m"
            else:
                assert d <= COPTER_REACHED_M, f"item {seq}: {d:.1f} m"


# ------------------------------------------------------------------------------------------------ the end
async def test_final_loiter_unlim_keeps_the_vehicle_there_in_auto(loiter_flight, measure) -> None:
    """After a final NAV_LOITER_UNLIM the mission does not end: mode stays AUTO (armed), the loiter item stays
    current, a plane circles it (wider than its radius, param3, as ArduPlane does), a copter holds over it."""
    flight = loiter_flight
    _flown(flight)
    loiter = flight.items[-1]
    assert flight.currents[-1] == loiter.seq
    assert flight.modes[-1][1:] == (AUTO[flight.plane], True), f"modes {flight.modes}"
    assert not [t for t in flight.texts if "mission complete" in t.lower()]
    window = flight.after(flight.done_at + 25.0)  # the last 15 s: there by then
    assert window
    distances = [horizontal_m(lat, lon, loiter) for _, lat, lon, _ in window]
    alts = [alt for *_, alt in window]
    measure(f"loitering {min(distances):.1f}-{max(distances):.1f} m from the loiter point (radius "
            f"{loiter.param3:g}), {min(alts):.1f}-{max(alts):.1f} m up")
    if flight.plane:
        assert all(abs(d - PLANE_LOITER_FLOWN_M) <= PLANE_LOITER_FLOWN_TOLERANCE_M for d in distances)
    else:
        assert max(distances) <= 3.0
    assert all(abs(a - loiter.z) <= 5.0 for a in alts)


async def test_after_the_last_item_plane_returns_and_copter_holds(open_end_flight, measure) -> None:
    """No end item: ArduPlane says "Mission complete, changing mode to RTL" and switches to RTL; ArduCopter
    stays in AUTO, armed, holding over the last waypoint."""
    flight = open_end_flight
    _flown(flight)
    last = flight.items[-1]
    measure(f"after the last item: texts {[t for t in flight.texts if 'ission' in t]}, modes {flight.modes[-2:]}")
    if flight.plane:
        assert "Mission complete, changing mode to RTL" in flight.texts
        assert flight.modes[-1][1:] == (RTL_PLANE, True), f"modes {flight.modes}"
    else:
        assert flight.modes[-1][1:] == (AUTO[False], True), f"modes {flight.modes}"
        window = flight.after(flight.done_at + 5.0)
        assert window
        assert max(horizontal_m(lat, lon, last) for _, lat, lon, _ in window) <= 3.0
        assert all(abs(alt - last.z) <= 2.0 for *_, alt in window)

"""Conformance suite: the same tests against the built-in simulator and real ArduPilot SITL.

The real autopilot is the judge: every test here asserts what ArduPilot SITL does, and runs unchanged against
the built-in simulated autopilot (``companion.sim``) so that the simulator can be held to it. It is the MAVSDK
integration-test layout (one scenario, each autopilot) with ArduPilot's autotest idea of one short mission per
vehicle.

Backends (the ``backend`` fixture's parameters): ``sim-plane``, ``sim-copter`` (the simulator on a TCP port of
its own) and ``sitl-plane``, ``sitl-copter`` (ArduPilot SITL from ``$FUSEPLAN_SITL_DIR``, marked ``sitl`` and
skipped with the harness's reason when it is not set). Everything runs on 127.0.0.1 sockets at speed-up
:data:`SPEEDUP`, home at the rescue_static scenario's home.

Fixtures:

* ``vehicle`` (module scope): a companion :class:`Vehicle` (``Link`` + ``MissionClient`` + ``FlightSupervisor``)
  connected where a companion sits (SITL: SERIAL1, a ground station holding SERIAL0), telemetry requested, the
  autopilot booted and ready to arm (home set). Shared by the tests of a module, whose state it must not depend on.
* ``launch`` (module scope): ``async with launch() as v`` starts a new autopilot of the module's backend and
  connects as ``vehicle`` does, stopping it on leaving the block (a flight on a fresh vehicle).
* ``fresh`` (per test): ``async with fresh() as v`` starts a new autopilot and connects at once, for the tests
  about boot. On SITL the companion takes SERIAL0 itself: SITL's clock starts with its first client there, so
  the companion sees the boot from its first HEARTBEAT on.

Telemetry: real ArduCopter streams nothing but HEARTBEAT until asked, so every connection asks for the
companion's rates with :func:`companion.mavlink.telemetry.request_rates` (the companion's own request;
REQUEST_DATA_STREAM for every group at 10 Hz while that module is not there).

The ``measure`` fixture notes the numbers the tests measure (boot times, acceptance distances, refusal texts…);
they are printed at the end of the run under "conformance measurements".

Test modules import the plain helpers below with ``from conformance.conftest import …`` (``tests`` is on the
path); fixtures come, as usual, by name.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import AsyncIterator, Callable, Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import pymap3d
import pytest
import pytest_asyncio
from leaks import Snapshot, fail_on_leaks
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from sitl_harness import SitlInstance, unavailable

from companion.flight.supervisor import FlightSupervisor
from companion.mavlink.items import FRAME_REL_ALT_INT, MISSION, MissionItem
from companion.mavlink.link import Link, Message, Subscription
from companion.mavlink.mavsdk_backend import MavsdkLink, MavsdkMissionClient
from companion.mavlink.protocol import MissionClient
from companion.mavlink.storage import Firmware, stored
from companion.mission.events import EventLog
from companion.sim import SimAutopilot

try:
    from companion.mavlink.telemetry import request_rates
except ImportError:  # companion.mavlink.telemetry not there yet: ask ArduPilot for every stream group ourselves
    request_rates = None
from planner.world.home import Home
from planner.world.scenario import Scenario, load_scenario

STATIC = Path(__file__).resolve().parents[2] / "sitl_scenarios" / "rescue_static.toml"
HOME: Home = load_scenario(STATIC).home  # -35.363261, 149.165230, 584 m
SPEEDUP = 10.0
# the built-in simulated plane's flights (``launch``): it keeps to SITL's behaviour in simulated time at 20× as at
# 10×, and the companion's own tests fly it at 20×. The copter stays at SPEEDUP (its telemetry, sent at most so
# many times a wall second, is too sparse at 20× to place a waypoint reached within 2.5 m), and so do boots
# (``fresh``), whose wall-clock window before ready the arming test needs
SIM_PLANE_FLIGHT_SPEEDUP = 20.0
BACKENDS = (
    pytest.param("sim-plane", id="sim-plane"),
    pytest.param("sim-copter", id="sim-copter"),
    pytest.param("sitl-plane", id="sitl-plane", marks=pytest.mark.sitl),
    pytest.param("sitl-copter", id="sitl-copter", marks=pytest.mark.sitl),
)
ARDUPLANE_INITIALISING = 16  # ArduPlane's custom mode while it boots
NAN = math.nan

_MEASURED = pytest.StashKey[list[str]]()


@pytest.fixture
def measure(request: pytest.FixtureRequest, backend: str) -> Callable[[str], None]:
    """``measure("what: value")`` notes a measured number for the end-of-run summary."""
    lines = request.config.stash.setdefault(_MEASURED, [])

    def note(what: str) -> None:
        lines.append(f"{backend} {request.node.originalname}: {what}")
        print(lines[-1])
    return note


def pytest_terminal_summary(terminalreporter: Any) -> None:
    lines = terminalreporter.config.stash.get(_MEASURED, [])
    if lines:
        terminalreporter.section("conformance measurements")
        for line in lines:
            terminalreporter.write_line(line)


# --------------------------------------------------------------------------------------------- geometry / items
def position(north_m: float, east_m: float) -> tuple[int, int]:
    """(x, y) of MISSION_ITEM_INT (degrees × 1e7) ``north_m``/``east_m`` from home."""
    lat, lon, _ = pymap3d.enu2geodetic(east_m, north_m, 0.0, HOME.lat, HOME.lon, HOME.alt)
    return round(float(lat) * 1e7), round(float(lon) * 1e7)


def item(command: int, north_m: float = 0.0, east_m: float = 0.0, z: float = 0.0, *,
         frame: int = FRAME_REL_ALT_INT, located: bool = True, **fields: Any) -> MissionItem:
    """One item (seq 0: lists are renumbered when uploaded); ``located=False`` leaves x/y at 0."""
    x, y = position(north_m, east_m) if located else (0, 0)
    return MissionItem(0, frame, command, x=x, y=y, z=z, **fields)


def numbered(items: Iterable[MissionItem], mission_type: int = MISSION) -> list[MissionItem]:
    """As the MissionClient sends them: renumbered from 0 and stamped with the list's type."""
    return [replace(it, seq=i, mission_type=mission_type) for i, it in enumerate(items)]


def home_item() -> MissionItem:
    """Item 0 as fuseplan's builder makes it (ArduPilot ignores it)."""
    return item(mavlink.MAV_CMD_NAV_WAYPOINT, frame=mavlink.MAV_FRAME_GLOBAL, z=HOME.alt)


def waypoint(north_m: float, east_m: float, alt: float, **params: float) -> MissionItem:
    return item(mavlink.MAV_CMD_NAV_WAYPOINT, north_m, east_m, alt, **params)


def takeoff(alt: float, pitch: float = 0.0) -> MissionItem:
    """NAV_TAKEOFF at home (ArduPlane ignores its position and climbs straight ahead)."""
    return item(mavlink.MAV_CMD_NAV_TAKEOFF, 0.0, 0.0, alt, param1=pitch)


def loiter_unlim(north_m: float, east_m: float, alt: float, radius: float = 0.0) -> MissionItem:
    return item(mavlink.MAV_CMD_NAV_LOITER_UNLIM, north_m, east_m, alt, param3=radius)


def horizontal_m(lat: float, lon: float, target: MissionItem) -> float:
    """Horizontal distance (m) from (lat, lon) in degrees to an item's position."""
    east, north, _ = pymap3d.geodetic2enu(target.lat, target.lon, 0.0, lat, lon, 0.0)
    return math.hypot(float(east), float(north))


# --------------------------------------------------------------------------------------------- MAVLink helpers
def booting(hb: Message, plane: bool) -> bool:
    """ArduPilot's HEARTBEAT while it boots: plane system_status BOOT/CALIBRATING in mode 16 (INITIALISING),
    copter system_status BOOT."""
    if plane:
        return hb.system_status in (mavlink.MAV_STATE_BOOT, mavlink.MAV_STATE_CALIBRATING) \
            and hb.custom_mode == ARDUPLANE_INITIALISING
    return hb.system_status == mavlink.MAV_STATE_BOOT


def texts(messages: Iterable[Message]) -> list[str]:
    """STATUSTEXT strings, chunks of one long text (same non-zero id) joined."""
    out: list[str] = []
    last_id = 0
    for msg in messages:
        if msg.get_type() != "STATUSTEXT":
            continue
        text = msg.text.rstrip("\x00") if isinstance(msg.text, str) else msg.text.decode(errors="replace")
        chunk_id = getattr(msg, "id", 0)
        if chunk_id and chunk_id == last_id and getattr(msg, "chunk_seq", 0) > 0 and out:
            out[-1] += text
        else:
            out.append(text)
        last_id = chunk_id
    return out


async def collect(sub: Subscription, seconds: float) -> list[Message]:
    """Everything ``sub`` receives for ``seconds`` (wall)."""
    got: list[Message] = []
    deadline = time.monotonic() + seconds
    while (left := deadline - time.monotonic()) > 0:
        try:
            got.append(await sub.get(left))
        except TimeoutError:
            break
    return got


async def next_matching(sub: Subscription, predicate: Callable[[Message], bool], timeout: float) -> Message:
    """The next message of ``sub`` passing ``predicate``; TimeoutError after ``timeout`` wall seconds."""
    deadline = time.monotonic() + timeout
    while True:
        msg = await sub.get(max(0.0, deadline - time.monotonic()))
        if predicate(msg):
            return msg


# --------------------------------------------------------------------------------------------- the vehicle
@dataclass(eq=False)
class Vehicle:
    """A companion connected to one autopilot of a backend."""

    backend: str  # "sim-plane", "sitl-copter", …
    link: Link
    client: MissionClient
    supervisor: FlightSupervisor
    events: EventLog
    sim: SimAutopilot | None = None
    sitl: SitlInstance | None = None

    @property
    def plane(self) -> bool:
        return self.backend.endswith("plane")

    @property
    def firmware(self) -> Firmware:
        return Firmware.of(self.link.autopilot, self.link.vehicle_type)

    def stored(self, it: MissionItem) -> MissionItem:
        """``it`` as this autopilot should store it (companion.mavlink.storage's rules)."""
        return stored(it, self.firmware)

    async def request_telemetry(self) -> dict[str, str]:
        """The companion's own rate requests (companion.mavlink.telemetry); without that module, REQUEST_DATA_STREAM
        MAV_DATA_STREAM_ALL at 10 Hz."""
        if request_rates is not None:
            return await request_rates(self.link)
        self.link.send(mavlink.MAVLink_request_data_stream_message(
            self.link.target_system, self.link.target_component, mavlink.MAV_DATA_STREAM_ALL, 10, 1))
        return {}

    async def param_set(self, name: str, value: float, timeout: float = 1.0, attempts: int = 3) -> Message:
        """PARAM_SET as a ground station sends it, confirmed by the PARAM_VALUE the autopilot answers with
        (value equal to what was set); AssertionError when none comes."""
        ts, tc = self.link.target_system, self.link.target_component
        msg = mavlink.MAVLink_param_set_message(ts, tc, name.encode(), float(value), mavlink.MAV_PARAM_TYPE_REAL32)
        with self.link.subscribe("PARAM_VALUE", predicate=lambda m: m.param_id == name) as sub:
            for _ in range(attempts):
                self.link.send(msg)
                try:
                    answer = await next_matching(sub, lambda m: abs(m.param_value - value) < 1e-6, timeout)
                except TimeoutError:
                    continue
                return answer
        raise AssertionError(f"{self.backend}: no PARAM_VALUE {name}={value:g} after {attempts} PARAM_SETs")


# The simulator's options that make it behave as SITL rather than as the other layers' tests want it (a boot
# phase, readiness after boot, telemetry only when asked, SITL's runway heading); passed only where its
# constructor has them, as the simulator grows them.
SIM_AS_SITL = {"boot_s": None, "ready_after_s": None, "streams_unasked": None, "heading_deg": 0.0,
               "wait_for_client": True}


SITL_PLANE_ROLL_LIMIT_DEG = 65.0  # ROLL_LIMIT_DEG of SITL's plane.parm: the simulator flies the same bank limit


def _sim_as_sitl() -> dict[str, Any]:
    return dict(SIM_AS_SITL)


def _sim_scenario(vehicle: str) -> Scenario:
    """rescue_static as the simulator flies it here: a plane with SITL's roll limit (the scenario says 45°)."""
    scenario = load_scenario(STATIC)
    if vehicle != "plane":
        return scenario
    return replace(scenario, vehicle=replace(scenario.vehicle, max_bank_deg=SITL_PLANE_ROLL_LIMIT_DEG))


@contextlib.asynccontextmanager
async def connect(backend: str, sitl_factory: Callable[..., SitlInstance] | None, *,
                  first_client: bool = False, mavsdk: bool = False,
                  sim_speedup: float = SPEEDUP) -> AsyncIterator[Vehicle]:
    """Start ``backend``'s autopilot, connect a companion and yield it; everything is stopped on exit. On SITL
    ``first_client`` puts the companion on SERIAL0 (its connection starts SITL's clock), else on SERIAL1 with a
    ground station holding SERIAL0. ``mavsdk``: the companion's MAVSDK backend instead of its own link."""
    kind, vehicle = backend.split("-")
    sim = sitl = None
    try:
        if kind == "sim":
            sim = SimAutopilot(_sim_scenario(vehicle), "tcp:127.0.0.1:0", speedup=sim_speedup, vehicle=vehicle,
                               **_sim_as_sitl())
            await sim.start()
            url = f"tcp:127.0.0.1:{sim.port}"
        else:
            assert sitl_factory is not None
            sitl = sitl_factory(vehicle, HOME, SPEEDUP)
            if first_client:
                url = sitl.serial0_url
            else:
                sitl.hold_serial0()
                url = sitl.serial1_url
        link = MavsdkLink(url) if mavsdk else Link(url)
        events = EventLog()
        client = MavsdkMissionClient(link) if mavsdk else MissionClient(link)
        v = Vehicle(backend, link, client, FlightSupervisor(link, client, events, arm=True), events, sim, sitl)
        try:
            await link.open()
            yield v
        finally:
            await link.close()
    finally:
        if sim is not None:
            await sim.stop()
        if sitl is not None:
            sitl.stop()  # now, not at the end of the module: flights must not share the machine's two cores


def _sitl_factory(request: pytest.FixtureRequest, backend: str, name: str) -> Callable[..., SitlInstance] | None:
    if not backend.startswith("sitl"):
        return None
    reason = unavailable(backend.split("-")[1])
    if reason:
        pytest.skip(reason)
    return request.getfixturevalue(name)


@pytest.fixture(scope="module", params=BACKENDS)
def backend(request: pytest.FixtureRequest) -> str:
    return request.param


async def ready(v: Vehicle) -> Vehicle:
    """Telemetry requested, booted, and ready to arm (3-D fix, EKF good, pre-arm checks pass: home is set)."""
    await v.link.wait_heartbeat(10.0)
    await v.request_telemetry()
    await v.supervisor.wait_booted(30.0)
    await v.supervisor.wait_ready(60.0)
    return v


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def vehicle(launch: Callable[[], contextlib.AbstractAsyncContextManager]) -> AsyncIterator[Vehicle]:
    """A module-shared autopilot, booted and ready to arm, with a companion on it."""
    async with launch() as v:
        yield await ready(v)


@pytest.fixture
def fresh(request: pytest.FixtureRequest, backend: str) -> Callable[[], contextlib.AbstractAsyncContextManager]:
    """``async with fresh() as v``: a newly started autopilot with the companion connected at once (nothing
    waited for: not even the first HEARTBEAT)."""
    factory = _sitl_factory(request, backend, "sitl_factory_fn")
    return lambda: connect(backend, factory, first_client=True)


@pytest.fixture(scope="module")
def launch(request: pytest.FixtureRequest, backend: str) -> Callable[[], contextlib.AbstractAsyncContextManager]:
    """For module-scoped fixtures: ``async with launch() as v`` starts a new autopilot of the module's backend
    with a companion where a companion sits (SITL: SERIAL1), stopped on leaving the block."""
    factory = _sitl_factory(request, backend, "sitl_factory")
    return lambda: connect(backend, factory,
                           sim_speedup=SIM_PLANE_FLIGHT_SPEEDUP if backend == "sim-plane" else SPEEDUP)


# --------------------------------------------------------------------------------------------- leaks
@pytest_asyncio.fixture(autouse=True, loop_scope="module")
async def no_leaks() -> AsyncIterator[None]:
    """As tests/companion's: a test leaves no asyncio task, thread or socket of its own behind (the module-shared
    vehicle's exist before and after)."""
    before = Snapshot.take()
    yield
    await fail_on_leaks(before)




def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """``@pytest.mark.xfail_backends({backend: reason})``: a known difference of that backend from the real
    autopilot, expected to fail (strict: it is reported the day it passes)."""
    for item in items:
        marker = item.get_closest_marker("xfail_backends")
        callspec = getattr(item, "callspec", None)
        if marker is None or callspec is None:
            continue
        reason = marker.args[0].get(callspec.params.get("backend"))
        if reason:
            item.add_marker(pytest.mark.xfail(reason=reason, strict=True))

"""The operator's world on the vehicle, as a plane holds it (the simulator and ArduPlane SITL): a ground-station
script on another port uploads a fence of polygons and a circle, rally points and a goal, and the companion reads
them back as geographic values (companion.mission.vehicle_world); a fence ArduPilot cannot store is refused as a
whole and the old one stays (AC_PolyFence_loader's checks, which the simulator reproduces)."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator

import pytest
from conformance.conftest import HOME, collect, item, numbered, texts
from gcs_world import ground_station_world, world_difference
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.mavlink.errors import MissionUploadError
from companion.mavlink.items import FENCE, MISSION, RALLY, MissionItem, compare_items
from companion.mavlink.link import Link
from companion.mavlink.protocol import MissionClient
from companion.mission.vehicle_world import download_world

pytestmark = pytest.mark.asyncio(loop_scope="module")

GCS_SYSTEM, GCS_COMPONENT = 255, mavlink.MAV_COMP_ID_MISSIONPLANNER
FRAME_GLOBAL_INT = mavlink.MAV_FRAME_GLOBAL_INT
INC, EXC = mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION


@pytest.fixture(scope="module", params=[pytest.param("sim-plane", id="sim-plane"),
                                        pytest.param("sitl-plane", id="sitl-plane", marks=pytest.mark.sitl)])
def backend(request: pytest.FixtureRequest) -> str:
    """A plane is enough: the fence, rally and mission storage are ArduPilot's libraries, the same on a copter."""
    return request.param


@contextlib.asynccontextmanager
async def ground_station(v) -> AsyncIterator[MissionClient]:
    """A ground station (system 255, Mission Planner's component) on another port of the vehicle: SITL's SERIAL2,
    or a second client of the simulator's TCP port."""
    url = f"tcp:127.0.0.1:{v.sim.port}" if v.sim is not None else v.sitl.serial2_url
    async with Link(url, source_system=GCS_SYSTEM, source_component=GCS_COMPONENT, open_timeout=5.0) as link:
        await link.wait_heartbeat(10.0)
        yield MissionClient(link)


async def test_the_world_a_ground_station_uploaded_reads_back_exactly(vehicle, measure) -> None:
    """The companion gets back the zones (vertices to 1e-7°, inclusion flags, radius), the rally points and the goal
    that the ground station put there; the mission's item 0 is the vehicle's real home."""
    world = ground_station_world(HOME, home_item=True)
    async with ground_station(vehicle) as gcs:
        await gcs.upload(world.fence, FENCE)
        await gcs.upload(world.rally, RALLY)
        await gcs.upload(world.mission, MISSION)
    got = await download_world(vehicle.client)
    assert world_difference(got, HOME) is None, world_difference(got, HOME)
    assert got.home is not None and got.home.alt is not None and got.home.alt.ref == "amsl"
    assert abs(got.home.lat - HOME.lat) < 2e-6 and abs(got.home.lon - HOME.lon) < 2e-6
    assert abs(got.home.alt.value - HOME.alt) < 1.0 and got.start == got.home
    measure(f"{len(world.fence)} fence, {len(world.rally)} rally, {len(world.mission)} mission items read back")


def _square(command: int, count: float = 4.0) -> list[MissionItem]:
    return [item(command, n, e, frame=FRAME_GLOBAL_INT, param1=count)
            for n, e in ((-1500.0, -1500.0), (-1500.0, 1500.0), (1500.0, 1500.0), (1500.0, -1500.0))]


def _triangle(command: int = EXC, count: float = 3.0) -> list[MissionItem]:
    return [item(command, n, e, frame=FRAME_GLOBAL_INT, param1=count)
            for n, e in ((500.0, -500.0), (500.0, -400.0), (400.0, -450.0))]


def _circle(radius: float) -> MissionItem:
    return item(mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, 300.0, 300.0, frame=FRAME_GLOBAL_INT, param1=radius)


# ArduPlane 4.7 SITL's STATUSTEXTs, in order, for each fence its polyfence loader refuses once the upload is complete
REFUSED = {
    "a vertex count that changes inside a polygon": (
        _square(EXC)[:2] + _triangle(), ["Unexpected vertex count want=4 got=3", "Fence validation failed"]),
    "a vertex of the other polygon type inside a polygon": (
        _square(INC)[:3] + _triangle(), ["Received incorrect vertex type (want=98 got=97)", "Fence validation failed"]),
    "a polygon cut short by the end of the list": (
        _triangle() + _square(INC)[:3], ["Incorrect item count", "Fence validation failed"]),
    "a circle inside a polygon": (
        _square(INC)[:2] + [_circle(50.0)] + _triangle(),
        ["Received incorrect type (want=98 got=93)", "Fence validation failed"]),
    "an inclusion circle inside a polygon": (
        _triangle()[:1] + [item(mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, 0.0, 0.0, frame=FRAME_GLOBAL_INT,
                                param1=2000.0)] + _triangle(),
        ["Received incorrect type (want=97 got=92)", "Fence validation failed"]),
    "a second return point": (
        _triangle() + [item(mavlink.MAV_CMD_NAV_FENCE_RETURN_POINT, 10.0 * k, 0.0, frame=FRAME_GLOBAL_INT)
                       for k in range(2)], ["Multiple return points", "Fence validation failed"]),
    "more than the fence storage holds": (  # 84 items are allowed, but 4 + 52 x 13 bytes are more than 672
        [item(mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, 10.0 * k, 0.0, frame=FRAME_GLOBAL_INT, param1=5.0)
         for k in range(52)], ["Fence exceeds storage size"]),
    "a two-vertex polygon": (
        _triangle(count=2.0) + [_circle(50.0)], ["Invalid vertex count (2)", "Fence validation failed"]),
    "a circle of radius 0": (_triangle() + [_circle(0.0)], ["Non-positive circle radius", "Fence validation failed"]),
}


@pytest.mark.parametrize("case", REFUSED)
async def test_a_fence_arduPilot_cannot_store_is_refused_and_the_old_one_stays(vehicle, case: str) -> None:
    """Every item is accepted as it arrives; the complete fence is then checked, refused with MAV_MISSION_ERROR after
    a STATUSTEXT saying why, and the fence stored before is left as it was."""
    good = numbered(_square(INC) + _triangle() + [_circle(60.0)], FENCE)
    await vehicle.client.upload(good, FENCE)
    bad, said = REFUSED[case]
    with vehicle.link.subscribe("STATUSTEXT") as sub:
        with pytest.raises(MissionUploadError) as refused:
            await vehicle.client.upload(numbered(bad, FENCE), FENCE)
        heard = [t.strip() for t in texts(sub.drain() + await collect(sub, 0.3))]
    seen = [t for t in heard if t in said]
    # the answer to the last item, and the old fence read back: a refusal, not a transfer fault to retry
    assert refused.value.result == mavlink.MAV_MISSION_ERROR and refused.value.refused
    assert seen == said, heard
    kept = await vehicle.client.download(FENCE)
    assert len(kept) == len(good) and all(compare_items(vehicle.stored(a), b) is None for a, b in zip(good, kept))


async def test_a_polygons_vertex_count_reads_back_as_the_byte_arduPilot_keeps(vehicle) -> None:
    """The count is cast to a byte when stored: 4.4 and 3.6 (the same on every vertex, so the fence is valid) read
    back 4 and 3 (PX4 rounds instead: tests/px4/test_px4_vehicle_world.py)."""
    fence = numbered(_square(INC, count=4.4) + _triangle(count=3.6), FENCE)
    await vehicle.client.upload(fence, FENCE)
    got = await vehicle.client.download(FENCE)
    assert [g.param1 for g in got] == [4.0] * 4 + [3.0] * 3
    assert all(compare_items(vehicle.stored(a), b) is None for a, b in zip(fence, got))

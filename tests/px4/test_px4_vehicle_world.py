"""The operator's world on a real PX4 (SIH SITL, one instance for the module): a ground-station script on PX4's GCS
link uploads a fence of polygons and a circle, rally points and a goal, and the companion on its own link reads them
back as geographic values (companion.mission.vehicle_world). PX4 checks less than ArduPilot when it stores a fence,
so a fence only the companion can tell is malformed is reported by it, naming the item."""

from __future__ import annotations

from collections.abc import AsyncIterator

import pytest
import pytest_asyncio
from gcs_world import e7, ground_station_world, world_difference
from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.errors import MissionUploadError, VehicleContentError
from companion.mavlink.items import FENCE, MISSION, RALLY, MissionItem, compare_items
from companion.mavlink.link import Link
from companion.mavlink.protocol import MissionClient
from companion.mavlink.storage import Firmware, stored
from companion.mission.vehicle_world import download_world
from planner.world.home import Home

pytestmark = pytest.mark.asyncio(loop_scope="module")

HOME = Home(-35.363261, 149.165230, 584.0)
SPEEDUP = 2.0  # nothing flies here: PX4's mission-protocol timeouts are all that run on its clock
GCS_SYSTEM, GCS_COMPONENT = 255, mavlink.MAV_COMP_ID_MISSIONPLANNER
EXC = mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION


@pytest.fixture(scope="module")
def px4(px4_factory):
    return px4_factory(HOME, speedup=SPEEDUP)


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def clients(px4) -> AsyncIterator[tuple[MissionClient, MissionClient]]:
    """(companion, ground station): the companion on PX4's API/offboard link, a ground station (system 255) on its
    GCS link (PX4 answers whoever sends there)."""
    async with (Link(px4.companion_url, open_timeout=5.0) as companion,
                Link(f"udpout:127.0.0.1:{px4.gcs_port}", source_system=GCS_SYSTEM, source_component=GCS_COMPONENT,
                     open_timeout=5.0) as gcs):
        await companion.wait_heartbeat(20.0)
        await gcs.wait_heartbeat(20.0)
        yield MissionClient(companion), MissionClient(gcs)


async def test_the_world_a_ground_station_uploaded_reads_back_exactly(clients) -> None:
    """Zones (vertices to 1e-7°, inclusion flags, radius), rally points and goal as the ground station sent them;
    PX4 has no home item, so the world has no home."""
    companion, gcs = clients
    world = ground_station_world(HOME, home_item=False)
    await gcs.upload(world.fence, FENCE)
    await gcs.upload(world.rally, RALLY)
    await gcs.upload(world.mission, MISSION)
    got = await download_world(companion)
    assert world_difference(got, HOME) is None, world_difference(got, HOME)
    assert got.home is None and got.start is None


SQUARE_X, SQUARE_Y = e7(HOME, north=0.0, east=0.0)


def _vertices(count: float, *points: tuple[float, float]) -> list[MissionItem]:
    return [MissionItem(0, mavlink.MAV_FRAME_GLOBAL_INT, EXC, param1=count, x=x, y=y, mission_type=FENCE)
            for x, y in (e7(HOME, north=n, east=e) for n, e in points)]


SQUARE = ((0.0, 0.0), (0.0, 100.0), (100.0, 100.0), (100.0, 0.0))
STORED_BUT_UNREADABLE = {  # what PX4 acknowledges and stores, the item the companion names, and why
    "a vertex count that changes inside a polygon": (
        _vertices(4.0, *SQUARE[:3]) + _vertices(3.0, SQUARE[3]), 3,
        "vertex count 3 inside the polygon of 4 vertices that begins at item 0"),
    "a polygon cut short by the end of the list": (
        _vertices(4.0, *SQUARE[:3]), 0, "a polygon of 4 vertices, but the fence ends after 3 of them"),
    "a circle of radius 0": (
        _vertices(4.0, *SQUARE) + [MissionItem(0, mavlink.MAV_FRAME_GLOBAL_INT,
                                               mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, x=SQUARE_X, y=SQUARE_Y,
                                               mission_type=FENCE)],
        4, "circle radius 0.0 is not a positive number"),
}


@pytest.mark.parametrize("case", STORED_BUT_UNREADABLE)
async def test_a_fence_px4_stores_but_the_companion_cannot_read_is_reported_naming_the_item(clients, case) -> None:
    """PX4 checks each vertex item alone (a count of at least 3), not the polygon, and no circle's radius: these
    fences are acknowledged and stored. The companion's reading names the item and the reason."""
    companion, gcs = clients
    fence, seq, reason = STORED_BUT_UNREADABLE[case]
    await gcs.upload(fence, FENCE)
    assert len(await companion.download(FENCE)) == len(fence)  # stored as sent
    with pytest.raises(VehicleContentError) as caught:
        await download_world(companion)
    assert (caught.value.list_name, caught.value.seq) == ("fence", seq)
    assert reason in str(caught.value)


async def test_a_polygons_vertex_count_reads_back_rounded(clients) -> None:
    """PX4 keeps the count as a whole number, rounded: 4.4 and 3.6 read back 4 (ArduPilot cuts them to 4 and 3)."""
    companion, gcs = clients
    fence = _vertices(4.4, *SQUARE) + _vertices(3.6, *SQUARE[:3])
    await gcs.upload(fence, FENCE)
    got = await companion.download(FENCE)
    assert [g.param1 for g in got] == [4.0] * 7
    sent = [a.with_seq(i) for i, a in enumerate(fence)]
    assert all(compare_items(stored(a, Firmware.PX4), b) is None for a, b in zip(sent, got))


async def test_a_polygon_of_two_vertices_is_refused_at_its_first_item(clients) -> None:
    """PX4 refuses a vertex item whose count is below 3 as it arrives (MAV_MISSION_ERROR for that item)."""
    _, gcs = clients
    with pytest.raises(MissionUploadError) as refused:
        await gcs.upload(_vertices(2.0, (0.0, 0.0), (0.0, 100.0)), FENCE)
    assert refused.value.result == mavlink.MAV_MISSION_ERROR and refused.value.seq == 0

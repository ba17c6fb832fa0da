"""The companion's MAVSDK backend (``fly --backend mavsdk``) on the ground, against ArduCopter SITL and the built-in
simulator as ArduCopter: MAVSDK's own transfers must leave what our storage rules say, as our protocol does
(test_ground.py). Where MAVSDK and our link differ, the test says which shows what the autopilot does.

Copter only: the transfers are the same for ArduPlane, and each SITL boot costs the suite time."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator, Callable

import pytest
import pytest_asyncio
from conformance.conftest import (
    HOME,
    Vehicle,
    _sitl_factory,
    collect,
    connect,
    home_item,
    next_matching,
    numbered,
    ready,
    takeoff,
    texts,
    waypoint,
)
from conformance.test_ground import _difference, _fence, _rally
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.mavlink.errors import CommandError
from companion.mavlink.items import FENCE, RALLY
from companion.mavlink.mavsdk_backend import MavsdkLink

pytestmark = pytest.mark.asyncio(loop_scope="module")


@pytest.fixture(scope="module", params=[pytest.param("sim-copter", id="sim-copter"),
                                        pytest.param("sitl-copter", id="sitl-copter", marks=pytest.mark.sitl)])
def backend(request: pytest.FixtureRequest) -> str:
    return request.param


@pytest.fixture(scope="module")
def launch(request: pytest.FixtureRequest, backend: str) -> Callable[[], contextlib.AbstractAsyncContextManager]:
    factory = _sitl_factory(request, backend, "sitl_factory")
    return lambda: connect(backend, factory, mavsdk=True)


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def vehicle(launch: Callable[[], contextlib.AbstractAsyncContextManager]) -> AsyncIterator[Vehicle]:
    async with launch() as v:
        assert isinstance(v.link, MavsdkLink)
        yield await ready(v)


def _six() -> list:
    return numbered([home_item(), takeoff(40.0)] + [waypoint(150.0 * i, 0.0, 40.0) for i in range(1, 5)])


async def test_mission_through_mavsdk_reads_back_with_the_real_home_at_item_0(vehicle) -> None:
    got = await vehicle.client.upload_verified(_six())
    assert len(got) == 6
    assert abs(got[0].lat - HOME.lat) < 2e-6 and abs(got[0].lon - HOME.lon) < 2e-6
    assert _difference(vehicle, _six(), got, skip_home=True) is None


async def test_fence_and_rally_through_mavsdk_read_back_as_storage_rules_say(vehicle) -> None:
    fence = _fence()
    got = await vehicle.client.upload_verified(fence, FENCE)
    assert _difference(vehicle, fence, got, skip_home=False) is None
    rally = _rally((60.0, HOME.alt + 100.0, 80.0))
    got = await vehicle.client.upload_verified(rally, RALLY)
    assert _difference(vehicle, rally, got, skip_home=False) is None


async def test_set_current_through_mavsdk_after_a_shorter_fence(vehicle) -> None:
    """MAVSDK 4.1 checks the index against the last list it transferred, of any type; the client reads the
    mission first, so item 5 of a 6-item mission can be made current after a 4-item fence."""
    await vehicle.client.upload(_six())
    await vehicle.client.upload(_fence(), FENCE)
    for seq in (5, 2):
        with vehicle.link.subscribe("MISSION_CURRENT") as sub:
            await vehicle.client.set_current(seq)
            assert (await next_matching(sub, lambda m, seq=seq: m.seq == seq, timeout=2.0)).seq == seq


async def test_set_current_past_the_end_is_refused_by_mavsdk_itself(vehicle) -> None:
    """ArduPilot answers DENIED (test_ground.py, our link); MAVSDK refuses before asking it, without a result."""
    await vehicle.client.upload(_six())
    with vehicle.link.subscribe("COMMAND_ACK", "MISSION_CURRENT") as sub, pytest.raises(CommandError) as refused:
        await vehicle.client.set_current(6)
    assert refused.value.result is None and "INVALID_ARGUMENT" in str(refused.value)
    assert not [m for m in sub.drain() if m.get_type() == "COMMAND_ACK"]


async def test_arming_in_auto_through_mavsdk_switches_to_hold_first(vehicle) -> None:
    """Our link's arm in AUTO is refused by ArduCopter ("Arm: AUTO mode not armable", test_ground.py). MAVSDK's
    action plugin first switches a vehicle in a mission mode to its Hold (ArduCopter BRAKE) on its own, so the
    autopilot's refusal then names BRAKE, reaches us as FAILED with its STATUSTEXT, and the vehicle is left in
    BRAKE. (The companion never arms in AUTO on ArduCopter: its start sequence arms in GUIDED.)"""
    await vehicle.client.upload(numbered([home_item(), takeoff(20.0), waypoint(150.0, 0.0, 20.0)]))
    with vehicle.link.subscribe("HEARTBEAT") as beats:
        await vehicle.supervisor.set_mode("AUTO")  # returns on the ACK, before a heartbeat says AUTO
        # MAVSDK chooses to switch to Hold from the flight mode its own heartbeats told it: arm only after two in
        # AUTO, or it may still think the copter is in its earlier mode and arm straight away (seen once in CI)
        for _ in range(2):
            await next_matching(beats, lambda m: m.custom_mode == 3 and m.type != mavlink.MAV_TYPE_GCS, timeout=3.0)
    try:
        with vehicle.link.subscribe("STATUSTEXT") as sub:
            with pytest.raises(CommandError) as refused:
                await vehicle.client.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
            said = texts(sub.drain() + await collect(sub, 0.5))
        assert refused.value.result == mavlink.MAV_RESULT_FAILED
        assert "Arm: BRAKE mode not armable" in said
        hb = await vehicle.link.wait_for("HEARTBEAT", timeout=2.0)
        assert hb.custom_mode == 17  # BRAKE
    finally:
        await vehicle.supervisor.set_mode("STABILIZE")

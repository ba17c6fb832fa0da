"""An autopilot refusing item k of an upload (MISSION_ACK error) before the flight (issue 7; during a flight:
tests/companion/replanning/test_replanning.py).

ArduPilot writes items as they arrive, so a refusal at item k leaves the stored mission part new, part old.
The companion must end with a verified mission stored (the previous one restored, proved by readback, or the
new one) and the vehicle must never begin an item that was not verified. Real UDP on 127.0.0.1.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from dataclasses import replace
from pathlib import Path

import pytest
from readback import same_item, same_mission

from companion.flight.supervisor import FlightSupervisor
from companion.mavlink.errors import UploadAborted
from companion.mavlink.link import Link
from companion.mavlink.protocol import MissionClient
from companion.mission.builder import mission_from_plan_json
from companion.mission.events import EventLog
from companion.mission.restore import restore_mission
from companion.sim import SimAutopilot
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]
STATIC = ROOT / "sitl_scenarios" / "rescue_static.toml"


@pytest.fixture
def static_doc(static_plan_doc) -> dict:
    return static_plan_doc()


@contextlib.asynccontextmanager
async def _on_sim() -> AsyncIterator[tuple[SimAutopilot, Link, MissionClient]]:
    """The simulated plane on rescue_static over UDP on 127.0.0.1, a link to it, and a mission client."""
    async with SimAutopilot(load_scenario(STATIC), "udpin:127.0.0.1:0", speedup=20.0, seed=1) as sim:
        async with Link(f"udpout:127.0.0.1:{sim.port}", open_timeout=5.0) as link:
            await link.wait_heartbeat(10.0)
            yield sim, link, MissionClient(link)


async def _refused_before_flight(doc: dict, k: int) -> tuple:
    async with _on_sim() as (sim, link, client):
        items = mission_from_plan_json(doc, load_scenario(STATIC), "ardupilot")
        # a different mission already on the vehicle (the operator's last one): 10 m higher
        previous = [items[0]] + [replace(it, z=it.z + 10.0) for it in items[1:]]
        await client.upload_verified(previous)
        sim.inject_item_refusal(k)
        events = EventLog()
        with pytest.raises(UploadAborted) as err:
            await FlightSupervisor(link, client, events, arm=True).fly(items, ready_timeout=30.0)
        readback = await client.download()
        return err.value, readback, previous, items, events.records, sim.refusals, sim.flown_items, sim.armed


def test_refusal_before_the_flight_restores_the_previous_mission(static_doc: dict) -> None:
    k = 4
    error, readback, previous, items, records, refused, flown, armed = asyncio.run(
        _refused_before_flight(static_doc, k))
    assert [it.seq for it, _ in refused] == [k]  # the fault happened once, on item k of our upload
    assert same_item(refused[0][0], replace(items[k], current=0))
    mixed = refused[0][1]  # what the refusal left stored: neither mission
    assert not same_mission(mixed, previous) and not same_mission(mixed, items)
    # one clear line naming the item, the autopilot's answer and what the vehicle was left with
    text = str(error)
    assert "\n" not in text
    assert f"refused at item {k}: MAV_MISSION_ERROR" in text and "previous verified mission" in text
    # the readback proves the previous mission is stored again (not the mix the refusal left)
    assert same_mission(readback, previous) and not same_mission(readback, items)
    names = [r["event"] for r in records]
    assert names.index("backup") < names.index("upload_failed") < names.index("mission_restored")
    failed = next(r for r in records if r["event"] == "upload_failed")
    assert failed["retrying"] is False  # a refusal is not a link fault: the same upload is not repeated
    assert next(r for r in records if r["event"] == "mission_restored")["which"] == "previous"
    assert "mission_start" not in names and flown == [] and not armed


def test_restore_with_no_known_previous_mission_clears_it(static_doc: dict) -> None:
    async def run() -> tuple:
        async with _on_sim() as (_sim, _link, client):
            await client.upload_verified(mission_from_plan_json(static_doc, load_scenario(STATIC), "ardupilot"))
            events = EventLog()
            restored, text = await restore_mission(client, events, None)
            return restored, text, await client.download(), events.records

    restored, text, readback, records = asyncio.run(run())
    assert restored and "cleared" in text
    assert len(readback) == 1  # ArduPilot keeps home at item 0
    assert records[-1]["event"] == "mission_restored" and records[-1]["which"] == "cleared"


def test_an_armed_vehicle_gets_no_upload(static_doc: dict) -> None:
    """A vehicle that is already armed (maybe flying its own mission) is left alone: uploads are not atomic."""
    from pymavlink.dialects.v20 import common as mavlink

    from companion.mavlink.errors import CompanionError

    async def run() -> tuple:
        async with _on_sim() as (sim, link, client):
            sup = FlightSupervisor(link, client, EventLog(), arm=True)
            await sup.wait_ready(30.0)
            await client.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
            await link.wait_for("HEARTBEAT", timeout=5.0,
                                predicate=lambda m: m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            with pytest.raises(CompanionError) as err:
                await sup.fly(mission_from_plan_json(static_doc, load_scenario(STATIC), "ardupilot"))
            return str(err.value), sim.mission, sim.armed

    text, mission, armed = asyncio.run(run())
    assert text.startswith("the vehicle is armed (mode MANUAL)") and "nothing was uploaded" in text
    assert len(mission) == 1 and armed  # untouched


def _fence_ring(vertices: int) -> list:
    """One exclusion polygon of ``vertices`` vertices, 3 km north of home."""
    import math

    from pymavlink.dialects.v20 import common as mavlink

    from companion.mavlink.items import FENCE, FRAME_GLOBAL_INT, MissionItem

    home = load_scenario(STATIC).home
    return [MissionItem(k, FRAME_GLOBAL_INT, mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION, param1=float(vertices),
                        x=round((home.lat + 0.027 + 0.003 * math.sin(2 * math.pi * k / vertices)) * 1e7),
                        y=round((home.lon + 0.003 * math.cos(2 * math.pi * k / vertices)) * 1e7), mission_type=FENCE)
            for k in range(vertices)]


@pytest.mark.parametrize("vertices, answer", [(85, "MAV_MISSION_NO_SPACE"), (84, "MAV_MISSION_ERROR")])
def test_a_fence_the_autopilot_has_no_room_for_leaves_mission_and_fence_as_they_were(
        static_doc: dict, vertices: int, answer: str) -> None:
    """A fence larger than the autopilot's storage, sent anyway (the pre-upload check had the wrong limit, e.g. a
    board with less storage): refused at MISSION_COUNT (NO_SPACE; right after boot, not taken for the boot's
    refusal and not retried) or after the last item ("Fence exceeds storage size"). One line says so; the fence
    stored before is kept and the mission uploaded just before it is put back, so nothing is half-uploaded."""
    from companion.mavlink.items import FENCE

    async def run() -> tuple:
        async with _on_sim() as (sim, link, client):
            items = mission_from_plan_json(static_doc, load_scenario(STATIC), "ardupilot")
            previous = [items[0]] + [replace(it, z=it.z + 10.0) for it in items[1:]]
            await client.upload_verified(previous)
            old_fence = await client.upload_verified(_fence_ring(5), FENCE)
            events = EventLog()
            sup = FlightSupervisor(link, client, events, arm=True)
            await sup.wait_booted()  # as `fuseplan fly` does: a NO_SPACE now is within the boot grace
            with pytest.raises(UploadAborted) as err:
                await sup.upload(items, _fence_ring(vertices))
            return (err.value, await client.download(), await client.download(FENCE), previous, old_fence,
                    events.records, sup.verified)

    error, mission, fence, previous, old_fence, records, verified = asyncio.run(run())
    text = str(error)
    where = "" if answer.endswith("NO_SPACE") else f" at item {vertices - 1}"  # at MISSION_COUNT, or the last item
    assert "\n" not in text and text.startswith(f"mission upload refused{where}: {answer}; "), text
    assert "previous verified fence (5 items) was restored" in text and "previous verified mission" in text
    assert same_mission(mission, previous) and [f.seq for f in fence] == [f.seq for f in old_fence]
    failed = [r for r in records if r["event"] == "upload_failed"]
    assert [(r["mission_type"], r["retrying"]) for r in failed] == [(FENCE, False)]
    assert [r["mission_type"] for r in records if r["event"] == "mission_restored"] == [FENCE, 0]
    assert same_mission(verified, previous)  # what the supervisor knows to be on the vehicle

"""Reliability under link faults (issue 7): the companion and the simulated autopilot through the seeded fault
proxy, real UDP on 127.0.0.1."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from companion.builder import mission_from_plan_json, spec_from_plan_json
from companion.events import EventLog
from companion.faultproxy import FaultProxy, Faults
from companion.link import Link
from companion.protocol import MissionClient
from companion.sim import SimAutopilot
from companion.supervisor import FlightSupervisor
from planner.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]
STATIC = ROOT / "sitl_scenarios" / "rescue_static.toml"


@pytest.fixture(scope="module")
def static_plan(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from planner.cli import _plan_doc_for

    doc, _ = _plan_doc_for(STATIC, None, ["planner.pso.n_pop=200", "planner.pso.max_iter=80"], None)
    path = tmp_path_factory.mktemp("static") / "PLAN.json"
    path.write_text(json.dumps(doc))
    return path


async def _fly_through_proxy(doc: dict, faults: Faults, seed: int, speedup: float = 20.0) -> tuple:
    sc = load_scenario(STATIC)
    async with SimAutopilot(sc, "udpin:127.0.0.1:0", speedup=speedup, seed=seed) as sim:
        async with FaultProxy(("127.0.0.1", sim.port), faults, seed=seed) as proxy:
            async with Link(f"udpout:127.0.0.1:{proxy.port}", open_timeout=5.0) as link:
                await link.wait_heartbeat(10.0)
                items = mission_from_plan_json(doc, sc, "ardupilot")
                events = EventLog()
                sup = FlightSupervisor(link, MissionClient(link), events, arm=True)
                out = await sup.fly(items, (), ready_timeout=30.0, flight_timeout=120.0)
                return out, proxy.counters, sim.mission, items, events.records


@pytest.mark.parametrize("seed", [1, 2])
def test_full_flight_through_30_percent_drop_with_duplicates_and_reordering(static_plan: Path, seed: int) -> None:
    doc = json.loads(static_plan.read_text())
    faults = Faults(drop=0.3, duplicate=0.1, reorder=0.1)
    out, counters, stored, items, events = asyncio.run(_fly_through_proxy(doc, faults, seed))
    assert out.completed, out.reason
    assert any(e["event"] == "upload_verified" for e in events)
    assert counters.dropped > 0 and counters.duplicated > 0 and counters.reordered > 0
    assert len(stored) == len(items)


def test_a_10_s_link_outage_mid_flight_is_survived(static_plan: Path) -> None:
    """The link goes silent for 10 s while the vehicle flies: the companion says so, waits, and when the link
    is back reads the mission back (it must still be ours) before going on to complete the flight."""
    doc = json.loads(static_plan.read_text())
    sc = load_scenario(STATIC)

    async def go() -> tuple:
        async with SimAutopilot(sc, "udpin:127.0.0.1:0", speedup=4.0, seed=1) as sim:
            async with FaultProxy(("127.0.0.1", sim.port), Faults(), seed=1) as proxy:
                async with Link(f"udpout:127.0.0.1:{proxy.port}", open_timeout=5.0) as link:
                    await link.wait_heartbeat(10.0)
                    items = mission_from_plan_json(doc, sc, "ardupilot")
                    events = EventLog()
                    sup = FlightSupervisor(link, MissionClient(link), events, arm=True)

                    async def cut() -> None:
                        while sim.mission_time is None or sim.mission_time < 20.0:  # on the route
                            await asyncio.sleep(0.05)
                        proxy.outage(10.0)

                    cutter = asyncio.create_task(cut())
                    out = await sup.fly(items, (), ready_timeout=30.0, flight_timeout=120.0)
                    await cutter
                    return out, events.records

    out, records = asyncio.run(go())
    names = [r["event"] for r in records]
    assert out.completed, out.reason
    assert names.index("link_lost") < names.index("link_restored") < names.index("resync")
    restored = next(r for r in records if r["event"] == "link_restored")
    assert restored["outage_s"] >= 5.0

"""A geographic scenario whose home lies inside its region, away from the frame's corner (Scenario.launch): the
simulated autopilot stands there at power-up and stores it as its home (item 0), as a real autopilot stands and
sets home where it is (docs/scenario_format.md, "Geographic scenarios")."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pymap3d
import pytest

from companion.mavlink.link import Link
from companion.mavlink.protocol import MissionClient
from companion.sim import SimAutopilot
from planner.world.scenario import load_scenario


@pytest.mark.asyncio
async def test_the_simulator_stands_and_sets_home_at_the_scenarios_home(tmp_path: Path,
                                                                       doc_toml: Callable[[str, str], str]) -> None:
    path = tmp_path / "lakeside_geo.toml"
    path.write_text(doc_toml("scenario_format.md", "## Geographic scenarios"))
    sc = load_scenario(path)
    assert np.hypot(*sc.launch) > 300.0  # home is well inside the region, far from the frame's corner
    async with SimAutopilot(sc, "udpin:127.0.0.1:0", speedup=20.0) as sim:
        await sim.run_until(sim.ready_after_s + 1.0)  # booted, ready: home set
        _, lat, lon, _, x, y, _ = sim.truth[-1]
        async with Link(f"udpout:127.0.0.1:{sim.port}") as link:  # item 0 as a ground station reads it back
            await link.wait_heartbeat(5.0)
            home = (await MissionClient(link).download())[0]
    assert np.hypot(x - sc.launch[0], y - sc.launch[1]) < 1.0  # it stands at home
    want_lat, want_lon, _ = pymap3d.enu2geodetic(*sc.launch, 0.0, sc.home.lat, sc.home.lon, sc.home.alt)
    assert abs(lat - want_lat) < 1e-6 and abs(lon - want_lon) < 1e-6
    assert (home.x, home.y) == (round(float(want_lat) * 1e7), round(float(want_lon) * 1e7))  # its home item

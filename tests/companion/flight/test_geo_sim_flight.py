"""A geographic scenario whose home is inside its region, not at the frame's corner, flown on the simulated
autopilot: the vehicle stands at home (Scenario.launch) at power-up, its HOME_POSITION is home's latitude and
longitude, and it flies the route round the polygon to the goal (docs/scenario_format.md, "Geographic scenarios")."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from companion.cli import main
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]


def test_a_region_scenario_flies_from_its_home_inside_the_region(tmp_path: Path) -> None:
    text = (ROOT / "docs" / "scenario_format.md").read_text().partition("## Geographic scenarios")[2]
    block = re.search(r"```toml\n(.*?)```", text, re.S)
    assert block is not None
    scenario = tmp_path / "lakeside_geo.toml"
    scenario.write_text(block[1])
    sc = load_scenario(scenario)
    assert np.hypot(*sc.launch) > 300.0  # home is well inside the region, far from the frame's corner
    report = tmp_path / "rep"
    code = main(["fly", str(scenario), "--sim", "--speedup", "20", "--report", str(report), "-q"])
    flight = json.loads((report / "flight.json").read_text())
    events = [json.loads(line) for line in (report / "events.jsonl").read_text().splitlines()]
    assert code == 0 and flight["completed"] and flight["flown_safe"], flight
    first = next(e for e in events if e["event"] == "position")
    assert np.hypot(first["x"] - sc.launch[0], first["y"] - sc.launch[1]) < 30.0, first  # it stood at home
    assert flight["min_static_clearance_m"] >= sc.hazard.d_coll

"""The flight record (issue 36) over real UDP on 127.0.0.1: the report's telemetry log, read back by pymavlink and
its ``mavlogdump.py``, holds what the companion uploaded and heard."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from pymavlink import mavutil, mavwp
from readback import same_item

from companion.cli import main
from companion.mavlink.items import MISSION, MissionItem
from companion.mavlink.link import MAV_COMP_ID_ONBOARD_COMPUTER

ROOT = Path(__file__).resolve().parents[3]
STATIC = ROOT / "sitl_scenarios" / "rescue_static.toml"
FAST = ["--set", "planner.pso.n_pop=200", "--set", "planner.pso.max_iter=80"]


def _waypoints(path: Path) -> list[MissionItem]:
    """A QGC WPL 110 file as MAVProxy loads it (pymavlink's mavwp), as mission items."""
    loader = mavwp.MAVWPLoader()
    loader.load(str(path))
    return [MissionItem.from_message(loader.wp(k)) for k in range(loader.count())]


def _tlog(path: Path) -> list:
    """Every message of a .tlog, read by pymavlink as MAVProxy's logs are."""
    log = mavutil.mavlink_connection(str(path))
    out = []
    while (msg := log.recv_match()) is not None:
        if msg.get_type() != "BAD_DATA":
            out.append(msg)
    log.close()
    return out


def _mavlogdump() -> list[str]:
    script = shutil.which("mavlogdump.py")
    if script is None:
        pytest.skip("mavlogdump.py (installed with pymavlink) is not on PATH")
    return [sys.executable, script]


def test_the_report_holds_a_tlog_of_the_link(tmp_path: Path) -> None:
    """`fly --sim`: flight.tlog holds every message of the companion's link. pymavlink reads it back with times that
    never go backwards, HEARTBEATs both ways (ours from the onboard computer's component, link 3 as MAVProxy marks
    what it sends), and the mission upload: mavlogdump.py lists the MISSION_ITEM_INTs sent, the same items (seq,
    command, coordinates) as the report's mission file."""
    report = tmp_path / "rep"
    assert main(["fly", str(STATIC), "--sim", "--speedup", "20", "--report", str(report), "-q", *FAST]) == 0
    flight = json.loads((report / "flight.json").read_text())
    assert flight["tlog"] == "flight.tlog" and flight["fuseplan_version"]
    mission = _waypoints(report / "mission.waypoints")[:flight["mission_items"]]  # the room behind it aside

    msgs = _tlog(report / "flight.tlog")
    times = [m._timestamp for m in msgs]
    assert len(msgs) > 500 and times == sorted(times) and times[-1] - times[0] > 2.0
    ours = (1, MAV_COMP_ID_ONBOARD_COMPUTER)
    beats = [((m.get_srcSystem(), m.get_srcComponent()), m._link) for m in msgs if m.get_type() == "HEARTBEAT"]
    assert (ours, 3) in beats and ((1, 1), 0) in beats  # ours, sent; the autopilot's, received
    sent = [m for m in msgs if m.get_type() == "MISSION_ITEM_INT" and m.mission_type == MISSION
            and (m.get_srcSystem(), m.get_srcComponent()) == ours]
    uploaded = {m.seq: MissionItem.from_message(m) for m in sent}  # an item asked for twice is sent twice
    assert sorted(uploaded)[:len(mission)] == list(range(len(mission)))
    assert all(same_item(uploaded[it.seq], it) for it in mission[1:])  # item 0 is home in the file too

    dump = subprocess.run([*_mavlogdump(), "--format", "json", "--types", "MISSION_ITEM_INT",
                           str(report / "flight.tlog")], capture_output=True, text=True, timeout=60, check=True)
    rows = [json.loads(line) for line in dump.stdout.splitlines() if line.startswith("{")]
    # ours go to the autopilot (component 1); the vehicle's (its readback) come to us
    to_vehicle = {r["data"]["seq"]: r["data"] for r in rows
                  if r["data"]["target_component"] == 1 and r["data"]["mission_type"] == MISSION}
    assert sorted(to_vehicle)[:len(mission)] == list(range(len(mission)))
    for it in mission:
        row = to_vehicle[it.seq]
        assert (row["command"], row["x"], row["y"]) == (it.command, it.x, it.y), (it, row)
        assert abs(row["z"] - it.z) < 1e-3
    stamps = [r["meta"]["timestamp"] for r in rows]
    assert stamps == sorted(stamps)

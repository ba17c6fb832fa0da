"""Repeated flights of the dynamic scenarios on real ArduPlane SITL, with and without replanning: the numbers
behind docs/results/sitl_replan.md (the test suite flies each case once).

    FUSEPLAN_SITL_DIR=/path/to/sitl python tests/sitl/campaign.py [--flights 10] [--speedup 10] [--out FILE]

FUSEPLAN_SITL_DIR names the ArduPilot SITL folder (CI points it at the team's SITL build when that is present;
docs/autopilots.md, "How the tests reach a real autopilot").

Each flight: a fresh SITL, a ground station holding SERIAL0, ``fuseplan fly SCENARIO --connect SERIAL1 --arm
--traffic SERIAL2`` (the scripted intruders reported by an ADS-B receiver, component 156), separation measured
from SITL's own GLOBAL_POSITION_INT against the intruders' scripted tracks. Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # tests/: sitl_harness

from sitl_harness import start_sitl, unavailable  # noqa: E402 - after the sys.path line: run as a script

from companion.cli import main as fuseplan  # noqa: E402 - after the sys.path line: run as a script
from planner.world.scenario import load_scenario  # noqa: E402 - after the sys.path line: run as a script

SCENARIOS = HERE.parents[1] / "sitl_scenarios"


def fly_once(name: str, replan: bool, speedup: float, work: Path) -> dict:
    """One flight; its flight.json plus how it went (exit code, wall time, outcomes of the replans)."""
    scenario = SCENARIOS / f"{name}.toml"
    (work / "sitl").mkdir()
    sitl = start_sitl("plane", load_scenario(scenario).home, work / "sitl", speedup)
    t0 = time.monotonic()
    try:
        with sitl.hold_serial0():
            code = fuseplan(["fly", str(scenario), "--connect", sitl.serial1_url, "--arm", "-q",
                             "--traffic", sitl.serial2_url, "--report", str(work / "rep"),
                             *([] if replan else ["--no-replan"])])
    finally:
        sitl.stop()
    flight = json.loads((work / "rep" / "flight.json").read_text())
    flight["exit"], flight["wall_s"] = code, round(time.monotonic() - t0, 1)
    return flight


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flights", type=int, default=10)
    ap.add_argument("--speedup", type=float, default=10.0)
    ap.add_argument("--scenario", action="append", default=None, help="default: rescue_dynamic, crossing_traffic")
    ap.add_argument("--out", type=Path, help="also write the table here")
    args = ap.parse_args()
    reason = unavailable("plane")
    if reason:
        print(reason, file=sys.stderr)
        return 2
    rows = ["| scenario | replanning | flight | exit | completed | static clearance, m | min separation, m (per "
            "intruder) | replans (attempts) | holds | wall s |", "|---|---|---|---|---|---|---|---|---|---|"]
    summary = []
    for name in args.scenario or ["rescue_dynamic", "crossing_traffic"]:
        for replan in (False, True):
            worst = []
            for k in range(1, args.flights + 1):
                with tempfile.TemporaryDirectory(prefix="campaign-") as tmp:
                    f = fly_once(name, replan, args.speedup, Path(tmp))
                    events = [json.loads(line) for line in (Path(tmp) / "rep" / "events.jsonl").open()]
                seps = f.get("min_separation_m") or {}
                holds = sum(e["event"] == "hold" for e in events)
                worst.append(min(seps.values(), default=float("nan")))
                static = f.get("min_static_clearance_m")
                row = (f"| {name} | {'on' if replan else 'off'} | {k} | {f['exit']} | {f.get('completed')} | "
                       + (f"{static:.1f} ({f.get('nearest_obstacle')})" if isinstance(static, (int, float)) else "-")
                       + " | " + ", ".join(f"{i} {v:.1f}" for i, v in sorted(seps.items()))
                       + f" | {f.get('replans', 0)} ({f.get('replan_attempts', 0)}) | {holds} | {f['wall_s']} |")
                rows.append(row)
                print(row, flush=True)
            d_coll = f.get("d_coll_m")
            kept = sum(w >= d_coll for w in worst)  # traffic; the static clearance is in each row
            summary.append(f"{name}, replanning {'on' if replan else 'off'}: closest {min(worst):.1f} m, "
                           f"d_coll {d_coll:g} m kept in {kept} of {len(worst)} flights")
    table = "\n".join(rows + [""] + [f"- {s}" for s in summary]) + "\n"
    print(table)
    if args.out:
        args.out.write_text(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""What ``plan``, ``export`` and ``fly`` take as their source: a scenario TOML, or a ground station's mission
(QGroundControl ``.plan``, Mission Planner ``.waypoints``), with airspace zones (``--zones FILE``: our GeoJSON,
OpenAIP airspace or ED-269 UAS zones) added to either. A mission, or a scenario with zones, becomes a scenario
file written beside the output, so the rest loads, checks and names it as any scenario (docs/scenario_format.md,
"Missions and zones from ground stations").
"""

from __future__ import annotations

import os
import tempfile
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from planner.errors import ScenarioError
from planner.world.geo_inputs import OperatorMission, Zone
from planner.world.operator_scenario import operator_raw, point_table
from planner.world.scenario import read_scenario_bytes
from planner.world.toml_text import dumps

MISSION_SUFFIXES = (".plan", ".waypoints")


def is_mission(path: Path) -> bool:
    """Whether ``path`` is a ground station's mission (by its suffix) rather than a scenario TOML."""
    return path.suffix.lower() in MISSION_SUFFIXES


def read_mission(path: Path, fence: Path | None = None, rally: Path | None = None) -> OperatorMission:
    """The operator's mission in ``path`` (QGroundControl or Mission Planner, by suffix); Mission Planner's fence
    and rally files beside it when given."""
    from planner.world.imports import read_qgc_plan, read_waypoints

    if path.suffix.lower() == ".plan":
        if fence is not None or rally is not None:
            raise ScenarioError(str(path), "", "--fence and --rally are for Mission Planner files (a .plan holds "
                                "its own geoFence and rallyPoints)")
        return read_qgc_plan(path)
    return read_waypoints(path, fence, rally)


def read_zone_files(paths: Sequence[Path]) -> tuple[Zone, ...]:
    """Every zone of the zones files (planner/world/imports/zones.py), each named by its file and zone."""
    from planner.world.imports import read_zones

    return tuple(z for p in paths for z in read_zones(p))


def _toml_of(path: Path) -> dict[str, Any]:
    try:
        return tomllib.loads(read_scenario_bytes(path).decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ScenarioError(str(path), "", f"malformed TOML: {exc}") from exc


def _with_zones(raw: dict[str, Any], zones: Sequence[Zone], source: Path) -> dict[str, Any]:
    """A scenario's raw tables with ``zones`` added as prisms and cylinders (an inclusion zone as a keep-in
    prism inside the scenario's own region), and a relative terrain path made absolute (the file moves)."""
    from planner.world.operator_scenario import zone_tables

    raw = dict(raw)
    prisms, cylinders, region = zone_tables(zones, str(source))
    if region is not None:
        name = next(z.name for z in zones if z.inclusion)
        prisms.append({"polygon": region, "keep_in": True, "name": name})
    raw["prisms"] = [*raw.get("prisms", []), *prisms]
    raw["cylinders"] = [*raw.get("cylinders", []), *cylinders]
    terrain = raw.get("terrain")
    if isinstance(terrain, dict) and isinstance(terrain.get("path"), str):
        raw["terrain"] = {**terrain, "path": str((source.parent / terrain["path"]).resolve())}
    return raw


def derived_scenario(source: Path, zone_files: Sequence[Path] = (), base: Path | None = None,
                     fence: Path | None = None, rally: Path | None = None, beside: Path | None = None) -> Path:
    """The scenario file to load for ``source``: the scenario itself when it is one and no zones are added;
    otherwise a scenario written as ``<beside>.scenario.toml`` (``beside``: the output, so the plan and its
    scenario stay together) or in a private temporary folder, written whole or not at all."""
    if not is_mission(source) and not zone_files:
        if base is not None or fence is not None or rally is not None:
            raise ScenarioError(str(source), "", "--base, --fence and --rally are for ground-station missions "
                                "(.plan, .waypoints), not scenario files")
        return source
    zones = read_zone_files(zone_files)
    if is_mission(source):
        mission = read_mission(source, fence, rally)
        base_raw = _toml_of(base) if base is not None else None
        raw = operator_raw(mission, base_raw, zones, base.parent if base is not None else None)
        header = f"A scenario made by fuseplan from {source}" + (f" on {base}" if base else "")
    else:
        raw = _with_zones(_toml_of(source), zones, source)
        header = f"{source} with the zones of {', '.join(str(p) for p in zone_files)}, made by fuseplan"
    if zone_files:
        header += f"\nzones: {', '.join(str(p) for p in zone_files)}"
    if beside is None:
        beside = Path(tempfile.mkdtemp(prefix="fuseplan-")) / source.name
    return _write(raw, header, beside)


def vehicle_scenario(base: Path, world: OperatorMission, fence: bool, goal: bool, beside: Path) -> Path:
    """``base`` with what the vehicle holds (docs/scenario_format.md, "The vehicle's own world"): its fence zones
    (``fence``) and the last navigation item of its mission as the goal, the places before it as the vias
    (``goal``), written as ``<beside>.scenario.toml``."""
    raw = _toml_of(base)
    what = []
    if fence:
        raw = _with_zones(raw, world.zones, base)
        what.append(f"{len(world.zones)} fence zones")
    if goal:
        if world.goal is None:
            raise ScenarioError(str(world.source), "mission", "the vehicle's mission has no navigation item with a "
                                "position: upload one (the goal) or plan without --goal-from-vehicle")
        route = dict(raw.get("route", {}))
        old = route.get("goal")
        alt = old[2] if isinstance(old, list) and len(old) == 3 else None
        route["goal"] = point_table(world.goal, None if world.goal.alt is not None or alt is None else alt)
        route.pop("vias", None)  # the vehicle's mission says where to pass, not the base scenario
        if world.vias:
            route["vias"] = [point_table(v, None if v.alt is not None or alt is None else alt) for v in world.vias]
        raw["route"] = route
        what.append(f"the goal{f' and {len(world.vias)} vias' if world.vias else ''}")
    return _write(raw, f"{base} with {' and '.join(what)} read from the vehicle at {world.source}", beside)


def _write(raw: dict[str, Any], header: str, beside: Path) -> Path:
    target = beside.parent / f"{beside.stem}.scenario.toml"
    part = target.with_name(target.name + ".part")
    try:
        part.write_text(dumps(raw, header + "\n(docs/scenario_format.md)"), encoding="utf-8")
        os.replace(part, target)
    except OSError as exc:
        raise ScenarioError(str(target), "", f"cannot write the scenario: {exc.strerror or exc}") from exc
    finally:
        part.unlink(missing_ok=True)
    return target

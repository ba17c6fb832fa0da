"""Readers for the operator's files: QGroundControl plans, Mission Planner waypoint, fence and rally files, and
zones files (our GeoJSON, OpenAIP airspace, ED-269 UAS geographical zones), each into planner/world/geo_inputs.py
values (docs/imports.md)."""

from planner.world.imports.mission_planner import read_waypoints
from planner.world.imports.qgc import read_qgc_plan
from planner.world.imports.zones import read_zones

__all__ = ["read_qgc_plan", "read_waypoints", "read_zones"]

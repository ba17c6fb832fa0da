"""Readers for the operator's files: QGroundControl plans, Mission Planner waypoint, fence and rally files, and
GeoJSON airspace zones, each into planner/world/geo_inputs.py values (docs/imports.md)."""

from planner.world.imports.geojson import read_zones
from planner.world.imports.mission_planner import read_waypoints
from planner.world.imports.qgc import read_qgc_plan

__all__ = ["read_qgc_plan", "read_waypoints", "read_zones"]

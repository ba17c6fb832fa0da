"""What every part of the live replanner shares (docs/design.md, "Live replanning"): the link and mission client,
the event log, the scenario and settings, the vehicle's limits, and the one vehicle state the supervisor feeds."""

from __future__ import annotations

from dataclasses import dataclass

from companion.mavlink.link import Link
from companion.mavlink.modes import mode_name
from companion.mavlink.profiles import AutopilotProfile
from companion.mavlink.protocol import MissionClient
from companion.mavlink.vehicle_limits import AutopilotLimits
from companion.mission.events import EventLog
from companion.mission.vehicle_state import VehicleState
from companion.replanning.replan import ReplanConfig
from planner.world.scenario import Scenario


@dataclass
class ReplanContext:
    """The flight as the replanner's parts see it. ``limits``: the vehicle's own (loiter radius, braking, roll);
    None: the config's and the scenario's."""

    link: Link
    client: MissionClient
    events: EventLog
    scenario: Scenario
    cfg: ReplanConfig
    state: VehicleState
    limits: AutopilotLimits | None = None

    @property
    def profile(self) -> AutopilotProfile:
        return self.link.profile

    @property
    def d_coll(self) -> float:
        return self.scenario.hazard.d_coll

    def mode_number(self, name: str) -> int:
        return self.link.profile.mode_number(name)

    def mode_name(self, custom_mode: int) -> str:
        """The vehicle's mode ``custom_mode`` by name, as pymavlink names it (:mod:`companion.mavlink.modes`)."""
        return mode_name(self.link.autopilot, self.link.vehicle_type, custom_mode)

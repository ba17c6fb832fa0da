"""``fuseplan serve``: the companion as a service beside the autopilot (issue 36; docs/serve.md). It waits for the
autopilot and reconnects forever, plans every mission the operator uploads with a ground station round the
vehicle's fence and the configured zones, replaces it with the verified safe route while the vehicle is disarmed,
supervises the flight the pilot starts, and tells the ground station by STATUSTEXT.

The top of the companion's layers, beside the CLI: the CLI only reads the options and runs :class:`Service`.
"""

from companion.service.config import ConfigError, ServeConfig, load_config
from companion.service.serve import MAV_COMP_ID_PATHPLANNER, Handled, Service

__all__ = ["ConfigError", "Handled", "MAV_COMP_ID_PATHPLANNER", "ServeConfig", "Service", "load_config"]

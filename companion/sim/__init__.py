"""Built-in simulated autopilot: an ArduPilot-like vehicle speaking MAVLink 2 over UDP/TCP on this machine.

Public API: :class:`SimAutopilot` (async context manager) and :func:`serve` (``fuseplan sim``).

Layers: ``transport`` (sockets, loss/latency) → ``mission_server`` (mission protocol) → ``navigator`` (mission
execution) → ``flight_model`` (kinematics); ``intruders`` (ADS-B traffic); ``autopilot`` ties them together.

Known differences from ArduPilot SITL: kinematic flight (no wind, no airspeed/throttle, instant speed changes, a
plane takes off at cruise speed), flat ground at home altitude (terrain frames are treated as relative and do not
block arming), no parameters, no guided-mode position targets (SET_POSITION_TARGET_*), no geofence enforcement
(fence items are stored only), SITL's TCP banner text and wait-for-first-client are not reproduced (time starts
at :meth:`SimAutopilot.start`). MAVLink 2 signing is supported (``signing_key``).

Fault injection for tests: packet loss and latency (transport), ``inject_outage`` (the link gone for a while;
TCP half-open), ``inject_upload_stall`` (an upload abandoned part-way), ``inject_item_refusal`` (item k refused
with a MISSION_ACK error), ``force_mode`` (a failsafe or the pilot changing mode).
"""

from companion.sim.autopilot import COPTER_MODES, PLANE_MODES, SimAutopilot, serve

__all__ = ["COPTER_MODES", "PLANE_MODES", "SimAutopilot", "serve"]

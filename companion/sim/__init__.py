"""Built-in simulated autopilot: an ArduPilot-like vehicle speaking MAVLink 2 over UDP/TCP on this machine.

Public API: :class:`SimAutopilot` (async context manager) and :func:`serve` (``fuseplan sim``).

Layers: ``transport`` (sockets, loss/latency) → ``mission_server`` (mission protocol) → ``navigator`` (mission
execution) → ``flight_model`` (kinematics); ``streams`` (telemetry rates); ``intruders`` (ADS-B traffic);
``autopilot`` ties them together.

**The real autopilot is the judge.** What the simulator imitates was measured on ArduPilot 4.7.0-dev SITL (the
team's build, in the folder FUSEPLAN_SITL_DIR names; plane.parm / copter.parm; docs/autopilots.md lists the
builds); ``tests/companion/sim/test_sim_conformance.py`` holds the measured numbers and checks the simulator against
them. When the two disagree, the simulator is wrong.

Imitated:

- Boot (``boot_s=None``): HEARTBEAT from ~half-way through, CALIBRATING in mode 16 INITIALISING (plane) or BOOT
  (copter), and what a client sent before it lost; a mission upload refused with MAV_MISSION_NO_SPACE ("Only 0
  items are supported"), a fence or rally upload answered only once booted, arming with "Arm: System not
  initialised"; then STANDBY and "ArduPilot Ready"
  (1.7 s plane, 2.5 s copter). Until home is set a download says count 0 (item 0 all zeros) and arming fails
  with a pre-arm text; GPS fix (type 6, as SITL's), home, EKF flags 0x33f and the pre-arm bit come together.
- HEARTBEAT as ArduPilot fills it (base_mode 81, + GUIDED in position-controlled modes, + ARMED; system_status
  ACTIVE only in the air), sent at once on a mode change.
- The mission protocol (``mission_server``) for the mission, fence and rally lists, storing items as ArduPilot
  does (:func:`companion.mavlink.storage.stored`), so a readback is the real one; polygon and circle fences checked
  as a whole when their upload completes, as ArduPilot's polyfence loader does (``mission_server.fence_problem``);
  ArduPlane SITL's capacities (84 fence items in 672 bytes of fence storage, 50 rally points; ArduCopter's fence:
  70 items in 560 bytes, as companion.mavlink.fence_capacity says).
- A few parameters (FENCE_ENABLE, FENCE_TYPE, FENCE_ACTION, RALLY_TOTAL, RALLY_LIMIT_KM, BRD_SD_FENCE, SITL's values):
  PARAM_SET echoed with PARAM_VALUE (other names ignored, as ArduPilot does), PARAM_REQUEST_READ / _LIST;
  SYS_STATUS says the geofence is enabled once FENCE_ENABLE is set and a fence is stored.
- ``wait_for_client=True``: time starts with the first client, as SITL's clock does on SERIAL0.
- Telemetry (``streams``): ArduPlane streams every group at 1 Hz unasked, ArduCopter only HEARTBEAT
  (``streams_unasked=None``); MAV_CMD_SET_MESSAGE_INTERVAL, GET_MESSAGE_INTERVAL, REQUEST_DATA_STREAM (its groups)
  and MAV_CMD_REQUEST_MESSAGE answered and honoured as ArduPilot does. MISSION_CURRENT is streamed, and sent as
  the answer to MISSION_SET_CURRENT / DO_SET_MISSION_CURRENT (out of range: nothing / DENIED), not on each change.
  Long STATUSTEXTs go in 50-byte chunks.
- Mission execution (``navigator``): DO commands run when the NAV command before them completes; "Mission: <seq>
  <name>" for each command started; one pending MISSION_ITEM_REACHED (a NAV command followed by DO commands is
  not reported); ArduPlane's "Takeoff complete at …m", "Reached waypoint #n dist …m", "Mission complete,
  changing mode to RTL"; ArduCopter's "Reached command #n", holding at the end.
- Plane take-off and climb-out as measured flying fuseplan's rescue_static mission: a ground roll on the heading
  it powered up with (``heading_deg``, SITL's --home heading, 0 = north), lift-off after ~3.9 s, a 10 m/s climb at
  ~27 m/s straight ahead, done at the take-off altitude ~8.9 s after arming, overshooting it by ~13 m, speed kept
  until over the top, then slowing at ~2 m/s²; the DO_CHANGE_SPEED after it runs only then. Copter take-off: a
  1 s spool-up, then 2.5 m/s with a slow approach to the altitude.
- ADS-B: the scripted intruders relayed by the autopilot (ADSB_VEHICLE, each aircraft at most once a second), or
  (``adsb_receiver=True``) sent by an ADS-B receiver, component 156 of the vehicle's system, with its own
  HEARTBEAT (MAV_TYPE_ADSB).

Defaults that are *not* the real vehicle, kept so that tests of the other layers work: ``boot_s=0`` (no boot:
they upload with a bare MissionClient at the first HEARTBEAT) and ``streams_unasked=True`` (a copter streams
unasked: only ``fuseplan fly`` asks for rates, tests driving a FlightSupervisor themselves do not). Readiness
comes 1 s after boot (SITL: ~20 s, its IMU consistency checks, with other pre-arm texts on the way).

Left out (known differences from ArduPilot SITL):

- Kinematic flight: no wind, no airspeed/throttle model. Plane turns are limited by the scenario's max bank
  (SITL's first turn after take-off is wider, ~17°/s at 26 m/s against ~21°/s here: the climb-out reaches 235 m
  north instead of 270 m and the route start ~1.5 s earlier). A plane waypoint without a radius uses the
  scenario's (SITL's plane.parm WP_RADIUS is 50 m). A copter flies legs at the scenario's speed with instant
  acceleration (ArduCopter: WPNAV_SPEED 10 m/s, 2.5 m/s²), braking at 2.5 m/s² only for the waypoint ahead.
- A copter starts its mission at MISSION_START (ArduCopter already on entering AUTO armed); entering AUTO
  disarmed, ArduPlane already makes item 1 current ("Mission: 1 Takeoff", MISSION_CURRENT ACTIVE), the
  simulator only when armed.
- Flat ground at home altitude (terrain frames are treated as relative and do not block arming); no other
  parameters (those it has change nothing in how it flies); no guided-mode position targets
  (SET_POSITION_TARGET_*); no geofence enforcement (fence items are stored only).
- Only HEARTBEAT, SYS_STATUS, GPS_RAW_INT, MISSION_CURRENT, GLOBAL_POSITION_INT, LOCAL_POSITION_NED, ATTITUDE,
  VFR_HUD, SYSTEM_TIME, EKF_STATUS_REPORT, HOME_POSITION and ADSB_VEHICLE are ever sent (the other members of a
  stream group are accepted, never sent); no TIMESYNC (SITL sends one every 10 s), no periodic HOME_POSITION
  (ArduPlane: every few seconds while disarmed). One rate table for every client (ArduPilot: one per link). At
  most 100 GLOBAL_POSITION_INT, 50 MISSION_CURRENT, 25 ADSB_VEHICLE, 10 HEARTBEAT and 5 of any other message per
  wall second: at high speed-ups the slower rates are not honoured (the simulator and the companion share one
  process).
- Not measured: the ADS-B relay rate, the list of message ids SET_MESSAGE_INTERVAL accepts.
- SITL's TCP banner text; by default time starts at :meth:`SimAutopilot.start` (``wait_for_client``).

MAVLink 2 signing is supported (``signing_key``).

Fault injection for tests: packet loss and latency (transport), ``inject_outage`` (the link gone for a while;
TCP half-open), ``inject_upload_stall`` (an upload abandoned part-way), ``inject_item_refusal`` (item k refused
with a MISSION_ACK error), ``force_mode`` (a failsafe or the pilot changing mode).
"""

from companion.sim.autopilot import COPTER_MODES, PLANE_MODES, SimAutopilot, serve

__all__ = ["COPTER_MODES", "PLANE_MODES", "SimAutopilot", "serve"]

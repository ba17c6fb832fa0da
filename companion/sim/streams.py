"""Telemetry rates of the simulated autopilot, as ArduPilot schedules them on one link (sans-IO).

Measured on ArduPilot 4.7.0-dev SITL (plane.parm / copter.parm, SERIAL0, speed-up 10; rates in simulated time):

- **Unasked.** ArduPlane streams every group below at 1 Hz; ArduCopter sends only HEARTBEAT (1 Hz) until a
  client asks (its SRn_* rates default to 0). Both send HEARTBEAT at 1 Hz whatever the groups do.
- **REQUEST_DATA_STREAM** (``req_stream_id``, ``req_message_rate`` Hz, ``start_stop``) sets every message of
  that group to the rate (``start_stop`` 0 or rate 0: off), overriding intervals set per message before it;
  MAV_DATA_STREAM_ALL sets every group. No answer is sent. The groups (what started flowing on SITL):

  ============== =======================================================================================
  RAW_SENSORS    RAW_IMU, SCALED_IMU2, SCALED_IMU3, SCALED_PRESSURE, SCALED_PRESSURE2 (+ AIRSPEED, plane)
  EXTENDED_STATUS SYS_STATUS, POWER_STATUS, MEMINFO, MISSION_CURRENT, GPS_RAW_INT, NAV_CONTROLLER_OUTPUT
  RC_CHANNELS    SERVO_OUTPUT_RAW, RC_CHANNELS
  RAW_CONTROLLER (nothing)
  POSITION       GLOBAL_POSITION_INT, LOCAL_POSITION_NED
  EXTRA1         ATTITUDE, SIMSTATE, AHRS2, ESC_TELEMETRY_1_TO_4 (+ AOA_SSA, plane)
  EXTRA2         VFR_HUD
  EXTRA3         AHRS, SYSTEM_TIME, WIND, BATTERY_STATUS, EKF_STATUS_REPORT, VIBRATION, TERRAIN_REPORT,
                 TERRAIN_REQUEST
  ============== =======================================================================================

- **MAV_CMD_SET_MESSAGE_INTERVAL** (param1 message id, param2 interval µs): COMMAND_ACK ACCEPTED and that rate
  exactly (also for HEARTBEAT and for ADSB_VEHICLE with no traffic to send); interval 0 → back to the group's
  rate (so off on a copter nobody asked), -1 → off. A message id ArduPilot has no sender for → DENIED with
  STATUSTEXT "No ap_message for mavlink id (N)"; an interval shorter than one scheduler loop (ArduPlane 50 Hz,
  ArduCopter 400 Hz) → DENIED with "Requested rate for message ID N too fast. Increase SCHED_LOOP_RATE".

ADSB_VEHICLE has its own rate (ArduPilot's SRn_ADSB), which REQUEST_DATA_STREAM cannot name (ALL leaves it
alone); it was not measured (SITL had no traffic): here 5 Hz when streaming unasked, else 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink


def _ids(*names: str) -> tuple[int, ...]:
    return tuple(int(getattr(mavlink, f"MAVLINK_MSG_ID_{n}")) for n in names)


ALL = mavlink.MAV_DATA_STREAM_ALL
GROUPS: dict[int, tuple[int, ...]] = {
    mavlink.MAV_DATA_STREAM_RAW_SENSORS: _ids("RAW_IMU", "SCALED_IMU2", "SCALED_IMU3", "SCALED_PRESSURE",
                                              "SCALED_PRESSURE2", "AIRSPEED"),
    mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: _ids("SYS_STATUS", "POWER_STATUS", "MEMINFO", "MISSION_CURRENT",
                                                  "GPS_RAW_INT", "NAV_CONTROLLER_OUTPUT"),
    mavlink.MAV_DATA_STREAM_RC_CHANNELS: _ids("SERVO_OUTPUT_RAW", "RC_CHANNELS"),
    mavlink.MAV_DATA_STREAM_RAW_CONTROLLER: (),
    mavlink.MAV_DATA_STREAM_POSITION: _ids("GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"),
    mavlink.MAV_DATA_STREAM_EXTRA1: _ids("ATTITUDE", "SIMSTATE", "AHRS2", "ESC_TELEMETRY_1_TO_4", "AOA_SSA"),
    mavlink.MAV_DATA_STREAM_EXTRA2: _ids("VFR_HUD"),
    mavlink.MAV_DATA_STREAM_EXTRA3: _ids("AHRS", "SYSTEM_TIME", "WIND", "BATTERY_STATUS", "EKF_STATUS_REPORT",
                                         "VIBRATION", "TERRAIN_REPORT", "TERRAIN_REQUEST"),
}
HEARTBEAT = mavlink.MAVLINK_MSG_ID_HEARTBEAT
ADSB_VEHICLE = mavlink.MAVLINK_MSG_ID_ADSB_VEHICLE
_GROUP_OF = {msg_id: group for group, ids in GROUPS.items() for msg_id in ids}
# Message ids ArduPilot can send on request (SET_MESSAGE_INTERVAL / REQUEST_MESSAGE accepted): the groups, the
# ones with their own rate, and those it sends on events. Others are refused ("No ap_message for mavlink id").
KNOWN: frozenset[int] = frozenset(_GROUP_OF) | frozenset({HEARTBEAT, ADSB_VEHICLE}) | frozenset(_ids(
    "HOME_POSITION", "GPS_GLOBAL_ORIGIN", "POSITION_TARGET_GLOBAL_INT", "EXTENDED_SYS_STATE", "AUTOPILOT_VERSION",
    "MISSION_ITEM_REACHED", "ATTITUDE_QUATERNION", "BATTERY2", "GPS2_RAW", "RANGEFINDER", "FENCE_STATUS",
    "DISTANCE_SENSOR", "TIMESYNC", "STATUSTEXT", "PARAM_VALUE", "SCALED_IMU", "SYSTEM_TIME", "RC_CHANNELS_RAW"))
LOOP_RATE_HZ = {"plane": 50.0, "copter": 400.0}  # SCHED_LOOP_RATE: no message faster than once a loop
ADSB_UNASKED_HZ = 5.0  # not measured (see the module docstring)
UNASKED_HZ = 1.0  # ArduPlane's rate for every group on SERIAL0


@dataclass
class StreamTable:
    """The rate of each message on the link, in Hz of the autopilot's (simulated) time; 0 = not sent.

    ``unasked``: stream every group at 1 Hz from power-up (ArduPlane), or nothing but HEARTBEAT (ArduCopter)."""

    vehicle: str  # "plane" | "copter"
    unasked: bool
    group_hz: dict[int, float] = field(default_factory=dict)
    override_hz: dict[int, float] = field(default_factory=dict)  # per-message intervals (SET_MESSAGE_INTERVAL)
    adsb_hz: float = 0.0

    def __post_init__(self) -> None:
        self.group_hz = {g: UNASKED_HZ if self.unasked else 0.0 for g in GROUPS}
        self.adsb_hz = ADSB_UNASKED_HZ if self.unasked else 0.0

    def hz(self, msg_id: int) -> float:
        if msg_id in self.override_hz:
            return self.override_hz[msg_id]
        if msg_id == HEARTBEAT:
            return 1.0
        if msg_id == ADSB_VEHICLE:
            return self.adsb_hz
        group = _GROUP_OF.get(msg_id)
        return 0.0 if group is None else self.group_hz[group]

    def set_interval(self, msg_id: int, interval_us: float) -> tuple[int, str | None]:
        """MAV_CMD_SET_MESSAGE_INTERVAL: (MAV_RESULT, STATUSTEXT or None)."""
        if msg_id not in KNOWN:
            return mavlink.MAV_RESULT_DENIED, f"No ap_message for mavlink id ({msg_id})"
        if interval_us == 0:
            self.override_hz.pop(msg_id, None)
        elif interval_us < 0:
            self.override_hz[msg_id] = 0.0
        else:
            if interval_us < 1e6 / LOOP_RATE_HZ[self.vehicle]:
                return (mavlink.MAV_RESULT_DENIED,
                        f"Requested rate for message ID {msg_id} too fast. Increase SCHED_LOOP_RATE")
            self.override_hz[msg_id] = 1e6 / interval_us
        return mavlink.MAV_RESULT_ACCEPTED, None

    def request_stream(self, stream_id: int, rate_hz: int, start: bool) -> None:
        """REQUEST_DATA_STREAM: the group's messages at ``rate_hz`` (off if not ``start`` or 0)."""
        hz = float(rate_hz) if start and rate_hz > 0 else 0.0
        groups = list(GROUPS) if stream_id == ALL else [stream_id] if stream_id in GROUPS else []
        for group in groups:
            self.group_hz[group] = hz
            for msg_id in GROUPS[group]:
                self.override_hz.pop(msg_id, None)

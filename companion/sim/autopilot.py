"""The built-in simulated autopilot: an ArduPilot-like MAVLink vehicle over UDP or TCP on this machine.

:class:`SimAutopilot` ties together the transport (``transport``), the mission protocol (``mission_server``),
mission execution (``navigator``), the kinematic vehicle (``flight_model``) and scripted ADS-B traffic
(``intruders``). It runs as three parts on one asyncio loop: the socket (protocol callbacks), a physics task and a
telemetry task. Simulated time runs ``speedup`` times faster than wall time, in physics steps of at most 0.05 s;
every timeout of the autopilot (mission protocol, readiness) is on simulated time, as in ArduPilot SITL.

Behaviour that differs from a real ArduPilot is listed in :mod:`companion.sim`.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import math
import time
from collections.abc import Callable
from typing import Any, Literal

import numpy as np
import pymap3d
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.mavlink.fence_capacity import fence_capacity
from companion.mavlink.items import FENCE, FRAME_GLOBAL, MISSION, RALLY, MissionItem
from companion.mavlink.signing import SigningKey
from companion.mavlink.storage import Firmware
from companion.mavlink.vehicle_limits import ARDUPLANE_L1_DAMPING
from companion.sim import streams
from companion.sim.flight_model import PLANE_L1_PERIOD_S, PLANE_LOITER_RADIUS, FlightModel, wrap_pi
from companion.sim.intruders import IntruderTrack, adsb_report
from companion.sim.mission_server import MAX_ITEMS, MissionServer, is_nav
from companion.sim.navigator import (
    Land,
    Loiter,
    Navigator,
    NavTask,
    ReturnHome,
    Takeoff,
    rtl_altitude,
)
from companion.sim.streams import StreamTable
from companion.sim.transport import SimTransport
from planner.world.config import VehicleLimits
from planner.world.home import Home
from planner.world.scenario import Scenario

logger = logging.getLogger(__name__)

COMPONENT_ID = mavlink.MAV_COMP_ID_AUTOPILOT1
PLANE_MODES = {"MANUAL": 0, "CIRCLE": 1, "STABILIZE": 2, "TRAINING": 3, "ACRO": 4, "FBWA": 5, "FBWB": 6,
               "CRUISE": 7, "AUTOTUNE": 8, "AUTO": 10, "RTL": 11, "LOITER": 12, "TAKEOFF": 13, "GUIDED": 15}
# ArduCopter modes it refuses to arm in: AUTO and BRAKE measured on SITL 4.7 (tests/conformance), the others as
# ArduCopter's mode classes declare them (allows_arming false)
COPTER_NOT_ARMABLE = frozenset({"AUTO", "BRAKE", "RTL", "LAND", "CIRCLE"})
COPTER_MODES = {"STABILIZE": 0, "ACRO": 1, "ALT_HOLD": 2, "AUTO": 3, "GUIDED": 4, "LOITER": 5, "RTL": 6,
                "CIRCLE": 7, "LAND": 9, "POSHOLD": 16, "BRAKE": 17}
# Boot (ArduPilot 4.7 SITL, sim s from power-up): HEARTBEAT from ~0.9 s saying CALIBRATING + mode 16
# INITIALISING (plane) / BOOT (copter), then STANDBY and "ArduPilot Ready" at 1.7 s (plane) / 2.5 s (copter).
BOOT_S = {"plane": 1.7, "copter": 2.5}
FIRST_HEARTBEAT_FRACTION = 0.5  # of the boot: nothing but STATUSTEXT before (SITL: first HEARTBEAT at 0.9 s)
READY_AFTER_BOOT_S = 1.0  # default sim s from the end of boot to GPS fix, home, EKF good and pre-arm checks passed
# (SITL takes ~20 s: its IMU consistency checks; short here so that tests do not wait)
PREARM_TEXT = {"plane": "Arm: AHRS: waiting for home", "copter": "Arm: Gyros inconsistent"}  # seen on SITL
ARDUPLANE_INITIALISING = 16
GPS_FIX_SITL = mavlink.GPS_FIX_TYPE_RTK_FIXED  # what SITL's simulated u-blox reports once fixed
PLANE_GUIDED_MODES = frozenset({"AUTO", "RTL", "LOITER", "GUIDED", "CIRCLE", "TAKEOFF"})  # base_mode GUIDED flag
COPTER_MANUAL_MODES = frozenset({"STABILIZE", "ACRO", "ALT_HOLD"})  # no position control: no GUIDED flag
ADSB_COMPONENT = mavlink.MAV_COMP_ID_ADSB
ADSB_RECEIVER_HZ = 1.0  # sim Hz at which the ADS-B receiver reports each aircraft (and its HEARTBEAT)
ADSB_MIN_INTERVAL_S = 1.0  # ArduPilot relays each aircraft at most once a second (AP_ADSB)
# Rates are honoured in sim time up to a number of packets per wall second per message: the simulator and the
# companion share one Python process, and at 20x ArduPlane's 1 Hz streams alone would be ~200 packets/s.
MAX_WALL_HZ = {mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 100.0, mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: 50.0,
               mavlink.MAVLINK_MSG_ID_ADSB_VEHICLE: 25.0, mavlink.MAVLINK_MSG_ID_HEARTBEAT: 10.0, "receiver": 25.0}
MAX_WALL_HZ_OTHERS = 5.0
# The few parameters the simulator has (SITL's values; name → (plane, copter), MAV_PARAM_TYPE): none of them
# changes how it flies. RALLY_TOTAL follows the rally list, as ArduPilot's does.
PARAMS = {"FENCE_ENABLE": ((0.0, 0.0), mavlink.MAV_PARAM_TYPE_INT8),
          "FENCE_TYPE": ((4.0, 7.0), mavlink.MAV_PARAM_TYPE_INT8),
          "FENCE_ACTION": ((1.0, 1.0), mavlink.MAV_PARAM_TYPE_INT8),
          "RALLY_TOTAL": ((0.0, 0.0), mavlink.MAV_PARAM_TYPE_INT8),
          "RALLY_LIMIT_KM": ((5.0, 0.3), mavlink.MAV_PARAM_TYPE_REAL32),
          # no SD-card fence storage (SITL has the parameter, 0): the fence is the storage layout's
          "BRD_SD_FENCE": ((0.0, 0.0), mavlink.MAV_PARAM_TYPE_INT16)}
PLANE_DEFAULT_LOITER_RAD = PLANE_LOITER_RADIUS  # WP_LOITER_RAD of SITL's plane.parm, settable with PARAM_SET


def vehicle_params(limits: VehicleLimits) -> dict[str, float]:
    """The flight parameters the simulator answers, in ArduPilot's names and units: what its flight model does
    (the scenario's vehicle) and its loiter radius (SITL's WP_LOITER_RAD, which LOITER and GUIDED circle at)."""
    if limits.type == "plane":
        return {"ROLL_LIMIT_DEG": limits.max_bank_deg, "AIRSPEED_CRUISE": limits.cruise_speed,
                "WP_RADIUS": limits.acceptance_radius, "WP_LOITER_RAD": PLANE_DEFAULT_LOITER_RAD,
                "NAVL1_PERIOD": PLANE_L1_PERIOD_S, "NAVL1_DAMPING": ARDUPLANE_L1_DAMPING}
    return {"WPNAV_SPEED": limits.cruise_speed * 100.0, "WPNAV_RADIUS": 200.0, "WPNAV_ACCEL": 250.0}


COMMAND_INT_ONLY = frozenset({mavlink.MAV_CMD_DO_REPOSITION})  # ArduPlane SITL: UNSUPPORTED as COMMAND_LONG
PHYSICS_DT = 0.05  # s of sim time per physics step
TRUTH_DT = 0.1  # s of sim time between truth samples
MAX_CATCH_UP_S = 0.25  # wall s simulated per tick at most (a stalled loop does not make time jump)
FORCE_DISARM = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2 magic
EKF_GOOD = 0x33F
EKF_UNINITIALISED = 0x400
SENSORS = (mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
           | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
           | mavlink.MAV_SYS_STATUS_SENSOR_GPS | mavlink.MAV_SYS_STATUS_AHRS | mavlink.MAV_SYS_STATUS_PREARM_CHECK)


PRODUCED = tuple(int(getattr(mavlink, f"MAVLINK_MSG_ID_{n}")) for n in (
    "HEARTBEAT", "SYS_STATUS", "GPS_RAW_INT", "MISSION_CURRENT", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED",
    "ATTITUDE", "VFR_HUD", "SYSTEM_TIME", "EKF_STATUS_REPORT", "ADSB_VEHICLE"))  # what the simulator can send


class _Events:
    """Navigator → autopilot notifications."""

    def __init__(self, ap: SimAutopilot) -> None:
        self._ap = ap

    def reached(self, seq: int, report: bool = True) -> None:
        self._ap._reached.append(seq)
        self._ap._reached_at[seq] = self._ap._sim_time
        if report:
            self._ap._send(mavlink.MAVLink_mission_item_reached_message(seq))

    def text(self, severity: int, text: str) -> None:
        self._ap._text(severity, text)

    def current_changed(self, seq: int) -> None:
        ap = self._ap
        if ap._nav.active is not None:
            ap._flown.append((time.monotonic(), ap._sim_time, ap._nav.active))

    def mission_complete(self) -> None:
        self._ap._on_mission_complete()

    def landed(self) -> None:
        self._ap._on_landed()


class SimAutopilot:
    """A simulated ArduPilot Plane or Copter serving MAVLink 2 (system ``system_id``, component 1).

    ``listen``: ``"udpin:HOST:PORT"`` (replies go to the last sender) or ``"tcp:HOST:PORT"`` (a TCP server, as
    SITL's port 5760); port 0 picks a free port, see :attr:`port`. ``loss`` drops each packet in either direction
    with that probability and ``latency_s`` delays outgoing packets (seeded from ``seed``). ``vehicle`` overrides
    ``scenario.vehicle.type``.

    ``boot_s``: sim s of booting after :meth:`start` (None: as SITL, 1.7 plane / 2.5 copter; the default 0: none,
    because tests of other layers upload with a bare MissionClient at the first HEARTBEAT); ready to arm
    ``ready_after_s`` after power-up (None: 1 s after boot). ``streams_unasked``: None, telemetry as the real
    vehicle on a link nobody asked for rates (ArduPlane streams every group at 1 Hz, ArduCopter sends only
    HEARTBEAT); True (the default, until every companion path asks for rates), every group at 1 Hz on both;
    False, only HEARTBEAT. ``adsb_receiver``: the scripted intruders come from an ADS-B receiver, component 156
    of this system (as one on the companion's link), not relayed by the autopilot. ``heading_deg``: where the
    vehicle points at power-up (SITL's --home heading; start.sh uses 0, north): a plane takes off that way.
    ``wait_for_client``: simulated time starts only when the first client connects (TCP) or sends (UDP), as
    SITL's clock waits for its first client on SERIAL0 (so that client sees the whole boot).
    """

    def __init__(self, scenario: Scenario, listen: str = "udpin:127.0.0.1:14550", speedup: float = 1.0,
                 loss: float = 0.0, latency_s: float = 0.0, seed: int = 0, system_id: int = 1,
                 vehicle: Literal["plane", "copter"] | None = None, signing_key: SigningKey | None = None, *,
                 boot_s: float | None = 0.0, ready_after_s: float | None = None,
                 streams_unasked: bool | None = True, adsb_receiver: bool = False,
                 heading_deg: float = 0.0, wait_for_client: bool = False) -> None:
        if speedup <= 0.0:
            raise ValueError(f"speedup must be > 0, got {speedup}")
        limits = scenario.vehicle
        if vehicle is not None and vehicle != limits.type:
            limits = dataclasses.replace(limits, type=vehicle)
        self.scenario = scenario
        self.vehicle = limits
        self.is_plane = limits.type == "plane"
        self.system_id = system_id
        self.speedup = float(speedup)
        self._home = scenario.home  # the frame's origin: every conversion to and from lat/lon
        # the vehicle's home, where it stands at power-up and returns to: the origin, but for a geographic
        # scenario's region (Scenario.launch)
        self._launch = (float(scenario.launch[0]), float(scenario.launch[1]))
        lat, lon, _ = pymap3d.enu2geodetic(*self._launch, 0.0, scenario.home.lat, scenario.home.lon, scenario.home.alt)
        self._launch_home = Home(float(lat), float(lon), scenario.home.alt)
        self._rng = np.random.default_rng(seed)
        self._transport = SimTransport(listen, self._on_message, system_id=system_id, component_id=COMPONENT_ID,
                                       loss=loss, latency_s=latency_s, rng=self._rng, signing_key=signing_key)
        self.boot_s = BOOT_S[limits.type] if boot_s is None else max(float(boot_s), 0.0)
        self.ready_after_s = self.boot_s + READY_AFTER_BOOT_S if ready_after_s is None \
            else max(float(ready_after_s), self.boot_s)
        self.adsb_receiver = adsb_receiver
        self.wait_for_client = wait_for_client
        self._params = {name: value[0 if limits.type == "plane" else 1] for name, (value, _) in PARAMS.items()}
        self._param_types = {name: kind for name, (_, kind) in PARAMS.items()}
        for name, value in vehicle_params(limits).items():  # what its flight model flies, as ArduPilot names it
            self._params[name] = value
            self._param_types[name] = mavlink.MAV_PARAM_TYPE_REAL32
        self._ready = False
        self._sim_time = 0.0
        self._model = FlightModel(limits, math.radians(heading_deg))
        self._model.state.x, self._model.state.y = self._launch
        self._events = _Events(self)
        self._nav = Navigator(self._model, self._item_to_enu, self._events, home=self._launch)
        firmware = Firmware.of(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, self._mav_type())
        self._server = MissionServer(self._send, self._home_item, lambda: self._nav.running,
                                     self._set_current, self._text, firmware=firmware,
                                     capacity=self._capacity, home_set=lambda: self._ready)
        self._modes = PLANE_MODES if self.is_plane else COPTER_MODES
        self._mode_names = {v: k for k, v in self._modes.items()}
        self._custom_mode = self._modes["MANUAL" if self.is_plane else "STABILIZE"]
        self._mode_task: NavTask | None = None
        self._armed = False
        self._next_truth = 0.0
        self._mission_t0: float | None = None
        self._complete = False  # the mission ran to its end (MISSION_CURRENT says COMPLETE until restarted)
        # intruders timed by a meet point are scheduled at mission start, along the route then stored
        self._tracks = [IntruderTrack(i) for i in scenario.intruders if i.meet is None]
        self._truth: list[tuple[float, float, float, float, float, float, float]] = []
        self._intruder_truth: dict[str, list[tuple[float, float, float, float]]] = {
            i.id: [] for i in scenario.intruders}
        self._reached: list[int] = []
        self._reached_at: dict[int, float] = {}  # sim time each item was last reached
        self._flown: list[tuple[float, float, MissionItem]] = []
        self._stall: tuple[int, int] | None = None  # (upload number, first item lost) for inject_upload_stall
        self._uploads_started = 0
        self._stall_count = 0
        self._refusals: list[tuple[MissionItem, list[MissionItem]]] = []
        self._change_signature: tuple | None = None
        unasked = self.is_plane if streams_unasked is None else streams_unasked
        self._streams = StreamTable(limits.type, unasked)
        self._due: dict[object, float] = {}  # message id (or "receiver") → loop time it is next due
        self._adsb_sent: dict[str, float] = {}  # intruder id → sim time of its last relayed report
        self._adsb_next = 0  # round robin over the intruders
        self._text_id = 0  # STATUSTEXT id of the last text sent in chunks
        self._tasks: list[asyncio.Task[None]] = []

    # --- public state ---------------------------------------------------------------------------------------

    @property
    def port(self) -> int:
        return self._transport.port

    @property
    def sim_time(self) -> float:
        return self._sim_time

    @property
    def truth(self) -> list[tuple[float, float, float, float, float, float, float]]:
        """(t_sim, lat, lon, alt_rel, x, y, z) every 0.1 s of simulated time (ENU m from home)."""
        return self._truth

    @property
    def intruder_truth(self) -> dict[str, list[tuple[float, float, float, float]]]:
        """Per intruder id: (t_sim, x, y, z) every 0.1 s of simulated time while it flies."""
        return self._intruder_truth

    @property
    def mission(self) -> list[MissionItem]:
        """The stored mission, item 0 = home (a copy)."""
        return list(self._server.mission)

    @property
    def fence(self) -> list[MissionItem]:
        return list(self._server.lists[mavlink.MAV_MISSION_TYPE_FENCE])

    @property
    def current_seq(self) -> int:
        return self._nav.current_seq

    @property
    def active_item(self) -> MissionItem | None:
        """The NAV command being flown (a copy taken when it started)."""
        return self._nav.active

    @property
    def armed(self) -> bool:
        return self._armed

    @property
    def mode(self) -> str:
        return self._mode_names[self._custom_mode]

    @property
    def custom_mode(self) -> int:
        return self._custom_mode

    @property
    def reached(self) -> list[int]:
        return list(self._reached)

    @property
    def reached_at(self) -> dict[int, float]:
        """Sim time at which each item was last reached."""
        return dict(self._reached_at)

    @property
    def ready(self) -> bool:
        """GPS fix, home set, EKF good and pre-arm checks passed."""
        return self._ready

    @property
    def booted(self) -> bool:
        return self._sim_time >= self.boot_s

    def message_rate(self, msg_id: int) -> float:
        """Hz of sim time at which message ``msg_id`` is streamed now (0: not sent)."""
        return self._streams.hz(msg_id)

    @property
    def position(self) -> tuple[float, float, float]:
        s = self._model.state
        return s.x, s.y, s.z

    @property
    def flown_items(self) -> list[tuple[float, float, MissionItem]]:
        """Every NAV item the vehicle began to fly: (monotonic wall time, sim time, the item as stored)."""
        return list(self._flown)

    @property
    def abandoned_uploads(self) -> list[list[MissionItem]]:
        """The stored mission each time an upload was abandoned part-way (what the vehicle was left with)."""
        return [list(m) for m in self._server.abandoned]

    def force_mode(self, name: str) -> None:
        """Fault injection: change mode as a failsafe or the pilot would (e.g. "RTL"), not through MAVLink."""
        if not self._set_mode(self._modes[name]):
            raise ValueError(f"mode {name!r} refused")

    def inject_stale_heartbeat(self, mode: str) -> None:
        """Fault injection: one HEARTBEAT that still reports ``mode`` (e.g. "AUTO" right after a mode change), as
        an autopilot sends when it acknowledges DO_SET_MODE before its HEARTBEAT shows the new mode (PX4)."""
        msg = self._heartbeat()
        msg.custom_mode = self._modes[mode]
        self._send(msg)

    def inject_upload_stall(self, upload: int, first_lost: int) -> None:
        """Fault injection: the ``upload``-th mission upload from now (1 = the next) loses every item from
        ``first_lost`` on (negative: counted back from its item count), so it stalls part-way and is abandoned
        after the autopilot's timeout, leaving the items written so far mixed with the old ones (ArduPilot
        uploads are not atomic)."""
        self._stall = (self._uploads_started + upload, first_lost)
        self._stall_count = 0

    def inject_outage(self, seconds: float) -> None:
        """Fault injection: the link is gone for ``seconds`` (wall): nothing in or out, TCP connects refused and
        open TCP connections left half-open (see :meth:`SimTransport.outage`). The vehicle flies on."""
        self._transport.outage(seconds)

    def inject_item_refusal(self, seq: int | None, result: int = mavlink.MAV_MISSION_ERROR, times: int | None = 1,
                            when: Callable[[MissionItem], bool] | None = None) -> None:
        """Fault injection: refuse mission item ``seq`` (None: any item) with MISSION_ACK ``result`` (as ArduPilot
        does when it cannot store an item) the next ``times`` times (None: always), only where ``when(item)``
        holds if given. Items before it stay written: the stored mission is left part new, part old."""
        left = times

        def refuse(item: MissionItem) -> int:
            nonlocal left
            if item.mission_type != MISSION or seq not in (None, item.seq) or left == 0 \
                    or (when is not None and not when(item)):
                return mavlink.MAV_MISSION_ACCEPTED
            if left is not None:
                left -= 1
            self._refusals.append((item, list(self._server.mission)))
            return result

        self._server.refuse = refuse

    @property
    def refusals(self) -> list[tuple[MissionItem, list[MissionItem]]]:
        """Every item :meth:`inject_item_refusal` refused, with the mission it left stored (part new, part old)."""
        return list(self._refusals)

    @property
    def mission_start_time(self) -> float | None:
        """Simulated time at which the mission first started (the intruders' and scripted threats' t = 0)."""
        return self._mission_t0

    @property
    def mission_time(self) -> float | None:
        """Simulated seconds since the mission started (intruders are scheduled on this), or None."""
        return None if self._mission_t0 is None else self._sim_time - self._mission_t0

    # --- lifecycle ------------------------------------------------------------------------------------------

    async def start(self) -> None:
        if self._tasks:
            return
        await self._transport.open()
        self._tasks = [asyncio.create_task(self._physics(), name="sim-physics"),
                       asyncio.create_task(self._telemetry(), name="sim-telemetry")]

    async def stop(self) -> None:
        tasks, self._tasks = self._tasks, []
        for task in tasks:
            task.cancel()
        for task in tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        await self._transport.close()

    async def __aenter__(self) -> SimAutopilot:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    async def run_until(self, sim_time: float) -> None:
        """Sleep until the simulated clock reaches ``sim_time``."""
        while self._sim_time < sim_time:
            await asyncio.sleep(max((sim_time - self._sim_time) / self.speedup, 0.005))

    # --- tasks ----------------------------------------------------------------------------------------------

    async def _physics(self) -> None:
        loop = asyncio.get_running_loop()
        tick = max(0.01, min(0.05, PHYSICS_DT / self.speedup))
        last = loop.time()
        while True:
            await asyncio.sleep(tick)
            now = loop.time()
            if self.wait_for_client and not self._transport.connected:
                last = now  # SITL: the clock waits for the first client
                continue
            self.advance(min(now - last, MAX_CATCH_UP_S) * self.speedup)
            last = now

    def advance(self, sim_seconds: float) -> None:
        """Run the simulation forward by ``sim_seconds`` in steps of at most PHYSICS_DT."""
        remaining = sim_seconds
        while remaining > 1e-9:
            dt = min(PHYSICS_DT, remaining)
            remaining -= dt
            self._step(dt)
            booting = not self.booted
            self._sim_time += dt
            if booting and self.booted:
                self._text(mavlink.MAV_SEVERITY_INFO, "ArduPilot Ready")
            self._server.tick(self._sim_time)
            if not self._ready and self._sim_time >= self.ready_after_s:
                self._ready = True
                self._text(mavlink.MAV_SEVERITY_INFO, "EKF3 IMU0 is using GPS")
                self._send(self._home_position())
            if self._sim_time >= self._next_truth:
                self._record_truth()
                self._next_truth += TRUTH_DT

    async def _telemetry(self) -> None:
        """Send each streamed message at its rate (sim Hz × speed-up, at most MAX_WALL_HZ per wall second)."""
        loop = asyncio.get_running_loop()
        while True:
            now = loop.time()
            # while booting, look often: the first HEARTBEAT (and the end of boot) is a matter of sim tenths
            wake = now + (0.2 if self.booted else min(0.2, 0.02 / self.speedup + 0.002))
            keys: tuple[int | str, ...] = (*PRODUCED, "receiver")
            for key in keys:
                hz = self._rate(key)
                if hz <= 0.0:
                    self._due.pop(key, None)
                    continue
                due = self._due.get(key, now)
                if now >= due:
                    if isinstance(key, str):  # "receiver"
                        self._send_receiver()
                    elif key == mavlink.MAVLINK_MSG_ID_ADSB_VEHICLE:
                        self._relay_adsb()
                    else:
                        for msg in self._stream_messages(key):
                            self._send(msg)
                    cap = MAX_WALL_HZ.get(key, MAX_WALL_HZ_OTHERS)
                    due = max(due + 1.0 / min(hz * self.speedup, cap), now)
                self._due[key] = due
                wake = min(wake, due)
            await asyncio.sleep(max(wake - loop.time(), 0.001))

    def _rate(self, key: object) -> float:
        """Sim Hz of a telemetry schedule entry now (0: not sent)."""
        if key == "receiver":
            return ADSB_RECEIVER_HZ if self.adsb_receiver else 0.0
        assert isinstance(key, int)
        if key == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            on = self._sim_time >= FIRST_HEARTBEAT_FRACTION * self.boot_s
        else:  # nothing streams before the end of boot (SITL: SYS_STATUS & co. from just after it)
            on = self.booted and not (key == mavlink.MAVLINK_MSG_ID_ADSB_VEHICLE and self.adsb_receiver)
        return self._streams.hz(key) if on else 0.0

    # --- flight ---------------------------------------------------------------------------------------------

    def _step(self, dt: float) -> None:
        model = self._model
        s = model.state
        if not self._armed:
            if not s.on_ground:
                model.touch_down()  # forced disarm in the air: it falls (no crash model)
            model.stay()
            return
        if self.mode == "AUTO":
            if self._nav.running:
                if not self.is_plane:
                    self._detect_mission_change()
                self._nav.step(self._server.mission, dt)
            elif s.on_ground:
                model.stay()
            else:
                model.circle((s.x, s.y), self.loiter_radius, s.z, True, dt)  # copter: hover
            return
        task = self._mode_task
        if task is not None:
            if task.step(model, dt):
                self._mode_task = None
                if s.on_ground:
                    self._on_landed()
                elif isinstance(task, Takeoff):
                    self._mode_task = Loiter((s.x, s.y, s.z), self.loiter_radius)
        elif s.on_ground:
            model.stay()
        else:
            model.straight(s.z, dt)

    def _detect_mission_change(self) -> None:
        """ArduCopter (and Rover) in AUTO: when the stored current item or either of the next two NAV items
        changes (an upload in progress rewriting them), the current item is re-read from storage and restarted
        (AP_Mission's change detector). ArduPlane keeps flying its copy."""
        mission = self._server.mission
        seq = self._nav.current_seq
        upcoming = [it for it in mission[seq:] if is_nav(it.command)][:3]
        signature = (seq, tuple(upcoming))
        previous, self._change_signature = self._change_signature, signature
        if previous is not None and previous[0] == seq and previous != signature and seq < len(mission):
            logger.info("simulator: mission changed under item %d: restarting it from storage", seq)
            self._nav.start(mission, seq)
            self._change_signature = (self._nav.current_seq, signature[1])

    def _capacity(self, mission_type: int) -> int | None:
        """Items an upload may have now: while booting a mission has room for none and the other lists are not
        loaded yet."""
        if self.booted:
            if mission_type == FENCE:  # ArduPlane's or ArduCopter's fence storage, as the vehicle imitated
                capacity = fence_capacity(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, self._mav_type())
                assert capacity is not None  # ArduPilot's fence storage is known for every vehicle
                return capacity.max_items
            return MAX_ITEMS.get(mission_type)
        return 0 if mission_type == MISSION else None

    def _item_to_enu(self, item: MissionItem) -> tuple[float, float, float]:
        s = self._model.state
        if item.x == 0 and item.y == 0:
            x, y = s.x, s.y
        else:
            e, n, _ = pymap3d.geodetic2enu(item.lat, item.lon, self._home.alt, self._home.lat, self._home.lon,
                                           self._home.alt)
            x, y = float(e), float(n)
        if item.frame in (mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT):
            z = item.z - self._home.alt
        elif item.frame == mavlink.MAV_FRAME_MISSION:
            z = s.z
        else:  # relative; terrain frames count as relative (the simulator's ground is flat at home altitude)
            z = item.z
        return x, y, float(z)

    def _start_mission(self, seq: int | None = None) -> None:
        if self._mission_t0 is None:
            self._mission_t0 = self._sim_time
            logger.info("simulator: mission started at t=%.1f s", self._sim_time)
            self._schedule_meet_intruders()
        self._complete = False
        self._nav.start(self._server.mission, seq)

    def _schedule_meet_intruders(self) -> None:
        """Intruders with a ``meet`` point follow the vehicle's progress along the route it starts with (the
        stored mission's waypoints), as :class:`companion.sim.traffic.TrafficFeed` does on a real autopilot."""
        meet = [i for i in self.scenario.intruders if i.meet is not None]
        if not meet:
            return
        route = np.array([self._item_to_enu(it) for it in self._server.mission[1:]
                          if it.command in (mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_SPLINE_WAYPOINT)])
        for intruder in meet:
            try:
                track = IntruderTrack(intruder, route)
            except ValueError as exc:  # no route to meet it on: it never flies
                logger.warning("simulator: intruder %s not scheduled: %s", intruder.id, exc)
                continue
            self._tracks.append(track)

    def _on_mission_complete(self) -> None:
        self._complete = True
        if self.is_plane:
            self._text(mavlink.MAV_SEVERITY_INFO, "Mission complete, changing mode to RTL")
            self._set_mode(PLANE_MODES["RTL"])

    def _on_landed(self) -> None:
        self._nav.stop()
        self._mode_task = None
        self._armed = False
        self._model.touch_down()
        self._text(mavlink.MAV_SEVERITY_INFO, "Disarming motors")

    def _set_mode(self, custom_mode: int) -> bool:
        if custom_mode not in self._mode_names:
            return False
        if custom_mode == self._custom_mode:
            return True
        previous = self.mode
        self._custom_mode = custom_mode
        name = self.mode
        s = self._model.state
        if previous == "AUTO":
            self._nav.stop()
        self._mode_task = None
        here = (s.x, s.y, s.z)
        if name == "AUTO":
            if self._armed and (self.is_plane or not s.on_ground):
                self._start_mission()
        elif name == "RTL":
            self._mode_task = ReturnHome((s.x, s.y), self.vehicle.acceptance_radius, rtl_altitude(self._model),
                                         for_ever=True, home=self._launch)
        elif name == "LAND":
            self._mode_task = Land((s.x, s.y), (s.x, s.y))
        elif name == "TAKEOFF":
            self._mode_task = Takeoff(self.vehicle.takeoff_alt)
        elif name in ("LOITER", "GUIDED", "CIRCLE") and not s.on_ground:
            # ArduPlane: LOITER (and GUIDED without a target) circles the point where the mode changed, at
            # |WP_LOITER_RAD|, counter-clockwise when it is negative
            self._mode_task = Loiter(here, self.loiter_radius, clockwise=self._params.get("WP_LOITER_RAD", 1.0) >= 0)
        logger.info("simulator: mode %s → %s", previous, name)
        self._send(self._heartbeat())
        return True

    def _set_current(self, seq: int) -> bool:
        """MISSION_SET_CURRENT / DO_SET_MISSION_CURRENT: restart that item now if the mission is running; a valid
        one is answered with MISSION_CURRENT (ArduPilot's acknowledgement of MISSION_SET_CURRENT), an invalid one
        with nothing."""
        mission = self._server.mission
        if not 0 <= seq < len(mission):
            return False
        seq = max(seq, 1) if len(mission) > 1 else 0
        if self.mode == "AUTO" and self._armed and (self._nav.running or not self._model.state.on_ground):
            self._start_mission(seq)
        else:
            self._nav.current_seq = seq
        self._send_mission_current()
        return True

    # --- incoming -------------------------------------------------------------------------------------------

    def _on_message(self, msg: mavlink.MAVLink_message) -> None:
        target = getattr(msg, "target_system", 0)
        if target not in (0, self.system_id):
            return
        if self._sim_time < FIRST_HEARTBEAT_FRACTION * self.boot_s:
            return  # SITL: what a client sends before the first HEARTBEAT is lost
        try:
            if self._stalled(msg):
                return
            if self._server.handle(msg, self._sim_time):
                return
            kind = msg.get_type()
            if kind in ("COMMAND_LONG", "COMMAND_INT"):
                if getattr(msg, "target_component", 0) not in (0, COMPONENT_ID):
                    return
                self._command(msg)
            elif kind == "SET_MODE":
                ok = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED) and \
                    self._set_mode(msg.custom_mode)
                self._ack(msg, mavlink.MAVLINK_MSG_ID_SET_MODE,
                          mavlink.MAV_RESULT_ACCEPTED if ok else mavlink.MAV_RESULT_FAILED)
            elif kind == "REQUEST_DATA_STREAM":
                if getattr(msg, "target_component", 0) in (0, COMPONENT_ID):
                    self._streams.request_stream(msg.req_stream_id, msg.req_message_rate, bool(msg.start_stop))
                    self._due.clear()  # new rates start now
            elif kind in ("PARAM_SET", "PARAM_REQUEST_READ", "PARAM_REQUEST_LIST"):
                if getattr(msg, "target_component", 0) in (0, COMPONENT_ID):
                    self._param(msg)
        except Exception:  # a malformed request must not take the simulated vehicle down
            logger.exception("simulator: error handling %s", msg)

    def _param(self, msg: mavlink.MAVLink_message) -> None:
        """PARAM_SET of a parameter the simulator has → stored and echoed with PARAM_VALUE (another name: ignored,
        as ArduPilot does); PARAM_REQUEST_READ by name (index 65535 in the answer) or index; PARAM_REQUEST_LIST."""
        self._params["RALLY_TOTAL"] = float(len(self._server.lists[RALLY]))
        names = list(self._params)
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_LIST":
            for i, name in enumerate(names):
                self._send_param(name, i)
            return
        name = msg.param_id.rstrip("\x00") if isinstance(msg.param_id, str) else msg.param_id.decode().rstrip("\x00")
        if kind == "PARAM_REQUEST_READ" and msg.param_index >= 0:
            if msg.param_index < len(names):
                self._send_param(names[msg.param_index], msg.param_index)
            return
        if name not in self._params:
            return
        if kind == "PARAM_SET":
            self._params[name] = float(msg.param_value)
        self._send_param(name, 0xFFFF)

    def _send_param(self, name: str, index: int) -> None:
        self._send(mavlink.MAVLink_param_value_message(name.encode(), self._params[name], self._param_types[name],
                                                       len(self._params), index))

    def _stalled(self, msg: mavlink.MAVLink_message) -> bool:
        """Count mission uploads and lose the items :meth:`inject_upload_stall` asked for."""
        kind = msg.get_type()
        if getattr(msg, "mission_type", MISSION) != MISSION:
            return False
        if kind == "MISSION_COUNT" and not self._server.receiving(MISSION):
            self._uploads_started += 1
            self._stall_count = msg.count
        elif kind in ("MISSION_ITEM_INT", "MISSION_ITEM") and self._stall is not None \
                and self._uploads_started == self._stall[0]:
            first = self._stall[1] if self._stall[1] >= 0 else self._stall_count + self._stall[1]
            return bool(msg.seq >= first)
        return False

    def _ack(self, msg: mavlink.MAVLink_message, command: int, result: int) -> None:
        self._send(mavlink.MAVLink_command_ack_message(command, result, 0, 0, msg.get_srcSystem(),
                                                       msg.get_srcComponent()))

    def _command(self, msg: mavlink.MAVLink_message) -> None:
        if msg.get_type() == "COMMAND_LONG":
            if msg.command in COMMAND_INT_ONLY:  # as ArduPlane SITL answers them
                self._ack(msg, msg.command, mavlink.MAV_RESULT_UNSUPPORTED)
                return
            p = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        else:
            p = (msg.param1, msg.param2, msg.param3, msg.param4, msg.x / 1e7, msg.y / 1e7, msg.z)
        self._ack(msg, msg.command, self._run_command(msg.command, p))

    def _run_command(self, cmd: int, p: tuple[float, ...]) -> int:
        ok, failed = mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_FAILED
        if cmd == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            return self._arm(p[0] == 1.0, force=int(p[1]) == FORCE_DISARM)
        if cmd == mavlink.MAV_CMD_DO_SET_MODE:
            custom = int(p[0]) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            return ok if custom and self._set_mode(int(p[1])) else failed
        if cmd == mavlink.MAV_CMD_MISSION_START:
            if not self._set_mode(self._modes["AUTO"]):
                return failed
            if self._armed and not self._nav.running:
                self._start_mission()
            return ok
        if cmd == mavlink.MAV_CMD_DO_SET_MISSION_CURRENT:
            return ok if self._set_current(int(p[0])) else mavlink.MAV_RESULT_DENIED
        if cmd == mavlink.MAV_CMD_REQUEST_MESSAGE:
            if int(p[0]) not in streams.KNOWN:
                return failed
            for m in self._on_request(int(p[0])):  # nothing to send (no home yet, no traffic) is still ACCEPTED
                self._send(m)
            return ok
        if cmd == mavlink.MAV_CMD_GET_HOME_POSITION:
            if not self._ready:
                return failed
            self._send(self._home_position())
            return ok
        if cmd == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            result, text = self._streams.set_interval(int(p[0]), p[1])
            if text is not None:
                self._text(mavlink.MAV_SEVERITY_WARNING, text)
            self._due.pop(int(p[0]), None)  # the new rate starts now
            return result
        if cmd == mavlink.MAV_CMD_GET_MESSAGE_INTERVAL:
            hz = self._streams.hz(int(p[0]))
            self._send(mavlink.MAVLink_message_interval_message(int(p[0]), round(1e6 / hz) if hz > 0 else -1))
            return ok
        if cmd == mavlink.MAV_CMD_DO_CHANGE_SPEED:
            if p[1] > 0.0:
                self._model.target_speed = float(p[1])
            return ok
        if cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return ok if self._set_mode(self._modes["RTL"]) else failed
        if cmd == mavlink.MAV_CMD_NAV_LAND and not self.is_plane:
            return ok if self._set_mode(COPTER_MODES["LAND"]) else failed
        if cmd == mavlink.MAV_CMD_NAV_TAKEOFF:
            return self._takeoff_command(p[6])
        if cmd == mavlink.MAV_CMD_DO_REPOSITION:
            return self._reposition(p)
        return mavlink.MAV_RESULT_UNSUPPORTED

    def _reposition(self, p: tuple[float, ...]) -> int:
        """MAV_CMD_DO_REPOSITION as ArduPlane takes it: lat/lon (param5/6), altitude above home (param7); GUIDED
        first when param2 has MAV_DO_REPOSITION_FLAGS_CHANGE_MODE, else only in GUIDED (FAILED otherwise); the
        plane circles the point at param3 when it is > 0 (else |WP_LOITER_RAD|), counter-clockwise when param4 is
        non-zero; a copter flies there and hovers."""
        s = self._model.state
        if not self._armed or s.on_ground or not (math.isfinite(p[4]) and math.isfinite(p[5])):
            return mavlink.MAV_RESULT_FAILED
        if int(p[1]) & 1:
            if not self._set_mode(self._modes["GUIDED"]):
                return mavlink.MAV_RESULT_FAILED
        elif self.mode != "GUIDED":
            return mavlink.MAV_RESULT_FAILED
        e, n, _ = pymap3d.geodetic2enu(p[4], p[5], self._home.alt, self._home.lat, self._home.lon, self._home.alt)
        radius = p[2] if p[2] > 0 else self.loiter_radius
        ccw = p[3] != 0 and math.isfinite(p[3])
        self._mode_task = Loiter((float(e), float(n), float(p[6])), radius, clockwise=not ccw)
        return mavlink.MAV_RESULT_ACCEPTED

    @property
    def loiter_radius(self) -> float:
        """|WP_LOITER_RAD| (ArduPlane uses 60 m when it is 0 or 1)."""
        r = abs(self._params.get("WP_LOITER_RAD", PLANE_DEFAULT_LOITER_RAD))
        return r if r > 1.0 else 60.0

    def _arm(self, arm: bool, force: bool) -> int:
        if not arm:
            if self._armed and not self._model.state.on_ground and not force:
                self._text(mavlink.MAV_SEVERITY_CRITICAL, "Disarm: vehicle is flying")
                return mavlink.MAV_RESULT_FAILED
            self._armed = False
            self._nav.stop()
            self._mode_task = None
            return mavlink.MAV_RESULT_ACCEPTED
        if self._armed:
            return mavlink.MAV_RESULT_ACCEPTED
        if not self.booted:
            self._text(mavlink.MAV_SEVERITY_CRITICAL, "Arm: System not initialised")
            return mavlink.MAV_RESULT_FAILED
        if not self.is_plane and self.mode in COPTER_NOT_ARMABLE:
            self._text(mavlink.MAV_SEVERITY_CRITICAL, f"Arm: {self.mode} mode not armable")
            return mavlink.MAV_RESULT_FAILED
        if not self._ready and not force:
            self._text(mavlink.MAV_SEVERITY_CRITICAL, PREARM_TEXT[self.vehicle.type])
            return mavlink.MAV_RESULT_FAILED
        self._armed = True
        self._text(mavlink.MAV_SEVERITY_INFO, "Throttle armed")
        if self.mode == "AUTO":
            self._start_mission()
        elif self.mode == "TAKEOFF":
            self._mode_task = Takeoff(self.vehicle.takeoff_alt)
        return mavlink.MAV_RESULT_ACCEPTED

    def _takeoff_command(self, altitude: float) -> int:
        if not self._armed or not altitude > 0.0:
            return mavlink.MAV_RESULT_FAILED
        if self.is_plane:
            if not self._set_mode(PLANE_MODES["TAKEOFF"]):
                return mavlink.MAV_RESULT_FAILED
        elif self.mode != "GUIDED":
            return mavlink.MAV_RESULT_FAILED
        self._mode_task = Takeoff(float(altitude))
        return mavlink.MAV_RESULT_ACCEPTED

    def _on_request(self, msg_id: int) -> list[mavlink.MAVLink_message]:
        """MAV_CMD_REQUEST_MESSAGE: the message(s) now, if the simulator has them."""
        if msg_id == mavlink.MAVLINK_MSG_ID_HOME_POSITION:
            return [self._home_position()] if self._ready else []
        if msg_id == mavlink.MAVLINK_MSG_ID_ADSB_VEHICLE:
            return [] if self.adsb_receiver else self._adsb_messages()
        return self._stream_messages(msg_id) if msg_id in PRODUCED else []

    # --- outgoing -------------------------------------------------------------------------------------------

    def _send(self, msg: mavlink.MAVLink_message) -> None:
        self._transport.send(msg)

    def _text(self, severity: int, text: str) -> None:
        """STATUSTEXT; a text longer than 50 bytes goes in 50-byte chunks sharing an id (as ArduPilot)."""
        logger.debug("simulator STATUSTEXT: %s", text)
        data = text.encode()
        if len(data) <= 50:
            self._send(mavlink.MAVLink_statustext_message(severity, data, 0, 0))
            return
        self._text_id = self._text_id % 0xFFFF + 1
        for n, i in enumerate(range(0, len(data), 50)):
            self._send(mavlink.MAVLink_statustext_message(severity, data[i:i + 50], self._text_id, n))

    def _send_mission_current(self) -> None:
        self._send(self._mission_current())

    def _time_boot_ms(self) -> int:
        return int(self._sim_time * 1000) & 0xFFFFFFFF

    def _home_item(self) -> MissionItem:
        """Item 0 as read back: home in frame GLOBAL with AMSL altitude, all zeros while home is not set."""
        if not self._ready:
            return MissionItem(0, FRAME_GLOBAL, mavlink.MAV_CMD_NAV_WAYPOINT, mission_type=MISSION)
        home = self._launch_home
        return MissionItem(0, FRAME_GLOBAL, mavlink.MAV_CMD_NAV_WAYPOINT, x=round(home.lat * 1e7),
                           y=round(home.lon * 1e7), z=float(home.alt), mission_type=MISSION)

    def _geodetic(self) -> tuple[float, float]:
        s = self._model.state
        lat, lon, _ = pymap3d.enu2geodetic(s.x, s.y, 0.0, self._home.lat, self._home.lon, self._home.alt)
        return float(lat), float(lon)

    def _record_truth(self) -> None:
        s = self._model.state
        lat, lon = self._geodetic()
        self._truth.append((self._sim_time, lat, lon, s.z, s.x, s.y, s.z))
        t_mission = self.mission_time
        if t_mission is None:
            return
        for track in self._tracks:
            track.follow(t_mission, np.array([s.x, s.y, s.z]))
            sample = track.sample(t_mission)
            if sample is not None:
                self._intruder_truth[track.intruder.id].append((self._sim_time, sample.x, sample.y, sample.z))

    def _mav_type(self) -> int:
        return mavlink.MAV_TYPE_FIXED_WING if self.is_plane else mavlink.MAV_TYPE_QUADROTOR

    def _heartbeat(self) -> mavlink.MAVLink_heartbeat_message:
        """As ArduPilot 4.7 SITL: base_mode CUSTOM|STABILIZE|MANUAL_INPUT (81), + GUIDED (89) in modes with
        position control (plane: AUTO, RTL, LOITER, GUIDED, CIRCLE, TAKEOFF; copter: all but STABILIZE, ACRO,
        ALT_HOLD), + SAFETY_ARMED; system_status ACTIVE only in the air (STANDBY on the ground, armed or not).
        Booting: plane CALIBRATING in mode 16 INITIALISING with base_mode 17; copter BOOT with base_mode 89."""
        flags = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        custom = self._custom_mode
        if not self.booted:
            if self.is_plane:
                custom, status = ARDUPLANE_INITIALISING, mavlink.MAV_STATE_CALIBRATING
            else:
                flags |= mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
                status = mavlink.MAV_STATE_BOOT
            return mavlink.MAVLink_heartbeat_message(self._mav_type(), mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, flags,
                                                     custom, status, 3)
        flags |= mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
        if (self.mode in PLANE_GUIDED_MODES) if self.is_plane else (self.mode not in COPTER_MANUAL_MODES):
            flags |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        if self._armed:
            flags |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        status = mavlink.MAV_STATE_STANDBY if self._model.state.on_ground else mavlink.MAV_STATE_ACTIVE
        return mavlink.MAVLink_heartbeat_message(self._mav_type(), mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, flags,
                                                 custom, status, 3)

    def _mission_current(self) -> mavlink.MAVLink_mission_current_message:
        total = len(self._server.mission) - 1
        if total < 1:
            state = mavlink.MISSION_STATE_NO_MISSION
        elif self._nav.running:
            state = mavlink.MISSION_STATE_ACTIVE
        elif self._complete:
            state = mavlink.MISSION_STATE_COMPLETE
        elif self._mission_t0 is None:
            state = mavlink.MISSION_STATE_NOT_STARTED
        else:
            state = mavlink.MISSION_STATE_PAUSED
        return mavlink.MAVLink_mission_current_message(self._nav.current_seq, max(total, 0), state,
                                                       1 if self.mode == "AUTO" else 0)

    def _home_position(self) -> mavlink.MAVLink_home_position_message:
        h = self._launch_home
        return mavlink.MAVLink_home_position_message(
            round(h.lat * 1e7), round(h.lon * 1e7), round(h.alt * 1000), 0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0],
            0.0, 0.0, 0.0, int(self._sim_time * 1e6))

    def _stream_messages(self, msg_id: int) -> list[mavlink.MAVLink_message]:
        s = self._model.state
        if msg_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            return [self._heartbeat()]
        if msg_id == mavlink.MAVLINK_MSG_ID_MISSION_CURRENT:
            return [self._mission_current()]
        if msg_id == mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
            lat, lon = self._geodetic()
            hdg = round(math.degrees(s.heading) * 100) % 36000
            return [mavlink.MAVLink_global_position_int_message(
                self._time_boot_ms(), round(lat * 1e7), round(lon * 1e7), round((self._home.alt + s.z) * 1000),
                round(s.z * 1000), round(s.vy * 100), round(s.vx * 100), round(-s.vz * 100), hdg)]
        if msg_id == mavlink.MAVLINK_MSG_ID_SYS_STATUS:
            health = SENSORS if self._ready else SENSORS & ~mavlink.MAV_SYS_STATUS_PREARM_CHECK
            fence = mavlink.MAV_SYS_STATUS_GEOFENCE
            enabled = SENSORS | (fence if self._params["FENCE_ENABLE"] and self._server.lists[FENCE] else 0)
            return [mavlink.MAVLink_sys_status_message(enabled, enabled, health | fence, 100, 12600, -1, 100, 0, 0,
                                                       0, 0, 0, 0)]
        if msg_id == mavlink.MAVLINK_MSG_ID_GPS_RAW_INT:
            lat, lon = self._geodetic()
            fix = GPS_FIX_SITL if self._ready else mavlink.GPS_FIX_TYPE_NO_GPS
            return [mavlink.MAVLink_gps_raw_int_message(
                int(self._sim_time * 1e6), fix, round(lat * 1e7) if self._ready else 0,
                round(lon * 1e7) if self._ready else 0, round((self._home.alt + s.z) * 1000),
                121 if self._ready else 65535, 200 if self._ready else 65535, round(s.speed * 100),
                round(math.degrees(s.heading) * 100) % 36000, 10 if self._ready else 0)]
        if msg_id == mavlink.MAVLINK_MSG_ID_EKF_STATUS_REPORT:
            flags = EKF_GOOD if self._ready else EKF_UNINITIALISED
            return [mavlink.MAVLink_ekf_status_report_message(flags, 0.01, 0.01, 0.01, 0.01, 0.0, 0.0)]
        if msg_id == mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
            return [mavlink.MAVLink_local_position_ned_message(self._time_boot_ms(), s.y, s.x, -s.z, s.vy, s.vx,
                                                               -s.vz)]
        if msg_id == mavlink.MAVLINK_MSG_ID_ATTITUDE:
            roll = s.bank
            pitch = math.atan2(s.vz, s.speed) if self.is_plane and not s.on_ground else 0.0
            return [mavlink.MAVLink_attitude_message(self._time_boot_ms(), roll, pitch, wrap_pi(s.heading), 0.0,
                                                     0.0, s.turn_rate)]
        if msg_id == mavlink.MAVLINK_MSG_ID_VFR_HUD:
            throttle = 0 if not self._armed else 100 if isinstance(self._nav.task, Takeoff) else 50
            return [mavlink.MAVLink_vfr_hud_message(s.speed, s.speed, round(math.degrees(s.heading)) % 360,
                                                    throttle, self._home.alt + s.z, s.vz)]
        if msg_id == mavlink.MAVLINK_MSG_ID_SYSTEM_TIME:
            return [mavlink.MAVLink_system_time_message(int(time.time() * 1e6), self._time_boot_ms())]
        if msg_id == mavlink.MAVLINK_MSG_ID_ADSB_VEHICLE:
            return self._adsb_messages()
        return []

    def _adsb_messages(self, only: str | None = None) -> list[mavlink.MAVLink_message]:
        """ADSB_VEHICLE for each scripted intruder in the air now (or just ``only``)."""
        t_mission = self.mission_time
        if t_mission is None:
            return []
        out = []
        for track in self._tracks:
            intruder = track.intruder
            sample = track.sample(t_mission)
            if sample is None or only not in (None, intruder.id):
                continue
            out.append(adsb_report(intruder, sample, self._home))
        return out

    def _relay_adsb(self) -> None:
        """The autopilot's ADSB_VEHICLE stream: one aircraft per message slot, each at most once a second (sim),
        taken in turn."""
        n = len(self._tracks)
        for k in range(n):
            i = (self._adsb_next + k) % n
            ident = self._tracks[i].intruder.id
            if self._sim_time - self._adsb_sent.get(ident, -math.inf) < ADSB_MIN_INTERVAL_S:
                continue
            messages = self._adsb_messages(only=ident)
            if messages:
                self._send(messages[0])
                self._adsb_sent[ident] = self._sim_time
                self._adsb_next = i + 1
                return

    def _send_receiver(self) -> None:
        """An ADS-B receiver (component 156 of this system, on the companion's link): its HEARTBEAT and every
        aircraft it hears, whatever rates the autopilot was asked for."""
        send = self._transport.send
        send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_ADSB, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                                               mavlink.MAV_STATE_ACTIVE, 3), ADSB_COMPONENT)
        for msg in self._adsb_messages():
            send(msg, ADSB_COMPONENT)


async def serve(scenario: Scenario, listen: str = "udpin:127.0.0.1:14550", speedup: float = 1.0,
                loss: float = 0.0, latency_s: float = 0.0, until: float | asyncio.Event | None = None,
                seed: int = 0, signing_key: SigningKey | None = None, **options: Any) -> None:
    """Run a :class:`SimAutopilot` until cancelled, until ``until`` seconds of simulated time have passed (a
    number), or until ``until`` is set (an :class:`asyncio.Event`). Used by ``fuseplan sim``. ``options``: the
    keyword-only options of :class:`SimAutopilot` (boot_s, streams_unasked, adsb_receiver…)."""
    async with SimAutopilot(scenario, listen, speedup, loss, latency_s, seed, signing_key=signing_key,
                            **options) as sim:
        logger.info("simulated %s serving on %s (port %d), speed-up %g", sim.vehicle.type, listen, sim.port,
                    speedup)
        if until is None:
            await asyncio.Event().wait()
        elif isinstance(until, asyncio.Event):
            await until.wait()
        else:
            await sim.run_until(float(until))

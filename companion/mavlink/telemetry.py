"""Telemetry rates: the companion asks the autopilot, on its own link, for the messages it needs at the rates it
needs (docs/autopilots.md §9.1; docs/design.md, "Companion").

An autopilot streams per link. ArduPilot's SERIAL1 — where a companion sits while a ground station holds SERIAL0 —
sends GLOBAL_POSITION_INT, MISSION_CURRENT, SYS_STATUS… at 1 Hz by default (its SR1_* parameters; measured on
ArduPlane 4.7 SITL), so a position can be a second old: 18 m at 18 m/s. :data:`RATES` is the one table of what the
companion reads and how often; :func:`request_rates` is the one function that asks for it:

* MAV_CMD_SET_MESSAGE_INTERVAL (COMMAND_LONG, param1 = message id, param2 = interval in µs) per message, which
  ArduPilot, PX4 and MAVSDK servers honour for the link the command came in on (ArduPilot 4.7 SITL: ACCEPTED for
  every message of the table, ADSB_VEHICLE included; DENIED for an id it does not know);
* for ArduPilot (its profile's ``data_streams``), first REQUEST_DATA_STREAM for each legacy stream group
  holding a message of the table, at the highest rate of its members (older firmware knows only that). It goes
  *first* because ArduPilot applies a stream request to every message of the group, overriding earlier
  per-message intervals (measured on SITL: GLOBAL_POSITION_INT at 10 Hz fell to 3 Hz after REQUEST_DATA_STREAM
  POSITION 3 Hz); the per-message intervals sent after it are then the ones that stay. A stream request also
  sets the group's other messages (LOCAL_POSITION_NED, NAV_CONTROLLER_OUTPUT, …) to that rate: a few hundred
  bytes/s at most;
* ahead of the per-message intervals, interval -1 (off) for what the autopilot streams to the companion unasked
  and the companion does not read (its profile's ``streams_off``: PX4's onboard link,
  :mod:`companion.mavlink.profiles`).

Rates are in the autopilot's time: under SITL speed-up N a 10 Hz request arrives at 10·N Hz of wall time.

**Fire and forget, with a look at the answers.** The requests never block or fail a flight. One background task
per round sends the stream requests (no answer exists for them) and then each SET_MESSAGE_INTERVAL in turn,
waiting at most ``ack_timeout`` for its COMMAND_ACK (one at a time, so each answer belongs to its message; on an
answering autopilot the round takes a few round trips: 15 ms on SITL). ACCEPTED is logged at debug, a refusal (DENIED,
UNSUPPORTED, FAILED) or no answer at info, and the round goes on; :attr:`TelemetryRates.results` keeps the last
answers. A lost link ends the round quietly: the next one comes with the reconnect.

**When.** :class:`TelemetryRates` registers on :meth:`companion.mavlink.link.Link.on_target_acquired`: a round starts
when the target autopilot is first identified, on the first HEARTBEAT of every new connection (the link
reconnects by itself), and when the HEARTBEAT comes back after a loss (an autopilot that rebooted behind a UDP or
serial link has forgotten the rates). A new round cancels one still running. The caller does nothing after
:meth:`TelemetryRates.start`.

**Layering.** This module sits just above the link and imports nothing else of the companion: COMMAND_ACKs are
read with a plain subscription, not with ``companion.mavlink.protocol``'s COMMAND_LONG machinery, whose retries and
errors are made for commands a flight depends on. HEARTBEAT (1 Hz from every autopilot), MISSION_ITEM_REACHED,
STATUSTEXT and the mission protocol's messages are sent without asking and are not in the table.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink  # EKF_STATUS_REPORT is ArduPilot's

from companion.mavlink.errors import LinkError
from companion.mavlink.link import Link, Message

log = logging.getLogger(__name__)

ACK_TIMEOUT_S = 0.5  # wall seconds to wait for each COMMAND_ACK (an autopilot answers within milliseconds)


def message_id(name: str) -> int:
    """The MAVLink message id of ``name`` (e.g. "GLOBAL_POSITION_INT")."""
    return int(getattr(mavlink, f"MAVLINK_MSG_ID_{name}"))


@dataclass(frozen=True)
class Rate:
    """One message the companion reads: ``hz`` in the autopilot's time; ``stream`` the ArduPilot
    MAV_DATA_STREAM group that carries it (None: no REQUEST_DATA_STREAM group can ask for it); ``used_by`` says
    who needs it."""

    message: str
    hz: float
    stream: int | None
    used_by: str

    @property
    def msg_id(self) -> int:
        return message_id(self.message)

    @property
    def interval_us(self) -> int:
        return round(1e6 / self.hz)


RATES: tuple[Rate, ...] = (
    Rate("GLOBAL_POSITION_INT", 10.0, mavlink.MAV_DATA_STREAM_POSITION,
         "replanner (position, vehicle clock) and the supervisor's monitor (flown track)"),
    Rate("MISSION_CURRENT", 2.0, mavlink.MAV_DATA_STREAM_EXTENDED_STATUS,
         "progress and completion; the replanner's active item (ArduPilot also sends it on every change)"),
    Rate("SYS_STATUS", 1.0, mavlink.MAV_DATA_STREAM_EXTENDED_STATUS, "readiness: pre-arm check bit"),
    Rate("GPS_RAW_INT", 1.0, mavlink.MAV_DATA_STREAM_EXTENDED_STATUS, "readiness: 3-D fix"),
    Rate("EKF_STATUS_REPORT", 1.0, mavlink.MAV_DATA_STREAM_EXTRA3, "readiness: EKF flags (ArduPilot)"),
    # ArduPilot sends one aircraft per ADSB_VEHICLE slot and each aircraft at most once a second (AP_ADSB), so
    # this is how many aircraft can be reported at 1 Hz. Its group is SRn_ADSB, which REQUEST_DATA_STREAM
    # cannot name.
    Rate("ADSB_VEHICLE", 5.0, None, "live threat tracks"),
)


OFF = -1  # SET_MESSAGE_INTERVAL param2: stop sending it


def stream_requests(rates: Sequence[Rate] = RATES) -> list[tuple[int, int]]:
    """``(MAV_DATA_STREAM, Hz)`` for each stream group in ``rates``: the highest rate of its members, rounded up
    (REQUEST_DATA_STREAM takes whole Hz)."""
    groups: dict[int, float] = {}
    for r in rates:
        if r.stream is not None:
            groups[r.stream] = max(groups.get(r.stream, 0.0), r.hz)
    return [(stream, math.ceil(hz)) for stream, hz in groups.items()]


def _result_name(result: int | None) -> str:
    if result is None:
        return "no answer"
    entry = mavlink.enums["MAV_RESULT"].get(result)
    return entry.name.removeprefix("MAV_RESULT_") if entry is not None else str(result)


async def request_rates(link: Link, rates: Sequence[Rate] = RATES,
                        ack_timeout: float = ACK_TIMEOUT_S) -> dict[str, str]:
    """Ask the link's target autopilot for ``rates`` (see the module docstring); returns each message's answer
    (``ACCEPTED``, ``DENIED``, ``UNSUPPORTED``, ``FAILED``…, or ``no answer``). Never raises for a refusal or
    silence; raises :class:`LinkError` if the link is down or closes meanwhile."""
    ts, tc = link.target_system, link.target_component
    if ts is None or tc is None:
        raise LinkError("no target autopilot yet")
    dialect = link.dialect
    profile = link.profile
    if profile.data_streams:
        for stream, stream_hz in stream_requests(rates):
            link.send(dialect.MAVLink_request_data_stream_message(ts, tc, stream, stream_hz, 1))

    def is_ack(m: Message) -> bool:
        return (m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL
                and m.target_system in (0, link.source_system) and m.target_component in (0, link.source_component))

    results: dict[str, str] = {}
    requests = [(r.message, r.msg_id, r.interval_us, r.hz) for r in rates]
    requests = [(f"{name} off", message_id(name), OFF, 0.0) for name in profile.streams_off] + requests
    with link.subscribe("COMMAND_ACK", predicate=is_ack) as acks:
        for message, msg_id, interval_us, hz in requests:
            acks.drain()  # a late answer to the previous request
            link.send(dialect.MAVLink_command_long_message(ts, tc, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                                           msg_id, interval_us, 0, 0, 0, 0, 0))
            try:
                result: int | None = (await acks.get(ack_timeout)).result
            except TimeoutError:
                result = None
            results[message] = _result_name(result)
            if result == mavlink.MAV_RESULT_ACCEPTED:
                log.debug("%s at %g Hz: accepted", message, hz)
            else:
                log.info("%s at %g Hz not confirmed by the autopilot (%s); using the rate it sends",
                         message, hz, results[message])
    return results


class TelemetryRates:
    """Keeps asking for ``rates`` on ``link``: a round of :func:`request_rates` each time the target autopilot
    is (re)acquired. :meth:`start` once (before or after the autopilot is identified); :meth:`stop`, or closing
    the link, ends it. ``results``: the last round's answers; ``rounds``: rounds started; ``on_results`` is
    called with the answers at the end of each round (e.g. to put them in the flight's event log)."""

    def __init__(self, link: Link, rates: Sequence[Rate] = RATES, ack_timeout: float = ACK_TIMEOUT_S,
                 on_results: Callable[[dict[str, str]], object] | None = None) -> None:
        self.link = link
        self.rates = tuple(rates)
        self.ack_timeout = ack_timeout
        self.on_results = on_results
        self.results: dict[str, str] = {}
        self.rounds = 0
        self._task: asyncio.Task | None = None
        self._unregister: Callable[[], None] | None = None

    def start(self) -> TelemetryRates:
        """Register for (re)acquisitions, and ask now if the target is already known and alive."""
        if self._unregister is None:
            self._unregister = self.link.on_target_acquired(self._acquired)
            if self.link.target_system is not None and self.link.heartbeat_age <= self.link.heartbeat_timeout:
                self._acquired(self.link.last_heartbeat_msg)
        return self

    def stop(self) -> None:
        if self._unregister is not None:
            self._unregister()
            self._unregister = None
        if self._task is not None:
            self._task.cancel()

    async def wait(self) -> dict[str, str]:
        """The answers of the round in progress (or of the last one), once it is over."""
        while self._task is not None and not self._task.done():
            await asyncio.gather(self._task, return_exceptions=True)  # a newer round may replace it meanwhile
        return self.results

    def _acquired(self, _heartbeat: Message) -> None:
        if self._task is not None and not self._task.done():
            self._task.cancel()  # a new connection: ask again from the start
        self.rounds += 1
        self._task = asyncio.get_running_loop().create_task(self._round(), name=f"telemetry-rates {self.link.url}")

    async def _round(self) -> None:
        try:
            self.results = await request_rates(self.link, self.rates, self.ack_timeout)
            log.info("telemetry rates requested: %s", ", ".join(f"{k} {v}" for k, v in self.results.items()))
            if self.on_results is not None:
                self.on_results(dict(self.results))
        except LinkError as exc:  # lost or closed meanwhile: the next connection asks again
            log.debug("telemetry rate requests interrupted: %s", exc)
        except Exception:  # nobody awaits this task: a bug here must be seen, and must not touch the flight
            log.exception("telemetry rate requests failed")

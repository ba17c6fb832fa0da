"""A hostile autopilot for tests (issue 33): the built-in simulator behind a MAVLink-aware TCP proxy that misbehaves
in one chosen way, all on 127.0.0.1.

    fuseplan fly --connect tcp:127.0.0.1:PORT  -->  HostileProxy (one fault)  -->  SimAutopilot (tcp)

The proxy parses both directions with pymavlink, message by message, so it can cut the connection at a chosen
item, answer for the autopilot, rewrite what it says or add bytes after it. Messages it writes itself are packed
with the autopilot's system and component ids (or a rogue's). It runs with the simulator in a thread of its own
(:func:`running`), so the test can call the real CLI, ``companion.cli.main``, in its own thread.
"""

from __future__ import annotations

import asyncio
import contextlib
import random
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.sim import SimAutopilot
from planner.world.scenario import load_scenario

MODES = ("pass", "disconnect_mid_upload", "outage_changed_item", "rogue_first", "request_beyond_count",
         "count_65535", "garbage_after_heartbeat", "deny_start")
ROGUE_SYSTEM = 2


@dataclass
class Record:
    """What the hostile side saw and did, for the test's assertions."""

    sessions: int = 0
    cut_at_item: int | None = None  # the item whose arrival cut the connection (disconnect_mid_upload)
    injected: int = 0  # messages or byte runs the proxy added
    items_beyond: int = 0  # items the companion sent with a seq beyond the count it announced
    rewritten: int = 0  # messages it changed
    changed_item: int | None = None  # the item changed on the vehicle during the outage
    armed_with: list[list] = field(default_factory=list)  # the stored mission each time the vehicle was armed
    outage_at: float | None = None  # mission time (s) when the outage began


class HostileProxy:
    """TCP proxy in front of ``sim`` that misbehaves as ``mode`` says (see :data:`MODES`)."""

    def __init__(self, sim: SimAutopilot, mode: str, seed: int = 1) -> None:
        if mode not in MODES:
            raise ValueError(f"unknown mode {mode!r}")
        self.sim, self.mode = sim, mode
        self.record = Record()
        self._rng = random.Random(seed)
        self._server: asyncio.Server | None = None
        self._tasks: set[asyncio.Task] = set()
        self._cut_done = False
        self._count = 0  # the count of the upload under way (the companion's last MISSION_COUNT)
        self._ap = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)  # packs what we say as the autopilot
        self._rogue = mavlink.MAVLink(None, srcSystem=ROGUE_SYSTEM, srcComponent=1)

    @property
    def port(self) -> int:
        assert self._server is not None
        return self._server.sockets[0].getsockname()[1]

    async def start(self) -> HostileProxy:
        self._server = await asyncio.start_server(self._serve, "127.0.0.1", 0)
        return self

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
        for t in list(self._tasks):
            t.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)

    async def _serve(self, client_r: asyncio.StreamReader, client_w: asyncio.StreamWriter) -> None:
        self.record.sessions += 1
        try:
            up_r, up_w = await asyncio.open_connection("127.0.0.1", self.sim.port)
        except OSError:  # the simulator refuses connects during its outage: so does the proxy
            client_w.close()
            return
        cut = asyncio.Event()
        pumps = [asyncio.create_task(self._pump(client_r, up_w, client_w, "up", cut)),
                 asyncio.create_task(self._pump(up_r, client_w, client_w, "down", cut)),
                 asyncio.create_task(cut.wait())]
        if self.mode == "rogue_first":
            pumps.append(asyncio.create_task(self._rogue_heartbeats(client_w)))
        self._tasks.update(pumps)
        try:
            await asyncio.wait(pumps[:3], return_when=asyncio.FIRST_COMPLETED)
        finally:
            for t in pumps:
                t.cancel()
            for w in (client_w, up_w):
                w.close()
            self._tasks.difference_update(pumps)

    async def _rogue_heartbeats(self, client_w: asyncio.StreamWriter) -> None:
        """A second autopilot (system 2) that speaks first and keeps speaking, and answers nothing."""
        while True:
            hb = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                   mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 0,
                                                   mavlink.MAV_STATE_STANDBY, 3)
            client_w.write(hb.pack(self._rogue))
            self.record.injected += 1
            await asyncio.sleep(0.5)

    async def _pump(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                    client_w: asyncio.StreamWriter, direction: str, cut: asyncio.Event) -> None:
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        if self.mode == "rogue_first" and direction == "down":
            await asyncio.sleep(1.0)  # the rogue is heard first
        with contextlib.suppress(OSError, ConnectionError):
            while data := await reader.read(65536):
                out = bytearray()
                for msg in parser.parse_buffer(data) or []:
                    if msg.get_type() == "BAD_DATA":
                        continue
                    chunk = self._act(msg, direction, client_w, cut)
                    if chunk is None:
                        break
                    out += chunk
                writer.write(bytes(out))
                await writer.drain()
                if cut.is_set():
                    return

    def _act(self, msg: mavlink.MAVLink_message, direction: str, client_w: asyncio.StreamWriter,
             cut: asyncio.Event) -> bytes | None:
        """The bytes to forward for ``msg`` (None: cut the connection here)."""
        raw = bytes(msg.get_msgbuf())
        kind = msg.get_type()
        if self.mode == "disconnect_mid_upload" and direction == "up" and not self._cut_done \
                and kind == "MISSION_ITEM_INT" and msg.mission_type == mavlink.MAV_MISSION_TYPE_MISSION \
                and msg.seq == 3:
            self._cut_done = True
            self.record.cut_at_item = msg.seq
            cut.set()
            return None
        if direction == "up" and kind == "MISSION_COUNT":
            self._count = msg.count
        if direction == "up" and kind == "MISSION_ITEM_INT" and msg.seq >= self._count:
            self.record.items_beyond += 1
        if self.mode == "request_beyond_count" and direction == "up" and kind == "MISSION_COUNT":
            # answer first, as the autopilot, with a request for an item the list does not have
            bogus = mavlink.MAVLink_mission_request_int_message(msg.get_srcSystem(), msg.get_srcComponent(),
                                                                msg.count + 5, msg.mission_type)
            client_w.write(bogus.pack(self._ap))
            self.record.injected += 1
        if self.mode == "deny_start" and direction == "up" and kind == "COMMAND_LONG" \
                and msg.command == mavlink.MAV_CMD_MISSION_START:
            # armed already (ArduPlane: AUTO, arm, start), the start is refused, as the autopilot would answer it
            deny = mavlink.MAVLink_command_ack_message(msg.command, mavlink.MAV_RESULT_DENIED, 0, 0,
                                                       msg.get_srcSystem(), msg.get_srcComponent())
            client_w.write(deny.pack(self._ap))
            self.record.injected += 1
            return b""
        if self.mode == "count_65535" and direction == "down" and kind == "MISSION_COUNT":
            lie = mavlink.MAVLink_mission_count_message(msg.target_system, msg.target_component, 65535,
                                                        msg.mission_type)
            self.record.rewritten += 1
            return lie.pack(self._ap)
        if self.mode == "garbage_after_heartbeat" and direction == "down" and kind == "HEARTBEAT":
            self.record.injected += 1
            return raw + bytes(self._rng.randrange(256) for _ in range(64))
        return raw


def change_item_in_outage(sim: SimAutopilot, record: Record, seq: int, seconds: float) -> None:
    """The link goes silent for ``seconds`` (the simulator's own outage: TCP half-open, connects refused) and, as
    a ground station on another link would meanwhile, item ``seq`` of the stored mission is moved 40 m up."""
    sim.inject_outage(seconds)
    mission = sim._server.mission  # the stored list itself: what another ground station's upload would change
    mission[seq] = replace(mission[seq], z=mission[seq].z + 40.0)
    record.changed_item = seq
    record.outage_at = sim.mission_time


@contextlib.contextmanager
def running(scenario: Path, mode: str, speedup: float = 20.0,
            during: Callable[[SimAutopilot, Record], bool] | None = None) -> Iterator[tuple[int, Record, dict]]:
    """The simulator and a :class:`HostileProxy` in ``mode``, served from a thread; yields (the proxy's port,
    its record, a dict that gets ``mission`` and ``armed`` when the thread ends). ``during(sim, record)`` is
    called every 50 ms in the simulator's loop until it returns True (a fault to inject at the right moment)."""
    ready, stop, port, left = threading.Event(), threading.Event(), [0], {}
    proxy_box: list[HostileProxy] = []
    errors: list[BaseException] = []

    async def serve() -> None:
        sim = SimAutopilot(load_scenario(scenario), "tcp:127.0.0.1:0", speedup=speedup, seed=1)
        async with sim:
            proxy = await HostileProxy(sim, mode).start()
            proxy_box.append(proxy)
            port[0] = proxy.port
            was_armed = False
            ready.set()
            pending = during
            try:
                while not stop.is_set():
                    if sim.armed and not was_armed:  # what the vehicle held when it was armed
                        proxy.record.armed_with.append([(it.seq, it.command, it.x, it.y, round(it.z, 2))
                                                        for it in sim.mission])
                    was_armed = sim.armed
                    if pending is not None and pending(sim, proxy.record):
                        pending = None
                    await asyncio.sleep(0.05)
            finally:
                left["mission"] = sim.mission
                left["armed"] = sim.armed
                await proxy.stop()

    def run() -> None:
        try:
            asyncio.run(serve())
        except BaseException as e:  # surfaced to the test below
            errors.append(e)
            ready.set()

    thread = threading.Thread(target=run, name=f"hostile-{mode}")
    thread.start()
    try:
        assert ready.wait(20.0), "the hostile autopilot did not start"
        if errors:
            raise errors[0]
        yield port[0], proxy_box[0].record, left
    finally:
        stop.set()
        thread.join(20.0)
    if errors:
        raise errors[0]

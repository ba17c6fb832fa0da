"""Fuzzing the link and the mission protocol (issue 7): a fake autopilot answers everything with random bytes and
random, well-formed but wrong MAVLink messages. The client must neither crash nor hang: an upload ends, within a
bound, either verified or with a CompanionError; the link keeps working afterwards."""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.mavlink.errors import CompanionError
from companion.mavlink.link import Link
from companion.mavlink.protocol import MissionClient
from companion.mission.builder import MissionSpec, build_mission
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]
SC = load_scenario(ROOT / "sitl_scenarios" / "rescue_static.toml")
ITEMS = build_mission([[200.0, 200, 50], [500, 600, 80], [800, 800, 50]], MissionSpec("ardupilot", SC.vehicle, SC.home))
KINDS = [mavlink.MAVLink_mission_request_message, mavlink.MAVLink_mission_request_int_message,
         mavlink.MAVLink_mission_ack_message, mavlink.MAVLink_mission_count_message,
         mavlink.MAVLink_mission_item_int_message, mavlink.MAVLink_mission_current_message,
         mavlink.MAVLink_command_ack_message, mavlink.MAVLink_statustext_message,
         mavlink.MAVLink_heartbeat_message, mavlink.MAVLink_adsb_vehicle_message,
         mavlink.MAVLink_global_position_int_message]
RANGES = {"uint8_t": (0, 255), "int8_t": (-128, 127), "uint16_t": (0, 65535), "int16_t": (-32768, 32767),
          "uint32_t": (0, 2**32 - 1), "int32_t": (-(2**31), 2**31 - 1), "uint64_t": (0, 2**63), "int64_t": (0, 2**62)}


def random_message(rng: np.random.Generator) -> mavlink.MAVLink_message:
    """A well-formed message of a mission-related kind with random field values (targets often ours)."""
    cls = KINDS[int(rng.integers(len(KINDS)))]
    args = []
    for name, ftype, n in zip(cls.fieldnames, cls.fieldtypes, cls.array_lengths):
        if ftype == "char":
            args.append(bytes(rng.integers(32, 127, n, dtype=np.uint8)))
        elif ftype in ("float", "double"):
            v = [float(x) for x in rng.normal(0, 1e4, max(n, 1))]
            args.append(v if n else v[0])
        else:
            lo, hi = RANGES[ftype]
            v = [int(rng.integers(lo, hi, endpoint=True)) for _ in range(max(n, 1))]
            if name in ("target_system",) and rng.random() < 0.7:
                v = [1]
            args.append(v if n else v[0])
    return cls(*args)


class _FakeAutopilot(asyncio.DatagramProtocol):
    """Replies to every datagram with a few random messages (some from system 1, comp 1) and random bytes."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)
        self.packers = {s: mavlink.MAVLink(None, srcSystem=s, srcComponent=c) for s, c in ((1, 1), (2, 1), (1, 50))}

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport

    def datagram_received(self, data: bytes, addr: tuple) -> None:
        rng = self.rng
        hb = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                               0, 0, 0, 3)
        self.transport.sendto(hb.pack(self.packers[1]), addr)
        for _ in range(int(rng.integers(0, 4))):
            packer = list(self.packers.values())[int(rng.integers(3))]
            msg = random_message(rng)
            buf = msg.pack(packer)
            if rng.random() < 0.2:  # a broken copy too
                buf = bytes(b ^ 0xFF if rng.random() < 0.05 else b for b in buf)
            self.transport.sendto(buf, addr)
        if rng.random() < 0.3:
            self.transport.sendto(bytes(rng.integers(0, 256, int(rng.integers(1, 300)), dtype=np.uint8)), addr)


async def _session(seed: int) -> str:
    loop = asyncio.get_running_loop()
    transport, _ = await loop.create_datagram_endpoint(lambda: _FakeAutopilot(seed), local_addr=("127.0.0.1", 0))
    port = transport.get_extra_info("sockname")[1]
    try:
        async with Link(f"udpout:127.0.0.1:{port}", open_timeout=2.0, heartbeat_interval=0.05) as link:
            await link.wait_heartbeat(2.0)
            client = MissionClient(link, timeout=0.1, item_timeout=0.05, retries=2)
            client.item_giveup_s = 0.5
            try:
                await asyncio.wait_for(client.upload_verified(ITEMS), 15.0)  # the bound: no hang
                outcome = "verified"
            except CompanionError as e:
                outcome = type(e).__name__
            assert link.connected
            await link.wait_heartbeat(2.0)  # still receiving
            return outcome
    finally:
        transport.close()


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1))
def test_upload_against_a_garbage_autopilot_ends_cleanly(seed: int) -> None:
    assert asyncio.run(_session(seed)) in {"verified", "MissionTimeout", "MissionUploadError", "MissionVerifyError",
                                           "CommandError"}

"""MAVLink 2 signing between the companion and the simulated autopilot (issue 7), real UDP on 127.0.0.1."""

from __future__ import annotations

import asyncio
import hashlib
from pathlib import Path

import pytest

from companion.mavlink.errors import CompanionError
from companion.mavlink.link import HeartbeatTimeout, Link
from companion.mavlink.protocol import MissionClient
from companion.mavlink.signing import SigningKey, signing_timestamp
from companion.mission.builder import MissionSpec, build_mission
from companion.sim import SimAutopilot
from planner.errors import FuseplanError
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]
SC = load_scenario(ROOT / "sitl_scenarios" / "rescue_static.toml")
KEY = SigningKey.from_passphrase("correct horse battery staple")
ITEMS = build_mission([[200.0, 200, 50], [500, 600, 80], [800, 800, 50]], MissionSpec("ardupilot", SC.vehicle, SC.home))


async def _upload(sim_key: SigningKey | None, link_key: SigningKey | None) -> tuple:
    async with SimAutopilot(SC, "udpin:127.0.0.1:0", speedup=5.0, signing_key=sim_key) as sim:
        async with Link(f"udpout:127.0.0.1:{sim.port}", open_timeout=5.0, signing_key=link_key) as link:
            await link.wait_heartbeat(3.0)
            client = MissionClient(link, timeout=0.3, retries=2)
            client.item_giveup_s = 1.0
            try:
                await client.upload_verified(ITEMS)
                error = None
            except CompanionError as e:
                error = e
            return error, sim.mission, sim._transport._udp_parser.signing  # counters


def test_signed_link_uploads_and_verifies() -> None:
    error, stored, signing = asyncio.run(_upload(KEY, KEY))
    assert error is None and len(stored) == len(ITEMS)
    assert signing.goodsig_count > 0 and signing.badsig_count == 0


def test_autopilot_with_signing_ignores_an_unsigned_sender() -> None:
    error, stored, signing = asyncio.run(_upload(KEY, None))
    assert error is not None  # every request went unanswered: the upload timed out
    assert len(stored) == 1  # home only: nothing the unsigned sender sent was taken


def test_a_wrong_key_is_refused_both_ways() -> None:
    async def go() -> tuple:
        async with SimAutopilot(SC, "udpin:127.0.0.1:0", speedup=5.0, signing_key=KEY) as sim:
            wrong = SigningKey.from_passphrase("wrong")
            async with Link(f"udpout:127.0.0.1:{sim.port}", open_timeout=5.0, signing_key=wrong) as link:
                with pytest.raises(HeartbeatTimeout, match="signed with another key .* were dropped: check that "
                                   "both ends hold the same key"):  # the autopilot's messages fail our check
                    await link.wait_heartbeat(1.5)
                return sim.mission, sim._transport._udp_parser.signing  # counters

    stored, signing = asyncio.run(go())
    assert len(stored) == 1 and signing.badsig_count > 0 and signing.goodsig_count == 0


def test_companion_with_signing_ignores_an_unsigned_autopilot() -> None:
    """Nothing is heard, and the error says why (issue 33): the autopilot does not sign."""
    with pytest.raises(HeartbeatTimeout, match=r"signing is on and \d+ unsigned messages were dropped: the "
                       "autopilot does not sign"):
        asyncio.run(_upload(None, KEY))


def test_key_files(tmp_path: Path) -> None:
    """A key file is the key (32 raw bytes or 64 hex digits); a passphrase file is hashed; never the one for the
    other. More cases, and the file checks, in test_secret_files.py."""
    raw = bytes(range(32))
    (tmp_path / "raw.key").write_bytes(raw)
    (tmp_path / "raw.key").chmod(0o600)
    assert SigningKey.from_key_file(tmp_path / "raw.key").secret == raw
    (tmp_path / "pass.txt").write_text("correct-horse-battery-staple\n")
    (tmp_path / "pass.txt").chmod(0o600)
    key = SigningKey.from_passphrase_file(tmp_path / "pass.txt")
    assert key.secret == hashlib.sha256(b"correct-horse-battery-staple").digest()  # as MAVProxy
    with pytest.raises(FuseplanError, match="--signing-passphrase"):
        SigningKey.from_key_file(tmp_path / "pass.txt")
    (tmp_path / "empty").write_text("  \n")
    (tmp_path / "empty").chmod(0o600)
    for bad in ("empty", "missing"):
        with pytest.raises(FuseplanError, match=bad):
            SigningKey.from_passphrase_file(tmp_path / bad)
        with pytest.raises(FuseplanError, match=bad):
            SigningKey.from_key_file(tmp_path / bad)
    (tmp_path / "binary").write_bytes(b"\xff\xfe" * 5)
    (tmp_path / "binary").chmod(0o600)
    with pytest.raises(FuseplanError, match="not binary data"):
        SigningKey.from_passphrase_file(tmp_path / "binary")


def test_keys_are_never_printed() -> None:
    for text in (repr(KEY), str(KEY), f"{KEY}"):
        assert KEY.secret.hex() not in text and str(KEY.secret) not in text
    assert KEY.fingerprint in str(KEY)


def test_fly_signed_on_the_simulator_and_a_bad_key_file(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from companion.cli import main

    (tmp_path / "pass.txt").write_text("field-passphrase\n")
    (tmp_path / "pass.txt").chmod(0o600)
    report = tmp_path / "rep"
    code = main(["fly", str(ROOT / "sitl_scenarios" / "rescue_static.toml"), "--sim", "--speedup", "20", "-q",
                 "--signing-passphrase", str(tmp_path / "pass.txt"), "--report", str(report),
                 "--set", "planner.pso.n_pop=200", "--set", "planner.pso.max_iter=80"])
    assert code == 0
    events = (report / "events.jsonl").read_text()
    key = SigningKey.from_passphrase_file(tmp_path / "pass.txt")
    assert f'"key": "{key.fingerprint}"' in events and key.secret.hex() not in events
    (tmp_path / "empty.key").write_text("")
    (tmp_path / "empty.key").chmod(0o600)
    code = main(["fly", str(ROOT / "sitl_scenarios" / "rescue_static.toml"), "--sim", "-q",
                 "--signing-key", str(tmp_path / "empty.key"), "--report", str(tmp_path / "rep2")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "empty.key" in err[0] and "not 0 bytes" in err[0]


def test_signing_timestamps_go_on_across_a_reconnect() -> None:
    """An autopilot whose signing clock is ahead of ours (SITL under speed-up; a vehicle that was powered for a
    long time) ignores a new stream more than 60 s behind it. The companion takes the autopilot's timestamp from
    its signed messages; after a reconnect it must go on from there, not restart from the wall clock."""
    ahead = 600 * 100_000  # 10 minutes in 10 µs units

    async def go() -> tuple[int, int, int, list[int]]:
        async with SimAutopilot(SC, "tcp:127.0.0.1:0", speedup=5.0, signing_key=KEY) as sim:
            transport = sim._transport
            transport._packer.signing.timestamp += ahead  # the vehicle's clock
            parsers = []  # one per TCP connection: what each rejected

            def parser(*args: int, make=transport._mavlink):
                parsers.append(make(*args))
                return parsers[-1]

            transport._mavlink = parser
            async with Link(f"tcp:127.0.0.1:{sim.port}", open_timeout=5.0, signing_key=KEY, heartbeat_interval=0.2,
                            heartbeat_timeout=0.8, reconnect_min=0.2, reconnect_max=0.5) as link:
                await link.wait_heartbeat(3.0)
                await asyncio.sleep(0.3)
                learned = link._conn.mav.signing.timestamp
                sim.inject_outage(3.0)  # well past the heartbeat timeout, also on a loaded machine
                for _ in range(100):
                    await asyncio.sleep(0.1)
                    if link.reconnects:
                        break
                await link.wait_heartbeat(5.0)
                client = MissionClient(link, timeout=0.3, retries=3)
                await client.upload_verified(ITEMS)
                return (learned, link._conn.mav.signing.timestamp, link.reconnects,
                        [p.signing.badsig_count for p in parsers])

    learned, after, reconnects, rejected = asyncio.run(go())
    assert reconnects >= 1 and len(rejected) >= 2
    assert rejected[-1] == 0  # not even the greeting HEARTBEAT sent at once on the new connection
    now = signing_timestamp()
    assert learned > now + ahead // 2  # taken from the autopilot
    assert after >= learned  # and kept across the reconnect (the upload above was accepted)

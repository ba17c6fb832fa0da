"""The SITL fixture itself: real ArduPilot binaries on real sockets, started, reached, held and stopped."""

from __future__ import annotations

import socket
import time
from contextlib import closing
from pathlib import Path

import pytest
from processes import bindable
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from sitl_harness import ENV, SKIP_REASON, _claim_instance, defaults_file, ports, start_sitl, unavailable

from planner.world.home import Home
from planner.world.scenario import load_scenario


@pytest.fixture(scope="module")
def home() -> Home:
    return load_scenario(Path(__file__).resolve().parents[2] / "sitl_scenarios" / "rescue_static.toml").home


def _connect(url: str) -> mavutil.mavfile:
    """A pymavlink client as a ground station would open it (system 255, MAV_COMP_ID_MISSIONPLANNER)."""
    return mavutil.mavlink_connection(url, source_system=255, source_component=190, retries=1)


def _heartbeat(conn: mavutil.mavfile, system: int, component: int, timeout: float = 10.0):
    """The first HEARTBEAT from ``system``/``component`` within ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        msg = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=left)
        if msg is not None and (msg.get_srcSystem(), msg.get_srcComponent()) == (system, component):
            return msg
    pytest.fail(f"no HEARTBEAT from {system}/{component} on {conn.address} in {timeout} s")


def _all_ports_free(instance: int) -> bool:
    tcp0, tcp1, tcp2, udp = ports(instance)
    return all(bindable(p, socket.SOCK_STREAM) for p in (tcp0, tcp1, tcp2)) and bindable(udp, socket.SOCK_DGRAM)


@pytest.mark.parametrize(
    ("vehicle", "mav_type"), [("plane", mavlink.MAV_TYPE_FIXED_WING), ("copter", mavlink.MAV_TYPE_QUADROTOR)]
)
def test_heartbeat_on_serial0_then_stop_leaves_nothing(sitl_factory, home, vehicle, mav_type) -> None:
    sitl = sitl_factory(vehicle, home)
    assert "Waiting for connection" in sitl.log_path.read_text()
    assert f"Home: {home.lat:.6f} {home.lon:.6f} alt={home.alt:.6f}m" in sitl.log_path.read_text()
    assert bindable(int(sitl.serial1_url.rsplit(":", 1)[1]), socket.SOCK_STREAM)  # SERIAL1: not before SERIAL0
    with closing(_connect(sitl.serial0_url)) as gcs:
        hb = _heartbeat(gcs, 1, 1)
    assert hb.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert hb.type == mav_type
    sitl.stop()
    assert not Path(f"/proc/{sitl.pid}").exists()
    assert _all_ports_free(sitl.instance)
    assert sitl.leftovers() == []
    sitl.stop()  # harmless


def test_two_instances_at_once_get_different_ports(sitl_factory, home) -> None:
    a, b = sitl_factory("plane", home), sitl_factory("plane", home)
    assert a.instance != b.instance
    assert len({a.serial0_url, a.serial1_url, a.serial2_url, b.serial0_url, b.serial1_url, b.serial2_url}) == 6
    with closing(_connect(a.serial0_url)) as ga, closing(_connect(b.serial0_url)) as gb:
        _heartbeat(ga, 1, 1)
        _heartbeat(gb, 1, 1)
    a.stop()
    b.stop()


def test_busy_instance_is_skipped() -> None:
    first, lock = _claim_instance()
    lock.close()
    with socket.socket() as squatter:  # a hand-started SITL would hold its SERIAL0 like this
        # as SITL binds it: a connection of an earlier test to that port may still be in TIME_WAIT (CI once failed
        # here with EADDRINUSE right after the serve tests' SITL had stopped)
        squatter.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        squatter.bind(("127.0.0.1", ports(first)[0]))
        squatter.listen()
        other, lock = _claim_instance()
        lock.close()
    assert other != first


def test_gcs_holder_and_companion_on_serial1(sitl_factory, home) -> None:
    sitl = sitl_factory("plane", home)
    with sitl.hold_serial0() as holder:
        companion = mavutil.mavlink_connection(sitl.serial1_url, source_system=1, source_component=191, retries=1)
        with closing(companion):
            hb = _heartbeat(companion, 1, 1)
            assert hb.type == mavlink.MAV_TYPE_FIXED_WING
            # ArduPilot routes the holder's HEARTBEAT to SERIAL1 only once something arrived there
            companion.mav.heartbeat_send(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            gcs = _heartbeat(companion, 255, 190, timeout=5.0)
            assert (gcs.type, gcs.autopilot) == (mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID)
        assert holder.messages > 0 and not holder.eof
    assert not holder.thread.is_alive()
    assert holder.sock.fileno() == -1
    sitl.stop()


def test_unavailable_without_the_variable(monkeypatch, tmp_path) -> None:
    monkeypatch.delenv(ENV, raising=False)
    assert unavailable("plane") == SKIP_REASON
    monkeypatch.setenv(ENV, str(tmp_path))
    assert unavailable("copter") == f"ArduPilot SITL not available: no executable arducopter in {ENV}={tmp_path}"


def test_defaults_beside_the_binary_or_from_a_build_tree(tmp_path) -> None:
    bin_dir = tmp_path / "ardupilot" / "build" / "sitl" / "bin"
    bin_dir.mkdir(parents=True)
    assert defaults_file(bin_dir, "plane") is None
    params = tmp_path / "ardupilot" / "Tools" / "autotest" / "default_params"
    params.mkdir(parents=True)
    (params / "copter.parm").write_text("")
    assert defaults_file(bin_dir, "copter") == params / "copter.parm"
    (bin_dir / "copter.parm").write_text("")
    assert defaults_file(bin_dir, "copter") == bin_dir / "copter.parm"


def test_exit_before_listening_is_reported_with_the_log(tmp_path, monkeypatch) -> None:
    fake = tmp_path / "bin" / "arduplane"  # a real process that dies at start, as a SITL that cannot bind would
    fake.parent.mkdir()
    fake.write_text("#!/bin/sh\necho 'bind port failed'\nexit 3\n")
    fake.chmod(0o755)
    monkeypatch.setenv(ENV, str(fake.parent))
    (tmp_path / "work").mkdir()
    with pytest.raises(RuntimeError, match=r"exited with code 3 before listening(.|\n)*bind port failed"):
        start_sitl("plane", (-35.363261, 149.165230, 584.0), tmp_path / "work")

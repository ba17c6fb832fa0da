"""The PX4 SITL fixture itself: a real PX4 (SIH) on real UDP sockets, started at a scenario's home, reached on the
companion link, stopped leaving nothing behind, and started again."""

from __future__ import annotations

import os
import re
import socket
import time
from contextlib import closing
from pathlib import Path

import pytest
from processes import bindable
from px4_harness import (
    ENV,
    SKIP_REASON,
    Px4Instance,
    broken_command_links,
    companion_port,
    ports,
    start_px4,
    unavailable,
)
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from planner.world.home import Home
from planner.world.scenario import load_scenario

SPEEDUP = 5.0
HOME_TOLERANCE_DEG = 1e-5  # PX4 keeps the home in float32 parameters: 149.16523 is stored as 149.1652374


@pytest.fixture(scope="module")
def home() -> Home:
    return load_scenario(Path(__file__).resolve().parents[2] / "sitl_scenarios" / "mountain_rescue.toml").home


def _connect(url: str) -> mavutil.mavfile:
    """A pymavlink client as a companion computer would open it (system 245, MAV_COMP_ID_ONBOARD_COMPUTER)."""
    return mavutil.mavlink_connection(url, source_system=245, source_component=191)


def _message(conn: mavutil.mavfile, kind: str, system: int, timeout: float = 10.0):
    """The first ``kind`` message from ``system``/1 within ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        msg = conn.recv_match(type=kind, blocking=True, timeout=left)
        if msg is not None and (msg.get_srcSystem(), msg.get_srcComponent()) == (system, 1):
            return msg
    pytest.fail(f"no {kind} from {system}/1 on {conn.address} in {timeout} s")


def _assert_gone(px4: Px4Instance) -> None:
    """Nothing of a stopped instance is left: process, any px4 in its directories, ports, directories."""
    assert px4.process.returncode is not None
    assert not Path(f"/proc/{px4.pid}").exists()
    assert all(bindable(p, socket.SOCK_DGRAM) for p in (*ports(px4.instance), companion_port(px4.instance)))
    assert px4.workdir is not None and px4.workdir.is_relative_to(px4.root)  # start.sh's mktemp went to our TMPDIR
    assert not px4.root.exists() and not px4.workdir.exists()
    assert px4.leftovers() == []


def test_unavailable_without_the_variable(monkeypatch, tmp_path) -> None:
    monkeypatch.delenv(ENV, raising=False)
    assert unavailable() == SKIP_REASON
    monkeypatch.setenv(ENV, str(tmp_path))
    assert unavailable() == f"PX4 SITL not available: no executable bin/px4 in {ENV}={tmp_path}"
    (tmp_path / "bin").mkdir()
    (tmp_path / "bin" / "px4").write_text("#!/bin/sh\n")
    (tmp_path / "bin" / "px4").chmod(0o755)
    assert unavailable() == f"PX4 SITL not available: neither start.sh nor etc/init.d-posix/rcS in {ENV}={tmp_path}"
    (tmp_path / "start.sh").write_text("#!/bin/sh\n")
    (tmp_path / "start.sh").chmod(0o755)
    assert unavailable() is None


def test_command_links_are_checked(tmp_path) -> None:
    (tmp_path / "bin").mkdir()
    flat = tmp_path / "bin" / "px4-commander"  # as in the shared install: a text file "px4", mode 0444
    flat.write_text("px4")
    flat.chmod(0o444)
    (tmp_path / "bin" / "px4-alias.sh").write_text("")  # sourced, not run
    assert broken_command_links(tmp_path) == ["px4-commander"]
    flat.unlink()
    flat.symlink_to("px4")
    (tmp_path / "bin" / "px4").write_text("")
    (tmp_path / "bin" / "px4").chmod(0o755)
    assert broken_command_links(tmp_path) == []


def test_heartbeat_and_home_then_stop_leaves_nothing(px4_factory, home) -> None:
    px4 = px4_factory(home, speedup=SPEEDUP)
    assert px4.companion_url == f"udpin:127.0.0.1:{14540 + px4.instance}"  # instance 0 unless one is running
    assert px4.system_id == px4.instance + 1
    log = px4.log_path.read_text()
    assert "model sihsim_quadx" in log and f"Simulation with {SPEEDUP:.1f}x speedup" in log
    with closing(_connect(px4.companion_url)) as link:
        hb = _message(link, "HEARTBEAT", px4.system_id)
        assert hb.autopilot == mavlink.MAV_AUTOPILOT_PX4
        assert hb.type == mavlink.MAV_TYPE_QUADROTOR
        pos = _message(link, "HOME_POSITION", px4.system_id)
    assert abs(pos.latitude * 1e-7 - home.lat) < HOME_TOLERANCE_DEG
    assert abs(pos.longitude * 1e-7 - home.lon) < HOME_TOLERANCE_DEG
    assert abs(pos.altitude * 1e-3 - home.alt) < 0.5  # m (measured: 584.0 -> 583.997..584.019)
    px4.stop()
    _assert_gone(px4)
    px4.stop()  # harmless


def test_start_stop_start_again_in_one_module(px4_factory, home) -> None:
    first = px4_factory(home, speedup=SPEEDUP)
    first.stop()
    _assert_gone(first)
    second = px4_factory(home, speedup=SPEEDUP)
    assert second.instance == first.instance  # the stop freed it
    assert second.root != first.root
    with closing(_connect(second.companion_url)) as link:
        assert _message(link, "HEARTBEAT", second.system_id).autopilot == mavlink.MAV_AUTOPILOT_PX4
    second.stop()
    _assert_gone(second)


def test_two_instances_at_once_get_their_own_ports_and_system_ids(px4_factory_fn, home) -> None:
    a, b = px4_factory_fn(home, speedup=SPEEDUP), px4_factory_fn(home, speedup=SPEEDUP)
    assert a.instance != b.instance and a.system_id != b.system_id
    assert a.companion_url != b.companion_url and not set(ports(a.instance)) & set(ports(b.instance))
    with closing(_connect(a.companion_url)) as la, closing(_connect(b.companion_url)) as lb:
        _message(la, "HEARTBEAT", a.system_id)
        _message(lb, "HEARTBEAT", b.system_id)
    a.stop()
    b.stop()
    _assert_gone(a)
    _assert_gone(b)


def test_a_build_folder_without_start_sh(px4_factory_fn, home, monkeypatch, tmp_path) -> None:
    """PX4's own build/px4_sitl_default: bin/px4 with working px4-* links and etc/, no start.sh (made here of
    symlinks to the shared install; nothing is copied)."""
    if unavailable():
        pytest.skip(unavailable())
    source = Path(os.environ[ENV]).resolve()
    build = tmp_path / "px4_sitl_default"
    (build / "bin").mkdir(parents=True)
    (build / "etc").symlink_to(source / "etc")
    (build / "bin" / "px4").symlink_to(source / "bin" / "px4")
    for p in (source / "bin").glob("px4-*"):
        (build / "bin" / p.name).symlink_to(p if p.name.endswith(".sh") else Path("px4"))
    assert broken_command_links(build) == []
    monkeypatch.setenv(ENV, str(build))
    px4 = px4_factory_fn(home, speedup=SPEEDUP)
    assert not (px4.root / "bin").exists()  # no symlink workaround needed
    assert px4.workdir == px4.root / "work"
    px4.stop()
    _assert_gone(px4)


def test_failed_startup_is_reported_with_the_log(monkeypatch, tmp_path) -> None:
    """A PX4 whose startup script fails keeps running without MAVLink (the shared install's flattened links did
    this): the start fails at once with PX4's output, and the process and directories are gone."""
    fake = tmp_path / "px4"
    (fake / "bin").mkdir(parents=True)
    (fake / "bin" / "px4").write_text("#!/bin/sh\n")
    (fake / "bin" / "px4").chmod(0o755)
    (fake / "start.sh").write_text(
        "#!/bin/sh\necho 'rcS: px4-param: Permission denied'\n"
        "echo 'ERROR [px4] Startup script returned with return value: 256'\nexec sleep 60\n"
    )
    (fake / "start.sh").chmod(0o755)
    monkeypatch.setenv(ENV, str(fake))
    with pytest.raises(RuntimeError, match=r"startup script failed(.|\n)*px4-param: Permission denied") as failed:
        start_px4((-35.363261, 149.165230, 584.0), timeout=10.0)
    log_path = Path(re.search(r"; (\S+/px4\.log) ", str(failed.value)).group(1))
    assert not log_path.parent.exists()  # the instance's temporary directory

"""Real ArduPilot SITL for tests: start the binary on free ports, wait until SERIAL0 listens, stop it leaving
nothing behind, and hold SERIAL0 as a ground station would.

The pytest fixtures are in tests/conftest.py; this module is importable from every test directory
(pyproject: ``pythonpath = ["tests"]``) and does not need pytest.
"""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Protocol

from processes import bindable, claim_instance, log_tail, processes_in, socket_inodes, terminate
from pymavlink.dialects.v20 import ardupilotmega as mavlink

ENV = "FUSEPLAN_SITL_DIR"
SKIP_REASON = (
    f"ArduPilot SITL not available: set {ENV} to a folder with arduplane/arducopter "
    "(see README: Flying against ArduPilot SITL)"
)
VEHICLES = {"plane": ("arduplane", "plane", "plane.parm"), "copter": ("arducopter", "quad", "copter.parm")}
FIRST_INSTANCE, LAST_INSTANCE = 1, 99  # engineers run SITL by hand on some of these: busy ones are skipped
LISTEN_TIMEOUT = 20.0  # s, start -> SERIAL0 in LISTEN (measured: under 0.1 s)
STOP_GRACE = 5.0  # s between SIGTERM and SIGKILL (measured: SIGTERM ends it in under 0.1 s)


class HomeLike(Protocol):
    """Anything with lat/lon (degrees) and alt (m AMSL), e.g. planner.world.scenario.Home."""

    @property
    def lat(self) -> float: ...
    @property
    def lon(self) -> float: ...
    @property
    def alt(self) -> float: ...


def ports(instance: int) -> tuple[int, int, int, int]:
    """TCP SERIAL0, SERIAL1, SERIAL2 and UDP RC-input port of ``-I instance`` (ArduPilot moves each by 10 N)."""
    return 5760 + 10 * instance, 5762 + 10 * instance, 5763 + 10 * instance, 5501 + 10 * instance


def unavailable(vehicle: str) -> str | None:
    """Why ``vehicle`` cannot be started (one line, for pytest.skip), or None when its binary is there."""
    sitl_dir = os.environ.get(ENV)
    if not sitl_dir or not Path(sitl_dir).is_dir():
        return SKIP_REASON
    binary = Path(sitl_dir) / VEHICLES[vehicle][0]
    if not os.access(binary, os.X_OK):
        return f"ArduPilot SITL not available: no executable {binary.name} in {ENV}={sitl_dir}"
    return None


def defaults_file(sitl_dir: Path, vehicle: str) -> Path | None:
    """The vehicle's default parameters: beside the binary, else from the ArduPilot tree of a build/sitl/bin."""
    name = VEHICLES[vehicle][2]
    candidates = [sitl_dir / name]
    if sitl_dir.parts[-3:] == ("build", "sitl", "bin"):
        candidates.append(sitl_dir.parents[2] / "Tools" / "autotest" / "default_params" / name)
    return next((p for p in candidates if p.is_file()), None)


def _claim_instance() -> tuple[int, IO[bytes]]:
    """The first instance whose four ports are free, claimed until stop (:func:`processes.claim_instance`)."""
    def free(n: int) -> bool:
        tcp0, tcp1, tcp2, udp = ports(n)
        return all(bindable(p, socket.SOCK_STREAM) for p in (tcp0, tcp1, tcp2)) and bindable(udp, socket.SOCK_DGRAM)

    return claim_instance("fuseplan-sitl-I{}.lock", range(FIRST_INSTANCE, LAST_INSTANCE + 1), free)


def _listening(port: int) -> set[str]:
    """Inodes of TCP sockets in LISTEN on ``port``."""
    return socket_inodes(("tcp", "tcp6"), port, "0A")


def _owned_sockets(pid: int) -> set[str]:
    """Inodes of the sockets process ``pid`` holds open."""
    found = set()
    try:
        fds = os.listdir(f"/proc/{pid}/fd")
    except OSError:
        return found
    for fd in fds:
        try:
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:["):
            found.add(target[8:-1])
    return found


class GcsHolder:
    """A ground station on SERIAL0 (system 255, component 190 = MAV_COMP_ID_MISSIONPLANNER): a daemon thread
    reads everything and sends a GCS HEARTBEAT at 1 Hz until closed. Connecting starts SITL's simulation."""

    def __init__(self, url: str) -> None:
        host, port = url.removeprefix("tcp:").rsplit(":", 1)
        self.url = url
        self.messages = 0  # MAVLink messages received from the autopilot
        self.eof = False  # the autopilot closed the connection
        self._codec = mavlink.MAVLink(None, srcSystem=255, srcComponent=mavlink.MAV_COMP_ID_MISSIONPLANNER)
        self._codec.robust_parsing = True
        self._closing = threading.Event()
        self.sock = socket.create_connection((host, int(port)), timeout=5.0)
        self.sock.settimeout(0.1)  # bounds how long close() waits for the thread
        self.thread = threading.Thread(target=self._run, name=f"sitl-gcs-{port}", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        """Heartbeat every second, read and parse the rest of the time; ends on close, EOF or a socket error."""
        next_beat = 0.0
        heartbeat = self._codec.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        while not self._closing.is_set():
            try:
                if time.monotonic() >= next_beat:
                    self.sock.sendall(heartbeat.pack(self._codec))
                    self._codec.seq = (self._codec.seq + 1) % 256
                    next_beat = time.monotonic() + 1.0
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            if not data:
                self.eof = True
                return
            self.messages += len(self._codec.parse_buffer(data) or [])

    def close(self) -> None:
        """Stop the thread, then close the socket (after the join, so the thread never sees a closed fd)."""
        self._closing.set()
        self.thread.join(5.0)
        self.sock.close()

    def __enter__(self) -> GcsHolder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(eq=False)
class SitlInstance:
    """One running SITL process and where to reach it; ``stop()`` ends it and checks nothing is left."""

    vehicle: str  # "plane" or "copter"
    instance: int  # the -I N it runs with
    workdir: Path  # its fresh working directory (eeprom.bin, terrain/, logs/, sitl.log)
    log_path: Path  # its stdout and stderr
    speedup: float
    binary: Path
    process: subprocess.Popen[bytes] = field(repr=False)
    startup_s: float = 0.0  # start -> SERIAL0 in LISTEN
    stop_s: float | None = None  # SIGTERM -> reaped, once stopped
    _lock: IO[bytes] | None = field(default=None, repr=False)
    _holders: list[GcsHolder] = field(default_factory=list, repr=False)

    @property
    def pid(self) -> int:
        return self.process.pid

    @property
    def serial0_url(self) -> str:
        """The ground station's port; SITL waits for a client here before it simulates anything."""
        return f"tcp:127.0.0.1:{ports(self.instance)[0]}"

    @property
    def serial1_url(self) -> str:
        """The companion computer's usual port (TELEM2); listening only once SERIAL0 has a client."""
        return f"tcp:127.0.0.1:{ports(self.instance)[1]}"

    @property
    def serial2_url(self) -> str:
        """A second spare port; listening only once SERIAL0 has a client."""
        return f"tcp:127.0.0.1:{ports(self.instance)[2]}"

    def log_tail(self, lines: int = 20) -> str:
        """The last lines of the SITL log, for failure messages."""
        return log_tail(self.log_path, lines)

    def wait_listening(self, url: str, timeout: float = LISTEN_TIMEOUT) -> float:
        """Wait until this process has a LISTEN socket on ``url``'s port (read from /proc, no connection made);
        returns the seconds waited. Raises RuntimeError with the log tail if it exits or the time runs out."""
        port = int(url.rsplit(":", 1)[1])
        t0 = time.monotonic()
        while not (_listening(port) & _owned_sockets(self.pid)):
            if self.process.poll() is not None:
                raise RuntimeError(
                    f"SITL {self.vehicle} -I{self.instance} exited with code {self.process.returncode} before "
                    f"listening on {port}; {self.log_path}:\n{self.log_tail()}"
                )
            if time.monotonic() - t0 > timeout:
                raise RuntimeError(
                    f"SITL {self.vehicle} -I{self.instance} not listening on {port} after {timeout:.0f} s; "
                    f"{self.log_path}:\n{self.log_tail()}"
                )
            time.sleep(0.01)
        return time.monotonic() - t0

    def hold_serial0(self, timeout: float = LISTEN_TIMEOUT) -> GcsHolder:
        """Connect a ground station to SERIAL0 (this starts the simulation) and return once SERIAL1 and SERIAL2
        listen; close it (or use ``with``) when done; ``stop()`` closes any still open."""
        holder = GcsHolder(self.serial0_url)
        self._holders.append(holder)
        try:
            self.wait_listening(self.serial1_url, timeout)
            self.wait_listening(self.serial2_url, timeout)
        except BaseException:
            holder.close()
            raise
        return holder

    def leftovers(self) -> list[str]:
        """What of this instance still exists: its process, a process of its binary in its workdir, a port."""
        found = []
        if self.process.returncode is None or Path(f"/proc/{self.pid}").exists():
            found.append(f"process {self.pid}")
        strays = processes_in(self.binary, self.workdir)
        found += [f"process {pid} ({self.binary.name} in {self.workdir})" for pid in strays]
        tcp0, tcp1, tcp2, udp = ports(self.instance)
        found += [f"LISTEN on tcp {p}" for p in (tcp0, tcp1, tcp2) if _listening(p)]
        if socket_inodes(("udp", "udp6"), udp, None):
            found.append(f"udp {udp} bound")
        return found

    def stop(self) -> None:
        """Close held ground stations, SIGTERM, SIGKILL after 5 s, reap; then assert nothing is left. A second
        call does nothing (the instance number may already belong to a newer SITL)."""
        if self._lock is None:
            return
        for holder in self._holders:
            holder.close()
        self.stop_s = terminate(self.process, STOP_GRACE)
        left = self.leftovers()
        self._lock.close()  # frees the instance number for the next start
        self._lock = None
        where = f"SITL {self.vehicle} -I{self.instance}"
        assert not left, f"{where} left {', '.join(left)}; {self.log_path}:\n{self.log_tail()}"


def start_sitl(
    vehicle: str, home: HomeLike | tuple[float, float, float], workdir: Path, speedup: float = 10.0
) -> SitlInstance:
    """Start ``vehicle`` from $FUSEPLAN_SITL_DIR in ``workdir`` on a free instance and return once SERIAL0
    listens (without connecting: the autopilot's boot is left for the test to watch)."""
    reason = unavailable(vehicle)
    if reason:
        raise FileNotFoundError(reason)
    sitl_dir = Path(os.environ[ENV]).resolve()
    binary_name, model, _ = VEHICLES[vehicle]
    binary = (sitl_dir / binary_name).resolve()  # as /proc/PID/exe shows it
    lat, lon, alt = home if isinstance(home, tuple) else (home.lat, home.lon, home.alt)
    instance, lock = _claim_instance()
    workdir = workdir.resolve()
    command = [str(binary), "--model", model, "--home", f"{lat},{lon},{alt},0"]
    defaults = defaults_file(sitl_dir, vehicle)
    if defaults is not None:
        command += ["--defaults", str(defaults)]
    command += ["--speedup", f"{speedup:g}", f"-I{instance}"]
    log_path = workdir / "sitl.log"
    with open(log_path, "wb") as log:
        log.write(f"$ {' '.join(command)}\n".encode())
        log.flush()
        t0 = time.monotonic()
        try:
            process = subprocess.Popen(
                command, cwd=workdir, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT
            )
        except OSError:
            lock.close()
            raise
    sitl = SitlInstance(vehicle, instance, workdir, log_path, speedup, binary, process, _lock=lock)
    try:
        sitl.wait_listening(sitl.serial0_url)
    except BaseException:
        with contextlib.suppress(AssertionError):  # the original error says more
            sitl.stop()
        raise
    sitl.startup_s = time.monotonic() - t0
    return sitl

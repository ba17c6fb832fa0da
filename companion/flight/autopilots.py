"""Real autopilots for ``fuseplan bench flights``: ArduPilot SITL or PX4 SITL (SIH), started for one flight on
free ports in a fresh temporary directory and stopped again leaving no process, port or file behind.

The test fixtures (``tests/sitl_harness.py``, ``tests/px4_harness.py``) do the same with more checks; this is the
part of them a bench needs, the same command lines, ports and lock files (so a bench and a test run at the same
time never pick the same instance). Linux only (it reads ``/proc/net``).

ArduPilot (README, "Flying against ArduPilot SITL"): ``arduplane --model plane --home LAT,LON,ALT,0 --defaults
plane.parm --speedup S -IN`` (copter: ``arducopter --model quad --defaults copter.parm``) in a fresh directory;
SERIAL0 on TCP 5760+10N, SERIAL1 5762+10N, SERIAL2 5763+10N, RC input UDP 5501+10N. SITL simulates nothing until
a client holds SERIAL0, and a client that stops reading stalls it: a ground station thread holds SERIAL0, reads
everything and sends a GCS HEARTBEAT every second; the companion flies on SERIAL1 and the scripted intruders are
reported on SERIAL2.

PX4 (README, "Flying against PX4 SITL"): ``start.sh LAT LON ALT`` of the PX4 folder (or ``bin/px4`` of a build
folder) with PX4_SIM_MODEL=sihsim_quadx and PX4_SIM_SPEED_FACTOR, instance N: the companion on
``udpin:127.0.0.1:14540+N``, the intruders on PX4's ground-station link ``udpout:127.0.0.1:18570+N``. When the
folder's ``bin/px4-*`` command links are not executable (the team's shared copy), real symlinks to ``bin/px4`` are
made in the temporary directory and put at the end of PATH.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from pymavlink.dialects.v20 import common as mavlink

log = logging.getLogger(__name__)
ARDUPILOT_ENV, PX4_ENV = "FUSEPLAN_SITL_DIR", "FUSEPLAN_PX4_DIR"
ARDUPILOT = {"plane": ("arduplane", "plane", "plane.parm"), "copter": ("arducopter", "quad", "copter.parm")}
PX4_MODEL = "sihsim_quadx"  # PX4's SIH airplane does not fly a mission (docs/px4.md)
PX4_VTOL_MODEL = "sihsim_standard_vtol"  # airframe 10043: flies a fixed-wing mission between VTOL take-off and landing
PX4_STARTED, PX4_FAILED = "Startup script returned successfully", "Startup script returned with return value"
START_TIMEOUT_S = 30.0  # start -> ready (measured: SITL listens in under 0.1 s, PX4 answers in 0.6-1.4 s)
STOP_GRACE_S = 5.0  # SIGTERM -> SIGKILL


class AutopilotError(RuntimeError):
    """An autopilot that would not start, or left something behind; the message ends with its log's tail."""


@dataclass(frozen=True)
class Endpoints:
    """Where ``fuseplan fly`` reaches a started autopilot."""

    connect: str  # the companion's link (``fly --connect``)
    traffic: str  # a spare MAVLink port for the scripted intruders (``fly --traffic``)
    describe: str  # one line for reports: firmware, instance, speed-up


def folder_of(env: str, folder: Path | None) -> Path | None:
    """``folder``, else the environment variable ``env``'s folder, else None."""
    named = folder if folder is not None else (Path(os.environ[env]) if os.environ.get(env) else None)
    return named.resolve() if named is not None else None


def ardupilot_missing(vehicle: str, folder: Path | None) -> str | None:
    """Why ArduPilot SITL ``vehicle`` cannot be started from ``folder`` (one line), or None."""
    if folder is None or not folder.is_dir():
        return f"ArduPilot SITL not found: set {ARDUPILOT_ENV} or --sitl-dir to the folder of arduplane/arducopter"
    if not os.access(folder / ARDUPILOT[vehicle][0], os.X_OK):
        return f"ArduPilot SITL not found: no executable {ARDUPILOT[vehicle][0]} in {folder}"
    return None


def px4_missing(folder: Path | None) -> str | None:
    """Why PX4 SITL cannot be started from ``folder`` (one line), or None."""
    if folder is None or not folder.is_dir():
        return f"PX4 SITL not found: set {PX4_ENV} or --sitl-dir to a folder with bin/px4 and start.sh"
    if not os.access(folder / "bin" / "px4", os.X_OK):
        return f"PX4 SITL not found: no executable bin/px4 in {folder}"
    if not os.access(folder / "start.sh", os.X_OK) and not (folder / "etc" / "init.d-posix" / "rcS").is_file():
        return f"PX4 SITL not found: neither start.sh nor etc/init.d-posix/rcS in {folder}"
    return None


# --- ArduPilot ------------------------------------------------------------------------------------------------------
def ardupilot_ports(instance: int) -> tuple[int, int, int, int]:
    """TCP SERIAL0, SERIAL1, SERIAL2 and the UDP RC-input port of ``-I instance``."""
    return 5760 + 10 * instance, 5762 + 10 * instance, 5763 + 10 * instance, 5501 + 10 * instance


@contextlib.contextmanager
def ardupilot_sitl(vehicle: str, home: tuple[float, float, float], folder: Path,
                   speedup: float = 10.0) -> Iterator[Endpoints]:
    """ArduPilot SITL ``vehicle`` ("plane", "copter") at ``home`` (lat, lon, alt AMSL), SERIAL0 held by a reading
    ground station, while the block runs; SERIAL1 and SERIAL2 listen on entry."""
    binary_name, model, parm = ARDUPILOT[vehicle]
    binary = folder / binary_name
    instance, lock = _claim("fuseplan-sitl-I{}.lock", range(1, 100), lambda n: _free_ardupilot(ardupilot_ports(n)))
    tcp0, tcp1, tcp2, udp = ardupilot_ports(instance)
    lat, lon, alt = home
    command = [str(binary), "--model", model, "--home", f"{lat},{lon},{alt},0"]
    if (folder / parm).is_file():
        command += ["--defaults", str(folder / parm)]
    command += ["--speedup", f"{speedup:g}", f"-I{instance}"]
    with lock, tempfile.TemporaryDirectory(prefix=f"fuseplan-sitl-I{instance}-") as work:
        log_path = Path(work) / "sitl.log"
        process = _spawn(command, Path(work), log_path, os.environ.copy(), new_session=False)
        gcs: _GroundStation | None = None
        try:
            gcs = _GroundStation.connect(tcp0, process, log_path)
            _wait_listening((tcp1, tcp2), process, log_path)
            yield Endpoints(f"tcp:127.0.0.1:{tcp1}", f"tcp:127.0.0.1:{tcp2}",
                            f"{binary_name} -I{instance} ({binary}) at {speedup:g}x")
        finally:
            if gcs is not None:
                gcs.close()
            _terminate(process, process.kill)
            left = _leftovers(process, tcp=(tcp0, tcp1, tcp2), udp=(udp,))
            tail = _tail(log_path)
    _raise_left(process, left, tail)


def _free_ardupilot(ports: tuple[int, int, int, int]) -> bool:
    return all(_bindable(p, socket.SOCK_STREAM) for p in ports[:3]) and _bindable(ports[3], socket.SOCK_DGRAM)


class _GroundStation:
    """A ground station on SERIAL0 (system 255, component 190): a daemon thread reads (and drops) everything
    SITL sends and sends a GCS HEARTBEAT every second, until closed."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.sock.settimeout(0.1)  # bounds how long close() waits for the thread
        self._closing = threading.Event()
        codec = mavlink.MAVLink(None, srcSystem=255, srcComponent=mavlink.MAV_COMP_ID_MISSIONPLANNER)
        self._heartbeat = codec.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        self._codec = codec
        self.thread = threading.Thread(target=self._run, name=f"sitl-gcs-{sock.getpeername()[1]}", daemon=True)
        self.thread.start()

    @classmethod
    def connect(cls, port: int, process: subprocess.Popen[bytes], log_path: Path) -> _GroundStation:
        """Connect once SITL accepts on ``port`` (it listens within a moment of starting)."""
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            try:
                return cls(socket.create_connection(("127.0.0.1", port), timeout=1.0))
            except OSError:
                if process.poll() is not None or time.monotonic() > deadline:
                    raise AutopilotError(_why(process, f"SERIAL0 (tcp {port}) never accepted", log_path)) from None
                time.sleep(0.05)

    def _run(self) -> None:
        next_beat = 0.0
        while not self._closing.is_set():
            try:
                if time.monotonic() >= next_beat:
                    self.sock.sendall(self._heartbeat.pack(self._codec))
                    self._codec.seq = (self._codec.seq + 1) % 256
                    next_beat = time.monotonic() + 1.0
                if not self.sock.recv(65536):
                    return  # SITL closed the connection
            except TimeoutError:
                continue
            except OSError:
                return

    def close(self) -> None:
        self._closing.set()
        self.thread.join(5.0)
        self.sock.close()


def _wait_listening(ports: tuple[int, ...], process: subprocess.Popen[bytes], log_path: Path) -> None:
    """Until every port has a TCP socket in LISTEN (read from /proc, no connection made)."""
    deadline = time.monotonic() + START_TIMEOUT_S
    while not all(_sockets(("tcp", "tcp6"), p, "0A") for p in ports):
        if process.poll() is not None or time.monotonic() > deadline:
            raise AutopilotError(_why(process, f"tcp {ports} not listening", log_path))
        time.sleep(0.02)


# --- PX4 ------------------------------------------------------------------------------------------------------------
PX4_OWN_PORTS = (14580, 18570, 14280, 13030, 19450)  # + instance: API link, GCS link, payload, gimbal, SIH
PX4_COMPANION_PORT = 14540  # + instance: where PX4's API link sends


@contextlib.contextmanager
def px4_sitl(home: tuple[float, float, float], folder: Path, speedup: float = 10.0,
             model: str = PX4_MODEL) -> Iterator[Endpoints]:
    """PX4 SITL (its SIH ``model``: the quadrotor, or :data:`PX4_VTOL_MODEL`) at ``home`` while the block runs; on
    entry it has sent a HEARTBEAT on the companion port (whose socket is closed again for ``fly`` to bind)."""
    instance, lock = _claim("fuseplan-px4-i{}.lock", range(10), lambda n: all(
        _bindable(p + n, socket.SOCK_DGRAM) for p in (*PX4_OWN_PORTS, PX4_COMPANION_PORT)))
    with lock:
        root = Path(tempfile.mkdtemp(prefix=f"fuseplan-px4-i{instance}-")).resolve()
        env = dict(os.environ, TMPDIR=str(root), PX4_SIM_MODEL=model, PX4_SIM_SPEED_FACTOR=f"{speedup:g}",
                   PX4_INSTANCE=str(instance))
        # no flight log (it would be deleted with the directory anyway): PX4 starts its logger unless SDLOG_BACKEND
        # is 0 (rc.logging); SDLOG_MODE -1 did not stop it, ~68 MB per flight
        env.setdefault("PX4_PARAM_SDLOG_BACKEND", "0")
        if any(not os.access(p, os.X_OK) for p in (folder / "bin").glob("px4-*") if not p.name.endswith(".sh")):
            links = root / "bin"
            links.mkdir()
            for p in (folder / "bin").glob("px4-*"):
                if not p.name.endswith(".sh"):
                    (links / p.name).symlink_to((folder / "bin" / "px4").resolve())
            env["PATH"] = f"{env.get('PATH', os.defpath)}:{links}"  # last: PX4 puts its own bin/ first
        where = [repr(float(v)) for v in home]
        if (folder / "start.sh").is_file():
            command = [str(folder / "start.sh"), *where]
        else:  # a build folder: what start.sh does
            for name in ("PX4_SYS_AUTOSTART", "PX4_NET_INTERFACE", "PX4_MAVLINK_BIND_ANY"):
                env.pop(name, None)
            env.update(PX4_SIMULATOR="sihsim", PX4_HOME_LAT=where[0], PX4_HOME_LON=where[1], PX4_HOME_ALT=where[2])
            (root / "work").mkdir()
            command = [str(folder / "bin" / "px4"), "-d", "-i", str(instance), "-w", str(root / "work"),
                       str(folder / "etc")]
        log_path = root / "px4.log"
        started = time.time()
        process = None
        try:
            process = _spawn(command, root, log_path, env, new_session=True)
            _wait_px4(process, log_path, PX4_COMPANION_PORT + instance, instance + 1)
            yield Endpoints(f"udpin:127.0.0.1:{PX4_COMPANION_PORT + instance}",
                            f"udpout:127.0.0.1:{PX4_OWN_PORTS[1] + instance}",
                            f"PX4 {model} -i{instance} ({folder}) at {speedup:g}x")
        finally:
            tail = _tail(log_path)
            if process is not None:
                _terminate(process, lambda: os.killpg(process.pid, signal.SIGKILL))
                for pid in _group(process.pid):  # a startup-script shell that outlived PX4
                    with contextlib.suppress(ProcessLookupError):
                        os.kill(pid, signal.SIGKILL)
            shutil.rmtree(root, ignore_errors=True)  # start.sh's working directory is made under TMPDIR
            sock = Path(f"/tmp/px4-sock-{instance}")  # PX4's command socket, left behind at a fixed path
            with contextlib.suppress(OSError):
                if sock.is_socket() and sock.lstat().st_mtime >= started:
                    sock.unlink()
            left = [] if process is None else _leftovers(process, udp=tuple(p + instance for p in PX4_OWN_PORTS))
    if process is not None:
        _raise_left(process, left, tail)


def _wait_px4(process: subprocess.Popen[bytes], log_path: Path, port: int, system: int) -> None:
    """Until PX4's startup script has run and its first HEARTBEAT from ``system``/1 arrives on ``port``."""
    deadline = time.monotonic() + START_TIMEOUT_S
    while PX4_STARTED not in (text := log_path.read_text(errors="replace")):
        if PX4_FAILED in text or process.poll() is not None or time.monotonic() > deadline:
            raise AutopilotError(_why(process, "startup script did not finish", log_path))
        time.sleep(0.02)
    codec = mavlink.MAVLink(None)
    codec.robust_parsing = True
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", port))
        sock.settimeout(0.1)
        while time.monotonic() < deadline:
            with contextlib.suppress(TimeoutError):
                for msg in codec.parse_buffer(sock.recv(65536)) or []:
                    if msg.get_type() == "HEARTBEAT" and (msg.get_srcSystem(), msg.get_srcComponent()) == (system, 1):
                        return
    raise AutopilotError(_why(process, f"no HEARTBEAT on udp {port}", log_path))


def _group(pgid: int) -> list[int]:
    """Pids in process group ``pgid`` (PX4 and the shells of its startup script)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            with contextlib.suppress(OSError, IndexError, ValueError):
                if int((entry / "stat").read_text().rsplit(")", 1)[1].split()[2]) == pgid:
                    pids.append(int(entry.name))
    return pids


# --- shared ---------------------------------------------------------------------------------------------------------
def _claim(lock_name: str, instances: range, free: Callable[[int], bool]) -> tuple[int, IO[bytes]]:
    """The first instance whose ports are ``free``, claimed by a lock file in the temporary directory (the test
    fixtures' own names) until it is closed."""
    for n in instances:
        try:
            lock = open(Path(tempfile.gettempdir()) / lock_name.format(n), "wb")  # held until stop
        except OSError:
            continue
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            lock.close()
            continue
        if free(n):
            return n, lock
        lock.close()
    raise AutopilotError(f"no free autopilot instance in {instances.start}..{instances.stop - 1}")


def _bindable(port: int, kind: socket.SocketKind) -> bool:
    """Whether 127.0.0.1:port can be bound (TCP with SO_REUSEADDR as SITL does: TIME_WAIT does not count)."""
    with socket.socket(socket.AF_INET, kind) as s:
        if kind == socket.SOCK_STREAM:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _sockets(tables: tuple[str, ...], port: int, state: str | None) -> bool:
    """Whether /proc/net ``tables`` hold a socket on local ``port`` (in ``state``, "0A" = LISTEN)."""
    for table in tables:
        with contextlib.suppress(FileNotFoundError):
            for row in Path("/proc/net", table).read_text().splitlines()[1:]:
                f = row.split()
                if int(f[1].rsplit(":", 1)[1], 16) == port and (state is None or f[3] == state):
                    return True
    return False


def _spawn(command: list[str], cwd: Path, log_path: Path, env: dict[str, str],
           new_session: bool) -> subprocess.Popen[bytes]:
    with open(log_path, "wb") as log:
        log.write(f"$ {' '.join(command)}\n".encode())
        log.flush()
        return subprocess.Popen(command, cwd=cwd, env=env, stdin=subprocess.DEVNULL, stdout=log,
                                stderr=subprocess.STDOUT, start_new_session=new_session)


def _terminate(process: subprocess.Popen[bytes], kill: Callable[[], None]) -> None:
    """SIGTERM, ``kill`` after :data:`STOP_GRACE_S`, reap."""
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(STOP_GRACE_S)
        except subprocess.TimeoutExpired:
            kill()
            process.wait()


def _program(process: subprocess.Popen[bytes]) -> str:
    """The program a process runs (its args: a list here, or one path)."""
    args = process.args
    return str(args[0] if isinstance(args, (list, tuple)) else args)


def _leftovers(process: subprocess.Popen[bytes], tcp: tuple[int, ...] = (), udp: tuple[int, ...] = ()) -> list[str]:
    """What of a stopped autopilot is still there: its process, a listening or bound port."""
    left = [f"process {process.pid}"] if Path(f"/proc/{process.pid}").exists() else []
    left += [f"tcp {p} listening" for p in tcp if _sockets(("tcp", "tcp6"), p, "0A")]
    left += [f"udp {p} bound" for p in udp if _sockets(("udp", "udp6"), p, None)]
    if left:  # said even when an error of the flight is on its way (the raise below is then not reached)
        log.warning("%s left %s after its stop", _program(process), ", ".join(left))
    return left


def _raise_left(process: subprocess.Popen[bytes], left: list[str], tail: str) -> None:
    if left:
        raise AutopilotError(f"{Path(_program(process)).name} left {', '.join(left)} after its stop:\n{tail}")


def _tail(log_path: Path | None, lines: int = 15) -> str:
    try:
        return "\n".join(log_path.read_text(errors="replace").splitlines()[-lines:]) if log_path else ""
    except OSError as e:
        return f"(no log: {e})"


def _why(process: subprocess.Popen[bytes], what: str, log_path: Path) -> str:
    state = f"exited with code {process.returncode}" if process.poll() is not None else "still running"
    return f"{Path(_program(process)).name}: {what} ({state}); the end of its log:\n{_tail(log_path)}"

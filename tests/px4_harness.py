"""Real PX4 SITL (its built-in SIH simulator) for tests: start it in a fresh temporary directory, wait until it
answers on the companion link, stop it leaving nothing behind.

``$FUSEPLAN_PX4_DIR`` names the PX4 folder: one with ``bin/px4`` and ``start.sh`` (the team's PX4 SITL install,
which CI points it at when present), or a PX4 build folder ``build/px4_sitl_default`` (``bin/px4`` and ``etc/``, no
start.sh: PX4 is then started the way start.sh does it). When the ``bin/px4-*`` command links of that folder are not
executable (the shared install's links were flattened into 3-byte text files, and PX4's startup script then fails on
``px4-param``), a directory of real symlinks ``px4-<cmd> -> bin/px4`` is made in the instance's temporary directory
and appended to PATH; nothing is copied. A working install or build folder is used as it is.

Ports: PX4 ``-i N`` binds UDP 127.0.0.1 ports 14580+N (API/offboard link, which sends to 14540+N: the companion's
``udpin:127.0.0.1:14540+N``), 18570+N (GCS link, sends to 14550), 14280+N, 13030+N and 19450+N, and is MAVLink
system N+1. Instances 0..9 are distinct (from 10 on PX4 sends every companion link to 14549), so several can run
at once: each start claims the first instance whose ports, the companion port included, are free, holding a lock
file (``$TMPDIR/fuseplan-px4-iN.lock``) until it is stopped. Alone on the machine a test gets instance 0:
``udpin:127.0.0.1:14540``, system 1. PX4 itself allows one process per instance number (``/tmp/px4-sock-N``).

The pytest fixtures are in tests/conftest.py; this module does not need pytest.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from processes import bindable, claim_instance, log_tail, processes_in, socket_inodes, terminate
from pymavlink.dialects.v20 import common as mavlink
from sitl_harness import HomeLike

ENV = "FUSEPLAN_PX4_DIR"
SKIP_REASON = (
    f"PX4 SITL not available: set {ENV} to a folder with bin/px4 and start.sh, or to a PX4 build/px4_sitl_default "
    "(see README: Flying against PX4 SITL)"
)
# the fastest lockstep a 2-core machine keeps up with (measured): 10x ran at 8.9x on one core, ATTITUDE never more
# than 0.02 s apart; 20x ran at 15-16x on both cores with gaps up to 0.4 s (6 s of PX4's time, more than its 5 s
# mission-protocol timeout), so uploads failed with MAV_MISSION_ERROR and the companion's planner process, starved,
# took 24 s to start: a rescue_static flight took 102 s at 20x, 37 s at 10x
FAST = 10.0
DEFAULT_MODEL = "sihsim_quadx"  # airframe 10040; sihsim_airplane boots but cannot fly a mission in SIH
FIRST_INSTANCE, LAST_INSTANCE = 0, 9
COMPANION_PORT, OWN_PORTS = 14540, (14580, 18570, 14280, 13030, 19450)  # each + instance
READY_TIMEOUT = 30.0  # s, start -> first HEARTBEAT on the companion link (measured: 0.6-1.2 s at 5x, 1.4 s at 1x)
STOP_GRACE = 5.0  # s between SIGTERM and SIGKILL (measured: SIGTERM ends it in 0.01 s)
STARTED = "Startup script returned successfully"  # PX4's log line once its startup script (rcS) has run
FAILED = "Startup script returned with return value"  # ... when it failed (PX4 keeps running, without MAVLink)


def ports(instance: int) -> tuple[int, ...]:
    """The UDP ports PX4 ``-i instance`` binds on 127.0.0.1: API/offboard link, GCS link, payload, gimbal, SIH."""
    return tuple(p + instance for p in OWN_PORTS)


def companion_port(instance: int) -> int:
    """Where PX4 ``-i instance`` sends its API/offboard link (from its port 14580+instance)."""
    return COMPANION_PORT + instance


def unavailable() -> str | None:
    """Why PX4 cannot be started (one line, for pytest.skip), or None when $FUSEPLAN_PX4_DIR holds it."""
    px4_dir = os.environ.get(ENV)
    if not px4_dir or not Path(px4_dir).is_dir():
        return SKIP_REASON
    root = Path(px4_dir)
    if not os.access(root / "bin" / "px4", os.X_OK):
        return f"PX4 SITL not available: no executable bin/px4 in {ENV}={px4_dir}"
    if not os.access(root / "start.sh", os.X_OK) and not (root / "etc" / "init.d-posix" / "rcS").is_file():
        return f"PX4 SITL not available: neither start.sh nor etc/init.d-posix/rcS in {ENV}={px4_dir}"
    return None


def broken_command_links(px4_dir: Path) -> list[str]:
    """Names of the ``bin/px4-*`` commands that are not executable (the startup script runs them from PATH)."""
    return sorted(
        p.name for p in (px4_dir / "bin").glob("px4-*") if not p.name.endswith(".sh") and not os.access(p, os.X_OK)
    )


def _make_command_links(px4_dir: Path, target: Path) -> Path | None:
    """Real symlinks ``target/px4-<cmd> -> bin/px4`` for every command, if any command link is broken."""
    if not broken_command_links(px4_dir):
        return None
    target.mkdir()
    binary = (px4_dir / "bin" / "px4").resolve()
    for p in (px4_dir / "bin").glob("px4-*"):
        if not p.name.endswith(".sh"):
            (target / p.name).symlink_to(binary)
    return target


def _claim_instance() -> tuple[int, IO[bytes]]:
    """The first instance whose ports and companion port are free, claimed until stop
    (:func:`processes.claim_instance`)."""
    return claim_instance("fuseplan-px4-i{}.lock", range(FIRST_INSTANCE, LAST_INSTANCE + 1),
                          lambda n: all(bindable(p, socket.SOCK_DGRAM) for p in (*ports(n), companion_port(n))))


def _process_group(pgid: int) -> list[int]:
    """Pids in process group ``pgid`` (PX4 and the shells of its startup script)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[2]) == pgid:
                pids.append(int(entry.name))
    return pids


def _first_heartbeat(port: int, system: int, timeout: float) -> bool:
    """Bind 127.0.0.1:port, wait up to ``timeout`` s for a HEARTBEAT from ``system``/1, close the socket."""
    codec = mavlink.MAVLink(None)
    codec.robust_parsing = True
    deadline = time.monotonic() + timeout
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", port))
        sock.settimeout(0.1)
        while time.monotonic() < deadline:
            try:
                data = sock.recv(65536)
            except TimeoutError:
                continue
            for msg in codec.parse_buffer(data) or []:
                if msg.get_type() == "HEARTBEAT" and (msg.get_srcSystem(), msg.get_srcComponent()) == (system, 1):
                    return True
    return False


@dataclass(eq=False)
class Px4Instance:
    """One running PX4 SITL and where to reach it; ``stop()`` ends it, deletes its directories and checks that
    nothing is left."""

    instance: int  # the -i N it runs with
    root: Path  # fresh temporary directory: start.sh's cwd and TMPDIR, px4.log, the command links if needed
    log_path: Path  # PX4's stdout and stderr (start.sh's own line first)
    home: tuple[float, float, float]  # lat, lon (degrees), alt (m AMSL) as requested
    speedup: float  # PX4_SIM_SPEED_FACTOR
    model: str  # PX4_SIM_MODEL
    binary: Path  # bin/px4, resolved as /proc/PID/exe shows it
    process: subprocess.Popen[bytes] = field(repr=False)
    workdir: Path | None = None  # PX4's working directory (parameters, dataman, .ulg logs), read once ready
    startup_s: float = 0.0  # start -> first HEARTBEAT on the companion link
    stop_s: float | None = None  # SIGTERM -> reaped, once stopped
    _started_at: float = field(default=0.0, repr=False)  # wall clock, to tell PX4's /tmp/px4-sock-N of this run
    _launch: tuple[list[str], dict[str, str]] | None = field(default=None, repr=False)  # command and environment
    _lock: IO[bytes] | None = field(default=None, repr=False)

    @property
    def pid(self) -> int:
        return self.process.pid

    @property
    def system_id(self) -> int:
        """PX4's MAVLink system id (MAV_SYS_ID = instance + 1); its autopilot is component 1."""
        return self.instance + 1

    @property
    def gcs_port(self) -> int:
        """PX4's ground-station link listens here (``udpout:127.0.0.1:PORT`` reaches it; it answers to the sender)."""
        return OWN_PORTS[1] + self.instance

    @property
    def companion_url(self) -> str:
        """The companion computer's link (PX4's API/offboard link sends here). Bind it after start() returns."""
        return f"udpin:127.0.0.1:{companion_port(self.instance)}"

    def log_tail(self, lines: int = 20) -> str:
        """The last lines of PX4's output, for failure messages."""
        return log_tail(self.log_path, lines)

    def _fail(self, what: str) -> RuntimeError:
        return RuntimeError(f"PX4 -i{self.instance} {what}; {self.log_path} (removed on stop):\n{self.log_tail()}")

    def wait_ready(self, timeout: float = READY_TIMEOUT) -> float:
        """Wait for PX4's startup line in its log, then for its first HEARTBEAT on the companion port (the socket
        is closed again, so the test can bind it); returns the seconds waited. RuntimeError with the log tail if
        PX4 exits, its startup script fails or the time runs out."""
        t0 = time.monotonic()
        while True:
            if self.process.poll() is not None:
                raise self._fail(f"exited with code {self.process.returncode} before answering")
            with contextlib.suppress(OSError):  # start.sh makes PX4's working directory, then execs PX4 there
                cwd = Path(os.readlink(f"/proc/{self.pid}/cwd"))
                self.workdir = cwd if cwd != self.root else self.workdir
            log = self.log_path.read_text(errors="replace")
            if FAILED in log:
                raise self._fail("startup script failed")
            if STARTED in log:
                break
            if time.monotonic() - t0 > timeout:
                raise self._fail(f"startup script not done after {timeout:.0f} s")
            time.sleep(0.02)
        left = max(0.5, timeout - (time.monotonic() - t0))
        try:
            answered = _first_heartbeat(companion_port(self.instance), self.system_id, left)
        except OSError as e:
            raise self._fail(f"companion port {companion_port(self.instance)} not bindable: {e}") from e
        if not answered:
            raise self._fail(f"no HEARTBEAT from {self.system_id}/1 on {self.companion_url} after {timeout:.0f} s")
        return time.monotonic() - t0

    def restart(self, timeout: float = READY_TIMEOUT) -> float:
        """Power-cycle the autopilot (PX4 SITL denies MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN): stop this PX4 as
        :meth:`stop` does, keeping its instance, ports and folder, and start it again with the same command; returns
        once its startup script has run again (its companion port is not probed: a companion may hold it). A fresh
        PX4: its parameters and mission storage are in a new working directory."""
        assert self._launch is not None and self._lock is not None
        terminate(self.process, STOP_GRACE, lambda: os.killpg(self.pid, signal.SIGKILL))
        for pid in _process_group(self.pid):
            if pid != self.pid:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
        with contextlib.suppress(OSError):
            self._socket_file().unlink()
        command, env = self._launch
        t0 = time.monotonic()
        with open(self.log_path, "ab") as log:
            offset = log.tell()
            log.write(f"$ {' '.join(command)}  (restart)\n".encode())
            log.flush()
            self.process = subprocess.Popen(command, cwd=self.root, env=env, stdin=subprocess.DEVNULL, stdout=log,
                                            stderr=subprocess.STDOUT, start_new_session=True)
        while True:
            if self.process.poll() is not None:
                raise self._fail(f"exited with code {self.process.returncode} after a restart")
            with contextlib.suppress(OSError):
                cwd = Path(os.readlink(f"/proc/{self.pid}/cwd"))
                self.workdir = cwd if cwd != self.root else self.workdir
            text = self.log_path.read_bytes()[offset:].decode(errors="replace")
            if FAILED in text:
                raise self._fail("startup script failed after a restart")
            if STARTED in text:
                return time.monotonic() - t0
            if time.monotonic() - t0 > timeout:
                raise self._fail(f"startup script not done {timeout:.0f} s after a restart")
            time.sleep(0.02)

    def _socket_file(self) -> Path:
        """PX4's command socket for this instance (PX4 leaves it behind; fixed path, not under TMPDIR)."""
        return Path(f"/tmp/px4-sock-{self.instance}")

    def leftovers(self) -> list[str]:
        """What of this instance still exists: its process (group), a px4 in its directories, a port, a directory."""
        found = []
        if self.process.returncode is None or Path(f"/proc/{self.pid}").exists():
            found.append(f"process {self.pid}")
        found += [f"process {pid} (group {self.pid})" for pid in _process_group(self.pid) if pid != self.pid]
        for where in {self.root, self.workdir or self.root}:
            found += [f"process {pid} ({self.binary.name} in {where})" for pid in processes_in(self.binary, where)]
        found += [f"udp {p} bound" for p in ports(self.instance) if socket_inodes(("udp", "udp6"), p, None)]
        found += [f"directory {d}" for d in {self.root, self.workdir or self.root} if d.exists()]
        return found

    def stop(self) -> None:
        """SIGTERM, SIGKILL to the process group after 5 s, reap; delete the temporary directory, PX4's working
        directory and its command socket of this run; then assert nothing is left. A second call does nothing."""
        if self._lock is None:
            return
        # SIGKILL to the whole group: it is ours, its leader not reaped yet
        self.stop_s = terminate(self.process, STOP_GRACE, lambda: os.killpg(self.pid, signal.SIGKILL))
        for pid in _process_group(self.pid):  # a startup-script shell that outlived PX4
            if pid != self.pid:  # the leader is reaped: that pid is no longer ours
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
        tail = self.log_tail()
        shutil.rmtree(self.root, ignore_errors=True)
        # under root when start.sh honours TMPDIR (its mktemp -t does); else only what its mktemp names px4sitl.*
        if self.workdir is not None and not self.workdir.is_relative_to(self.root):
            if self.workdir.name.startswith("px4sitl."):
                shutil.rmtree(self.workdir, ignore_errors=True)
        sock = self._socket_file()
        with contextlib.suppress(OSError):
            if sock.is_socket() and sock.lstat().st_mtime >= self._started_at:
                sock.unlink()
        left = self.leftovers()
        self._lock.close()  # frees the instance number for the next start
        self._lock = None
        assert not left, f"PX4 -i{self.instance} left {', '.join(left)}; {self.log_path} (removed):\n{tail}"


def start_px4(
    home: HomeLike | tuple[float, float, float],
    speedup: float = 5.0,
    model: str = DEFAULT_MODEL,
    timeout: float = READY_TIMEOUT,
) -> Px4Instance:
    """Start PX4 SITL from $FUSEPLAN_PX4_DIR at ``home`` on a free instance, in a fresh temporary directory, and
    return once it has sent a HEARTBEAT on its companion link (the link's socket is closed again by then)."""
    reason = unavailable()
    if reason:
        raise FileNotFoundError(reason)
    px4_dir = Path(os.environ[ENV]).resolve()
    lat, lon, alt = home if isinstance(home, tuple) else (home.lat, home.lon, home.alt)
    instance, lock = _claim_instance()
    try:
        root = Path(tempfile.mkdtemp(prefix=f"fuseplan-px4-i{instance}-")).resolve()
    except OSError:
        lock.close()
        raise
    env = dict(os.environ, TMPDIR=str(root), PX4_SIM_MODEL=model, PX4_SIM_SPEED_FACTOR=f"{speedup:g}")
    # PX4's flight log (ulog) off unless asked for: it is deleted with the instance, and at 20x it wrote 3.6 MB/s
    # and took a quarter of a core (rcS turns PX4_PARAM_<NAME> variables into parameters). rc.logging starts the
    # logger unless SDLOG_BACKEND is 0; SDLOG_MODE -1, set here before, did not stop it (~68 MB per VTOL flight)
    env.setdefault("PX4_PARAM_SDLOG_BACKEND", "0")
    env["PX4_INSTANCE"] = str(instance)
    links = _make_command_links(px4_dir, root / "bin")
    if links is not None:
        env["PATH"] = f"{env.get('PATH', os.defpath)}:{links}"  # last: PX4 puts its own bin/ first
    home_args = [repr(float(lat)), repr(float(lon)), repr(float(alt))]
    if (px4_dir / "start.sh").is_file():
        command = [str(px4_dir / "start.sh"), *home_args]
    else:  # a build folder: what start.sh does
        for name in ("PX4_SYS_AUTOSTART", "PX4_NET_INTERFACE", "PX4_MAVLINK_BIND_ANY"):
            env.pop(name, None)
        env.update(PX4_SIMULATOR="sihsim", PX4_HOME_LAT=home_args[0], PX4_HOME_LON=home_args[1])
        env["PX4_HOME_ALT"] = home_args[2]
        (root / "work").mkdir()
        command = [str(px4_dir / "bin" / "px4"), "-d", "-i", str(instance), "-w", str(root / "work")]
        command.append(str(px4_dir / "etc"))
    log_path = root / "px4.log"
    with open(log_path, "wb") as log:
        log.write(f"$ {' '.join(command)}\n".encode())
        log.flush()
        t0, started_at = time.monotonic(), time.time()
        try:
            process = subprocess.Popen(
                command, cwd=root, env=env, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                start_new_session=True,  # its own process group, so a SIGKILL reaches the startup script too
            )
        except OSError:
            lock.close()
            shutil.rmtree(root, ignore_errors=True)
            raise
    binary = (px4_dir / "bin" / "px4").resolve()
    px4 = Px4Instance(
        instance, root, log_path, (lat, lon, alt), speedup, model, binary, process, _started_at=started_at, _lock=lock,
        _launch=(command, env),
    )
    try:
        px4.wait_ready(timeout)
    except BaseException:
        with contextlib.suppress(AssertionError):  # the original error says more
            px4.stop()
        raise
    px4.startup_s = time.monotonic() - t0
    return px4

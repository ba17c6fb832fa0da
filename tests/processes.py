"""What the processes the tests start hold, and how they are claimed and stopped: shared by
tests/sitl_harness.py (ArduPilot SITL), tests/px4_harness.py (PX4 SITL) and tests/demo_flight.py (the companion);
also their resident memory. Linux /proc only; no pytest."""

from __future__ import annotations

import fcntl
import os
import socket
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import IO

_pick_lock = threading.Lock()


def bindable(port: int, kind: socket.SocketKind) -> bool:
    """Whether 127.0.0.1:port can be bound (TCP with SO_REUSEADDR as SITL does, so TIME_WAIT does not count)."""
    with socket.socket(socket.AF_INET, kind) as s:
        if kind == socket.SOCK_STREAM:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def claim_instance(lock_name: str, instances: Iterable[int], free: Callable[[int], bool]) -> tuple[int, IO[bytes]]:
    """The first of ``instances`` whose ports are ``free``, claimed by a lock file (``lock_name`` formatted with the
    instance) held until stop, so neither another fixture of this process nor a parallel pytest picks it before
    the autopilot has bound all its ports."""
    with _pick_lock:
        tried = list(instances)
        for n in tried:
            try:
                lock = open(Path(tempfile.gettempdir()) / lock_name.format(n), "wb")
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
    raise RuntimeError(f"no free instance in {tried[0]}..{tried[-1]} ({lock_name.format('N')})")


def socket_inodes(tables: tuple[str, ...], port: int, state: str | None) -> set[str]:
    """Inodes of the sockets in /proc/net ``tables`` on local ``port`` (in ``state``, e.g. "0A" = LISTEN)."""
    found = set()
    for table in tables:
        try:
            rows = Path("/proc/net", table).read_text().splitlines()[1:]
        except FileNotFoundError:
            continue
        for row in rows:
            f = row.split()
            if int(f[1].rsplit(":", 1)[1], 16) == port and (state is None or f[3] == state):
                found.add(f[9])
    return found


def processes_in(binary: Path, root: Path) -> list[int]:
    """Pids running ``binary`` with their working directory at or under ``root`` (an instance, or anything it
    left behind)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if os.readlink(entry / "exe") == str(binary) and Path(os.readlink(entry / "cwd")).is_relative_to(root):
                    pids.append(int(entry.name))
            except OSError:
                continue
    return pids


def log_tail(path: Path, lines: int = 20) -> str:
    """The last lines of a process's log, for failure messages."""
    try:
        text = path.read_text(errors="replace")
    except OSError as e:
        return f"(no log: {e})"
    return "\n".join(text.splitlines()[-lines:])


def terminate(process: subprocess.Popen, grace: float, kill: Callable[[], None] | None = None) -> float:
    """SIGTERM, then ``kill`` (default: SIGKILL to the process) after ``grace`` seconds, and reap; returns the
    seconds it took."""
    t0 = time.monotonic()
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(grace)
        except subprocess.TimeoutExpired:
            (kill or process.kill)()
            process.wait()
    return time.monotonic() - t0


def rss_kib(pid: int) -> int | None:
    """Resident memory of ``pid`` (KiB), None once it is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except (OSError, ValueError):
        return None
    return None

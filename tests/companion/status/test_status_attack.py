"""The status page attacked during a real flight: `fuseplan demo --status-page 0` in a child process limited to
256 file descriptors, and 300 connections that never finish their request held against its page for the whole
flight (each one the page closes is opened again). Before the page had its limits this aborted the flight before
its upload ("Too many open files"), with megabytes of tracebacks; now the page reads at most 16 of them at a time
(the rest wait in the kernel's queue, or fail to connect when it is full), the flight completes, its report
directory is whole, and stderr has one warning and no traceback."""

from __future__ import annotations

import json
import re
import resource
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

from demo_flight import CLI
from processes import terminate

FD_LIMIT = 256
HALF_OPEN = 300
ROUND_S = 0.5  # how often the attacker opens again what the page closed
# what the README says a report directory holds
REPORT = ("PLAN.json", "mission.waypoints", "mission.plan", "mission.geojson", "events.jsonl", "flight.json",
          "track.png")
# a third send nothing, a third half a request line, a third a request line and Host but never the blank line
OPENINGS = (b"", b"GET /eve", b"GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\n")


def _lower_fd_limit() -> None:
    resource.setrlimit(resource.RLIMIT_NOFILE, (FD_LIMIT, FD_LIMIT))


class HalfOpen:
    """:data:`HALF_OPEN` connections to ``port`` on 127.0.0.1, never finishing a request, kept until :meth:`stop`:
    every :data:`ROUND_S` each one the page has closed is opened again. Counts what it opened and what the page
    closed."""

    def __init__(self, port: int) -> None:
        self.port = port
        self.socks: list[socket.socket | None] = [None] * HALF_OPEN
        self.opened = self.closed_by_page = self.failed = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="half-open attacker", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            for i, sock in enumerate(self.socks):
                if sock is not None and self._open(sock):
                    continue
                if sock is not None:
                    sock.close()
                    self.closed_by_page += 1
                self.socks[i] = None
                try:
                    sock = socket.create_connection(("127.0.0.1", self.port), timeout=1.0)
                    sock.sendall(OPENINGS[i % len(OPENINGS)])
                except OSError:
                    self.failed += 1
                    continue
                self.socks[i] = sock
                self.opened += 1
            self._stop.wait(ROUND_S)

    @staticmethod
    def _open(sock: socket.socket) -> bool:
        try:
            return sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT) != b""
        except BlockingIOError:
            return True
        except OSError:
            return False

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(10)
        for sock in self.socks:
            if sock is not None:
                sock.close()


def test_300_half_open_connections_under_a_256_descriptor_limit_leave_the_flight_whole(tmp_path: Path) -> None:
    out, err = tmp_path / "stdout.txt", tmp_path / "stderr.txt"
    with out.open("w") as stdout, err.open("w") as stderr:
        proc = subprocess.Popen([sys.executable, "-c", CLI, "demo", "--status-page", "0"], cwd=tmp_path,
                                stdout=stdout, stderr=stderr, preexec_fn=_lower_fd_limit)
    attack = None
    try:
        end = time.monotonic() + 60
        while not (m := re.search(r"status page: http://127\.0\.0\.1:(\d+)/", out.read_text())):
            assert proc.poll() is None and time.monotonic() < end, out.read_text() + err.read_text()
            time.sleep(0.05)
        start = time.monotonic()
        attack = HalfOpen(int(m.group(1)))
        code = proc.wait(timeout=120)
        flew_s = time.monotonic() - start
    finally:
        if attack is not None:
            attack.stop()
        terminate(proc, 5.0)
    stderr_text = err.read_text()
    print(f"flight {flew_s:.1f} s under attack: {attack.opened} connections opened, {attack.closed_by_page} closed "
          f"by the page, {attack.failed} failed to connect; stderr: {stderr_text!r}")
    assert code == 0, out.read_text()[-3000:] + stderr_text[-3000:]
    assert "Traceback" not in stderr_text, stderr_text[:3000]
    assert len(stderr_text) < 2000, f"{len(stderr_text)} bytes on stderr: {stderr_text[:3000]}"  # no flood
    # the page was at its limits: its budget of connections reading a request full, and the kernel's queue behind it
    assert attack.opened + attack.failed >= HALF_OPEN and attack.failed > 0
    assert "connections reading their request, its limit" in stderr_text
    report = tmp_path / "fuseplan-demo"
    missing = [name for name in REPORT if not (report / name).is_file() or not (report / name).stat().st_size]
    assert not missing, f"the report directory lacks {missing}"
    flight = json.loads((report / "flight.json").read_text())
    assert flight["completed"] and flight["reason"] == "goal waypoint reached", flight
    last = json.loads((report / "events.jsonl").read_text().splitlines()[-1])
    assert last["event"] == "finished" and last["completed"], last

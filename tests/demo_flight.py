"""`fuseplan demo --status-page 0` as a child process for the status page's tests: started, its page's address
read from its output, its peak memory sampled from /proc while it flies; and 50 browsers' worth of event streams
plus one that stops reading, in a process of their own, with the checks they must pass."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

from processes import rss_kib, terminate

from companion.replanning.replan import ReplanConfig
from companion.status import load_events

CLI = "import sys; from companion.cli import main; sys.exit(main())"
CLIENTS = 50
LATENCY_TARGET_S = 1.0  # conflict seen → new mission current (README, the replan bench's target)

# 50 event streams read to the end and one connection that asks for the stream and never reads; in a process of
# its own, as browsers are. Prints one JSON line: records per stream, and which streams saw the flight finish.
CLIENTS_SCRIPT = r"""
import asyncio, json, socket, sys
import aiohttp

async def stream(session, url):
    n, finished = 0, False
    async with session.get(url) as r:
        async for line in r.content:
            if line.startswith(b"data: {\"t\""):
                n += 1
                finished |= b'"event":"finished"' in line
    return n, finished

async def main(url, clients):
    host, port = url.split("//")[1].split("/")[0].rsplit(":", 1)
    stalled = socket.socket()
    stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    stalled.connect((host, int(port)))
    stalled.sendall(f"GET /events HTTP/1.1\r\nHost: {host}:{port}\r\n\r\n".encode())
    async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(limit=0)) as s:
        got = await asyncio.gather(*(stream(s, url + "events") for _ in range(clients)))
    stalled.close()
    print(json.dumps({"records": [g[0] for g in got], "finished": [g[1] for g in got]}), flush=True)

asyncio.run(main(sys.argv[1], int(sys.argv[2])))
"""


class Companion:
    """``with Companion(cwd, "demo", "--status-page", "0") as c:`` → ``c.url``, then ``c.wait()``."""

    def __init__(self, cwd: Path, *args: str) -> None:
        self.proc = subprocess.Popen([sys.executable, "-c", CLI, *args], cwd=cwd, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True)
        self.lines: list[str] = []
        self.url = ""
        for line in self.proc.stdout:  # type: ignore[union-attr]  # Popen with stdout=PIPE
            self.lines.append(line)
            m = re.search(r"status page: (http://\S+)", line)
            if m:
                self.url = m.group(1)
                break
        if not self.url:
            self.proc.wait()
            raise AssertionError("no status page address in the output:\n" + "".join(self.lines))
        self.rss_start = rss_kib(self.proc.pid) or 0
        self.rss_peak = self.rss_start
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line)

    def wait(self, timeout: float = 120.0) -> int:
        """Exit code, sampling memory until then."""
        end = time.monotonic() + timeout
        while self.proc.poll() is None and time.monotonic() < end:
            self.rss_peak = max(self.rss_peak, rss_kib(self.proc.pid) or 0)
            time.sleep(0.05)
        code = self.proc.wait(timeout=max(end - time.monotonic(), 1.0))
        self._reader.join(5)
        return code

    @property
    def output(self) -> str:
        return "".join(self.lines)

    def __enter__(self) -> Companion:
        return self

    def __exit__(self, *exc: object) -> None:
        terminate(self.proc, 5.0)
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        self._reader.join(5)


def start_clients(url: str, n: int = CLIENTS) -> subprocess.Popen:
    """``n`` streams and one stalled connection to the page at ``url``, in a process of their own."""
    return subprocess.Popen([sys.executable, "-c", CLIENTS_SCRIPT, url, str(n)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def check_load(companion: Companion, clients: subprocess.Popen, report: Path) -> str:
    """Assert what the load must leave intact: every stream served to the end with every record, the replans
    within their targets, the companion's memory bounded; returns a summary line."""
    out, err = clients.communicate(timeout=60)
    assert clients.returncode == 0, err
    seen = json.loads(out)
    events = load_events(report)
    n = len(seen["records"])
    assert seen["finished"] == [True] * n  # every browser was served to the end
    assert min(seen["records"]) == max(seen["records"]) == len(events)  # every record, none skipped
    flight = json.loads((report / "flight.json").read_text())
    assert flight["completed"] and flight["replans"] >= 1, flight
    cfg = ReplanConfig()
    for r in flight["replan_log"]:
        if r["latency_s"] is not None:
            assert r["latency_s"] <= LATENCY_TARGET_S, r
        # the planner's own budget for that plan (doubled after a failed one), with the overrun the bench allows
        assert cfg.budget_s <= r["budget_s"] <= cfg.max_budget_s, r
        assert r["plan_s"] <= r["budget_s"] + 0.1, r
    growth_mib = (companion.rss_peak - companion.rss_start) / 1024
    assert growth_mib < 64, f"the companion grew by {growth_mib:.0f} MiB during the flight"
    return (f"{n} clients + 1 stalled: replan latency {[r['latency_s'] for r in flight['replan_log']]} s, "
            f"companion memory {companion.rss_start / 1024:.0f} MiB at the page's start, peak +{growth_mib:.1f} "
            f"MiB, {len(events)} records to each client")

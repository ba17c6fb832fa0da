"""``fuseplan serve`` from the command line: the documented example configuration checks; every mistake in a
configuration is one line naming the file and the field (exit 2); the service runs until SIGTERM and exits 0,
with its status page served meanwhile."""

from __future__ import annotations

import asyncio
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from companion.cli import main
from companion.service import load_config
from companion.service.cli import _serve
from companion.service.config import ConfigError

ROOT = Path(__file__).resolve().parents[3]
SCENARIO = ROOT / "sitl_scenarios" / "rescue_static.toml"


def test_the_documented_example_checks(capsys) -> None:
    assert main(["serve", "--check", str(ROOT / "docs" / "serve.example.toml")]) == 0
    assert "ok: link tcp:127.0.0.1:5762" in capsys.readouterr().out


@pytest.mark.parametrize(("body", "says"), [
    ('[link]\nurl = "tcp:127.0.0.1:5762"\nbaud = "fast"\n[plan]\nscenario = "{s}"\n', "link.baud: Input should be"),
    ('[link]\nurl = "tcp:127.0.0.1:5762"\nspeed = 1\n[plan]\nscenario = "{s}"\n', "link.speed: unknown key"),
    ('[link]\nurl = "tcp:127.0.0.1:5762"\n', "plan: required key is missing"),
    ('[link]\nurl = "carrier-pigeon:1"\n[plan]\nscenario = "{s}"\n', "link.url 'carrier-pigeon:1': unknown"),
    ('[link]\nurl = "tcp:127.0.0.1:5762"\n[plan]\nscenario = "none.toml"\n', "plan.scenario: "),
    ('[link]\nurl = "tcp:127.0.0.1:5762"\n[plan]\nscenario = "{s}"\nset = ["vehicle.cruise_speed=-1"]\n',
     "plan.scenario: "),
    ('[link]\nurl = "tcp:127.0.0.1:5762"\n[plan]\nscenario = "{s}"\nzones = ["nothere.json"]\n', "plan.zones[0]: "),
    ('[link]\nurl = "tcp:127.0.0.1:5762"\n[plan]\nscenario = "{s}"\n[service]\npoll_s = 0.01\n', "service.poll_s: "),
    ('[link\n', "malformed TOML"),
    ('[link]\nurl = "tcp:127.0.0.1:5762"\n[plan]\nscenario = "{s}"\n[service]\nstatus_page = "port 80"\n',
     "service.status_page: 'port 80': expected PORT or HOST:PORT"),
    ('[link]\nurl = "tcp:127.0.0.1:5762"\n[plan]\nscenario = "{s}"\n[service]\nstatus_page = "0.0.0.0:0"\n',
     "service.status_token: required: the page at 0.0.0.0:0 is reachable from other machines"),
    ('[link]\nurl = "tcp:127.0.0.1:5762"\n[plan]\nscenario = "{s}"\n[service]\nstatus_page = "0"\n'
     'status_token = "nothere.token"\n', "service.status_token: "),
    ('[link]\nurl = "tcp:127.0.0.1:5762"\n[plan]\nscenario = "{s}"\n[service]\nstatus_page = "127.0.0.1:{busy}"\n',
     "service.status_page: cannot listen on 127.0.0.1:"),
    ('[link]\nurl = "tcp:127.0.0.1:5762"\n[plan]\nscenario = "{s}"\n[service]\nlog_folder = "/proc/fuseplan"\n',
     "service.log_folder: cannot create /proc/fuseplan: "),
])
def test_a_bad_configuration_is_one_line_naming_file_and_field(tmp_path: Path, capsys, body: str, says: str) -> None:
    config = tmp_path / "serve.toml"
    with socket.socket() as busy:  # a port another program listens on
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        config.write_text(body.replace("{s}", str(SCENARIO)).replace("{busy}", str(busy.getsockname()[1])))
        assert main(["serve", "--check", str(config)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith(f"fuseplan: error: {config}: ") and says in err, err


def test_a_log_folder_it_cannot_write_at_start_up_is_one_line_exit_2(tmp_path: Path, capsys) -> None:
    """Checked, then made unwritable before the start (a file where the folder should be): one line, exit 2."""
    config = tmp_path / "serve.toml"
    config.write_text(f'[link]\nurl = "tcp:127.0.0.1:{_free_port()}"\n[plan]\nscenario = "{SCENARIO}"\n'
                      f'[service]\nlog_folder = "{tmp_path / "logs"}"\n')
    cfg = load_config(config)
    (tmp_path / "logs").write_text("not a folder")
    with pytest.raises(ConfigError, match=r"serve.toml: service.log_folder: cannot write .*logs"):
        asyncio.run(_serve(cfg, None))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_serve_runs_until_sigterm_and_exits_0_with_its_status_page(tmp_path: Path) -> None:
    """No autopilot at all: the service waits for one (retrying the link), serves its page, and stops cleanly."""
    config = tmp_path / "serve.toml"
    config.write_text(f'[link]\nurl = "tcp:127.0.0.1:{_free_port()}"\n[plan]\nscenario = "{SCENARIO}"\n'
                      f'[service]\nlog_folder = "{tmp_path / "logs"}"\nstatus_page = "127.0.0.1:0"\n')
    proc = subprocess.Popen([sys.executable, "-m", "companion.cli", "serve", str(config)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        url = None
        deadline = time.monotonic() + 60.0
        while url is None and time.monotonic() < deadline:
            line = proc.stderr.readline()
            if line.startswith("status page: "):
                url = line.split(": ", 1)[1].strip()
            assert line or proc.poll() is None, proc.stderr.read()
        assert url is not None
        with urllib.request.urlopen(url, timeout=10) as page:
            assert page.status == 200
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=20)
        print(f"stopped {time.monotonic() - t0:.2f} s after SIGTERM")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, out
    assert "fuseplan serve: stopped" in out
    events = (tmp_path / "logs" / "service.jsonl").read_text()
    assert '"serve_start"' in events and '"serve_stop"' in events


def test_quiet_serve_prints_only_its_start_and_stop_banners(tmp_path: Path) -> None:
    """-q: no progress lines (serve_start…), the two banners only; the events are still logged."""
    config = tmp_path / "serve.toml"
    config.write_text(f'[link]\nurl = "tcp:127.0.0.1:{_free_port()}"\n[plan]\nscenario = "{SCENARIO}"\n'
                      f'[service]\nlog_folder = "{tmp_path / "logs"}"\n')
    proc = subprocess.Popen([sys.executable, "-m", "companion.cli", "-q", "serve", str(config)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert proc.stdout is not None and proc.stdout.readline().startswith("fuseplan serve: link ")
        log = tmp_path / "logs" / "service.jsonl"
        deadline = time.monotonic() + 30.0
        while '"serve_start"' not in (log.read_text() if log.exists() else "") and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(0.5)  # its progress line would be out by now
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    assert out == "fuseplan serve: stopped\n" and not err, (out, err)
    assert '"serve_start"' in log.read_text() and '"serve_stop"' in log.read_text()

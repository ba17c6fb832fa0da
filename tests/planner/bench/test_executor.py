"""The executors of `fuseplan bench` and `compare` (issue 17): dask-local and a running dask cluster give the local
pool's records field by field (wall times aside), a worker killed mid-sweep costs only a re-run of its tasks,
failed runs are reported and retried, and every mistake in the options is one line."""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from companion.cli import main
from planner.bench import executor, runner
from planner.bench.executor import ExecutorSpec
from planner.errors import FuseplanError
from planner.world.scenario_text import ScenarioText

pytest.importorskip("distributed", reason="the [cluster] extra (dask.distributed) is part of [test]")
psutil = pytest.importorskip("psutil")  # distributed's own dependency

TINY = ["--runs", "2", "--set", "planner.pso.n_pop=20", "--set", "planner.pso.max_iter=5", "-q"]
TIMES = {"time_s", "roadmap_build_s"}  # wall clock: the only fields allowed to differ
SCENARIOS = Path(__file__).resolve().parents[3] / "sitl_scenarios"


def _records(jsonl: Path) -> dict[tuple[str, int], dict[str, Any]]:
    recs = [json.loads(line) for line in jsonl.read_text().splitlines()]
    keyed = {(r["variant"], r["run"]): r for r in recs}
    assert len(keyed) == len(recs), "a run written twice"
    return keyed


def _without_times(rec: dict[str, Any]) -> dict[str, Any]:
    out = {k: v for k, v in rec.items() if k not in TIMES}
    if "phases" in out:
        out["phases"] = {name: {k: v for k, v in ph.items() if k != "time_s"} for name, ph in out["phases"].items()}
    return out


def _assert_same_records(a: Path, b: Path) -> None:
    ra, rb = _records(a), _records(b)
    assert ra.keys() == rb.keys()
    for key in ra:
        assert set(ra[key]) == set(rb[key]), key
        for field, value in _without_times(ra[key]).items():  # field by field, so a failure names the field
            assert _without_times(rb[key])[field] == value, (key, field)


@pytest.fixture(scope="module")
def local_ablation(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("local")
    assert main(["bench", "ablation", "-o", str(out), *TINY, "--workers", "1"]) == 0
    return out


@pytest.fixture(scope="module")
def dask_local_ablation(tmp_path_factory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("dask-local")
    with contextlib.redirect_stdout(io.StringIO()) as stdout:
        assert main(["bench", "ablation", "-o", str(out), *TINY, "--executor", "dask-local", "--workers", "2"]) == 0
    return out, stdout.getvalue()


def test_dask_local_gives_the_local_records_field_by_field(local_ablation, dask_local_ablation) -> None:
    out, stdout = dask_local_ablation
    assert "12 runs computed, 0 reused" in stdout and " s on dask-local, 2 workers\n" in stdout
    _assert_same_records(local_ablation / "ablation.jsonl", out / "ablation.jsonl")
    md = (out / "ablation.md").read_text()
    assert "ran on dask-local, 2 workers" in md
    assert "ran on local, 1 process)" in (local_ablation / "ablation.md").read_text()
    strip = re.compile(r"ran on [^)]*|\d+\.\d+ ± \d+\.\d+ \| (?=\d+\.\d ± )")  # the executor, then the time column
    assert strip.sub("", md) == strip.sub("", (local_ablation / "ablation.md").read_text())


def test_a_sweep_interrupted_on_one_executor_resumes_on_another(local_ablation, dask_local_ablation, tmp_path,
                                                                 capsys) -> None:
    lines = (dask_local_ablation[0] / "ablation.jsonl").read_text().splitlines()
    (tmp_path / "ablation.jsonl").write_text("\n".join(lines[:9]) + "\n")  # nine runs done on dask-local
    capsys.readouterr()
    assert main(["bench", "ablation", "-o", str(tmp_path), *TINY, "--workers", "2"]) == 0
    out = capsys.readouterr().out
    assert "3 runs computed, 9 reused" in out and " s on local, 2 processes\n" in out
    _assert_same_records(local_ablation / "ablation.jsonl", tmp_path / "ablation.jsonl")


def _worker_processes(parent: int) -> list[Any]:
    """The dask-local worker processes under ``parent`` (multiprocessing spawns them)."""
    out = []
    for p in psutil.Process(parent).children(recursive=True):
        try:
            if "spawn_main" in " ".join(p.cmdline()):
                out.append(p)
        except psutil.NoSuchProcess:
            continue
    return out


def test_a_worker_killed_mid_sweep_costs_only_its_runs(tmp_path) -> None:
    """SIGKILL one of two workers once a few runs are in: the sweep completes, every run once, with the records
    the local pool makes."""
    sets = ["--runs", "2", "--set", "planner.pso.n_pop=40", "--set", "planner.pso.max_iter=30", "-q"]
    ref, out = tmp_path / "local", tmp_path / "dask"
    assert main(["bench", "ablation", "-o", str(ref), *sets, "--workers", "2"]) == 0
    jsonl = out / "ablation.jsonl"
    cmd = [sys.executable, "-c", "import sys; from companion.cli import main; sys.exit(main(sys.argv[1:]))",
           "bench", "ablation", "-o", str(out), *sets, "--executor", "dask-local", "--workers", "2"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    killed = None
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            done = len(jsonl.read_text().splitlines()) if jsonl.exists() else 0
            workers = _worker_processes(proc.pid)
            if done >= 3 and len(workers) == 2:
                killed = (done, workers[0].pid)
                os.kill(workers[0].pid, signal.SIGKILL)
                break
            time.sleep(0.05)
        stdout, stderr = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert killed is not None, "no worker to kill before the sweep ended"
    assert killed[0] < 12, "the kill came after the last run"
    assert not psutil.pid_exists(killed[1]) or psutil.Process(killed[1]).status() == psutil.STATUS_ZOMBIE
    assert proc.returncode == 0, stderr
    assert "12 runs computed, 0 reused" in stdout and " s on dask-local, 2 workers" in stdout
    _assert_same_records(ref / "ablation.jsonl", jsonl)  # every run once, the same numbers


def test_failed_runs_are_reported_the_others_kept_and_a_rerun_retries_them(tmp_path) -> None:
    path = SCENARIOS / "rescue_static.toml"
    sets = ("planner.pso.n_pop=10", "planner.pso.max_iter=3", 'planner.algorithm="spso"')
    good = ScenarioText.read(path, sets)
    broken = ScenarioText(good.file_name, good.data.replace(b"[route]", b"[route"))  # not TOML any more
    specs = [runner.RunSpec(str(path), sets, "S", r, 10 + r, source=broken if r == 1 else good) for r in range(3)]
    jsonl = tmp_path / "runs.jsonl"
    seen: list[tuple[int, int, int]] = []
    with pytest.raises(FuseplanError) as info:
        runner.run_specs(specs, jsonl, ExecutorSpec("local", 2), lambda *a: seen.append(a))
    msg = str(info.value)
    assert "1 of 3 runs failed" in msg and "S run 1 (seed 11)" in msg and "malformed TOML" in msg
    assert "\n" not in msg and str(jsonl) in msg
    assert seen[-1] == (3, 3, 1)
    assert sorted(_records(jsonl)) == [("S", 0), ("S", 2)]
    fixed = [s if s.run != 1 else runner.RunSpec(s.scenario, s.overrides, "S", 1, 11, source=good) for s in specs]
    outcome = runner.run_specs(fixed, jsonl, ExecutorSpec("local", 2))
    assert (outcome.computed, outcome.reused) == (1, 2)
    assert [r["run"] for r in outcome.records] == [0, 1, 2]


def test_a_run_needs_no_file_on_the_worker(tmp_path) -> None:
    """A spec carries its scenario's text: it runs where the scenario's path does not exist."""
    path = SCENARIOS / "rescue_static.toml"
    sets = ("planner.pso.n_pop=10", "planner.pso.max_iter=3", 'planner.algorithm="spso"')
    here = runner.run_one(runner.RunSpec(str(path), sets, "S", 0, 5, source=ScenarioText.read(path, sets)))
    nowhere = str(tmp_path / "gone" / "rescue_static.toml")
    there = runner.run_one(runner.RunSpec(nowhere, sets, "S", 0, 5, source=ScenarioText.read(path, sets)))
    assert _without_times(there) == _without_times(here)  # the fingerprint too: it names the file, not its folder


def _dask_command() -> list[str]:
    bin_dir = Path(sys.executable).parent
    return [str(bin_dir / "dask")] if (bin_dir / "dask").exists() else [sys.executable, "-m", "distributed.cli.dask"]


def _stop(procs: list[subprocess.Popen]) -> None:
    for p in reversed(procs):
        p.terminate()
    for p in procs:
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def _start_worker(address: str, folder: Path, env: dict[str, str] | None = None) -> subprocess.Popen:
    """One single-threaded `dask worker` in a folder of its own, as a user starts it."""
    folder.mkdir()
    return subprocess.Popen([*_dask_command(), "worker", address, "--host", "127.0.0.1", "--nthreads", "1",
                             "--no-nanny", "--no-dashboard"], env={**os.environ, **(env or {})}, cwd=folder,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


@pytest.fixture(scope="module")
def dask_cluster(tmp_path_factory) -> Iterator[str]:
    """`dask scheduler` and one `dask worker` (dask's own commands) on loopback; the scheduler's address."""
    folder = tmp_path_factory.mktemp("cluster")
    address_file = folder / "scheduler.json"
    procs = [subprocess.Popen([*_dask_command(), "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(address_file)],
                              cwd=folder, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        deadline = time.monotonic() + 60
        while not address_file.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(address_file.read_text())["address"]
        procs.append(_start_worker(address, folder / "worker"))
        yield address
    finally:
        _stop(procs)


def test_compare_on_a_running_dask_cluster_matches_the_local_pool(dask_cluster, tmp_path, capsys) -> None:
    args = ["compare", str(SCENARIOS / "rescue_static.toml"), "--runs", "2", "--algorithms", "spso,qpso",
            "--set", "planner.pso.n_pop=20", "--set", "planner.pso.max_iter=5", "-q"]
    assert main([*args, "-o", str(tmp_path / "local"), "--workers", "1"]) == 0
    capsys.readouterr()
    assert main([*args[:-1], "-o", str(tmp_path / "dask"), "--executor", "dask", "--scheduler", dask_cluster]) == 0
    jsonl = tmp_path / "dask" / "compare.jsonl"
    assert f"4 runs computed, 0 reused from {jsonl}; on dask, 1 worker\n" in capsys.readouterr().err
    _assert_same_records(tmp_path / "local" / "compare.jsonl", tmp_path / "dask" / "compare.jsonl")
    assert "(ran on dask, 1 worker)" in (tmp_path / "dask" / "compare.md").read_text()


def test_a_worker_with_other_software_is_refused(dask_cluster, tmp_path, capsys) -> None:
    """Records must not depend on which worker ran them: a worker on the numpy cost kernel (here: compiled) joins
    the cluster, and the sweep is refused before any run, naming the worker and what differs; a task checks again
    on its worker (one may join later)."""
    from distributed import Client

    bad = _start_worker(dask_cluster, tmp_path / "numpy-worker", {"FUSEPLAN_KERNEL": "numpy"})
    try:
        with Client(dask_cluster, timeout="10s") as client:
            client.wait_for_workers(2, timeout=60)
        code = main(["bench", "ablation", "-o", str(tmp_path / "out"), *TINY, "--executor", "dask", "--scheduler",
                     dask_cluster])
    finally:
        _stop([bad])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert re.search(r"dask worker tcp://127\.0\.0\.1:\d+ runs other software than this machine: cost kernel numpy "
                     r"\(here compiled\)", err), err
    assert not (tmp_path / "out" / "ablation.jsonl").exists() or not (tmp_path / "out" / "ablation.jsonl").read_text()
    want = {**executor.software(), "numpy": "0.0.0"}
    with pytest.raises(FuseplanError, match=r"numpy .* \(here 0\.0\.0\)"):
        executor._on_worker(len, "abc", want)
    assert executor._on_worker(len, "abc", executor.software()) == 3


@pytest.mark.parametrize("extra, word", [
    (["--executor", "dask"], "--scheduler"),
    (["--executor", "local", "--scheduler", "tcp://127.0.0.1:8786"], "--scheduler is for --executor dask"),
    (["--executor", "dask", "--scheduler", "tcp://127.0.0.1:8786", "--workers", "2"], "--workers does not apply"),
    (["--executor", "dask-local", "--workers", "0"], "--workers must be >= 1"),
    (["--executor", "nosuch"], "invalid choice"),
])
def test_executor_mistakes_are_one_line(extra, word, tmp_path, capsys) -> None:
    code = main(["bench", "ablation", "-o", str(tmp_path), *TINY, *extra]) if word != "invalid choice" else None
    if code is None:
        with pytest.raises(SystemExit) as info:
            main(["bench", "ablation", "-o", str(tmp_path), *TINY, *extra])
        code = info.value.code
    err = capsys.readouterr().err.strip()
    assert code == 2 and word in err, err
    if word != "invalid choice":
        assert len(err.splitlines()) == 1
    assert not (tmp_path / "ablation.jsonl").exists()


def test_unreachable_scheduler_is_one_line(tmp_path, capsys, monkeypatch) -> None:
    import socket

    monkeypatch.setattr(executor, "CONNECT_TIMEOUT_S", 1.0)  # refused at once, but dask retries until then
    with socket.socket() as s:  # a loopback port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    code = main(["bench", "ablation", "-o", str(tmp_path), *TINY, "--executor", "dask", "--scheduler",
                 f"tcp://127.0.0.1:{port}"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert f"cannot reach the dask scheduler at tcp://127.0.0.1:{port}" in err


def test_missing_cluster_extra_is_one_line(tmp_path) -> None:
    code = ("import sys; sys.modules['distributed'] = None; from companion.cli import main; "
            "sys.exit(main(sys.argv[1:]))")
    r = subprocess.run([sys.executable, "-c", code, "compare", str(SCENARIOS / "rescue_static.toml"), "-q",
                        "--executor", "dask-local", "-o", str(tmp_path / "c")], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0, r.stderr
    assert "pip install 'fuseplan[cluster]'" in r.stderr


def test_the_cluster_extra_is_imported_only_for_a_dask_executor(tmp_path) -> None:
    code = ("import sys; from companion.cli import main; code = main(sys.argv[1:]); "
            "print(code, 'distributed' in sys.modules, 'dask' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code, "compare", str(SCENARIOS / "rescue_static.toml"), "--runs", "1",
                        "--algorithms", "spso", "--set", "planner.pso.n_pop=10", "--set", "planner.pso.max_iter=2",
                        "--workers", "1", "-q", "-o", str(tmp_path / "c")], capture_output=True, text=True, timeout=120)
    assert r.stdout.split()[-3:] == ["0", "False", "False"], r.stdout + r.stderr


@pytest.mark.parametrize("argv", [["bench", "speed", "--quick"], ["bench", "replan"]])
def test_timing_benches_run_locally_only(argv, tmp_path, capsys) -> None:
    assert main([*argv, "-o", str(tmp_path), "-q", "--executor", "dask-local"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--executor local only" in err

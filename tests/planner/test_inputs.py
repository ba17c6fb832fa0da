"""Issue 33, inputs: every user mistake the issue lists is one line on stderr and exit 2 from the real command
line (``companion.cli.main``), never a traceback, a hang or minutes of work; and the pieces behind that
(:func:`planner.files.read_regular_file`, :mod:`planner.workload`) on their own."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from companion.cli import main
from planner import kernel
from planner.errors import FuseplanError
from planner.files import FileRefused, read_regular_file
from planner.plan import plan, problem_from_scenario
from planner.workload import MAX_PLAN_S, JobTooLarge, check_workload, estimate_s, memory_parts
from planner.world.scenario import MAX_SCENARIO_BYTES, load_scenario

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = ROOT / "sitl_scenarios"
RESCUE = SCENARIOS / "rescue_static.toml"
SHIPPED = sorted(SCENARIOS.glob("*.toml"))
# a 50 km square with nothing in it: the map of the sample-spacing row
BIG_MAP = """
[home]
lat = -35.363261
lon = 149.165230
alt = 584.0
[bounds]
x = 50000.0
y = 50000.0
[altitude]
min = 50.0
max = 300.0
[route]
start = [1000.0, 1000.0, 100.0]
goal = [45000.0, 45000.0, 100.0]
"""


def one_line_exit_2(capsys: pytest.CaptureFixture[str], argv: list[str], *words: str) -> str:
    """Run the command line; it must exit 2 with exactly one line on stderr holding every one of ``words``."""
    started = time.perf_counter()
    code = main(argv)
    out, err = capsys.readouterr()
    assert code == 2, (out, err)
    assert "Traceback" not in out + err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("fuseplan: error: ")
    for word in words:
        assert word in lines[0], lines[0]
    assert time.perf_counter() - started < 30, "a refusal must come before the work, not after it"
    return lines[0]


def _nested(depth: int) -> str:
    return "[" * depth + "]" * depth


@pytest.mark.parametrize(("setting", "field"), [
    ("vehicle.cruise_speed=1e308", "vehicle.cruise_speed: 1e+308 must be > 0 and <= 150 m/s"),
    ("vehicle.acceptance_radius=1e308", "vehicle.acceptance_radius: 1e+308 must be > 0 and <= 1000 m"),
    ("hazard.d_coll=1e308", "hazard.d_coll: 1e+308 must be >= 0"),
    ("hazard.d_safe=1e308", "hazard.d_safe: 1e+308 must be > 0"),
    ("vehicle.turn_overshoot=1e308", "vehicle.turn_overshoot"),
    ("vehicle.takeoff_alt=1e308", "vehicle.takeoff_alt"),
    ("planner.seed=100000000000000000000000000000000000000", "planner.seed: about 1e38 must be"),
    ("planner.pso.n_pop=1", "planner.pso.n_pop: 1 must be >= 2"),
    ("hazard.d_coll=100", "hazard.d_safe: 40 m must be >= d_coll (100 m)"),
    ("random_obstacles={seed=1, count=1000000, radius=[5.0, 10.0], height=[0.0, 50.0]}",
     "random_obstacles.count: Input should be less than or equal to 100000"),
])
def test_out_of_range_setting_is_one_line(capsys: pytest.CaptureFixture[str], setting: str, field: str) -> None:
    one_line_exit_2(capsys, ["plan", str(RESCUE), "-q", "--set", setting], str(RESCUE), field)


@pytest.mark.parametrize("value", [_nested(3000), "{a=" * 3000 + "1" + "}" * 3000, _nested(17)],
                         ids=["3000 arrays", "3000 inline tables", "17 arrays"])
def test_deep_set_value_is_one_line(capsys: pytest.CaptureFixture[str], value: str) -> None:
    one_line_exit_2(capsys, ["plan", str(RESCUE), "-q", "--set", f"planner.x={value}"], str(RESCUE), "--set",
                    "nested", "planner.x")


def test_deep_set_key_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    key = ".".join(["a"] * 3000)
    one_line_exit_2(capsys, ["plan", str(RESCUE), "-q", "--set", f"{key}=1"], str(RESCUE), "--set", "nested")


@pytest.mark.parametrize("tail", [f"extra = {_nested(3000)}", "extra = " + "{a=" * 3000 + "1" + "}" * 3000,
                                  f"extra = {_nested(17)}", "[" + ".".join(["t"] * 3000) + "]\nx = 1"],
                         ids=["3000 arrays", "3000 inline tables", "17 arrays", "3000 dotted table names"])
def test_deep_scenario_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], tail: str) -> None:
    path = tmp_path / "deep.toml"
    path.write_text(BIG_MAP + tail + "\n")
    one_line_exit_2(capsys, ["plan", str(path), "-q"], str(path), "nested", "deeper than 16 levels")


def test_fine_sampling_on_a_huge_map_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "big.toml"
    path.write_text(BIG_MAP)
    line = one_line_exit_2(capsys, ["plan", str(path), "--set", "planner.sample_spacing=0.1"], str(path),
                           "planner.sample_spacing=0.1 m on a 62225 m route", "trajectory samples",
                           "raise planner.sample_spacing to at least 0.7 m")
    assert "planning" not in line  # the refusal comes before the progress line, so stderr holds only it


@pytest.mark.parametrize(("sets", "words"), [
    (["planner.pso.n_pop=20000", "planner.pso.max_iter=100000"],
     ("lower planner.pso.n_pop",)),  # the time it would take (or, on the numpy kernel, the memory)
    (["planner.aco.cross_half=20", "planner.aco.vert_half=10"], ("planner.aco.cross_half=20", "corridor lattice")),
    (["planner.roadmap.enabled=true", "planner.roadmap.spacing=1", "planner.roadmap.max_levels=50"],
     ("planner.roadmap", "lattice nodes", "raise planner.roadmap.spacing")),
])
def test_impossible_job_is_one_line(capsys: pytest.CaptureFixture[str], sets: list[str],
                                    words: tuple[str, ...]) -> None:
    argv = ["plan", str(SCENARIOS / "hardmap_maze_0.toml"), "--set", "planner.pso.stagnation_iters=1"]
    for s in sets:
        argv += ["--set", s]
    one_line_exit_2(capsys, argv, str(SCENARIOS / "hardmap_maze_0.toml"), *words)


def test_a_million_obstacles_in_the_file_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """10^6 cylinders do not fit the 16 MB a scenario may hold: refused by size before a byte is parsed."""
    path = tmp_path / "field.toml"
    row = "[[cylinders]]\nx = 1.0\ny = 2.0\nradius = 3.0\n"
    path.write_text(BIG_MAP + row * (MAX_SCENARIO_BYTES // len(row) + 1))
    one_line_exit_2(capsys, ["plan", str(path), "-q"], str(path), "a scenario file may hold (16 MB)")


@pytest.mark.parametrize("kind", ["/dev/zero", "directory", "oversized", "symlink to /dev/zero", "missing"])
def test_unreadable_scenario_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], kind: str) -> None:
    path = {"/dev/zero": Path("/dev/zero"), "directory": tmp_path}.get(kind, tmp_path / "s.toml")
    if kind == "oversized":
        with path.open("wb") as f:  # sparse: nothing is written, the size alone refuses it
            f.truncate(MAX_SCENARIO_BYTES + 1)
    elif kind == "symlink to /dev/zero":
        path.symlink_to("/dev/zero")
    word = {"/dev/zero": "not a character device", "directory": "not a directory", "oversized": "is more than",
            "symlink to /dev/zero": "(/dev/zero)", "missing": "scenario file not found"}[kind]
    one_line_exit_2(capsys, ["plan", str(path), "-q"], str(path), word)


@pytest.mark.parametrize("dem", ["fifo.asc", "/dev/zero.hgt"])
def test_unreadable_terrain_file_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], dem: str) -> None:
    """The DEM a scenario names is read through the same gate: a FIFO (in-process: it is never opened, so it cannot
    block) or a device is refused, naming terrain.path."""
    if dem == "fifo.asc":
        os.mkfifo(tmp_path / dem)
    else:
        (tmp_path / "N35E149.hgt").symlink_to("/dev/zero")
        dem = "N35E149.hgt"
    path = tmp_path / "dem.toml"
    path.write_text(BIG_MAP + f'[terrain]\nkind = "file"\npath = "{dem}"\n')
    one_line_exit_2(capsys, ["plan", str(path), "-q"], str(path), "terrain.path: cannot read",
                    "a terrain file must be a regular file")


def test_terrain_grid_too_fine_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "hills.toml"
    path.write_text(BIG_MAP + '[terrain]\nkind = "hills"\nseed = 1\ncount = 5\nmax_height = 100.0\n'
                    "sigma = [500.0, 2000.0]\nspacing = 1.0\n")
    one_line_exit_2(capsys, ["plan", str(path), "-q"], str(path), "terrain.spacing: 1 m on a 50000 × 50000 m map",
                    "raise terrain.spacing")


def test_fifo_scenario_does_not_hang(tmp_path: Path) -> None:
    """In a process of its own, so that a regression hangs one subprocess (killed at the timeout), not the run."""
    fifo = tmp_path / "scenario.toml"
    os.mkfifo(fifo)
    done = subprocess.run([sys.executable, "-m", "companion.cli", "plan", str(fifo), "-q"], capture_output=True,
                          text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 2, done.stderr
    assert done.stderr.splitlines() == [f"fuseplan: error: {fifo}: a scenario file must be a regular file, not a FIFO "
                                        "(named pipe)"]
    assert "Traceback" not in done.stdout + done.stderr


# --- read_regular_file --------------------------------------------------------------------------------------------

def test_read_regular_file_reads_a_file(tmp_path: Path) -> None:
    path = tmp_path / "f.txt"
    path.write_bytes(b"x" * 100)
    assert read_regular_file(path, 100, "test") == b"x" * 100
    with pytest.raises(FileRefused, match=r"100 bytes is more than a test file may hold \(99 bytes\)"):
        read_regular_file(path, 99, "test")


def test_read_regular_file_refusals_are_fuseplan_errors(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(FuseplanError) as info:  # a FIFO with no writer: refused at once, never opened
        read_regular_file(fifo, 10, "plan")
    assert str(info.value) == f"{fifo}: a plan file must be a regular file, not a FIFO (named pipe)"
    assert (info.value.path, info.value.reason) == (str(fifo), "a plan file must be a regular file, not a FIFO "
                                                                "(named pipe)")


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux /proc")
def test_read_regular_file_caps_a_file_that_reports_no_size() -> None:
    """/proc files report size 0 and still hold bytes: the read stops one byte past the limit."""
    assert os.stat("/proc/self/status").st_size == 0
    with pytest.raises(FileRefused, match="more than 16 bytes"):
        read_regular_file("/proc/self/status", 16, "status")


# --- the work estimate --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_shipped_scenarios_are_far_inside_the_limits(path: Path) -> None:
    """The time limit stands two orders of magnitude above what the shipped scenarios ask on the compiled kernel
    (one on the numpy reference), each memory limit several times above."""
    sc = load_scenario(path)
    problem = problem_from_scenario(sc)
    check_workload(problem, sc.planner)
    assert estimate_s(problem, sc.planner) < MAX_PLAN_S / (100 if kernel.chosen() == "compiled" else 10)
    for part, limit in memory_parts(problem, sc.planner):
        assert part.amount < limit / 5, part.detail


def test_plan_refuses_before_it_allocates() -> None:
    """plan() itself checks (the replanner and the benches call it directly): 20 000 particles × 100 000 iterations
    would need hours, so it raises at once; with a time budget the search bounds itself and the same is allowed."""
    sc = load_scenario(RESCUE, ["planner.pso.n_pop=20000", "planner.pso.max_iter=100000"])
    problem = problem_from_scenario(sc)
    started = time.perf_counter()
    with pytest.raises(JobTooLarge, match="lower planner.pso.n_pop or planner.pso.max_iter"):
        plan(problem, sc.planner, np.random.default_rng(0))
    assert time.perf_counter() - started < 1.0
    check_workload(problem, sc.planner, budgeted=True)

"""What an install carries besides the code (planner.distribution, issue 36): the shipped scenarios found through
importlib.resources, every one loading from there with the terrain it names; each file they need declared as
package data, so a wheel carries it; and the version, in PLAN.json too. (.ci/run builds and installs the wheel and
flies ``fuseplan demo`` from an empty directory: too slow for a test.)"""

from __future__ import annotations

import fnmatch
import importlib.metadata
import importlib.resources
import subprocess
import tomllib
from pathlib import Path

import numpy as np
import pytest

from planner import distribution
from planner.distribution import SCENARIO_PACKAGE, fuseplan_version, shipped_scenarios
from planner.plan import plan, plan_to_json, problem_from_scenario
from planner.world.scenario import load_scenario

REPO = Path(__file__).resolve().parents[2]
SHIPPED = sorted(p.name for p in importlib.resources.files(SCENARIO_PACKAGE).iterdir() if p.name.endswith(".toml"))


def _package_data() -> list[str]:
    with (REPO / "pyproject.toml").open("rb") as f:
        return tomllib.load(f)["tool"]["setuptools"]["package-data"][SCENARIO_PACKAGE]


def test_the_shipped_scenarios_are_the_resources_of_their_package() -> None:
    where = shipped_scenarios()
    assert where == Path(str(importlib.resources.files(SCENARIO_PACKAGE))) and where.is_dir()
    assert where == REPO / "sitl_scenarios"  # in a checkout, the folder the docs and tests name
    assert {"rescue_dynamic.toml", "rescue_static.toml", "hardmap_valley_0.toml"} <= set(SHIPPED)


def test_the_cli_and_the_benches_read_them_from_there() -> None:
    from companion import cli
    from planner.bench import runner

    assert cli.SCENARIOS == runner.SCENARIO_DIR == shipped_scenarios()
    assert (cli.SCENARIOS / "rescue_dynamic.toml").is_file()  # what `fuseplan demo` flies


@pytest.mark.parametrize("name", SHIPPED, ids=lambda n: n.removesuffix(".toml"))
def test_every_shipped_scenario_loads_from_the_resolved_place_with_its_terrain(name: str) -> None:
    """Each one loads from the resolved directory; a terrain file it names is a file of the same package, beside
    it, of a kind declared as package data: a wheel carries it and the relative path still finds it."""
    resource = importlib.resources.files(SCENARIO_PACKAGE).joinpath(name)
    sc = load_scenario(shipped_scenarios() / name)
    assert sc.source == shipped_scenarios() / name
    terrain = tomllib.loads(resource.read_text(encoding="utf-8")).get("terrain", {})
    if "path" in terrain:
        dem = Path(terrain["path"])
        assert not dem.is_absolute() and dem.parent == Path("."), f"{name}: terrain {dem} is not beside it"
        assert importlib.resources.files(SCENARIO_PACKAGE).joinpath(dem.name).is_file()
        assert any(fnmatch.fnmatch(dem.name, pattern) for pattern in _package_data())
        assert sc.environment.terrain is not None  # read from the file


def test_every_file_of_the_folder_is_declared_package_data() -> None:
    """A scenario or terrain file added to the folder in a new format would be left out of the wheel."""
    patterns = _package_data()
    tracked = subprocess.run(["git", "ls-files", "sitl_scenarios"], cwd=REPO, capture_output=True, text=True)
    names = [Path(line).name for line in tracked.stdout.split()] if tracked.returncode == 0 else [
        p.name for p in shipped_scenarios().iterdir() if p.is_file()]  # no git: the files on disk
    data = [n for n in names if not n.endswith(".py") and not n.endswith(".pyc")]
    assert data and all(any(fnmatch.fnmatch(n, p) for p in patterns) for n in data), (data, patterns)
    assert (shipped_scenarios() / "__init__.py").is_file()  # a regular package: setuptools finds it by name


def test_the_version_comes_from_the_installed_metadata(monkeypatch: pytest.MonkeyPatch) -> None:
    try:
        installed = importlib.metadata.version("fuseplan")
    except importlib.metadata.PackageNotFoundError:
        installed = "unknown"
    assert fuseplan_version() == installed

    def missing(name: str) -> str:
        raise importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(importlib.metadata, "version", missing)
    distribution.fuseplan_version.cache_clear()
    try:
        assert fuseplan_version() == "unknown"  # sources run from a checkout that was never installed
    finally:
        distribution.fuseplan_version.cache_clear()


def test_plan_json_records_the_version() -> None:
    few = ['planner.algorithm="spso"', "planner.pso.max_iter=3"]
    sc = load_scenario(shipped_scenarios() / "rescue_static.toml", few)
    doc = plan_to_json(plan(problem_from_scenario(sc), sc.planner, np.random.default_rng(0), seed=0), sc)
    assert doc["fuseplan_version"] == fuseplan_version() and doc["format"] == "fuseplan-plan/1"

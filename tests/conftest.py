"""Shared fixtures: paths to the shipped scenarios, the TOML examples in the docs, and real ArduPilot SITL processes
(tests/sitl_harness.py) and PX4 SITL processes (tests/px4_harness.py)."""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TypeVar

import pytest
from px4_harness import DEFAULT_MODEL, Px4Instance, start_px4
from px4_harness import unavailable as px4_unavailable
from sitl_harness import HomeLike, SitlInstance, start_sitl, unavailable

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ROOT / "sitl_scenarios"

T = TypeVar("T", SitlInstance, Px4Instance)  # an autopilot process: it has stop()
SitlFactory = Callable[..., SitlInstance]
SITL_FIXTURES = {"sitl_factory", "sitl_factory_fn"}
Px4Factory = Callable[..., Px4Instance]
PX4_FIXTURES = {"px4_factory", "px4_factory_fn"}


@pytest.fixture
def rescue_static() -> Path:
    return SCENARIOS / "rescue_static.toml"


@pytest.fixture
def doc_toml() -> Callable[[str, str], str]:
    """``doc_toml(doc, heading)``: the first TOML block after ``heading`` in docs/``doc`` (examples run as tests)."""

    def block(doc: str, heading: str) -> str:
        found = re.search(r"```toml\n(.*?)```", (ROOT / "docs" / doc).read_text().partition(heading)[2], re.S)
        assert found is not None, f"no TOML block after {heading!r} in docs/{doc}"
        return found[1]

    return block


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--with-covered", action="store_true",
                     help="also run the slow tests that a faster test covers (marked slow(covered_by=...))")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark every test that uses an ArduPilot SITL fixture ``sitl`` and every one that uses a PX4 fixture ``px4``, so
    ``-m "not sitl"`` / ``-m "not px4"`` leaves them out. Leave out a test marked ``slow(covered_by=NAME)`` when the
    faster test NAME (of its module, or PATH::NAME from tests/; or every one of a tuple of them) runs, its autopilot
    installed (``--with-covered`` keeps it): the suite must fit CI's 20 minutes."""
    for item in items:
        if SITL_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.sitl)
        if PX4_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.px4)
    if config.getoption("--with-covered"):
        return
    # the tests that will run: an autopilot test only where that autopilot is installed (else it skips)
    missing = {"sitl": bool(unavailable("plane") or unavailable("copter")), "px4": bool(px4_unavailable())}
    runs = {item.nodeid for item in items if not any(item.get_closest_marker(k) and missing[k] for k in missing)}
    covered = []
    for item in items:
        mark = item.get_closest_marker("slow")
        by = mark.kwargs.get("covered_by") if mark is not None else None
        if not by:
            continue
        # NAME: a test of the same module; PATH::NAME: one of another module (PATH from tests/); a tuple: all of them
        names = (by,) if isinstance(by, str) else by
        by_ids = [item.nodeid.split("::")[0] + "::" + n if "::" not in n else "tests/" + n for n in names]
        if all(i in runs for i in by_ids):
            covered.append(item)
    if covered:
        config.hook.pytest_deselected(items=covered)
        left_out = {item.nodeid for item in covered}
        items[:] = [item for item in items if item.nodeid not in left_out]


def _stopped_afterwards(launch: Callable[..., T]) -> Iterator[Callable[..., T]]:
    """Yield ``launch`` (which starts an autopilot process, or skips the test) remembering what it started;
    afterwards stop all of it, each one, then fail once naming what any left behind."""
    started: list[T] = []

    def start(*args: object, **kwargs: object) -> T:
        instance = launch(*args, **kwargs)
        started.append(instance)
        return instance

    yield start
    problems = []
    for instance in started:
        try:
            instance.stop()
        except AssertionError as e:
            problems.append(str(e))
    if problems:
        pytest.fail("\n".join(problems))


def _sitl_factory(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SitlFactory]:
    """Yield ``start(vehicle, home, speedup=10.0) -> SitlInstance``; stop all it started afterwards."""

    def launch(vehicle: str, home: HomeLike | tuple[float, float, float], speedup: float = 10.0) -> SitlInstance:
        reason = unavailable(vehicle)
        if reason:
            pytest.skip(reason)
        return start_sitl(vehicle, home, tmp_path_factory.mktemp(f"sitl-{vehicle}"), speedup)

    yield from _stopped_afterwards(launch)


@pytest.fixture(scope="module")
def sitl_factory(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SitlFactory]:
    """``start(vehicle, home, speedup=10.0)``: a real SITL per call, stopped at the end of the test module
    (skips the test when $FUSEPLAN_SITL_DIR or the vehicle's binary is missing)."""
    yield from _sitl_factory(tmp_path_factory)


@pytest.fixture
def sitl_factory_fn(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SitlFactory]:
    """As ``sitl_factory``, but everything started is stopped at the end of the test."""
    yield from _sitl_factory(tmp_path_factory)


def _px4_factory() -> Iterator[Px4Factory]:
    """Yield ``start(home, speedup=5.0, model="sihsim_quadx") -> Px4Instance``; stop all it started afterwards."""

    def launch(
        home: HomeLike | tuple[float, float, float], speedup: float = 5.0, model: str = DEFAULT_MODEL
    ) -> Px4Instance:
        reason = px4_unavailable()
        if reason:
            pytest.skip(reason)
        return start_px4(home, speedup, model)

    yield from _stopped_afterwards(launch)


@pytest.fixture(scope="module")
def px4_factory() -> Iterator[Px4Factory]:
    """``start(home, speedup=5.0, model="sihsim_quadx")``: a real PX4 SITL per call, answering on
    ``.companion_url`` when returned, stopped at the end of the test module (skips the test when
    $FUSEPLAN_PX4_DIR is not a PX4 folder)."""
    yield from _px4_factory()


@pytest.fixture
def px4_factory_fn() -> Iterator[Px4Factory]:
    """As ``px4_factory``, but everything started is stopped at the end of the test."""
    yield from _px4_factory()

"""Issue 33: every number of [vehicle], [hazard] and [planner] has a finite, physical range on its field
(planner.world.config.within): far out of it is one line naming the dotted field, and a plan at either end of it
is a plan (finite cost, strict JSON), not an overflow."""

from __future__ import annotations

import dataclasses
import json
import math
import typing
from pathlib import Path

import numpy as np
import pytest

from planner.errors import ScenarioError
from planner.plan import plan, plan_to_json, problem_from_scenario
from planner.world.config import HazardConfig, PlannerSettings, VehicleLimits
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]
RESCUE = ROOT / "sitl_scenarios" / "rescue_static.toml"
QUICK = ("planner.pso.n_pop=10", "planner.pso.max_iter=3", "planner.aco.max_iter=2", "planner.aco.n_ants=5")


def numeric_fields(cls: type, prefix: str) -> list[tuple[str, type, tuple | None]]:
    """(dotted name, int or float, the field's within() bounds or None) of every number in a config dataclass."""
    hints = typing.get_type_hints(cls, include_extras=True)
    out = []
    for f in dataclasses.fields(cls):
        hint = hints[f.name]
        base = typing.get_args(hint)[0] if typing.get_origin(hint) is typing.Annotated else hint
        if dataclasses.is_dataclass(base):
            out += numeric_fields(base, f"{prefix}.{f.name}")
        elif base in (int, float):
            bounds = [getattr(getattr(m, "func", None), "bounds", None) for m in getattr(hint, "__metadata__", ())]
            out.append((f"{prefix}.{f.name}", base, next((b for b in bounds if b is not None), None)))
    return out


FIELDS = (numeric_fields(VehicleLimits, "vehicle") + numeric_fields(HazardConfig, "hazard")
          + numeric_fields(PlannerSettings, "planner"))


def test_every_number_is_found() -> None:
    names = {name for name, _, _ in FIELDS}
    assert {"vehicle.cruise_speed", "hazard.d_coll", "planner.sample_spacing", "planner.pso.n_pop",
            "planner.aco.cross_half", "planner.roadmap.spacing", "planner.weights.destination"} <= names
    assert len(FIELDS) >= 79


@pytest.mark.parametrize(("name", "kind"), [(n, k) for n, k, _ in FIELDS], ids=[n for n, _, _ in FIELDS])
def test_far_out_of_range_is_refused_naming_the_field(name: str, kind: type) -> None:
    for value in (("1e308", "-1e308") if kind is float else ("10" + "0" * 30, "-" + "1" + "0" * 30)):
        with pytest.raises(ScenarioError) as info:
            load_scenario(RESCUE, [f"{name}={value}"])
        assert info.value.field == name, str(info.value)
        assert "\n" not in str(info.value) and str(info.value).startswith(f"{RESCUE}: {name}: ")


def test_every_range_is_declared_on_the_field() -> None:
    """All but roadmap.spacing (0 or a range) carry within(): a rule lives beside its field, in one place."""
    undeclared = [name for name, _, bounds in FIELDS if bounds is None]
    assert undeclared == ["planner.roadmap.spacing"]
    for name, _, bounds in FIELDS:
        if bounds is not None:
            assert all(math.isfinite(b) for b in bounds[:2]), name


def _edge(bounds: tuple, kind: type) -> list[float]:
    """The two ends of a range, or just inside an open end."""
    lo, hi, open_lo, open_hi = bounds
    if kind is int:
        return [lo + open_lo, hi - open_hi]
    inside = [lo + max(abs(lo), 1.0) * 1e-6 if open_lo else lo, hi - max(abs(hi), 1.0) * 1e-6 if open_hi else hi]
    return [float(v) for v in inside]


# the physical ends that a plan could overflow on: vehicle, hazard and sampling
PHYSICAL = [(n, k, b) for n, k, b in FIELDS if n.startswith(("vehicle.", "hazard.")) or n == "planner.sample_spacing"]


@pytest.mark.parametrize(("name", "kind", "bounds"), PHYSICAL, ids=[n for n, _, _ in PHYSICAL])
def test_a_plan_at_either_end_of_a_range_is_finite(name: str, kind: type, bounds: tuple) -> None:
    for value in _edge(bounds, kind):
        sets = [*QUICK, f"{name}={value!r}"]
        if name == "hazard.d_coll":
            sets.append(f"hazard.d_safe={max(value, 40.0)!r}")  # d_safe >= d_coll
        if name == "hazard.d_safe":
            sets.append(f"hazard.d_coll={min(value, 10.0)!r}")
        sc = load_scenario(RESCUE, sets)
        result = plan(problem_from_scenario(sc), sc.planner, np.random.default_rng(0))
        assert math.isfinite(result.cost), (name, value)
        json.dumps(plan_to_json(result, sc), allow_nan=False)

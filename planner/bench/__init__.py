"""``fuseplan bench NAME``: the paper's experiments, one command each (issue 5).

A bench is a :class:`~planner.bench.runner.Bench`: a scenario, a budget, variants and a report writer.
:mod:`planner.bench.runner` runs it (process pool, JSON-lines records, resume); each bench module writes its
own tables and figures.
"""

from __future__ import annotations

from planner.bench import ablation
from planner.bench.runner import Bench

BENCHES: dict[str, Bench] = {b.name: b for b in (ablation.BENCH,)}

__all__ = ["BENCHES", "Bench"]

"""The layering is a checked contract (pyproject.toml ``[tool.importlinter]``): companion above planner, the order
of the subpackages inside each, no import cycles. Checked on the repository, and shown to catch a planner module
that imports the companion."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LINT = [sys.executable, "-c", "import sys; from importlinter.cli import lint_imports_command; "
        "sys.exit(lint_imports_command())"]


def _lint(cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*LINT, "--no-cache"], cwd=cwd, capture_output=True, text=True, timeout=120,
                          env={"PATH": "/usr/bin:/bin", "PYTHONPATH": str(cwd)})


def test_the_repository_keeps_every_import_contract() -> None:
    res = _lint(ROOT)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "0 broken" in res.stdout
    for contract in ("planner never imports companion", "Planner layers", "Kernel modules", "Companion layers",
                     "No import cycles"):
        assert contract in res.stdout  # each contract was read and checked, none silently dropped


def test_a_planner_module_that_imports_the_companion_breaks_the_contract(tmp_path: Path) -> None:
    for part in ("planner", "companion"):
        shutil.copytree(ROOT / part, tmp_path / part, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    with (tmp_path / "planner" / "world" / "geometry.py").open("a") as f:
        f.write("\nfrom companion.mission import geo  # noqa: E402\n")
    res = _lint(tmp_path)
    assert res.returncode == 1, res.stdout + res.stderr
    assert "planner never imports companion BROKEN" in res.stdout
    assert "planner.world.geometry -> companion.mission.geo" in res.stdout


def test_an_import_cycle_between_siblings_breaks_the_contract(tmp_path: Path) -> None:
    for part in ("planner", "companion"):
        shutil.copytree(ROOT / part, tmp_path / part, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    with (tmp_path / "planner" / "bench" / "runner.py").open("a") as f:  # compare already imports runner
        f.write("\nfrom planner.bench import compare  # noqa: E402\n")
    res = _lint(tmp_path)
    assert res.returncode == 1, res.stdout + res.stderr
    assert "No import cycles between sibling modules or packages BROKEN" in res.stdout

"""What the installed fuseplan carries besides its code: its version and its shipped scenarios (issue 36).

The distribution is named ``fuseplan``; its import packages are ``planner``, ``companion`` and ``sitl_scenarios``.
The scenarios (``sitl_scenarios/*.toml`` and the terrain ``*.asc`` the hard maps name beside them) are package
data of ``sitl_scenarios``, found through :mod:`importlib.resources`, so a wheel install finds them in
site-packages as a source tree finds them in the repository. This is the one place that says where they are.
"""

from __future__ import annotations

import functools
import importlib.metadata
import importlib.resources
from pathlib import Path

DISTRIBUTION = "fuseplan"
SCENARIO_PACKAGE = "sitl_scenarios"


@functools.cache
def fuseplan_version() -> str:
    """The installed fuseplan's version (``"0.1.0"``), from its metadata; ``"unknown"`` when it is not installed
    (the sources run from a checkout, never ``pip install``-ed)."""
    try:
        return importlib.metadata.version(DISTRIBUTION)
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def shipped_scenarios() -> Path:
    """The directory of the shipped scenarios: ``rescue_static.toml``, ``hardmap_valley_0.toml`` … and the terrain
    files they name, relative to it.

    Any ``pip install`` (wheel or editable) puts them on the file system, so this is a plain directory. A checkout
    whose editable install predates ``sitl_scenarios`` being a package cannot import it: its folder beside the
    ``planner`` package is the same one (``pip install -e .`` again makes the import work).
    """
    try:
        where = importlib.resources.files(SCENARIO_PACKAGE)
    except ModuleNotFoundError:
        return Path(__file__).resolve().parent.parent / SCENARIO_PACKAGE
    # a zip import (never made by pip) would give a zipfile.Path: its files then read as "not found", one line
    return where if isinstance(where, Path) else Path(str(where))

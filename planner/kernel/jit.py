"""How the kernel's functions are compiled (numba): a decorator for each way a function is called, identities
without numba. A cached function's disk cache is stamped with every file of this package, not only its own:
it inlines helpers from the other files, and an edit to any of them must recompile it."""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path
from typing import Any

njit: Any  # numba's decorator, or None
try:
    from numba import njit
except ImportError:  # pragma: no cover - numba is a dependency; the reference path still works without it
    njit = None

PACKAGE = Path(__file__).resolve().parent


@functools.cache
def package_stamp() -> str:
    """A hash of this package's sources (read once per process)."""
    h = hashlib.sha256()
    for f in sorted(PACKAGE.glob("*.py")):
        h.update(f.name.encode() + b"\0" + f.read_bytes())
    return h.hexdigest()


def _stamp_caches_with_the_package() -> bool:
    """Put a locator ahead of numba's for this package's functions: numba's own (found as numba would), with
    :func:`package_stamp` added to its source stamp. numba's list of locators is not public API: where it is not
    found, caches are stamped as numba does (with the function's own file) and this returns False."""
    from numba.core import caching

    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)  # numba ≥ 0.68, older
    classes: Any = getattr(impl, "_locator_classes", None)
    base: Any = getattr(caching, "_CacheLocator", None)
    if not isinstance(classes, list) or base is None:
        return False
    if any(getattr(c, "fuseplan_kernel", False) for c in classes):
        return True

    class PackageLocator(base):
        fuseplan_kernel = True

        def __init__(self, inner: caching._CacheLocator) -> None:
            self._inner = inner

        @classmethod
        def from_function(cls, py_func: Any, py_file: str) -> PackageLocator | None:
            if Path(py_file).resolve().parent != PACKAGE:
                return None
            for other in classes:
                inner = None if other is cls else other.from_function(py_func, py_file)
                if inner is not None:
                    return cls(inner)
            return None

        def ensure_cache_path(self) -> None:
            self._inner.ensure_cache_path()

        def get_cache_path(self) -> str:
            return self._inner.get_cache_path()

        def get_disambiguator(self) -> str:
            return self._inner.get_disambiguator()

        def get_source_stamp(self) -> tuple:
            return self._inner.get_source_stamp(), package_stamp()

    classes.insert(0, PackageLocator)
    return True


PACKAGE_STAMPED = njit is not None and _stamp_caches_with_the_package()  # every cached function below this line


def jit(fn):
    """Compile with an on-disk cache (no JIT pause after the first run on a machine); identity without numba."""
    return fn if njit is None else njit(cache=True, nogil=True, error_model="numpy")(fn)


def inline(fn):
    """A helper compiled into its caller (a call passing arrays costs more than the arithmetic inside)."""
    return fn if njit is None else njit(inline="always", error_model="numpy")(fn)


def linked(fn):
    """A helper left to LLVM to inline where it pays (scalar paths): faster to compile than ``inline``."""
    return fn if njit is None else njit(error_model="numpy")(fn)


def called(fn):
    """A helper on a rare or long path, compiled once and called: inlining it into each caller would cost more
    compile time (the first run on a machine) than the call costs at run time."""
    return fn if njit is None else njit(cache=True, nogil=True, error_model="numpy")(fn)

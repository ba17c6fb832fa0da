"""Exception root for fuseplan: every user-facing error names what went wrong and where."""

from __future__ import annotations


class FuseplanError(Exception):
    """Root of all fuseplan errors."""


def one_line(text: object) -> str:
    """``text`` on one line: line breaks shown as ``\\r`` / ``\\n``, so a value from a file cannot split a message."""
    return str(text).replace("\r", "\\r").replace("\n", "\\n")


class ScenarioError(FuseplanError):
    """A scenario file is missing, malformed or invalid.

    ``str(err)`` is one line: ``FILE: FIELD: REASON``.
    """

    def __init__(self, file: str, field: str, reason: str) -> None:
        self.file = str(file)
        self.field = field
        self.reason = reason
        # one line whatever the pieces hold (a key or a value from the file may contain line breaks)
        where = f"{self.file}: {one_line(field)}" if field else self.file
        super().__init__(f"{where}: {one_line(reason)}")

    def __reduce__(self) -> tuple[type[ScenarioError], tuple[str, str, str]]:  # survives pickling across process pools
        return (type(self), (self.file, self.field, self.reason))


class PlanRefused(FuseplanError):
    """A plan that fails its check (a PLAN.json whose route breaks its scenario's constraints): exit 3, not 2."""

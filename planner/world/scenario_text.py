"""A scenario carried as text: the file's bytes and the files it names, so that a run can load it on a machine
that has no copy of the scenario's folder (a cluster worker, issue 17).

:func:`materialise` writes it once per process into a private temporary folder, under the file's own name, so the
scenario loads there exactly as it loads here: same name, same DEM bytes, same numbers.
"""

from __future__ import annotations

import hashlib
import json
import tempfile
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from planner.files import FileRefused, read_regular_file
from planner.world.dem import MAX_ESRI_BYTES, MAX_HGT_BYTES
from planner.world.scenario import ScenarioError, named_files, read_scenario_bytes


@dataclass(frozen=True)
class ScenarioText:
    file_name: str  # the scenario file's name (its stem is the scenario's default name)
    data: bytes  # the file's bytes
    named: tuple[tuple[str, str, bytes], ...] = ()  # (key that names it, file name, bytes), e.g. a terrain DEM

    @classmethod
    def read(cls, path: str | Path, overrides: Sequence[str] = ()) -> ScenarioText:
        """The scenario at ``path`` and every file it names once ``overrides`` apply."""
        path = Path(path)
        named = []
        for key, file in named_files(path, overrides).items():  # a terrain DEM, the only file a scenario names
            try:
                named.append((key, file.name, read_regular_file(file, max(MAX_ESRI_BYTES, MAX_HGT_BYTES), "terrain")))
            except FileRefused as exc:
                raise ScenarioError(str(path), key, f"cannot read {exc}") from exc
        return cls(path.name, read_scenario_bytes(path), tuple(named))

    @property
    def digest(self) -> str:
        h = hashlib.sha256(self.file_name.encode() + b"\0" + self.data)
        for key, name, data in self.named:
            h.update(b"\0" + key.encode() + b"\0" + name.encode() + b"\0" + data)
        return h.hexdigest()[:16]


_LOCK = threading.Lock()  # a dask worker may run several tasks in threads
_DIR: list[Path] = []  # this process's folder of materialised scenarios


def materialise(text: ScenarioText) -> tuple[Path, tuple[str, ...]]:
    """The scenario written in this process's folder (once per content) and the overrides that point the files it
    names at their copies there; load it with ``load_scenario(path, (*overrides, *these))``."""
    with _LOCK:
        if not _DIR:
            _DIR.append(Path(tempfile.mkdtemp(prefix="fuseplan-scenarios-")))
        folder = _DIR[0] / text.digest
        path = folder / text.file_name
        extra = tuple(f"{key}={json.dumps(str(folder / name))}" for key, name, _ in text.named)
        if not path.exists():
            folder.mkdir(exist_ok=True)
            for _, name, data in text.named:
                (folder / name).write_bytes(data)
            partial = folder / (text.file_name + ".part")
            partial.write_bytes(text.data)
            partial.rename(path)  # last, so an existing scenario file means a complete folder
        return path, extra

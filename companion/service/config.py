"""``fuseplan serve``'s configuration file (docs/serve.md): one TOML file, validated once here (pydantic), after
which the service trusts it. Every mistake is one line, ``FILE: FIELD: REASON``, as for scenario files; relative
paths are read from the file's own folder.

.. code-block:: toml

    [link]
    url = "/dev/ttyAMA0"          # the autopilot (pymavlink URL: serial device, tcp:HOST:PORT, udpin:HOST:PORT)
    baud = 921600                 # serial only
    [plan]
    scenario = "base.toml"        # the vehicle, its band and clearances, the home and region planned in
    zones = ["airspace.json"]     # zones files planned round besides the vehicle's fence (GeoJSON, OpenAIP, ED-269)
    set = ["vehicle.cruise_speed=18"]
    [service]
    log_folder = "/var/lib/fuseplan"
"""

from __future__ import annotations

import os
import tempfile
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from companion.mavlink.link import DEFAULT_BAUD
from planner.errors import FuseplanError, ScenarioError
from planner.world.scenario import _from_validation_error

_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True, frozen=True)
MAX_CONFIG_BYTES = 1_000_000


class ConfigError(FuseplanError):
    """The service's configuration file is missing, malformed or invalid; ``str(err)`` is one line."""


class _Link(BaseModel):
    model_config = _STRICT
    url: Annotated[str, Field(min_length=1)]
    baud: Annotated[int, Field(ge=50, le=12_000_000)] = DEFAULT_BAUD
    target_system: Annotated[int, Field(ge=1, le=255)] | None = None
    heartbeat_timeout: Annotated[float, Field(gt=0, le=3600)] = 5.0


class _Plan(BaseModel):
    model_config = _STRICT
    scenario: Annotated[str, Field(min_length=1)]
    zones: list[Annotated[str, Field(min_length=1)]] = []
    set: list[str] = []
    seed: Annotated[int, Field(ge=0)] | None = None
    budget_s: Annotated[float, Field(ge=0, le=600)] = 3.0  # 0: no budget (the planner's own stop criteria)


class _Service(BaseModel):
    model_config = _STRICT
    log_folder: Annotated[str, Field(min_length=1)] = "fuseplan-serve"
    status_page: str | None = None  # [HOST:]PORT of the live status page (loopback unless a token is given)
    status_token: str | None = None  # a file holding the page's token
    poll_s: Annotated[float, Field(ge=0.5, le=600)] = 5.0
    replan: bool = True
    flight_timeout: Annotated[float, Field(gt=0)] | None = None


class _ServeFile(BaseModel):
    model_config = _STRICT
    link: _Link
    plan: _Plan
    service: _Service = _Service()


@dataclass(frozen=True)
class ServeConfig:
    """The checked configuration; paths absolute."""

    source: Path  # the configuration file
    url: str
    baud: int
    target_system: int | None
    heartbeat_timeout: float  # s without the autopilot's HEARTBEAT before the link counts as lost
    scenario: Path  # the base scenario: vehicle, band, clearances, home, region
    zones: tuple[Path, ...]
    overrides: tuple[str, ...]
    seed: int | None
    budget_s: float | None  # wall seconds a request's search may take (the best route by then, checked)
    log_folder: Path
    status_page: str | None
    status_token: Path | None
    poll_s: float  # wall s between two readbacks of the mission while disarmed, when nothing else tells of a change
    replan: bool  # live replanning and the flown-safety guard in flight
    flight_timeout: float | None  # wall s a flight is supervised; None: 120 s + 4 x its flying time


def load_config(path: Path) -> ServeConfig:
    """Read and check ``path``; raises :class:`ConfigError` (one line) for any problem, files it names included."""
    file = str(path)
    try:
        data = path.read_bytes()[:MAX_CONFIG_BYTES + 1]
    except OSError as e:
        raise ConfigError(f"{file}: cannot read: {e.strerror or e}") from None
    if len(data) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{file}: larger than {MAX_CONFIG_BYTES} bytes: not a configuration file")
    try:
        raw = tomllib.loads(data.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise ConfigError(f"{file}: malformed TOML: {e}") from None
    try:
        spec = _ServeFile.model_validate(raw)
    except ValidationError as exc:
        err = _from_validation_error(file, exc)
        reason = err.reason.replace("the scenario format", "the serve configuration")
        raise ConfigError(f"{file}: {err.field}: {reason}" if err.field else f"{file}: {reason}") from None
    here = path.resolve().parent

    def at(text: str) -> Path:
        return (here / Path(text).expanduser()).resolve()

    cfg = ServeConfig(
        source=path, url=spec.link.url, baud=spec.link.baud, target_system=spec.link.target_system,
        heartbeat_timeout=spec.link.heartbeat_timeout, scenario=at(spec.plan.scenario),
        zones=tuple(at(z) for z in spec.plan.zones), overrides=tuple(spec.plan.set), seed=spec.plan.seed,
        budget_s=spec.plan.budget_s or None,
        log_folder=at(spec.service.log_folder), status_page=spec.service.status_page,
        status_token=at(spec.service.status_token) if spec.service.status_token else None,
        poll_s=spec.service.poll_s, replan=spec.service.replan, flight_timeout=spec.service.flight_timeout)
    check_config(cfg)
    return cfg


def check_config(cfg: ServeConfig) -> None:
    """What the file names must be usable before the service starts: the link URL, the base scenario with its
    overrides, every zones file, a log folder that can be made and written in, the status page's address (free now)
    and its token."""
    from companion.mavlink.link import check_url
    from planner.world.scenario import load_scenario
    from planner.world.sources import read_zone_files

    file = str(cfg.source)
    try:
        check_url(cfg.url, "link.url")
    except FuseplanError as e:
        raise ConfigError(f"{file}: {e}") from None
    try:
        load_scenario(cfg.scenario, cfg.overrides)
    except ScenarioError as e:
        raise ConfigError(f"{file}: plan.scenario: {e}") from None
    for k, zones in enumerate(cfg.zones):
        try:
            read_zone_files([zones])
        except FuseplanError as e:
            raise ConfigError(f"{file}: plan.zones[{k}]: {e}") from None
    folder = cfg.log_folder
    if folder.exists() and not folder.is_dir():
        raise ConfigError(f"{file}: service.log_folder: {folder} is a file")
    parent = next((a for a in folder.parents if a.exists()), None)
    if not folder.exists() and (parent is None or not parent.is_dir()):
        raise ConfigError(f"{file}: service.log_folder: cannot create {folder}")
    nearest = folder if folder.exists() else parent
    assert nearest is not None
    try:  # a probe, made and removed at once, as the user the service runs as (os.access says yes to root always)
        os.rmdir(tempfile.mkdtemp(prefix=".fuseplan-check-", dir=nearest))
    except OSError as e:
        raise ConfigError(f"{file}: service.log_folder: cannot {'write in' if nearest == folder else 'create'} "
                          f"{folder}: {e.strerror or e}") from None
    _check_status_page(cfg)


def _check_status_page(cfg: ServeConfig) -> None:
    """The status page's address parses and is free now, and its token file is readable and long enough (or, for a
    page beyond loopback, given at all): the mistakes the page itself would find only once the service runs."""
    from companion.status import Bind, read_token

    file = str(cfg.source)
    if cfg.status_page is None:
        if cfg.status_token is not None:
            raise ConfigError(f"{file}: service.status_token: given without service.status_page")
        return
    try:
        bind = Bind.parse(cfg.status_page)
    except FuseplanError:
        raise ConfigError(f"{file}: service.status_page: {cfg.status_page!r}: expected PORT or HOST:PORT (e.g. 8765 "
                          "or 0.0.0.0:8765)") from None
    if cfg.status_token is None and not bind.loopback:
        raise ConfigError(f"{file}: service.status_token: required: the page at {bind.host}:{bind.port} is "
                          "reachable from other machines (a file holding a secret of 16 characters or more)")
    try:
        read_token(cfg.status_token, bind)
    except FuseplanError as e:
        raise ConfigError(f"{file}: service.status_token: {e}") from None
    try:
        bind.check_free()
    except FuseplanError as e:
        raise ConfigError(f"{file}: service.status_page: {status_listen_reason(bind, e)}") from None


def status_listen_reason(bind: object, e: BaseException) -> str:
    """``cannot listen on HOST:PORT: REASON`` from the status module's error (which names the fly option)."""
    cause = e.__cause__ if isinstance(e.__cause__, OSError) else e
    reason = (cause.strerror if isinstance(cause, OSError) else None) or str(cause).rpartition(": ")[2]
    return f"cannot listen on {getattr(bind, 'host', '?')}:{getattr(bind, 'port', '?')}: {reason}"


__all__ = ["ConfigError", "ServeConfig", "load_config", "status_listen_reason"]

"""What ``fuseplan serve`` does once its options are read: load the configuration, run the :class:`Service` until
SIGINT or SIGTERM (a clean exit 0), and the status page when the configuration asks for one."""

from __future__ import annotations

import asyncio
import contextlib
import signal
import sys
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

from companion.service.config import ConfigError, ServeConfig, load_config, status_listen_reason
from companion.service.serve import Service
from planner.errors import FuseplanError

EXIT_OK = 0


def run_service(config: Path, *, check_only: bool = False, echo: Callable[[dict[str, Any]], None] | None = None,
                quiet: bool = False) -> int:
    """Load ``config`` (raises :class:`~companion.service.config.ConfigError`, one line) and serve until stopped.
    ``quiet`` (-q): no progress lines, only the start and stop banners (and the status page's address)."""
    cfg = load_config(config)
    if check_only:
        print(f"{config}: ok: link {cfg.url}, scenario {cfg.scenario}, {len(cfg.zones)} zones files, logs in "
              f"{cfg.log_folder}")
        return EXIT_OK
    print(f"fuseplan serve: link {cfg.url}, logs in {cfg.log_folder}; Ctrl-C or SIGTERM to stop", flush=True)
    asyncio.run(_serve(cfg, None if quiet else _with_service_lines(echo)))
    print("fuseplan serve: stopped", flush=True)
    return EXIT_OK


# the service's own decisions, one progress line each (journald shows them); the flight's go to the CLI's echo
SERVICE_LINES = ("serve_start", "waiting_for_autopilot", "connected", "autopilot_restarted", "baseline", "request",
                 "plan_request", "planned", "plan_accepted", "plan_refused", "route_set", "session_error")


def _with_service_lines(echo: Callable[[dict[str, Any]], None] | None) -> Callable[[dict[str, Any]], None]:
    def say(rec: dict[str, Any]) -> None:
        if rec["event"] in SERVICE_LINES:
            detail = " ".join(f"{k}={v}" for k, v in rec.items() if k not in ("t", "event"))
            print(f"{rec['event']} {detail}".rstrip(), flush=True)
        elif echo is not None:
            echo(rec)
    return say


async def _serve(cfg: ServeConfig, echo: Callable[[dict[str, Any]], None] | None) -> None:
    """The service as a task, cancelled on SIGINT/SIGTERM; with the status page if configured."""
    loop = asyncio.get_running_loop()
    service = Service(cfg, echo=echo)
    task = asyncio.create_task(service.run(), name="fuseplan-serve")
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, service.stop, task)
    try:
        async with contextlib.AsyncExitStack() as stack:
            if cfg.status_page is not None:
                await stack.enter_async_context(_status_page(cfg, service))
            with contextlib.suppress(asyncio.CancelledError):
                await task
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)


@contextlib.asynccontextmanager
async def _status_page(cfg: ServeConfig, service: Service) -> AsyncIterator[object]:
    """The live status page over every request's events (the service's own log's too); ``cfg.status_page`` set."""
    from companion.status import Bind, StatusHub, StatusServer, read_token

    assert cfg.status_page is not None  # entered only when the configuration names a page (checked at load)
    file = cfg.source
    try:
        bind = Bind.parse(cfg.status_page)
        token = read_token(cfg.status_token, bind, False)
    except FuseplanError as e:  # changed since the check (the token file)
        raise ConfigError(f"{file}: service.status_token: {e}") from None
    hub = StatusHub()
    service.listeners.append(hub.publish)
    server = StatusServer(hub, bind, token)
    try:
        await server.__aenter__()
    except (OSError, FuseplanError) as e:  # the port taken since the check
        raise ConfigError(f"{file}: service.status_page: {status_listen_reason(bind, e)}") from None
    try:
        print(f"status page: {server.url}" + ("?token=<the token in service.status_token>" if token else ""),
              file=sys.stderr, flush=True)
        yield server
    finally:
        await server.__aexit__(None, None, None)


__all__ = ["run_service"]

"""Reading named parameters from the autopilot (MAVLink parameter protocol, PARAM_REQUEST_READ by name).

Each name is asked for on its own and the answers are gathered as they come; a name the autopilot does not have is
simply not answered (ArduPilot and PX4 stay silent), so once a resend brings nothing new the rest are left out
rather than failing (about 0.6 s; a silent autopilot costs :data:`READ_TIMEOUT_S`).
"""

from __future__ import annotations

import time
from collections.abc import Iterable

from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.link import Link, Message

RESEND_S = 0.3  # wall seconds between two rounds of requests for the names still missing
READ_TIMEOUT_S = 3.0  # wall seconds for the whole read


def _name(msg: Message) -> str:
    raw = msg.param_id
    return (raw.decode(errors="replace") if isinstance(raw, bytes) else str(raw)).rstrip("\x00")


async def read_params(link: Link, names: Iterable[str], timeout: float = READ_TIMEOUT_S) -> dict[str, float]:
    """name → value for every name in ``names`` the target autopilot answers within ``timeout`` seconds."""
    wanted = list(dict.fromkeys(names))
    got: dict[str, float] = {}
    if not wanted:
        return got
    ts, tc = link.target_system or 1, link.target_component or 1
    deadline = time.monotonic() + timeout
    with link.subscribe("PARAM_VALUE") as sub:
        rounds, answered = 0, -1
        while (missing := [n for n in wanted if n not in got]) and time.monotonic() < deadline:
            if rounds >= 2 and len(got) == answered:
                break  # a whole resend round brought nothing new: the rest are names this autopilot lacks
            answered, rounds = len(got), rounds + 1
            for n in missing:
                link.send(mavlink.MAVLink_param_request_read_message(ts, tc, n.encode(), -1))
            round_end = min(time.monotonic() + RESEND_S, deadline)
            while (left := round_end - time.monotonic()) > 0:
                try:
                    msg = await sub.get(left)
                except TimeoutError:
                    break
                name = _name(msg)
                if name in wanted:
                    got[name] = float(msg.param_value)
                if all(n in got for n in wanted):
                    break
    return got

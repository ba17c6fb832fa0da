"""MAVLink 2 message signing: keys, switching it on for a pymavlink packer/parser, and provisioning a key on an
autopilot with SETUP_SIGNING (issue 7).

A key file holds either the 32-byte secret itself or a passphrase, which is hashed with SHA-256 as MAVProxy's
``signing setup`` and QGroundControl do. With signing on, every outgoing message is signed and an incoming
message without a valid signature is rejected (pymavlink's parser reports it as bad data, which we drop).
Keys are never logged or shown: :class:`SigningKey` prints as its fingerprint only.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from planner.errors import FuseplanError

KEY_BYTES = 32
SIGNING_EPOCH = 1420070400  # 2015-01-01T00:00:00Z: MAVLink signing timestamps count 10 µs units from here


@dataclass(frozen=True)
class SigningKey:
    secret: bytes = field(repr=False)

    def __post_init__(self) -> None:
        if len(self.secret) != KEY_BYTES:
            raise ValueError(f"a MAVLink signing key has {KEY_BYTES} bytes, not {len(self.secret)}")

    @property
    def fingerprint(self) -> str:
        """A short, non-secret name for the key (first 8 hex digits of SHA-256 of the key)."""
        return hashlib.sha256(self.secret).hexdigest()[:8]

    def __str__(self) -> str:
        return f"signing key {self.fingerprint}"

    @classmethod
    def from_passphrase(cls, passphrase: str) -> SigningKey:
        return cls(hashlib.sha256(passphrase.encode("utf-8")).digest())

    @classmethod
    def load(cls, path: Path) -> SigningKey:
        """A 32-byte key file, or a text file whose (stripped) content is a passphrase."""
        try:
            data = Path(path).read_bytes()
        except OSError as e:
            raise FuseplanError(f"{path}: cannot read the signing key: {e.strerror or e}") from e
        if len(data) == KEY_BYTES:
            return cls(data)
        try:
            text = data.decode("utf-8").strip()
        except UnicodeDecodeError:
            raise FuseplanError(f"{path}: a signing key file holds {KEY_BYTES} raw bytes or a text passphrase "
                                f"(found {len(data)} bytes that are neither)") from None
        if not text:
            raise FuseplanError(f"{path}: the signing key file is empty")
        return cls.from_passphrase(text)


def enable_signing(mav: object, key: SigningKey, link_id: int = 0, timestamp: int = 0) -> None:
    """Sign everything ``mav`` (a pymavlink ``MAVLink``) sends and reject unsigned or badly signed input;
    timestamps go on from the latest of ``timestamp`` (a previous connection's), ``mav``'s own and now."""
    signing = mav.signing  # type: ignore[attr-defined]
    signing.secret_key = key.secret
    signing.sign_outgoing = True
    signing.allow_unsigned_callback = None
    signing.link_id = link_id
    signing.timestamp = max(signing.timestamp, timestamp, signing_timestamp())


def signing_timestamp(unix_time: float | None = None) -> int:
    """A MAVLink signing timestamp (10 µs units since 2015-01-01) for ``unix_time`` (default: now)."""
    return int(((time.time() if unix_time is None else unix_time) - SIGNING_EPOCH) * 100_000)


def setup_signing(link_or_conn: Any, key: SigningKey, target_system: int | None = None,
                  target_component: int | None = None, initial_timestamp: int | None = None) -> int:
    """Provision ``key`` on an autopilot as a ground station does: send it SETUP_SIGNING (message 256: target
    system/component, the 32-byte secret, an initial timestamp in 10 µs units since 2015-01-01, default now).
    The autopilot stores key and timestamp persistently (ArduPilot: in its storage, eeprom.bin in SITL) and at
    once signs all it sends. ArduPilot (4.7 SITL) then ignores unsigned input on every channel but its first
    (SERIAL0, taken for USB, where everything is still accepted), apart from RADIO_STATUS (and RADIO). It signs
    from the initial timestamp + 60 s on (SITL's GPS clock then runs ahead under speed-up) and refuses a new
    signed stream more than 60 s behind its own timestamp: a peer whose clock is behind is ignored until it takes
    the autopilot's timestamp from a signed message it received (pymavlink does). Nothing answers
    SETUP_SIGNING: check the result by talking signed afterwards.

    ``link_or_conn`` is a :class:`companion.mavlink.link.Link` (targets default to its autopilot) or a pymavlink
    connection (``conn.mav.send``; targets default to its ``target_system``/``target_component``). The message
    goes out as that link sends everything (unsigned unless it signs already) and carries the secret in clear:
    use a link nobody else can listen to. Returns the initial timestamp sent."""
    from pymavlink.dialects.v20 import common

    conn_mav = getattr(link_or_conn, "mav", None)
    if target_system is None:
        target_system = link_or_conn.target_system
    if target_component is None:
        target_component = link_or_conn.target_component
    if target_system is None or target_component is None:
        raise ValueError("setup_signing: the autopilot's system/component is not known yet (wait for its "
                         "HEARTBEAT or pass target_system and target_component)")
    stamp = signing_timestamp() if initial_timestamp is None else initial_timestamp
    msg = common.MAVLink_setup_signing_message(target_system, target_component, list(key.secret), stamp)
    if conn_mav is not None:
        conn_mav.send(msg)
    else:
        link_or_conn.send(msg)
    return stamp

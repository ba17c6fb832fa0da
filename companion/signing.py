"""MAVLink 2 message signing: keys and switching it on for a pymavlink packer/parser (issue 7).

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


def enable_signing(mav: object, key: SigningKey, link_id: int = 0) -> None:
    """Sign everything ``mav`` (a pymavlink ``MAVLink``) sends and reject unsigned or badly signed input."""
    signing = mav.signing  # type: ignore[attr-defined]
    signing.secret_key = key.secret
    signing.sign_outgoing = True
    signing.allow_unsigned_callback = None
    signing.link_id = link_id
    signing.timestamp = max(signing.timestamp, int((time.time() - SIGNING_EPOCH) * 100_000))

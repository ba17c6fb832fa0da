"""MAVLink 2 message signing: keys, switching it on for a pymavlink packer/parser, and provisioning a key on an
autopilot with SETUP_SIGNING (issue 7); and the one reader of secret files (issue 33).

A key comes from one of two files, never guessed from the content: a key file (``--signing-key``) holds the 32-byte
secret itself, raw or as 64 hex digits (QGroundControl's form for a raw key); a passphrase file
(``--signing-passphrase``) holds a passphrase on its first line, hashed with SHA-256 as MAVProxy's
``signing setup PASSPHRASE`` does (QGroundControl's newer key store derives a passphrase's key with salted PBKDF2
instead: share the raw key with it). With signing on, every outgoing message is signed and an incoming message without a
valid signature is rejected (pymavlink's parser reports it as bad data, which we drop). Keys are never logged or
shown: :class:`SigningKey` prints as its fingerprint only.

Secret files (key, passphrase, the status page's token) are read by :func:`read_secret` only: a regular file (after
symlinks; FIFOs, devices and directories are refused without being opened), a few KB at most, and, on POSIX, not
open to other users unless the caller accepts that (``--insecure-key-file``).
"""

from __future__ import annotations

import hashlib
import logging
import os
import shlex
import stat
import string
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from planner.errors import FuseplanError
from planner.files import read_regular_file

log = logging.getLogger(__name__)
KEY_BYTES = 32
MIN_PASSPHRASE_CHARS = 8  # QGroundControl's minimum too
SECRET_MAX_BYTES = 4096  # a key, passphrase or token file is tiny: anything bigger is the wrong file
HEX_DIGITS = frozenset(string.hexdigits.encode("ascii"))
TEXT_BYTES = frozenset(range(0x20, 0x7F)) | frozenset(b"\t\n\r")
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
        """SHA-256 of the passphrase's UTF-8 bytes, as MAVProxy's ``signing setup PASSPHRASE`` derives its key."""
        return cls(hashlib.sha256(passphrase.encode("utf-8")).digest())

    @classmethod
    def from_key_file(cls, path: Path, insecure: bool = False) -> SigningKey:
        """The key in ``path``: exactly 32 raw bytes, or 64 hex digits (surrounding white space ignored)."""
        data = read_secret(path, "signing key", insecure)
        text = data.strip()
        if len(text) == 2 * KEY_BYTES and all(c in HEX_DIGITS for c in text):
            return cls(bytes.fromhex(text.decode("ascii")))
        if len(data) != KEY_BYTES:
            raise FuseplanError(f"{path}: a --signing-key file holds the {KEY_BYTES}-byte key itself (raw or as "
                                f"{2 * KEY_BYTES} hex digits), not {len(data)} bytes; for a passphrase use "
                                "--signing-passphrase FILE")
        if all(c in TEXT_BYTES for c in data):  # 32 random bytes are all text about once in 10^13 keys
            raise FuseplanError(f"{path}: these {KEY_BYTES} bytes are text, a passphrase rather than a raw key: use "
                                "--signing-passphrase FILE (hashed as MAVProxy does), or write a raw key as "
                                f"{2 * KEY_BYTES} hex digits")
        return cls(data)

    @classmethod
    def from_passphrase_file(cls, path: Path, insecure: bool = False) -> SigningKey:
        """The key MAVProxy's ``signing setup`` derives from the passphrase on the first line of ``path``."""
        try:
            text = read_secret(path, "signing passphrase", insecure).decode("utf-8-sig")
        except UnicodeDecodeError:
            raise FuseplanError(f"{path}: a --signing-passphrase file holds a text passphrase, not binary data "
                                "(for a raw key use --signing-key FILE)") from None
        lines = text.strip().splitlines()
        passphrase = lines[0].strip() if lines else ""
        if not passphrase:
            raise FuseplanError(f"{path}: the signing passphrase file is empty")
        if not all("!" <= c <= "~" for c in passphrase):  # visible ASCII: MAVProxy encodes it as ASCII
            raise FuseplanError(f"{path}: the passphrase must be one word of visible ASCII characters (no spaces), "
                                "as MAVProxy's `signing setup PASSPHRASE` takes it, or MAVProxy cannot make its key")
        if len(passphrase) < MIN_PASSPHRASE_CHARS:
            raise FuseplanError(f"{path}: a passphrase needs {MIN_PASSPHRASE_CHARS} characters or more to resist "
                                f"guessing (and the key with it); this one has {len(passphrase)}")
        return cls.from_passphrase(passphrase)


def key_from_files(key_file: Path | None, passphrase_file: Path | None, insecure: bool = False) -> SigningKey | None:
    """The key of ``--signing-key FILE`` or ``--signing-passphrase FILE`` (one of them at most); None without."""
    if key_file is not None and passphrase_file is not None:
        raise FuseplanError("--signing-key and --signing-passphrase exclude each other: give one")
    if key_file is not None:
        return SigningKey.from_key_file(key_file, insecure)
    if passphrase_file is not None:
        return SigningKey.from_passphrase_file(passphrase_file, insecure)
    return None


def read_secret(path: Path, what: str, insecure: bool = False) -> bytes:
    """The content of the secret file ``path`` (``what``: "signing key", "status token", ... for the messages).

    Read as any file the user names is (:func:`planner.files.read_regular_file`: a regular file once symlinks are
    followed, never a FIFO or a device, at most :data:`SECRET_MAX_BYTES`), and on POSIX refused with one line when
    its mode gives group or others any access, unless ``insecure`` (then a warning is logged and the file used)."""
    def private(path: Path, st: os.stat_result) -> None:
        mode = stat.S_IMODE(st.st_mode)
        if os.name != "posix" or not mode & 0o077:
            return
        if not insecure:
            raise FuseplanError(f"{path}: other users have access to this {what} (mode {mode:04o}): run "
                                f"chmod 600 {shlex.quote(str(path))}, or give --insecure-key-file to use it anyway")
        log.warning("%s: other users have access to this %s (mode %04o); used anyway (--insecure-key-file)",
                    path, what, mode)

    return read_regular_file(path, SECRET_MAX_BYTES, what, private)


def enable_signing(mav: Any, key: SigningKey, link_id: int = 0, timestamp: int = 0) -> None:
    """Sign everything ``mav`` (a pymavlink ``MAVLink``) sends and reject unsigned or badly signed input;
    timestamps go on from the latest of ``timestamp`` (a previous connection's), ``mav``'s own and now."""
    signing = mav.signing
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

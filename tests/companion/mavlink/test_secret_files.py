"""Secret files (issue 33): a raw key and a passphrase are told apart by the option, never by the content; a
passphrase is hashed as MAVProxy's ``signing setup`` does; key, passphrase and status-token files are read only
when they are small regular files that other users cannot read. Real files in tmp_path; the CLI refuses each case
with exit 2 and one line."""

from __future__ import annotations

import hashlib
import logging
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from companion.cli import main
from companion.mavlink.signing import SECRET_MAX_BYTES, SigningKey, key_from_files, read_secret
from companion.status import Bind, read_token
from planner.errors import FuseplanError

ROOT = Path(__file__).resolve().parents[3]
SCENARIO = str(ROOT / "sitl_scenarios" / "rescue_static.toml")
RAW = bytes(range(7, 39))  # 32 bytes, not all text
TOKEN = "s3cret-token-for-tests-0123456789"
PASSPHRASE_32 = "abcdefghijklmnopqrstuvwxyz012345"

pytestmark = pytest.mark.skipif(os.name != "posix", reason="file modes, FIFOs and /dev/zero are POSIX")


def _secret(path: Path, content: bytes | str, mode: int = 0o600) -> Path:
    if isinstance(content, str):
        path.write_text(content)
    else:
        path.write_bytes(content)
    path.chmod(mode)
    return path


def _fifo(tmp_path: Path) -> Path:
    os.mkfifo(tmp_path / "fifo", 0o600)
    return tmp_path / "fifo"


def _quickly(fifo: Path, call: Callable[[], object]) -> BaseException | None:
    """What ``call`` raised, within 5 s. Should it block opening or reading ``fifo``, a writer opens and closes it
    (which releases the reader) and the test fails instead of hanging."""
    out: list[BaseException | None] = []

    def run() -> None:
        try:
            call()
            out.append(None)
        except BaseException as e:  # handed to the test
            out.append(e)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(5.0)
    if thread.is_alive():
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        thread.join(5.0)
        pytest.fail(f"reading the FIFO {fifo} blocked")
    return out[0]


# --- a raw key and a passphrase, told apart ---------------------------------------------------------------------


def test_a_passphrase_is_hashed_with_sha256_as_mavproxy_does(tmp_path: Path) -> None:
    """MAVProxy's ``signing setup PASSPHRASE`` (MAVProxy/modules/mavproxy_signing.py, passphrase_to_key) sends
    SHA-256 of the passphrase's bytes; a 32-character passphrase too is hashed, never taken as the key."""
    assert len(PASSPHRASE_32) == 32
    path = _secret(tmp_path / "pass.txt", PASSPHRASE_32 + "\n")
    key = SigningKey.from_passphrase_file(path)
    assert key.secret == hashlib.sha256(PASSPHRASE_32.encode("utf-8")).digest()
    assert key.secret != PASSPHRASE_32.encode("ascii")
    _secret(path, PASSPHRASE_32)  # no line end: 32 bytes, still a passphrase
    assert SigningKey.from_passphrase_file(path) == key
    _secret(path, f"  {PASSPHRASE_32}  \r\nsecond line ignored\n")
    assert SigningKey.from_passphrase_file(path) == key
    _secret(path, ("\ufeff" + PASSPHRASE_32).encode("utf-8"))  # a byte-order mark from a Windows editor
    assert SigningKey.from_passphrase_file(path) == key
    assert key_from_files(None, path) == key and key_from_files(None, None) is None


def test_a_key_file_is_32_raw_bytes_or_64_hex_digits(tmp_path: Path) -> None:
    path = _secret(tmp_path / "raw.key", RAW)
    assert SigningKey.from_key_file(path).secret == RAW
    assert key_from_files(path, None).secret == RAW
    for text in (RAW.hex(), RAW.hex().upper() + "\n", f"  {RAW.hex()}\r\n"):  # QGroundControl's raw-key form
        assert SigningKey.from_key_file(_secret(tmp_path / "hex.key", text)).secret == RAW


@pytest.mark.parametrize("content", [b"", RAW[:31], RAW + b"\n", RAW * 2, "field-passphrase\n", RAW.hex()[:-1],
                                     "g" * 64], ids=["empty", "31", "33", "64-raw", "passphrase", "63-hex", "not-hex"])
def test_anything_else_in_a_key_file_is_refused_pointing_to_the_passphrase_option(tmp_path: Path, content) -> None:
    path = _secret(tmp_path / "x.key", content)
    with pytest.raises(FuseplanError, match="--signing-passphrase") as err:
        SigningKey.from_key_file(path)
    assert str(err.value).startswith(f"{path}: ") and "\n" not in str(err.value)


def test_a_32_character_passphrase_given_as_a_key_file_is_refused_not_used_raw(tmp_path: Path) -> None:
    for text in (PASSPHRASE_32, PASSPHRASE_32[:31] + "\n"):
        path = _secret(tmp_path / "looks-like-a-key", text)
        with pytest.raises(FuseplanError, match="text, a passphrase rather than a raw key: use --signing-passphrase"):
            SigningKey.from_key_file(path)


@pytest.mark.parametrize(("content", "why"), [
    ("a\n", "needs 8 characters or more .* has 1$"), ("seven77", "needs 8 characters or more .* has 7$"),
    ("", "empty"), ("   \n\n", "empty"), ("correct horse battery staple", "one word of visible ASCII"),
    ("pässphrase-long", "one word of visible ASCII"), (b"\xff\xfe\x00\x01" * 4, "not binary data")])
def test_a_bad_passphrase_is_refused_saying_why(tmp_path: Path, content, why: str) -> None:
    path = _secret(tmp_path / "pass.txt", content)
    with pytest.raises(FuseplanError, match=why) as err:
        SigningKey.from_passphrase_file(path)
    assert str(err.value).startswith(f"{path}: ") and "\n" not in str(err.value)
    assert SigningKey.from_passphrase_file(_secret(path, "eight888"))  # 8 is enough


# --- secret files: regular, small, private ----------------------------------------------------------------------


def test_a_fifo_is_refused_at_once_without_blocking(tmp_path: Path) -> None:
    fifo = _fifo(tmp_path)
    for call in (lambda: read_secret(fifo, "signing key"), lambda: SigningKey.from_passphrase_file(fifo),
                 lambda: read_token(fifo, Bind.parse("0.0.0.0:8765"))):
        err = _quickly(fifo, call)
        assert isinstance(err, FuseplanError) and str(err).startswith(f"{fifo}: ")
        assert "must be a regular file, not a FIFO" in str(err)


def test_dev_zero_and_a_symlink_to_it_are_refused(tmp_path: Path) -> None:
    if not Path("/dev/zero").exists():
        pytest.skip("no /dev/zero")
    (tmp_path / "zero.key").symlink_to("/dev/zero")
    with pytest.raises(FuseplanError, match="^/dev/zero: a signing key file must be a regular file, not a character"):
        SigningKey.from_key_file(Path("/dev/zero"))
    with pytest.raises(FuseplanError, match=r"zero.key: .* not a character device \(/dev/zero\)"):
        SigningKey.from_key_file(tmp_path / "zero.key")
    with pytest.raises(FuseplanError, match="not a character device"):
        read_token(tmp_path / "zero.key", Bind.parse("0.0.0.0:8765"))
    with pytest.raises(FuseplanError, match="not a directory"):
        read_secret(tmp_path, "signing key")


def test_a_symlink_to_a_private_regular_file_is_followed(tmp_path: Path) -> None:
    _secret(tmp_path / "real.key", RAW)
    (tmp_path / "link.key").symlink_to(tmp_path / "real.key")
    assert SigningKey.from_key_file(tmp_path / "link.key").secret == RAW


def test_an_oversize_file_is_refused(tmp_path: Path) -> None:
    path = _secret(tmp_path / "big", b"x" * SECRET_MAX_BYTES)
    assert len(read_secret(path, "status token")) == SECRET_MAX_BYTES
    _secret(path, "y" * 20 + "\n" + "x" * SECRET_MAX_BYTES)  # a valid first line does not save it
    for call in (lambda: read_secret(path, "status token"), lambda: SigningKey.from_passphrase_file(path),
                 lambda: read_token(path, Bind.parse("0.0.0.0:8765"))):
        with pytest.raises(FuseplanError, match=f"{SECRET_MAX_BYTES + 21} bytes is more than a"):
            call()


@pytest.mark.parametrize("mode", [0o644, 0o640, 0o604, 0o660])
def test_a_file_other_users_can_read_is_refused_unless_insecure(tmp_path: Path, mode: int,
                                                                  caplog: pytest.LogCaptureFixture) -> None:
    key = _secret(tmp_path / "my key", RAW, mode)
    token = _secret(tmp_path / "token", TOKEN, mode)
    with pytest.raises(FuseplanError) as err:
        SigningKey.from_key_file(key)
    assert str(err.value) == (f"{key}: other users have access to this signing key (mode {mode:04o}): run "
                              f"chmod 600 '{key}', or give --insecure-key-file to use it anyway")
    with pytest.raises(FuseplanError, match=f"token: other users have access to this status token .mode {mode:04o}"):
        read_token(token, Bind.parse("0.0.0.0:8765"))
    with caplog.at_level(logging.WARNING, logger="companion.mavlink.signing"):
        assert SigningKey.from_key_file(key, insecure=True).secret == RAW
        assert read_token(token, Bind.parse("0.0.0.0:8765"), insecure=True) == TOKEN
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warnings == [f"{key}: other users have access to this signing key (mode {mode:04o}); used anyway "
                        "(--insecure-key-file)",
                        f"{token}: other users have access to this status token (mode {mode:04o}); used anyway "
                        "(--insecure-key-file)"]


def test_private_modes_are_accepted(tmp_path: Path) -> None:
    for mode in (0o600, 0o400):
        assert SigningKey.from_key_file(_secret(tmp_path / f"k{mode:o}", RAW, mode)).secret == RAW


# --- the command line: exit 2, one line naming the file, no traceback, on fly and sim alike -----------------------


def _refusals(tmp_path: Path) -> list[tuple[str, Path, str]]:
    """(option, file, what the one line says) for every kind of bad file."""
    big = _secret(tmp_path / "big.key", b"\x01" * (SECRET_MAX_BYTES + 1))
    (tmp_path / "zero.key").symlink_to("/dev/zero")
    return [
        ("--signing-key", _fifo(tmp_path), "not a FIFO"),
        ("--signing-passphrase", Path("/dev/zero"), "not a character device"),
        ("--signing-key", tmp_path / "zero.key", "not a character device (/dev/zero)"),
        ("--signing-passphrase", big, "bytes is more than a"),
        ("--signing-key", _secret(tmp_path / "open.key", RAW, 0o644), "(mode 0644): run chmod 600"),
        ("--signing-passphrase", _secret(tmp_path / "open.txt", "field-passphrase\n", 0o644), "chmod 600"),
        ("--signing-passphrase", _secret(tmp_path / "short.txt", "abc\n"), "needs 8 characters or more"),
        ("--signing-key", _secret(tmp_path / "pass32.txt", PASSPHRASE_32), "use --signing-passphrase FILE"),
        ("--signing-key", _secret(tmp_path / "pass.txt", "field-passphrase\n"), "use --signing-passphrase FILE"),
        ("--signing-key", tmp_path / "missing.key", "signing key file not found"),
    ]


@pytest.mark.parametrize("command", ["fly", "sim"])
def test_the_cli_refuses_each_bad_file_in_one_line(command: str, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    where = ["--sim", "-q", "--report", str(tmp_path / "r")] if command == "fly" else ["--listen", "udpin:127.0.0.1:0"]
    for option, path, says in _refusals(tmp_path):
        start = time.monotonic()
        code = main([command, SCENARIO, *where, option, str(path)])
        out, err = capsys.readouterr()
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1, (option, path, err)
        assert lines[0].startswith(f"fuseplan: error: {path}: ") and says in lines[0], lines[0]
        assert "Traceback" not in err and "simulated" not in out and "planning" not in out
        assert time.monotonic() - start < 5.0
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("command", ["fly", "sim"])
def test_key_and_passphrase_options_exclude_each_other(command: str, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    key, passphrase = _secret(tmp_path / "k", RAW), _secret(tmp_path / "p", "field-passphrase")
    where = ["--sim"] if command == "fly" else []
    with pytest.raises(SystemExit) as exit_:
        main([command, SCENARIO, *where, "--signing-key", str(key), "--signing-passphrase", str(passphrase)])
    assert exit_.value.code == 2
    assert "argument --signing-passphrase: not allowed with argument --signing-key" in capsys.readouterr().err
    with pytest.raises(FuseplanError, match="exclude each other"):
        key_from_files(key, passphrase)


def test_fly_status_token_refused_when_open_and_taken_with_insecure_key_file(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture) -> None:
    token = _secret(tmp_path / "token", TOKEN + "\n", 0o644)
    passphrase = _secret(tmp_path / "pass.txt", "field-passphrase\n", 0o644)
    base = ["fly", SCENARIO, "--sim", "-q", "--report", str(tmp_path / "r")]
    assert main([*base, "--status-page", "0.0.0.0:0", "--status-token", str(token)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"fuseplan: error: {token}: ") and "chmod 600" in lines[0]
    with socket.socket() as taken:  # both files taken (with warnings); then a port in use stops it before planning
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with caplog.at_level(logging.WARNING, logger="companion.mavlink.signing"):
            code = main([*base, "--status-page", str(port), "--status-token", str(token), "--signing-passphrase",
                         str(passphrase), "--insecure-key-file"])
    err = capsys.readouterr().err
    assert code == 2 and f"127.0.0.1:{port}: cannot listen" in err and "chmod" not in err
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warned) == 2 and warned[0].startswith(f"{passphrase}: ") and warned[1].startswith(f"{token}: ")
    assert not (tmp_path / "r").exists()


def test_report_serve_refuses_an_open_token_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    token = _secret(tmp_path / "token", TOKEN + "\n", 0o644)
    assert main(["report", str(tmp_path), "--serve", "0.0.0.0:0", "--status-token", str(token)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and f"{token}: other users have access" in lines[0]


def test_the_insecure_key_file_warning_is_one_line_on_stderr(tmp_path: Path) -> None:
    """Outside pytest's log capture: what a person at the terminal sees."""
    key = _secret(tmp_path / "open.key", RAW, 0o644)
    proc = subprocess.run([sys.executable, "-m", "companion.cli", "fly", SCENARIO, "--sim", "--signing-key", str(key),
                           "--insecure-key-file", "--status-page", "0.0.0.0:0", "--report", str(tmp_path / "r")],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 2, proc.stderr
    assert lines[0] == (f"WARNING companion.mavlink.signing: {key}: other users have access to this signing key "
                        "(mode 0644); used anyway (--insecure-key-file)")
    assert lines[1].startswith("fuseplan: error: --status-page 0.0.0.0:0 is reachable from other machines")

"""Reading a file the user names (a scenario, a terrain DEM, a PLAN.json, a key or token file) without trusting it.

A path can name a FIFO that never delivers a byte, a device that never ends (``/dev/zero``), a directory or a file
far larger than anything the format holds. :func:`read_regular_file` refuses each in one line, before it reads, and
never blocks: it looks with ``os.stat`` first, opens with ``O_NONBLOCK``, looks again at what it opened (the path
may have been swapped in between) and reads at most one byte past the limit.
"""

from __future__ import annotations

import errno
import os
import stat
from collections.abc import Callable
from pathlib import Path

from planner.errors import FuseplanError

_NOT_REGULAR = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                (stat.S_ISSOCK, "a socket"))


class FileRefused(FuseplanError):
    """A file that cannot be read or is not one to read: ``str(err)`` is one line, ``PATH: REASON``."""

    def __init__(self, path: str | Path, reason: str) -> None:
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")

    def __reduce__(self):  # noqa: ANN204 - survives pickling across process pools
        return (type(self), (self.path, self.reason))


def size_text(n: int) -> str:
    """``16 MB`` for 16 × 2**20 bytes, ``1500 bytes`` for 1500: a limit as a user reads it."""
    for unit, scale in (("GB", 2**30), ("MB", 2**20), ("kB", 2**10)):
        if n >= scale and n % scale == 0:
            return f"{n // scale} {unit}"
    return f"{n} bytes"


def read_regular_file(path: str | Path, max_bytes: int, what: str,
                      check: Callable[[Path, os.stat_result], None] | None = None) -> bytes:
    """The bytes of the regular file at ``path`` (symbolic links followed), at most ``max_bytes`` of them.

    ``what`` names the file for the user ("scenario", "plan", "signing key"). Raises :class:`FileRefused` (a
    :class:`FuseplanError`, one line ``PATH: REASON``) when the file is missing or unreadable, is not a regular
    file (a directory, FIFO, device or socket: refused without opening it, so a FIFO never blocks), or holds more
    than ``max_bytes`` bytes (checked by size before reading and again while reading, for a file that grows).
    ``check(path, stat)`` looks at what was opened before anything is read (a secret file's permissions) and
    raises to refuse it.
    """
    path = Path(path)
    try:
        _check_regular(path, os.stat(path), what)
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as e:
        raise _unreadable(path, e, what) from None
    except ValueError:  # a NUL in the name: no file can have it
        raise FileRefused(repr(str(path)), f"not a {what} file name (it holds a NUL character)") from None
    try:
        st = os.fstat(fd)
        _check_regular(path, st, what)  # what was opened: the path may have been replaced since the stat
        if check is not None:
            check(path, st)
        if st.st_size > max_bytes:
            raise FileRefused(path, f"{st.st_size} bytes is more than a {what} file may hold "
                              f"({size_text(max_bytes)}): is it the right file?")
        chunks: list[bytes] = []
        size = 0
        while size <= max_bytes and (chunk := os.read(fd, min(max_bytes + 1 - size, 2**20))):
            chunks.append(chunk)
            size += len(chunk)
    except OSError as e:
        raise _unreadable(path, e, what) from None
    finally:
        os.close(fd)
    if size > max_bytes:  # it grew after the fstat, or reports no size (a /proc file)
        raise FileRefused(path, f"more than {size_text(max_bytes)} is more than a {what} file may hold")
    return b"".join(chunks)


def _unreadable(path: Path, e: OSError, what: str) -> FileRefused:
    if e.errno == errno.ENOENT:
        return FileRefused(path, f"{what} file not found")
    return FileRefused(path, f"cannot read the {what} file: {e.strerror or e}")


def _check_regular(path: Path, st: os.stat_result, what: str) -> None:
    if stat.S_ISREG(st.st_mode):
        return
    kind = next((name for test, name in _NOT_REGULAR if test(st.st_mode)), "a special file")
    target = os.path.realpath(path)
    via = f" ({target})" if target != os.path.abspath(path) else ""  # a symlink's target, e.g. /dev/zero
    raise FileRefused(path, f"a {what} file must be a regular file, not {kind}{via}")

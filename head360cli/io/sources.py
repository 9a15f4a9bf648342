"""Inputs that are pipes rather than files.

A shell script can hand head360 a photo, a stream or a head file through a pipe instead
of a file: process substitution (``head360 fit <(curl -s URL)``), ``/dev/stdin`` or a
named pipe. A pipe has no size, can be read only once and cannot seek, while the readers
check the size, look at the first bytes before reading the rest, or seek (Pillow, zip
archives). :func:`readable` reads a pipe whole into memory once and hands the readers a
seekable buffer instead; a regular file is passed on as its path.
"""

from __future__ import annotations

import contextlib
import errno
import io
import os
import stat
from pathlib import Path
from typing import BinaryIO

__all__ = ["MAX_READ_BYTES", "NamedBytes", "check_stdin", "existing", "input_stem", "is_pipe",
           "missing", "read_whole", "readable"]

MAX_READ_BYTES = 1 << 30
"""The most an input that is read whole into memory may hold (1 GiB): a pipe, standard
input or an ARKit stream. An hour of a Live Link Face take is about 130 MB; without a
bound, ``--arkit /dev/zero`` or an endless pipe read until the memory ran out."""


class NamedBytes(io.BytesIO):
    """A pipe's content in memory, with the pipe's path as ``name`` for messages."""

    def __init__(self, data: bytes, name: str) -> None:
        super().__init__(data)
        self.name = name


def check_stdin(what: str) -> None:
    """Refuse to read ``what`` (``"an ARKit stream"``) from standard input when it is a
    terminal: nothing was piped in, and the read would wait for typing.

    Raises:
        BadInputError: Standard input is a terminal or closed.
    """
    import sys

    from head360cli.errors import BadInputError

    stdin = sys.stdin
    if stdin is None or (hasattr(stdin, "isatty") and stdin.isatty()):
        found = "it closed" if stdin is None else "a terminal"
        raise BadInputError(f"expected {what} on standard input ('-'), found {found}: "
                            "pipe one in (... | head360 ... -) or give a file")


def is_pipe(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` exists and is neither a regular file nor a folder (a pipe, a
    character device such as ``/dev/stdin``, a socket)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode))


def existing(path: str | os.PathLike[str] | NamedBytes, what: str) -> Path | NamedBytes:
    """``path`` as a ``Path`` once it is known to exist and not to be a folder (a
    :class:`NamedBytes` is returned as it is).

    Args:
        path: The input.
        what: What was expected, for the message (``"an image file"``).

    Raises:
        BadInputError: No such file, or a folder.
    """
    from head360cli.errors import BadInputError

    if isinstance(path, NamedBytes):
        return path
    if not Path(path).exists():
        raise missing(path, f"no such file: {os.fspath(path)!r}")
    path = Path(path)
    if path.is_dir():
        raise BadInputError(f"expected {what}, found a folder: {str(path)!r}")
    return path


def read_whole(source: str | os.PathLike[str] | BinaryIO, name: str) -> bytes:
    """Everything ``source`` (a path, a pipe or an open binary stream) holds, read in
    pieces up to :data:`MAX_READ_BYTES`.

    Raises:
        BadInputError: It holds more (a regular file is told by its size, unread).
        OSError: The read failed.
    """
    from head360cli.errors import BadInputError

    limit = MAX_READ_BYTES

    def too_large() -> BadInputError:
        return BadInputError(f"expected at most {limit / 2**30:g} GiB in {name!r} (it is "
                             f"read whole into memory), found more")

    if not hasattr(source, "read"):
        path = Path(source)
        if path.is_file() and path.stat().st_size > limit:
            raise too_large()
        with open(path, "rb") as f:
            return read_whole(f, name)
    pieces, size = [], 0
    while piece := source.read(min(1 << 22, limit + 1 - size)):
        pieces.append(piece)
        size += len(piece)
        if size > limit:
            raise too_large()
    return b"".join(pieces)


def missing(path: str | os.PathLike[str], message: str) -> Exception:
    """The error for an input ``path`` that does not exist: ``message``, or, for a URL
    (``https://...``, ``s3://...``; Path would also fold its ``//``), what to do instead,
    since head360 reads local files and pipes only."""
    import re

    from head360cli.errors import BadInputError

    text = os.fspath(path)
    if re.match(r"[A-Za-z][A-Za-z0-9+.-]*://", text):
        return BadInputError(f"expected a local file, found a URL ({text!r}): head360 does "
                             f"not download; fetch it first, or pipe it in as '-' "
                             f"(curl -s URL | head360 ... -)")
    if os.path.islink(text):  # it is there, in a listing: say why it does not count
        try:
            os.stat(text)
        except OSError as exc:
            if exc.errno == errno.ELOOP:
                return BadInputError(f"{message} (a loop of symbolic links)")
        with contextlib.suppress(OSError):
            return BadInputError(f"{message} (a symbolic link to {os.readlink(text)!r}, "
                                 f"which does not exist)")
    return BadInputError(message)


def readable(path: str | os.PathLike[str] | NamedBytes) -> tuple[Path | NamedBytes, int]:
    """What a reader should open for an existing, non-folder ``path``, and its size.

    Returns:
        ``(source, size)``: for a regular file its ``Path`` and size on disk; for a pipe
        (:func:`is_pipe`) a :class:`NamedBytes` of everything it held, and that length;
        a :class:`NamedBytes` already read is returned as it is.
    """
    if isinstance(path, NamedBytes):
        return path, len(path.getbuffer())
    path = Path(path)
    if is_pipe(path):
        data = read_whole(path, str(path))
        return NamedBytes(data, str(path)), len(data)
    return path, path.stat().st_size


def input_stem(path: str | os.PathLike[str]) -> str:
    """The name outputs made from ``path`` are called after: its stem, except for a pipe
    without a name of its own (process substitution's ``/dev/fd/63``, ``/dev/stdin``),
    which gives ``"pipe"`` (a named pipe keeps its name)."""
    stem = Path(path).stem
    if str(path) == "/dev/stdin" or (is_pipe(path) and stem.isdigit()):
        return "pipe"  # /dev/stdin even when it is a file redirected with <
    return stem

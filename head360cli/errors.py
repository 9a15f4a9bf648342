"""The head360 exception family and the exit code of each.

Library code raises these; the CLI maps each class to its own exit code and prints a
single line (``head360: error: <message>``) unless ``--debug`` is given. Messages say what
was expected and what was found.

Exit codes:

====  =====================  ==================================================
code  exception              meaning
====  =====================  ==================================================
0     -                      success
1     (any other)            an internal error: a bug, please report it
2     (click usage error)    unknown option, missing argument, bad option value
3     BadInputError          the input's content is invalid (NaN in a stream,
                             image too large or transparent everywhere, missing
                             or unreadable file, bad parameter value, a deleted
                             current folder), or the output cannot be written
                             (no permission, a read-only file or disk, a full
                             disk, a file-size limit, a full standard output),
                             or the process limit refused a thread
4     NoFaceError            no face was found where one was needed
5     FileFormatError        a file is unreadable, truncated, corrupted, of an
                             unsupported version or unsafe (pickles), or model
                             weights hold NaN or infinity
6     ModelMismatchError     a file was made with another model than the one
                             loaded, or a checkpoint's config does not fit
7     ModelNotFoundError     a model file or an optional package the command
                             needs is not installed, or ffmpeg cannot be run
8     (out of memory)        the CPU's or the GPU's memory ran out (MemoryError,
                             torch's OutOfMemoryError or failed CPU allocation),
                             or a library could not be mapped (``ulimit -v``)
9     UnsupportedPlatformError
                             the CPU or system cannot run a model's runtime
                             (an x86-64 CPU without AVX for LiteRT)
129   (SIGHUP)               the terminal or ssh session closed; as for 130
130   (KeyboardInterrupt)    interrupted; nothing half-written is left behind
143   (SIGTERM)              terminated (``kill``, ``timeout``); as for 130
====  =====================  ==================================================
"""

from __future__ import annotations

__all__ = [
    "EXIT_CODES",
    "BadInputError",
    "FileFormatError",
    "Head360Error",
    "ModelMismatchError",
    "ModelNotFoundError",
    "NoFaceError",
    "UnsupportedPlatformError",
    "is_out_of_memory",
]


class Head360Error(Exception):
    """Base class of every error head360 reports to a user.

    Attributes:
        exit_code: The process exit status the CLI uses for this error.
    """

    exit_code: int = 1

    def __init__(self, message: str) -> None:
        # One line only: the CLI prints it as it is.
        super().__init__(" ".join(str(message).split()))


class BadInputError(Head360Error, ValueError):
    """The content of an input is invalid (values, sizes, missing files, options)."""

    exit_code = 3


class NoFaceError(Head360Error):
    """No face could be detected where one was needed."""

    exit_code = 4


class FileFormatError(Head360Error):
    """A file is unreadable, truncated, corrupted, of another version or unsafe."""

    exit_code = 5


class ModelMismatchError(Head360Error):
    """A head file or checkpoint does not belong to the model that was loaded."""

    exit_code = 6


class ModelNotFoundError(Head360Error, FileNotFoundError):
    """A model file or an optional package needed by the command is not installed."""

    exit_code = 7


class UnsupportedPlatformError(Head360Error):
    """The CPU or system cannot run a model's runtime (LiteRT on an x86-64 CPU without
    AVX)."""

    exit_code = 9


EXIT_CODES: dict[str, int] = {
    "ok": 0,
    "internal": 1,
    "usage": 2,
    BadInputError.__name__: BadInputError.exit_code,
    NoFaceError.__name__: NoFaceError.exit_code,
    FileFormatError.__name__: FileFormatError.exit_code,
    ModelMismatchError.__name__: ModelMismatchError.exit_code,
    ModelNotFoundError.__name__: ModelNotFoundError.exit_code,
    "out_of_memory": 8,
    UnsupportedPlatformError.__name__: UnsupportedPlatformError.exit_code,
    "hangup": 129,
    "interrupted": 130,
    "terminated": 143,
}
"""Exit code by error name, as documented in the README."""


def is_out_of_memory(exc: BaseException) -> bool:
    """Whether ``exc`` says that memory ran out: Python's or numpy's ``MemoryError``,
    torch's ``OutOfMemoryError`` (a GPU's), torch's failed CPU allocation (a
    ``RuntimeError`` that says "can't allocate memory"), or a library that could not be
    mapped into memory (an ``ImportError`` or ``OSError`` saying "failed to map segment",
    or ``ENOMEM``: under ``ulimit -v``, importing torch or OpenCV was an internal
    error). torch is not imported here."""
    import errno
    import sys

    if isinstance(exc, MemoryError):
        return True
    if isinstance(exc, ImportError | OSError) and (
            getattr(exc, "errno", None) == errno.ENOMEM
            or "failed to map segment" in str(exc)):
        return True
    torch = sys.modules.get("torch")
    oom = getattr(torch, "OutOfMemoryError", None) if torch is not None else None
    if oom is not None and isinstance(exc, oom):
        return True
    return isinstance(exc, RuntimeError) and "can't allocate memory" in str(exc)

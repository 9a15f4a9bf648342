"""Atomic outputs: write to a temporary name beside the target, then rename.

A failure or an interrupt at any point leaves the target as it was (absent, or the
previous complete version) and removes the temporary file. A run killed outright (SIGKILL,
the out-of-memory killer) cannot; the next write of the same output removes what it left,
once it is an hour old and its process has gone.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

__all__ = [
    "atomic_dir",
    "atomic_path",
    "atomic_paths",
    "check_dir_target",
    "check_file_target",
    "check_folder_name",
    "check_name_length",
    "check_replaceable",
    "check_writable",
    "commit_dir",
    "current_umask",
    "empty_file",
    "remove_leftovers",
    "replace_keeping_mode",
    "short_name",
    "temp_dir_beside",
    "temp_name_beside",
    "write_target",
]


_INPUTS: list[tuple[str, os.stat_result]] = []
"""The files the running command reads (:func:`protect_inputs`), which no output may
replace."""


@contextlib.contextmanager
def protect_inputs(paths, allow: bool = False) -> Iterator[None]:
    """Inside the ``with`` block, refuse to write over any of the existing regular files
    ``paths`` (the same file by path, link or hard link: device and inode), unless
    ``allow`` (``--overwrite``). A command whose output names one of its inputs (``-o
    clip.mp4`` for ``--video clip.mp4``) would otherwise replace it."""
    own = list(_INPUTS)
    if not allow:
        for p in paths:
            try:
                st = os.stat(p)
            except (OSError, ValueError, TypeError):
                continue
            if stat.S_ISREG(st.st_mode):
                _INPUTS.append((os.fspath(p), st))
    try:
        yield
    finally:
        _INPUTS[:] = own


def check_not_an_input(target: str | os.PathLike[str]) -> None:
    """Refuse ``target`` when it is one of the files the command reads
    (:func:`protect_inputs`).

    Raises:
        BadInputError: Naming the input and the option that allows it.
    """
    if not _INPUTS:
        return
    try:
        st = os.stat(target)
    except (OSError, ValueError):
        return
    for name, seen in _INPUTS:
        if (st.st_dev, st.st_ino) == (seen.st_dev, seen.st_ino):
            from head360cli.errors import BadInputError

            same = "" if os.fspath(target) == name else f" ({name})"
            raise BadInputError(f"expected an output other than the inputs, found "
                                f"{os.fspath(target)!r}, an input{same}; give --overwrite "
                                f"to replace it")


def write_target(target: str | os.PathLike[str]) -> Path:
    """Where a write to ``target`` goes: where a symbolic link at ``target`` leads
    (followed to the end, as a shell's ``>`` follows it; it need not exist yet), else
    ``target`` itself. Renaming a new file onto the link would replace the link and leave
    the file it leads to as it was."""
    target = Path(target)
    try:
        link = target.is_symlink()
    except OSError:  # a name too long to look up: the checks that follow say so
        return target
    return Path(os.path.realpath(target)) if link else target


def current_umask() -> int:
    """The process's file-creation mask (``0o022`` on most systems).

    Read from ``/proc/self/status`` where Linux has it; elsewhere ``os.umask`` is set and
    put back at once (the only portable way to read it).
    """
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_TEMP_STEM = 48
"""How much of an output's name its temporary name repeats: a name near the file system's
limit (255 bytes on most) would otherwise make a temporary name over it."""


LEFTOVER_AGE_S = 3600.0
"""How long a temporary file of a process that no longer runs is left alone before the
next write of the same output removes it."""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)  # POSIX: no signal is sent, only whether the process exists
    except ProcessLookupError:
        return False
    except OSError:  # another user's process, or a check that failed: assume it runs
        return True
    return True


def remove_leftovers(folder: Path, prefix: str, suffix: str) -> list[Path]:
    """Remove the temporary files and folders of ``prefix`` and ``suffix`` in ``folder``
    that a run killed outright (SIGKILL, the out-of-memory killer, a power cut) left:
    named as this module names them, by a process that no longer runs, untouched for
    :data:`LEFTOVER_AGE_S`. Nothing else is touched; nothing at all off POSIX.

    Returns:
        What was removed.
    """
    import glob
    import re
    import time

    if os.name != "posix":
        return []
    pattern = re.compile(re.escape(prefix) + r"(\d+)-[^./]*" + re.escape(suffix) + "$")
    removed = []
    now = time.time()
    for entry in folder.glob(glob.escape(prefix) + "*" + glob.escape(suffix)):
        found = pattern.match(entry.name)
        if not found or int(found.group(1)) == os.getpid() or _alive(int(found.group(1))):
            continue
        try:
            if now - entry.lstat().st_mtime < LEFTOVER_AGE_S:
                continue
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
        except OSError:
            continue
        removed.append(entry)
    return removed


def empty_file(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is a plain file of no bytes (through a symbolic link): nothing is
    lost by writing over it. The shell makes one for ``> me.json`` before the command
    runs, so a result redirected to the name of a file the command writes itself is
    found there empty. A named pipe, which also reads as size 0, is not one."""
    try:
        st = os.stat(path)
    except OSError:
        return False
    return stat.S_ISREG(st.st_mode) and st.st_size == 0


def replace_keeping_mode(tmp: Path, target: Path) -> None:
    """Rename ``tmp`` onto ``target``; where ``target`` exists, ``tmp`` takes its
    permission bits first, as a write into the file itself would keep them (a head file
    made private with ``chmod 600`` stayed private, not readable by all under umask 022)."""
    try:
        mode = target.stat().st_mode
    except OSError:  # none there yet: the mode the temporary one was made with
        pass
    else:
        os.chmod(tmp, stat.S_IMODE(mode))
    os.replace(tmp, target)


def temp_name_beside(target: Path) -> Path:
    """A fresh temporary file name in ``target``'s folder, keeping its suffix; the file
    does not exist, so whatever writes it creates it with the usual permissions (a
    reserved ``mkstemp`` file would stay readable by its owner only).

    The name carries this process's id, so the next write of ``target`` can tell the
    leftovers of a killed run (:func:`remove_leftovers`), and removes them."""
    prefix = f".{target.stem[:_TEMP_STEM]}."
    suffix = f".tmp{target.suffix[:_TEMP_STEM]}"
    remove_leftovers(target.parent, prefix, suffix)
    fd, name = tempfile.mkstemp(prefix=f"{prefix}{os.getpid()}-", suffix=suffix,
                                dir=target.parent)
    os.close(fd)
    os.unlink(name)
    return Path(name)


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; rename it onto ``target`` on success.

    The temporary name keeps the target's suffix, so tools that pick a format by
    extension (ffmpeg, numpy) still do the right thing.

    Args:
        target: The final output path. Its parent folder must exist.

    Yields:
        The temporary path to write to. It does not exist yet.
    """
    target = write_target(target)
    _check_file_name(target)  # no test file: making the temporary name below is the test
    check_not_an_input(target)
    try:
        tmp = temp_name_beside(target)
    except OSError as exc:
        raise _unwritable(target.parent, exc) from None
    try:
        yield tmp
        if not tmp.exists():
            raise RuntimeError(f"nothing was written to the temporary file for {target}")
        replace_keeping_mode(tmp, target)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


@contextlib.contextmanager
def atomic_paths(*targets: str | os.PathLike[str]) -> Iterator[list[Path]]:
    """Yield temporary paths for files that belong together (a mesh and its texture, a
    head file and its preview); rename every one onto its target, in the order given, only
    once the block ends without error.

    A failure part-way (a full disk at the last file) therefore leaves every target as it
    was, rather than some files of the new set beside others of the old one or none.

    Args:
        targets: The final output paths; their folders must exist.

    Yields:
        One temporary path per target, in the same order. Each must be written.
    """
    with contextlib.ExitStack() as stack:
        # ExitStack leaves the last one entered first: enter in reverse to rename in order.
        tmps = [stack.enter_context(atomic_path(t)) for t in reversed(targets)]
        yield tmps[::-1]


def check_writable(folder: Path) -> None:
    """Refuse an existing ``folder`` that no file can be made in (read-only, no
    permission, ``/proc``): outputs are written there as temporary files first, which
    had failed only after the work, as an internal error.

    Raises:
        BadInputError: A file cannot be created there.
    """
    try:
        fd, name = tempfile.mkstemp(prefix=".head360-check.", dir=folder)
    except OSError as exc:
        raise _unwritable(folder, exc) from None
    os.close(fd)
    os.unlink(name)


def _unwritable(folder: Path, exc: OSError) -> Exception:
    from head360cli.errors import BadInputError

    return BadInputError(f"cannot write into output folder {str(folder)!r}: "
                         f"{exc.strerror or exc}")


def _check_file_name(target: Path) -> None:
    """Refuse a file target whose folder does not exist, or which is a folder, a named
    pipe, a device, a socket or read-only (:func:`check_replaceable`)."""
    from head360cli.errors import BadInputError

    check_name_length(target)
    if not target.parent.is_dir():
        raise BadInputError(f"output folder {str(target.parent)!r} does not exist")
    if target.is_dir():
        raise BadInputError(f"expected a file name for {str(target)!r}, found a folder")
    check_replaceable(target)


def check_replaceable(target: Path) -> None:
    """Refuse an output that exists as something other than a file or folder: a named
    pipe (``mkfifo``), a device or a socket. Outputs are written whole under a temporary
    name and renamed, which would put a plain file in its place, and a reader waiting on
    the pipe would wait for ever. Refuse a file this process may not write, too (made
    read-only to keep it; root may write any, as a shell's ``>`` lets it), or may not
    rename onto (another user's in a sticky folder such as ``/tmp``).

    Raises:
        BadInputError: Naming what is there.
    """
    from head360cli.errors import BadInputError

    try:
        mode = target.stat().st_mode
    except OSError:  # nothing there (or nothing that can be looked at): a new file
        return
    kind = ("named pipe" if stat.S_ISFIFO(mode) else "device"
            if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "socket"
            if stat.S_ISSOCK(mode) else None)
    if kind is not None:
        raise BadInputError(f"expected a file name for {str(target)!r}, found a {kind}: "
                            f"outputs are written whole and renamed into place, which "
                            f"would replace it; give a file name")
    if hasattr(os, "geteuid") and os.geteuid() != 0:
        folder = target.parent.stat()
        if folder.st_mode & stat.S_ISVTX and os.geteuid() not in (folder.st_uid,
                                                                  target.stat().st_uid):
            raise BadInputError(f"expected an output that may be replaced, found "
                                f"{str(target)!r} another user's, in a folder where only "
                                f"a file's owner may replace it (sticky, as /tmp is): "
                                f"give another name")
    if stat.S_ISREG(mode) and not os.access(target, os.W_OK):
        # the rename needs only the folder's permission: without this, a file made
        # read-only to keep it (chmod a-w) was replaced where a shell's > refuses
        raise BadInputError(f"expected an output that may be replaced, found "
                            f"{str(target)!r} read-only: give another name, or make it "
                            f"writable (chmod u+w) to replace it")


def check_name_length(target: Path) -> None:
    """Refuse an output whose name is longer than its file system allows (255 bytes on
    most; ``os.pathconf`` where the folder exists), naming the limit.

    Raises:
        BadInputError: The name's UTF-8 bytes are over the limit.
    """
    from head360cli.errors import BadInputError

    size = len(os.fsencode(target.name))
    try:
        limit = os.pathconf(target.parent, "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):  # no such folder, or not POSIX
        limit = 255
    if size > limit:
        raise BadInputError(f"expected an output name of at most {limit} bytes, found "
                            f"{size}: {short_name(target.name)}")


def short_name(name: str) -> str:
    """``name`` for a one-line message: its first 40 and last 12 characters when longer
    than 60."""
    return f"{name[:40]}...{name[-12:]}" if len(name) > 60 else name


def check_file_target(target: str | os.PathLike[str]) -> None:
    """Refuse a file target whose folder does not exist or cannot be written, or which is
    a folder (as :func:`atomic_path` does when it is asked to write; callers with long
    work before the write check first). A symbolic link is checked where it leads."""
    target = write_target(target)
    _check_file_name(target)
    check_not_an_input(target)
    check_writable(target.parent)


FILE_SUFFIXES = frozenset((
    ".png", ".jpg", ".jpeg", ".gif", ".webp", ".bmp", ".tif", ".tiff", ".mp4", ".mov",
    ".m4v", ".h360", ".glb", ".obj", ".csv", ".json", ".npz", ".onnx", ".pt"))
"""Suffixes of the files head360 reads or writes: a new output folder named so is taken
for a mistaken file name."""


def check_folder_name(target: str | os.PathLike[str]) -> None:
    """Refuse a new output folder named like a file (``-o heads.png`` for a command that
    writes a folder; a folder that exists already is its owner's choice), or one that
    cannot be written in (:func:`check_writable`, on its nearest existing folder).

    Raises:
        BadInputError: ``target`` does not exist and ends in one of :data:`FILE_SUFFIXES`,
            or no file can be made where it is or would be.
    """
    from head360cli.errors import BadInputError

    target = Path(target)
    if target.suffix.lower() in FILE_SUFFIXES and not target.is_dir():
        raise BadInputError(f"expected a folder name for the outputs, found "
                            f"{str(target)!r}, a file's name")
    existing = target
    while not existing.exists() and existing != existing.parent:  # made with its parents
        existing = existing.parent
    if existing.is_dir():
        check_writable(existing)


def check_dir_target(target: Path, overwrite: bool) -> None:
    """Refuse a folder target that is a file or a non-empty folder (unless ``overwrite``)."""
    from head360cli.errors import BadInputError

    parent = target.parent
    if not parent.is_dir():
        raise BadInputError(f"output folder {str(parent)!r} does not exist")
    if target.exists() and not target.is_dir():
        raise BadInputError(f"expected a folder for {str(target)!r}, found a file")
    check_writable(parent)
    if target.is_dir() and any(target.iterdir()) and not overwrite:
        raise BadInputError(
            f"expected a new or empty output folder, found {str(target)!r} holding files "
            "(it would be replaced whole): choose another name, or empty it"
        )


def temp_dir_beside(target: Path) -> Path:
    """A new empty temporary folder in the same parent as ``target``, with the
    permissions a plain ``mkdir`` would give it (``mkdtemp`` makes it private, and the
    folder it becomes would stay so)."""
    prefix = f".{target.name[:_TEMP_STEM]}."
    remove_leftovers(target.parent, prefix, ".tmp")
    tmp = Path(tempfile.mkdtemp(prefix=f"{prefix}{os.getpid()}-", suffix=".tmp",
                                dir=target.parent))
    os.chmod(tmp, 0o777 & ~current_umask())
    return tmp


def commit_dir(tmp: Path, target: Path) -> None:
    """Move a complete temporary folder onto ``target``, replacing an old one last."""
    if target.exists():
        old = temp_dir_beside(target)
        os.chmod(tmp, stat.S_IMODE(target.stat().st_mode))  # as the folder it replaces
        os.replace(target, old / "old")
        os.replace(tmp, target)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, target)


@contextlib.contextmanager
def atomic_dir(target: str | os.PathLike[str], overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary folder beside ``target``; move it onto ``target`` on success.

    Args:
        target: The final folder. It must not exist, or be empty, unless ``overwrite``.
        overwrite: Replace an existing non-empty folder (only after the new one is
            complete).

    Yields:
        The temporary folder to write into (it exists and is empty).
    """
    target = write_target(target)
    check_dir_target(target, overwrite)
    tmp = temp_dir_beside(target)
    try:
        yield tmp
        commit_dir(tmp, target)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)

"""The ``head360`` entry point: runs the command group and turns every outcome into
one line and an exit code (errors of the :mod:`head360cli.errors` family, interrupts,
signals, full disks, out of memory); ``--debug`` shows the traceback instead.

Importing this module registers every command: each command group's module adds its
commands to :data:`head360cli.cli.base.cli` when imported."""

from __future__ import annotations

import contextlib
import json
import os
import sys
from pathlib import Path

import click

from head360cli.cli import bench, corpus, files, head, photo  # noqa: F401  (registers the commands)
from head360cli.cli.base import cli, drop_stdout
from head360cli.errors import EXIT_CODES, BadInputError, Head360Error, is_out_of_memory

__all__ = ["cli", "main"]


def _restore_help(command: click.Command) -> None:
    """Give ``command`` and its subcommands back the help texts that ``python -OO`` (or
    ``PYTHONOPTIMIZE=2``) dropped with every docstring: each command's docstring, read
    from its module's source. Without it, ``head360 fit --help`` under ``-OO`` showed
    the options and neither what the command does nor its examples."""
    import ast
    import inspect

    modules: dict[str, dict[str, str]] = {}
    todo = [command]
    while todo:
        cmd = todo.pop()
        if isinstance(cmd, click.Group):
            todo += cmd.commands.values()
        if cmd.help is not None or cmd.callback is None:
            continue
        code = getattr(inspect.unwrap(cmd.callback), "__code__", None)
        if code is None:
            continue
        if code.co_filename not in modules:
            try:
                tree = ast.parse(Path(code.co_filename).read_text(encoding="utf-8"))
            except (OSError, SyntaxError, ValueError):  # no source beside the bytecode
                tree = ast.Module(body=[], type_ignores=[])
            modules[code.co_filename] = {
                node.name: ast.get_docstring(node, clean=False) or ""
                for node in tree.body if isinstance(node, ast.FunctionDef)}
        cmd.help = modules[code.co_filename].get(code.co_name) or None


if sys.flags.optimize >= 2:
    _restore_help(cli)

# --------------------------------------------------------------------------- entry point


def _address_space_limit() -> str:
    """`` (at most N MiB: ulimit -v)`` where the process's address space is limited."""
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    except (ImportError, OSError, ValueError):  # no such limit on this system
        return ""
    return "" if soft == resource.RLIM_INFINITY else \
        f" (at most {soft / 2**20:.0f} MiB: ulimit -v)"


def _memory_shortfall(exc: BaseException) -> str:
    """What an out-of-memory error says, in a few words: a GPU's first two sentences
    ("CUDA out of memory. Tried to allocate 2.00 GiB"), the size a CPU allocation asked
    for, or the error's own start."""
    import re

    text = " ".join(str(exc).split())
    asked = re.search(r"tried to allocate (\d+) bytes", text)
    if asked:
        return f"the CPU could not allocate {int(asked.group(1)) / 2**30:.1f} GiB"
    if "out of memory" in text.lower():
        return ". ".join(text.split(". ")[:2])[:160]
    return text[:160] or type(exc).__name__


def _failed(kind: str, message: str, code: int, debug: bool, as_json: bool,
            label: str = "error", hint: str = "") -> int:
    """Report the exception being handled as one line on stderr (``head360: LABEL:
    MESSAGE HINT``), its traceback first with ``--debug``, and as JSON on stdout with
    ``--json``; return the exit ``code``."""
    if debug:
        import traceback

        traceback.print_exc()
    with contextlib.suppress(OSError):  # standard error full or closed: the code remains
        click.echo(f"head360: {label}: {message}{hint}", err=True)
    if as_json:
        _error_json(kind, message, code)
    return code


def _error_json(kind: str, message: str, code: int) -> None:
    """Print the error as JSON on standard output, if it can be written."""
    try:
        print(json.dumps({"ok": False, "error": {"type": kind, "message": message,
                                                 "exit_code": code}}), flush=True)
    except OSError:
        drop_stdout()


class _Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, ``timeout``, a batch system) or SIGHUP (the terminal or ssh
    session closed), raised in the main thread as an interrupt is, so that half-written
    outputs are removed and spawned processes ended; by default Python dies at once and
    leaves both behind.

    Attributes:
        signum: The signal's number.
    """

    signum = 15  # SIGTERM's


def _on_terminate(signum, frame) -> None:
    exc = _Terminated()
    exc.signum = signum
    raise exc


def _stop_signals() -> list[int]:
    """The signals :func:`_on_terminate` handles: SIGTERM, and SIGHUP where there is one
    and it is not ignored (``nohup`` ignores it, and it must stay so)."""
    import signal

    found = [signal.SIGTERM]
    hup = getattr(signal, "SIGHUP", None)
    if hup is not None and signal.getsignal(hup) is not signal.SIG_IGN:
        found.append(hup)
    return found


def main(argv: list[str] | None = None) -> int:
    """Run the CLI and return its exit code (see ``head360 --help`` for the codes)."""
    import signal
    import threading

    args = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args
    if debug:  # FFmpeg's own log lines too (head360 keeps them quiet otherwise)
        import os

        from head360cli.io.frames import FFMPEG_LOG

        os.environ.setdefault(FFMPEG_LOG, "24")  # FFmpeg's warnings and errors
    as_json = "--json" in args
    _open_closed_outputs()
    for stream in (sys.stdout, sys.stderr):  # a name the terminal's encoding lacks
        if hasattr(stream, "reconfigure"):   # (an emoji, in Latin-1) is escaped, not
            with contextlib.suppress(Exception):  # an internal error after the work
                stream.reconfigure(errors="backslashreplace")
    handles = threading.current_thread() is threading.main_thread()  # only it may
    previous = {sig: signal.signal(sig, _on_terminate) for sig in _stop_signals()} \
        if handles else {}
    if handles and argv is not None:  # called from Python: its Ctrl-C is given back
        previous[signal.SIGINT] = signal.getsignal(signal.SIGINT)
    try:
        return _run(args, debug, as_json)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _open_closed_outputs() -> None:
    """Point a closed standard output or error (``2>&-``, a daemon's) at ``os.devnull``.
    Python makes ``sys.stderr`` None then, and the first progress line was an internal
    error that lost the work; the descriptor itself is opened too, so spawned processes
    and ffmpeg inherit one that works."""
    for fd, name in ((1, "stdout"), (2, "stderr")):
        if getattr(sys, name) is not None:
            continue
        try:
            os.fstat(fd)
        except OSError:  # closed: the lowest free descriptor, or this one by dup2
            null = os.open(os.devnull, os.O_WRONLY)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)
        with contextlib.suppress(OSError):
            setattr(sys, name, open(fd, "w", closefd=False))  # noqa: SIM115 (for the run)


def _run(args: list[str], debug: bool, as_json: bool) -> int:
    try:
        # click's main() would print an empty line before an interrupt's Abort: the
        # context is made and invoked here, so an interrupt is one line of ours
        with cli.make_context("head360", list(args)) as ctx:
            cli.invoke(ctx)
        return 0
    except click.exceptions.Exit as exc:
        return int(exc.exit_code)
    except click.ClickException as exc:
        exc.show()
        if as_json:
            _error_json("UsageError", exc.format_message(), exc.exit_code)
        return int(exc.exit_code)
    except (click.Abort, KeyboardInterrupt) as exc:  # click turns the interrupt into Abort
        if isinstance(exc, _Terminated) or isinstance(exc.__cause__, _Terminated):
            import signal

            stop = exc if isinstance(exc, _Terminated) else exc.__cause__
            if stop.signum != signal.SIGTERM:  # SIGHUP: the terminal may be gone too
                with contextlib.suppress(OSError):
                    click.echo("head360: hung up", err=True)
                return EXIT_CODES["hangup"]
            click.echo("head360: terminated", err=True)
            return EXIT_CODES["terminated"]
        _ignore_further_interrupts()
        click.echo("head360: interrupted", err=True)
        return EXIT_CODES["interrupted"]
    except Head360Error as exc:
        return _failed(type(exc).__name__, str(exc), exc.exit_code, debug, as_json)
    except BrokenPipeError:
        return 0  # e.g. `head360 inspect x.csv | head`
    except OSError as exc:
        import errno

        if exc.errno == errno.ENAMETOOLONG:  # a name no check before the work caught
            from head360cli.io.atomic import short_name

            name = Path(str(exc.filename or "")).name
            shown = f": {short_name(name)}" if name else ""
            return _failed("BadInputError", f"file name too long{shown}: use a shorter name",
                           EXIT_CODES["BadInputError"], debug, as_json)
        named = exc.filename2 or exc.filename  # a rename's target, not its temporary file
        where = f" ({named})" if named else ""
        if exc.errno in (errno.EACCES, errno.EPERM):  # one no check before the work caught
            return _failed("BadInputError", f"{exc.strerror or exc}{where}: check the "
                           f"file's and its folder's permissions",
                           EXIT_CODES["BadInputError"], debug, as_json)
        if exc.errno not in (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG):
            return _internal(exc, debug, as_json)
        todo = {errno.EROFS: "write elsewhere",
                errno.EFBIG: "past the file system's or the shell's file-size limit (ulimit "
                             "-f): write elsewhere"}.get(exc.errno,
                                                         "free space or write elsewhere")
        return _failed("BadInputError", f"{exc.strerror or exc}{where}: {todo} (nothing "
                       "half-written was kept)", EXIT_CODES["BadInputError"], debug, as_json)
    except Exception as exc:
        return _internal(exc, debug, as_json)


def _ignore_further_interrupts() -> None:
    """Once head360 is ending on an interrupt, ignore another SIGINT: the interpreter's
    shutdown puts SIGINT back to its default action, and a Ctrl-C arriving then (a second
    press, or the process group's signal delivered late) ended the process by the signal
    (exit -2) instead of 130, after its one line. :func:`main` called from Python (with
    ``argv``) puts the caller's handler back."""
    import signal
    import threading

    if threading.current_thread() is threading.main_thread():
        with contextlib.suppress(ValueError, OSError):
            signal.signal(signal.SIGINT, signal.SIG_IGN)
    # CPython notes a KeyboardInterrupt that leaves exec() of a string (a dataclass or
    # namedtuple being made by an import the interrupt landed in) as "unhandled", even
    # when head360 then handles it, and at exit kills itself by SIGINT (exit -2) in place
    # of 130. Each exec() of a string clears that note first: this one clears it.
    exec("pass")


def _internal(exc: Exception, debug: bool, as_json: bool) -> int:
    """Report an exception no head360 error class names: out of memory, else a bug."""
    if is_out_of_memory(exc) and "failed to map segment" in str(exc):
        # a library that could not be mapped: no option asks for less of that
        message = (f"out of memory ({_memory_shortfall(exc)}): head360's libraries need "
                   f"more memory than this process may have{_address_space_limit()}: "
                   f"raise the limit or free memory")
        return _failed("OutOfMemory", message, EXIT_CODES["out_of_memory"], debug, as_json)
    if is_out_of_memory(exc):  # not a bug: a resource the user can free or ask less of
        message = (f"out of memory ({_memory_shortfall(exc)}): ask for less at once (a "
                   f"smaller --size or --samples; animate: fewer frames a call, --batch), "
                   f"free memory, or use another --device")
        return _failed("OutOfMemory", message, EXIT_CODES["out_of_memory"], debug, as_json)
    if isinstance(exc, RuntimeError) and "can't start new thread" in str(exc):
        # Python's own thread refused (EAGAIN): a limit of the system, not a bug
        message = ("cannot start a thread: the limit on processes and threads (ulimit -u, "
                   "a container's pids limit) is reached; raise it or run fewer jobs")
        return _failed("BadInputError", message, BadInputError.exit_code, debug, as_json)
    message = " ".join(f"{type(exc).__name__}: {exc}".split())
    return _failed("InternalError", message, EXIT_CODES["internal"], debug, as_json,
                   label="internal error",
                   hint=" (run with --debug for the traceback; please report it)")

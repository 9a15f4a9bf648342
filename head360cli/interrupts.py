"""Stopping a long loop cleanly: Ctrl-C, SIGTERM or SIGHUP ends it after the step it is
on, so the loop can save what it has before the signal takes effect.

A loop calls :func:`catch_interrupts` before it starts, checks the list it passed after
each step (save, then stop), calls :func:`restore_handlers` in a ``finally`` and, when a
signal was caught, :func:`signal.raise_signal` with it: the process then ends as the
signal asked (exit 130 for Ctrl-C), with its work saved. Used by ``train`` and
``train-hair-prior``.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

__all__ = ["catch_interrupts", "restore_handlers", "sigint_ignored"]


def catch_interrupts(caught: list[int]) -> dict[int, Any]:
    """Make SIGINT, SIGTERM and SIGHUP append their number to ``caught`` instead of stopping
    the process at once (main thread only, and not where one is ignored); a second one
    calls the handler it replaced.

    Returns:
        The replaced handlers, for :func:`restore_handlers`.
    """
    import contextlib
    import signal
    import sys
    import threading

    if threading.current_thread() is not threading.main_thread():
        return {}

    def on_signal(signum, frame) -> None:
        if caught:  # asked twice: stop now
            handler = previous[signum]
            if callable(handler):
                handler(signum, frame)
            raise KeyboardInterrupt
        caught.append(signum)
        with contextlib.suppress(OSError):  # after SIGHUP the terminal may be gone
            sys.stderr.write("\nhead360: interrupted: stopping after this step with a "
                             "checkpoint (again to stop at once)\n")

    # a signal ignored already stays so (a background job's SIGINT, as the shell set it)
    wanted = [signal.SIGINT, signal.SIGTERM, *([signal.SIGHUP] if hasattr(signal, "SIGHUP")
                                               else [])]
    previous = {sig: signal.signal(sig, on_signal) for sig in wanted
                if signal.getsignal(sig) is not signal.SIG_IGN}
    return previous


def restore_handlers(previous: dict[int, Any]) -> None:
    """Put back the handlers :func:`catch_interrupts` replaced."""
    import signal

    for sig, handler in previous.items():
        signal.signal(sig, handler)


@contextlib.contextmanager
def sigint_ignored() -> Iterator[None]:
    """Start processes inside this block: they ignore SIGINT for their whole life.

    A Ctrl-C at a terminal goes to every process of the foreground group, the spawned
    ones too; one still importing torch printed a traceback of its own, or a stray
    "Process SpawnProcess-1:" line. A signal ignored at ``exec`` stays ignored, and
    Python then installs no handler of its own for it, so processes started here leave
    Ctrl-C to this one, which ends them. This process ignores SIGINT only while the
    block runs (main thread only; elsewhere the block changes nothing).
    """
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)

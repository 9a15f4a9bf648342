"""Frames of an animation rendered by several processes on a CPU, written in order.

One torch process with two threads keeps two cores only partly busy: much of a frame is
small operations and Python between them. Two one-thread processes, each rendering its
own frames, got 1.3 to 1.5 times the frames of one two-thread process on 2 cores (the
fitted astronaut on a turning capture, 256 px). :func:`parallel_frames` splits the frames
into blocks; the calling process and ``workers - 1`` spawned ones each take the next
block not yet taken, render it with :meth:`~head360cli.model.head_render.HeadRenderer.
frames` (a still camera reuses decoded points within a block) and the caller yields the
frames in order. At most a few blocks wait to be written, so memory does not grow with
the length of the take. The spawned processes get the renderer (its tensors in shared
memory) and die with the caller.
"""

from __future__ import annotations

import copy
import os
import queue as queue_module
import threading
import traceback
from collections.abc import Iterator
from typing import Any

import numpy as np

__all__ = ["BLOCK", "MIN_FRAMES", "auto_workers", "parallel_frames", "peak_rss_mib",
           "usable_cpus"]

BLOCK = 16
"""Frames per block: long enough that a still camera's reuse of decoded points (which
starts afresh with each block) keeps most of its gain, short enough that the first
blocks are ready soon."""

MIN_FRAMES = 4 * BLOCK
"""Fewer frames than this are rendered in the calling process alone: starting a process
(about 3 s to import torch and receive the head) would cost more than it saves."""

AHEAD = 4
"""The calling process renders a block of its own while it waits only if fewer than this
many are waiting to be written; spawned processes start no block more than ``AHEAD x
workers`` beyond the blocks written."""


def peak_rss_mib() -> float:
    """This process's peak resident memory (``VmHWM``) in MiB, 0 where unknown."""
    try:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) / 1024 for line in f
                        if line.startswith("VmHWM:"))
    except (OSError, StopIteration):
        return 0.0


def usable_cpus() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def auto_workers(frames: int, device: str, cpus: int | None = None) -> int:
    """Processes for rendering ``frames`` frames: one per usable core (at most 4) on a
    CPU when there are at least :data:`MIN_FRAMES` frames, else 1."""
    if device != "cpu" or frames < MIN_FRAMES:
        return 1
    return max(1, min(4, usable_cpus() if cpus is None else cpus))


def _blocks(n: int, size: int) -> list[tuple[int, int]]:
    return [(i, min(i + size, n)) for i in range(0, n, size)]


def _render_block(renderer, c2w, weights, intrinsics, hair, block) -> tuple[Any, ...]:
    """``(frames (b, H, W, 3) uint8, points, decoded)`` of frames ``block[0]:block[1]``."""
    a, b = block
    frames = np.concatenate(list(renderer.frames(c2w[a:b], weights[a:b], intrinsics,
                                                 hair=hair, batch=1)))
    return frames, *_reuse_counts(renderer)


def _reuse_counts(renderer) -> tuple[int, int]:
    """``(points, decoded)`` of the renderer's latest :meth:`frames`."""
    reuse = renderer.last_reuse
    return (0, 0) if reuse is None else (reuse.points, reuse.decoded)


def _take(counter) -> int:
    with counter.get_lock():
        i = counter.value
        counter.value += 1
    return i


def _worker(renderer, c2w, weights, intrinsics, hair, block, threads, counter, written,
            limit, results) -> None:
    """A spawned process: render the blocks it takes until none is left, none more
    than ``limit`` blocks beyond the ``written`` ones."""
    import time

    import torch

    torch.set_num_threads(threads)
    blocks = _blocks(len(c2w), block)
    try:
        while (i := _take(counter)) < len(blocks):
            while i >= written.value + limit:
                time.sleep(0.005)
            made = _render_block(renderer, c2w, weights, intrinsics, hair, blocks[i])
            results.put((i, *made, (os.getpid(), peak_rss_mib())))
    except BaseException:  # reported to the caller, which renders the rest itself
        results.put((-1, traceback.format_exc(), 0, 0))


def parallel_frames(renderer, c2w, weights: np.ndarray, intrinsics, hair: bool = True,
                    workers: int = 2, counts: dict[str, Any] | None = None,
                    block: int = BLOCK, render_here: bool = True,
                    batch: int | None = None) -> Iterator[np.ndarray]:
    """:meth:`HeadRenderer.frames` (one frame at a time, uint8) by ``workers`` processes.

    Args:
        renderer: A :class:`~head360cli.model.head_render.HeadRenderer` on the CPU, torch
            backend (its generator and tensors are shared with the spawned processes).
        c2w: ``(N, 4, 4)`` cameras; weights: ``(N, 52)`` driving weights; intrinsics:
            ``(3, 3)``; hair: as :meth:`HeadRenderer.frames`.
        workers: Processes in all, the caller included; the cores are shared out among
            them as torch threads.
        counts: If given, ``workers`` is set to the processes used, and ``points`` and
            ``decoded`` are added to it (the points asked
            for and decoded afresh where frames reused decoded points), and
            ``spawned_blocks``, the blocks the spawned processes rendered; ``peaks``
            maps each spawned process's id to its peak resident memory (MiB) as of its
            last block.
        block: Frames per block.
        render_here: This process renders blocks too while it waits (with False it
            only collects and yields them).
        batch: Frames per generator call where this process renders alone (fewer than
            2 workers or blocks; the renderer's default for ``None``); several processes
            render one frame per call.

    Yields:
        ``(H, W, 3)`` uint8 frames in order.

    If a spawned process fails (or cannot start), the others are stopped and this
    process renders the frames not yet made, with a line on it in ``counts["warnings"]``;
    an error of the frames themselves is then raised here, as one process would.
    """
    import torch
    import torch.multiprocessing as mp

    n = len(c2w)
    blocks = _blocks(n, block)
    alone = workers < 2 or len(blocks) < 2
    if counts is not None:
        counts["workers"] = 1 if alone else workers
    if alone:  # one process: one run, reuse over all frames
        for frames in renderer.frames(c2w, weights, intrinsics, hair=hair, batch=batch):
            yield from frames
        _count(counts, *_reuse_counts(renderer))
        return
    ctx = mp.get_context("spawn")
    threads = max(1, usable_cpus() // workers)
    counter = ctx.Value("i", 0)  # the next block not yet taken
    written = ctx.Value("i", 0)  # blocks yielded so far
    results = ctx.Queue()
    c2w = c2w.detach().cpu().contiguous()
    weights = np.ascontiguousarray(weights, np.float32)
    # The processes are started (the renderer pickled) from another thread while this
    # one renders. Pickling moves each tensor's storage into shared memory, and
    # rendering replaces the renderer's last_reuse, whose tensors were then freed under
    # the pickler ("bad value(s) in fds_to_keep", once a crash): the spawned ones get a
    # copy made now, without it, whose tensors are moved to shared memory here, before
    # this thread uses them again
    shipped = copy.copy(renderer)
    shipped.last_reuse = None
    _share(vars(shipped))
    c2w.share_memory_()
    procs = [ctx.Process(target=_worker, daemon=True,
                         args=(shipped, c2w, weights, intrinsics, hair, block, threads,
                               counter, written, AHEAD * workers, results))
             for _ in range(workers - 1)]
    own_threads = torch.get_num_threads()
    done: dict[int, np.ndarray] = {}
    failed = None  # why the spawned processes are no longer used
    # Process.start() returns only once the child has read the renderer, which it does
    # after importing torch (seconds): started from a thread, this process renders
    # meanwhile
    starter = threading.Thread(target=_start, args=(procs,), daemon=True)
    try:
        starter.start()
        torch.set_num_threads(threads)
        for i in range(len(blocks)):
            while i not in done:
                if failed is not None:  # render what is left here, with every core
                    frames, points, decoded = _render_block(renderer, c2w, weights,
                                                            intrinsics, hair, blocks[i])
                    done[i] = frames
                    _count(counts, points, decoded)
                    break
                got = _poll(results, block=False)
                if got is None and render_here and len(done) < AHEAD:
                    j = _take(counter)  # nothing ready: render a block here
                    if j < len(blocks):
                        got = (j, *_render_block(renderer, c2w, weights, intrinsics, hair,
                                                 blocks[j]))
                if got is None:
                    got = _poll(results, block=True, procs=procs)
                if got is None or got[0] < 0:
                    failed = ("they ended without their frames" if got is None
                              else got[1].strip().splitlines()[-1])
                    _stop(starter, procs)
                    torch.set_num_threads(own_threads)
                    if counts is not None:
                        counts.setdefault("warnings", []).append(
                            f"a process rendering frames failed ({failed}); the rest "
                            f"were rendered in this process")
                    continue
                j, frames, points, decoded = got[:4]
                done[j] = frames
                _count(counts, points, decoded, spawned_blocks=int(len(got) > 4))
                if len(got) > 4 and counts is not None:  # (pid, its peak memory)
                    counts.setdefault("peaks", {})[got[4][0]] = got[4][1]
            yield from done.pop(i)
            written.value = i + 1
    finally:
        torch.set_num_threads(own_threads)
        _stop(starter, procs)
        results.close()


def _share(obj: Any) -> None:
    """Move the tensors in ``obj`` (a module, a dataclass, or containers of them) into
    shared memory, as pickling them for another process would."""
    import dataclasses

    import torch

    if isinstance(obj, torch.Tensor):
        obj.share_memory_()
    elif isinstance(obj, torch.nn.Module):
        obj.share_memory()
    elif isinstance(obj, dict):
        for v in obj.values():
            _share(v)
    elif isinstance(obj, list | tuple):
        for v in obj:
            _share(v)
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        _share(vars(obj))


def _start(procs) -> None:
    for p in procs:
        p.start()


def _stop(starter: threading.Thread, procs) -> None:
    """End the spawned processes (once they have all been started)."""
    starter.join()
    for p in procs:
        if p.pid is None:  # never started (starting it failed)
            continue
        if p.is_alive():
            p.terminate()
        p.join(timeout=5)


def _count(counts: dict[str, Any] | None, points: int, decoded: int,
           spawned_blocks: int = 0) -> None:
    if counts is not None:
        for key, add in (("points", points), ("decoded", decoded),
                         ("spawned_blocks", spawned_blocks)):
            counts[key] = counts.get(key, 0) + add


def _poll(results, block: bool, procs=()) -> tuple[Any, ...] | None:
    """The next finished block, or ``None`` if none is ready (``block=False``) or, when
    blocking, once every spawned process has ended without sending one."""
    if not block:
        try:
            return results.get_nowait()
        except queue_module.Empty:
            return None
    while True:
        try:
            return results.get(timeout=1.0)
        except queue_module.Empty:
            if all(p.exitcode is not None for p in procs):  # started, then ended
                return None

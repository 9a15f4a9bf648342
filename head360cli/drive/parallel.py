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
memory) and die with the caller. Spawning one costs seconds (it imports torch), so a
caller that knows early that it will render many frames starts them with :class:`Workers`
before it loads the head (as ``head360 animate`` does), and their start overlaps the
loading.
"""

from __future__ import annotations

import copy
import os
import pickle
import queue as queue_module
import traceback
from collections.abc import Iterator
from typing import Any

import numpy as np

from head360cli.devices import usable_cpus

__all__ = ["BLOCK", "MIN_FRAMES", "TAIL", "Workers", "auto_workers", "parallel_frames",
           "peak_rss_mib", "usable_cpus"]

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


def _threads(workers: int) -> int:
    """Torch threads for each of ``workers`` processes sharing the usable cores."""
    return max(1, usable_cpus() // workers)


def auto_workers(frames: int, device: str, cpus: int | None = None) -> int:
    """Processes for rendering ``frames`` frames: one per usable core (at most 4) on a
    CPU when there are at least :data:`MIN_FRAMES` frames, else 1."""
    if device != "cpu" or frames < MIN_FRAMES:
        return 1
    return max(1, min(4, usable_cpus() if cpus is None else cpus))


TAIL = 4
"""Frames per block over a take's last ``workers x block`` frames, so that the processes
finish within a few frames of each other rather than one waiting while another renders
a whole block (16 frames: 3 s of a turning head on one core)."""


def _blocks(n: int, size: int, workers: int) -> list[tuple[int, int]]:
    """``(first, end)`` frames of each block: ``size`` frames, then :data:`TAIL`."""
    tail = max(0, n - workers * size)
    small = min(size, TAIL)
    return ([(i, min(i + size, tail)) for i in range(0, tail, size)]
            + [(i, min(i + small, n)) for i in range(tail, n, small)])


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


def _take(counter, parent: int | None = None) -> int:
    """The next block's index, taken from the shared ``counter``; in a spawned process
    (``parent``: its parent's pid) the wait for the lock ends it once the parent is gone,
    which may have been killed holding it."""
    lock = counter.get_lock()
    while not lock.acquire(timeout=0.5):
        if parent is not None and os.getppid() != parent:
            _orphaned()
    try:
        i = counter.value
        counter.value += 1
    finally:
        lock.release()
    return i


def _orphaned() -> None:
    """End a spawned process whose parent is gone, at once: its results queue's thread
    could never hand its last block to anyone, and a normal exit waits for it."""
    os._exit(0)


def _worker(jobs, counter, written, results, parent: int) -> None:
    """A spawned process: import torch and the renderer's modules (the seconds a start
    costs), wait for the job (:meth:`Workers.send`), then render the blocks it takes until
    none is left, none more than the job's ``limit`` blocks beyond the ``written`` ones.
    It ends when ``parent``, the process that spawned it, is gone (killed before it
    could end it)."""
    import queue
    import time

    import torch

    import head360cli.model.head_render  # noqa: F401  (what unpickling the job needs)

    try:
        while True:
            try:
                job = jobs.get(timeout=0.5)
                break
            except queue.Empty:
                if os.getppid() != parent:
                    _orphaned()
        if job is None:  # closed unused
            return
        renderer, c2w, weights, intrinsics, hair, block, workers, limit = pickle.loads(job)
        del job  # the bytes: not needed once unpickled
        torch.set_num_threads(_threads(workers))
        blocks = _blocks(len(c2w), block, workers)
        while (i := _take(counter, parent)) < len(blocks):
            while i >= written.value + limit:
                if os.getppid() != parent:
                    _orphaned()
                time.sleep(0.005)
            made = _render_block(renderer, c2w, weights, intrinsics, hair, blocks[i])
            results.put((i, *made, (os.getpid(), peak_rss_mib())))
    except BaseException:  # reported to the caller, which renders the rest itself
        results.put((-1, traceback.format_exc(), 0, 0))


class Workers:
    """Processes spawned to render frames before the frames are known.

    Each imports torch at once and then waits for the job :func:`parallel_frames` sends
    it; the set serves one call of :func:`parallel_frames`, which closes it. A caller that
    will render a long take on a CPU starts them before loading the head, so that their
    start (seconds each) overlaps the loading; :meth:`close` ends them if they are not
    needed after all.

    Args:
        workers: Processes in all, the caller included (``workers - 1`` are spawned).
    """

    def __init__(self, workers: int) -> None:
        import multiprocessing

        if workers < 2:
            raise ValueError(f"expected at least 2 workers, found {workers}")
        ctx = multiprocessing.get_context("spawn")
        self.workers = workers
        self.procs = []
        self.closed = False
        self.error: str | None = None
        """Why the processes could not be started (they were ended), or ``None``."""
        try:
            self.counter = ctx.Value("i", 0)  # the next block not yet taken
            self.written = ctx.Value("i", 0)  # blocks yielded so far
            self.results = ctx.Queue()
            self.jobs = ctx.Queue()
        except OSError as exc:  # no POSIX semaphores: /dev/shm read-only or missing
            self.error = f"{type(exc).__name__}: {exc}"
            self.closed = True
            return
        self.procs = [ctx.Process(target=_worker, daemon=True, args=(
            self.jobs, self.counter, self.written, self.results, os.getpid()))
            for _ in range(workers - 1)]
        from head360cli.interrupts import sigint_ignored

        try:
            with sigint_ignored():  # Ctrl-C is this process's to handle: it ends them
                for p in self.procs:  # returns at once: the arguments are small
                    p.start()
        except Exception as exc:  # e.g. no more processes allowed: render without them
            self.error = f"{type(exc).__name__}: {exc}"
            self.close()

    def send(self, job: tuple[Any, ...]) -> None:
        """Give every process the job. It is pickled here, in the calling thread (a
        tensor's storage is moved into shared memory as it is pickled, which must not
        happen while another thread renders with it); the queue's thread only sends the
        bytes. One pickle per process: each carries its own file descriptors."""
        from multiprocessing.reduction import ForkingPickler

        for _ in self.procs:
            self.jobs.put(bytes(ForkingPickler.dumps(job)))

    def close(self) -> None:
        """End the processes, whatever they are doing."""
        if self.closed:
            return
        self.closed = True
        for p in self.procs:
            if p.pid is None:  # never started
                continue
            if p.is_alive():
                p.terminate()
            p.join(timeout=5)
        for q in (self.results, self.jobs):
            q.close()
            q.cancel_join_thread()


def parallel_frames(renderer, c2w, weights: np.ndarray, intrinsics, hair: bool = True,
                    workers: int = 2, counts: dict[str, Any] | None = None,
                    block: int = BLOCK, render_here: bool = True,
                    batch: int | None = None,
                    pool: Workers | None = None) -> Iterator[np.ndarray]:
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
        block: Frames per block (over the last ``workers x block`` frames,
            :data:`TAIL`).
        render_here: This process renders blocks too while it waits (with False it
            only collects and yields them).
        batch: Frames per generator call where this process renders alone (fewer than
            2 workers or blocks; the renderer's default for ``None``); several processes
            render one frame per call.
        pool: Processes started beforehand (their count replaces ``workers``); closed
            here, used or not. ``None``: they are started here.

    Yields:
        ``(H, W, 3)`` uint8 frames in order.

    If a spawned process fails (or cannot start), the others are stopped and this
    process renders the frames not yet made, with a line on it in ``counts["warnings"]``;
    an error of the frames themselves is then raised here, as one process would.
    """
    import torch

    n = len(c2w)
    if pool is not None:
        workers = pool.workers
    alone = workers < 2 or n <= block
    blocks = _blocks(n, block, workers)
    if counts is not None:
        counts["workers"] = 1 if alone else workers
    if alone:  # one process: one run, reuse over all frames
        if pool is not None:
            pool.close()
        for frames in renderer.frames(c2w, weights, intrinsics, hair=hair, batch=batch):
            yield from frames
        _count(counts, *_reuse_counts(renderer))
        return
    own_threads = torch.get_num_threads()
    threads = _threads(workers)
    done: dict[int, np.ndarray] = {}
    failed = None  # why the spawned processes are no longer used
    try:
        if pool is None:  # they import torch while this process renders
            pool = Workers(workers)
        if pool.error is None:
            try:
                c2w = _send(pool, renderer, c2w, weights, intrinsics, hair, block, workers)
                torch.set_num_threads(threads)
            except RuntimeError as exc:
                if "shared memory" not in str(exc):
                    raise
                # /dev/shm too small for the renderer's tensors (16 MiB failed here,
                # 64 did not; a container's may be small): this process renders
                pool.error = (f"no room in shared memory for the head ({_shm_size()}): "
                              f"{' '.join(str(exc).split())[:160]}")
                pool.close()
        if pool.error is not None:
            failed = _failed(counts, pool.error)
        for i in range(len(blocks)):
            while i not in done:
                if failed is not None:  # render what is left here, with every core
                    frames, points, decoded = _render_block(renderer, c2w, weights,
                                                            intrinsics, hair, blocks[i])
                    done[i] = frames
                    _count(counts, points, decoded)
                    break
                got = _poll(pool.results, block=False)
                if got is None and render_here and len(done) < AHEAD:
                    j = _take(pool.counter)  # nothing ready: render a block here
                    if j < len(blocks):
                        got = (j, *_render_block(renderer, c2w, weights, intrinsics, hair,
                                                 blocks[j]))
                if got is None:
                    got = _poll(pool.results, block=True, procs=pool.procs)
                if got is None or got[0] < 0:
                    failed = _failed(counts, "they ended without their frames"
                                     if got is None else got[1].strip().splitlines()[-1])
                    pool.close()
                    torch.set_num_threads(own_threads)
                    continue
                j, frames, points, decoded = got[:4]
                done[j] = frames
                _count(counts, points, decoded, spawned_blocks=int(len(got) > 4))
                if len(got) > 4 and counts is not None:  # (pid, its peak memory)
                    counts.setdefault("peaks", {})[got[4][0]] = got[4][1]
            yield from done.pop(i)
            if failed is None:
                pool.written.value = i + 1
    finally:
        torch.set_num_threads(own_threads)
        if pool is not None:
            pool.close()


def _send(pool: Workers, renderer, c2w, weights: np.ndarray, intrinsics, hair: bool,
          block: int, workers: int):
    """Give the spawned processes the job; returns ``c2w`` in shared memory.

    They get a copy of the renderer without its last run's reuse (which this process
    replaces as it renders) and without the bilinear model and float64 deltas it was
    made from, which frames do not read (74 MB pickled by value; 600 frames: peaks 663
    -> 595 MiB here, 623 -> 478 MiB in the spawned process); pickling it here moves its
    tensors into shared memory.

    Raises:
        RuntimeError: torch found no room in shared memory (``/dev/shm``).
    """
    c2w = c2w.detach().cpu().contiguous().share_memory_()
    weights = np.ascontiguousarray(weights, np.float32)
    shipped = copy.copy(renderer)
    shipped.last_reuse = shipped.model = shipped.deltas = None
    pool.send((shipped, c2w, weights, intrinsics, hair, block, workers, AHEAD * workers))
    return c2w


def _shm_size() -> str:
    """``/dev/shm``'s size, in words (``"/dev/shm holds 16 MiB"``)."""
    try:
        st = os.statvfs("/dev/shm")
    except OSError:
        return "no /dev/shm"
    return f"/dev/shm holds {st.f_blocks * st.f_frsize / 2**20:.0f} MiB"


def _failed(counts: dict[str, Any] | None, why: str) -> str:
    """Note in ``counts["warnings"]`` that the spawned processes failed; ``why``."""
    if counts is not None:
        counts.setdefault("warnings", []).append(
            f"a process rendering frames failed ({why}); the rest were rendered in this "
            f"process")
    return why


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

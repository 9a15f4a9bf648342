"""parallel_frames: the frames of several processes, in order, as one process makes them."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from head360cli.drive.parallel import MIN_FRAMES, Workers, auto_workers, parallel_frames
from head360cli.mesh.arkit52 import INDEX

# the job is sent by a queue's thread while this one renders: an error there (a race on
# the renderer's tensors, when it was pickled there, once crashed this file) fails the
# test, not just a warning
pytestmark = pytest.mark.filterwarnings(
    "error::pytest.PytestUnhandledThreadExceptionWarning")


@pytest.fixture(scope="module")
def renderer(head_file):
    from head360cli.fitting.pipeline import load_head_renderer

    return load_head_renderer(head_file, samples=4, size=64, precision="fp32")


def _weights(n):
    w = np.zeros((n, 52), np.float32)
    w[:, INDEX["jawOpen"]] = np.linspace(0.0, 0.6, n)
    w[:, INDEX["eyeBlinkLeft"]] = np.linspace(0.0, 1.0, n) ** 2
    return w


def _one_process(renderer, cams, w, k):
    return np.stack([f for batch in renderer.frames(cams, w, k) for f in batch])


def _turning(renderer, n, spread, pitch):
    """``(weights, intrinsics, cameras, one process's frames)`` of ``n`` frames whose
    camera turns from -``spread`` to ``spread`` degrees of yaw."""
    from head360cli.drive.views import view_cameras, view_intrinsics

    w, k = _weights(n), view_intrinsics(64)
    cams = view_cameras(np.linspace(-spread, spread, n), pitch)
    return w, k, cams, _one_process(renderer, cams, w, k)


@pytest.mark.slow
def test_spawned_processes_give_the_frames_of_one_process_in_order(renderer):
    from head360cli.drive.views import view_cameras

    n = 11
    w, k, moving, ref = _turning(renderer, n, 30.0, 5.0)
    counts = {}
    # every block rendered by the spawned process (blocks of 3: 4 blocks, the last short)
    got = np.stack(list(parallel_frames(renderer, moving, w, k, workers=2, block=3,
                                        counts=counts, render_here=False)))
    assert counts["spawned_blocks"] == 4
    assert got.shape == ref.shape == (n, 64, 64, 3)
    # the same frames (one torch thread there, two here: at most a level of rounding)
    assert np.abs(got.astype(int) - ref).max() <= 1
    assert np.abs(ref[-1].astype(int) - ref[0]).mean() > 1  # the frames differ
    # a still camera reuses decoded points within each block, so within the reuse
    # tolerance of one process's frames, which reuse across all of them
    still = view_cameras(20.0, 5.0).expand(n, 4, 4)
    ref = _one_process(renderer, still, w, k)
    counts = {}
    got = np.stack(list(parallel_frames(renderer, still, w, k, workers=2, block=4,
                                        counts=counts)))
    assert np.abs(got.astype(int) - ref).max() <= 2
    # a deferred generator decodes no points to count (a hex-plane one's reuse did)
    assert counts["decoded"] == counts["points"] == 0


def _explode():
    raise RuntimeError("this renderer cannot be loaded in another process")


class _LoadsNowhereElse:
    """Pickles, but fails to unpickle: a spawned process that cannot start."""

    def __reduce__(self):
        return (_explode, ())


@pytest.mark.slow
def test_a_process_that_fails_leaves_its_frames_to_this_one(renderer):
    import copy

    n = 7
    w, k, cams, ref = _turning(renderer, n, 20.0, 0.0)
    broken = copy.copy(renderer)
    broken.poison = _LoadsNowhereElse()
    counts = {}
    got = np.stack(list(parallel_frames(broken, cams, w, k, workers=2, block=2,
                                        counts=counts, render_here=False)))
    assert counts.get("spawned_blocks", 0) == 0
    assert "rest were rendered in this process" in counts["warnings"][0]
    assert np.abs(got.astype(int) - ref).max() <= 1
    # an error of the frames themselves: the spawned process fails, then this one
    # raises it as rendering alone would
    bad = np.zeros((n, 51), np.float32)
    with pytest.raises(Exception) as alone:
        _one_process(renderer, cams, bad, k)
    counts = {}
    with pytest.raises(type(alone.value)):
        list(parallel_frames(renderer, cams, bad, k, workers=2, block=2, counts=counts,
                             render_here=False))
    assert type(alone.value).__name__ in counts["warnings"][0]


@pytest.mark.slow
def test_animate_starts_the_processes_before_it_loads_the_head(renderer, tmp_path):
    import multiprocessing

    import imageio.v3 as iio

    from head360cli.drive.animate import AnimateConfig, animate
    from head360cli.io.arkit import ArkitStream

    n = 20  # two blocks
    stream = ArkitStream(_weights(n), np.arange(n) / 30.0, 30.0)
    started = []

    def load():
        started.append(len(multiprocessing.active_children()))
        return renderer

    res = animate(load, stream, tmp_path / "two", AnimateConfig(workers=2))
    assert started == [1] and res["workers"] == 2 and res["frames"] == n
    assert not multiprocessing.active_children()  # ended with the frames
    alone = animate(renderer, stream, tmp_path / "one", AnimateConfig(workers=1))
    assert alone["workers"] == 1
    two, one = (np.stack([iio.imread(p) for p in sorted((tmp_path / d).iterdir())])
                for d in ("two", "one"))
    assert two.shape == one.shape == (n, 64, 64, 3)
    # a still camera: reuse restarts with each block in the spawned process
    assert np.abs(two.astype(int) - one).max() <= 2

    def fails():
        raise RuntimeError("no such head")

    with pytest.raises(RuntimeError, match="no such head"):
        animate(fails, stream, tmp_path / "none", AnimateConfig(workers=2))
    assert not multiprocessing.active_children()  # ended, unused
    assert not (tmp_path / "none").exists()


def test_blocks_cover_the_frames_and_end_small():
    from head360cli.drive.parallel import TAIL, _blocks

    for n, size, workers in ((187, 16, 2), (64, 16, 4), (11, 3, 2), (5, 16, 2), (1, 16, 3)):
        blocks = _blocks(n, size, workers)
        assert [a for a, _ in blocks] == [0] + [b for _, b in blocks[:-1]]  # in order
        assert blocks[-1][1] == n and all(b > a for a, b in blocks)
        # the last workers x size frames go in blocks of at most TAIL
        assert all(b - a <= min(size, TAIL) for a, b in blocks if b > n - workers * size)
    assert [b - a for a, b in _blocks(187, 16, 2)] == [16] * 9 + [11] + [4] * 8


def test_workers_closed_unused_end():
    pool = Workers(3)
    procs = list(pool.procs)
    assert len(procs) == 2 and all(p.is_alive() for p in procs)
    pool.close()
    assert not any(p.is_alive() for p in procs)
    pool.close()  # twice: nothing more to do
    with pytest.raises(ValueError, match="at least 2"):
        Workers(1)


def test_processes_that_cannot_start_leave_the_frames_to_this_one(renderer, monkeypatch):
    import multiprocessing.context

    def refuse(self):
        raise OSError("Resource temporarily unavailable")

    monkeypatch.setattr(multiprocessing.context.SpawnProcess, "start", refuse)
    n = 6
    w, k, cams, ref = _turning(renderer, n, 20.0, 0.0)
    pool = Workers(2)
    assert pool.error == "OSError: Resource temporarily unavailable" and pool.closed
    counts = {}
    got = np.stack(list(parallel_frames(renderer, cams, w, k, workers=2, block=2,
                                        counts=counts)))
    assert "Resource temporarily unavailable" in counts["warnings"][0]
    assert counts.get("spawned_blocks", 0) == 0
    assert np.abs(got.astype(int) - ref).max() <= 1


def test_no_room_in_shared_memory_leaves_the_frames_to_this_one(renderer, monkeypatch):
    """A container's small /dev/shm (16 MiB, measured by mounting one): pickling the head
    for the spawned processes failed with torch's "unable to allocate shared memory",
    and ``animate`` of a long take stopped as an internal error. It renders alone."""
    from head360cli.drive import parallel

    def full(*args, **kwargs):
        raise RuntimeError("unable to allocate shared memory(shm) for file "
                           "</torch_1_2_3>: No space left on device (28)")

    monkeypatch.setattr(parallel.Workers, "send", full)
    n = 6
    w, k, cams, ref = _turning(renderer, n, 20.0, 0.0)
    counts = {}
    got = np.stack(list(parallel_frames(renderer, cams, w, k, workers=2, block=2,
                                        counts=counts)))
    assert np.abs(got.astype(int) - ref).max() <= 1
    assert counts.get("spawned_blocks", 0) == 0
    assert "no room in shared memory for the head (" in counts["warnings"][0]
    assert "No space left on device" in counts["warnings"][0]

    def other(*args, **kwargs):  # any other error is not taken for a full /dev/shm
        raise RuntimeError("a bug")

    monkeypatch.setattr(parallel.Workers, "send", other)
    with pytest.raises(RuntimeError, match="a bug"):
        list(parallel_frames(renderer, cams, w, k, workers=2, block=2))


def test_no_semaphores_leave_the_frames_to_this_one(renderer, monkeypatch):
    """A read-only /dev/shm (measured by mounting one; AWS Lambda has none): the
    processes' shared counter needs a POSIX semaphore there, and ``animate`` of a long
    take stopped with "Read-only file system (/dev/shm/pym-...): write elsewhere", exit
    3, as if the video could not be written. It renders alone."""
    import multiprocessing.context

    def no_semaphores(self, *args, **kwargs):
        raise OSError(30, "Read-only file system", "/dev/shm/pym-1-x")

    monkeypatch.setattr(multiprocessing.context.BaseContext, "Value", no_semaphores)
    pool = Workers(2)
    assert pool.closed and pool.procs == [] and "Read-only file system" in pool.error
    n = 6
    w, k, cams, ref = _turning(renderer, n, 20.0, 0.0)
    counts = {}
    got = np.stack(list(parallel_frames(renderer, cams, w, k, block=2, counts=counts,
                                        pool=pool)))
    assert np.abs(got.astype(int) - ref).max() <= 1
    assert "Read-only file system" in counts["warnings"][0]


def test_auto_workers():
    assert auto_workers(MIN_FRAMES - 1, "cpu", cpus=8) == 1  # too short to pay
    assert auto_workers(MIN_FRAMES, "cpu", cpus=2) == 2
    assert auto_workers(1000, "cpu", cpus=16) == 4
    assert auto_workers(1000, "cpu", cpus=1) == 1
    assert auto_workers(1000, "cuda", cpus=16) == 1  # a GPU batches frames instead


@pytest.mark.slow
def test_cli_animate_with_two_processes(run_cli, head_file, tmp_path):
    import imageio.v3 as iio

    from head360cli.io.arkit import ArkitStream, write_arkit_csv

    n = 20
    rot = np.zeros((n, 3), np.float32)
    rot[:, 0] = np.linspace(0.0, 0.4, n)
    write_arkit_csv(ArkitStream(_weights(n), np.arange(n) / 30.0, 30.0,
                                head_rotation=rot), tmp_path / "s.csv")
    got = {}
    for workers in (1, 2):
        out = tmp_path / f"w{workers}"
        r = run_cli("animate", head_file, "--arkit", tmp_path / "s.csv", "--head-pose",
                    "-o", out, "--size", "64", "--samples", "2", "--precision", "fp32",
                    "--workers", workers, "--json")
        assert r.code == 0, r.err
        res = json.loads(r.out)
        assert res["workers"] == workers and res["frames"] == n
        got[workers] = np.stack([iio.imread(p) for p in sorted(out.iterdir())])
    assert got[2].shape == (n, 64, 64, 3)
    assert np.abs(got[2].astype(int) - got[1]).max() <= 1
    r = run_cli("animate", head_file, "--arkit", tmp_path / "s.csv", "-o",
                tmp_path / "x.mp4", "--workers", "0")
    assert r.code == 3 and "--workers" in r.err and not (tmp_path / "x.mp4").exists()


def _gone(pid: int, seconds: float) -> bool:
    """Whether process ``pid`` ends (or is a zombie) within ``seconds``."""
    import time

    end = time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            with open(f"/proc/{pid}/stat") as f:
                if f.read().rsplit(")", 1)[1].split()[0] == "Z":
                    return True
        except FileNotFoundError:
            return True
        time.sleep(0.2)
    return False


@pytest.mark.skipif(not __import__("os").path.isdir("/proc"), reason="reads /proc")
def test_a_spawned_process_ends_when_its_parent_is_killed(tmp_path):
    """A parent killed without a chance to end its processes (SIGKILL, or SIGTERM before
    head360 handled it) left them waiting for a job, or for blocks to be written, for
    ever."""
    import subprocess
    import sys

    script = ("import os, sys\n"
              "from head360cli.drive.parallel import Workers\n"
              "pool = Workers(2)\n"
              "print(pool.procs[0].pid, flush=True)\n"
              "os._exit(0)  # as a kill: no clean-up at all\n")
    out = tmp_path / "pid.txt"  # not a pipe: the orphan would hold it open
    with open(out, "w") as f:
        p = subprocess.run([sys.executable, "-c", script], stdout=f, timeout=120)
    assert p.returncode == 0
    assert _gone(int(out.read_text().split()[0]), 60), "the orphaned process still runs"


@pytest.mark.slow
@pytest.mark.parametrize(("signame", "code", "says"), [("SIGTERM", 143, "terminated"),
                                                       ("SIGHUP", 129, "hung up")])
def test_cli_animate_terminated_leaves_no_output_and_no_processes(head_file, tmp_path,
                                                                  signame, code, says):
    """SIGTERM (kill, timeout, a batch system) killed head360 at once: the video's
    temporary file stayed beside the output and the spawned process kept running. So did
    SIGHUP (a closed terminal or ssh session) before 2026-12-05."""
    import signal
    import subprocess
    import sys
    import time

    from head360cli.io.arkit import ArkitStream, write_arkit_csv

    n = 3000  # far more than it renders before the signal
    write_arkit_csv(ArkitStream(_weights(n), np.arange(n) / 30.0, 30.0), tmp_path / "s.csv")
    out = tmp_path / "o" / "take.mp4"
    out.parent.mkdir()
    p = subprocess.Popen([sys.executable, "-m", "head360cli", "animate", str(head_file),
                          "--arkit", str(tmp_path / "s.csv"), "-o", str(out), "--size", "32",
                          "--samples", "2", "--workers", "2"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        end = time.monotonic() + 120
        while not any(out.parent.iterdir()) and time.monotonic() < end:  # rendering now
            time.sleep(0.1)
        assert any(out.parent.iterdir()), "the video was never started"
        with open(f"/proc/{p.pid}/task/{p.pid}/children") as f:
            children = [int(c) for c in f.read().split()]
        p.send_signal(getattr(signal, signame))
        _, err = p.communicate(timeout=60)
    finally:
        p.kill()
    assert p.returncode == code, err
    assert f"head360: {says}" in err
    assert list(out.parent.iterdir()) == []
    assert all(_gone(c, 30) for c in children)


@pytest.mark.slow
@pytest.mark.skipif(not os.path.exists("/proc/self/task"), reason="reads /proc")
@pytest.mark.parametrize("delay", [0.0, 0.1, 0.3, 0.6, 1.0, 1.5])
def test_ctrl_c_while_the_processes_start_is_one_line_and_exit_130(head_file, tmp_path,
                                                                     delay):
    """A terminal's Ctrl-C reaches the whole process group: a spawned process still
    importing torch printed a 17-line KeyboardInterrupt traceback of its own, or a stray
    "Process SpawnProcess-1:" line. The spawned processes leave SIGINT to head360,
    which says one line, exits 130 and ends them."""
    import signal
    import subprocess
    import sys
    import time

    from head360cli.io.arkit import ArkitStream, write_arkit_csv

    n = 3000
    write_arkit_csv(ArkitStream(_weights(n), np.arange(n) / 30.0, 30.0), tmp_path / "s.csv")
    out = tmp_path / "take.mp4"
    p = subprocess.Popen([sys.executable, "-m", "head360cli", "animate", str(head_file),
                          "--arkit", str(tmp_path / "s.csv"), "-o", str(out), "--size", "32",
                          "--samples", "2", "--workers", "2"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         start_new_session=True)  # its own group, as a terminal's job is
    try:
        end, children = time.monotonic() + 120, []
        while not children and time.monotonic() < end and p.poll() is None:
            with open(f"/proc/{p.pid}/task/{p.pid}/children") as f:
                children = [int(c) for c in f.read().split()]
            time.sleep(0.02)
        assert children, "no process was spawned"
        time.sleep(delay)  # the child is importing torch, or waiting for its job
        os.killpg(p.pid, signal.SIGINT)
        _, err = p.communicate(timeout=60)
    finally:
        p.kill()
    assert p.returncode == 130, err
    assert err == "head360: interrupted\n", err
    assert not out.exists()
    assert all(_gone(c, 30) for c in children)

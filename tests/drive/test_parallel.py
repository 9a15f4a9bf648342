"""parallel_frames: the frames of several processes, in order, as one process makes them."""

from __future__ import annotations

import json

import numpy as np
import pytest

from head360cli.drive.parallel import MIN_FRAMES, auto_workers, parallel_frames
from head360cli.mesh.arkit52 import INDEX

# the processes start from a thread while this one renders: an error there (a race on
# the renderer's tensors once crashed this file) fails the test, not just a warning
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
    assert 0 < counts["decoded"] < counts["points"]


def _explode():
    raise RuntimeError("this renderer cannot be loaded in another process")


class _LoadsNowhereElse:
    """Pickles, but fails to unpickle: a spawned process that cannot start."""

    def __reduce__(self):
        return (_explode, ())


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


def test_auto_workers():
    assert auto_workers(MIN_FRAMES - 1, "cpu", cpus=8) == 1  # too short to pay
    assert auto_workers(MIN_FRAMES, "cpu", cpus=2) == 2
    assert auto_workers(1000, "cpu", cpus=16) == 4
    assert auto_workers(1000, "cpu", cpus=1) == 1
    assert auto_workers(1000, "cuda", cpus=16) == 1  # a GPU batches frames instead


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

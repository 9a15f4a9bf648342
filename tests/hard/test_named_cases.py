"""Named hard cases next to the property tests: a camera that sees nothing, the smallest and
an oversized image, a very long stream."""

from __future__ import annotations

import numpy as np
import pytest
import torch


def looking_away(yaw: float = 0.0) -> torch.Tensor:
    """A camera at the usual distance whose rays all miss the head (turned around)."""
    from head360cli.drive.views import view_cameras

    c2w = view_cameras(yaw, 0.0).clone()
    c2w[:, :3, 0] *= -1  # turn about the camera's y axis: still a rotation
    c2w[:, :3, 2] *= -1
    return c2w


def test_rays_that_all_miss_give_a_blank_frame(head_file):
    from head360cli.drive.views import view_intrinsics
    from head360cli.fitting.pipeline import load_head_renderer

    r = load_head_renderer(head_file, samples=2, size=32, precision="fp32")
    img = r.render(looking_away(), view_intrinsics(32), np.zeros(52))
    assert torch.isfinite(img).all()
    assert img.min() > 0.97  # white background, nothing drawn


def test_smallest_image_renders_and_oversized_is_refused(run_cli, head_file, tmp_path):
    from PIL import Image

    out = tmp_path / "s.png"
    assert run_cli("render", head_file, "--size", "32", "--samples", "2", "-o", out).code == 0
    assert Image.open(out).size == (32, 32)
    r = run_cli("render", head_file, "--size", "4096", "-o", tmp_path / "h.png")
    assert r.code == 3 and "--size" in r.err and not (tmp_path / "h.png").exists()
    r = run_cli("render", head_file, "--size", "33", "-o", tmp_path / "o.png")
    assert r.code == 3 and not (tmp_path / "o.png").exists()


@pytest.mark.slow
def test_very_long_stream_reads_and_resamples(tmp_path):
    """An hour at 10 frames per second (36,000 rows) reads, cuts and resamples."""
    from head360cli.drive.animate import AnimateConfig, prepare_stream
    from head360cli.io.arkit import ArkitStream, read_arkit_csv, write_arkit_csv

    n = 36_000
    rng = np.random.default_rng(0)
    w = rng.uniform(0, 1, (n, 52)).astype(np.float32)
    path = tmp_path / "long.csv"
    write_arkit_csv(ArkitStream(w, np.arange(n) / 10.0, 10.0), path)
    s = read_arkit_csv(path)
    assert s.weights.shape == (n, 52) and np.isfinite(s.weights).all()
    np.testing.assert_allclose(s.weights, w, atol=1e-4)
    np.testing.assert_allclose(s.timestamps, np.arange(n) / 10.0, atol=1e-3)  # 10 fps kept
    cut = prepare_stream(s, AnimateConfig(fps=5.0, start=3500.0))
    assert cut.num_frames in (499, 500) and cut.fps == 5.0
    assert np.isfinite(cut.weights).all() and cut.timestamps[0] == 0.0  # from the cut
    np.testing.assert_allclose(cut.weights[0], w[35_000], atol=1e-4)  # row at 3500 s

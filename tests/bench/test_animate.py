"""``head360 bench animate``'s image-size sweep on a sampled head (tiny sizes)."""

from __future__ import annotations

import numpy as np

from head360cli.bench.animate import _resolution


def test_resolution_sweep_scores_each_size_twice(head_file):
    weights = np.zeros((3, 52), np.float32)
    weights[1, 24] = 1.0  # jawOpen on one frame
    rows = _resolution(head_file, weights, sizes=(32, 64), samples=4)
    assert [r["size"] for r in rows] == [32, 64]
    for r in rows:
        assert r["fps"] > 0 and r["ms_per_frame"] > 0 and r["samples"] == 4
        assert 15.0 < r["psnr_vs_32_samples_same_size"] < 120.0
        assert 10.0 < r["psnr_vs_32_samples_64px"] < 120.0
    # at the largest size the two scores are the same comparison (upsampling is identity)
    assert rows[1]["psnr_vs_32_samples_64px"] == rows[1]["psnr_vs_32_samples_same_size"]
    # 32 pixels upsampled lose detail the 64-pixel render keeps
    assert rows[0]["psnr_vs_32_samples_64px"] < rows[1]["psnr_vs_32_samples_64px"]

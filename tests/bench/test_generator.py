"""``head360 bench generator`` on a tiny trained generator: metrics, rows and the sweep."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from head360cli.bench.generator import bench_generator, fit_code, psnr, ssim
from head360cli.model.data import Views
from head360cli.model.train import CHECKPOINT, TrainConfig, load_generator, save_generator, train
from tests.model.test_generator import TINY


def _tiny(folder, cfg, name):
    train(folder / name, TrainConfig(identities=2, steps=4, batch=2, log_every=2), cfg,
          progress=False)
    save_generator(folder / name / CHECKPOINT, folder / f"{name}.pt")
    return folder / f"{name}.pt"


@pytest.fixture(scope="module")
def tiny_weights(tmp_path_factory):
    """A tiny deferred generator (the default kind), trained for 4 steps."""
    return _tiny(tmp_path_factory.mktemp("bench"), TINY, "tiny")


@pytest.fixture(scope="module")
def tiny_hexplane_weights(tmp_path_factory):
    """A tiny hex-plane generator, trained for 4 steps."""
    import dataclasses

    return _tiny(tmp_path_factory.mktemp("bench"), dataclasses.replace(
        TINY, renderer="hexplane"), "hex")


def test_psnr_and_ssim_golden_values():
    truth = torch.full((3, 16, 16), 0.5)
    assert psnr(truth + 0.1, truth) == pytest.approx(20.0, abs=1e-4)  # MSE 0.01
    mask = torch.zeros(1, 16, 16)
    mask[:, :8] = 1
    pred = truth.clone()
    pred[:, 8:] += 0.3  # errors only outside the mask
    assert psnr(pred, truth, mask) == pytest.approx(120.0, abs=1e-3)  # the 1e-12 floor
    assert psnr(pred, truth) == pytest.approx(-10 * math.log10(0.045), abs=1e-4)
    assert ssim(truth, truth) == pytest.approx(1.0, abs=1e-9)
    assert ssim(pred, truth) < 0.99


@pytest.mark.slow
def test_fit_code_lowers_the_image_error(tiny_weights):
    gen, codes = load_generator(tiny_weights)
    views = Views(1, "test", 0, TINY.image_res)
    batch = views.render(0, np.zeros(52, np.float32), views.rig[24:48:3])

    def error(code):
        with torch.no_grad():
            out = gen(batch.verts, batch.c2w, batch.intrinsics,
                      code=code[None].expand(len(batch.c2w), -1))
        return float((out["rgb"] - batch.rgb).abs().mean())

    start = codes.mean(0)
    fitted = fit_code(gen, views, 0, start, steps=15, lr=0.1)
    assert error(fitted) < error(start)
    assert not any(p.requires_grad for p in gen.parameters())


@pytest.mark.slow
def test_bench_rows_for_several_weights_and_the_sweep(tiny_weights, tiny_hexplane_weights,
                                                     tmp_path):
    """A deferred and a hex-plane generator compared in one run (and a copy of the
    first, which scores the same); the speed sweep is the first's: samples a pixel."""
    other = tmp_path / "other.pt"
    other.write_bytes(tiny_weights.read_bytes())
    result, md = bench_generator([str(tiny_weights), str(other), str(tiny_hexplane_weights)],
                                 train_ids=1, test_ids=1, fit_steps=2, cameras=2)
    views = [(r["model"], r["views"]) for r in result["quality"]]
    names = ["bald, held-out views", "hair, held-out views", "hair swap",
             "held-out ids, bald", "held-out ids, hair", "held-out ids + texture, bald",
             "held-out ids + texture, hair"]
    assert views == [(m, v) for m in ("tiny", "other", "hex") for v in names]
    for row in result["quality"]:
        assert row["n"] == 2 and 3 < row["psnr"] < 60 and -1 <= row["ssim"] <= 1
    # The same weights score the same on the same views.
    n = len(names)
    assert result["quality"][:n] == [{**r, "model": "tiny"} for r in result["quality"][n:2 * n]]
    sweep = result["sweep"]
    assert sweep[0]["pixel_samples"] == TINY.pixel_samples
    assert sorted(r["pixel_samples"] for r in sweep) == [1, 2, 4]
    assert all(r["ms_bald"] > 0 and r["ms_hair"] > 0 for r in sweep)
    assert "hair swap" in md and "Speed against quality" in md and "deferred" in md
    json.dumps(result)


def test_cli_rejects_bad_counts(run_cli, tmp_path):
    done = run_cli("bench", "generator", "--cameras", "30", "--out", tmp_path)
    assert done.code != 0 and "--cameras" in done.err and not list(tmp_path.iterdir())

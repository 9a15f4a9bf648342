"""``head360 bench generator``: novel-view quality and speed of the trained generator.

- Held-out views of training identities: the generator with each identity's training code,
  from 24 cameras between the training rig's (yaw 7.5 + 15 k, pitch +-10 degrees), neutral
  and with one random expression; PSNR and SSIM at the training resolution against the
  corpus renderer's image (bald heads: the head branch).
- Held-out identities (SynHead-P test split): the texture code fitted with the generator
  frozen to eight rig views, then the same 24 held-out cameras.
- Speed of one frame on this machine, and how speed and PSNR trade as the samples per ray
  and the hex-plane resolution change.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np
import torch

__all__ = ["bench_generator", "fit_code", "psnr", "ssim"]


def psnr(pred: torch.Tensor, truth: torch.Tensor, mask: torch.Tensor | None = None) -> float:
    """PSNR (dB) of images in [0, 1], ``(3, H, W)``; within ``mask (1, H, W)`` if given."""
    err = (pred.clamp(0, 1) - truth).square()
    mse = err.mean() if mask is None else (err * mask).sum() / (3 * mask.sum()).clamp_min(1)
    return float(10 * torch.log10(1.0 / mse.clamp_min(1e-12)))


def ssim(pred: torch.Tensor, truth: torch.Tensor) -> float:
    """SSIM of ``(3, H, W)`` images in [0, 1] (scikit-image, Gaussian window)."""
    from skimage.metrics import structural_similarity

    a = pred.clamp(0, 1).permute(1, 2, 0).numpy().astype(np.float64)
    b = truth.permute(1, 2, 0).numpy().astype(np.float64)
    return float(structural_similarity(a, b, channel_axis=2, data_range=1.0,
                                       gaussian_weights=True, sigma=1.5))


def _score(gen, views, index: int, code: torch.Tensor, rng: np.random.Generator
           ) -> list[dict[str, float]]:
    from head360cli.model.data import eval_cameras, sample_expression

    c2w, _, _ = eval_cameras()
    rows = []
    for weights in (np.zeros(52, np.float32), sample_expression(rng, p_neutral=0.0)):
        batch = views.render(index, weights, c2w)
        with torch.no_grad():
            out = gen(batch.verts, batch.c2w, batch.intrinsics,
                      code=code[None].expand(len(c2w), -1))
        for i in range(len(c2w)):
            mask = ((batch.alpha[i] > 0) | (out["alpha"][i] > 0.5)).float()
            rows.append({"psnr": psnr(out["rgb"][i], batch.rgb[i]),
                         "psnr_head": psnr(out["rgb"][i], batch.rgb[i], mask),
                         "ssim": ssim(out["rgb"][i], batch.rgb[i])})
    return rows


def fit_code(gen, views, index: int, start: torch.Tensor, steps: int = 100,
             lr: float = 0.02, cameras: int = 8, seed: int = 0) -> torch.Tensor:
    """A held-out head's texture code, fitted with the generator frozen to ``cameras``
    rig views of its neutral face (L1 on the image and the low-resolution colour)."""
    from head360cli.geometry.cameras import rig72

    rig, _, _ = rig72()
    pick = torch.linspace(0, 23, cameras).round().long() + 24  # pitch 0, around the head
    batch = views.render(index, np.zeros(52, np.float32), rig[pick])
    code = start.clone().requires_grad_(True)
    opt = torch.optim.Adam([code], lr=lr)
    gen.requires_grad_(False)
    g = torch.Generator().manual_seed(seed)
    for _ in range(steps):
        sel = torch.randperm(cameras, generator=g)[:4]
        out = gen(batch.verts[sel], batch.c2w[sel], batch.intrinsics,
                  code=code[None].expand(len(sel), -1))
        res = out["rgb_low"].shape[-1]
        low = torch.nn.functional.interpolate(batch.rgb[sel], size=(res, res), mode="area")
        loss = (out["rgb"] - batch.rgb[sel]).abs().mean() + 0.5 * (
            out["rgb_low"] - low).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return code.detach()


def _mean(rows: list[dict[str, float]]) -> dict[str, float]:
    return {k: round(float(np.mean([r[k] for r in rows])), 3) for k in rows[0]}


def _frame_time(gen, batch, repeats: int = 3) -> float:
    times = []
    with torch.no_grad():
        gen(batch.verts[:1], batch.c2w[:1], batch.intrinsics,
            code=torch.zeros(1, gen.cfg.code_dim))  # warm-up
        for _ in range(repeats):
            t0 = time.perf_counter()
            gen(batch.verts[:1], batch.c2w[:1], batch.intrinsics,
                code=torch.zeros(1, gen.cfg.code_dim))
            times.append(time.perf_counter() - t0)
    return min(times)


def bench_generator(weights: str | None = None, train_ids: int = 8, test_ids: int = 4,
                    fit_steps: int = 100, seed: int = 0, device: str = "cpu"
                    ) -> tuple[dict[str, Any], str]:
    """Run the benchmark; returns ``(result, markdown)``."""
    from head360cli.bench.report import machine, markdown_table
    from head360cli.model.data import Views, eval_cameras
    from head360cli.model.generator import Generator
    from head360cli.model.train import load_generator

    gen, codes = load_generator(weights)
    cfg = gen.cfg
    rng = np.random.default_rng(seed)
    train_views = Views(train_ids, "train", 0, cfg.image_res)
    seen = []
    for i in range(train_ids):
        seen += _score(gen, train_views, i, codes[i], rng)
    test_views = Views(test_ids, "test", 0, cfg.image_res)
    unseen = []
    fit_seconds = 0.0
    for i in range(test_ids):
        test_views.head(i)  # build the synthetic head outside the timing
        t0 = time.perf_counter()
        code = fit_code(gen, test_views, i, codes.mean(0), steps=fit_steps, seed=seed)
        fit_seconds += (time.perf_counter() - t0) / test_ids
        unseen += _score(gen, test_views, i, code, rng)
    quality = [{"views": "held-out views, training identities", "n": len(seen),
                **_mean(seen)},
               {"views": "held-out identities (code fitted)", "n": len(unseen),
                **_mean(unseen)}]
    # Speed against quality: samples per ray and plane resolution, on identity 0.
    c2w, _, _ = eval_cameras()
    batch = train_views.render(0, np.zeros(52, np.float32), c2w[::3])
    sweep = []
    settings = dict.fromkeys(((max(cfg.samples // 2, 1), cfg.plane_res),
                              (cfg.samples, cfg.plane_res), (2 * cfg.samples, cfg.plane_res),
                              (cfg.samples, cfg.plane_res // 2),
                              (cfg.samples, cfg.plane_res * 2)))
    for samples, plane_res in settings:
        variant = Generator(dataclasses.replace(cfg, samples=samples, plane_res=plane_res),
                            gen.faces.numpy(), gen.uv.numpy(), gen.faces_uv.numpy())
        variant.load_state_dict(gen.state_dict())
        variant.eval()
        with torch.no_grad():
            out = variant(batch.verts, batch.c2w, batch.intrinsics,
                          code=codes[0][None].expand(len(batch.c2w), -1))
        score = np.mean([psnr(out["rgb"][i], batch.rgb[i]) for i in range(len(batch.c2w))])
        sweep.append({"samples": samples, "plane_res": plane_res,
                      "psnr": round(float(score), 2),
                      "frame_ms": round(1000 * _frame_time(variant, batch), 1)})
    frame_ms = next(r["frame_ms"] for r in sweep if r["samples"] == cfg.samples
                    and r["plane_res"] == cfg.plane_res)
    result = {"machine": machine(), "config": cfg.to_dict(), "quality": quality,
              "code_fit_seconds": round(fit_seconds, 1), "frame_ms": frame_ms,
              "sweep": sweep}
    md = (f"### Generator: novel views at {cfg.image_res}x{cfg.image_res} (bald heads)\n\n"
          + markdown_table(quality, ["views", "n", "psnr", "psnr_head", "ssim"])
          + f"\n\nPSNR over the whole image (white background) and inside the head "
          f"(psnr_head). Held-out identities: code fitted in {fit_seconds:.0f} s each "
          f"({fit_steps} steps, 8 views).\n\n### Speed against quality\n\n"
          + markdown_table(sweep, list(sweep[0]))
          + f"\n\nOne frame: {frame_ms} ms on this machine's CPU.")
    return result, md

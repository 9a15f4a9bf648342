"""``head360 bench generator``: novel-view quality, hair swap and speed of trained generators.

Every score compares the generator's 256x256 image with the corpus renderer's image of the
same head, expression and camera, from held-out cameras (:func:`eval_cameras`: between the
training rig's, yaw 7.5 + 15 k, pitch +-10 degrees; every third of them by default, so the
views go all around the head). Each head gets one random expression (or neutral).

Rows, per weights file:

- ``bald, held-out views``: training identities, their training codes, no hair (the head
  branch alone).
- ``hair, held-out views``: the same heads with their own hair (the composite).
- ``hair swap``: training identity A with another identity's hairstyle k, in A's hair
  colour, against the corpus render of A with k (the paper's Table 3). The generator gets the
  hairstyle's mesh fitted to A and the style and colour codes; A with k never appears in
  training.
- ``held-out ids, bald`` / ``held-out ids, hair``: heads of the test split; their texture
  code fitted with the generator frozen to bald rig views of the neutral face
  (:func:`fit_code`), then scored like the training identities.
- ``held-out ids + texture, bald`` / ``hair``: the same, with the neural texture itself
  then fitted to those views as a fit does (:func:`fit_texture`), for either generator.

The speed sweep (first weights file only) times one frame on this machine and changes the
samples per ray and the feature-plane resolution of hex-plane weights, or the samples per
pixel of deferred ones.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

__all__ = ["bench_generator", "fit_code", "psnr", "score_views", "ssim"]


def psnr(pred: torch.Tensor, truth: torch.Tensor, mask: torch.Tensor | None = None) -> float:
    """PSNR (dB) of images in [0, 1], ``(3, H, W)``; within ``mask (1, H, W)`` if given."""
    err = (pred.clamp(0, 1) - truth).square()
    mse = err.mean() if mask is None else (err * mask).sum() / (3 * mask.sum()).clamp_min(1)
    return float(10 * torch.log10(1.0 / mse.clamp_min(1e-12)))


def ssim(pred: torch.Tensor, truth: torch.Tensor) -> float:
    """SSIM of ``(3, H, W)`` images in [0, 1] (scikit-image, Gaussian window)."""
    from skimage.metrics import structural_similarity

    a = pred.detach().clamp(0, 1).permute(1, 2, 0).cpu().numpy().astype(np.float64)
    b = truth.permute(1, 2, 0).cpu().numpy().astype(np.float64)
    return float(structural_similarity(a, b, channel_axis=2, data_range=1.0,
                                       gaussian_weights=True, sigma=1.5))


def score_views(gen, batch, code: torch.Tensor, hair: bool) -> list[dict[str, float]]:
    """PSNR over the image and inside the head, and SSIM, of one rendered batch against
    its targets; ``code (code_dim,)``, or a neural texture ``(C, R, R)``."""
    n = len(batch.c2w)
    given = ({"texture": code[None].expand(n, -1, -1, -1)} if code.ndim == 3 else
             {"code": code[None].expand(n, -1)})
    with torch.no_grad():
        out = gen(batch.verts, batch.c2w, batch.intrinsics, **given,
                  hair=batch.hair if hair else None)
    rows = []
    for i in range(len(batch.c2w)):
        mask = ((batch.alpha[i] > 0) | (out["alpha"][i] > 0.5)).float()
        rows.append({"psnr": psnr(out["rgb"][i], batch.rgb[i]),
                     "psnr_head": psnr(out["rgb"][i], batch.rgb[i], mask),
                     "ssim": ssim(out["rgb"][i], batch.rgb[i])})
    return rows


def _fit_views(views, index: int, cameras: int):
    """``cameras`` bald rig views (pitch 0, around the head) of held-out head ``index``'s
    neutral face: what :func:`fit_code` and :func:`fit_texture` fit to."""
    from head360cli.geometry.cameras import rig72

    rig, _, _ = rig72()
    pick = torch.linspace(0, 23, cameras).round().long() + 24
    return views.render(index, np.zeros(52, np.float32), rig[pick])


def _fit(gen, batch, param: torch.Tensor, given, steps: int, lr: float, per_step: int,
         seed: int, low_weight: float) -> torch.Tensor:
    """Adam on ``param`` with the generator frozen: ``given(param, n)`` is the generator's
    code or texture keyword for ``n`` views; L1 on the image (and, weighted by
    ``low_weight``, on the low-resolution colour), ``per_step`` of the views a step."""
    param = param.clone().requires_grad_(True)
    opt = torch.optim.Adam([param], lr=lr)
    gen.requires_grad_(False)
    g = torch.Generator().manual_seed(seed)
    for _ in range(steps):
        sel = torch.randperm(len(batch.c2w), generator=g)[:per_step]
        out = gen(batch.verts[sel], batch.c2w[sel], batch.intrinsics,
                  **given(param, len(sel)))
        loss = (out["rgb"] - batch.rgb[sel]).abs().mean()
        if low_weight:
            res = out["rgb_low"].shape[-1]
            low = torch.nn.functional.interpolate(batch.rgb[sel], size=(res, res),
                                                  mode="area")
            loss = loss + low_weight * (out["rgb_low"] - low).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return param.detach()


def fit_code(gen, views, index: int, start: torch.Tensor, steps: int = 40,
             lr: float = 0.03, cameras: int = 8, per_step: int = 2,
             seed: int = 0) -> torch.Tensor:
    """A held-out head's texture code, fitted with the generator frozen to ``cameras``
    bald rig views of its neutral face (L1 on the image and on the low-resolution colour,
    ``per_step`` views a step)."""
    return _fit(gen, _fit_views(views, index, cameras), start,
                lambda c, n: {"code": c[None].expand(n, -1)}, steps, lr, per_step, seed,
                0.5)


def fit_texture(gen, views, index: int, code: torch.Tensor, steps: int = 40,
                lr: float = 0.02, cameras: int = 8, per_step: int = 2,
                seed: int = 0) -> torch.Tensor:
    """A held-out head's neural texture ``(C, R, R)``, started from ``code``'s and fitted
    with the generator frozen to the same views as :func:`fit_code` (L1)."""
    with torch.no_grad():
        start = gen.texture(code[None])[0]
    return _fit(gen, _fit_views(views, index, cameras), start,
                lambda t, n: {"texture": t[None].expand(n, -1, -1, -1)}, steps, lr,
                per_step, seed, 0.0)


def _mean(rows: list[dict[str, float]]) -> dict[str, float]:
    return {k: round(float(np.mean([r[k] for r in rows])), 3) for k in rows[0]}


def _frame_time(gen, batch, code: torch.Tensor, hair: bool, repeats: int = 3) -> float:
    """Best-of-``repeats`` seconds for one frame (after a warm-up call)."""
    def once() -> float:
        t0 = time.perf_counter()
        gen(batch.verts[:1], batch.c2w[:1], batch.intrinsics, code=code[None],
            hair=_first(batch.hair) if hair else None)
        if batch.verts.is_cuda:
            torch.cuda.synchronize()
        return time.perf_counter() - t0

    with torch.no_grad():
        once()
        return min(once() for _ in range(repeats))


def _first(hair):
    from head360cli.model.generator import Hair

    return Hair(hair.meshes[:1], hair.style[:1], hair.colour[:1])


def _speed_settings(gen) -> list[dict[str, int]]:
    """The settings the speed sweep renders the same weights with, the shipped one first:
    samples per ray and plane resolution (hex-plane), samples per pixel (deferred)."""
    cfg = gen.cfg
    if gen.kind == "deferred":
        return [{"pixel_samples": s} for s in dict.fromkeys((cfg.pixel_samples, 1, 2, 4))]
    pairs = dict.fromkeys(((cfg.samples, cfg.plane_res),
                           (max(cfg.samples // 2, 1), cfg.plane_res),
                           (max(cfg.samples // 4, 1), cfg.plane_res),
                           (2 * cfg.samples, cfg.plane_res),
                           (cfg.samples, cfg.plane_res // 2),
                           (cfg.samples, cfg.plane_res * 2)))
    return [{"samples": s, "plane_res": r} for s, r in pairs]


def _variant(gen, change: dict[str, int]):
    """A generator of ``gen``'s weights with its config changed by ``change``."""
    from head360cli.model.train import build_generator

    variant = build_generator(dataclasses.replace(gen.cfg, **change))
    variant.load_state_dict(gen.state_dict())
    return variant


def _setting(cfg) -> str:
    """The shipped render setting in words."""
    if cfg.renderer == "deferred":
        return (f"deferred, {cfg.pixel_samples} samples a pixel, texture "
                f"{cfg.texture_res}x{cfg.texture_res}")
    return (f"{cfg.samples} samples per ray, planes {cfg.plane_res}x{cfg.plane_res}, "
            f"features rendered at {cfg.render_res}x{cfg.render_res}")


def _swap_style(index: int, own: int, styles: int) -> int:
    """A hairstyle other than ``own``, spread over the styles by identity."""
    return (own + 1 + (7 * index) % (styles - 1)) % styles


def bench_generator(weights: list[str | None] | None = None, train_ids: int = 6,
                    test_ids: int = 2, fit_steps: int = 40, cameras: int = 8,
                    speed: bool = True, seed: int = 0, device: str = "cpu",
                    progress: bool = False) -> tuple[dict[str, Any], str]:
    """Score each weights file and time the first; returns ``(result, markdown)``.

    Args:
        weights: Weights files (``None``: ``models/generator.pt``); labelled by file stem.
        train_ids: Training identities scored on held-out views and hair swap.
        test_ids: Held-out identities (0 skips the code fitting).
        fit_steps: Code-fitting steps per held-out identity.
        cameras: Held-out cameras per head (spread over the 24 of :func:`eval_cameras`).
        speed: Time frames and sweep samples and plane resolution (first weights only).
        seed: Expression seed.
        device: Where the generators and the corpus renderer run.
        progress: Print one line per model and row to stderr.
    """
    import sys

    from head360cli.bench.report import machine, markdown_table
    from head360cli.model.data import Views, eval_cameras, sample_expression
    from head360cli.model.train import load_generator

    weights = list(weights or [None])
    all_cams, _, _ = eval_cameras()
    cams = all_cams[torch.linspace(0, 23, cameras).round().long()]
    rows: list[dict[str, Any]] = []
    views_cache: dict[tuple, Views] = {}
    fit_seconds = []
    first = None

    def say(text: str) -> None:
        if progress:
            print(text, file=sys.stderr, flush=True)

    for path in weights:
        label = "generator" if path is None else Path(path).stem
        gen, codes = load_generator(path, device=device)
        gen.eval()
        cfg = gen.cfg
        key = (cfg.image_res,)
        if key not in views_cache:
            views_cache[key] = (Views(train_ids, "train", 0, cfg.image_res, device=device),
                                Views(test_ids, "test", 0, cfg.image_res, device=device))
        train_views, test_views = views_cache[key]
        if first is None:
            first = (gen, codes, train_views)
        rng = np.random.default_rng(seed)
        exprs = [sample_expression(rng, p_neutral=0.3) for _ in range(train_ids + test_ids)]
        found: dict[str, list] = {"bald, held-out views": [], "hair, held-out views": [],
                                  "hair swap": []}
        for i in range(train_ids):
            code = codes[i]
            found["bald, held-out views"] += score_views(
                gen, train_views.render(i, exprs[i], cams), code, hair=False)
            if cfg.hair:
                head = train_views.head(i)
                found["hair, held-out views"] += score_views(
                    gen, train_views.render(i, exprs[i], cams, with_hair=True), code, True)
                k = _swap_style(i, head.hair_style, cfg.hair_styles)
                swapped = train_views.render(i, exprs[i], cams, with_hair=True, style=k,
                                             colour=head.hair_colour)
                found["hair swap"] += score_views(gen, swapped, code, True)
            say(f"{label}: training identity {i + 1}/{train_ids}")
        if test_ids:
            for name in ("held-out ids", "held-out ids + texture"):
                found[f"{name}, bald"], found[f"{name}, hair"] = [], []
        for i in range(test_ids):
            test_views.head(i)  # build the synthetic head outside the timing
            t0 = time.perf_counter()
            code = fit_code(gen, test_views, i, codes.mean(0), steps=fit_steps, seed=seed)
            fit_seconds.append(time.perf_counter() - t0)
            texture = fit_texture(gen, test_views, i, code, steps=fit_steps, seed=seed)
            e = exprs[train_ids + i]
            for name, fitted in (("held-out ids", code), ("held-out ids + texture", texture)):
                found[f"{name}, bald"] += score_views(
                    gen, test_views.render(i, e, cams), fitted, hair=False)
                if cfg.hair:
                    found[f"{name}, hair"] += score_views(
                        gen, test_views.render(i, e, cams, with_hair=True), fitted, True)
            say(f"{label}: held-out identity {i + 1}/{test_ids} (code and texture fitted)")
        for name, got in found.items():
            if got:
                rows.append({"model": label, "views": name, "n": len(got), **_mean(got)})
    result: dict[str, Any] = {"machine": machine(), "device": device, "cameras": cameras,
                              "train_ids": train_ids, "test_ids": test_ids,
                              "fit_steps": fit_steps, "quality": rows}
    if fit_seconds:
        result["code_fit_seconds"] = round(float(np.mean(fit_seconds)), 1)
    md = ("### Generator: novel views at 256x256 against the corpus renderer\n\n"
          + markdown_table(rows, ["model", "views", "n", "psnr", "psnr_head", "ssim"])
          + "\n\nPSNR (dB) over the whole image (white background) and inside the head "
          "(psnr_head, where either image covers it); n views.")
    if fit_seconds:
        md += (f" Held-out identities: code fitted in {result['code_fit_seconds']} s each "
               f"({fit_steps} steps, 2 of 8 bald rig views a step); with '+ texture', "
               f"then their texture, as many steps.")
    if speed:
        gen, codes, train_views = first
        cfg = gen.cfg
        # The first scored identity that has hair (style 0 is bald), so both are timed.
        who = next((i for i in range(train_ids)
                    if len(train_views.head(i).hair.faces)), 0)
        batches = {hair: train_views.render(who, np.zeros(52, np.float32), cams,
                                            with_hair=hair)
                   for hair in ((False, True) if cfg.hair else (False,))}
        sweep = []
        for change in _speed_settings(gen):
            variant = _variant(gen, change).to(device).eval()
            row: dict[str, Any] = dict(change)
            for hair, batch in batches.items():
                got = score_views(variant, batch, codes[who], hair)
                tag = "hair" if hair else "bald"
                row[f"psnr_{tag}"] = round(float(np.mean([r["psnr"] for r in got])), 2)
                row[f"ms_{tag}"] = round(1000 * _frame_time(variant, batch, codes[who], hair),
                                         1)
            sweep.append(row)
            say(f"speed: {change}: {row}")
        result["sweep"] = sweep
        result["frame_ms"] = {k[3:]: v for k, v in sweep[0].items() if k.startswith("ms_")}
        where = "GPU" if device.startswith("cuda") else "CPU"
        md += (f"\n\n### Speed against quality ({Path(weights[0] or 'generator').stem}, "
               f"{where}, identity {who}, one frame)\n\n"
               + markdown_table(sweep, list(sweep[0]))
               + f"\n\nShipped setting: {_setting(cfg)}; one frame "
               + ", ".join(f"{v} ms {k}" for k, v in result["frame_ms"].items())
               + f" on this machine's {where} ({machine()['torch_threads']} threads).")
    return result, md

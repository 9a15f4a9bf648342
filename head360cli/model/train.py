"""Training the generator on SynHead-P: auto-decoded texture codes, an L1 photometric loss
at both resolutions, coverage (mask) and hair-coverage losses, and a code prior.

Hair detachment: a share of the views are rendered bald and supervise the head branch
alone; the others, with their hair, supervise the composite. Without detachment every view
has its hair, so nothing says what the head looks like under it.

Adam with a short warm-up and a cosine decay, gradients clipped; a step whose loss is not
finite is skipped rather than applied.

Resumable (``checkpoint.pt`` in the run folder holds everything: configs, weights, codes,
optimiser, step, random states; Ctrl-C or SIGTERM in a one-process run checkpoints the
step it is on before stopping), logged (``log.jsonl``, one line per logged step, trimmed
to the checkpoint's step on resuming),
deterministic for a seed and a process count, and data parallel under ``torchrun`` (gloo on
CPU, NCCL on GPUs): every process draws its own views, gradients are averaged.
"""

from __future__ import annotations

import dataclasses
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from head360cli.interrupts import catch_interrupts, restore_handlers
from head360cli.io.jsontext import dumps
from head360cli.model.config import GeneratorConfig
from head360cli.model.generator import Generator

__all__ = ["TrainConfig", "build_generator", "load_generator", "read_checkpoint",
           "save_generator", "train"]

CHECKPOINT = "checkpoint.pt"
WEIGHTS_FORMAT = 1


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """How to train."""

    identities: int = 100
    """SynHead-P training heads (the first ones of the train split)."""
    seed: int = 0
    """Seed of the corpus, the initialisation and the view sampling."""
    steps: int = 3000
    """Optimiser steps (each process renders ``batch`` views per step)."""
    minutes: float = 0.0
    """Stop after this many minutes of training (0: no limit), for equal-budget runs."""
    batch: int = 4
    """Views per step and process."""
    lr: float = 2e-3
    """Adam learning rate of the networks."""
    code_lr: float = 1e-2
    """Adam learning rate of the texture codes."""
    code_prior: float = 1e-3
    """Weight of the squared norm of the codes."""
    low_res_weight: float = 0.5
    """Weight of the L1 loss on the volume-rendered colour (before the RefineNet)."""
    mask_weight: float = 0.5
    """Weight of the L1 loss on the coverage."""
    hair_weight: float = 0.5
    """Weight of the L1 loss on the hair coverage (with detachment only)."""
    detach: bool = True
    """Hair detachment: render a share of the views bald (see ``bald_share``)."""
    bald_share: float = 0.5
    """With detachment, the probability that a view is rendered bald."""
    featured_share: float = 0.25
    """Share of expressions with a blink, both blinks or ``jawOpen`` pushed to 0.7-1 on top
    (``data.FEATURED``): uniform random expressions rarely close the eyes."""
    warmup: int = 100
    """Steps of linear learning-rate warm-up."""
    final_lr: float = 0.1
    """Learning rate at the last step, as a fraction of the initial one (cosine decay)."""
    clip: float = 1.0
    """Gradient-norm clipping."""
    group: int = 1
    """Views per head in a batch (rendered together: faster data, less variety)."""
    workers: int = 1
    """Processes that build the corpus heads before training starts."""
    log_every: int = 25
    """Steps between log lines."""
    checkpoint_every: int = 200
    """Steps between checkpoints."""
    init: str = ""
    """Generator weights (``save_generator``'s file) to start a new run from instead of a
    random initialisation: the networks and the training codes (``""``: none). The
    generator configuration is then the weights' own."""
    skin_scan: str = ""
    """Folder of a head scan whose skin detail the corpus heads take (``""``: painted
    noise, the corpus the shipped generator was trained on)."""
    soft_hair: bool = False
    """Train on soft hairlines; the generator then records it
    (``GeneratorConfig.soft_hair``) and fits its hair so at run time."""
    residual_weight: float = 0.1
    """Deferred generator: weight of the shader's mean absolute residual (the colour its
    light does not explain), so that the albedo channels carry the colour."""
    albedo_weight: float = 1.0
    """Deferred generator: weight of the L1 loss between the neural texture's first three
    channels and the corpus head's albedo atlas (what makes them albedo, so a fit can
    write a photo's colours there)."""

    def __post_init__(self) -> None:
        """Refuse settings no run can train with (the CLI checks its options first, with
        their own names; this guards library callers and resumed checkpoints).

        Raises:
            BadInputError: The first field out of range, expected against found.
        """
        import math

        from head360cli.errors import BadInputError

        def bad(name: str, expected: str) -> BadInputError:
            return BadInputError(f"expected TrainConfig.{name} {expected}, found "
                                 f"{getattr(self, name)!r}")

        for name in ("identities", "batch", "group", "workers", "log_every",
                     "checkpoint_every"):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 1):
                raise bad(name, ">= 1")
        for name in ("steps", "warmup", "seed"):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 0):
                raise bad(name, ">= 0")
        for name in ("lr", "code_lr", "clip"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise bad(name, "finite and > 0")
        for name in ("minutes", "code_prior", "low_res_weight", "mask_weight",
                     "hair_weight", "albedo_weight", "residual_weight"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise bad(name, "finite and >= 0")
        for name in ("bald_share", "featured_share", "final_lr"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise bad(name, "in [0, 1]")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


class _Model(nn.Module):
    """The generator and the training identities' texture codes, trained together."""

    def __init__(self, gen: Generator, identities: int) -> None:
        super().__init__()
        self.generator = gen
        self.codes = nn.Parameter(torch.randn(identities, gen.cfg.code_dim) * 0.01)

    def forward(self, batch, jitter: bool = True):
        hair = batch.hair if self.generator.cfg.hair else None
        # each identity's texture made once, however many of its views the batch holds
        ids, inverse = torch.unique(batch.identity, return_inverse=True)
        texture = self.generator.texture(self.codes[ids])[inverse]
        return self.generator(batch.verts, batch.c2w, batch.intrinsics, texture=texture,
                              hair=hair, jitter=jitter)


def build_generator(cfg: GeneratorConfig) -> nn.Module:
    """A generator of ``cfg`` (deferred or hex-plane) on the head template's topology,
    its weights freshly initialised."""
    from head360cli.synth.sculpt import topology

    topo = topology()
    if cfg.renderer == "deferred":
        from head360cli.model.deferred import DeferredGenerator

        ears = [topo.part_names.index(n) for n in ("ear_l", "ear_r")]
        return DeferredGenerator(cfg, topo.faces, topo.uv, topo.faces_uv,
                                 topo.normal_groups, np.isin(topo.face_parts, ears))
    if cfg.renderer != "hexplane":
        raise ValueError(f"expected renderer deferred or hexplane, found {cfg.renderer!r}")
    return Generator(cfg, topo.faces, topo.uv, topo.faces_uv)


def losses(out: dict[str, torch.Tensor], batch, cfg: TrainConfig) -> dict[str, torch.Tensor]:
    """The training losses (and their weighted sum under ``total``)."""
    res = out["rgb_low"].shape[-1]
    rgb_low = F.interpolate(batch.rgb, size=(res, res), mode="area")
    alpha_low = F.interpolate(batch.alpha, size=(res, res), mode="area")
    parts = {"l1": (out["rgb"] - batch.rgb).abs().mean(),
             "l1_low": (out["rgb_low"] - rgb_low).abs().mean(),
             "mask": (out["alpha"] - batch.alpha).abs().mean()
             + (out["alpha_low"] - alpha_low).abs().mean()}
    parts["total"] = (parts["l1"] + cfg.low_res_weight * parts["l1_low"]
                      + cfg.mask_weight * parts["mask"])
    if "residual" in out and cfg.residual_weight > 0:
        parts["residual"] = out["residual"]
        parts["total"] = parts["total"] + cfg.residual_weight * parts["residual"]
    if batch.albedo is not None and cfg.albedo_weight > 0:
        res = batch.albedo.shape[-1]
        tex = out["texture"][:, :3]
        if tex.shape[-1] != res:
            tex = F.interpolate(tex, size=(res, res), mode="area")
        parts["albedo"] = (tex - batch.albedo).abs().mean()
        if batch.hair_albedo is not None and "hair_texture" in out and \
                bool(batch.with_hair.any()):
            worn = batch.with_hair
            parts["albedo"] = parts["albedo"] + (
                out["hair_texture"][worn, :3] - batch.hair_albedo[worn]).abs().mean()
        parts["total"] = parts["total"] + cfg.albedo_weight * parts["albedo"]
    if cfg.detach:
        parts["hair"] = (out["hair_alpha"] - batch.hair_alpha).abs().mean()
        parts["total"] = parts["total"] + cfg.hair_weight * parts["hair"]
    return parts


def learning_rate_scale(step: int, cfg: TrainConfig, elapsed: float = 0.0) -> float:
    """Multiplier of the learning rates at ``step`` (warm-up, then cosine decay over the
    steps, or over the minutes when those run out first)."""
    import math

    if step < cfg.warmup:
        return (step + 1) / cfg.warmup
    frac = min(1.0, (step - cfg.warmup) / max(1, cfg.steps - cfg.warmup))
    if cfg.minutes > 0:
        frac = max(frac, min(1.0, elapsed / (60.0 * cfg.minutes)))
    return cfg.final_lr + (1.0 - cfg.final_lr) * 0.5 * (1.0 + math.cos(math.pi * frac))


def _dist() -> tuple[int, int]:
    """``(rank, world)``; starts the process group under torchrun."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world > 1 and not torch.distributed.is_initialized():
        # HEAD360_DIST_BACKEND=gloo lets several processes share one GPU.
        backend = os.environ.get("HEAD360_DIST_BACKEND") or (
            "nccl" if torch.cuda.is_available() else "gloo")
        torch.distributed.init_process_group(backend)
    rank = torch.distributed.get_rank() if world > 1 else 0
    return rank, world


def train(out: str | Path, cfg: TrainConfig | None = None,
          gen_cfg: GeneratorConfig | None = None, device: str = "cpu",
          progress: bool = True, stop_at: int | None = None) -> dict[str, Any]:
    """Train (or resume) a run in folder ``out``; returns the last logged metrics.

    ``stop_at`` ends this call after that step with a checkpoint, as an interruption
    would; the learning-rate schedule still runs to ``cfg.steps``."""
    cfg = cfg or TrainConfig()
    gen_cfg = gen_cfg or GeneratorConfig()
    from head360cli.model.data import Views
    from head360cli.progress import progress_bar

    owned = not torch.distributed.is_initialized()  # a group _dist starts, train ends
    rank, world = _dist()
    if world > 1 and device.startswith("cuda"):
        device = f"cuda:{int(os.environ.get('LOCAL_RANK', '0'))}"
    out = Path(out)
    ckpt_path = out / CHECKPOINT
    start = 0
    state = None
    if ckpt_path.is_file():  # resume: the checkpoint's configs win
        state = read_checkpoint(ckpt_path)
        cfg = dataclasses.replace(TrainConfig(**state["train_config"]), steps=cfg.steps,
                                  minutes=cfg.minutes)
        gen_cfg = GeneratorConfig.from_dict(state["generator_config"])
        start = int(state["step"])
    init = None
    if state is None and cfg.init:
        init, gen_cfg = _read_weights(cfg.init)
        if init["codes"].shape[0] != cfg.identities:
            raise ValueError(f"{cfg.init}: expected codes for {cfg.identities} identities, "
                             f"found {init['codes'].shape[0]}")
    if state is None:  # the hair meshes at run time are those it learns from
        gen_cfg = dataclasses.replace(gen_cfg, soft_hair=cfg.soft_hair)
    torch.manual_seed(cfg.seed)
    model = _Model(build_generator(gen_cfg), cfg.identities).to(device)
    if init is not None:
        model.generator.load_state_dict(init["generator"])
        with torch.no_grad():
            model.codes.copy_(init["codes"])
    opt = torch.optim.Adam([
        {"params": model.generator.parameters(), "lr": cfg.lr},
        {"params": [model.codes], "lr": cfg.code_lr}])
    rng = np.random.default_rng([cfg.seed, rank])
    if state is not None:
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        rng.bit_generator.state = state["rng"][rank] if rank < len(state["rng"]) else \
            rng.bit_generator.state
        torch.set_rng_state(state["torch_rng"])
    run = model
    if world > 1:  # a bald-only step leaves the hair branch without gradients
        run = nn.parallel.DistributedDataParallel(model, find_unused_parameters=gen_cfg.hair)
    views = Views(cfg.identities, "train", cfg.seed, gen_cfg.image_res, device=device,
                  skin_scan=cfg.skin_scan, soft_hair=gen_cfg.soft_hair,
                  albedo_res=(min(gen_cfg.texture_res, 256) if gen_cfg.renderer == "deferred"
                              and cfg.albedo_weight > 0 else 0),
                  hair_albedo_res=(gen_cfg.hair_texture_res if gen_cfg.renderer == "deferred"
                                   and cfg.albedo_weight > 0 and gen_cfg.hair else 0))
    bald_share = cfg.bald_share if (cfg.detach and gen_cfg.hair) else (
        0.0 if gen_cfg.hair else 1.0)
    base_lrs = [cfg.lr, cfg.code_lr]
    if rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    views.prefetch(cfg.workers)
    t0 = time.perf_counter()
    last: dict[str, Any] = {"step": start}  # what a resumed run that is done returns
    sums: dict[str, float] = {}
    count = skipped = 0
    bar = progress_bar(range(start, cfg.steps), total=cfg.steps - start, desc="train",
                       enabled=progress and rank == 0)
    step = start
    if rank == 0:
        _trim_log(out / "log.jsonl", start)
    # Ctrl-C or SIGTERM (one process): finish the step, log and checkpoint it, then stop as
    # the signal asks; a second one stops at once (the last checkpoint stays).
    interrupted: list[int] = []
    previous = catch_interrupts(interrupted) if world == 1 else {}
    try:
        for step in bar:
            batch = views.sample(rng, cfg.batch, bald_share, cfg.group,
                                 cfg.featured_share).to(device)
            scale = learning_rate_scale(step, cfg, time.perf_counter() - t0)
            for group, lr in zip(opt.param_groups, base_lrs, strict=True):
                group["lr"] = lr * scale
            output = run(batch, jitter=True)
            parts = losses(output, batch, dataclasses.replace(
                cfg, detach=cfg.detach and gen_cfg.hair))
            total = parts["total"] + cfg.code_prior * model.codes[batch.identity].square().sum(
                1).mean()
            opt.zero_grad(set_to_none=True)
            total.backward()
            norm = nn.utils.clip_grad_norm_(model.parameters(), cfg.clip)
            parts["grad_norm"] = norm
            if torch.isfinite(total) and torch.isfinite(norm):
                opt.step()
                for k, v in parts.items():  # the logged means are over the steps taken
                    sums[k] = sums.get(k, 0.0) + v.item()
                count += 1
            else:
                skipped += 1
                for k in parts:
                    sums.setdefault(k, 0.0)
            done = step + 1
            elapsed = time.perf_counter() - t0
            stop = ((cfg.minutes > 0 and elapsed > 60.0 * cfg.minutes) or done == stop_at
                    or bool(interrupted))
            if world > 1:  # every process stops at the same step
                flag = torch.tensor([float(stop)], device=device)
                torch.distributed.all_reduce(flag, op=torch.distributed.ReduceOp.MAX)
                stop = bool(flag.item())
            if done % cfg.log_every == 0 or done == cfg.steps or stop:
                last = {"step": done, "seconds": round(elapsed, 1), "skipped": skipped,
                        "lr": round(opt.param_groups[0]["lr"], 7),
                        **{k: round(v / count, 5) if count else None for k, v in sums.items()}}
                sums, count = {}, 0
                if rank == 0:
                    with open(out / "log.jsonl", "a") as f:
                        f.write(dumps(last) + "\n")
            if done % cfg.checkpoint_every == 0 or done == cfg.steps or stop:
                _checkpoint(out, model, opt, cfg, gen_cfg, done, rng, world, rank)
            if stop:
                break
    finally:
        restore_handlers(previous)
    if interrupted:
        import signal

        signal.raise_signal(interrupted[0])  # handled as it would have been, now saved
    if world > 1:
        torch.distributed.barrier()
    if world > 1 and owned:
        # left to the interpreter's exit, gloo's threads were sometimes torn down while
        # busy: "terminate called without an active exception" (SIGABRT) after a run
        # that had finished and checkpointed, one CI run in many
        torch.distributed.destroy_process_group()
    return last


def _trim_log(path: Path, step: int) -> None:
    """Drop the lines of a resumed run's log past its checkpoint's ``step`` (logged, then
    interrupted before the next checkpoint: the resumed run logs those steps again), and
    a last line cut off mid-write."""
    import json

    if not path.is_file():
        return
    kept = []
    for line in path.read_text().splitlines():
        try:
            logged = json.loads(line)["step"]
        except (ValueError, KeyError, TypeError):
            continue
        if logged <= step:
            kept.append(line)
    from head360cli.io.atomic import atomic_path

    with atomic_path(path) as tmp:
        tmp.write_text("".join(f"{line}\n" for line in kept))


def _checkpoint(out, model, opt, cfg, gen_cfg, step, rng, world, rank) -> None:
    """Write the resumable checkpoint (rank 0), with every process's sampler state."""
    from head360cli.io.atomic import atomic_path

    states = [rng.bit_generator.state]
    if world > 1:
        gathered: list[Any] = [None] * world
        torch.distributed.all_gather_object(gathered, states[0])
        states = gathered
    if rank != 0:
        return
    state = {"format": "head360-train", "step": step, "train_config": cfg.to_dict(),
             "generator_config": gen_cfg.to_dict(), "model": model.state_dict(),
             "optimizer": opt.state_dict(), "rng": states, "torch_rng": torch.get_rng_state()}
    with atomic_path(out / CHECKPOINT) as tmp:
        torch.save(state, tmp)


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """A training checkpoint (:data:`CHECKPOINT`), loaded without running any code it may
    carry: only tensors, numbers, strings and containers are read (``weights_only``).

    Raises:
        FileFormatError: The file does not load that way (not a torch file, truncated, or
            a pickle that would run code: :func:`~head360cli.io.torchfile.load_data`), or
            is not a head360 training checkpoint.
    """
    from head360cli.errors import FileFormatError
    from head360cli.io.torchfile import load_data

    state = load_data(path, "a head360 training checkpoint")
    if not isinstance(state, dict) or state.get("format") != "head360-train":
        found = state.get("format") if isinstance(state, dict) else type(state).__name__
        raise FileFormatError(f"{path}: expected a head360 training checkpoint, found "
                              f"{found!r}")
    return state


def save_generator(checkpoint: str | Path, path: str | Path) -> dict[str, Any]:
    """Write the shippable weights (generator, training codes, configs) from a training
    checkpoint; returns a summary."""
    from head360cli.io.atomic import atomic_path

    state = read_checkpoint(checkpoint)
    model = {k: v.to(torch.float32) if v.is_floating_point() else v
             for k, v in state["model"].items()}
    weights = {"format": "head360-generator", "format_version": WEIGHTS_FORMAT,
               "generator_config": state["generator_config"],
               "train_config": state["train_config"], "step": state["step"],
               "generator": {k[len("generator."):]: v for k, v in model.items()
                             if k.startswith("generator.")},
               "codes": model["codes"]}
    with atomic_path(path) as tmp:
        torch.save(weights, tmp)
    return {"path": str(path), "bytes": Path(path).stat().st_size, "step": state["step"]}


def load_generator(path: str | Path | None = None, device: str = "cpu"
                   ) -> tuple[Generator, torch.Tensor]:
    """The shipped generator and its training identities' texture codes.

    Raises:
        ModelNotFoundError: No weights at ``path`` (default ``models/generator.pt``).
        FileFormatError: Not head360 generator weights.
    """
    from head360cli.errors import FileFormatError
    from head360cli.paths import installed_generator

    path = installed_generator(path)
    w, cfg = _read_weights(path)
    try:
        gen = build_generator(cfg)
        gen.load_state_dict(w["generator"])
    except (KeyError, RuntimeError) as exc:  # missing, extra or mis-shaped tensors
        raise FileFormatError(f"{path}: expected head360 generator weights ({exc})") from exc
    return gen.to(device).eval(), w["codes"].to(device)


def _read_weights(path: str | Path) -> tuple[dict, GeneratorConfig]:
    """The dictionary of a generator weights file and its generator config.

    Raises:
        FileFormatError: The file does not load, or is not head360 generator weights.
    """
    from head360cli.errors import FileFormatError
    from head360cli.io.torchfile import load_data

    w = load_data(path, "head360 generator weights")
    if not isinstance(w, dict) or w.get("format") != "head360-generator":
        found = w.get("format") if isinstance(w, dict) else type(w).__name__
        raise FileFormatError(f"{path}: expected head360 generator weights, found "
                              f"{found!r}")
    missing = {"generator", "codes", "generator_config"} - set(w)
    if missing:
        raise FileFormatError(f"{path}: expected head360 generator weights, found no "
                              f"{sorted(missing)}")
    try:
        cfg = GeneratorConfig.from_dict(w["generator_config"])
    except (KeyError, TypeError, ValueError) as exc:
        raise FileFormatError(f"{path}: expected head360 generator weights ({exc!r})"
                              ) from exc
    tensors = {**w["generator"], "codes": w["codes"]} if isinstance(w["generator"], dict) \
        else {}
    bad = [name for name, value in tensors.items() if isinstance(value, torch.Tensor)
           and value.is_floating_point() and not bool(torch.isfinite(value).all())]
    if bad:  # a run that diverged: every render would be NaN, shown as black
        raise FileFormatError(f"{path}: expected finite generator weights, found NaN or "
                              f"infinity in {', '.join(bad[:3])}"
                              f"{f' and {len(bad) - 3} more' if len(bad) > 3 else ''}")
    return w, cfg

"""Random heads drawn from the model.

Shape codes come from the bilinear model's identity prior (a Gaussian with the training
identities' mean and covariance), texture codes from a Gaussian fitted to the generator's
training codes (the texture generator was trained on those, not on a unit Gaussian), and
the hair from the 30 styles and 10 colours of SynHead-P. A sampled head is an ordinary
head file: it renders, animates, swaps hair and exports like a fitted one.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["sample_heads", "sample_names", "write_samples"]


def _gaussian(rng: np.random.Generator, mean: np.ndarray, cov: np.ndarray, scale: float
              ) -> np.ndarray:
    cov = np.asarray(cov, np.float64)
    ridge = 1e-6 * max(float(np.trace(cov)) / len(cov), 1e-12)
    chol = np.linalg.cholesky(cov + ridge * np.eye(len(cov)))
    return np.asarray(mean, np.float64) + scale * chol @ rng.standard_normal(len(cov))


def sample_heads(n: int, seed: int = 0, scale: float = 1.0, bald: bool = False,
                 device: str = "cpu", lids: bool = True) -> list[Any]:
    """``n`` random :class:`~head360cli.io.headfile.HeadFile` heads, the same for the same
    ``seed``; ``scale`` shrinks (< 1) or widens the spread around the mean head. With
    ``lids``, each gets the texture change that closes its eyelids as it blinks
    (:func:`~head360cli.fitting.lids.close_lids`, about 1 s a head on 2 CPU cores)."""
    import torch

    from head360cli.errors import BadInputError
    from head360cli.fitting.lids import head_lids
    from head360cli.io.headfile import HeadFile, lid_change_arrays
    from head360cli.mesh.bilinear import load_bilinear
    from head360cli.model.train import load_generator
    from head360cli.paths import generator_hash
    from head360cli.synth.hair import HAIR_COLOURS, HAIRSTYLES

    if n < 1:
        raise BadInputError(f"expected at least 1 head, found {n}")
    if not (np.isfinite(scale) and 0 <= scale <= 3):
        raise BadInputError(f"expected a spread between 0 and 3, found {scale}")
    model = load_bilinear()
    gen, codes = load_generator(device=device)
    c = codes.detach().cpu().double().numpy()
    code_mean, code_cov = c.mean(0), np.cov(c, rowvar=False)
    rng = np.random.default_rng(seed)
    colours = list(HAIR_COLOURS)
    model_hash = generator_hash()
    heads = []
    for _ in range(n):
        shape = _gaussian(rng, model.code_mean, model.code_cov, scale)
        code = _gaussian(rng, code_mean, code_cov, scale)
        style = 0 if bald else int(rng.integers(1, len(HAIRSTYLES)))
        colour = colours[int(rng.integers(len(colours)))]
        with torch.no_grad():
            tex = gen.texture(torch.tensor(code, dtype=torch.float32, device=codes.device
                                           )[None])[0]
        extra = {}
        if lids:
            extra = lid_change_arrays(head_lids(gen, model, shape, tex).change.cpu().numpy())
        heads.append(HeadFile(
            arrays={"shape": shape.astype(np.float32), "expression": np.zeros(52, np.float32),
                    "texture": tex.cpu().numpy().astype(np.float32),
                    "texture_code": code.astype(np.float32),
                    "hair_style": np.array(style, np.int64),
                    "hair_color": np.asarray(HAIR_COLOURS[colour], np.float32),
                    "vertices": model.vertices(shape, np.zeros(52)).astype(np.float32),
                    **extra},
            model_hash=model_hash,
            info={"sampled": {"seed": seed, "scale": scale},
                  "hair_style_name": HAIRSTYLES[style].name, "hair_color_name": colour,
                  "bilinear_model": model.meta["sha256"]}))
    return heads


def write_samples(heads: list[Any], out_dir: str | Path, prefix: str = "sample"
                  ) -> list[Path]:
    """Write heads as ``<prefix>_000.h360`` ... into ``out_dir`` (made if missing).

    Raises:
        ValueError: No heads (nothing would be written, not even the folder).
    """
    from head360cli.io.headfile import write_head

    if not len(heads):
        raise ValueError("expected at least one head to write, found none")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = sample_names(len(heads), out, prefix)
    for head, p in zip(heads, paths, strict=True):
        write_head(head, p)
    return paths


def sample_names(count: int, out_dir: str | Path, prefix: str = "sample") -> list[Path]:
    """The files :func:`write_samples` writes ``count`` heads to: ``<prefix>_000.h360``..."""
    return [Path(out_dir) / f"{prefix}_{i:03d}.h360" for i in range(count)]

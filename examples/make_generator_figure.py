"""Regenerate examples/figures/generator_views.png, the README's novel-view grid.

Training identity 2 of SynHead-P from six held-out cameras around the head (between the
training rig's), each pair of rows the corpus renderer's image (ground truth) above the
shipped generator's (``models/generator.pt``): bald (the head branch), with its own hair,
and with another identity's hairstyle in its own hair colour (a hair swap the generator
never saw). Run from the repository root (about a minute on 2 CPU cores):

    python examples/make_generator_figure.py
"""

from __future__ import annotations

from pathlib import Path

import cv2
import imageio.v3 as iio
import numpy as np
import torch

from head360cli.bench.generator import psnr
from head360cli.model.data import Views, eval_cameras
from head360cli.model.train import load_generator

OUT = Path("examples/figures/generator_views.png")
IDENTITY, SWAP_STYLE = 2, 17
TILE, MARGIN = 192, 150


def _tile(image: torch.Tensor, note: str = "") -> np.ndarray:
    rgb = (image.clamp(0, 1).permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
    rgb = cv2.resize(rgb, (TILE, TILE), interpolation=cv2.INTER_AREA)
    if note:
        cv2.putText(rgb, note, (6, TILE - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (40, 40, 40),
                    1, cv2.LINE_AA)
    return rgb


def _label(text: str) -> np.ndarray:
    pad = np.full((TILE, MARGIN, 3), 255, np.uint8)
    for k, line in enumerate(text.split("\n")):
        cv2.putText(pad, line, (8, TILE // 2 - 10 + 20 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                    (0, 0, 0), 1, cv2.LINE_AA)
    return pad


def main() -> None:
    gen, codes = load_generator()
    views = Views(IDENTITY + 1, "train", 0, gen.cfg.image_res)
    head = views.head(IDENTITY)
    cams = eval_cameras()[0][torch.tensor([0, 4, 8, 12, 16, 20])]
    neutral = np.zeros(52, np.float32)
    rows = []
    cases = [("bald", {}), ("own hair", {"with_hair": True}),
             (f"hairstyle {SWAP_STYLE}", {"with_hair": True, "style": SWAP_STYLE,
                                          "colour": head.hair_colour})]
    for name, kwargs in cases:
        batch = views.render(IDENTITY, neutral, cams, **kwargs)
        with torch.no_grad():
            out = gen(batch.verts, batch.c2w, batch.intrinsics,
                      code=codes[IDENTITY][None].expand(len(cams), -1),
                      hair=batch.hair if kwargs else None)
        truth = [_tile(batch.rgb[i]) for i in range(len(cams))]
        made = [_tile(out["rgb"][i], f"{psnr(out['rgb'][i], batch.rgb[i]):.1f} dB")
                for i in range(len(cams))]
        rows.append(np.hstack([_label(f"{name}\nground truth"), *truth]))
        rows.append(np.hstack([_label(f"{name}\ngenerator"), *made]))
    OUT.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(OUT, np.vstack(rows), optimize=True)
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()

"""Regenerate ``examples/figures/parse_profiles.png``: ``parse-hair`` on faces in profile.

Five held-out heads of corpus seed 1 (development heads, not the bench's), seen from 65
or 90 degrees to either side on a plain backdrop at 256 pixels; each row shows the
render, the parse without looking for a face in profile (the face taken for hair), the
parse with OpenCV's profile cascade (hair red, face blue; the default since 2026-12-04) and
the true hair. The last row is a miss: the cascade finds about half of the faces turned
90 degrees, and where it finds none the parse is as before. Tiles at 160 pixels; the
hair IoUs are printed.

Run from the repository root (about 20 s on 2 CPU cores):

    python examples/make_profile_figure.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

FIGURE = Path("examples/figures/parse_profiles.png")

VIEWS = ((3, 65.0), (6, -90.0), (10, 90.0), (14, -65.0), (7, -90.0))
"""(held-out head, yaw in degrees) of each row."""

TILE = 160


def _overlay(rgb: np.ndarray, hair: np.ndarray, face: np.ndarray) -> np.ndarray:
    out = rgb.astype(np.float32)
    out[hair] = 0.45 * out[hair] + 0.55 * np.array([235, 40, 40])
    out[face] = 0.6 * out[face] + 0.4 * np.array([40, 90, 235])
    return out.round().astype(np.uint8)


def main() -> None:
    import torch

    from head360cli.fitting.hair_parse import mask_iou, parse_hair
    from head360cli.geometry.cameras import RIG_DISTANCE, camera_on_sphere
    from head360cli.model.data import Views

    data = Views(max(i for i, _ in VIEWS) + 1, split="test", seed=1, size=256)
    rows = []
    for i, yaw in VIEWS:
        cam = camera_on_sphere(torch.tensor([yaw]), torch.tensor([5.0]), RIG_DISTANCE)
        b = data.render(i, np.zeros(52, np.float32), cam, with_hair=True)
        alpha = b.alpha[0, 0].numpy()[..., None]
        rgb = (b.rgb[0].permute(1, 2, 0).numpy() * alpha * 255
               + np.array([120, 140, 160]) * (1 - alpha)).astype(np.uint8)
        truth = b.hair_alpha[0, 0].numpy() > 0.5
        plain, found = parse_hair(rgb, None, profile=False), parse_hair(rgb, None)
        print(f"head {i}, yaw {yaw:+.0f}: hair IoU {mask_iou(plain.hair, truth):.3f} "
              f"without the cascade, {mask_iou(found.hair, truth):.3f} with it "
              f"(a face in profile found: {found.profile})")
        tiles = [rgb, _overlay(rgb, plain.hair, plain.face),
                 _overlay(rgb, found.hair, found.face),
                 np.repeat(truth[..., None] * 255, 3, 2).astype(np.uint8)]
        rows.append(np.concatenate([np.asarray(Image.fromarray(t).resize(
            (TILE, TILE), Image.Resampling.LANCZOS)) for t in tiles], 1))
    Image.fromarray(np.concatenate(rows, 0)).save(FIGURE, optimize=True)
    print(f"wrote {FIGURE}")


if __name__ == "__main__":
    main()

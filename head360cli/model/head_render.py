"""Render a fitted head (its mesh, neural texture and hair) from any camera.

:class:`HeadRenderer` holds what does not change between frames (the generator, the neutral
mesh, the texture, the hair meshes) and renders batches of views. The turntable, the fit
preview and animation build on it.
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["HeadRenderer", "to_uint8"]


def to_uint8(rgb: torch.Tensor) -> np.ndarray:
    """``(B, 3, H, W)`` in [0, 1] -> ``(B, H, W, 3)`` uint8."""
    return (rgb.clamp(0, 1) * 255).round().byte().permute(0, 2, 3, 1).cpu().numpy()


class HeadRenderer:
    """A head ready to render.

    Args:
        gen: The generator.
        shape: ``(K,)`` identity code of the bilinear model.
        texture: ``(C, R, R)`` neural texture.
        hair_style: Hairstyle id (0 = bald).
        hair_colour: ``(3,)`` linear RGB.
        expression: ``(52,)`` ARKit weights used when a render call gives none.
        samples: Samples per ray (default: the generator's own).
    """

    def __init__(self, gen, shape: np.ndarray, texture: torch.Tensor, hair_style: int,
                 hair_colour: np.ndarray, expression: np.ndarray | None = None,
                 samples: int | None = None) -> None:
        from head360cli.mesh.bilinear import load_bilinear
        from head360cli.model.generator import hair_for

        self.gen = gen
        self.samples = samples or gen.cfg.samples
        device = next(gen.parameters()).device
        self.device = device
        self.model = load_bilinear()
        self.shape = np.asarray(shape, np.float64)
        self.expression = (np.zeros(52) if expression is None
                           else np.asarray(expression, np.float64))
        self.neutral = self.model.vertices(self.shape, np.zeros(52))
        self.texture = texture.to(device)[None]
        self.hair = hair_for(self.neutral, [int(hair_style)], np.asarray(hair_colour)[None]
                             ).to(device) if gen.cfg.hair else None
        if self.hair is not None and self.hair.meshes[0] is None:
            self.hair = None  # bald

    def vertices(self, expression: np.ndarray | None = None) -> torch.Tensor:
        """``(V, 3)`` the mesh with ARKit ``expression (52,)`` (default: the head's own)."""
        w = self.expression if expression is None else np.asarray(expression, np.float64)
        return torch.tensor(self.model.vertices(self.shape, w), dtype=torch.float32,
                            device=self.device)

    @torch.no_grad()
    def render(self, c2w: torch.Tensor, intrinsics: torch.Tensor,
               expression: np.ndarray | None = None, hair: bool = True,
               batch: int = 4) -> torch.Tensor:
        """Views ``(B, 3, H, W)`` in [0, 1] on white from cameras ``c2w (B, 4, 4)`` with
        ``intrinsics (3, 3)`` for the generator's image size, ``batch`` at a time."""
        from head360cli.model.generator import Hair

        verts = self.vertices(expression)
        out = []
        with self.gen.samples_per_ray(self.samples):
            for i in range(0, len(c2w), batch):
                cams = c2w[i:i + batch].to(self.device)
                n = len(cams)
                h = None
                if hair and self.hair is not None:
                    h = Hair(self.hair.meshes * n, self.hair.style.expand(n),
                             self.hair.colour.expand(n, 3))
                o = self.gen(verts[None].expand(n, -1, -1), cams, intrinsics.to(self.device),
                             texture=self.texture.expand(n, -1, -1, -1), hair=h)
                out.append(o["rgb"].cpu())
        return torch.cat(out)

"""The generator: (mesh vertices, texture code or neural texture, camera) -> image.

    t --TextureGenerator--> neural texture (C, R, R)
    vertices + texture --rasterize_planes--> hex-planes (P, C + 2, res, res)
    camera --surface_samples--> points around the rasterized surface
    points --sample_planes--> features --Decoder--> density, colour features
    --composite--> feature image (render_res) --RefineNet--> RGB, alpha (image_res)

The vertices come from the parametric head (:class:`head360cli.mesh.bilinear.BilinearHead`
for codes ``s`` and ARKit weights ``w``) or straight from a mesh of the same topology.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from head360cli.model.config import GeneratorConfig
from head360cli.model.networks import Decoder, RefineNet, TextureGenerator
from head360cli.model.planes import PLANE_SETS, rasterize_planes, sample_planes
from head360cli.model.render import composite, surface_samples

__all__ = ["Generator"]


class Generator(nn.Module):
    """The head generator (head branch).

    Args:
        cfg: Sizes.
        faces: ``(F, 3)`` triangles of the head topology.
        uv: ``(T, 2)`` texture coordinates.
        faces_uv: ``(F, 3)`` indices into ``uv``.
    """

    def __init__(self, cfg: GeneratorConfig, faces: np.ndarray, uv: np.ndarray,
                 faces_uv: np.ndarray) -> None:
        super().__init__()
        if cfg.planes not in PLANE_SETS:
            raise ValueError(f"expected planes hex or tri, found {cfg.planes!r}")
        self.cfg = cfg
        self.plane_names = PLANE_SETS[cfg.planes]
        self.register_buffer("faces", torch.as_tensor(np.asarray(faces), dtype=torch.long))
        self.register_buffer("uv", torch.as_tensor(np.asarray(uv), dtype=torch.float32))
        self.register_buffer("faces_uv",
                             torch.as_tensor(np.asarray(faces_uv), dtype=torch.long))
        self.texture_generator = TextureGenerator(cfg)
        self.decoder = Decoder(cfg, len(self.plane_names))
        self.refine = RefineNet(cfg) if cfg.refine else None

    def texture(self, code: torch.Tensor) -> torch.Tensor:
        """``(B, code_dim)`` -> neural texture ``(B, C, R, R)``."""
        return self.texture_generator(code)

    def planes(self, verts: torch.Tensor, texture: torch.Tensor) -> torch.Tensor:
        """Hex-planes ``(B, P, C + 2, res, res)`` of a posed mesh ``(B, V, 3)``."""
        c = self.cfg
        return rasterize_planes(verts, self.faces, self.uv, self.faces_uv, texture,
                                self.plane_names, c.plane_res, c.plane_centre,
                                c.plane_half_size)

    def forward(self, verts: torch.Tensor, c2w: torch.Tensor, intrinsics: torch.Tensor, *,
                code: torch.Tensor | None = None, texture: torch.Tensor | None = None,
                jitter: bool = False) -> dict[str, Any]:
        """Render heads.

        Args:
            verts: ``(B, V, 3)`` posed mesh in head coordinates (metres).
            c2w: ``(B, 4, 4)`` camera-to-world (OpenCV axes).
            intrinsics: ``(B, 3, 3)`` or ``(3, 3)`` for an ``image_res`` image.
            code: ``(B, code_dim)`` texture codes, or
            texture: ``(B, C, R, R)`` neural textures (inversion optimises these).
            jitter: Stratified random sample positions (training).

        Returns:
            ``rgb (B, 3, H, W)`` on a white background, ``alpha (B, 1, H, W)``,
            ``rgb_low``/``alpha_low``/``depth_low`` at ``render_res``.
        """
        c = self.cfg
        if texture is None:
            if code is None:
                raise ValueError("expected a texture code or a neural texture, found neither")
            texture = self.texture(code)
        b = verts.shape[0]
        planes = self.planes(verts, texture)
        k = intrinsics.expand(b, 3, 3).clone()
        k[:, :2] *= c.render_res / c.image_res
        rays = c.render_res * c.render_res
        noise = (torch.rand(b, rays, c.samples, dtype=verts.dtype, device=verts.device)
                 if jitter else None)
        points, depths, near = surface_samples(verts, self.faces, c2w, k, c.render_res,
                                               c.samples, c.shell, noise)
        feats = sample_planes(points.reshape(b, -1, 3), planes, self.plane_names,
                              c.plane_centre, c.plane_half_size, c.surface_tau)
        density, colour = self.decoder(feats)
        density = density.view(b, rays, c.samples)
        colour = colour.view(b, rays, c.samples, -1)
        image, alpha, depth = composite(density, colour, depths, near, c.shell)
        shape = (b, c.render_res, c.render_res)
        image = image.transpose(1, 2).reshape(b, -1, *shape[1:])
        alpha = alpha.view(b, 1, *shape[1:])
        rgb_low = image[:, :3] + (1.0 - alpha)  # on white
        if self.refine is not None:
            rgb, alpha_hi = self.refine(image, alpha, rgb_low)
        else:
            scale = c.image_res / c.render_res
            rgb = F.interpolate(rgb_low, scale_factor=scale, mode="bilinear",
                                align_corners=False)
            alpha_hi = F.interpolate(alpha, scale_factor=scale, mode="bilinear",
                                     align_corners=False)
        return {"rgb": rgb, "alpha": alpha_hi, "rgb_low": rgb_low, "alpha_low": alpha,
                "depth_low": depth.view(b, 1, *shape[1:]), "texture": texture}

"""The near-surface volume renderer: samples only around the rasterized surface.

The mesh is rasterized from the camera at the feature resolution; each pixel's ray gets
``samples`` points within ``shell`` metres in front of and behind that surface (uncovered
pixels next to a silhouette borrow their neighbour's depth, so edges can be soft; covered
pixels keep their own, so a surface behind an edge, the head behind an ear or the hair, is
still sampled), the field gives
their density and features, and alpha compositing gives the feature image. Shapes are
static (every pixel is computed, pixels without a surface nearby get zero weight), which
keeps the graph exportable. Pure functions; nothing here holds parameters.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from head360cli.geometry.cameras import project
from head360cli.geometry.rasterize import ZBuffer, rasterize

__all__ = ["EMPTY", "composite", "lit", "samples_around", "screen_depth", "surface_samples"]


EMPTY = 1e3
"""Depth (metres) of pixels where the rasterizer found no surface."""


def screen_depth(verts: torch.Tensor, faces: torch.Tensor, c2w: torch.Tensor,
                 intrinsics: torch.Tensor, res: int, draw: torch.Tensor | None = None,
                 under: ZBuffer | None = None, zbuffer: bool = False
                 ) -> torch.Tensor | tuple[torch.Tensor, ZBuffer]:
    """Depth of the nearest front-facing surface per pixel.

    Args:
        verts: ``(B, V, 3)`` head (world) coordinates.
        faces: ``(F, 3)``.
        c2w: ``(B, 4, 4)``.
        intrinsics: ``(B, 3, 3)`` for a ``res x res`` image.
        res: Image resolution.
        draw, under: Draw only triangles ``draw (F,)`` over the depth test ``under`` of
            the others (see :func:`~head360cli.geometry.rasterize.rasterize`).
        zbuffer: Also return the depth test's state (to pass as ``under`` later).

    Returns:
        ``(B, res, res)`` depth, :data:`EMPTY` where no surface covers the pixel (and the
        :class:`ZBuffer` with ``zbuffer``). The depth of several meshes seen together is
        the minimum of theirs.
    """
    pix, depth = project(verts, c2w, intrinsics)
    frags = rasterize(pix, depth, faces, res, res, cull_backfaces=True, draw=draw,
                      under=under)
    out = torch.where(frags.mask, frags.depth, torch.full_like(frags.depth, EMPTY))
    return (out, frags.zbuffer) if zbuffer else out


def _filled(depth: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(depth, near)`` of a ``(B, 1, res, res)`` depth map: covered pixels keep their
    depth, uncovered ones next to a silhouette take their nearest neighbour's (only there:
    borrowing a nearer one at a covered pixel left background seams behind ears and
    hair); ``near`` is 1 where a surface is within one pixel."""
    mask = (depth < EMPTY).to(depth.dtype)
    fill = torch.where(mask > 0, depth, -F.max_pool2d(-depth, 3, stride=1, padding=1))
    return fill, F.max_pool2d(mask, 3, stride=1, padding=1)


def samples_around(depth: torch.Tensor, c2w: torch.Tensor, intrinsics: torch.Tensor,
                   samples: int, shell: float, jitter: torch.Tensor | None = None,
                   behind: torch.Tensor | None = None
                   ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Points along each pixel's ray around a depth map's surface.

    Args:
        depth: ``(B, res, res)`` from :func:`screen_depth`.
        c2w: ``(B, 4, 4)``.
        intrinsics: ``(B, 3, 3)`` for a ``res x res`` image.
        samples: Points per ray ``S``.
        shell: Metres covered in front of and behind the surface.
        jitter: Optional ``(B, res * res, S)`` in [0, 1): stratified offsets (training).
        behind: Optional ``(B, res, res)`` depth of a surface at or behind ``depth`` (the
            head under the hair): the odd-numbered samples go around it instead, so both
            are sampled. Where the two coincide the samples are exactly those without it;
            the depths come back sorted along each ray.

    Returns:
        ``(points (B, res*res, S, 3), depths (B, res*res, S), near (B, res*res))`` where
        ``near`` is 1 for pixels with a surface within one pixel, else 0.
    """
    b, res = depth.shape[0], depth.shape[-1]
    dtype, device = c2w.dtype, c2w.device
    d_fill, near = _filled(depth[:, None])
    d_fill = torch.where(near > 0, d_fill, torch.ones_like(d_fill))  # arbitrary, weight 0
    d_fill = d_fill.view(b, res * res, 1)
    steps = torch.arange(samples, dtype=dtype, device=device)
    u = (steps + 0.5)[None, None] if jitter is None else steps + jitter
    offsets = shell * (2.0 * u / samples - 1.0)
    if behind is None:
        t = d_fill + offsets  # (B, HW, S)
    else:
        d_back, near_back = _filled(behind[:, None])
        d_back = torch.where(near_back > 0, d_back, d_fill.view(b, 1, res, res))
        odd = (steps % 2 == 1)[None, None]
        t = torch.where(odd, d_back.view(b, res * res, 1), d_fill) + offsets
        t = torch.sort(t, dim=-1).values
    # Ray directions with unit depth, in world coordinates.
    ys, xs = torch.meshgrid(torch.arange(res, dtype=dtype, device=device),
                            torch.arange(res, dtype=dtype, device=device), indexing="ij")
    k = intrinsics
    dx = (xs.reshape(-1)[None] + 0.5 - k[:, 0, 2, None]) / k[:, 0, 0, None]
    dy = (ys.reshape(-1)[None] + 0.5 - k[:, 1, 2, None]) / k[:, 1, 1, None]
    dirs_cam = torch.stack([dx, dy, torch.ones_like(dx)], -1)  # (B, HW, 3)
    dirs = dirs_cam @ c2w[:, :3, :3].transpose(1, 2)
    origin = c2w[:, None, None, :3, 3]
    points = origin + t[..., None] * dirs[:, :, None, :]
    return points, t, near.view(b, res * res)


def surface_samples(verts: torch.Tensor, faces: torch.Tensor, c2w: torch.Tensor,
                    intrinsics: torch.Tensor, res: int, samples: int, shell: float,
                    jitter: torch.Tensor | None = None
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`samples_around` the surface of one mesh (see :func:`screen_depth`)."""
    return samples_around(screen_depth(verts, faces, c2w, intrinsics, res), c2w,
                          intrinsics, samples, shell, jitter)


def composite(density: torch.Tensor, features: torch.Tensor, depths: torch.Tensor,
              near: torch.Tensor, shell: float) -> tuple[torch.Tensor, torch.Tensor,
                                                           torch.Tensor]:
    """Alpha compositing along each ray.

    Args:
        density: ``(B, R, S)`` per metre.
        features: ``(B, R, S, C)``.
        depths: ``(B, R, S)``.
        near: ``(B, R)`` 1 where the ray passes near the surface.
        shell: The half-width the samples cover (the last sample's interval).

    Returns:
        ``(features (B, R, C), alpha (B, R), depth (B, R))``.
    """
    s = depths.shape[-1]
    delta = torch.cat([depths[..., 1:] - depths[..., :-1],
                       torch.full_like(depths[..., :1], 2.0 * shell / s)], -1)
    optical = density * delta
    alpha = 1.0 - torch.exp(-optical)
    # transmittance to each sample: exp(-sum of the optical depths before it) (a cumsum,
    # not a cumprod of 1 - alpha: the same values, and ONNX has CumSum)
    trans = torch.exp(-torch.cumsum(torch.cat([torch.zeros_like(optical[..., :1]),
                                               optical[..., :-1]], -1), -1))
    weights = alpha * trans * near[..., None]
    acc = weights.sum(-1)
    feats = (weights[..., None] * features).sum(-2)
    depth = (weights * depths).sum(-1) / acc.clamp_min(1e-6)
    return feats, acc, depth


def lit(rgb: torch.Tensor, alpha: torch.Tensor, gain: torch.Tensor) -> torch.Tensor:
    """Images ``rgb (B, 3, H, W)`` composited on white, of coverage ``alpha (B, 1, H, W)``,
    with the head's pixels scaled by ``gain`` (``(3,)`` or broadcastable to ``(B, 3, 1,
    1)``: the colour of a photo's light) and the backdrop left white:
    ``gain * (rgb - (1 - alpha)) + (1 - alpha)``."""
    if gain.ndim == 1:
        gain = gain.view(1, -1, 1, 1)
    back = 1.0 - alpha
    return gain * (rgb - back) + back

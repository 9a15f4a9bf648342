"""The deferred renderer's geometry pass: posed head and hair meshes rasterized once per
view into a G-buffer of surface attributes (texture coordinates, normal, view direction,
which mesh), at ``samples`` subpixel offsets per pixel. It holds no parameters; the
networks that turn a G-buffer into colour are in :mod:`head360cli.model.networks`.

The subpixel offsets are the corpus renderer's (:mod:`head360cli.synth.render`), so a
G-buffer of 2 samples averages to the same coverage as the corpus's antialiased views.
"""

from __future__ import annotations

import dataclasses

import torch

from head360cli.geometry.cameras import project
from head360cli.geometry.mesh_ops import vertex_normals
from head360cli.geometry.rasterize import interpolate_face_corners, rasterize

__all__ = ["OFFSETS", "GBuffer", "MeshPart", "gbuffer"]

OFFSETS: dict[int, tuple[tuple[float, float], ...]] = {
    1: ((0.0, 0.0),),
    2: ((-0.25, -0.25), (0.25, 0.25)),
    4: ((-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)),
}
"""Subpixel sample offsets (pixels) for 1, 2 and 4 samples per pixel."""


@dataclasses.dataclass
class MeshPart:
    """One mesh drawn into a G-buffer: ``verts (B, V, 3)`` in head coordinates,
    ``faces (F, 3)``, texture coordinates ``uv (T, 2)`` indexed by ``faces_uv (F, 3)``,
    and optional ``normal_groups (G, K)`` (vertices welded for normals)."""

    verts: torch.Tensor
    faces: torch.Tensor
    uv: torch.Tensor
    faces_uv: torch.Tensor
    normal_groups: torch.Tensor | None = None


@dataclasses.dataclass
class GBuffer:
    """Surface attributes of ``S`` samples of ``B`` views, sample-major: ``R = S * B``
    rows, sample ``s`` of view ``b`` at row ``s * B + b``.

    Attributes:
        samples: ``S``.
        uv: ``(R, H, W, 2)`` texture coordinates in [0, 1] (of the head's texture, or the
            hair's where ``hair`` is set); 0 where nothing is.
        normal: ``(R, H, W, 3)`` unit surface normals in head coordinates.
        view: ``(R, H, W, 3)`` unit directions from the surface to the camera.
        mask: ``(R, H, W)`` bool: a surface covers the sample point.
        hair: ``(R, H, W)`` bool: that surface is the hair mesh.
        depth: ``(R, H, W)`` camera depth of the visible surface (0 where none).
    """

    samples: int
    uv: torch.Tensor
    normal: torch.Tensor
    view: torch.Tensor
    mask: torch.Tensor
    hair: torch.Tensor
    depth: torch.Tensor

    @property
    def views(self) -> int:
        """``B``."""
        return self.depth.shape[0] // self.samples

    def index(self) -> torch.Tensor:
        """``(n,)`` flat indices of the covered sample points (into ``R * H * W``)."""
        return torch.nonzero(self.mask.reshape(-1)).squeeze(1)

    def mean(self, images: torch.Tensor) -> torch.Tensor:
        """Per-sample images ``(R, C, H, W)`` -> ``(B, C, H, W)``, averaged over the
        samples."""
        return images.view(self.samples, self.views, *images.shape[1:]).mean(0)


def _sample_cameras(c2w: torch.Tensor, intrinsics: torch.Tensor, samples: int
                    ) -> tuple[torch.Tensor, torch.Tensor]:
    """``(S * B, 4, 4)`` cameras and ``(S * B, 3, 3)`` intrinsics shifted by the
    subpixel offsets, sample-major."""
    b = c2w.shape[0]
    offsets = torch.tensor(OFFSETS[samples], dtype=c2w.dtype, device=c2w.device)
    k = intrinsics.expand(b, 3, 3).repeat(samples, 1, 1).clone()
    shift = offsets.repeat_interleave(b, 0)
    k[:, 0, 2] += shift[:, 0]
    k[:, 1, 2] += shift[:, 1]
    return c2w.repeat(samples, 1, 1), k


def _surface(part: MeshPart, cams: torch.Tensor, k: torch.Tensor, size: int):
    """``(fragments, uv (R, H, W, 2), normal (R, H, W, 3))`` of one mesh seen by
    ``R`` cameras (its ``verts`` given for ``R / S`` views, repeated over the samples)."""
    verts = part.verts.repeat(cams.shape[0] // part.verts.shape[0], 1, 1)
    pix, depth = project(verts, cams, k)
    frags = rasterize(pix, depth, part.faces, size, size, cull_backfaces=True)
    uv = interpolate_face_corners(part.uv[part.faces_uv], frags)
    normals = vertex_normals(verts, part.faces, part.normal_groups)
    normal = interpolate_face_corners(normals[:, part.faces], frags)
    return frags, uv, normal


def gbuffer(head: MeshPart, c2w: torch.Tensor, intrinsics: torch.Tensor, size: int,
            samples: int = 1, hairs: list[tuple[MeshPart, torch.Tensor]] = ()) -> GBuffer:
    """Rasterize heads (and hair) into a G-buffer.

    Args:
        head: The posed heads, ``verts (B, V, 3)``.
        c2w: ``(B, 4, 4)`` camera-to-world (OpenCV axes).
        intrinsics: ``(B, 3, 3)`` or ``(3, 3)`` for a ``size`` x ``size`` image.
        size: Image side in pixels.
        samples: Subpixel samples per pixel (1, 2 or 4: :data:`OFFSETS`).
        hairs: Hair meshes, each ``(mesh with verts (1, H, 3), views (B_h,))`` drawn
            with the heads of those views; the nearer surface wins each sample point.

    Returns:
        The :class:`GBuffer` of the ``B`` views.
    """
    b = c2w.shape[0]
    cams, k = _sample_cameras(c2w, intrinsics, samples)
    frags, uv, normal = _surface(head, cams, k, size)
    mask = frags.face_id >= 0
    depth = frags.depth
    hair_mask = torch.zeros_like(mask)
    for hair, items in hairs:
        rows = (items[None] + b * torch.arange(samples, device=c2w.device)[:, None]
                ).reshape(-1)
        hverts = hair.verts.expand(len(items), -1, -1)
        hfrags, huv, hnormal = _surface(dataclasses.replace(hair, verts=hverts),
                                        cams[rows], k[rows], size)
        nearer = (hfrags.face_id >= 0) & (~mask[rows] | (hfrags.depth < depth[rows]))
        hair_mask = hair_mask.index_copy(0, rows, nearer)
        sel = nearer[..., None]
        uv = uv.index_copy(0, rows, torch.where(sel, huv, uv[rows]))
        normal = normal.index_copy(0, rows, torch.where(sel, hnormal, normal[rows]))
        depth = depth.index_copy(0, rows, torch.where(nearer, hfrags.depth, depth[rows]))
        mask = mask.index_copy(0, rows, mask[rows] | nearer)
    normal = torch.nn.functional.normalize(normal, dim=-1)
    # direction to the camera: minus the ray through each sample point, in head axes
    h, w = mask.shape[1:]
    ys = torch.arange(h, dtype=c2w.dtype, device=c2w.device) + 0.5
    xs = torch.arange(w, dtype=c2w.dtype, device=c2w.device) + 0.5
    x = (xs[None, None, :] - k[:, 0, 2, None, None]) / k[:, 0, 0, None, None]
    y = (ys[None, :, None] - k[:, 1, 2, None, None]) / k[:, 1, 1, None, None]
    x, y = torch.broadcast_tensors(x, y)
    ray = torch.stack([x, y, torch.ones_like(x)], -1)
    ray = (ray[..., None, :] * cams[:, None, None, :3, :3]).sum(-1)
    view = -torch.nn.functional.normalize(ray, dim=-1)
    return GBuffer(samples, uv, normal, view, mask, hair_mask, depth)

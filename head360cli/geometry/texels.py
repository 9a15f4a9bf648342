"""Texels located on a mesh, and what a photo shows of them: pure functions shared by the
mesh bake and the fit's projection of a photo into the texture."""

from __future__ import annotations

import dataclasses

import torch
import torch.nn.functional as F

from head360cli.geometry.cameras import project
from head360cli.geometry.rasterize import interpolate_face_corners, rasterize

__all__ = ["DEGENERATE_AREA", "TexelSurface", "seen_in_photo", "texel_surface"]

DEGENERATE_AREA = 1e-10
"""Twice the area (m^2) below which a triangle of the mesh counts as having none."""


@dataclasses.dataclass
class TexelSurface:
    """Per texel of an ``R`` x ``R`` UV layout: the triangle that covers it
    (``face_id (R, R)``, -1 where none), its barycentrics ``bary (R, R, 3)``, the
    point ``points (R, R, 3)`` and unit ``normals (R, R, 3)`` there, and ``covered (R, R)``:
    a triangle with an area on the mesh covers the texel."""

    face_id: torch.Tensor
    bary: torch.Tensor
    points: torch.Tensor
    normals: torch.Tensor
    covered: torch.Tensor

    def at(self, values: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
        """Per-vertex ``values (V, C)`` interpolated at every texel: ``(R, R, C)``."""
        fid = self.face_id.clamp_min(0)
        corners = values[faces[fid]]  # (R, R, 3, C)
        return (corners * self.bary[..., None]).sum(-2) * (self.face_id >= 0)[..., None]


def texel_surface(verts: torch.Tensor, faces: torch.Tensor, uv: torch.Tensor,
                  faces_uv: torch.Tensor, size: int, normals: torch.Tensor) -> TexelSurface:
    """Locate the texels of a ``size`` x ``size`` layout on a mesh.

    Args:
        verts: ``(V, 3)`` the mesh.
        faces: ``(F, 3)`` its triangles; ``uv (T, 2)`` and ``faces_uv (F, 3)`` their
            texture coordinates (v down).
        size: Texels a side.
        normals: ``(V, 3)`` unit vertex normals.

    Returns:
        The :class:`TexelSurface`. Triangles of no area on the mesh (the template closes
        its seams with such, which have room in the UV layout) leave their texels
        uncovered: their normal is undefined.
    """
    screen = (uv * size)[None]
    frags = rasterize(screen, torch.ones(1, len(uv), dtype=uv.dtype, device=uv.device),
                      faces_uv, size, size, perspective_correct=False, near=float("-inf"))
    points = interpolate_face_corners(verts[faces], frags)[0]
    normal = interpolate_face_corners(normals[faces], frags)[0]
    normal = normal / normal.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    tri = verts[faces]
    area = torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]).norm(dim=-1)
    flat = area[frags.face_id[0].clamp_min(0)] <= DEGENERATE_AREA
    return TexelSurface(frags.face_id[0], frags.bary[0], points, normal,
                        frags.mask[0] & ~flat)


def seen_in_photo(points: torch.Tensor, normals: torch.Tensor, image: torch.Tensor,
                  c2w: torch.Tensor, intrinsics: torch.Tensor, depth: torch.Tensor,
                  tolerance: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """What an image shows of surface points.

    Args:
        points: ``(N, 3)`` points and ``normals (N, 3)`` their unit normals.
        image: ``(C, H, W)`` the image (any channels: colours, weights).
        c2w: ``(4, 4)`` its camera and ``intrinsics (3, 3)``.
        depth: ``(H, W)`` the camera depth of the surface the image shows there (0 or
            less: none).
        tolerance: Metres a point may lie behind that surface and count as seen.

    Returns:
        ``(values (N, C)`` read bilinearly, ``facing (N,)`` the cosine between normal
        and the direction to the camera (0 if it faces away), ``visible (N,)`` bool: in
        the image and not hidden).
    """
    h, w = image.shape[-2:]
    pix, z = project(points[None], c2w[None], intrinsics[None])
    pix, z = pix[0], z[0]
    scale = torch.tensor([w, h], dtype=pix.dtype, device=pix.device)
    grid = (pix / scale * 2 - 1)[None, None]
    values = F.grid_sample(image[None], grid, align_corners=False)[0, :, 0].T
    surface = F.grid_sample(depth[None, None], grid, mode="nearest",
                            align_corners=False)[0, 0, 0]
    inside = (pix >= 0).all(1) & (pix[:, 0] < w) & (pix[:, 1] < h) & (z > 0)
    visible = inside & (surface > 0) & (z <= surface + tolerance)
    towards = c2w[:3, 3][None] - points
    towards = towards / towards.norm(dim=1, keepdim=True).clamp_min(1e-9)
    facing = (normals * towards).sum(1).clamp_min(0)
    return values, facing, visible

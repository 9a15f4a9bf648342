"""The corpus renderer: textured meshes under fixed studio lighting, with masks.

It holds no parameters. Lighting is computed in world space from the surface normal (a
key, a fill and a rim light plus a sky/ground ambient), so the shading is baked into the
head: every camera of the rig sees the same appearance, as in a studio capture with fixed
lights. Antialiasing is by supersampling: render at ``ssaa`` times the size and average.
"""

from __future__ import annotations

import dataclasses

import torch
import torch.nn.functional as F

from head360cli.geometry.cameras import project
from head360cli.geometry.mesh_ops import vertex_normals
from head360cli.geometry.rasterize import interpolate, interpolate_face_corners, rasterize

__all__ = ["RenderOutput", "StudioLights", "render_mesh", "shade"]


@dataclasses.dataclass(frozen=True)
class StudioLights:
    """Directional lights in world space: (direction towards the light, intensity)."""

    key: tuple[tuple[float, float, float], float] = ((0.45, 0.55, 0.70), 0.75)
    """Main light: upper left of the face (the subject's left), in front."""
    fill: tuple[tuple[float, float, float], float] = ((-0.6, 0.1, 0.6), 0.30)
    """Softer light from the other side."""
    rim: tuple[tuple[float, float, float], float] = ((0.0, 0.5, -0.85), 0.35)
    """Light from behind and above, so the back of the head is lit too."""
    sky: float = 0.42
    """Ambient from above."""
    ground: float = 0.22
    """Ambient from below."""


@dataclasses.dataclass
class RenderOutput:
    """Images of a batch of views, all ``(B, C, H, W)`` float in [0, 1] unless noted.

    Attributes:
        rgb: Colour composited over ``background``.
        alpha: Coverage (antialiased).
        depth: Camera depth in metres of the nearest surface (0 where none), not averaged
            across the supersamples but taken at their centre one.
        normals: World-space unit normals in [-1, 1] (0 where none).
        labels: ``(B, L, H, W)`` coverage of each label set asked for (e.g. hair, face).
    """

    rgb: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor
    normals: torch.Tensor
    labels: torch.Tensor


def shade(albedo: torch.Tensor, normals: torch.Tensor, lights: StudioLights,
          emissive: torch.Tensor | None = None) -> torch.Tensor:
    """Lambertian shading under the studio lights.

    Args:
        albedo: ``(..., 3)`` base colour.
        normals: ``(..., 3)`` unit world normals.
        lights: The lights.
        emissive: ``(..., 1)`` in [0, 1]: 1 keeps the albedo unlit (eyes' highlights).

    Returns:
        ``(..., 3)`` colour, clipped to [0, 1].
    """
    light = lights.sky * (0.5 + 0.5 * normals[..., 1:2]) + lights.ground * (
        0.5 - 0.5 * normals[..., 1:2])
    for direction, intensity in (lights.key, lights.fill, lights.rim):
        d = torch.tensor(direction, dtype=normals.dtype, device=normals.device)
        d = d / d.norm()
        light = light + intensity * (normals @ d).clamp_min(0.0)[..., None]
    out = albedo * light
    if emissive is not None:
        out = out * (1 - emissive) + albedo * emissive
    return out.clamp(0.0, 1.0)


def render_mesh(verts: torch.Tensor, faces: torch.Tensor, c2w: torch.Tensor,
                intrinsics: torch.Tensor, size: int, *, uv: torch.Tensor,
                faces_uv: torch.Tensor, texture: torch.Tensor,
                face_labels: torch.Tensor | None = None,
                label_sets: tuple[tuple[int, ...], ...] = (),
                lights: StudioLights = StudioLights(), ssaa: int = 2,
                background: float = 1.0, normal_groups: torch.Tensor | None = None
                ) -> RenderOutput:
    """Render textured meshes from cameras.

    Args:
        verts: ``(B, V, 3)`` world positions (one mesh per camera, or the same expanded).
        faces: ``(F, 3)``.
        c2w: ``(B, 4, 4)`` camera-to-world.
        intrinsics: ``(3, 3)`` for a ``size x size`` image.
        size: Output width and height.
        uv: ``(T, 2)`` texture coordinates (v = 0 at the top of the texture image).
        faces_uv: ``(F, 3)`` indices into ``uv``.
        texture: ``(B, 3, Ht, Wt)`` or ``(1, 3, Ht, Wt)`` albedo atlas.
        face_labels: ``(F,)`` int label per face, for ``label_sets``.
        label_sets: Each a tuple of labels; the output has one coverage image per set.
        lights: Studio lights.
        ssaa: Supersampling factor for antialiasing.
        background: Grey level behind the head.
        normal_groups: ``(G, K)`` vertex groups whose coincident members share a normal.

    Returns:
        Colour, alpha, depth, normals and label coverage at ``size x size``.
    """
    b = verts.shape[0]
    hi = size * ssaa
    k = intrinsics.clone()
    k[:2] = k[:2] * ssaa
    pix, depth = project(verts, c2w, k)
    frags = rasterize(pix, depth, faces, hi, hi)
    normals_v = vertex_normals(verts, faces, normal_groups)
    n = interpolate(normals_v, faces, frags)
    n = F.normalize(n, dim=-1)
    uvs = interpolate_face_corners(uv[faces_uv], frags)  # (B, H, W, 2)
    grid = uvs * 2 - 1
    tex = texture.expand(b, -1, -1, -1)
    albedo = F.grid_sample(tex, grid, mode="bilinear", padding_mode="border",
                           align_corners=False).permute(0, 2, 3, 1)
    colour = shade(albedo, n, lights)
    mask = frags.mask[..., None].to(colour.dtype)
    colour = colour * mask + background * (1 - mask)
    chans = [colour.permute(0, 3, 1, 2), mask.permute(0, 3, 1, 2)]
    if label_sets:
        assert face_labels is not None
        fid = frags.face_id.clamp_min(0)
        lab = face_labels[fid]
        for s in label_sets:
            member = torch.zeros_like(lab, dtype=torch.bool)
            for value in s:
                member |= lab == value
            chans.append((member & frags.mask).to(colour.dtype)[:, None])
    stacked = torch.cat(chans, 1)
    if ssaa > 1:
        stacked = F.avg_pool2d(stacked, ssaa)
    centre = ssaa // 2
    depth_lo = frags.depth[:, centre::ssaa, centre::ssaa][:, None]
    normals_lo = (n * frags.mask[..., None])[:, centre::ssaa, centre::ssaa].permute(0, 3, 1, 2)
    return RenderOutput(rgb=stacked[:, :3], alpha=stacked[:, 3:4], depth=depth_lo,
                        normals=normals_lo, labels=stacked[:, 4:])

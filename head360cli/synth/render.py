"""The corpus renderer: textured meshes under fixed studio lighting, with masks.

It holds no parameters. Lighting is computed in world space from the surface normal (a
key, a fill and a rim light plus a sky/ground ambient), so the shading is baked into the
head: every camera of the rig sees the same appearance, as in a studio capture with fixed
lights. Antialiasing is by multi-sampling: the view is rendered at 1, 2 or 4 subpixel
offsets (batched together) and averaged, which costs far less than rendering at twice
the size, since triangles stay small in pixels.
"""

from __future__ import annotations

import dataclasses

import torch
import torch.nn.functional as F

from head360cli.geometry.cameras import project
from head360cli.geometry.mesh_ops import vertex_normals
from head360cli.geometry.rasterize import rasterize

__all__ = ["RenderOutput", "StudioLights", "render_mesh", "shade"]

# Subpixel sample offsets (pixels) for 1, 2 and 4 samples per pixel.
_OFFSETS = {
    1: [(0.0, 0.0)],
    2: [(-0.25, -0.25), (0.25, 0.25)],
    4: [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)],
}


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
        depth: Camera depth in metres of the nearest surface (0 where none), from the first
            sample (not averaged).
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
                lights: StudioLights = StudioLights(), samples: int = 2,
                background: float = 1.0, normal_groups: torch.Tensor | None = None,
                cull_backfaces: bool = True) -> RenderOutput:
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
        samples: Antialiasing samples per pixel: 1, 2 (diagonal) or 4 (a 2x2 grid).
        background: Grey level behind the head.
        normal_groups: ``(G, K)`` vertex groups whose coincident members share a normal.
        cull_backfaces: Skip triangles facing away (all corpus meshes are closed and
            outward-facing, so nothing visible is lost and half the work is saved).

    Returns:
        Colour, alpha, depth, normals and label coverage at ``size x size``.
    """
    if samples not in _OFFSETS:
        raise ValueError(f"expected 1, 2 or 4 antialiasing samples, found {samples}")
    nb = verts.shape[0]
    offsets = torch.tensor(_OFFSETS[samples], dtype=verts.dtype, device=verts.device)
    # Each sample is the view shifted by a subpixel offset; all go through one batch.
    k = intrinsics.to(verts.dtype).expand(samples, 3, 3).clone()
    k[:, 0, 2] += offsets[:, 0]
    k[:, 1, 2] += offsets[:, 1]
    k = k.repeat_interleave(nb, 0)  # sample-major: (S * B, 3, 3)
    verts = verts.repeat(samples, 1, 1)
    c2w = c2w.repeat(samples, 1, 1)
    b = verts.shape[0]
    hi = size
    pix, depth = project(verts, c2w, k)
    frags = rasterize(pix, depth, faces, hi, hi, cull_backfaces=cull_backfaces)
    normals_v = vertex_normals(verts[:nb], faces, normal_groups).repeat(samples, 1, 1)
    # Shade only the covered pixels.
    fg = torch.nonzero(frags.face_id.reshape(-1) >= 0, as_tuple=True)[0]
    fid = frags.face_id.reshape(-1)[fg]
    bidx = fg // (hi * hi)
    w = frags.bary.reshape(-1, 3)[fg][..., None]  # (n, 3, 1)
    n = (normals_v[bidx[:, None], faces[fid]] * w).sum(1)
    n = F.normalize(n, dim=-1)
    uvs = (uv[faces_uv[fid]] * w).sum(1)  # (n, 2)
    grid = (uvs * 2 - 1)[None, None]  # (1, 1, n, 2)
    if texture.shape[0] > 1:
        texture = texture.repeat(samples, 1, 1, 1)
    if texture.shape[0] == 1:
        albedo = F.grid_sample(texture, grid, mode="bilinear", padding_mode="border",
                               align_corners=False)[0, :, 0].T
    else:  # one texture per view: sample each view's pixels from its own texture
        albedo = torch.empty(len(fg), 3, dtype=verts.dtype, device=verts.device)
        for i in range(b):
            m = bidx == i
            albedo[m] = F.grid_sample(texture[i:i + 1], grid[:, :, m], mode="bilinear",
                                      padding_mode="border", align_corners=False)[0, :, 0].T
    colour = shade(albedo, n, lights)
    chans = [colour, torch.ones(len(fg), 1, dtype=colour.dtype, device=colour.device)]
    if label_sets:
        assert face_labels is not None
        lab = face_labels[fid]
        for s_ in label_sets:
            member = torch.zeros_like(lab, dtype=torch.bool)
            for value in s_:
                member |= lab == value
            chans.append(member.to(colour.dtype)[:, None])
    values = torch.cat(chans, 1)
    image = torch.zeros(b * hi * hi, values.shape[1], dtype=colour.dtype, device=colour.device)
    image[:, :3] = background
    image = image.index_put((fg,), values)
    stacked = image.view(samples, nb, hi, hi, -1).mean(0).permute(0, 3, 1, 2)
    depth_lo = frags.depth[:nb, None]
    first = fg < nb * hi * hi  # normals of the first sample only, like depth
    normal_img = torch.zeros(nb * hi * hi, 3, dtype=colour.dtype, device=colour.device)
    normals_lo = normal_img.index_put((fg[first],), n[first]).view(nb, hi, hi, 3).permute(
        0, 3, 1, 2)
    return RenderOutput(rgb=stacked[:, :3], alpha=stacked[:, 3:4], depth=depth_lo,
                        normals=normals_lo, labels=stacked[:, 4:])

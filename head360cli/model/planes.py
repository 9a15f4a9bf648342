"""Hex-planes: the mesh and its neural texture rasterized onto orthographic feature planes.

Each plane looks at the head from one side (front, back, left, right, top, bottom) and holds,
per pixel, the neural texture at the visible surface, that surface's height towards the
viewer, and coverage. A 3D point reads every plane at its projection; a plane's feature
counts in proportion to how close the point lies to the surface that plane sees, so a
point on the cheek takes its feature from the planes that see the cheek. The plane set is
a parameter: ``hex`` (all six) or ``tri`` (front, left, top: the tri-plane ablation).

Pure functions; nothing here holds parameters.
"""

from __future__ import annotations

import dataclasses

import torch
import torch.nn.functional as F

from head360cli.geometry.rasterize import (
    ZBuffer,
    exporting,
    interpolate_face_corners,
    rasterize,
)

__all__ = ["PLANES", "PLANE_SETS", "PlaneRaster", "TexelReads", "add_texture_change",
           "plane_coordinates", "plane_raster", "plane_zbuffer", "rasterize_planes",
           "reading_pixels", "sample_planes", "texel_reads", "texture_planes"]

# name: (u axis, u sign, v axis, v sign, height axis, height sign). Model axes: +x the
# subject's left, +y up, +z the way the face looks. Height grows towards the viewer.
PLANES = {
    "front": (0, 1.0, 1, -1.0, 2, 1.0),
    "back": (0, -1.0, 1, -1.0, 2, -1.0),
    "left": (2, -1.0, 1, -1.0, 0, 1.0),
    "right": (2, 1.0, 1, -1.0, 0, -1.0),
    "top": (0, 1.0, 2, 1.0, 1, 1.0),
    "bottom": (0, 1.0, 2, -1.0, 1, -1.0),
}
PLANE_SETS = {"hex": ("front", "back", "left", "right", "top", "bottom"),
              "tri": ("front", "left", "top")}


def _axes(names: tuple[str, ...], like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    table = torch.tensor([PLANES[n] for n in names], dtype=like.dtype, device=like.device)
    return table[:, 0::2].long(), table[:, 1::2]  # (P, 3) axes, (P, 3) signs


def plane_coordinates(points: torch.Tensor, names: tuple[str, ...],
                      centre: tuple[float, float, float], half: float
                      ) -> tuple[torch.Tensor, torch.Tensor]:
    """Where points fall on each plane.

    Args:
        points: ``(B, N, 3)`` head coordinates (metres).
        names: Plane names (``P`` of them).
        centre: Centre of the planes' cube.
        half: Half its side (metres).

    Returns:
        ``(uv (B, P, N, 2) in [-1, 1], height (B, P, N) in metres towards each viewer)``.
    """
    axes, signs = _axes(names, points)
    q = points - torch.tensor(centre, dtype=points.dtype, device=points.device)
    picked = q[:, None, :, :].expand(-1, len(names), -1, -1)  # (B, P, N, 3)
    idx = axes[None, :, None, :].expand(q.shape[0], -1, q.shape[1], -1)
    coords = torch.gather(picked, 3, idx) * signs[None, :, None, :]
    return coords[..., :2] / half, coords[..., 2]


def _plane_screen(verts: torch.Tensor, names: tuple[str, ...], res: int,
                  centre: tuple[float, float, float], half: float
                  ) -> tuple[torch.Tensor, torch.Tensor]:
    """Vertices on each plane's raster: ``(B P, V, 2)`` pixels and ``(B P, V)`` depth
    (smaller is nearer that plane's viewer)."""
    b, p = verts.shape[0], len(names)
    coords, height = plane_coordinates(verts, names, centre, half)  # (B, P, V, 2), (B,P,V)
    return ((coords + 1.0) * 0.5 * res).reshape(b * p, -1, 2), -height.reshape(b * p, -1)


def plane_zbuffer(verts: torch.Tensor, faces: torch.Tensor, names: tuple[str, ...],
                  res: int, centre: tuple[float, float, float], half: float,
                  draw: torch.Tensor, cull_backfaces: bool = False) -> ZBuffer:
    """The planes' depth test after drawing only the triangles ``draw (F,)``: give it to
    :func:`rasterize_planes` as ``under`` with the other triangles as ``draw`` (for
    triangles that never move, drawn once for many frames)."""
    return rasterize(*_plane_screen(verts, names, res, centre, half), faces, res, res,
                     perspective_correct=False, near=float("-inf"), draw=draw,
                     cull_backfaces=cull_backfaces).zbuffer


@dataclasses.dataclass
class TexelReads:
    """The bilinear texture reads of a raster's covered plane pixels, as gathers.

    :func:`texture_planes` reads the texture with ``grid_sample``, whose gradient with
    respect to the texture is a slow scatter on a CPU (19-22 ms of a 240-280 ms step of
    a fit's texture inversion, 256-texel texture, 128-pixel planes; one in four plane
    pixels is covered). A mesh that stays put reads the same texels at every step, so
    those reads are worked out once: a gather forward and an ``index_add`` backward
    (5-6 ms together), the same bilinear samples.

    Attributes:
        pixel: ``(N,)`` int64 the covered pixels, flat indices into ``(B, P, res, res)``.
        texel: ``(N, 4)`` int64 each one's four bilinear taps, flat indices into the
            ``(B, R, R)`` texels of the batch.
        weight: ``(N, 4)`` their bilinear weights.
        res: ``R``, the texture resolution the indices are for.
    """

    pixel: torch.Tensor
    texel: torch.Tensor
    weight: torch.Tensor
    res: int


@dataclasses.dataclass
class PlaneRaster:
    """Where a posed mesh lands on the planes, for any texture: what
    :func:`rasterize_planes` computes before it reads the texture. A mesh that stays put
    (a texture inversion's) is rasterized once and textured at every step.

    Attributes:
        grid: ``(B, P res, res, 2)`` each plane pixel's texture coordinate in [-1, 1],
            the planes stacked into one tall grid.
        mask: ``(B, 1, P, res, res)`` coverage (0 or 1).
        surface: ``(B, 1, P, res, res)`` the visible surface's height towards the viewer
            (metres), 0 where nothing is.
        reads: The same reads as gathers for one texture resolution
            (:func:`texel_reads`), or ``None``: :func:`texture_planes` uses them for a
            texture of that resolution.
    """

    grid: torch.Tensor
    mask: torch.Tensor
    surface: torch.Tensor
    reads: TexelReads | None = None


def plane_raster(verts: torch.Tensor, faces: torch.Tensor, uv: torch.Tensor,
                 faces_uv: torch.Tensor, names: tuple[str, ...], res: int,
                 centre: tuple[float, float, float], half: float,
                 draw: torch.Tensor | None = None, under: ZBuffer | None = None,
                 cull_backfaces: bool = False) -> PlaneRaster:
    """Rasterize a mesh onto the planes, without a texture (see :func:`rasterize_planes`
    for the arguments; :func:`texture_planes` adds the texture)."""
    b, p = verts.shape[0], len(names)
    frags = rasterize(*_plane_screen(verts, names, res, centre, half), faces, res, res,
                      perspective_correct=False, near=float("-inf"), draw=draw, under=under,
                      cull_backfaces=cull_backfaces)
    corner_uv = uv[faces_uv]  # (F, 3, 2)
    uvs = interpolate_face_corners(corner_uv, frags)  # (BP, res, res, 2)
    # One texture read by all P planes at once: the grids stacked into one tall grid
    # (the same values as sampling P copies of the texture, without making the copies).
    grid = (uvs * 2.0 - 1.0).reshape(b, p * res, res, 2)
    mask = frags.mask.to(grid.dtype).view(b, 1, p, res, res)
    surface = -frags.depth.view(b, 1, p, res, res) * mask
    return PlaneRaster(grid, mask, surface)


def texel_reads(raster: PlaneRaster, res: int) -> PlaneRaster:
    """``raster`` with its :class:`TexelReads` for an ``res`` x ``res`` texture: for a
    mesh textured many times (a fit's) and for renders (:func:`rasterize_planes` without
    gradients), :func:`texture_planes` then gathers instead of calling ``grid_sample``
    (the same samples, rounded apart by about 1e-7)."""
    _, _, p, pr, _ = raster.mask.shape
    pixel = torch.nonzero(raster.mask.reshape(-1) > 0).squeeze(1)
    item = pixel // (p * pr * pr)
    lim = 1.0 - 1.0 / res
    g = raster.grid.reshape(-1, 2).index_select(0, pixel).clamp(-lim, lim).double()
    # grid_sample's unnormalisation (align_corners=False): texel centres at i + 0.5
    xy = ((g + 1.0) * res - 1.0) / 2.0
    low = xy.floor()
    frac = (xy - low).to(raster.grid.dtype)
    low = low.long()  # in [0, res - 1] inside the clamp
    x0, y0 = low[:, 0], low[:, 1]
    x1, y1 = (x0 + 1).clamp_max(res - 1), (y0 + 1).clamp_max(res - 1)  # weight 0 there
    fx, fy = frac[:, 0], frac[:, 1]
    base = item * res * res
    texel = torch.stack([base + y0 * res + x0, base + y0 * res + x1,
                         base + y1 * res + x0, base + y1 * res + x1], 1)
    weight = torch.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], 1)
    return dataclasses.replace(raster, reads=TexelReads(pixel, texel, weight, res))


def _gather_texture(texture: torch.Tensor, reads: TexelReads, pixels: int
                    ) -> torch.Tensor:
    """``(C, pixels)``: ``texture (B, C, R, R)`` read at ``reads``, zero elsewhere."""
    c = texture.shape[1]
    flat = texture.transpose(0, 1).reshape(c, -1)  # (C, B R R), a view for one item
    taps = flat.index_select(1, reads.texel.reshape(-1)).view(c, -1, 4)
    got = (taps * reads.weight).sum(-1)  # (C, N)
    return got.new_zeros(c, pixels).index_copy(1, reads.pixel, got)


def _read_texture(texture: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """Bilinear reads ``(B, C, H, W)`` of ``texture (B, C, R, R)`` at ``grid (B, H, W, 2)``
    in [-1, 1], the texture's border repeated beyond its edge.

    Border padding is written as a grid clamped half a texel inside the edge with zero
    padding: the same samples (the outer texel's weight is 1 at the clamp), and
    onnxruntime's border mode was 4x slower than its zero padding (35 vs 8 ms a frame).
    """
    lim = 1.0 - 1.0 / texture.shape[-1]
    return F.grid_sample(texture, grid.clamp(-lim, lim), mode="bilinear",
                         padding_mode="zeros", align_corners=False)


def texture_planes(texture: torch.Tensor, raster: PlaneRaster) -> torch.Tensor:
    """Planes ``(B, P, C + 2, res, res)`` of a neural texture ``(B, C, R, R)`` on a mesh
    rasterized by :func:`plane_raster`: as :func:`rasterize_planes`."""
    b, _, p, res, _ = raster.mask.shape
    reads = raster.reads
    mask = raster.mask.to(texture.dtype)
    if reads is not None and reads.res == texture.shape[-1] and \
            texture.shape[-2] == reads.res:  # zero already where nothing is covered
        feat = _gather_texture(texture, reads, b * p * res * res)
        feat = feat.view(-1, b, p, res, res).transpose(0, 1)
    else:
        feat = _read_texture(texture, raster.grid)  # (B, C, P res, res)
        feat = feat.view(b, -1, p, res, res) * mask
    out = torch.cat([feat, raster.surface.to(feat.dtype), mask], 1)  # (B, C + 2, P, res, res)
    return out.transpose(1, 2).contiguous()


def reading_pixels(raster: PlaneRaster, texels: torch.Tensor) -> torch.Tensor:
    """The covered plane pixels whose texture read touches any of ``texels``.

    Args:
        raster: Where a mesh lands on the planes (:func:`plane_raster`).
        texels: ``(R, R)`` bool texture mask.

    Returns:
        ``(N,)`` int64 flat indices into ``(B, P, res, res)``.
    """
    b, _, p, res, _ = raster.mask.shape
    near = _read_texture(texels.to(raster.grid.dtype)[None, None].expand(b, -1, -1, -1),
                         raster.grid)  # (B, 1, P res, res)
    hit = (near.view(b, p, res, res) > 0) & (raster.mask.view(b, p, res, res) > 0)
    return torch.nonzero(hit.reshape(-1)).squeeze(1)


def add_texture_change(planes: torch.Tensor, change: torch.Tensor, raster: PlaneRaster,
                       at: torch.Tensor) -> torch.Tensor:
    """Planes of ``texture + change`` from the planes of ``texture``, reading ``change``
    at the pixels ``at`` only: what :func:`texture_planes` gives when ``change`` is zero
    wherever :func:`reading_pixels` did not look (texture planes are linear in the
    texture), at the cost of those pixels rather than of every plane pixel.

    Args:
        planes: ``(B, P, C + 2, res, res)`` :func:`texture_planes` of the texture.
        change: ``(1, C, R, R)`` or ``(B, C, R, R)`` change of the texture.
        raster: The planes' :class:`PlaneRaster`.
        at: ``(N,)`` :func:`reading_pixels` of the texels where ``change`` is not zero.

    Returns:
        ``(B, P, C + 2, res, res)``.
    """
    b, p, c2, res, _ = planes.shape
    c = c2 - 2
    item, pixel = at // (p * res * res), at % (p * res * res)
    grid = raster.grid.reshape(b, -1, 2)[item, pixel]
    if change.shape[0] == 1:
        got = _read_texture(change, grid[None, :, None])[0, :, :, 0]
    else:
        got = _read_texture(change[item], grid[:, None, None])[:, :, 0, 0].T
    delta = torch.zeros(b, p, res * res, c, dtype=got.dtype, device=got.device)
    delta = delta.index_put((item, pixel // (res * res), pixel % (res * res)), got.T)
    feat = planes[:, :, :c] + delta.transpose(2, 3).reshape(b, p, c, res, res)
    return torch.cat([feat, planes[:, :, c:]], 2)


def rasterize_planes(verts: torch.Tensor, faces: torch.Tensor, uv: torch.Tensor,
                     faces_uv: torch.Tensor, texture: torch.Tensor, names: tuple[str, ...],
                     res: int, centre: tuple[float, float, float], half: float,
                     draw: torch.Tensor | None = None, under: ZBuffer | None = None,
                     cull_backfaces: bool = False) -> torch.Tensor:
    """Rasterize the textured mesh onto the planes.

    Args:
        verts: ``(B, V, 3)`` head coordinates.
        faces: ``(F, 3)``.
        uv: ``(T, 2)`` texture coordinates (v = 0 at the top of the texture).
        faces_uv: ``(F, 3)``.
        texture: ``(B, C, R, R)`` neural texture.
        names: Plane names (``P``).
        res: Plane resolution.
        centre, half: The planes' cube.
        draw, under: Draw only triangles ``draw (F,)`` over the others' depth test
            ``under`` (see :func:`plane_zbuffer` and :func:`~head360cli.geometry.
            rasterize.rasterize`).
        cull_backfaces: Drop the triangles each plane sees from behind. Only for a
            closed mesh with outward-facing triangles, where the surface a plane sees
            from outside is front-facing anyway (the head template: a third less work).

    Returns:
        ``(B, P, C + 2, res, res)``: texture features, surface height (metres towards the
        viewer) and coverage.
    """
    raster = plane_raster(verts, faces, uv, faces_uv, names, res, centre, half, draw, under,
                          cull_backfaces)
    if not (torch.is_grad_enabled() or exporting()) and \
            texture.shape[-1] == texture.shape[-2]:
        # a render: gathering the covered pixels' texels (a quarter of the pixels) beats
        # grid_sample's reads of every pixel, the indices included (12 -> 8.5 ms a frame);
        # an exported graph keeps grid_sample (no index sets that depend on the data)
        raster = texel_reads(raster, texture.shape[-1])
    return texture_planes(texture, raster)


def sample_planes(points: torch.Tensor, planes: torch.Tensor, names: tuple[str, ...],
                  centre: tuple[float, float, float], half: float, tau: float
                  ) -> torch.Tensor:
    """Features of points from the planes.

    Args:
        points: ``(B, N, 3)`` head coordinates.
        planes: ``(B, P, C + 2, R, R)`` from :func:`rasterize_planes`.
        names, centre, half: As there.
        tau: Metres over which a plane's feature fades away from its visible surface.

    Returns:
        ``(B, N, C + P + 1)``: the planes' features averaged with weights that favour the
        planes whose visible surface is near the point, each plane's offset from its
        surface (in units of ``tau``, clipped to +-4; +4 where the plane sees nothing),
        and the total weight.
    """
    b, n, _ = points.shape
    p, c2, r = planes.shape[1], planes.shape[2], planes.shape[-1]
    uv, height = plane_coordinates(points, names, centre, half)
    grid = uv.reshape(b * p, n, 1, 2)
    got = F.grid_sample(planes.reshape(b * p, c2, r, r), grid, mode="bilinear",
                        padding_mode="zeros", align_corners=False)  # (BP, C+2, N, 1)
    got = got.view(b, p, c2, n)  # a reshape, not a select: no copy in onnxruntime
    feat, surface, cover = got[:, :, :-2], got[:, :, -2], got[:, :, -1]
    # Coverage blends towards 0 at silhouettes; the surface height there is blended with
    # 0 too, so divide it back out where coverage is partial.
    seen = cover > 0.5
    surface = surface / cover.clamp_min(1e-3)
    offset = torch.where(seen, (height - surface) / tau, torch.full_like(height, 4.0))
    offset = offset.clamp(-4.0, 4.0)
    weight = cover * torch.exp(-offset.square())  # (B, P, N)
    total = weight.sum(1, keepdim=True)
    mixed = (feat * weight[:, :, None]).sum(1) / (total + 1e-3)  # (B, C, N)
    return torch.cat([mixed, offset, total], 1).transpose(1, 2)

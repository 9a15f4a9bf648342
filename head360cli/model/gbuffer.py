"""The deferred renderer's geometry pass: posed head and hair meshes rasterized once per
view into a G-buffer of surface attributes (texture coordinates, normal, view direction,
which mesh), at ``samples`` subpixel offsets per pixel. It holds no parameters; the
networks that turn a G-buffer into colour are in :mod:`head360cli.model.networks`.

The subpixel offsets are the corpus renderer's (:mod:`head360cli.synth.render`), so a
G-buffer of 2 samples averages to the same coverage as the corpus's antialiased views.

A hair mesh given its distances to its open edge is see-through there
(:func:`strand_opacity`: strands ending at staggered lengths), and where it is, the head
surface behind it is kept too, so that the shader can blend the two: hair with soft
edges instead of a cut-out shell.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from head360cli.geometry.cameras import project
from head360cli.geometry.mesh_ops import vertex_normals
from head360cli.geometry.rasterize import rasterize

__all__ = ["EAR_DEPTH", "FADE", "GRAZE", "OFFSETS", "STRANDS", "GBuffer", "MeshPart", "gbuffer",
           "strand_opacity"]

OFFSETS: dict[int, tuple[tuple[float, float], ...]] = {
    1: ((0.0, 0.0),),
    2: ((-0.25, -0.25), (0.25, 0.25)),
    4: ((-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)),
}
"""Subpixel sample offsets (pixels) for 1, 2 and 4 samples per pixel."""

FADE = 0.025
"""How far in from its open edge (metres along the surface) hair becomes opaque."""

STRANDS = 180
"""Strand bundles round the head (in the hair's u) whose ends are staggered over
:data:`FADE`: about 3 pixels each at 256 pixels, so the edge reads as strand tips."""

STAGGER = 0.5
"""Share of :data:`FADE` over which the bundles' ends are spread."""

_STAGGERS = torch.tensor(np.random.default_rng(0).uniform(0.0, 1.0, STRANDS),
                         dtype=torch.float32)
"""Where each bundle's end lies within the stagger (a table, not a hash of floats, so
torch and an exported graph draw the same strands)."""

GRAZE = 0.5
"""Facing (cosine of the view to the surface's normal) under which see-through hair
grows denser."""

EAR_DEPTH = 0.02
"""Hair up to this far (metres) behind an ear is drawn over it: an ear stands out of
the skull further than a thin shell of hair over it, and pierced the hair."""


def strand_opacity(dist: torch.Tensor, u: torch.Tensor, facing: torch.Tensor
                   ) -> torch.Tensor:
    """Opacity in [0, 1] of hair points at ``dist`` (metres, any shape) from the hair's
    open edge, ``u`` round the head and ``facing`` (the cosine between the surface's
    normal and the view; same shape). Seen squarely it is 0 at the edge and 1 from
    :data:`FADE` in, each of :data:`STRANDS` bundles reaching 1 at its own distance (a
    fixed draw per bundle, interpolated between bundles, so it is smooth in u). Seen
    obliquely, strands overlap: the transparency falls with ``facing`` under
    :data:`GRAZE`, to none edge-on (the side of a curtain of hair seen from the front
    is dense, where only its nearest layer is drawn)."""
    x = torch.remainder(u, 1.0) * STRANDS
    i0 = torch.floor(x)
    w = x - i0
    table = _STAGGERS.to(device=u.device, dtype=u.dtype)
    first = i0.long().clamp(0, STRANDS - 1)
    jitter = table[first] * (1 - w) + table[(first + 1) % STRANDS] * w
    t = (dist / FADE).clamp(0.0, 1.0)
    square = ((t - STAGGER * jitter) / (1.0 - STAGGER)).clamp(0.0, 1.0)
    return 1.0 - (1.0 - square) * (facing.abs() / GRAZE).clamp(max=1.0)


@dataclasses.dataclass
class MeshPart:
    """One mesh drawn into a G-buffer: ``verts (B, V, 3)`` in head coordinates,
    ``faces (F, 3)``, texture coordinates ``uv (T, 2)`` indexed by ``faces_uv (F, 3)``,
    and optional ``normal_groups (G, K)`` (vertices welded for normals); a hair mesh's
    ``edge (V,)``, each vertex's distance to its open edge (metres; it is see-through
    there), and a head's ``under_hair (F,)`` bool, its triangles that hair covers
    (ears: :data:`EAR_DEPTH`)."""

    verts: torch.Tensor
    faces: torch.Tensor
    uv: torch.Tensor
    faces_uv: torch.Tensor
    normal_groups: torch.Tensor | None = None
    edge: torch.Tensor | None = None
    under_hair: torch.Tensor | None = None


@dataclasses.dataclass
class GBuffer:
    """Surface attributes of ``S`` samples of ``B`` views, sample-major: ``R = S * B``
    rows, sample ``s`` of view ``b`` at row ``s * B + b``; the attributes are kept at the
    ``n`` covered sample points only.

    Attributes:
        samples: ``S``.
        index: ``(n,)`` flat indices (into ``R * H * W``) of the covered sample points.
        uv: ``(n, 2)`` their texture coordinates in [0, 1] (of the head's texture, or the
            hair's where ``hair`` is set).
        normal: ``(n, 3)`` unit surface normals in head coordinates.
        view: ``(n, 3)`` unit directions from the surface to the camera.
        hair: ``(n,)`` bool: the surface is the hair mesh.
        mask: ``(R, H, W)`` bool: a surface covers the sample point.
        hair_mask: ``(R, H, W)`` bool: that surface is the hair mesh.
        depth: ``(R, H, W)`` camera depth of the visible surface (0 where none).
        alpha: ``(n,)`` the opacity of each point's surface (1 but near the hair's
            edge), or ``None``: all opaque.
        under: ``(k,)`` the points (indices into the ``n``) that are not opaque and have
            the head's surface behind them; ``under_uv (k, 2)`` and ``under_normal
            (k, 3)`` are that surface's.
    """

    samples: int
    index: torch.Tensor
    uv: torch.Tensor
    normal: torch.Tensor
    view: torch.Tensor
    hair: torch.Tensor
    mask: torch.Tensor
    hair_mask: torch.Tensor
    depth: torch.Tensor
    alpha: torch.Tensor | None = None
    under: torch.Tensor | None = None
    under_uv: torch.Tensor | None = None
    under_normal: torch.Tensor | None = None

    @property
    def views(self) -> int:
        """``B``."""
        return self.depth.shape[0] // self.samples

    def mean(self, images: torch.Tensor) -> torch.Tensor:
        """Per-sample images ``(R, C, H, W)`` -> ``(B, C, H, W)``, averaged over the
        samples."""
        return images.view(self.samples, self.views, *images.shape[1:]).mean(0)

    def points_image(self, values: torch.Tensor) -> torch.Tensor:
        """Per-point ``values (n,)`` -> ``(B, 1, H, W)``, zero where no surface is,
        averaged over the samples."""
        r, h, w = self.mask.shape
        flat = values.new_zeros(r * h * w).index_copy(0, self.index, values)
        return self.mean(flat.view(r, 1, h, w))

    def coverage(self, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
        """``(B, 1, H, W)`` images of the share of each pixel covered by any surface, and
        by the hair (its opacity counted)."""
        if self.alpha is None:
            return (self.mean(self.mask[:, None].to(dtype)),
                    self.mean(self.hair_mask[:, None].to(dtype)))
        cover = self.alpha.to(dtype)
        if self.under is not None:
            cover = cover.index_add(0, self.under, 1.0 - cover.index_select(0, self.under))
        return self.points_image(cover), self.points_image(
            self.alpha.to(dtype) * self.hair.to(dtype))


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


def _fragments(part: MeshPart, cams: torch.Tensor, k: torch.Tensor, size: int,
               still: torch.Tensor | None = None, cache: dict | None = None):
    """The fragments of one mesh seen by ``R`` cameras (its ``verts`` given for
    ``R / S`` views, repeated over the samples). With ``still (F,)`` (the triangles that
    never move) and a ``cache`` kept between frames seen by the same cameras, the still
    triangles are drawn once and each frame draws the others over them (the same
    fragments)."""
    verts = part.verts.repeat(cams.shape[0] // part.verts.shape[0], 1, 1)
    pix, depth = project(verts, cams, k)
    if still is None or cache is None:
        return rasterize(pix, depth, part.faces, size, size, cull_backfaces=True)
    under = cache.get("still")
    if under is None:
        under = cache["still"] = rasterize(pix, depth, part.faces, size, size,
                                           cull_backfaces=True, draw=still).zbuffer
    return rasterize(pix, depth, part.faces, size, size, cull_backfaces=True,
                     draw=~still, under=under)


def _attributes(part: MeshPart, frags, at: torch.Tensor, rows: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Texture coordinates ``(m, 2)``, normals ``(m, 3)`` (not yet of unit length) and
    distances to the open edge ``(m,)`` (``None`` without ``part.edge``) of one mesh's
    fragments at flat sample points ``at (m,)``, whose view of ``part.verts`` is
    ``rows (m,)``."""
    fid = frags.face_id.reshape(-1).index_select(0, at)
    bary = frags.bary.reshape(-1, 3).index_select(0, at)[..., None]
    uv = (part.uv[part.faces_uv.index_select(0, fid)] * bary).sum(1)
    normals = vertex_normals(part.verts, part.faces, part.normal_groups)
    corners = part.faces.index_select(0, fid)  # (m, 3)
    flat = rows[:, None] * normals.shape[1] + corners
    normal = (normals.reshape(-1, 3)[flat.reshape(-1)].view(-1, 3, 3) * bary).sum(1)
    edge = None if part.edge is None else (part.edge[corners] * bary[..., 0]).sum(1)
    return uv, normal, edge


def _view_directions(cams: torch.Tensor, k: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """``(R, H, W, 3)`` unit directions from each sample point towards its camera, in
    head axes (minus the ray through the point)."""
    ys = torch.arange(h, dtype=cams.dtype, device=cams.device) + 0.5
    xs = torch.arange(w, dtype=cams.dtype, device=cams.device) + 0.5
    x = (xs[None, None, :] - k[:, 0, 2, None, None]) / k[:, 0, 0, None, None]
    y = (ys[None, :, None] - k[:, 1, 2, None, None]) / k[:, 1, 1, None, None]
    x, y = torch.broadcast_tensors(x, y)
    ray = torch.stack([x, y, torch.ones_like(x)], -1)
    ray = (ray[..., None, :] * cams[:, None, None, :3, :3]).sum(-1)
    return -torch.nn.functional.normalize(ray, dim=-1)


def gbuffer(head: MeshPart, c2w: torch.Tensor, intrinsics: torch.Tensor, size: int,
            samples: int = 1, hairs: list[tuple[MeshPart, torch.Tensor]] = (),
            still: torch.Tensor | None = None, cache: dict | None = None) -> GBuffer:
    """Rasterize heads (and hair) into a G-buffer.

    Args:
        head: The posed heads, ``verts (B, V, 3)``.
        c2w: ``(B, 4, 4)`` camera-to-world (OpenCV axes).
        intrinsics: ``(B, 3, 3)`` or ``(3, 3)`` for a ``size`` x ``size`` image.
        size: Image side in pixels.
        samples: Subpixel samples per pixel (1, 2 or 4: :data:`OFFSETS`).
        hairs: Hair meshes, each ``(mesh with verts (1, H, 3), views (B_h,))`` drawn
            with the heads of those views; the nearer surface wins each sample point.
        still: ``(F,)`` bool, the head's triangles that no expression moves, and
        cache: a dict kept between calls for the same cameras, hair and size (frames of
            an animation seen by a still camera): what depends on them alone (the still
            triangles' depth test, the hair's fragments, the view directions) is made
            once. The G-buffer is the same.

    Returns:
        The :class:`GBuffer` of the ``B`` views.
    """
    b = c2w.shape[0]
    cams, k = _sample_cameras(c2w, intrinsics, samples)
    frags = _fragments(head, cams, k, size, still, cache)
    mask = head_mask = frags.face_id >= 0
    depth = frags.depth
    slack = None  # how far behind the head's surface hair still wins (ears)
    if head.under_hair is not None and hairs:
        slack = head.under_hair.index_select(0, frags.face_id.clamp(min=0).reshape(-1)
                                             ).view_as(mask) & mask
        slack = slack.to(depth.dtype) * EAR_DEPTH
    hair_mask = torch.zeros_like(mask)
    drawn = []  # per hair mesh: (mesh, its rows, its fragments)
    for hair, items in hairs:
        rows = (items[None] + b * torch.arange(samples, device=c2w.device)[:, None]
                ).reshape(-1)
        hkey = None if cache is None else (
            "hair", hair.verts.data_ptr(), tuple(hair.verts.shape), tuple(items.tolist()))
        if hkey is not None and hkey in cache:
            hfrags = cache[hkey]
        else:
            hverts = hair.verts.expand(len(items), -1, -1)
            hfrags = _fragments(dataclasses.replace(hair, verts=hverts), cams[rows], k[rows],
                                size)
            if cache is not None:
                cache[hkey] = hfrags
        limit = depth[rows] if slack is None else depth[rows] + slack[rows]
        nearer = (hfrags.face_id >= 0) & (~mask[rows] | (hfrags.depth < limit))
        hair_mask = hair_mask.index_copy(0, rows, nearer)
        depth = depth.index_copy(0, rows, torch.where(nearer, hfrags.depth, depth[rows]))
        mask = mask.index_copy(0, rows, mask[rows] | nearer)
        drawn.append((hair, rows, hfrags))
    h, w = mask.shape[1:]
    index = torch.nonzero(mask.reshape(-1)).squeeze(1)
    is_hair = hair_mask.reshape(-1).index_select(0, index)
    row = index // (h * w)
    uv = torch.zeros(len(index), 2, dtype=c2w.dtype, device=c2w.device)
    normal = torch.zeros(len(index), 3, dtype=c2w.dtype, device=c2w.device)
    own = torch.nonzero(~is_hair).squeeze(1)
    at = index.index_select(0, own)
    got = _attributes(head, frags, at, row.index_select(0, own) % b)
    uv, normal = uv.index_copy(0, own, got[0]), normal.index_copy(0, own, got[1])
    edge = None  # distances to the hair's open edge (the head's points: FADE)
    if any(hair.edge is not None for hair, _, _ in drawn):
        edge = torch.zeros_like(index, dtype=c2w.dtype) + FADE
    for hair, rows, hfrags in drawn:
        # the hair's fragments are stored for its own rows: map each point's row there
        slot = torch.full((cams.shape[0],), -1, dtype=torch.long, device=c2w.device)
        slot[rows] = torch.arange(len(rows), device=c2w.device)
        mine = torch.nonzero(is_hair & (slot[row] >= 0)).squeeze(1)
        local = slot[row.index_select(0, mine)] * (h * w) + index.index_select(0, mine) % (
            h * w)
        got = _attributes(hair, hfrags, local, torch.zeros_like(mine))
        uv, normal = uv.index_copy(0, mine, got[0]), normal.index_copy(0, mine, got[1])
        if got[2] is not None:
            edge = edge.index_copy(0, mine, got[2])
    normal = torch.nn.functional.normalize(normal, dim=-1)
    if cache is None:
        view = _view_directions(cams, k, h, w)
    else:
        view = cache.get("view")
        if view is None:
            view = cache["view"] = _view_directions(cams, k, h, w)
    view = view.reshape(-1, 3).index_select(0, index)
    alpha = under = under_uv = under_normal = None
    if edge is not None:
        alpha = strand_opacity(edge, uv[:, 0], (normal * view).sum(-1))
        # where the hair is see-through, the head's own surface behind it is kept too
        under = torch.nonzero((alpha < 1) & head_mask.reshape(-1).index_select(0, index)
                              ).squeeze(1)
        got = _attributes(head, frags, index.index_select(0, under),
                          row.index_select(0, under) % b)
        under_uv, under_normal = got[0], torch.nn.functional.normalize(got[1], dim=-1)
    return GBuffer(samples, index, uv, normal, view, is_hair, mask, hair_mask, depth,
                   alpha, under, under_uv, under_normal)

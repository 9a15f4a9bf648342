"""The deferred generator: (mesh vertices, texture code or neural texture, hair, camera)
-> image, by deferred neural rendering.

    t --TextureGenerator--> neural texture (C, R, R)
    style, colour --HairTextureGenerator--> hair texture (C, r, r)
    posed head + hair meshes --gbuffer (rasterized once per view, S samples a pixel)-->
        per sample point: texture coordinates, normal, view direction, hair flag
    neural texture read at each point's own surface point --PixelShader--> colour and
        features --mean over the samples--> --ScreenNet (3x3, 3x3)--> RGB and alpha

Each pixel reads only the texels of the surface it shows, so a texel's change shows only
where its surface is seen (within the image network's two pixels). The texture's first
three channels act as albedo (see :class:`~head360cli.model.networks.PixelShader`), which
is what lets a fit write a photo's colours into it.

It takes the same arguments as the hex-plane :class:`~head360cli.model.generator.
Generator` and returns the same outputs, so fitting, animation and the benches drive
either; what serves only the hex-planes (samples per ray, plane rasters, decoded-point
reuse) is accepted and has nothing to do here.
"""

from __future__ import annotations

import contextlib
import dataclasses
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from head360cli.geometry.mesh_ops import edge_distance, seam_uv
from head360cli.geometry.rasterize import exporting
from head360cli.model.config import GeneratorConfig
from head360cli.model.gbuffer import FADE, GBuffer, MeshPart, gbuffer
from head360cli.model.generator import Hair, _hair_groups
from head360cli.model.networks import (
    GeneratorBase,
    HairTextureGenerator,
    PixelShader,
    ScreenNet,
    TextureGenerator,
)

__all__ = ["HAIR_TEXTURE_SIDE", "DeferredGenerator", "enlarged", "read_texels",
           "with_hair_detail"]


def exact_hair_colour(texture: torch.Tensor, colour: torch.Tensor) -> torch.Tensor:
    """Hair textures ``(B, C, r, r)`` whose albedo channels (0-2) are the colour of the
    corpus's strand texture of ``colour (B, 3)`` (linear RGB; plus 0.03 for near-black
    hair) times the network's strand shading (its albedo's brightness over its mean), as
    the corpus makes them. The network learnt ten colours and turns any other towards
    them (green came out grey); this keeps its strands and takes the colour asked for."""
    target = colour + 0.03 * (colour.amax(-1, keepdim=True) < 0.1).to(colour.dtype)
    bright = texture[:, :3].mean(1, keepdim=True).clamp_min(0.0)
    shade = bright / bright.mean((-2, -1), keepdim=True).clamp_min(1e-4)
    albedo = (target[..., None, None] * shade).clamp(0.0, 1.0)
    return torch.cat([albedo, texture[:, 3:]], 1)


HAIR_TEXTURE_SIDE = 256
"""Side of the hair texture renders read: the network's (64 texels a side) enlarged, so
that a fit's hair detail (made at this side) shows its strands at about a texel a
pixel, and every head's texture has one shape (one exported graph renders them all)."""


def enlarged(texture: torch.Tensor, side: int = HAIR_TEXTURE_SIDE) -> torch.Tensor:
    """A hair texture ``(B, C, r, r)`` bilinearly resized to ``side``."""
    if texture.shape[-1] == side:
        return texture
    return F.interpolate(texture, size=(side, side), mode="bilinear", align_corners=False)


def with_hair_detail(texture: torch.Tensor, detail: torch.Tensor, colour: torch.Tensor
                     ) -> torch.Tensor:
    """A hair texture ``(1, C, r, r)`` at the side ``A`` of a fit's hair ``detail (3, A,
    A)`` (its albedo over the colour), its albedo channels ``detail x colour (3,)``
    (the detail's range narrowed where that would pass white, and a texel brighter than
    white scaled down to it) and its other channels the network's, enlarged: the photo's
    strands, where the network's 64 texels a side drew a smooth shell."""
    feats = enlarged(texture[:, 3:], detail.shape[-1])
    detail = detail.to(texture.dtype).clamp_min(0)
    colour = colour.to(texture.dtype)
    # light hair has little room above it before white: the detail's range is narrowed
    # (a power below 1) until its 90th percentile, in the colour, reaches white at most;
    # capped there instead, a blonde's warm highlights went white and her cool shadows
    # stayed, and her hair rendered blue-grey
    room = 1.0 / colour.max().clamp_min(1e-3)
    high = torch.quantile(detail.amax(0).flatten(), 0.9).clamp_min(1e-3)
    if bool(high > room):
        power = (torch.log(room.clamp_min(1.0)) / torch.log(high)).clamp(0.0, 1.0)
        detail = detail.clamp_min(1e-3) ** power
    albedo = detail * colour[:, None, None]
    # above white, scaled down whole: clipped channel by channel, a blonde's highlights
    # lost their red first and rendered cyan
    albedo = albedo / albedo.amax(0, keepdim=True).clamp_min(1.0)
    return torch.cat([albedo[None], feats], 1)


def read_texels(table: torch.Tensor, base: torch.Tensor, res: torch.Tensor,
               uv: torch.Tensor) -> torch.Tensor:
    """Bilinear reads of textures stored texel by texel in one table.

    Args:
        table: ``(T, C)`` texels of several square textures, each row by row.
        base: ``(n,)`` the first row of each point's texture in ``table``.
        res: ``(n,)`` that texture's side.
        uv: ``(n, 2)`` where to read it, in [0, 1] (v down; texel centres at
            ``(i + 0.5) / res``, the border texels held beyond them).

    Returns:
        ``(n, C)``; its gradient reaches only the four texels each point reads.
    """
    side = res.to(uv.dtype)
    x = (uv[:, 0] * side - 0.5).clamp(min=0.0)
    y = (uv[:, 1] * side - 0.5).clamp(min=0.0)
    top = res - 1
    x0 = x.floor().long().clamp(max=top)
    y0 = y.floor().long().clamp(max=top)
    wx = (x - x0.to(x.dtype)).clamp(0.0, 1.0)[:, None]
    wy = (y - y0.to(y.dtype)).clamp(0.0, 1.0)[:, None]
    x1 = (x0 + 1).clamp(max=top)
    y1 = (y0 + 1).clamp(max=top)

    def at(yy: torch.Tensor, xx: torch.Tensor) -> torch.Tensor:
        return table.index_select(0, base + yy * res + xx)

    return ((at(y0, x0) * (1 - wx) + at(y0, x1) * wx) * (1 - wy)
            + (at(y1, x0) * (1 - wx) + at(y1, x1) * wx) * wy)


class DeferredGenerator(GeneratorBase):
    """The deferred head generator: texture generators, pixel shader, image network.

    Args:
        cfg: Sizes (``renderer="deferred"``).
        faces: ``(F, 3)`` triangles of the head topology.
        uv: ``(T, 2)`` texture coordinates.
        faces_uv: ``(F, 3)`` indices into ``uv``.
        normal_groups: ``(G, K)`` vertices welded for normals (the template's), or
            ``None``.
        under_hair: ``(F,)`` bool, the triangles hair is drawn over when it is close
            behind them (the ears; :data:`~head360cli.model.gbuffer.EAR_DEPTH`), or
            ``None``.
    """

    kind = "deferred"
    """Which generator this is (the hex-plane ``Generator.kind`` is ``"hexplane"``)."""
    soft_hairlines = True
    """Run-time hair meshes have soft hairlines, whatever the corpus had: the hair texture
    is read at each pixel's strand UV, which the soft mesh keeps, so the stair steps go
    and the learnt texture stays (measured: docs/decisions.md)."""

    def __init__(self, cfg: GeneratorConfig, faces: np.ndarray, uv: np.ndarray,
                 faces_uv: np.ndarray, normal_groups: np.ndarray | None = None,
                 under_hair: np.ndarray | None = None) -> None:
        if cfg.pixel_samples not in (1, 2, 4):
            raise ValueError(f"expected pixel_samples 1, 2 or 4, found {cfg.pixel_samples}")
        super().__init__(cfg)
        self.register_buffer("faces", torch.as_tensor(np.asarray(faces), dtype=torch.long))
        self.register_buffer("uv", torch.as_tensor(np.asarray(uv), dtype=torch.float32))
        self.register_buffer("faces_uv",
                             torch.as_tensor(np.asarray(faces_uv), dtype=torch.long))
        self.normal_groups = (None if normal_groups is None else
                              torch.as_tensor(np.asarray(normal_groups), dtype=torch.long))
        self.register_buffer("under_hair", None if under_hair is None else torch.as_tensor(
            np.asarray(under_hair), dtype=torch.bool), persistent=False)
        self.cull_rays = self.hair_rays_only = True  # hex-plane settings; nothing here
        self.texture_generator = TextureGenerator.from_config(cfg)
        self.shader = PixelShader(cfg.texture_channels, cfg.hidden, cfg.shader_extra)
        self.refine = ScreenNet(3 + cfg.shader_extra + 1, cfg.refine_width) \
            if cfg.refine else None
        if cfg.hair:
            self.hair_texture_generator = HairTextureGenerator(cfg)

    def _apply(self, fn, recurse: bool = True):  # keep the plain tensor on the device
        out = super()._apply(fn, recurse)
        if self.normal_groups is not None:
            self.normal_groups = fn(self.normal_groups)
        return out


    def samples_per_ray(self, samples: int | None) -> contextlib.AbstractContextManager:
        """Nothing to change: a deferred render has no rays (kept so that callers drive
        either generator)."""
        return self._override()

    def pixel_samples(self, samples: int | None) -> contextlib.AbstractContextManager:
        """Render with ``samples`` subpixel samples a pixel (1, 2 or 4) inside the
        ``with`` block (``None``: the configured count)."""
        if samples is None:
            return self._override()
        if samples not in (1, 2, 4):
            raise ValueError(f"expected 1, 2 or 4 samples a pixel, found {samples}")
        return self._override(pixel_samples=int(samples))

    def image_size(self, size: int | None) -> contextlib.AbstractContextManager:
        """Render ``size`` x ``size`` images inside the ``with`` block (``None``: the
        trained size); the low-resolution copies keep about their ratio.

        Raises:
            ValueError: ``size`` is odd or under 16.
        """
        if size is None:
            return self._override()
        if size < 16 or size % 2:
            raise ValueError(f"expected an image size that is a multiple of 2 and at least "
                             f"16, found {size}")
        ratio = self.cfg.image_res // self.cfg.render_res
        return self._override(image_res=int(size), render_res=max(int(size) // ratio, 1))

    def texture(self, code: torch.Tensor) -> torch.Tensor:
        """``(B, code_dim)`` -> neural texture ``(B, C, R, R)``."""
        return self.texture_generator(code)

    def plane_raster(self, verts: torch.Tensor) -> None:
        """Nothing: a deferred render rasterizes per camera (kept for callers of both
        generators; pass ``view_rays`` to keep a fixed camera's G-buffer)."""
        return None

    def prepare_hair(self, hair: Hair) -> Hair:
        """The same hair with its textures made now (kept in ``Hair.planes``), so that
        renders of many frames or views reuse them; outside training they are
        :data:`HAIR_TEXTURE_SIDE` texels a side, and an item with a ``Hair.detail``
        takes its albedo from it (:func:`with_hair_detail`); its ``Hair.edges`` too
        (renders make the strand ends see-through from them)."""
        items = [i for i, m in enumerate(hair.meshes) if m is not None]
        textures: list[torch.Tensor | None] = [None] * len(hair.meshes)
        if items:
            idx = torch.tensor(items, device=hair.style.device)
            tex = self.hair_texture_generator(hair.style[idx], hair.colour[idx])
            if not self.training:
                tex = enlarged(exact_hair_colour(tex, hair.colour[idx]))
            made: dict[int, torch.Tensor] = {}
            for j, i in enumerate(items):  # one texture per mesh object (views of a head)
                detail = None if hair.detail is None else hair.detail[i]
                if id(hair.meshes[i]) not in made and detail is not None:
                    made[id(hair.meshes[i])] = with_hair_detail(tex[j:j + 1], detail,
                                                                hair.colour[i])
                textures[i] = made.setdefault(id(hair.meshes[i]), tex[j:j + 1])
        edges = None  # training draws the corpus's opaque hair
        if not self.training:
            edges, done = [None] * len(hair.meshes), {}
            for i in items:
                key = id(hair.meshes[i])
                if key not in done:
                    done[key] = edge_distance(*hair.meshes[i], FADE)
                edges[i] = done[key]
        return dataclasses.replace(hair, planes=textures, edges=edges)

    def gbuffer(self, verts: torch.Tensor, c2w: torch.Tensor, intrinsics: torch.Tensor,
                hair: Hair | None = None, cache: dict | None = None) -> GBuffer:
        """The G-buffer of posed heads ``verts (B, V, 3)`` (and their hair) from cameras
        ``c2w (B, 4, 4)`` with ``intrinsics (B, 3, 3)`` at the current image size;
        ``cache``: see :meth:`forward`'s ``reuse``. Outside training the hair is
        see-through near its open edge and drawn over the ears
        (:mod:`~head360cli.model.gbuffer`); training keeps the corpus's opaque hair."""
        soft = not self.training
        head = MeshPart(verts, self.faces, self.uv, self.faces_uv, self.normal_groups,
                        under_hair=self.under_hair if soft else None)
        parts = []
        if hair is not None:
            items = [i for i, m in enumerate(hair.meshes) if m is not None]
            for g in _hair_groups(hair, items):
                hv, hf, huv = hair.meshes[g[0]]
                wrapped, faces_uv = seam_uv(hf, huv)
                edge = None
                if soft:  # made once by prepare_hair, or here (an exported graph)
                    edge = (hair.edges[g[0]] if hair.edges is not None
                            else edge_distance(hv, hf, huv, FADE))
                parts.append((MeshPart(hv[None], hf, wrapped, faces_uv, edge=edge),
                              torch.tensor(g, device=verts.device)))
        still = None if cache is None else cache.get("still_faces")
        return gbuffer(head, c2w, intrinsics, self.cfg.image_res, self.cfg.pixel_samples,
                       parts, still, cache)


    def shade(self, buf: GBuffer, texture: torch.Tensor, hair: Hair | None
              ) -> tuple[torch.Tensor, torch.Tensor]:
        """Shaded sample points of ``buf`` as images ``(B, 3 + extra, H, W)``,
        premultiplied by coverage and averaged over the samples, and the mean absolute
        residual of the shader (what its light did not explain). Only covered points are
        read and decoded."""
        b, c, res = texture.shape[0], texture.shape[1], texture.shape[-1]
        r, h, w = buf.mask.shape
        index, uv, is_hair = buf.index, buf.uv, buf.hair
        view_of = (index // (h * w)) % b
        # texels row by row (a view, no copy, of a channels-last texture)
        table = texture.permute(0, 2, 3, 1).reshape(-1, c)
        if hair is None or not (exporting() or bool(is_hair.any())):
            feats = read_texels(table, view_of * (res * res), torch.full_like(index, res), uv)
        else:
            own = torch.nonzero(~is_hair).squeeze(1)
            feats = uv.new_zeros(len(index), c).index_copy(0, own, read_texels(
                table, view_of.index_select(0, own) * (res * res),
                torch.full_like(own, res), uv.index_select(0, own)))
            items = [i for i, m in enumerate(hair.meshes) if m is not None]
            for g in _hair_groups(hair, items):
                tex = hair.planes[g[0]][0]
                wearer = torch.zeros(b, dtype=torch.bool, device=index.device)
                wearer[g] = True
                sel = torch.nonzero(is_hair & wearer[view_of]).squeeze(1)
                side = tex.shape[-1]
                at = uv.index_select(0, sel)  # u wraps round the head (seam_uv)
                at = torch.stack([torch.remainder(at[:, 0], 1.0), at[:, 1]], 1)
                feats = feats.index_copy(0, sel, read_texels(
                    tex.permute(1, 2, 0).reshape(-1, c), torch.zeros_like(sel),
                    torch.full_like(sel, side), at))
        values, residual = self._net(self.shader, feats, buf.normal, buf.view,
                                     is_hair[:, None].to(feats.dtype))
        if buf.alpha is not None:
            # see-through hair over the head's own surface behind it
            alpha = buf.alpha.to(values.dtype)[:, None]
            values = values * alpha
            under = buf.under
            below = read_texels(table, view_of.index_select(0, under) * (res * res),
                                torch.full_like(under, res), buf.under_uv)
            shaded, _ = self._net(self.shader, below, buf.under_normal,
                                  buf.view.index_select(0, under),
                                  below.new_zeros(len(under), 1))
            values = values.index_add(0, under, shaded * (1 - alpha.index_select(0, under)))
        out = values.new_zeros(r * h * w, values.shape[1]).index_copy(0, index, values)
        return buf.mean(out.view(r, h, w, -1).permute(0, 3, 1, 2)), residual.abs().mean()

    def forward(self, verts: torch.Tensor, c2w: torch.Tensor, intrinsics: torch.Tensor, *,
                code: torch.Tensor | None = None, texture: torch.Tensor | None = None,
                hair: Hair | None = None, jitter: bool = False, reuse: Any = None,
                plane_raster: Any = None, head_planes: torch.Tensor | None = None,
                view_rays: dict[str, Any] | None = None) -> dict[str, Any]:
        """Render heads.

        Args:
            verts: ``(B, V, 3)`` posed mesh in head coordinates (metres).
            c2w: ``(B, 4, 4)`` camera-to-world (OpenCV axes).
            intrinsics: ``(B, 3, 3)`` or ``(3, 3)`` for an ``image_res`` image.
            code: ``(B, code_dim)`` texture codes, or
            texture: ``(B, C, R, R)`` neural textures (inversion optimises these).
            hair: The items' hair; ``None`` renders bald heads.
            jitter, plane_raster: Hex-plane options; nothing here.
            reuse: A dict kept between the frames of an animation seen by one still
                camera (one-item batches, the same hair and size), holding
                ``still_faces (F,)``, the triangles no expression moves: what depends on
                the camera alone is made once there (the same images); anything else
                (a hex-plane ``DecodeReuse``) is ignored.
            head_planes: Not for this generator (change the texture instead).
            view_rays: A dict the caller keeps between renders of the same ``verts``,
                cameras and hair that change only the texture: the first render keeps
                its G-buffer there, the others read it.

        Returns:
            ``rgb (B, 3, H, W)`` on a white background, ``alpha`` and ``hair_alpha``
            ``(B, 1, H, W)``, their ``*_low`` copies and ``depth_low`` at
            ``render_res``, the ``texture``, the shader's mean absolute ``residual``,
            and with hair ``hair_texture (B, C, r, r)`` (zero for bald items).
        """
        c = self.cfg
        if head_planes is not None:
            raise ValueError("expected a texture: the deferred generator has no head "
                             "planes")
        if texture is None:
            if code is None:
                raise ValueError("expected a texture code or a neural texture, found neither")
            texture = self.texture(code)
        if hair is not None and not c.hair:
            raise ValueError("expected no hair: this generator was built without a hair "
                             "branch")
        b = verts.shape[0]
        k = intrinsics.expand(b, 3, 3)
        if hair is not None and hair.planes is None:
            hair = self.prepare_hair(hair)
        cache = reuse if isinstance(reuse, dict) else None
        if cache is not None and b != 1:
            raise ValueError(f"expected one item to reuse a still camera's G-buffer, found "
                             f"{b}")
        if view_rays is not None and "gbuffer" in view_rays:
            buf = view_rays["gbuffer"]
        else:
            # the G-buffer carries gradients only to a camera or mesh being fitted (the
            # texture lookups move with them); training and renders build it without
            fitted = c2w.requires_grad or verts.requires_grad
            with torch.set_grad_enabled(torch.is_grad_enabled() and fitted):
                buf = self.gbuffer(verts, c2w, k, hair, cache)
            if view_rays is not None:
                view_rays["gbuffer"] = buf
        image, residual = self.shade(buf, texture, hair)
        coverage, hair_alpha = buf.coverage(image.dtype)
        if self.refine is not None:
            rgb, alpha = self._net(self.refine, image, coverage)
        else:
            rgb, alpha = image[:, :3] + (1.0 - coverage), coverage
        low = [F.adaptive_avg_pool2d(x, c.render_res) for x in (rgb, alpha, hair_alpha)]
        depth = F.adaptive_avg_pool2d(buf.depth[:b, None], c.render_res)
        out = {"rgb": rgb, "alpha": alpha, "hair_alpha": hair_alpha, "rgb_low": low[0],
               "alpha_low": low[1], "hair_alpha_low": low[2], "depth_low": depth,
               "texture": texture, "residual": residual}
        if hair is not None and any(p is not None for p in hair.planes):
            made = next(p for p in hair.planes if p is not None)
            out["hair_texture"] = torch.cat([made * 0 if p is None else p
                                             for p in hair.planes])
        return out

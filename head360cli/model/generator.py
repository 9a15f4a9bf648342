"""The generator: (mesh vertices, texture code or neural texture, hair, camera) -> image.

    t --TextureGenerator--> neural texture (C, R, R)
    vertices + texture --rasterize_planes--> head hex-planes (P, C + 2, res, res)
    style, colour --HairTextureGenerator--> hair texture --on the style's mesh--> hair planes
    camera --screen_depth of head and hair--> points around the nearest surface
    points --sample_planes--> features --Decoder (head), Decoder (hair)--> densities, colours
    --composite--> feature image, alpha, hair alpha (render_res) --RefineNet--> RGB, alpha

The vertices come from the parametric head (:class:`head360cli.mesh.bilinear.BilinearHead`
for codes ``s`` and ARKit weights ``w``) or straight from a mesh of the same topology. The
hair's geometry is the hairstyle's mesh fitted to the neutral head
(:func:`head360cli.synth.hair.fit_hair`); what the hair branch learns is its appearance and
density around that mesh. Items without hair skip the hair branch.
"""

from __future__ import annotations

import contextlib
import dataclasses
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from head360cli.model.config import GeneratorConfig
from head360cli.model.networks import (
    Decoder,
    GeneratorBase,
    HairTextureGenerator,
    RefineNet,
    TextureGenerator,
    onednn_decodes,
)
from head360cli.model.planes import (
    PLANE_SETS,
    PlaneRaster,
    plane_raster,
    plane_zbuffer,
    rasterize_planes,
    sample_planes,
    texel_reads,
    texture_planes,
)
from head360cli.model.render import EMPTY, composite, samples_around, screen_depth
from head360cli.model.reuse import DecodeReuse

__all__ = ["HAIR_MARGIN", "HEAD_CLOSED", "Generator", "Hair", "hair_for", "near_rays"]

DECODE_BLOCK = 2048
"""Where the decoders run through oneDNN on a CPU (bfloat16 networks, and every render
without gradients: :func:`~head360cli.model.networks.onednn_decodes`), their inputs are
padded to a multiple of this many points: oneDNN keeps a primitive per input shape, and
an animation's point count changes every frame, so without padding its memory grew with
the frames (measurements: docs/decisions.md)."""

HEAD_CLOSED = True
"""The head template is a closed mesh with outward-facing triangles (a test checks it),
so the surface each hex-plane sees from outside is front-facing: its planes are
rasterized with back faces culled, the same planes (13 of 22667 covered plane pixels
took another triangle, all at silhouettes, on the fitted astronaut) for a third less
rasterizing (34 -> 23 ms a frame on 2 cores). Hair meshes are drawn without culling."""

HAIR_MARGIN = 2
"""Pixels (at ``render_res``) around the hair mesh's silhouette where the hair branch is
still decoded when :attr:`Generator.hair_rays_only` is on."""


@dataclasses.dataclass
class Hair:
    """The hair of each item of a batch.

    Attributes:
        meshes: Per item ``(verts (H, 3), faces (G, 3), uv (H, 2))`` tensors of the
            hairstyle's mesh, or ``None`` for a bald item.
        style: ``(B,)`` hairstyle ids.
        colour: ``(B, 3)`` hair colours, RGB in [0, 1].
        planes: Per item hair planes ``(1, P, C + 2, res, res)`` made once by
            :meth:`Generator.prepare_hair` (``None`` for a bald item), or ``None``: the
            generator makes them on every call (training, where the hair branch learns).
        detail: Per item ``(3, A, A)`` the hair's albedo over its colour in strand
            coordinates (a fit's, :mod:`~head360cli.fitting.hair_texture`), or ``None``
            (the generator's own strands); ``None`` for all: none has one.
        edges: Per item ``(H,)`` its vertices' distances along their strands to the
            strands' ends (:func:`~head360cli.geometry.mesh_ops.edge_distance`), made
            once by the deferred generator's ``prepare_hair``, or ``None``: made on
            every render that needs them.
    """

    meshes: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None]
    style: torch.Tensor
    colour: torch.Tensor
    planes: list[torch.Tensor | None] | None = None
    detail: list[torch.Tensor | None] | None = None
    edges: list[torch.Tensor | None] | None = None

    def to(self, device: torch.device | str) -> Hair:
        def moved(items):
            return None if items is None else [None if p is None else p.to(device)
                                               for p in items]

        return Hair([None if m is None else tuple(t.to(device) for t in m)
                     for m in self.meshes], self.style.to(device), self.colour.to(device),
                    moved(self.planes), moved(self.detail), moved(self.edges))

    def repeat(self, n: int) -> Hair:
        """The hair of a one-item batch for ``n`` items (views or frames of one head)."""
        return Hair(self.meshes * n, self.style.expand(n), self.colour.expand(n, 3),
                    None if self.planes is None else self.planes * n,
                    None if self.detail is None else self.detail * n,
                    None if self.edges is None else self.edges * n)


def hair_for(neutral: np.ndarray, styles: list[int], colours: np.ndarray,
             offsets: np.ndarray | None = None, soft: bool = False,
             scales: np.ndarray | None = None, end_shifts: np.ndarray | None = None
             ) -> Hair:
    """Hair of hairstyles ``styles`` and ``colours (B, 3)`` fitted to neutral heads
    ``(B, V, 3)`` (or one ``(V, 3)`` head for all), each moved by ``offsets (B, 3)``
    metres in the head's frame (a fit's hair placement; default: not moved) and its
    thickness scaled by ``scales (B, WARP_BINS)`` (a fit's; default: as built,
    :func:`~head360cli.synth.hair.warp_hair`) and its ends moved by ``end_shifts (B,)``
    metres (a fit's length, :attr:`~head360cli.synth.hair.HairStyle.end_shift`);
    ``soft`` hairlines for a generator trained on them (``GeneratorConfig.soft_hair``)."""
    from head360cli.synth.hair import fit_hair

    neutral = np.asarray(neutral)
    shift = (np.zeros((len(styles), 3)) if offsets is None
             else np.broadcast_to(np.asarray(offsets, np.float64), (len(styles), 3)))
    meshes: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None] = []
    for i, style in enumerate(styles):
        m = fit_hair(neutral if neutral.ndim == 2 else neutral[i], int(style), soft=soft,
                     scale=None if scales is None else scales[i],
                     end_shift=0.0 if end_shifts is None else float(end_shifts[i]))
        meshes.append(None if len(m.faces) == 0 else (
            torch.tensor(m.verts + shift[i], dtype=torch.float32), torch.tensor(m.faces),
            torch.tensor(m.uv, dtype=torch.float32)))
    return Hair(meshes, torch.tensor(list(styles), dtype=torch.long),
                torch.as_tensor(np.asarray(colours, dtype=np.float32)).reshape(-1, 3))


def _hair_groups(hair: Hair | None, items: list[int]) -> list[list[int]]:
    """``items`` grouped by the hair they wear: the same mesh and planes objects (frames
    or views of one head, ``Hair.repeat``), so that a group is drawn and decoded in one
    call rather than item by item."""
    groups: dict[tuple[int, int], list[int]] = {}
    for i in items:
        groups.setdefault((id(hair.meshes[i]), id(hair.planes[i])), []).append(i)
    return list(groups.values())


def near_rays(near: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The rays worth decoding.

    Args:
        near: ``(B, R)`` 1 where a ray passes near a surface (from ``samples_around``).

    Returns:
        ``order (B, n)``: ray indices, the near ones first and in order, ``n`` the largest
        count of near rays in the batch (at least 1); ``kept (B, n)`` bool, which of them
        are near. A one-item batch takes its near rays with ``nonzero`` (plus ray 0, so
        ``n >= 1``), which needs no Python integer from the data and so exports to ONNX
        with a data-dependent ray count.
    """
    keep = near > 0
    if keep.shape[0] == 1:
        first = torch.zeros_like(keep)
        first[:, 0] = True
        order = torch.nonzero(keep[0] | first[0]).reshape(1, -1)
        return order, torch.gather(keep, 1, order)
    n = max(int(keep.sum(1).max()), 1)
    order = torch.argsort((~keep).to(torch.uint8), dim=1, stable=True)[:, :n]
    return order, torch.gather(keep, 1, order)


class Generator(GeneratorBase):
    """The paper's hex-plane head generator: head branch, hair branch, volume renderer and
    RefineNet.

    Args:
        cfg: Sizes.
        faces: ``(F, 3)`` triangles of the head topology.
        uv: ``(T, 2)`` texture coordinates.
        faces_uv: ``(F, 3)`` indices into ``uv``.
    """

    kind = "hexplane"
    """Which generator this is (``DeferredGenerator.kind`` is ``"deferred"``)."""

    @property
    def soft_hairlines(self) -> bool:
        """Whether run-time hair meshes have soft hairlines: as the corpus it learnt had
        them (its hair planes learnt where that corpus's hair was)."""
        return self.cfg.soft_hair

    def __init__(self, cfg: GeneratorConfig, faces: np.ndarray, uv: np.ndarray,
                 faces_uv: np.ndarray) -> None:
        if cfg.planes not in PLANE_SETS:
            raise ValueError(f"expected planes hex or tri, found {cfg.planes!r}")
        super().__init__(cfg)
        self.plane_names = PLANE_SETS[cfg.planes]
        self.register_buffer("faces", torch.as_tensor(np.asarray(faces), dtype=torch.long))
        self.register_buffer("uv", torch.as_tensor(np.asarray(uv), dtype=torch.float32))
        self.register_buffer("faces_uv",
                             torch.as_tensor(np.asarray(faces_uv), dtype=torch.long))
        self.cull_rays = True
        """Decode only rays near a surface (same image, less work); export turns it off
        for static shapes."""
        self.hair_rays_only = True
        """Decode the hair branch only on rays within :data:`HAIR_MARGIN` pixels of the
        hair mesh (elsewhere its density is taken as zero: a close approximation, measured
        in the tests); export turns it off for static shapes."""
        self.texture_generator = TextureGenerator.from_config(cfg)
        self.decoder = Decoder(cfg, len(self.plane_names))
        self.refine = RefineNet(cfg) if cfg.refine else None
        if cfg.hair:
            self.hair_texture_generator = HairTextureGenerator(cfg)
            self.hair_decoder = Decoder(cfg, len(self.plane_names))


    def samples_per_ray(self, samples: int | None) -> contextlib.AbstractContextManager:
        """Render with ``samples`` per ray inside the ``with`` block (``None``: keep the
        configured count); the config is restored afterwards, errors included."""
        return self._override() if samples is None else self._override(samples=int(samples))

    def image_size(self, size: int | None) -> contextlib.AbstractContextManager:
        """Render ``size`` x ``size`` images inside the ``with`` block (``None``: the
        trained size). The volume-rendered features keep their ratio to the output
        (``render_res / image_res``), so more pixels also mean more rays; intrinsics must be
        given for ``size``.

        Raises:
            ValueError: ``size`` is not a multiple of ``image_res / render_res``.
        """
        if size is None:
            return self._override()
        ratio = self.cfg.image_res // self.cfg.render_res
        if size < ratio * 8 or size % ratio:
            raise ValueError(f"expected an image size that is a multiple of {ratio} and at "
                             f"least {ratio * 8}, found {size}")
        return self._override(image_res=int(size), render_res=int(size) // ratio)


    def _decode(self, net: nn.Module, feats: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """``net(feats)`` for a decoder, ``feats (B, N, D)`` -> ``(B, N)`` and
        ``(B, N, C)``, padded to :data:`DECODE_BLOCK` points where oneDNN runs it."""
        n = feats.shape[1]
        onednn = onednn_decodes(feats) or (self.network_dtype is not None
                                           and feats.device.type == "cpu")
        if not onednn or n % DECODE_BLOCK == 0:
            return self._net(net, feats)
        pad = feats.new_zeros(feats.shape[0], DECODE_BLOCK - n % DECODE_BLOCK,
                              feats.shape[2])
        density, colour = self._net(net, torch.cat([feats, pad], 1))
        return density[:, :n], colour[:, :n]

    def texture(self, code: torch.Tensor) -> torch.Tensor:
        """``(B, code_dim)`` -> neural texture ``(B, C, R, R)``."""
        return self.texture_generator(code)

    def planes(self, verts: torch.Tensor, texture: torch.Tensor,
               raster: PlaneRaster | None = None) -> torch.Tensor:
        """Hex-planes ``(B, P, C + 2, res, res)`` of a posed mesh ``(B, V, 3)``; with
        ``raster`` (:meth:`plane_raster` of the same ``verts``) only the texture is read."""
        if raster is not None:
            return texture_planes(texture, raster)
        c = self.cfg
        return rasterize_planes(verts, self.faces, self.uv, self.faces_uv, texture,
                                self.plane_names, c.plane_res, c.plane_centre,
                                c.plane_half_size, cull_backfaces=HEAD_CLOSED)

    def plane_raster(self, verts: torch.Tensor) -> PlaneRaster:
        """Where a posed mesh ``(B, V, 3)`` lands on the hex-planes, for any texture: give
        it to :meth:`forward` as ``plane_raster`` to render the same mesh many times
        (a texture inversion) without rasterizing it each time. It carries the texture
        reads worked out for this generator's texture size (:func:`~head360cli.model.
        planes.texel_reads`), which the texture's gradient needs far less time through."""
        c = self.cfg
        return texel_reads(plane_raster(verts, self.faces, self.uv, self.faces_uv,
                                        self.plane_names, c.plane_res, c.plane_centre,
                                        c.plane_half_size, cull_backfaces=HEAD_CLOSED),
                           c.texture_res)

    def hair_planes(self, mesh: tuple[torch.Tensor, torch.Tensor, torch.Tensor],
                    texture: torch.Tensor) -> torch.Tensor:
        """Hair planes ``(1, P, C + 2, res, res)`` of one hair mesh and its texture
        ``(1, C, R, R)``. They depend on the hair only, so animation reuses them."""
        c = self.cfg
        verts, faces, uv = mesh
        return rasterize_planes(verts[None], faces, uv, faces, texture, self.plane_names,
                                c.plane_res, c.hair_plane_centre, c.hair_plane_half_size)

    def _still(self, verts: torch.Tensor, reuse: DecodeReuse | None
               ) -> tuple[torch.Tensor, torch.Tensor] | None:
        """``(triangles no expression moves (F,), their vertices' positions)`` when
        ``reuse`` knows the still vertices, else ``None``."""
        if reuse is None or reuse.still_vertices is None:
            return None
        faces = reuse.still_vertices[self.faces].all(1)
        return faces, verts[0].index_select(0, reuse.still_index)

    def _head_depth(self, verts: torch.Tensor, c2w: torch.Tensor, k: torch.Tensor,
                    reuse: DecodeReuse | None,
                    still: tuple[torch.Tensor, torch.Tensor] | None) -> torch.Tensor:
        """The head's screen depth; with ``still`` (from :meth:`_still`) and ``reuse``,
        the triangles no expression moves are drawn once per camera and the others over
        them each frame (the same depth)."""
        res = self.cfg.render_res
        if still is None or reuse is None:
            return screen_depth(verts, self.faces, c2w, k, res)
        faces, pos = still
        under = reuse.kept("head_depth_under", (pos, c2w[0], k[0]), lambda: screen_depth(
            verts, self.faces, c2w, k, res, draw=faces, zbuffer=True)[1])
        return screen_depth(verts, self.faces, c2w, k, res, draw=~faces, under=under)

    def _head_planes(self, verts: torch.Tensor, texture: torch.Tensor,
                     reuse: DecodeReuse | None,
                     still: tuple[torch.Tensor, torch.Tensor] | None,
                     raster: PlaneRaster | None = None) -> torch.Tensor:
        """:meth:`planes`; with ``still``, the still triangles drawn once (as
        :meth:`_head_depth`)."""
        if still is None:
            return self.planes(verts, texture, raster)
        faces, pos = still
        c = self.cfg
        under = reuse.kept("planes_under", (pos,), lambda: plane_zbuffer(
            verts, self.faces, self.plane_names, c.plane_res, c.plane_centre,
            c.plane_half_size, draw=faces, cull_backfaces=HEAD_CLOSED))
        return rasterize_planes(verts, self.faces, self.uv, self.faces_uv, texture,
                                self.plane_names, c.plane_res, c.plane_centre,
                                c.plane_half_size, draw=~faces, under=under,
                                cull_backfaces=HEAD_CLOSED)

    def prepare_hair(self, hair: Hair) -> Hair:
        """The same hair with its planes made now, so that renders of many frames or views
        reuse them (they depend on the hairstyle and colour only)."""
        items = [i for i, m in enumerate(hair.meshes) if m is not None]
        planes: list[torch.Tensor | None] = [None] * len(hair.meshes)
        if items:
            idx = torch.tensor(items, device=hair.style.device)
            tex = self.hair_texture_generator(hair.style[idx], hair.colour[idx])
            for j, i in enumerate(items):
                planes[i] = self.hair_planes(hair.meshes[i], tex[j:j + 1])
        return dataclasses.replace(hair, planes=planes)

    def forward(self, verts: torch.Tensor, c2w: torch.Tensor, intrinsics: torch.Tensor, *,
                code: torch.Tensor | None = None, texture: torch.Tensor | None = None,
                hair: Hair | None = None, jitter: bool = False,
                reuse: DecodeReuse | None = None,
                plane_raster: PlaneRaster | None = None,
                head_planes: torch.Tensor | None = None,
                view_rays: dict[str, torch.Tensor] | None = None) -> dict[str, Any]:
        """Render heads.

        Args:
            verts: ``(B, V, 3)`` posed mesh in head coordinates (metres).
            c2w: ``(B, 4, 4)`` camera-to-world (OpenCV axes).
            intrinsics: ``(B, 3, 3)`` or ``(3, 3)`` for an ``image_res`` image.
            code: ``(B, code_dim)`` texture codes, or
            texture: ``(B, C, R, R)`` neural textures (inversion optimises these).
            hair: The items' hair; ``None`` renders bald heads.
            jitter: Stratified random sample positions (training).
            reuse: Decoded points kept from the previous frame of an animation (a
                one-item batch, no gradients): the decoders run only on points whose
                input changed (see :class:`~head360cli.model.reuse.DecodeReuse`); with
                ``camera_moves``, only the head planes' still triangles and the
                RefineNet's output where its input did not change are kept.
            plane_raster: :meth:`plane_raster` of these ``verts``, when the caller renders
                the same mesh many times; without it the mesh is rasterized here. An
                animation's ``reuse`` keeps its own (its still triangles) and ignores it.
            head_planes: ``(B, P, C + 2, res, res)`` the head's planes made by the caller
                (:meth:`planes`, or
                :func:`~head360cli.model.planes.add_texture_change` of them), rendered
                instead of the texture's; not with ``reuse``.
            view_rays: A dict the caller keeps between renders of the same ``verts``, camera
                and settings that change only the texture (a texture inversion's steps):
                the first render fills it with the rays' depth and samples, the others
                read them instead of rasterizing again (the same tensors, so the same
                result). Bald heads, no jitter, no ``reuse``; nothing in it may need
                gradients.

        Returns:
            ``rgb (B, 3, H, W)`` on a white background, ``alpha`` and ``hair_alpha``
            ``(B, 1, H, W)``, and ``rgb_low``/``alpha_low``/``hair_alpha_low``/``depth_low``
            at ``render_res``, and the ``texture``.
        """
        c = self.cfg
        if head_planes is not None and reuse is not None:
            raise ValueError("expected head planes or decoded points to reuse, found both")
        if texture is None and head_planes is None:
            if code is None:
                raise ValueError("expected a texture code or a neural texture, found neither")
            texture = self.texture(code)
        if hair is not None and not c.hair:
            raise ValueError("expected no hair: this generator was built without a hair "
                             "branch")
        b = verts.shape[0]
        if view_rays is not None and (hair is not None or jitter or reuse is not None):
            raise ValueError(f"expected kept rays for a bald head without jitter or reuse, "
                             f"found hair {hair is not None}, jitter {jitter}, reuse "
                             f"{reuse is not None}")
        if reuse is not None and (b != 1 or jitter or torch.is_grad_enabled()):
            raise ValueError(f"expected one item, no jitter and no gradients to reuse "
                             f"decoded points, found {b} items, jitter {jitter}, gradients "
                             f"{torch.is_grad_enabled()}")
        k = intrinsics.expand(b, 3, 3).clone()
        k[:, :2] *= c.render_res / c.image_res
        still = self._still(verts, reuse)  # once a frame, for the depth and the planes
        # a moving camera keeps what depends on the frame's own inputs alone: the head
        # planes' still triangles and the RefineNet's output where its input is unchanged
        camera_free = reuse
        if reuse is not None and reuse.camera_moves:
            reuse = None
        depth = (view_rays["depth"] if view_rays else
                 self._head_depth(verts, c2w, k, reuse, still))
        hair_items = [] if hair is None else [i for i, m in enumerate(hair.meshes)
                                               if m is not None]
        if hair_items and hair.planes is None:
            hair = self.prepare_hair(hair)
        groups = _hair_groups(hair, hair_items)
        group_idx = [torch.tensor(g, device=verts.device) for g in groups]
        hair_near: dict[int, torch.Tensor] = {}  # first item of a group -> (m, rays)
        head_depth = depth
        if hair_items:
            depth = depth.clone()
            for g, gi in zip(groups, group_idx, strict=True):
                hv, hf, _ = hair.meshes[g[0]]

                def hair_depth(hv=hv, hf=hf, gi=gi):
                    return screen_depth(hv[None].expand(len(gi), -1, -1), hf, c2w[gi],
                                        k[gi], c.render_res)
                # the hair does not move with the expression: a still camera sees the same
                hd = (hair_depth() if reuse is None else
                      reuse.kept("hair_depth", (hv, hf, c2w[0], k[0]), hair_depth))
                depth[gi] = torch.minimum(depth[gi], hd)
                if self.hair_rays_only:  # rays within HAIR_MARGIN pixels of the hair mesh
                    m = (hd < EMPTY).to(hd.dtype)[:, None]
                    hair_near[g[0]] = F.max_pool2d(
                        m, 2 * HAIR_MARGIN + 1, stride=1,
                        padding=HAIR_MARGIN).reshape(len(g), -1) > 0
        rays = c.render_res * c.render_res
        noise = (torch.rand(b, rays, c.samples, dtype=verts.dtype, device=verts.device)
                 if jitter else None)
        if view_rays:
            points, depths, near = (view_rays[n] for n in ("points", "depths", "near"))
            order = view_rays.get("order")
        else:
            # with hair, half the samples stay around the head under it (seen through thin
            # hair)
            points, depths, near = samples_around(depth, c2w, k, c.samples, c.shell, noise,
                                                  behind=head_depth if hair_items else None)
            if self.cull_rays:  # decode only the rays that pass near a surface
                order, _ = near_rays(near)
                points = torch.gather(points, 1, order[..., None, None].expand(
                    -1, -1, c.samples, 3))
            if view_rays is not None:
                view_rays.update(depth=depth, points=points, depths=depths, near=near)
                if self.cull_rays:
                    view_rays["order"] = order
        kept_rays = points.shape[1]
        points = points.reshape(b, -1, 3)
        if head_planes is None:
            head_planes = self._head_planes(verts, texture, camera_free, still,
                                            plane_raster)
        feats = sample_planes(points, head_planes,
                              self.plane_names,
                              c.plane_centre, c.plane_half_size, c.surface_tau)
        keys = slots = None
        if reuse is None:
            density, colour = self._decode(self.decoder, feats)
        else:  # sample slot of each point: ray index x samples + sample
            slots = rays * c.samples
            ray_ids = order[0] if self.cull_rays else torch.arange(rays, device=verts.device)
            keys = (ray_ids[:, None] * c.samples
                    + torch.arange(c.samples, device=verts.device)).reshape(-1)
            density, colour = reuse.decode("head", lambda f: self._decode(self.decoder, f),
                                           feats[0], keys, slots)
            density, colour = density[None], colour[None]
        hair_part = torch.zeros_like(density)
        if hair_items:
            per_item = density.shape[1]  # points per item: kept rays x samples
            block = torch.arange(per_item, device=verts.device)
            at, d_hair, c_hair = [], [], []
            for g, gi in zip(groups, group_idx, strict=True):
                if g[0] in hair_near:  # decode only the points of rays near the hair
                    ray = order[gi] if self.cull_rays else torch.arange(
                        rays, device=verts.device).expand(len(g), -1)
                    sel = torch.nonzero(torch.gather(hair_near[g[0]], 1, ray)
                                        .repeat_interleave(c.samples, 1).reshape(-1)
                                        ).squeeze(1)
                else:
                    sel = torch.arange(len(g) * per_item, device=verts.device)
                pts = points[gi].reshape(-1, 3).index_select(0, sel)
                f = sample_planes(pts[None], hair.planes[g[0]], self.plane_names,
                                  c.hair_plane_centre, c.hair_plane_half_size,
                                  c.surface_tau)
                if reuse is None:
                    dh, ch = self._decode(self.hair_decoder, f)
                    dh, ch = dh[0], ch[0]
                else:  # one item: its flat positions are its point indices
                    dh, ch = reuse.decode(
                        "hair", lambda x: self._decode(self.hair_decoder, x), f[0],
                        keys.index_select(0, sel), slots)
                # positions in the flat (B x points) batch: item g[j] owns j's block
                at.append((gi[:, None] * per_item + block).reshape(-1).index_select(0, sel))
                d_hair.append(dh)
                c_hair.append(ch)
            at_all = torch.cat(at)
            dh_full = torch.zeros_like(density).reshape(-1).index_copy(
                0, at_all, torch.cat(d_hair)).view_as(density)
            ch_full = torch.zeros_like(colour).reshape(-1, colour.shape[-1]).index_copy(
                0, at_all, torch.cat(c_hair)).view_as(colour)
            total = density + dh_full
            share = dh_full / (total + 1e-6)
            colour = colour * (1.0 - share[..., None]) + ch_full * share[..., None]
            density, hair_part = total, share
        colour = torch.cat([colour, hair_part[..., None]], -1)
        density = density.view(b, kept_rays, c.samples)
        colour = colour.view(b, kept_rays, c.samples, -1)
        if self.cull_rays:
            # composite the kept rays, then put them back among every ray: the others
            # (and a kept ray that is not near, see near_rays) carry no weight, so they
            # composite to zero, exactly what the zeros they get here are
            image, alpha, depth_low = composite(
                density, colour, torch.gather(depths, 1, order[..., None].expand(
                    -1, -1, c.samples)), torch.gather(near, 1, order), c.shell)
            image = torch.zeros(b, rays, image.shape[-1], dtype=image.dtype,
                                device=image.device).scatter(
                1, order[..., None].expand(-1, -1, image.shape[-1]), image)
            alpha, depth_low = (torch.zeros(b, rays, dtype=v.dtype, device=v.device)
                                .scatter(1, order, v) for v in (alpha, depth_low))
        else:
            image, alpha, depth_low = composite(density, colour, depths, near, c.shell)
        shape = (b, c.render_res, c.render_res)
        image = image.transpose(1, 2).reshape(b, -1, *shape[1:])
        image, hair_low = image[:, :-1], image[:, -1:]
        alpha = alpha.view(b, 1, *shape[1:])
        rgb_low = image[:, :3] + (1.0 - alpha)  # on white
        scale = c.image_res / c.render_res
        if self.refine is not None and camera_free is not None:
            # its input is the frame's own image, so a moving camera reuses it too:
            # around the head, where the empty background stays as it was
            rgb, alpha_hi = camera_free.refine(lambda *a: self._net(self.refine, *a),
                                               image, alpha, rgb_low, self.refine.scale,
                                               self.refine.reach)
        elif self.refine is not None:
            rgb, alpha_hi = self._net(self.refine, image, alpha, rgb_low)
        else:
            rgb = F.interpolate(rgb_low, scale_factor=scale, mode="bilinear",
                                align_corners=False)
            alpha_hi = F.interpolate(alpha, scale_factor=scale, mode="bilinear",
                                     align_corners=False)
        hair_hi = F.interpolate(hair_low, scale_factor=scale, mode="bilinear",
                                align_corners=False)
        return {"rgb": rgb, "alpha": alpha_hi, "hair_alpha": hair_hi, "rgb_low": rgb_low,
                "alpha_low": alpha, "hair_alpha_low": hair_low,
                "depth_low": depth_low.view(b, 1, *shape[1:]), "texture": texture}

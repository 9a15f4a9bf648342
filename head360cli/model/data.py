"""Training and evaluation views of SynHead-P heads, rendered on the fly.

A view is a head of the corpus (identity ``i`` of a split), an expression, and a camera; its
target is the corpus renderer's image of that head without hair (the head branch learns
bald heads; hair renders come with the hair branch). Training cameras are the 72-camera
rig; evaluation cameras lie between them (yaw 7.5 + 15 k degrees, pitch -10 or +10), so
every evaluation view is a view the generator never saw.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from head360cli.geometry.cameras import (
    RIG_DISTANCE,
    RIG_FOV_DEG,
    camera_on_sphere,
    intrinsics_from_fov,
    rig72,
)
from head360cli.mesh.arkit52 import INDEX
from head360cli.model.generator import Hair

__all__ = ["FEATURED", "Views", "eval_cameras", "sample_expression"]


def eval_cameras() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(c2w (24, 4, 4), yaw, pitch)``: held-out cameras between the rig's."""
    yaw = 7.5 + 15.0 * torch.arange(24, dtype=torch.float32)
    pitch = torch.where(torch.arange(24) % 2 == 0, torch.tensor(-10.0), torch.tensor(10.0))
    return camera_on_sphere(yaw, pitch, RIG_DISTANCE), yaw, pitch


FEATURED: tuple[tuple[int, ...], ...] = tuple(
    tuple(INDEX[name] for name in group)
    for group in (("eyeBlinkLeft",), ("eyeBlinkRight",), ("eyeBlinkLeft", "eyeBlinkRight"),
                  ("jawOpen",)))
"""ARKit index groups that ``sample_expression`` can push to a strong weight: one eye's
blink, both blinks, ``jawOpen``. Closed eyes and an open mouth show texels an open-eyed,
closed-mouth view never shows (the lids, the mouth's inside), and random expressions
alone close an eye in well under 1 % of views."""


def sample_expression(rng: np.random.Generator, p_neutral: float = 0.4,
                      featured: float = 0.0) -> np.ndarray:
    """ARKit weights (52,): neutral, or one to three shapes at weights in (0, 1]; then,
    with probability ``featured``, one group of ``FEATURED`` set to a weight in [0.7, 1]
    on top (``featured=0`` draws exactly as before it existed)."""
    w = np.zeros(52, dtype=np.float32)
    if rng.random() >= p_neutral:
        k = int(rng.integers(1, 4))
        w[rng.choice(52, k, replace=False)] = rng.uniform(0.2, 1.0, k)
    if featured > 0 and rng.random() < featured:
        group = FEATURED[int(rng.integers(len(FEATURED)))]
        w[list(group)] = rng.uniform(0.7, 1.0)
    return w


@dataclasses.dataclass
class Batch:
    """Views ready for the generator: ``verts (B, V, 3)``, ``c2w (B, 4, 4)``,
    ``intrinsics (3, 3)``, targets ``rgb (B, 3, H, W)``, ``alpha`` and ``hair_alpha``
    ``(B, 1, H, W)``, the ``identity (B,)`` indices, ``with_hair (B,)`` and the ``hair``
    to render them with (meshes ``None`` for bald views)."""

    verts: torch.Tensor
    c2w: torch.Tensor
    intrinsics: torch.Tensor
    rgb: torch.Tensor
    alpha: torch.Tensor
    hair_alpha: torch.Tensor
    identity: torch.Tensor
    with_hair: torch.Tensor
    hair: Hair
    albedo: torch.Tensor | None = None
    """``(B, 3, R, R)`` the heads' albedo atlases (``Views(albedo_res=R)``), or ``None``."""
    hair_albedo: torch.Tensor | None = None
    """``(B, 3, r, r)`` their hair's strand textures (``Views(hair_albedo_res=r)``), or
    ``None``."""

    def to(self, device: torch.device | str) -> Batch:
        return Batch(**{f.name: None if getattr(self, f.name) is None
                        else getattr(self, f.name).to(device)
                        for f in dataclasses.fields(self)})

    @staticmethod
    def cat(parts: list[Batch]) -> Batch:
        fields = {f.name: torch.cat([getattr(p, f.name) for p in parts])
                  for f in dataclasses.fields(Batch)
                  if f.name not in ("intrinsics", "hair", "albedo", "hair_albedo")}
        hair = Hair([m for p in parts for m in p.hair.meshes],
                    torch.cat([p.hair.style for p in parts]),
                    torch.cat([p.hair.colour for p in parts]))
        albedo, hair_albedo = (
            None if getattr(parts[0], name) is None else
            torch.cat([getattr(p, name) for p in parts]) for name in ("albedo", "hair_albedo"))
        return Batch(intrinsics=parts[0].intrinsics, hair=hair, albedo=albedo,
                     hair_albedo=hair_albedo, **fields)


class Views:
    """Renders views of one split's heads.

    Args:
        identities: How many heads (indices ``0 .. identities - 1``).
        split: ``train`` or ``test``.
        seed: Corpus seed.
        size: Image resolution.
        texture_size: Atlas size of the synthetic heads.
        device: Where the corpus renderer runs (the targets stay there).
        skin_scan: Folder of a head scan whose skin detail the heads take (``""``: none;
            see :func:`head360cli.synth.scene.make_head`).
        soft_hair: Soft hairlines (:func:`head360cli.synth.hair.build_hair`).
        albedo_res: Give batches the heads' albedo atlases at this size (0: none).
        hair_albedo_res: And their hair's strand textures at this size (0: none).
    """

    def __init__(self, identities: int, split: str = "train", seed: int = 0,
                 size: int = 256, texture_size: int = 512, device: str = "cpu",
                 skin_scan: str = "", soft_hair: bool = False, albedo_res: int = 0,
                 hair_albedo_res: int = 0) -> None:
        self.identities, self.split, self.seed, self.size = identities, split, seed, size
        self.texture_size = texture_size
        self.skin_scan, self.soft_hair = skin_scan, soft_hair
        self.device = torch.device(device)
        self.intrinsics = intrinsics_from_fov(RIG_FOV_DEG, size, size).to(self.device)
        self.rig, _, _ = rig72()
        self._heads: dict[tuple, object] = {}
        self.albedo_res, self.hair_albedo_res = albedo_res, hair_albedo_res
        self._albedo: dict[tuple[int, str], torch.Tensor] = {}

    def albedo(self, index: int, part: str = "texture") -> torch.Tensor:
        """``(1, 3, R, R)`` head ``index``'s skin atlas at ``albedo_res`` (``part=
        "hair_tex"``: its hair's strand texture at ``hair_albedo_res``), kept."""
        key = (index, part)
        if key not in self._albedo:
            size = self.albedo_res if part == "texture" else self.hair_albedo_res
            tex = torch.as_tensor(getattr(self.head(index), part)).permute(2, 0, 1)[None]
            self._albedo[key] = torch.nn.functional.interpolate(
                tex.float(), size=(size, size), mode="area").to(self.device)
        return self._albedo[key]

    def head(self, index: int, style: int | None = None, colour: str | None = None):
        """Corpus head ``index``, optionally with another hairstyle and colour (built once,
        kept)."""
        key = (index, style, colour)
        if key not in self._heads:
            from head360cli.synth.scene import make_head, prepare_render

            head = make_head(index, self.split, self.seed, texture_size=self.texture_size,
                             hair_style=style, hair_colour=colour,
                             skin_scan=self.skin_scan or None, soft_hair=self.soft_hair)
            prepare_render(head, self.device)
            self._heads[key] = head
        return self._heads[key]

    def forget(self) -> None:
        """Drop the heads built so far (a pass that renders each head once keeps memory
        flat)."""
        self._heads.clear()

    def prefetch(self, workers: int = 1) -> None:
        """Build every head of the split now, in ``workers`` processes."""
        from head360cli.synth.scene import make_head, prepare_render

        todo = [i for i in range(self.identities) if (i, None, None) not in self._heads]
        if workers > 1 and len(todo) > 1:
            import concurrent.futures
            import multiprocessing

            from head360cli.interrupts import sigint_ignored

            ctx = multiprocessing.get_context("spawn")
            with concurrent.futures.ProcessPoolExecutor(workers, mp_context=ctx) as pool:
                with sigint_ignored():  # the pool's processes start with the first jobs
                    jobs = [pool.submit(_make_head, (i, self.split, self.seed,
                                                     self.texture_size, self.skin_scan,
                                                     self.soft_hair))
                            for i in todo]
                heads = [job.result() for job in jobs]
        else:
            heads = [make_head(i, self.split, self.seed, texture_size=self.texture_size,
                               skin_scan=self.skin_scan or None, soft_hair=self.soft_hair)
                     for i in todo]
        for i, head in zip(todo, heads, strict=True):
            prepare_render(head, self.device)
            self._heads[(i, None, None)] = head

    def render(self, index: int, weights: np.ndarray, c2w: torch.Tensor,
               with_hair: bool = False, style: int | None = None,
               colour: str | None = None) -> Batch:
        """Views of one head with one expression from cameras ``c2w (B, 4, 4)``, with its
        hair (or hairstyle ``style`` in ``colour``) or bald."""
        from head360cli.synth.hair import HAIR_COLOURS
        from head360cli.synth.scene import render_head

        head = self.head(index, style, colour)
        c2w = c2w.to(self.device)
        out = render_head(head, weights, c2w, self.intrinsics, self.size,
                          with_hair=with_hair)
        verts = torch.tensor(head.verts + np.tensordot(weights, head.deltas, 1),
                             dtype=torch.float32, device=self.device)
        b = c2w.shape[0]
        mesh = None
        if with_hair and len(head.hair.faces):
            mesh = tuple(torch.tensor(a, dtype=d, device=self.device) for a, d in
                         ((head.hair.verts, torch.float32), (head.hair.faces, torch.long),
                          (head.hair.uv, torch.float32)))
        colour_rgb = torch.tensor(HAIR_COLOURS[head.hair_colour], dtype=torch.float32,
                                  device=self.device)
        hair = Hair([mesh] * b, torch.full((b,), head.hair_style, device=self.device),
                    colour_rgb.expand(b, 3))
        hair_alpha = out.labels[:, :1] if with_hair else torch.zeros_like(out.alpha)
        own = style is None and colour is None
        albedo = (self.albedo(index).expand(b, -1, -1, -1) if self.albedo_res and own
                  else None)
        hair_albedo = (self.albedo(index, "hair_tex").expand(b, -1, -1, -1)
                       if self.hair_albedo_res and own else None)
        return Batch(verts[None].expand(b, -1, -1).contiguous(), c2w, self.intrinsics,
                     out.rgb, out.alpha, hair_alpha,
                     torch.full((b,), index, dtype=torch.long, device=self.device),
                     torch.full((b,), with_hair, dtype=torch.bool, device=self.device),
                     hair, albedo, hair_albedo)

    def sample(self, rng: np.random.Generator, batch: int, bald_share: float = 0.5,
               group: int = 1, featured: float = 0.0) -> Batch:
        """A training batch of ``batch`` views: groups of ``group`` rig cameras on one
        random head and expression (one render call per group; ``featured`` as in
        ``sample_expression``), each group bald with probability ``bald_share``."""
        parts = []
        for start in range(0, batch, group):
            n = min(group, batch - start)
            index = int(rng.integers(self.identities))
            cams = self.rig[torch.as_tensor(rng.choice(len(self.rig), n, replace=False))]
            bald = bool(rng.random() < bald_share)
            weights = sample_expression(rng, featured=featured)
            parts.append(self.render(index, weights, cams, with_hair=not bald))
        return Batch.cat(parts)


def _make_head(args):
    from head360cli.synth.scene import make_head

    index, split, seed, size, skin_scan, soft_hair = args
    return make_head(index, split, seed, texture_size=size, skin_scan=skin_scan or None,
                     soft_hair=soft_hair)

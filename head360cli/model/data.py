"""Training and evaluation views of SynHead-P heads, rendered on the fly.

A view is a head of the corpus (identity ``i`` of a split), an expression, and a camera; its
target is the corpus renderer's image of that head without hair (the head branch learns
bald heads; hair renders come with the hair branch). Training cameras are the 72-camera
rig; evaluation cameras lie between them (yaw 7.5 + 15 k degrees, pitch -10 or +10), so
every evaluation view is a view the generator never saw.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import torch

from head360cli.geometry.cameras import (
    RIG_DISTANCE,
    RIG_FOV_DEG,
    camera_on_sphere,
    intrinsics_from_fov,
    rig72,
)

__all__ = ["Views", "eval_cameras", "sample_expression"]


def eval_cameras() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(c2w (24, 4, 4), yaw, pitch)``: held-out cameras between the rig's."""
    yaw = 7.5 + 15.0 * torch.arange(24, dtype=torch.float32)
    pitch = torch.where(torch.arange(24) % 2 == 0, torch.tensor(-10.0), torch.tensor(10.0))
    return camera_on_sphere(yaw, pitch, RIG_DISTANCE), yaw, pitch


def sample_expression(rng: np.random.Generator, p_neutral: float = 0.4) -> np.ndarray:
    """ARKit weights: neutral, or one to three shapes at weights in (0, 1]."""
    w = np.zeros(52, dtype=np.float32)
    if rng.random() >= p_neutral:
        k = int(rng.integers(1, 4))
        w[rng.choice(52, k, replace=False)] = rng.uniform(0.2, 1.0, k)
    return w


@dataclasses.dataclass
class Batch:
    """Views ready for the generator: ``verts (B, V, 3)``, ``c2w (B, 4, 4)``,
    ``intrinsics (3, 3)``, targets ``rgb (B, 3, H, W)`` and ``alpha (B, 1, H, W)``, and
    the ``identity (B,)`` indices."""

    verts: torch.Tensor
    c2w: torch.Tensor
    intrinsics: torch.Tensor
    rgb: torch.Tensor
    alpha: torch.Tensor
    identity: torch.Tensor


class Views:
    """Renders views of one split's heads.

    Args:
        identities: How many heads (indices ``0 .. identities - 1``).
        split: ``train`` or ``test``.
        seed: Corpus seed.
        size: Image resolution.
        texture_size: Atlas size of the synthetic heads.
    """

    def __init__(self, identities: int, split: str = "train", seed: int = 0,
                 size: int = 256, texture_size: int = 512) -> None:
        self.identities, self.split, self.seed, self.size = identities, split, seed, size
        self.texture_size = texture_size
        self.intrinsics = intrinsics_from_fov(RIG_FOV_DEG, size, size)
        self.rig, _, _ = rig72()

    @functools.lru_cache(maxsize=128)  # noqa: B019  (one Views per run)
    def head(self, index: int):
        from head360cli.synth.scene import make_head

        return make_head(index, self.split, self.seed, texture_size=self.texture_size)

    def render(self, index: int, weights: np.ndarray, c2w: torch.Tensor) -> Batch:
        """Views of one head with one expression from cameras ``c2w (B, 4, 4)``."""
        from head360cli.synth.scene import render_head

        head = self.head(index)
        out = render_head(head, weights, c2w, self.intrinsics, self.size, with_hair=False)
        verts = torch.tensor(head.verts + np.tensordot(weights, head.deltas, 1),
                             dtype=torch.float32)
        b = c2w.shape[0]
        return Batch(verts[None].expand(b, -1, -1).contiguous(), c2w, self.intrinsics,
                     out.rgb, out.alpha, torch.full((b,), index, dtype=torch.long))

    def sample(self, rng: np.random.Generator, batch: int) -> Batch:
        """A training batch: ``batch`` random (head, expression, rig camera) views."""
        parts = []
        for _ in range(batch):
            index = int(rng.integers(self.identities))
            cam = self.rig[int(rng.integers(len(self.rig)))][None]
            parts.append(self.render(index, sample_expression(rng), cam))
        return Batch(*(torch.cat([getattr(p, f.name) for p in parts]) if f.name !=
                       "intrinsics" else parts[0].intrinsics
                       for f in dataclasses.fields(Batch)))

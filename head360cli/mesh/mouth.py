"""The inside of the template's mouth: the texels of its pocket, teeth and tongue (where
the mouth change of a fitted head's neural texture lives, see
:func:`head360cli.fitting.texture.mouth_change`). Pure functions over the bilinear
model's topology."""

from __future__ import annotations

import numpy as np

__all__ = ["MOUTH_REGIONS", "mouth_texels"]

MOUTH_REGIONS = ("mouth_interior", "teeth", "tongue")
"""The template regions (:data:`head360cli.mesh.template.REGION_NAMES`) inside the lips."""


def mouth_texels(faces: np.ndarray, uv: np.ndarray, faces_uv: np.ndarray,
                 region: np.ndarray, res: int) -> np.ndarray:
    """Texels of the triangles wholly inside the mouth (every corner in one of
    :data:`MOUTH_REGIONS`); the lips' own triangles are left out.

    Args:
        faces: ``(F, 3)`` vertex indices.
        uv: ``(T, 2)`` texture coordinates in [0, 1].
        faces_uv: ``(F, 3)`` indices into ``uv``.
        region: ``(V,)`` region index per vertex (into ``REGION_NAMES``).
        res: Texture side.

    Returns:
        ``(res, res)`` bool.
    """
    import torch

    from head360cli.geometry.rasterize import rasterize
    from head360cli.mesh.template import REGION_NAMES

    inside = np.isin(region, [REGION_NAMES.index(n) for n in MOUTH_REGIONS])
    draw = inside[faces].all(1)
    corners = torch.tensor(uv, dtype=torch.float32) * res
    frags = rasterize(corners[None], torch.ones(1, len(uv)), torch.as_tensor(faces_uv),
                      res, res, perspective_correct=False, draw=torch.as_tensor(draw))
    return (frags.face_id[0] >= 0).numpy()

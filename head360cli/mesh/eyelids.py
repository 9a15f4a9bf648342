"""The eyelids of the template mesh: the weights that close both eyes, the texels of the
triangles a set of vertices moves, and each eye's region (where a lid change of the
neural texture lives, see :mod:`head360cli.fitting.lids`). Pure functions over the
bilinear model's topology."""

from __future__ import annotations

import numpy as np

__all__ = ["EYE_SHAPES", "blink_weights", "eye_texels", "lid_texels"]


def blink_weights() -> np.ndarray:
    """``(52,)`` ARKit weights with both eyes closed."""
    from head360cli.mesh.arkit52 import INDEX

    w = np.zeros(52)
    w[[INDEX["eyeBlinkLeft"], INDEX["eyeBlinkRight"]]] = 1.0
    return w


def lid_texels(faces: np.ndarray, uv: np.ndarray, faces_uv: np.ndarray, moved: np.ndarray,
               res: int, grow: int = 2) -> np.ndarray:
    """Texels of the triangles a blink moves.

    Args:
        faces: ``(F, 3)`` vertex indices.
        uv: ``(T, 2)`` texture coordinates in [0, 1].
        faces_uv: ``(F, 3)`` indices into ``uv``.
        moved: ``(V,)`` bool, the vertices the blink moves.
        res: Texture side.
        grow: Texels added around them (the planes read the texture bilinearly).

    Returns:
        ``(res, res)`` bool.
    """
    import torch
    from scipy import ndimage

    from head360cli.geometry.rasterize import rasterize

    draw = moved[faces].any(1)
    corners = torch.tensor(uv, dtype=torch.float32) * res
    frags = rasterize(corners[None], torch.ones(1, len(uv)), torch.as_tensor(faces_uv),
                      res, res, perspective_correct=False, draw=torch.as_tensor(draw))
    inside = (frags.face_id[0] >= 0).numpy()
    return ndimage.binary_dilation(inside, iterations=grow) if grow else inside


EYE_SHAPES = ("eyeBlink", "eyeLookDown", "eyeLookIn", "eyeLookOut", "eyeLookUp", "eyeSquint",
              "eyeWide")
"""The ARKit blendshapes of one eye, less their side (``Left`` / ``Right``): the triangles
they move are that eye's region (:func:`eye_texels`)."""


def eye_texels(model, shape: np.ndarray, res: int) -> tuple[np.ndarray, np.ndarray]:
    """The texels of each eye's region: ``(left, right)``, ``(res, res)`` bool each, of
    the triangles that any of that eye's blendshapes (:data:`EYE_SHAPES`) moves on the
    head of identity ``shape`` (a :class:`~head360cli.mesh.bilinear.BilinearModel`'s): the
    lids, the eyeball and the lower lid, where a lid change lives
    (:func:`head360cli.fitting.lids.close_lids`). Not only the lid's own texels: a fit can
    leave the photo's eye white on the lower lid's, which a blink does not move. Texels
    both regions reach are in neither."""
    from head360cli.mesh.arkit52 import INDEX

    neutral = model.vertices(shape, np.zeros(52))
    out = []
    for side in ("Left", "Right"):
        moved = np.zeros(len(neutral), bool)
        for name in EYE_SHAPES:
            w = np.zeros(52)
            w[INDEX[name + side]] = 1.0
            moved |= np.any(model.vertices(shape, w) != neutral, axis=1)
        out.append(lid_texels(model.faces, model.uv, model.faces_uv, moved, res))
    # the two eyeballs lie side by side in the atlas: the texels both regions grow into
    # (a few dozen) belong to neither, so no texel changes with both blinks
    both = out[0] & out[1]
    return out[0] & ~both, out[1] & ~both

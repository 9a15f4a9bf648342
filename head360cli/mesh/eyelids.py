"""The eyelids of the template mesh: the weights that close both eyes, and the texels of
the triangles a blink moves (where a lid change of the neural texture lives, see
:mod:`head360cli.fitting.lids`). Pure functions over the bilinear model's topology."""

from __future__ import annotations

import numpy as np

__all__ = ["blink_weights", "eye_texels", "lid_texels"]


def blink_weights() -> np.ndarray:
    """``(52,)`` ARKit weights with both eyes closed."""
    from head360cli.mesh.arkit52 import INDEX

    w = np.zeros(52)
    w[[INDEX["eyeBlinkLeft"], INDEX["eyeBlinkRight"]]] = 1.0
    return w


def grow_mask(mask: np.ndarray, steps: int) -> np.ndarray:
    """``(H, W)`` bool ``mask`` grown by ``steps`` pixels along rows and columns (a cross
    each step), as ``scipy.ndimage.binary_dilation(mask, iterations=steps)`` gives, with
    OpenCV, which a fit has imported already (scipy.ndimage costs 0.27 s to import)."""
    import cv2

    if steps <= 0:
        return mask.astype(bool, copy=True)
    cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    return cv2.dilate(mask.astype(np.uint8), cross, iterations=steps).astype(bool)


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

    from head360cli.geometry.rasterize import rasterize

    draw = moved[faces].any(1)
    corners = torch.tensor(uv, dtype=torch.float32) * res
    frags = rasterize(corners[None], torch.ones(1, len(uv)), torch.as_tensor(faces_uv),
                      res, res, perspective_correct=False, draw=torch.as_tensor(draw))
    inside = (frags.face_id[0] >= 0).numpy()
    return grow_mask(inside, grow)


def eye_texels(model, shape: np.ndarray, res: int) -> tuple[np.ndarray, np.ndarray]:
    """The lid texels of each eye: ``(left, right)``, ``(res, res)`` bool each, of the
    triangles ``eyeBlinkLeft`` and ``eyeBlinkRight`` move on the head of identity
    ``shape`` (a :class:`~head360cli.mesh.bilinear.BilinearModel`'s)."""
    from head360cli.mesh.arkit52 import INDEX

    neutral = model.vertices(shape, np.zeros(52))
    out = []
    for name in ("eyeBlinkLeft", "eyeBlinkRight"):
        w = np.zeros(52)
        w[INDEX[name]] = 1.0
        moved = np.any(model.vertices(shape, w) != neutral, axis=1)
        out.append(lid_texels(model.faces, model.uv, model.faces_uv, moved, res))
    return out[0], out[1]

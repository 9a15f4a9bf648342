"""Colour sets of a photo: which colours its skin (or its skin and hair) has, and how far
other colours lie from them, in CIELAB (CIE76 differences).

The fit keeps pixels whose colour the photo's face skin lacks (a collar, the backdrop,
a microphone) out of the texture's loss around the face; ``bench`` counts rendered
pixels whose colour the photo's head lacks (colour outliers).
"""

from __future__ import annotations

import numpy as np

__all__ = ["PALETTE_SIZE", "palette", "palette_distance", "to_lab"]

PALETTE_SIZE = 4000
"""Pixels sampled into a palette (a fixed seed)."""


def to_lab(rgb: np.ndarray) -> np.ndarray:
    """``(..., 3)`` CIELAB of uint8 sRGB ``(..., 3)``."""
    import cv2

    flat = np.ascontiguousarray(rgb.reshape(-1, 1, 3)).astype(np.float32) / 255.0
    return cv2.cvtColor(flat, cv2.COLOR_RGB2Lab).reshape(*rgb.shape[:-1], 3)


def palette(rgb: np.ndarray, mask: np.ndarray, seed: int = 0) -> np.ndarray:
    """``(N, 3)`` CIELAB colours of the ``mask (H, W)`` pixels of ``rgb (H, W, 3)``
    uint8 (at most :data:`PALETTE_SIZE`, drawn with ``seed``)."""
    pixels = rgb[np.asarray(mask, bool)]
    if len(pixels) > PALETTE_SIZE:
        pick = np.random.default_rng(seed).choice(len(pixels), PALETTE_SIZE, replace=False)
        pixels = pixels[pick]
    return to_lab(pixels)


def palette_distance(pixels: np.ndarray, colours: np.ndarray) -> np.ndarray:
    """``(N,)`` CIE76 distance from each uint8 sRGB pixel ``(N, 3)`` to the nearest colour
    of the palette ``colours (M, 3)`` (CIELAB, :func:`palette`)."""
    from scipy.spatial import cKDTree

    if len(pixels) == 0:
        return np.zeros(0)
    dist, _ = cKDTree(colours).query(to_lab(np.asarray(pixels, np.uint8)), k=1)
    return np.asarray(dist, np.float64)

"""Colour outliers: rendered head pixels whose colour the photo's head does not have.

Streaks of backdrop or clothing colour on the cheeks, a blue-green tint on the neck, hair
of a colour the photo's hair is not: each puts pixels on the head whose colour lies far
from every colour of the photo's skin and hair. :func:`photo_palette` samples those
colours (CIELAB) from the parsed photo; :func:`outlier_share` counts, in renders of the
fitted head, the head pixels further than :data:`OUTLIER_DELTA_E` from all of them.
"""

from __future__ import annotations

import numpy as np

__all__ = ["OUTLIER_DELTA_E", "outlier_share", "photo_palette", "photo_palette_of"]

OUTLIER_DELTA_E = 15.0
"""CIE76 colour difference beyond which a rendered pixel is an outlier (about three times
what tells two colours apart side by side)."""
PALETTE_SIZE = 4000
"""Photo pixels sampled into the palette (a fixed seed)."""
MIN_ALPHA = 0.9
"""A rendered pixel counts as the head's where its coverage is at least this."""


def _lab(rgb: np.ndarray) -> np.ndarray:
    """``(..., 3)`` CIELAB of uint8 sRGB ``(..., 3)``."""
    import cv2

    flat = np.ascontiguousarray(rgb.reshape(-1, 1, 3)).astype(np.float32) / 255.0
    return cv2.cvtColor(flat, cv2.COLOR_RGB2Lab).reshape(*rgb.shape[:-1], 3)


def photo_palette(rgb: np.ndarray, mask: np.ndarray, seed: int = 0) -> np.ndarray:
    """``(N, 3)`` CIELAB colours of the ``mask (H, W)`` pixels of ``rgb (H, W, 3)``
    (at most :data:`PALETTE_SIZE`, drawn with ``seed``)."""
    pixels = rgb[np.asarray(mask, bool)]
    if len(pixels) > PALETTE_SIZE:
        pick = np.random.default_rng(seed).choice(len(pixels), PALETTE_SIZE, replace=False)
        pixels = pixels[pick]
    return _lab(pixels)


def photo_palette_of(rgb: np.ndarray) -> np.ndarray | None:
    """The palette of a photo's skin and hair as head360 parses them (default detector
    and hair segmenter); ``None`` where no face is found."""
    from head360cli.errors import Head360Error
    from head360cli.fitting.hair_parse import parse_hair
    from head360cli.fitting.landmarks import find_faces

    try:
        faces = find_faces(rgb)
    except Head360Error:
        return None
    if not faces:
        return None
    parse = parse_hair(rgb, faces[0].landmarks)
    return photo_palette(rgb, parse.hair | parse.face)


def outlier_share(renders: np.ndarray, alphas: np.ndarray, palette: np.ndarray,
                  delta_e: float = OUTLIER_DELTA_E) -> list[float | None]:
    """Per render, the share of the head's pixels (``alphas (B, H, W)`` at least
    :data:`MIN_ALPHA`) of ``renders (B, H, W, 3)`` uint8 whose CIELAB colour is further
    than ``delta_e`` from every colour of ``palette (N, 3)``; ``None`` for a render
    with no head pixel."""
    from scipy.spatial import cKDTree

    tree = cKDTree(palette)
    out: list[float | None] = []
    for img, a in zip(renders, alphas, strict=True):
        head = a >= MIN_ALPHA
        if not head.any():
            out.append(None)
            continue
        dist, _ = tree.query(_lab(img[head]), k=1)
        out.append(float((dist > delta_e).mean()))
    return out

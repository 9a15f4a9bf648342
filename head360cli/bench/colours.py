"""Colour outliers: rendered head pixels whose colour the photo's head does not have.

Streaks of backdrop or clothing colour on the cheeks, a blue-green tint on the neck, hair
of a colour the photo's hair is not: each puts pixels on the head whose colour lies far
from every colour of the photo's skin and hair. :func:`photo_palette_of` samples those
colours (:func:`~head360cli.fitting.colours.palette`) from the parsed photo;
:func:`outlier_share` counts, in renders of the fitted head, the head pixels further than
:data:`OUTLIER_DELTA_E` from all of them.
"""

from __future__ import annotations

import numpy as np

from head360cli.fitting.colours import palette, palette_distance

__all__ = ["OUTLIER_DELTA_E", "as_grey", "outlier_share", "photo_palette_of"]

OUTLIER_DELTA_E = 15.0
"""CIE76 colour difference beyond which a rendered pixel is an outlier (about three times
what tells two colours apart side by side)."""
MIN_ALPHA = 0.9
"""A rendered pixel counts as the head's where its coverage is at least this."""


def as_grey(images: np.ndarray) -> np.ndarray:
    """``(..., 3)`` uint8 images in grey (BT.601 weights), each channel the same."""
    from head360cli.fitting.texture import LUMA

    grey = (images.astype(np.float64) @ np.array(LUMA)).round().clip(0, 255)
    return np.repeat(grey[..., None], 3, -1).astype(np.uint8)


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
    return palette(rgb, parse.hair | parse.face)


def outlier_share(renders: np.ndarray, alphas: np.ndarray, colours: np.ndarray,
                  delta_e: float = OUTLIER_DELTA_E) -> list[float | None]:
    """Per render, the share of the head's pixels (``alphas (B, H, W)`` at least
    :data:`MIN_ALPHA`) of ``renders (B, H, W, 3)`` uint8 whose colour is further than
    ``delta_e`` from every colour of the palette ``colours (N, 3)``; ``None`` for a
    render with no head pixel."""
    out: list[float | None] = []
    for img, a in zip(renders, alphas, strict=True):
        head = a >= MIN_ALPHA
        if not head.any():
            out.append(None)
            continue
        out.append(float((palette_distance(img[head], colours) > delta_e).mean()))
    return out

"""How a render's hair compares with a photo's: the measures that `bench multiview` takes at
each yaw of a real head turn.

- :func:`hair_colour_difference`: CIEDE2000 between the median Lab colours of two images'
  hair pixels (a colour the eye would call the hair's, robust to highlights and to a
  few stray pixels of skin).
- :func:`reads_as_hair`: whether MediaPipe's hair segmenter, run on a render, finds the
  hair the render drew (a helmet seen from the side does not read as hair).
- :func:`silhouette_steps`: jumps of 2 pixels or more along a mask's edge between flat
  runs, the stair steps of a hairstyle made of grid rows, not the pixels of a slope.
"""

from __future__ import annotations

import numpy as np

__all__ = ["MIN_HAIR_PIXELS", "READ_SHARE", "compare_hair", "hair_colour_difference",
           "median_lab", "reads_as_hair", "segmented_hair", "silhouette_steps"]

MIN_HAIR_PIXELS = 50
"""Fewer hair pixels than this (at 256 x 256) count as no hair: no colour is measured."""
READ_SHARE = 0.5
"""A render reads as hair where the segmenter marks at least this share of the pixels
the render's hair covers."""


def median_lab(rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``(3,)`` the median CIELAB colour of the ``mask (H, W)`` pixels of ``rgb (H, W, 3)``
    uint8 (sRGB, D65)."""
    from skimage.color import rgb2lab

    pixels = rgb[np.asarray(mask, bool)].reshape(-1, 1, 3)
    return np.median(rgb2lab(pixels).reshape(-1, 3), axis=0)


def hair_colour_difference(rgb_a: np.ndarray, hair_a: np.ndarray, rgb_b: np.ndarray,
                           hair_b: np.ndarray) -> float | None:
    """CIEDE2000 between the median Lab colours of two images' hair pixels, or ``None``
    when either has fewer than :data:`MIN_HAIR_PIXELS`."""
    from skimage.color import deltaE_ciede2000

    if np.count_nonzero(hair_a) < MIN_HAIR_PIXELS or np.count_nonzero(
            hair_b) < MIN_HAIR_PIXELS:
        return None
    return float(deltaE_ciede2000(median_lab(rgb_a, hair_a), median_lab(rgb_b, hair_b)))


def segmented_hair(rgb: np.ndarray) -> np.ndarray:
    """``(H, W)`` bool: the hair MediaPipe's segmenter finds in ``rgb (H, W, 3)`` uint8
    (the photo and its mirror image averaged, no face needed, no GrabCut)."""
    from head360cli.fitting.hair_parse import segment_hair

    return segment_hair(np.ascontiguousarray(rgb), None, refine=False).hair


def reads_as_hair(rgb: np.ndarray, hair: np.ndarray) -> bool | None:
    """Whether the segmenter marks at least :data:`READ_SHARE` of the ``hair (H, W)``
    pixels a render ``rgb`` drew; ``None`` when it drew fewer than
    :data:`MIN_HAIR_PIXELS`."""
    hair = np.asarray(hair, bool)
    if np.count_nonzero(hair) < MIN_HAIR_PIXELS:
        return None
    found = segmented_hair(rgb)
    return bool(np.count_nonzero(found & hair) >= READ_SHARE * np.count_nonzero(hair))


def _profile_steps(mask: np.ndarray, min_step: int, flat: float, reach: int) -> int:
    """Steps along the top and bottom edges of ``mask``, column by column."""
    count = 0
    covered = mask.any(0)
    if not covered.any():
        return 0
    rows = np.arange(mask.shape[0])[:, None]
    top = np.where(mask, rows, mask.shape[0]).min(0)
    bottom = np.where(mask, rows, -1).max(0)
    # contiguous runs of covered columns: an edge is followed only within one run
    edges = np.diff(np.concatenate([[0], covered.astype(np.int8), [0]]))
    for start, stop in zip(np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0],
                           strict=True):
        for profile in (top[start:stop], bottom[start:stop]):
            d = np.abs(np.diff(profile))
            for i in np.nonzero(d >= min_step)[0]:
                around = np.concatenate([d[max(0, i - reach):i], d[i + 1:i + 1 + reach]])
                if len(around) and around.mean() <= flat:
                    count += 1
    return count


def silhouette_steps(mask: np.ndarray, min_step: int = 2, flat: float = 0.5,
                     reach: int = 3) -> int:
    """Stair steps on the edge of ``mask (H, W)``: where the edge, read column by column
    (its top and bottom) or row by row (its left and right), jumps by ``min_step``
    pixels or more while the ``reach`` columns (rows) on either side move by ``flat`` or
    less on average. A slope jumps every column, so it is not a step; a rasterised
    circle or slanted line has none. A stair whose rise is also a flat run of 4 or more
    pixels the other way (rise 5, tread 8) counts from both sides."""
    mask = np.asarray(mask, bool)
    return (_profile_steps(mask, min_step, flat, reach)
            + _profile_steps(mask.T, min_step, flat, reach))


def compare_hair(render: np.ndarray, hair: np.ndarray, real: np.ndarray,
                 real_hair: np.ndarray) -> dict[str, float | int | None]:
    """A render ``(H, W, 3)`` uint8 and its hair ``(H, W)`` bool against a photo's crop and
    the hair the segmenter finds there: ``hair_iou``, ``hair_delta_e`` (``None`` under
    :data:`MIN_HAIR_PIXELS` on either side) and the render's ``hair_steps``."""
    from head360cli.fitting.hair_parse import mask_iou

    de = hair_colour_difference(render, hair, real, real_hair)
    return {"hair_iou": round(mask_iou(hair, real_hair), 4),
            "hair_delta_e": None if de is None else round(de, 2),
            "hair_steps": silhouette_steps(hair)}

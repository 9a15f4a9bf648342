"""The hair's own texture from the photo: its strands, not a smooth shell of one colour.

A head's ``hair_detail (A, A, 3)`` is its hair's albedo over the hair colour (about 1
where the photo's hair is at its median), in the hair mesh's strand coordinates (u
round the head, v along the hair). It is made in two parts:

- **Seen**: the photo's hair pixels that the fitted hair covers at the photo's view are
  written into the texels they show (:func:`project_hair`), weighted by how squarely the
  surface faces the camera.
- **Unseen**: everywhere else, patches of the photo's own hair laid side by side with
  feathered overlaps (:func:`quilt_hair`), so that the sides and back have the photo's
  strands, curls and spread of colour rather than a flat colour.

The fit then scales it per channel until the hair renders as the photo's
(:func:`~head360cli.fitting.stages.texture_hair`). The renderer multiplies it by the
hair colour (:func:`~head360cli.model.deferred.with_hair_detail`), so ``swap-hair
--color`` recolours the same strands.
"""

from __future__ import annotations

import numpy as np

from head360cli.model.deferred import HAIR_TEXTURE_SIDE

__all__ = ["DETAIL_RES", "MAX_DETAIL", "hair_detail", "hair_ratio", "project_hair",
           "quilt_hair"]

DETAIL_RES = HAIR_TEXTURE_SIDE
"""Side of the hair detail texture, texels (the side renders read the hair texture at):
about one texel a pixel around a head rendered at 256 px (u spans the whole way round
it)."""
MAX_DETAIL = 4.0
"""The largest ratio kept (a highlight four times the hair's median); the photo's
clipped whites and stray background pixels go no further."""
PATCH_SIZES = (32, 24, 16, 12, 8)
"""Patch sides tried, largest first, until :data:`MIN_PATCHES` fit inside the hair."""
MIN_PATCHES = 20
"""The fewest places a patch must fit wholly (90 %) inside the parsed hair."""
LOCAL_LIGHT = 1.0
"""The power of the photo's broad light (its ratio blurred over :data:`LIGHT_SIGMA`)
divided out of the patches: the renderer lights the hair again, and whole patches of
a lit crown beside ones of a shadowed side showed as blotches (at 0.5 too)."""
LIGHT_SIGMA = 8.0
"""Pixels of the blur that finds the photo's broad light on its hair."""
EDGE_PX = 2
"""Pixels of the parsed hair's edge not projected: there the photo mixes the hair with
the forehead and the backdrop (a skin-coloured band showed along the hairline)."""
SEEN_SIGMA = 1.5
"""Texels of the blur that fills the gaps between projected pixels."""
SEEN_DENSITY = 0.5
"""Projected weight a texel needs (after :data:`SEEN_SIGMA`'s blur) to show the photo
alone; less is blended with the patches."""


def hair_ratio(crop: np.ndarray, hair: np.ndarray, gain: np.ndarray | None = None
               ) -> np.ndarray:
    """``(H, W, 3)`` float32: the crop ``(H, W, 3)`` uint8 in linear RGB, without the
    light's ``gain (3,)`` if given, over the median of its ``hair (H, W)`` pixels,
    clipped to [0, :data:`MAX_DETAIL`]."""
    from head360cli.io.colour import srgb_to_linear

    lin = srgb_to_linear(crop.astype(np.float32) / 255.0).astype(np.float32)
    if gain is not None:
        lin = lin / np.asarray(gain, np.float32)
    median = np.maximum(np.median(lin[hair], axis=0), 1e-3)
    return np.clip(lin / median, 0.0, MAX_DETAIL).astype(np.float32)


def quilt_hair(ratio: np.ndarray, hair: np.ndarray, size: int = DETAIL_RES, seed: int = 0
               ) -> np.ndarray:
    """``(size, size, 3)`` float32: square patches of ``ratio (H, W, 3)`` that lie
    inside ``hair (H, W)`` (the largest of :data:`PATCH_SIZES` with enough places),
    placed in rows with a quarter's overlap, every other row shifted by half a patch,
    feathered into each other (and round the seam in u), the photo's broad light taken
    out (:data:`LOCAL_LIGHT`); the patches keep their orientation, so strands that run
    down the photo run along v. All ones where
    no patch fits (a few hair pixels)."""
    import cv2

    rng = np.random.default_rng([seed, 0x4A12])
    inside = hair.astype(np.float32)
    light = cv2.GaussianBlur(ratio * inside[..., None], (0, 0), LIGHT_SIGMA)
    weight = cv2.GaussianBlur(inside, (0, 0), LIGHT_SIGMA)[..., None]
    light = light / np.maximum(weight, 1e-3)
    flat = ratio / np.maximum(light, 1e-3) ** LOCAL_LIGHT
    flat = flat * (float(ratio[hair].mean()) / max(float(flat[hair].mean()), 1e-6))
    flat = np.clip(flat, 0.0, MAX_DETAIL)  # a bright strand beside a dark hollow
    h, w = hair.shape
    found = None
    for patch in PATCH_SIZES:
        if patch >= min(h, w):
            continue
        cover = cv2.boxFilter(hair.astype(np.float32), -1, (patch, patch),
                              anchor=(0, 0), borderType=cv2.BORDER_CONSTANT)
        ys, xs = np.nonzero(cover[:h - patch, :w - patch] > 0.9)
        if len(ys) >= MIN_PATCHES:
            found = patch, ys, xs
            break
    if found is None:
        return np.ones((size, size, 3), np.float32)
    patch, ys, xs = found
    overlap = patch // 4
    step = patch - overlap
    ramp = np.minimum(1.0, np.minimum(np.arange(patch) + 1, patch - np.arange(patch))
                      / overlap).astype(np.float32)
    feather = (ramp[:, None] * ramp[None, :])[..., None]
    total = np.zeros((size + patch, size + 2 * patch, 3), np.float32)
    weights = np.zeros((size + patch, size + 2 * patch, 1), np.float32)
    for row, y in enumerate(range(0, size, step)):
        # every other row shifted by half a patch, as bricks, so no seam runs down v
        for x in range((row % 2) * step // 2, size + (row % 2) * step // 2, step):
            i = rng.integers(len(ys))
            total[y:y + patch, x:x + patch] += feather * flat[ys[i]:ys[i] + patch,
                                                              xs[i]:xs[i] + patch]
            weights[y:y + patch, x:x + patch] += feather
    over = total.shape[1] - size  # u wraps round the head: so do the patches
    total[:, :over] += total[:, size:]
    weights[:, :over] += weights[:, size:]
    return (total / np.maximum(weights, 1e-6))[:size, :size]


def project_hair(ratio: np.ndarray, hair: np.ndarray, uv: np.ndarray, pixels: np.ndarray,
                 facing: np.ndarray, size: int = DETAIL_RES
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Photo pixels written into the texels the hair shows there.

    Args:
        ratio: ``(H, W, 3)`` the photo's hair ratio (:func:`hair_ratio`).
        hair: ``(H, W)`` bool, the parsed hair.
        uv: ``(n, 2)`` strand coordinates of the hair mesh's points seen at the photo's
            view, one per pixel.
        pixels: ``(n, 2)`` int their (row, column).
        facing: ``(n,)`` the cosine between the surface normal and the view.

    Returns:
        ``(size, size, 3)`` the projected ratio (ones where nothing was projected) and
        ``(size, size)`` its weight in [0, 1].
    """
    import cv2

    rows, cols = pixels[:, 0], pixels[:, 1]
    keep = hair[rows, cols] & (facing > 0.1)
    rows, cols, uv, w = rows[keep], cols[keep], uv[keep], facing[keep] ** 2
    tx = np.clip((uv[:, 0] * size).astype(np.int64), 0, size - 1)
    ty = np.clip((uv[:, 1] * size).astype(np.int64), 0, size - 1)
    flat = ty * size + tx
    total = np.stack([np.bincount(flat, w * ratio[rows, cols, c], size * size)
                      for c in range(3)], -1).reshape(size, size, 3).astype(np.float32)
    weight = np.bincount(flat, w, size * size).reshape(size, size).astype(np.float32)
    total = cv2.GaussianBlur(total, (0, 0), SEEN_SIGMA)
    weight = cv2.GaussianBlur(weight, (0, 0), SEEN_SIGMA)
    seen = total / np.maximum(weight, 1e-6)[..., None]
    share = np.clip(weight / SEEN_DENSITY, 0.0, 1.0)
    share = cv2.GaussianBlur(share, (0, 0), 2 * SEEN_SIGMA)
    seen = np.where(weight[..., None] > 1e-6, seen, 1.0)
    return seen.astype(np.float32), share.astype(np.float32)


def hair_detail(gen, verts, c2w, k, hair, crop: np.ndarray, parsed: np.ndarray,
                gain: np.ndarray | None = None, size: int = DETAIL_RES, seed: int = 0
                ) -> np.ndarray:
    """``(size, size, 3)`` float32 a fitted head's hair detail: the photo projected
    where the fitted hair shows it, patches of the photo's hair elsewhere.

    Args:
        gen: The deferred generator.
        verts: ``(V, 3)`` tensor, the posed head at the photo's expression.
        c2w, k: ``(4, 4)``, ``(3, 3)`` tensors, the photo's camera for the crop.
        hair: The head's prepared :class:`~head360cli.model.generator.Hair` (one item).
        crop: ``(R, R, 3)`` uint8 the photo's crop.
        parsed: ``(R, R)`` bool the parsed hair in it.
        gain: ``(3,)`` the photo's light, taken out of its colours, or ``None``.
    """
    import cv2
    import torch

    if np.count_nonzero(parsed) < 50:
        return np.ones((size, size, 3), np.float32)
    ratio = hair_ratio(crop, parsed, gain)
    res = crop.shape[0]
    with torch.no_grad(), gen.image_size(res), gen.pixel_samples(1):
        buf = gen.gbuffer(verts[None], c2w[None], k[None], hair)
    sel = buf.hair
    index = buf.index[sel].cpu().numpy()
    pixels = np.stack([index // res % res, index % res], 1)
    facing = (buf.normal[sel] * buf.view[sel]).sum(-1).cpu().numpy()
    uv = buf.uv[sel].cpu().numpy()
    uv[:, 0] %= 1.0  # across the seam (seam_uv)
    # the parse's edge pixels mix in the forehead's and the backdrop's colours
    inner = cv2.erode(parsed.astype(np.uint8), np.ones((3, 3), np.uint8), iterations=EDGE_PX)
    seen, share = project_hair(ratio, inner > 0, uv, pixels, facing, size)
    quilt = quilt_hair(ratio, parsed, size, seed)
    share = share[..., None]
    detail = share * seen + (1.0 - share) * quilt
    return np.clip(detail, 0.0, MAX_DETAIL).astype(np.float32)

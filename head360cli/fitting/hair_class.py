"""Hairstyle classification by analysis by synthesis, and the hair colour of a photo.

Every SynHead-P hairstyle is a procedural mesh fitted to a head
(:func:`head360cli.synth.hair.fit_hair`). Given the fitted head and the photo's camera,
each of the 30 styles is fitted to that head and rasterized from that camera; the part of
it in front of the head is the silhouette the style would show in this photo. The score of
a style is the intersection over union of its silhouette with the parsed hair mask, and
the ranking follows the score. Nothing is trained, so nothing is tuned on the evaluation
photos; the only constant, the softmax temperature of the reported probabilities, is
fixed below.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

__all__ = [
    "HairGuess",
    "classify_hair",
    "hair_colour",
    "nearest_colour_name",
    "style_silhouettes",
]

TEMPERATURE = 0.05
"""IoU difference that multiplies a style's probability by e."""


@dataclasses.dataclass
class HairGuess:
    """Result of :func:`classify_hair`.

    Attributes:
        ranking: Style ids, best first.
        iou: ``(30,)`` IoU of each style's silhouette with the hair mask.
        probability: ``(30,)`` softmax of ``iou / TEMPERATURE``.
    """

    ranking: list[int]
    iou: np.ndarray
    probability: np.ndarray

    def top(self, k: int = 3) -> list[dict[str, float | int | str]]:
        """The best ``k`` styles as ``{"id", "name", "score", "iou"}``."""
        from head360cli.synth.hair import HAIRSTYLES

        return [{"id": int(i), "name": HAIRSTYLES[i].name,
                 "score": round(float(self.probability[i]), 4),
                 "iou": round(float(self.iou[i]), 4)} for i in self.ranking[:k]]


def style_silhouettes(neutral: np.ndarray, posed: np.ndarray, faces: np.ndarray,
                      c2w: np.ndarray, intrinsics: np.ndarray, res: int,
                      styles: list[int] | None = None) -> np.ndarray:
    """Visible hair of each style on a head, seen by one camera.

    Args:
        neutral: ``(V, 3)`` neutral head the styles are fitted to.
        posed: ``(V, 3)`` the head as seen (with its expression), for occlusion.
        faces: ``(F, 3)`` head triangles.
        c2w: ``(4, 4)`` camera-to-world and ``intrinsics (3, 3)`` for a ``res`` image.
        res: Image size.
        styles: Style ids (default: all 30).

    Returns:
        ``(S, res, res)`` bool: where each style's hair is in front of the head.
    """
    from head360cli.model.render import EMPTY, screen_depth
    from head360cli.synth.hair import HAIRSTYLES, fit_hair

    styles = list(range(len(HAIRSTYLES))) if styles is None else styles
    cam = torch.as_tensor(c2w, dtype=torch.float32)[None]
    k = torch.as_tensor(intrinsics, dtype=torch.float32)[None]
    head = screen_depth(torch.as_tensor(posed, dtype=torch.float32)[None],
                        torch.as_tensor(faces, dtype=torch.long), cam, k, res)[0]
    out = np.zeros((len(styles), res, res), bool)
    for j, s in enumerate(styles):
        mesh = fit_hair(neutral, s)
        if len(mesh.faces) == 0:
            continue
        d = screen_depth(torch.as_tensor(mesh.verts, dtype=torch.float32)[None],
                         torch.as_tensor(mesh.faces, dtype=torch.long), cam, k, res)[0]
        out[j] = ((d < EMPTY) & (d < head + 1e-3)).numpy()
    return out


def classify_hair(hair: np.ndarray, silhouettes: np.ndarray,
                  valid: np.ndarray | None = None) -> HairGuess:
    """Rank hairstyles by how well their silhouettes match a hair mask.

    Args:
        hair: ``(R, R)`` bool hair mask in the silhouettes' camera.
        valid: ``(R, R)`` bool, where the photo has pixels (a crop can reach beyond the
            photo's edge; there the hair is unknown and not scored). Default: all.
        silhouettes: ``(30, R, R)`` bool, from :func:`style_silhouettes`.

    Returns:
        The ranking with IoU and probabilities. A photo without hair pixels ranks the
        bald style (empty silhouette) first.
    """
    from head360cli.fitting.hair_parse import mask_iou

    if valid is not None:
        hair, silhouettes = hair[valid], silhouettes[:, valid]
    iou = np.array([mask_iou(s, hair) for s in silhouettes])
    z = (iou - iou.max()) / TEMPERATURE
    p = np.exp(z) / np.exp(z).sum()
    ranking = [int(i) for i in np.argsort(-iou, kind="stable")]
    return HairGuess(ranking, iou, p)


COLOUR_GAIN = 4.0
"""Linear hair albedo per unit of linear pixel colour: rendered hair is shaded, so darker
than its albedo. Measured on 19 frontal SynHead-P renders of corpus seed 1 (not the
training corpus, not photos): the ratio of the albedo to the median hair pixel had a
geometric mean of 3.9 (median 5.2, quartiles 2.8 and 6.3)."""


def hair_colour(rgb: np.ndarray, hair: np.ndarray, gain: float = COLOUR_GAIN) -> np.ndarray:
    """``(3,)`` linear RGB hair colour in [0, 1]: the per-channel median of the hair
    pixels of ``rgb (H, W, 3)`` uint8, linearised from sRGB and scaled by ``gain``.
    Falls back to dark brown when the mask is empty."""
    from head360cli.synth.hair import HAIR_COLOURS

    if not hair.any():
        return np.asarray(HAIR_COLOURS["dark brown"], np.float32)
    srgb = np.median(rgb[hair].astype(np.float64) / 255.0, axis=0)
    linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    return np.clip(linear * gain, 0.0, 1.0).astype(np.float32)


def nearest_colour_name(colour: np.ndarray) -> str:
    """The SynHead-P hair colour name nearest to a linear RGB colour (in sRGB terms)."""
    from head360cli.synth.hair import HAIR_COLOURS

    def srgb(c):
        c = np.asarray(c, np.float64)
        return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1 / 2.4) - 0.055)

    target = srgb(colour)
    return min(HAIR_COLOURS, key=lambda n: float(np.sum((srgb(HAIR_COLOURS[n]) - target) ** 2)))


FIGARO_CLASSES: dict[str, tuple[str, ...]] = {
    "straight": ("bob", "lob", "bangs", "shoulder straight", "long straight",
                 "ponytail high", "ponytail low", "bun", "top knot", "middle part long"),
    "wavy": ("shoulder wavy", "long wavy"),
    "curly": ("curly short", "long curly"),
    "kinky": ("afro",),
    "braids": ("braid", "twin tails"),
    "dreadlocks": ("dreadlocks",),
    "short-men": ("bald", "buzz", "crew", "side part", "slicked back", "pompadour",
                  "undercut", "mohawk", "pixie", "mullet", "receding", "side swept"),
}
"""Figaro-1k's 7 coarse classes, each as the SynHead-P styles that belong to it (every
style in exactly one class; tied-back long hair counts as straight)."""


def figaro_class(style: int) -> str:
    """The Figaro-1k class of a SynHead-P style id."""
    from head360cli.synth.hair import HAIRSTYLES

    name = HAIRSTYLES[style].name
    return next(k for k, names in FIGARO_CLASSES.items() if name in names)

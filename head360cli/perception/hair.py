"""Hair probability from MediaPipe's hair segmenter on LiteRT.

The model reads a 512x512 RGB square (values in [0, 1]) with a fourth channel for the
previous frame's mask (zero for a photo) and answers two logits per pixel (background,
hair). It reads the whole photo letterboxed into the square, and its answer is mapped
back to the photo's pixels.
"""

from __future__ import annotations

import numpy as np

__all__ = ["HAIR_SIDE", "hair_probability"]

HAIR_SIDE = 512
"""The hair model's input side."""


def _square_about(centre: tuple[float, float], side: float) -> np.ndarray:
    """The ``(2, 3)`` affine map from photo pixels to a unit square (side 1) of ``side``
    pixels about ``centre``."""
    return np.array([[1.0 / side, 0.0, 0.5 - centre[0] / side],
                     [0.0, 1.0 / side, 0.5 - centre[1] / side]])


def _run_letterboxed(rgb: np.ndarray, out: int, run) -> np.ndarray:
    """Warp ``rgb`` letterboxed to an ``out`` square, ``run`` the model on it, and warp
    the ``(out, out)`` map back to ``(H, W)``."""
    import cv2

    h, w = rgb.shape[:2]
    to_input = _square_about((w / 2, h / 2), max(h, w)) * out
    img = cv2.warpAffine(rgb, to_input, (out, out), flags=cv2.INTER_AREA
                         if to_input[0, 0] < 1 else cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT)
    prob = run(img.astype(np.float32) / 255.0)
    back = cv2.warpAffine(prob.astype(np.float32), to_input, (w, h),
                          flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    return np.clip(back, 0.0, 1.0)


def hair_probability(rgb: np.ndarray, threads: int | None = None) -> np.ndarray:
    """``(H, W)`` float32 probability of hair for an ``(H, W, 3)`` uint8 RGB photo.

    Args:
        rgb: The photo.
        threads: LiteRT threads (default: the process's budget, at most 2).
    """
    from head360cli.perception.runtime import tflite_model

    model = tflite_model("hair_segmenter", None, threads)

    def run(x: np.ndarray) -> np.ndarray:
        x4 = np.concatenate([x, np.zeros((*x.shape[:2], 1), np.float32)], -1)
        logits = model(x4[None])[0][0]
        return 1.0 / (1.0 + np.exp(np.clip(logits[..., 0] - logits[..., 1], -60, 60)))

    return _run_letterboxed(rgb, HAIR_SIDE, run)

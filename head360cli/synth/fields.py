"""Smooth scalar fields shared by the procedural head: sculpting, blendshapes, painting."""

from __future__ import annotations

import numpy as np

__all__ = ["gauss2d", "smoothstep"]


def smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    """0 at ``e0``, 1 at ``e1``, a cubic ramp between (``e1 < e0`` ramps down)."""
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def gauss2d(x: np.ndarray, y: np.ndarray, cx: float, cy: float, sx: float, sy: float
            ) -> np.ndarray:
    """An axis-aligned Gaussian bump of height 1 centred at ``(cx, cy)``."""
    return np.exp(-0.5 * (((x - cx) / sx) ** 2 + ((y - cy) / sy) ** 2))

"""The 68 iBUG landmarks read from the landmarker's 478 points.

Each iBUG point is a fixed convex combination of a few mesh points (``index (68, K)``,
``weight (68, K)``), learnt by :func:`fit_ibug68_map` from faces whose 68 points are
known and stored in ``models/ibug68_map.npz`` (``head360 build-landmark-map`` makes it
again). A combination rather than one mesh point: iBUG's points (the eyebrows' upper
edge, the jawline) fall between the mesh's vertices.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["IBUG68_FILE", "fit_ibug68_map", "load_ibug68_map", "nme", "to_ibug68"]

IBUG68_FILE = "ibug68_map.npz"
"""The map's file name in the models folder."""
CANDIDATES = 8
"""Mesh points each iBUG point may combine: the nearest to it on the training faces."""


def nme(pred: np.ndarray, truth: np.ndarray) -> float:
    """Mean landmark error over sqrt(w x h) of the ground truth's bounding box (the
    normalisation of AFLW2000-3D benchmarks)."""
    span = truth.max(0) - truth.min(0)
    return float(np.linalg.norm(pred - truth, axis=1).mean() / np.sqrt(span[0] * span[1]))


def fit_ibug68_map(meshes: list[np.ndarray], targets: list[np.ndarray],
                   candidates: int = CANDIDATES) -> tuple[np.ndarray, np.ndarray]:
    """The combination of mesh points that best gives each iBUG point.

    Args:
        meshes: Per face, ``(478, 2)`` (or ``(478, 3)``) landmarker points in pixels.
        targets: Per face, ``(68, 2)`` iBUG points in the same pixels.
        candidates: Mesh points per iBUG point.

    Returns:
        ``index (68, K)`` int and ``weight (68, K)`` float, weights >= 0 summing to 1,
        minimising the squared error over the faces (each face scaled to its landmark
        box's size).
    """
    from scipy.optimize import nnls

    pairs = []
    for mesh, target in zip(meshes, targets, strict=True):
        span = target.max(0) - target.min(0)
        size = float(np.sqrt(span[0] * span[1]))
        pairs.append((mesh[:468, :2] / size, target / size))
    index = np.zeros((68, candidates), np.int64)
    weight = np.zeros((68, candidates))
    for k in range(68):
        dist = np.mean([np.linalg.norm(m - t[k], axis=1) for m, t in pairs], axis=0)
        near = np.argsort(dist)[:candidates]
        a = np.concatenate([(m[near] - t[k]).T for m, t in pairs])  # (2N, K)
        rho = 10.0 * np.sqrt(len(pairs))
        w, _ = nnls(np.vstack([a, rho * np.ones((1, candidates))]),
                    np.r_[np.zeros(len(a)), rho])
        index[k], weight[k] = near, w / w.sum()
    return index, weight


@functools.lru_cache(maxsize=1)
def load_ibug68_map() -> tuple[np.ndarray, np.ndarray]:
    """The shipped map ``(index (68, K), weight (68, K))``.

    Raises:
        ModelNotFoundError: The file is missing. FileFormatError: it is unreadable.
    """
    from head360cli.errors import FileFormatError, ModelNotFoundError
    from head360cli.paths import models_dir

    path = models_dir() / IBUG68_FILE
    if not path.is_file():
        raise ModelNotFoundError(f"expected the landmark map {path}, found none: make it "
                                 "with head360 build-landmark-map, or reinstall head360")
    try:
        with np.load(path, allow_pickle=False) as data:
            index, weight = data["index"], data["weight"]
    except (OSError, ValueError, KeyError) as exc:
        raise FileFormatError(f"{path}: not a readable landmark map ({exc})") from exc
    if index.shape != weight.shape or index.shape[0] != 68 or index.max() >= 478:
        raise FileFormatError(f"{path}: expected index and weight of shape (68, K) with "
                              f"indices below 478, found {index.shape}, {weight.shape}")
    return index, weight


def to_ibug68(points: np.ndarray, mapping: tuple[np.ndarray, np.ndarray] | None = None
              ) -> np.ndarray:
    """``(68, 2)`` iBUG landmarks from ``(478, D)`` landmarker points (by the shipped map
    unless ``mapping`` is given)."""
    index, weight = mapping if mapping is not None else load_ibug68_map()
    return (points[index, :2] * weight[..., None]).sum(1)

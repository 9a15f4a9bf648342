"""Mesh export: Wavefront OBJ with texture coordinates, written atomically."""

from __future__ import annotations

import os

import numpy as np

__all__ = ["write_obj"]


def write_obj(path: str | os.PathLike[str], verts: np.ndarray, faces: np.ndarray,
              uv: np.ndarray | None = None, faces_uv: np.ndarray | None = None,
              comment: str = "") -> None:
    """Write an OBJ file (``v``, optional ``vt``, ``f`` with 1-based indices).

    Args:
        path: Output ``.obj``.
        verts: ``(V, 3)`` positions.
        faces: ``(F, 3)`` vertex indices (0-based).
        uv: ``(T, 2)`` texture coordinates (v up, as OBJ expects: stored as ``1 - v``).
        faces_uv: ``(F, 3)`` indices into ``uv``.
        comment: A header comment.
    """
    from head360cli.io.atomic import atomic_path

    lines = [f"# {line}" for line in comment.splitlines()] if comment else []
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in np.asarray(verts, dtype=np.float64)]
    with_uv = uv is not None and faces_uv is not None and len(uv)
    if with_uv:
        lines += [f"vt {u:.6f} {1.0 - v:.6f}" for u, v in np.asarray(uv, dtype=np.float64)]
        f1, t1 = np.asarray(faces) + 1, np.asarray(faces_uv) + 1
        lines += [f"f {a}/{ta} {b}/{tb} {c}/{tc}"
                  for (a, b, c), (ta, tb, tc) in zip(f1, t1, strict=True)]
    else:
        lines += [f"f {a} {b} {c}" for a, b, c in np.asarray(faces) + 1]
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n")

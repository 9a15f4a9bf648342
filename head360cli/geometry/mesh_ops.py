"""Pure batched mesh functions: face and vertex normals."""

from __future__ import annotations

import torch

__all__ = ["face_normals", "vertex_normals"]


def face_normals(verts: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Area-weighted face normals (length = twice the area).

    Args:
        verts: ``(B, V, 3)``.
        faces: ``(F, 3)``.

    Returns:
        ``(B, F, 3)``.
    """
    tri = verts[:, faces]
    return torch.cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0], dim=-1)


def vertex_normals(verts: torch.Tensor, faces: torch.Tensor,
                   weld_groups: torch.Tensor | None = None, tol: float = 1e-7
                   ) -> torch.Tensor:
    """Unit vertex normals: the area-weighted sum of the adjacent face normals.

    Degenerate (zero-area) faces contribute nothing; a vertex with no area around it gets
    +z. ``weld_groups`` handles a surface folded onto itself (the closed lips of the head,
    whose mouth pocket collapses at the corners): vertices of a group that sit where the
    group's first vertex is share one normal, so no shading seam shows there. Where they
    separate (an open mouth) nothing changes.

    Args:
        verts: ``(B, V, 3)``.
        faces: ``(F, 3)``.
        weld_groups: ``(G, K)`` vertex ids, or ``None``.
        tol: Distance under which vertices of a group coincide.

    Returns:
        ``(B, V, 3)`` unit vectors.
    """
    fn = face_normals(verts, faces)  # (B, F, 3)
    b, v = verts.shape[:2]
    acc = torch.zeros(b, v, 3, dtype=verts.dtype, device=verts.device)
    acc = acc.index_add(1, faces.reshape(-1), fn.repeat_interleave(3, dim=1))
    if weld_groups is not None:
        pos = verts[:, weld_groups]  # (B, G, K, 3)
        same = ((pos - pos[:, :, :1]).norm(dim=-1, keepdim=True) <= tol).to(acc.dtype)
        members = acc[:, weld_groups]  # (B, G, K, 3)
        shared = (members * same).sum(2, keepdim=True)
        welded = same * shared + (1 - same) * members
        index = weld_groups.reshape(-1)
        acc = acc.index_copy(1, index, welded.reshape(b, -1, 3))
    length = acc.norm(dim=-1, keepdim=True)
    fallback = torch.zeros_like(acc)
    fallback[..., 2] = 1.0
    return torch.where(length > 1e-20, acc / length.clamp_min(1e-20), fallback)

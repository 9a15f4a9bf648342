"""Pure batched mesh functions: face and vertex normals, texture coordinates across a
wrap-around seam."""

from __future__ import annotations

import torch

__all__ = ["face_normals", "seam_uv", "vertex_normals"]


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


def seam_uv(faces: torch.Tensor, uv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Texture coordinates for a mesh whose u wraps round (a hair shell: u from 0 to 1
    around the head): a face that spans more than half of u crosses the seam, and its
    corners below 0.5 read u + 1 instead, so the face interpolates across the seam
    rather than back over the whole texture (read u modulo 1 afterwards).

    Args:
        faces: ``(F, 3)`` vertex indices, which index ``uv`` too.
        uv: ``(V, 2)``.

    Returns:
        ``uv (2V, 2)`` (the original, then each shifted by one in u) and ``faces_uv
        (F, 3)`` into it; shapes depend on nothing but the input's, for export.
    """
    fu = uv[faces, 0]
    crosses = (fu.amax(1, keepdim=True) - fu.amin(1, keepdim=True)) > 0.5
    shifted = crosses & (fu < 0.5)
    one = torch.zeros_like(uv)
    one[:, 0] = 1.0
    return torch.cat([uv, uv + one]), faces + shifted.to(faces.dtype) * uv.shape[0]

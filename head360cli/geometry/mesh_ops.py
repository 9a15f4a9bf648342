"""Pure batched mesh functions: face and vertex normals, texture coordinates across a
wrap-around seam, distances to a shell's open edge."""

from __future__ import annotations

import torch

__all__ = ["edge_distance", "face_normals", "seam_uv", "vertex_normals"]


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


def edge_distance(verts: torch.Tensor, faces: torch.Tensor, uv: torch.Tensor,
                  reach: float, rounds: int = 12) -> torch.Tensor:
    """Each vertex's distance along its strand to the strand's end in a hair shell
    (its tip, or its root at a hairline), capped at ``reach``.

    The shell is a grid whose columns (one u each) are strands running in v. It is
    closed by walls joining its outer layer to the inner one, which shares the outer's
    texture coordinates: two distinct corners of a face at one texture point are twins
    on a wall. Twins on a wall across a column (the face's corners at one v) end their
    strands there, where twins run on along the row on both sides: a staircase (the
    side of the face's opening, cut from the grid) is where strands pass by. The ring
    round the crown (v = 0) ends none; pieces without walls (tails, buns) are ``reach``
    everywhere. Distances run along the columns only, so the side of a parting or of
    the face's opening, where strands run alongside the edge, stays dense.

    Args:
        verts: ``(V, 3)``.
        faces: ``(F, 3)``, which index ``uv`` too.
        uv: ``(V, 2)``.
        reach: Largest distance kept (metres).
        rounds: Relaxation rounds (a strand of more edges than this is not followed).

    Returns:
        ``(V,)`` distances in [0, reach]; shapes depend on the input's only (export).
    """
    t = uv[faces]  # (F, 3, 2)
    v = t[..., 1]
    across = ((v.amax(1) - v.amin(1)) < 1e-9) & (v.amax(1) > 0)
    end = torch.zeros(verts.shape[0], dtype=verts.dtype, device=verts.device)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        # two distinct corners at one texture point (a padded face repeats one corner):
        # both are on a wall across a column
        twin = (((t[:, i] - t[:, j]).abs().sum(-1) < 1e-9) & (faces[:, i] != faces[:, j])
                & across).to(verts.dtype)
        for k in (i, j):
            end = end.scatter_reduce(0, faces[:, k], twin, reduce="amax")
    a = torch.cat([faces[:, 0], faces[:, 1], faces[:, 2]])
    b = torch.cat([faces[:, 1], faces[:, 2], faces[:, 0]])
    a, b = torch.cat([a, b]), torch.cat([b, a])
    # an end counts where the ends run on along the row on both sides: a staircase
    # (the side of the face's opening, cut from the grid) is where strands pass by
    du = uv[b, 0] - uv[a, 0]
    du = du - torch.round(du)  # across the seam in u
    row = (end[a] * end[b] > 0) & ((uv[b, 1] - uv[a, 1]).abs() < 1e-9)
    zeros = torch.zeros_like(end)
    left = zeros.scatter_reduce(0, a, (row & (du < 0)).to(end.dtype), reduce="amax")
    right = zeros.scatter_reduce(0, a, (row & (du > 0)).to(end.dtype), reduce="amax")
    end = end * left * right
    dist = float(reach) * (1.0 - end)
    # along a column only: elsewhere the step is at least reach, so it changes nothing
    along = (uv[a, 0] - uv[b, 0]).abs() < 1e-9
    length = (verts[a] - verts[b]).norm(dim=-1)
    length = torch.where(along, length, torch.full_like(length, float(reach)))
    for _ in range(rounds):
        dist = dist.scatter_reduce(0, b, dist[a] + length, reduce="amin")
    return dist.clamp(max=reach)

"""A triangle rasterizer in plain torch (gather and scatter ops), for CPU and GPU.

It serves the corpus renderer, the hex-plane rasterization and the screen depth used to
place volume samples. Input is already in screen space (pixels plus depth), so the same
function rasterizes perspective views (``perspective_correct=True``) and orthographic ones.

How it works: every triangle is given the pixels of its bounding box as candidates. To keep
the work proportional to the covered area, triangles are grouped by bounding-box size and
each group uses a ``K x K`` candidate window with ``K`` the group's power of two. Candidates
inside the triangle write their depth key (``1/depth``, linear in screen space) into a
z-buffer with ``scatter_reduce("amax")``; the candidates that match the z-buffer then write
their triangle id (ties: the larger id). Each triangle's barycentrics and depth key are
plane equations, so a whole candidate window is one small batched matrix product. The
barycentric coordinates of each covered pixel are recomputed from its triangle, so they are
differentiable with respect to the vertex positions (visibility is not).
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator

import torch

__all__ = ["Fragments", "ZBuffer", "exporting", "interpolate", "interpolate_face_corners",
           "rasterize", "static_windows"]


_STATIC_LEVELS: tuple[int, ...] | None = None


def exporting() -> bool:
    """Whether torch is tracing for an export (``torch.export`` or ONNX) now: code with a
    faster eager form and an export form picks by it."""
    return bool(torch.compiler.is_exporting() or torch.onnx.is_in_onnx_export())


@contextlib.contextmanager
def static_windows(sizes: tuple[int, ...] = (1, 2, 4, 8, 16, 32, 64)) -> Iterator[None]:
    """Inside the ``with`` block, rasterize with this fixed list of candidate-window sizes
    instead of one chosen from the data, so the graph has no data-dependent control flow
    (``torch.export`` and ONNX need that). Triangles wider or taller than the last size
    are not drawn; with the default that is 64 pixels, far above the generator's
    triangles at its 128-pixel resolutions."""
    global _STATIC_LEVELS
    own = _STATIC_LEVELS
    _STATIC_LEVELS = tuple(sizes)
    try:
        yield
    finally:
        _STATIC_LEVELS = own


@dataclasses.dataclass
class Fragments:
    """What the rasterizer found at each pixel.

    Attributes:
        face_id: ``(B, H, W)`` int64 index of the visible triangle, -1 where none.
        bary: ``(B, H, W, 3)`` barycentric coordinates in that triangle (perspective-
            correct if asked), zero where none.
        depth: ``(B, H, W)`` depth of the visible surface, zero where none.
        zbuffer: The depth test's state (see :class:`ZBuffer`); ``None`` where the
            fragments were made with static windows.
    """

    face_id: torch.Tensor
    bary: torch.Tensor
    depth: torch.Tensor
    zbuffer: ZBuffer | None = None

    @property
    def mask(self) -> torch.Tensor:
        """``(B, H, W)`` bool: a triangle covers the pixel."""
        return self.face_id >= 0


@dataclasses.dataclass
class ZBuffer:
    """The depth test's state after drawing some triangles: what :func:`rasterize` with
    ``draw`` returns in ``Fragments.zbuffer`` and takes back as ``under``, so that
    triangles that never move are drawn once and the others drawn over them each frame
    (the same fragments as drawing all of them together).

    Attributes:
        key: ``(B * H * W,)`` nearest depth key per pixel (``1/depth`` for perspective,
            ``-depth`` for orthographic rasterization; larger is nearer), ``-inf`` where
            no triangle was drawn.
        face_id: ``(B * H * W,)`` int64 triangle with that key (ties: the larger id), -1
            where none.
    """

    key: torch.Tensor
    face_id: torch.Tensor


def _barycentric(tri: torch.Tensor, px: torch.Tensor, py: torch.Tensor, area: torch.Tensor
                 ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Screen barycentrics of points ``(px, py)`` in triangles ``tri (..., 3, 2)``."""
    x0, y0 = tri[..., 0, 0], tri[..., 0, 1]
    x1, y1 = tri[..., 1, 0], tri[..., 1, 1]
    x2, y2 = tri[..., 2, 0], tri[..., 2, 1]
    w0 = ((x1 - px) * (y2 - py) - (x2 - px) * (y1 - py)) / area
    w1 = ((x2 - px) * (y0 - py) - (x0 - px) * (y2 - py)) / area
    return w0, w1, 1.0 - w0 - w1


def rasterize(screen: torch.Tensor, depth: torch.Tensor, faces: torch.Tensor, height: int,
              width: int, *, perspective_correct: bool = True, near: float = 1e-4,
              eps: float = 1e-6, cull_backfaces: bool = False,
              draw: torch.Tensor | None = None, under: ZBuffer | None = None) -> Fragments:
    """Rasterize triangles given in screen space.

    Args:
        screen: ``(B, V, 2)`` vertex positions in pixels (OpenCV: x right, y down; pixel
            ``(i, j)`` is sampled at ``(j + 0.5, i + 0.5)``).
        depth: ``(B, V)`` vertex depths; smaller is nearer. Triangles with a vertex at
            depth ``<= near`` (behind a perspective camera) are dropped.
        faces: ``(F, 3)`` int64 vertex indices.
        height: Image height ``H``.
        width: Image width ``W``.
        perspective_correct: Interpolate ``1/depth`` (perspective views); ``False``
            interpolates depth linearly (orthographic views, where depth may be negative:
            pass ``near=-inf``).
        near: Near clipping depth.
        eps: Tolerance of the inside test, in barycentric units (shared edges leave no
            cracks).
        cull_backfaces: Drop triangles seen from behind (counter-clockwise in the world,
            seen from outside, is front). Only for closed, outward-facing meshes.
        draw: Optional ``(F,)`` bool: draw only these triangles.
        under: Optional :class:`ZBuffer` of the other triangles drawn at the same
            positions before (``Fragments.zbuffer`` of a call with ``draw`` their mask):
            the result is that of drawing both sets at once.

    Returns:
        The visible triangle, barycentrics and depth at every pixel.
    """
    b = depth.shape[0]
    device, dtype = screen.device, screen.dtype
    hw = height * width
    corners = faces.reshape(-1)
    tri = screen.index_select(1, corners).view(b, -1, 3, 2)  # (B, F, 3, 2)
    tri_z = depth.index_select(1, corners).view(b, -1, 3)  # (B, F, 3)
    x, y = tri[..., 0], tri[..., 1]
    area = (x[..., 1] - x[..., 0]) * (y[..., 2] - y[..., 0]) - (
        x[..., 2] - x[..., 0]) * (y[..., 1] - y[..., 0])
    j0 = torch.ceil(x.min(-1).values - 0.5).clamp(0, width)
    j1 = torch.floor(x.max(-1).values - 0.5).clamp(-1, width - 1)
    i0 = torch.ceil(y.min(-1).values - 0.5).clamp(0, height)
    i1 = torch.floor(y.max(-1).values - 0.5).clamp(-1, height - 1)
    finite = torch.isfinite(tri).all(-1).all(-1) & torch.isfinite(tri_z).all(-1)
    valid = (finite & (tri_z > near).all(-1) & (area.abs() > 1e-12)
             & (j1 >= j0) & (i1 >= i0))
    if cull_backfaces:
        # With image y pointing down, a triangle that is counter-clockwise seen from the
        # camera has negative screen area.
        valid &= area < 0
    if draw is not None:
        valid &= draw[None]

    bi, fi = torch.nonzero(valid, as_tuple=True)
    # Gathers here are index_select on a flat index: tensor indexing exports as ONNX
    # GatherND, which onnxruntime (and torch, for a (batch, face) pair) runs 2-3x slower
    sel_all = bi * faces.shape[0] + fi
    t = tri.flatten(0, 1).index_select(0, sel_all)
    tz = tri_z.flatten(0, 1).index_select(0, sel_all)
    tj0, ti0, tj1, ti1, ar = torch.stack([j0, i0, j1, i1, area], -1).flatten(
        0, 1).index_select(0, sel_all).unbind(1)
    sizes = torch.maximum(tj1 - tj0, ti1 - ti0) + 1  # bounding-box extent in pixels
    # Plane equations of the selected triangles: w_k = A_k x + B_k y + C_k for the three
    # barycentrics, and the depth key (1/z for perspective, -z for orthographic, larger
    # is nearer) likewise, all linear in screen space.
    x0, y0, x1, y1, x2, y2 = (t[:, 0, 0], t[:, 0, 1], t[:, 1, 0], t[:, 1, 1], t[:, 2, 0],
                              t[:, 2, 1])
    a = torch.stack([y1 - y2, y2 - y0, y0 - y1], 1) / ar[:, None]
    bb = torch.stack([x2 - x1, x0 - x2, x1 - x0], 1) / ar[:, None]
    c = torch.stack([x1 * y2 - x2 * y1, x2 * y0 - x0 * y2, x0 * y1 - x1 * y0], 1) / ar[:, None]
    key_v = 1.0 / tz if perspective_correct else -tz
    a = torch.cat([a, (a * key_v).sum(1, keepdim=True)], 1)  # (n, 4)
    bb = torch.cat([bb, (bb * key_v).sum(1, keepdim=True)], 1)
    c = torch.cat([c, (c * key_v).sum(1, keepdim=True)], 1)
    base = a * (tj0 + 0.5)[:, None] + bb * (ti0 + 0.5)[:, None] + c  # at the box corner
    plane = torch.stack([a, bb, base], 2)  # (n, 4, 3)
    # one row per triangle: its plane equations (12: three barycentrics, then the depth
    # key), box corner and box extent (4); and its flat pixel offset and face id
    table = torch.cat([plane.flatten(1), torch.stack([tj0, ti0, tj1 - tj0, ti1 - ti0], 1)],
                      1)
    ids = torch.stack([bi * hw, fi], 1)

    pix_all, key_all, face_all = [], [], []
    static = _STATIC_LEVELS is not None
    if static:  # a fixed list of window sizes: no data-dependent Python control flow
        windows = list(_STATIC_LEVELS)
    else:  # as many sizes as the largest triangle needs
        max_size = int(sizes.max().item()) if sizes.numel() else 0
        windows = [1]
        while windows[-1] < max_size:
            windows.append(windows[-1] * 2)
    lower = 0
    for k in windows:
        sel = torch.nonzero((sizes > lower) & (sizes <= k), as_tuple=True)[0]
        if static or sel.numel():
            d = torch.arange(k, device=device, dtype=dtype)
            dy, dx = torch.meshgrid(d, d, indexing="ij")
            offsets = torch.stack([dx.reshape(-1), dy.reshape(-1)])  # (2, K2)
            rows = table.index_select(0, sel)
            p = rows[:, :9].view(-1, 3, 3)
            # (n, 3, K2): the three barycentrics, element-wise rather than a matrix
            # product so that torch and onnxruntime round them alike (same coverage)
            values = (p[..., 0:1] * offsets[0] + p[..., 1:2] * offsets[1]) + p[..., 2:3]
            inside = ((values.amin(1) >= -eps)
                      & (offsets[0][None] <= rows[:, 14:15])
                      & (offsets[1][None] <= rows[:, 15:16]))
            row, col = torch.nonzero(inside, as_tuple=True)
            hit = rows.index_select(0, row)
            hit_ids = ids.index_select(0, sel.index_select(0, row))
            ox, oy = offsets[0].index_select(0, col), offsets[1].index_select(0, col)
            px = (hit[:, 12] + ox).long()
            py = (hit[:, 13] + oy).long()
            pix_all.append(hit_ids[:, 0] + py * width + px)
            # depth key only where needed
            key_all.append(hit[:, 9] * ox + hit[:, 10] * oy + hit[:, 11])
            face_all.append(hit_ids[:, 1])
        lower = k

    if under is None:
        face_id = torch.full((b * hw,), -1, dtype=torch.long, device=device)
        zbuf = torch.full((b * hw,), float("-inf"), dtype=dtype, device=device)
    else:
        face_id, zbuf = under.face_id, under.key
    if pix_all:
        pix = torch.cat(pix_all)
        key = torch.cat(key_all).detach()
        face = torch.cat(face_all)
        nearest = zbuf.scatter_reduce(0, pix, key, reduce="amax", include_self=True)
        if under is not None:  # the earlier triangles keep the pixels they still win
            face_id = torch.where(zbuf >= nearest, face_id, torch.full_like(face_id, -1))
        zbuf = nearest
        win = torch.nonzero(key >= zbuf.index_select(0, pix)).squeeze(1)
        face_id = face_id.scatter_reduce(0, pix.index_select(0, win),
                                         face.index_select(0, win), reduce="amax",
                                         include_self=True)

    if static:  # every pixel, then masked: no data-dependent (possibly empty) index sets
        if draw is not None or under is not None:
            raise ValueError("expected no draw or under with static windows (export)")
        return _dense_fragments(face_id, tri, tri_z, area, b, height, width,
                                perspective_correct)
    fg = torch.nonzero(face_id >= 0, as_tuple=True)[0]
    bary = torch.zeros(b * hw, 3, dtype=dtype, device=device)
    zout = torch.zeros(b * hw, dtype=dtype, device=device)
    if fg.numel():
        w, zf = _surface_at(fg, face_id[fg], tri, tri_z, area, hw, width,
                            perspective_correct)
        bary = bary.index_put((fg,), w)
        zout = zout.index_put((fg,), zf)
    return Fragments(
        face_id=face_id.view(b, height, width),
        bary=bary.view(b, height, width, 3),
        depth=zout.view(b, height, width),
        zbuffer=ZBuffer(zbuf, face_id),
    )


def _surface_at(pix: torch.Tensor, f: torch.Tensor, tri: torch.Tensor,
                tri_z: torch.Tensor, area: torch.Tensor, hw: int, width: int,
                perspective_correct: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """Barycentrics ``(n, 3)`` and depth ``(n,)`` of triangle ``f[i]`` at the centre of
    flat pixel ``pix[i]`` (``batch * H W + row * W + column``), recomputed from the
    triangle so they are differentiable."""
    dtype = tri.dtype
    fb, rem = pix // hw, pix % hw
    cy = (rem // width).to(dtype) + 0.5
    cx = (rem % width).to(dtype) + 0.5
    flat = fb * tri.shape[1] + f  # one flat gather per array (see rasterize)
    a = area.flatten().index_select(0, flat)
    tz = tri_z.flatten(0, 1).index_select(0, flat)
    w0, w1, w2 = _barycentric(tri.flatten(0, 1).index_select(0, flat), cx, cy, a)
    w = torch.stack([w0, w1, w2], dim=-1).clamp(0.0, 1.0)
    w = w / w.sum(-1, keepdim=True).clamp_min(1e-12)
    if perspective_correct:
        wz = w / tz
        zf = 1.0 / wz.sum(-1)
        return wz * zf[:, None], zf
    return w, (w * tz).sum(-1)


def _dense_fragments(face_id, tri, tri_z, area, b, height, width, perspective_correct):
    """The fragments of :func:`rasterize` computed at every pixel and masked where no
    triangle is visible: the same formulas (:func:`_surface_at`, so the same values),
    with no index set that can be empty (onnxruntime's ScatterND refused an empty
    update).

    Uncovered pixels read a sentinel triangle appended to each batch item (unit area,
    depth 1), so every value computed is finite and masking is a product; a ``where``
    broadcast over the three barycentrics cost onnxruntime 6 ms a frame."""
    hw = height * width
    n_faces = tri.shape[1]
    covered = face_id >= 0
    unit = torch.tensor([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]], dtype=tri.dtype,
                        device=tri.device)
    tri = torch.cat([tri, unit.expand(b, 1, 3, 2)], 1)
    tri_z = torch.cat([tri_z, torch.ones_like(tri_z[:, :1])], 1)
    area = torch.cat([area, torch.ones_like(area[:, :1])], 1)
    pix = torch.arange(b * hw, device=tri.device)
    w, zf = _surface_at(pix, torch.where(covered, face_id, n_faces), tri, tri_z, area, hw,
                        width, perspective_correct)
    keep = covered.to(w.dtype)
    bary = w * keep[:, None]
    zout = zf * keep
    return Fragments(face_id=face_id.view(b, height, width),
                     bary=bary.view(b, height, width, 3), depth=zout.view(b, height, width))


def interpolate(attr: torch.Tensor, faces: torch.Tensor, frags: Fragments) -> torch.Tensor:
    """Interpolate per-vertex attributes at every pixel.

    Args:
        attr: ``(B, V, C)`` or ``(V, C)`` vertex attributes.
        faces: ``(F, 3)`` vertex indices.
        frags: The rasterizer's output.

    Returns:
        ``(B, H, W, C)``; zero where no triangle is visible.
    """
    return interpolate_face_corners(attr[..., faces, :] if attr.dim() == 3 else attr[faces],
                                    frags)


def interpolate_face_corners(corner_attr: torch.Tensor, frags: Fragments) -> torch.Tensor:
    """Interpolate attributes given per face corner (e.g. UVs with seams).

    Args:
        corner_attr: ``(B, F, 3, C)`` or ``(F, 3, C)``.
        frags: The rasterizer's output.

    Returns:
        ``(B, H, W, C)``; zero where no triangle is visible.
    """
    b, h, w = frags.face_id.shape
    fid = frags.face_id.clamp_min(0).reshape(b, h * w)
    if corner_attr.dim() == 3:
        corners = corner_attr.index_select(0, fid.reshape(-1)).view(
            b, h * w, 3, corner_attr.shape[-1])  # (B, HW, 3, C)
    else:
        corners = torch.gather(
            corner_attr, 1,
            fid[:, :, None, None].expand(b, h * w, 3, corner_attr.shape[-1]))
    bary = frags.bary.reshape(b, h * w, 3, 1)
    # the three corners summed explicitly: the same sum as .sum(2), and onnxruntime's
    # ReduceSum over a middle axis was slow
    out = (corners[:, :, 0] * bary[:, :, 0] + corners[:, :, 1] * bary[:, :, 1]
           + corners[:, :, 2] * bary[:, :, 2])
    out = out * frags.mask.reshape(b, h * w, 1).to(out.dtype)
    return out.view(b, h, w, -1)

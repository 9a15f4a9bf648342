"""Bake a head's rendered appearance onto its mesh, for export to other tools.

With the deferred generator each texel of the UV layout is located on the mesh (by
rasterizing the mesh in UV space) and shaded as a view that faces it would shade it,
straight from the neural texture; the hair likewise from the hair texture (a GLB's
hair as a texture on its strand coordinates, an OBJ's as vertex colours). With a
hex-plane generator, whose colour lives in a neural field, the bald head is
rendered from :data:`BAKE_VIEWS` and every texel takes the colour of the views that see
it, weighted towards views that face it; the hair's vertices the same way from renders
with hair. Texels no view sees, and the gutter between UV islands, are filled from their
nearest neighbours.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from head360cli.errors import BadInputError

__all__ = ["BAKE_VIEWS", "bake_hair_texture", "bake_head", "export_head", "grow_fill",
           "write_mesh_sequence"]

BAKE_VIEWS: tuple[tuple[float, float], ...] = (
    *((float(y), 0.0) for y in range(0, 360, 30)),
    *((float(y), 35.0) for y in range(0, 360, 45)),
    *((float(y), -30.0) for y in range(0, 360, 90)),
    (0.0, 75.0), (180.0, 75.0),
)
"""(yaw, pitch) in degrees of the renders a bake takes its colours from."""

VISIBLE_TOLERANCE = 0.004
"""Metres a texel may lie behind the rendered surface and still count as seen."""

TEXTURED_PART = "head"
"""The exported part that carries the baked texture (an OBJ writes it as
``<stem>_head.png``; an OBJ's hair part has vertex colours, a GLB's its own texture)."""


def grow_fill(colour: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Fill pixels of zero weight from their nearest known neighbours: ring after ring,
    each new pixel takes the mean of the known pixels around it (3 x 3).

    Only each ring's pixels are computed (a 512-pixel UV layout has about 200 rings in
    its gutters: filtering the whole image for each took 7 s, the rings take a fraction
    of a second).

    Args:
        colour: ``(H, W, C)`` float, meaningful where ``weight > 0``.
        weight: ``(H, W)`` non-negative.

    Returns:
        ``(H, W, C)`` with the weighted pixels unchanged and the others filled (all of
        them with the mean colour when nothing is known).
    """
    import cv2

    colour = np.asarray(colour, np.float64)
    known = np.asarray(weight) > 0
    if not known.any():
        return np.broadcast_to(colour.reshape(-1, colour.shape[-1]).mean(0),
                               colour.shape).copy()
    h, w = known.shape
    # padded by one pixel of nothing known, so that a ring's 3 x 3 reads stay inside
    c = np.zeros((h + 2, w + 2, colour.shape[-1]))
    c[1:-1, 1:-1][known] = colour[known]
    k = np.zeros((h + 2, w + 2))
    k[1:-1, 1:-1] = known
    grow = np.ones((3, 3), np.uint8)
    ring = (cv2.dilate(known.astype(np.uint8), grow) > 0) & ~known
    while ring.any():
        ys, xs = np.nonzero(ring)
        total = np.zeros((len(ys), c.shape[-1]))
        count = np.zeros(len(ys))
        for dy in range(3):
            for dx in range(3):
                total += c[ys + dy, xs + dx]  # zero where nothing is known
                count += k[ys + dy, xs + dx]
        c[ys + 1, xs + 1] = total / count[:, None]
        k[ys + 1, xs + 1] = 1.0
        known[ys, xs] = True
        ring = (cv2.dilate(ring.astype(np.uint8), grow) > 0) & ~known
    return c[1:-1, 1:-1].copy()


def _texels(renderer, size: int):
    """Per texel of a ``size`` x ``size`` UV layout: the point on the neutral mesh, its
    normal, and whether a triangle with an area on the mesh covers it (the template's
    seam triangles of no area took streaks of whatever the views showed there; they are
    left to the fill from the skin around them)."""
    import torch

    from head360cli.geometry.texels import texel_surface

    gen = renderer.gen
    faces, uv, faces_uv = gen.faces.cpu(), gen.uv.cpu(), gen.faces_uv.cpu()
    verts = renderer.vertices(np.zeros(52)).cpu()
    normals = torch.tensor(_normals(verts.numpy(), faces.numpy()), dtype=torch.float32)
    surf = texel_surface(verts, faces, uv, faces_uv, size, normals)
    return surf.points, surf.normals, surf.covered, verts


def _gather(points, normals, images, cams, k, depth_maps):
    """Weighted colour sums ``(N, 3)`` and weights ``(N,)`` of points seen in images."""
    import torch

    from head360cli.geometry.texels import seen_in_photo

    total = torch.zeros(len(points), 3, dtype=torch.float64)
    weight = torch.zeros(len(points), dtype=torch.float64)
    for img, cam, dmap in zip(images, cams, depth_maps, strict=True):
        colour, facing, visible = seen_in_photo(points, normals, img, cam, k,
                                                torch.where(dmap > 0, dmap, 1e9),
                                                VISIBLE_TOLERANCE)
        w = (facing ** 4) * visible
        total += (colour * w[:, None]).double()
        weight += w.double()
    return total, weight


def bake_head(renderer, size: int = 512, views=BAKE_VIEWS, progress: Any = None
              ) -> tuple[np.ndarray, np.ndarray | None]:
    """Bake the head's colours.

    Args:
        renderer: The head (:class:`~head360cli.model.head_render.HeadRenderer`).
        size: Texture width and height.
        views: (yaw, pitch) pairs to take colours from.
        progress: ``progress(stage, done, total)`` callback.

    Returns:
        ``(texture (size, size, 3) uint8, hair vertex colours (H, 3) uint8 or None)``.
    """
    import torch

    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.model.render import screen_depth

    if size < 16:
        raise BadInputError(f"expected a texture size of at least 16, found {size}")
    if not len(views):
        raise ValueError("expected at least one (yaw, pitch) view to bake from, found none")
    if renderer.gen.kind == "deferred":
        return _bake_deferred(renderer, size, progress)
    points, normals, covered, verts = _texels(renderer, size)
    cams = view_cameras([v[0] for v in views], [v[1] for v in views])
    k = view_intrinsics(renderer.size)
    faces = renderer.gen.faces.cpu()
    res = renderer.size
    flat_p, flat_n = points[covered], normals[covered]
    bald = renderer.render(cams, k, np.zeros(52), hair=False)
    if progress:
        progress("bake", 1, 2)
    head_depth = screen_depth(verts[None].expand(len(cams), -1, -1), faces, cams, k, res)
    total, weight = _gather(flat_p, flat_n, bald, cams, k, head_depth)
    colour = np.zeros((size, size, 3))
    w = np.zeros((size, size))
    m = covered.numpy()
    colour[m] = (total / weight.clamp_min(1e-12)[:, None]).numpy()
    w[m] = weight.numpy()
    texture = np.clip(grow_fill(colour, w) * 255 + 0.5, 0, 255).astype(np.uint8)
    hair_colours = None
    if renderer.hair is not None:
        hv, hf, _ = (t.cpu() for t in renderer.hair.meshes[0])
        with_hair = renderer.render(cams, k, np.zeros(52), hair=True)
        hair_depth = torch.minimum(head_depth, screen_depth(
            hv[None].expand(len(cams), -1, -1), hf, cams, k, res))
        hn = torch.tensor(_normals(hv.numpy(), hf.numpy()), dtype=torch.float32)
        total, weight = _gather(hv, hn, with_hair, cams, k, hair_depth)
        seen = weight > 0
        mean = (total[seen].sum(0) / weight[seen].sum().clamp_min(1e-12)
                if bool(seen.any()) else torch.full((3,), 0.5, dtype=torch.float64))
        c = torch.where(seen[:, None], total / weight.clamp_min(1e-12)[:, None], mean)
        hair_colours = np.clip(c.numpy() * 255 + 0.5, 0, 255).astype(np.uint8)
    if progress:
        progress("bake", 2, 2)
    return texture, hair_colours


def _smoothed(colour: np.ndarray, known: np.ndarray, rounds: int = 24) -> np.ndarray:
    """``colour (H, W, C)`` with its unknown texels (``~known``) relaxed towards the mean
    of their neighbours ``rounds`` times, the known ones held: where two fronts of
    :func:`grow_fill` meet (the template's seam band, between sharply textured islands)
    no step is left."""
    import cv2

    out = colour.astype(np.float32)
    free = ~known
    for _ in range(rounds):
        out[free] = cv2.blur(out, (3, 3))[free]
    return out.astype(np.float64)


def _shaded(renderer, texture, uv, normals, hair: bool):
    """Colours ``(N, 3)`` in [0, 1] of points at ``uv (N, 2)`` on ``texture (1, C, R,
    R)`` with ``normals (N, 3)``, seen squarely, as the deferred generator's shader (and
    the head's light) colours them."""
    import torch

    from head360cli.model.deferred import read_texels

    gen = renderer.gen
    c, res = texture.shape[1], texture.shape[-1]
    table = texture[0].permute(1, 2, 0).reshape(-1, c)
    n = len(uv)
    zeros = torch.zeros(n, dtype=torch.long, device=table.device)
    feats = read_texels(table, zeros, torch.full_like(zeros, res), uv.to(table))
    normals = normals.to(table)
    flag = torch.full((n, 1), float(hair), dtype=table.dtype, device=table.device)
    with torch.no_grad():
        rgb = gen.shader(feats, normals, normals, flag)[0][:, :3]
        if renderer.colour_gain is not None:
            rgb = rgb * renderer.colour_gain.reshape(1, 3).to(rgb)
    return rgb.clamp(0, 1).double().cpu()


def _bake_deferred(renderer, size: int, progress: Any):
    """:func:`bake_head` of a deferred generator: each texel's colour is its own texels
    shaded as a view that faces it would shade them, read straight from the neural
    texture (no renders); the hair's vertices likewise from the hair texture."""
    import torch

    from head360cli.geometry.texels import texel_surface

    gen = renderer.gen
    verts = renderer.vertices(np.zeros(52)).cpu()
    faces = gen.faces.cpu()
    normals = torch.tensor(_normals(verts.numpy(), faces.numpy()), dtype=torch.float32)
    surf = texel_surface(verts, faces, gen.uv.cpu(), gen.faces_uv.cpu(), size, normals)
    u = (torch.arange(size, dtype=torch.float32) + 0.5) / size
    uv = torch.stack(torch.meshgrid(u, u, indexing="xy"), -1)
    m = surf.covered
    colour = np.zeros((size, size, 3))
    colour[m.numpy()] = _shaded(renderer, renderer.texture, uv[m], surf.normals[m],
                                False).numpy()
    filled = _smoothed(grow_fill(colour, m.numpy().astype(np.float64)), m.numpy())
    texture = np.clip(filled * 255 + 0.5, 0, 255).astype(np.uint8)
    if progress:
        progress("bake", 1, 2)
    hair_colours = None
    if renderer.hair is not None:
        hv, hf, huv = (t.cpu() for t in renderer.hair.meshes[0])
        hn = torch.tensor(_normals(hv.numpy(), hf.numpy()), dtype=torch.float32)
        c = _shaded(renderer, renderer.hair.planes[0].detach().cpu(), huv, hn, True)
        hair_colours = np.clip(c.numpy() * 255 + 0.5, 0, 255).astype(np.uint8)
    if progress:
        progress("bake", 2, 2)
    return texture, hair_colours


def bake_hair_texture(renderer, size: int | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The hair's texture for an export (a deferred generator's head with hair):
    ``(uv (2H, 2), faces_uv (G, 3), texture (size, size, 4) uint8, shell (G,) bool)``.
    Each texel's colour is its hair texture shaded as a view that faces it would shade
    it, with the normal of the hair's vertices around it; its alpha is the shell's
    opacity there seen squarely (:func:`~head360cli.model.gbuffer.strand_opacity`, from
    the distances of the shell's vertices to their strands' ends). ``shell`` marks the
    faces of the pieces with strand ends (the shell); the others (tails, buns) share the
    texture's colour but not its alpha. ``uv`` runs past 1 across the shell's seam
    (:func:`~head360cli.geometry.mesh_ops.seam_uv`), so the texture repeats in u.
    ``size``: the hair texture's own side by default
    (:data:`~head360cli.model.deferred.HAIR_TEXTURE_SIDE`). ``None`` for a bald head."""
    import torch

    from head360cli.geometry.mesh_ops import edge_distance, seam_uv
    from head360cli.model.gbuffer import FADE, strand_opacity

    if renderer.hair is None or renderer.gen.kind != "deferred":
        return None
    planes = renderer.hair.planes[0].detach().cpu().float()
    size = planes.shape[-1] if size is None else size
    hv, hf, huv = (t.cpu() for t in renderer.hair.meshes[0])
    normals = _normals(hv.numpy(), hf.numpy())
    edges = renderer.hair.edges  # made with the hair's textures (prepare_hair)
    edge = (edges[0] if edges is not None else edge_distance(hv, hf, huv, FADE))
    edge = edge.detach().cpu().double().numpy()
    shell = _with_ends(hf.numpy(), len(hv), edge < FADE)
    uv = huv.numpy().astype(np.float64)
    tx = np.clip((uv[:, 0] % 1.0 * size).astype(np.int64), 0, size - 1)
    ty = np.clip((uv[:, 1] * size).astype(np.int64), 0, size - 1)
    flat = ty * size + tx
    # the shell's inner layer shares the outer's coordinates and faces inwards: only
    # normals that face away from the hair's middle count
    out = np.einsum("ij,ij->i", normals, hv.numpy() - hv.numpy().mean(0)) > 0
    grid = _texel_field(normals, out, flat, size, 2.0)
    grid = grid / np.maximum(np.linalg.norm(grid, axis=-1, keepdims=True), 1e-6)
    centres = (torch.arange(size, dtype=torch.float32) + 0.5) / size
    at = torch.stack(torch.meshgrid(centres, centres, indexing="xy"), -1).reshape(-1, 2)
    colour = _shaded(renderer, planes, at, torch.as_tensor(grid.reshape(-1, 3)), True)
    # the distances to the strands' ends, texel by texel, from the shell's vertices
    on = np.zeros(len(hv), bool)
    on[hf.numpy()[shell].reshape(-1)] = True
    dist = _texel_field(edge[:, None], on, flat, size, 1.0)[..., 0]
    alpha = strand_opacity(torch.as_tensor(dist.reshape(-1)), at[:, 0],
                           torch.ones(size * size)).numpy()
    rgba = np.concatenate([colour.numpy().reshape(size, size, 3),
                           alpha.reshape(size, size, 1)], -1)
    texture = np.clip(rgba * 255 + 0.5, 0, 255)
    wrapped, faces_uv = seam_uv(hf, huv)
    return wrapped.numpy(), faces_uv.numpy(), texture.astype(np.uint8), shell


def _texel_field(values: np.ndarray, use: np.ndarray, flat: np.ndarray, size: int,
                 sigma: float) -> np.ndarray:
    """``(size, size, C)`` float32: the mean of the vertices' ``values (V, C)`` that
    ``use (V,)`` marks in each texel ``flat (V,)`` (row by row) lies in, grown into the
    empty texels and blurred by ``sigma`` texels, wrapping round in u."""
    import cv2

    count = np.bincount(flat, use.astype(np.float64), size * size)
    grid = np.stack([np.bincount(flat, values[:, c] * use, size * size)
                     for c in range(values.shape[1])], -1)
    grid = grid.reshape(size, size, -1) / np.maximum(count, 1).reshape(size, size, 1)
    grid = grow_fill(grid, (count > 0).reshape(size, size).astype(np.float64))
    pad = 8
    grid = np.pad(grid.astype(np.float32), ((0, 0), (pad, pad), (0, 0)), mode="wrap")
    blurred = cv2.GaussianBlur(grid, (0, 0), sigma)
    return blurred.reshape(size, size + 2 * pad, -1)[:, pad:-pad]


def _with_ends(faces: np.ndarray, count: int, ends: np.ndarray) -> np.ndarray:
    """``(F,)`` bool: the faces of the connected pieces of a mesh (``count`` vertices)
    that hold a vertex of ``ends (V,)``."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    a = np.concatenate([faces[:, 0], faces[:, 1]])
    b = np.concatenate([faces[:, 1], faces[:, 2]])
    graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(count, count))
    _, label = connected_components(graph, directed=False)
    held = np.zeros(label.max() + 1, bool)
    held[label[ends]] = True
    return held[label[faces[:, 0]]]


def _normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    from head360cli.io.mesh import vertex_normals

    return vertex_normals(verts, faces)


def _parts(renderer, texture: np.ndarray | None, hair_colours: np.ndarray | None,
           expression: np.ndarray, targets: bool, hair_texture=None):
    from head360cli.io.mesh import MeshPart
    from head360cli.mesh.arkit52 import ARKIT52

    gen = renderer.gen
    verts = renderer.vertices(expression).cpu().numpy().astype(np.float64)
    parts = [MeshPart(TEXTURED_PART, verts, gen.faces.cpu().numpy(), gen.uv.cpu().numpy(),
                      gen.faces_uv.cpu().numpy(), texture,
                      targets=renderer.driven_deltas() if targets else None,
                      target_names=list(ARKIT52) if targets else None)]
    if renderer.hair is not None and hair_texture is not None:
        # the shell blends its alpha; tails and buns share its colours, opaque
        hv, hf, _ = (t.cpu().numpy() for t in renderer.hair.meshes[0])
        uv, faces_uv, image, shell = hair_texture
        for name, mine, img in (("hair", shell, image), ("hair_pieces", ~shell,
                                                         image[..., :3])):
            if mine.any():
                parts.append(MeshPart(name, hv.astype(np.float64), hf[mine], uv,
                                      faces_uv[mine], img, wrap_u=True))
    elif renderer.hair is not None and hair_colours is not None:
        hv, hf, _ = (t.cpu().numpy() for t in renderer.hair.meshes[0])
        parts.append(MeshPart("hair", hv.astype(np.float64), hf, colours=hair_colours))
    return parts


def export_head(renderer, out: str | Path, texture_size: int = 512, hair: bool = True,
                progress: Any = None) -> dict[str, Any]:
    """Write the head as ``.glb`` (52 ARKit morph targets, baked texture) or ``.obj``
    (+ ``.mtl`` and PNG texture; the neutral mesh).

    Returns:
        ``{"files": [...], "vertices": V, "faces": F, "morph_targets": 52 or 0, "parts":
        [...], "part_vertices": {part: V}}``: the head's vertices and triangles as the
        file holds them (a GLB's split at the UV seams).
    """
    from head360cli.io.atomic import check_file_target
    from head360cli.io.mesh import obj_companions, write_glb, write_obj

    out = Path(out)
    kind = out.suffix.lower()
    if kind not in (".glb", ".obj"):
        raise BadInputError(f"expected a .glb or .obj output, found {out.name!r}")
    # an OBJ's material and texture are named after it: their names too, before the bake
    for target in [out] + (obj_companions(out, [TEXTURED_PART]) if kind == ".obj" else []):
        check_file_target(target)
    texture, hair_colours = bake_head(renderer, texture_size, progress=progress)
    if not hair:
        hair_colours = None
    # a GLB's hair carries its strands as a texture; an OBJ's keeps vertex colours
    hair_texture = bake_hair_texture(renderer) if hair and kind == ".glb" else None
    parts = _parts(renderer, texture, hair_colours, np.zeros(52), targets=kind == ".glb",
                   hair_texture=hair_texture)
    if kind == ".glb":
        from head360cli.version import __version__

        files = [write_glb(out, parts, generator=f"head360 {__version__}")]
    else:
        files = write_obj(out, parts)
    written = {p.name: _written_vertices(p, kind) for p in parts}
    return {"files": [str(f) for f in files], "vertices": written[parts[0].name],
            "faces": len(parts[0].faces),
            "morph_targets": 52 if kind == ".glb" else 0,
            "parts": [p.name for p in parts], "part_vertices": written}


def _written_vertices(part, kind: str) -> int:
    """How many vertices ``part`` has in the file: a GLB splits a textured mesh's
    vertices where its UV layout has seams (one vertex per position and UV pair), an OBJ
    keeps the positions and indexes the UVs apart."""
    from head360cli.io.mesh import split_seams

    if kind != ".glb" or part.uv is None:
        return len(part.verts)
    faces_uv = part.faces if part.faces_uv is None else part.faces_uv
    return len(split_seams(part.faces, faces_uv)[0])


def write_mesh_sequence(renderer, weights: np.ndarray, folder: str | Path,
                        motions: np.ndarray | None = None, hair: bool = True,
                        texture_size: int = 512, progress: Any = None) -> Path:
    """One OBJ per frame (``frame_00000.obj`` ...) of the head with ARKit ``weights
    (F, 52)``, moved by rigid ``motions (F, 4, 4)`` when given (the stream's head pose),
    sharing one material and baked texture, into a new folder (made under a temporary
    name and renamed when complete)."""
    from head360cli.io.atomic import atomic_dir
    from head360cli.io.mesh import write_obj

    folder = Path(folder)
    texture, hair_colours = bake_head(renderer, texture_size)
    if not hair:
        hair_colours = None
    n = len(weights)
    with atomic_dir(folder) as tmp:
        for i, w in enumerate(weights):
            parts = _parts(renderer, texture, hair_colours, w, targets=False)
            if motions is not None:
                m = motions[i]
                for part in parts:
                    part.verts = part.verts @ m[:3, :3].T + m[:3, 3]
            write_obj(tmp / f"frame_{i:05d}.obj", parts, material="head",
                      write_material=i == 0)
            if i == 0:
                _check_room(tmp / "frame_00000.obj", n, folder)
            if progress:
                progress("meshes", i + 1, n)
    return folder


def _check_room(first: Path, frames: int, folder: Path) -> None:
    """Refuse a mesh sequence the disk has no room for, once its first OBJ shows the
    size of each (the same topology and fixed decimals: within a few per cent). A
    3046-frame take is about 3.9 GB of OBJs, and a full disk stopped it minutes in.

    Raises:
        BadInputError: The other ``frames - 1`` OBJs, at 98 % of the first one's size,
            would not fit in the free space.
    """
    import shutil

    from head360cli.errors import BadInputError

    def size(n: float) -> str:
        return f"{n / 1e9:.1f} GB" if n >= 1e9 else f"{n / 1e6:.0f} MB"

    each = first.stat().st_size
    free = shutil.disk_usage(first.parent).free
    if 0.98 * each * (frames - 1) > free:
        raise BadInputError(
            f"expected room for {frames} OBJ frames of about {each / 1e6:.1f} MB each "
            f"({size(each * frames)}) for {str(folder)!r}, found {size(free)} free: "
            f"write them elsewhere or animate part of the take (--start, --end)")

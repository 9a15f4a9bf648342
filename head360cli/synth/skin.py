"""Skin from a real head scan, carried onto the template's texture atlas and recoloured
per identity.

The scan (a textured OBJ, such as Lee Perry-Smith's head in ``../shared/assets``) is
rendered from the front, its 68 landmarks read by the face search, and lifted to 3D from
the render's depth. A similarity and a thin-plate warp on those landmarks lay the scan
over the mean identity's head; every skin and ear texel of the template's atlas then takes
the scan's colour at the nearest point of its surface. Every head shares the template's
topology and UVs, so one atlas serves all identities: :func:`skin_layers` splits it into
ratios (fine detail: pores, stubble, small marks; slower colour changes across the face),
which :func:`head360cli.synth.appearance.paint_texture` lays over each identity's own tone.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import numpy as np

__all__ = ["Scan", "align_scan", "build_skin_atlas", "read_scan", "render_scan", "scan_landmarks",
           "scan_skin", "skin_layers"]

_ATLAS_SIDE = 1024
"""Side of the atlas the scan is carried onto (layers are resized from it)."""

_NORMAL_WEIGHT = 0.01
"""Metres a unit of normal disagreement counts for when a texel looks for its scan point."""

_BASE_SIGMA = 0.03
"""Blur (fraction of the atlas side) that separates the skin's base colour from its detail."""


@dataclasses.dataclass(frozen=True)
class Scan:
    """A textured head scan: triangles with per-corner UVs and the colour texture."""

    verts: np.ndarray
    """``(V, 3)`` vertex positions in the scan's units, y up, facing +z."""
    faces: np.ndarray
    """``(F, 3)`` vertex ids."""
    uv: np.ndarray
    """``(T, 2)`` texture coordinates, v up."""
    faces_uv: np.ndarray
    """``(F, 3)`` ids into ``uv``."""
    texture: np.ndarray
    """``(H, W, 3)`` uint8 RGB, row 0 at v = 1."""


def read_scan(folder: str | Path, texture_side: int = 2048) -> Scan:
    """Read ``head.obj`` and ``lambertian.jpg`` from ``folder`` (quads split in two).

    Raises:
        BadInputError: A file is missing or holds no triangles.
    """
    import cv2

    from head360cli.errors import BadInputError

    folder = Path(folder)
    obj, jpg = folder / "head.obj", folder / "lambertian.jpg"
    for p in (obj, jpg):
        if not p.is_file():
            raise BadInputError(f"expected a head scan with {p.name} in {str(folder)!r}, "
                                "found none")
    v, vt, f, ft = [], [], [], []
    with open(obj, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            if line.startswith("v "):
                v.append(line.split()[1:4])
            elif line.startswith("vt "):
                vt.append(line.split()[1:3])
            elif line.startswith("f "):
                corners = [c.split("/") for c in line.split()[1:]]
                vi = [int(c[0]) - 1 for c in corners]
                ti = [int(c[1]) - 1 for c in corners]
                for k in range(1, len(corners) - 1):
                    f.append((vi[0], vi[k], vi[k + 1]))
                    ft.append((ti[0], ti[k], ti[k + 1]))
    if not f:
        raise BadInputError(f"expected triangles or quads in {str(obj)!r}, found none")
    # The texture's pixels as stored (its EXIF orientation tag does not apply to UVs).
    tex = cv2.imread(str(jpg), cv2.IMREAD_IGNORE_ORIENTATION | cv2.IMREAD_COLOR)
    tex = cv2.resize(tex, (texture_side, texture_side), interpolation=cv2.INTER_AREA)
    return Scan(np.asarray(v, float), np.asarray(f, np.int64), np.asarray(vt, float),
                np.asarray(ft, np.int64), np.ascontiguousarray(tex[:, :, ::-1]))


def _front_camera(verts: np.ndarray, size: int):
    """A camera in front of the scan's face (+z), framing its upper part."""
    import torch

    from head360cli.geometry.cameras import intrinsics_from_fov, look_at

    lo, hi = verts.min(0), verts.max(0)
    height = hi[1] - lo[1]
    centre = np.array([(lo[0] + hi[0]) / 2, hi[1] - 0.3 * height, lo[2] + 0.8 * (hi[2] - lo[2])])
    dist = 2.4 * height
    c2w = look_at(torch.tensor(centre + np.array([0.0, 0.0, dist]))[None].float(),
                  torch.tensor(centre)[None].float())
    k = intrinsics_from_fov(20.0, size, size).float()
    return c2w, k.reshape(1, 3, 3)


def render_scan(scan: Scan, size: int = 640):
    """Render the scan from the front. Returns ``(rgb (H, W, 3) uint8, depth (H, W),
    c2w (1, 4, 4), K (1, 3, 3))``."""
    import torch

    from head360cli.synth.render import render_mesh

    c2w, k = _front_camera(scan.verts, size)
    uv = scan.uv.copy()
    uv[:, 1] = 1 - uv[:, 1]  # the rasterizer's texture rows run down
    tex = torch.tensor(scan.texture).permute(2, 0, 1)[None].float() / 255
    out = render_mesh(torch.tensor(scan.verts, dtype=torch.float32)[None],
                      torch.tensor(scan.faces), c2w, k, size,
                      uv=torch.tensor(uv, dtype=torch.float32),
                      faces_uv=torch.tensor(scan.faces_uv), texture=tex, samples=4,
                      background=1.0)
    rgb = (out.rgb[0].permute(1, 2, 0).numpy() * 255 + 0.5).clip(0, 255).astype(np.uint8)
    return rgb, out.depth[0, 0].numpy(), c2w, k


def scan_landmarks(scan: Scan) -> np.ndarray:
    """The scan's 68 iBUG landmarks in 3D, ``(68, 3)`` in its units.

    Raises:
        NoFaceError: The face search finds no face in the frontal render.
    """
    from head360cli.errors import NoFaceError
    from head360cli.fitting.landmarks import find_faces

    rgb, depth, c2w, k = render_scan(scan)
    faces = find_faces(rgb)
    if not faces:
        raise NoFaceError("expected a face in the scan's frontal render, found none")
    lm = max(faces, key=lambda f: f.area).landmarks
    # The depth at each landmark (nearest covered pixel), then back along its camera ray
    # (OpenCV axes: world = R cam + t).
    ys, xs = np.nonzero(depth > 0)
    kk = k[0].numpy().astype(float)
    m = c2w[0].numpy().astype(float)
    pts = []
    for x, y in lm:
        j = np.argmin((xs - x) ** 2 + (ys - y) ** 2)
        d = float(depth[ys[j], xs[j]])
        cam = np.array([(x - kk[0, 2]) / kk[0, 0], (y - kk[1, 2]) / kk[1, 1], 1.0]) * d
        pts.append(m[:3, :3] @ cam + m[:3, 3])
    return np.array(pts)


def _similarity(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Scale, rotation and translation taking ``src (N, 3)`` closest to ``dst (N, 3)``
    (least squares, Umeyama)."""
    ms, md = src.mean(0), dst.mean(0)
    a, b = src - ms, dst - md
    u, s, vt = np.linalg.svd(b.T @ a)
    d = np.eye(3)
    d[2, 2] = np.sign(np.linalg.det(u @ vt))
    rot = u @ d @ vt
    scale = float((s * np.diag(d)).sum() / (a ** 2).sum())
    return scale, rot, md - scale * rot @ ms


def align_scan(scan: Scan, scan_lm: np.ndarray, head: np.ndarray, head_lm: np.ndarray
               ) -> np.ndarray:
    """The scan's vertices laid over a head: a similarity on the landmarks, then a
    thin-plate warp that moves each scan landmark onto the head's.

    Args:
        scan_lm: ``(68, 3)`` the scan's landmarks.
        head: ``(V, 3)`` the head's vertices (unused but for its landmarks).
        head_lm: ``(68,)`` the head's landmark vertex ids.

    Returns:
        ``(Vs, 3)`` the scan's vertices in the head's frame.
    """
    from scipy.interpolate import RBFInterpolator

    target = head[head_lm]
    inner = np.arange(17, 68)  # the jaw's contour points depend on the view: not used
    scale, rot, shift = _similarity(scan_lm[inner], target[inner])
    moved = scale * scan.verts @ rot.T + shift
    lm = scale * scan_lm @ rot.T + shift
    warp = RBFInterpolator(lm[inner], target[inner] - lm[inner],
                           kernel="thin_plate_spline", smoothing=1e-6)
    return moved + warp(moved)


def build_skin_atlas(scan_folder: str | Path, size: int = 1024) -> np.ndarray:
    """The scan's colour on the template's atlas: ``(size, size, 3)`` uint8 RGB, filled
    where the atlas has skin or ears (elsewhere 0)."""
    import torch
    from scipy.spatial import cKDTree

    from head360cli.mesh.template import template
    from head360cli.synth.appearance import texel_positions
    from head360cli.synth.identity import mean_identity
    from head360cli.synth.sculpt import build_head, topology

    scan = read_scan(scan_folder)
    head, _ = build_head(mean_identity())
    verts = align_scan(scan, scan_landmarks(scan), head, template().landmarks)
    topo = topology()
    pos, part = texel_positions(head, topo, size)
    keep = np.isin(part, [topo.part_names.index(n) for n in ("skin", "ear_l", "ear_r")])
    # The scan's surface, densely sampled with its UVs and normals; each texel takes the
    # nearest point that faces its way (so that a cheek never takes the inside of a lip).
    normals = _texel_normals(head, topo, size)[keep]
    n = 12
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    ok = i + j <= n
    bary = np.stack([i[ok], j[ok], n - i[ok] - j[ok]], -1) / n  # (S, 3)
    tri = verts[scan.faces]  # (F, 3, 3)
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True) + 1e-12
    pts = np.einsum("sk,fkc->fsc", bary, tri).reshape(-1, 3)
    pn = np.repeat(fn, len(bary), 0)
    uvs = np.einsum("sk,fkc->fsc", bary, scan.uv[scan.faces_uv]).reshape(-1, 2)
    w = _NORMAL_WEIGHT
    _, idx = cKDTree(np.hstack([pts, w * pn])).query(
        np.hstack([pos[keep], w * normals]), workers=-1)
    uv = uvs[idx]
    tex = torch.tensor(scan.texture).permute(2, 0, 1)[None].float()
    grid = torch.tensor(np.stack([uv[:, 0] * 2 - 1, 1 - uv[:, 1] * 2], -1),
                        dtype=torch.float32)[None, None]
    col = torch.nn.functional.grid_sample(tex, grid, mode="bilinear", align_corners=False)
    out = np.zeros((size, size, 3), np.uint8)
    out[keep] = col[0, :, 0].T.round().clamp(0, 255).to(torch.uint8).numpy()
    return out


def _texel_normals(head: np.ndarray, topo, size: int) -> np.ndarray:
    """Unit surface normal at every texel of the atlas, ``(size, size, 3)``."""
    import torch

    from head360cli.geometry.mesh_ops import vertex_normals
    from head360cli.synth.appearance import texel_positions

    vn = vertex_normals(torch.tensor(head, dtype=torch.float64)[None],
                        torch.tensor(topo.faces))[0].numpy()
    nrm, _ = texel_positions(vn, topo, size)
    return nrm / (np.linalg.norm(nrm, axis=-1, keepdims=True) + 1e-12)


def skin_layers(atlas: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Split a scan atlas into multiplicative layers at ``size x size``.

    Returns:
        ``(fine (size, size, 3), mid (size, size, 3))`` float32 ratios around 1: ``fine``
        the detail finer than two texels' blur (pores, stubble, small marks), ``mid`` the
        colour's slower changes across the face (warmer cheeks and nose, shadows of the
        scan's folds) against its mean over a wider area. Both are 1 where the atlas is
        empty.
    """
    import cv2

    a = cv2.resize(atlas, (size, size), interpolation=cv2.INTER_AREA).astype(np.float32) / 255
    filled = (a.sum(-1) > 0).astype(np.float32)

    def blur(x: np.ndarray, sigma: float) -> np.ndarray:
        # normalized: empty texels neither darken nor count
        num = cv2.GaussianBlur(x * filled[..., None], (0, 0), sigma)
        den = cv2.GaussianBlur(filled, (0, 0), sigma)[..., None]
        return num / np.maximum(den, 1e-6)

    eps = 0.02
    near = blur(a, 1.5)
    wide = blur(a, _BASE_SIGMA * size)
    fine = np.clip((a + eps) / (near + eps), 0.6, 1.4)
    mid = np.clip((near + eps) / (wide + eps), 0.75, 1.25)
    empty = filled < 0.5
    fine[empty] = 1.0
    mid[empty] = 1.0
    return fine.astype(np.float32), mid.astype(np.float32)


def scan_skin(folder: str | Path, size: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`skin_layers` of the scan in ``folder`` at ``size``; its atlas is made once
    (about 40 s) and kept in head360's cache, named by the scan files' sizes and times."""
    return _scan_skin(str(Path(folder).resolve()), int(size))


@functools.lru_cache(maxsize=4)
def _scan_skin(folder: str, size: int) -> tuple[np.ndarray, np.ndarray]:
    import hashlib

    from head360cli.cache import cached_array

    stamp = hashlib.sha256()
    for name in ("head.obj", "lambertian.jpg"):
        p = Path(folder) / name
        st = p.stat() if p.is_file() else None
        stamp.update(f"{name}:{st and st.st_size}:{st and st.st_mtime_ns};".encode())
    side = _ATLAS_SIDE
    atlas = cached_array(f"skin_atlas_{stamp.hexdigest()[:16]}_{side}.npy",
                         lambda: build_skin_atlas(folder, side), (side, side, 3), np.uint8)
    return skin_layers(atlas, size)


SKIN_DETAIL_FILE = "skin_detail.npz"
"""The shipped skin detail (:func:`write_skin_detail`) in the models folder."""


def write_skin_detail(folder: str | Path, out: str | Path, size: int = 256) -> dict:
    """Write the scan's fine skin detail (:func:`skin_layers`' ``fine`` ratios, as
    ``fine (size, size, 3)`` float16 in the template's UV layout) to ``out`` (``.npz``):
    the pore-level detail a fit gives the skin the photo does not show."""
    from head360cli.io.atomic import atomic_path

    fine, _ = scan_skin(folder, size)
    with atomic_path(Path(out)) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, fine=fine.astype(np.float16),
                            source=np.array("Infinite, 3D Head Scan by Lee Perry-Smith, CC BY "
                                            "3.0 (www.triplegangers.com)"))
    return {"out": str(out), "size": size, "bytes": Path(out).stat().st_size}


@functools.lru_cache(maxsize=2)
def skin_detail(size: int) -> np.ndarray | None:
    """``(size, size, 3)`` float32 fine skin detail ratios around 1 from the shipped
    :data:`SKIN_DETAIL_FILE` (resized), or ``None`` where it is not installed."""
    import cv2

    from head360cli.paths import models_dir

    path = models_dir() / SKIN_DETAIL_FILE
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as data:
        fine = data["fine"].astype(np.float32)
    if fine.shape[0] != size:
        fine = cv2.resize(fine, (size, size), interpolation=cv2.INTER_AREA)
    return fine

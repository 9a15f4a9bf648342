"""Mesh export: Wavefront OBJ (+ MTL + PNG texture) and binary glTF 2.0 (GLB).

A head is exported as named parts (the head, the hair). A part may carry UVs with a colour
texture, per-vertex colours, and morph targets: the GLB stores the 52 ARKit blendshapes as
named morph targets (``mesh.extras.targetNames``, the convention Blender, three.js and
Babylon read), so the head can be driven outside head360. Vertices are split where a vertex
has several UVs (texture seams), as both formats need one UV per vertex; OBJ keeps the
unsplit positions and indexes UVs separately.

Coordinates are head coordinates (metres, +y up, the face looking along +z), which are
glTF's own conventions. Files are written under a temporary name and renamed.
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
import struct
from pathlib import Path

import numpy as np

__all__ = ["MeshPart", "obj_companions", "split_seams", "vertex_normals", "write_glb",
           "write_obj"]


@dataclasses.dataclass
class MeshPart:
    """One named mesh of an export."""

    name: str
    """Object/node name (``head``, ``hair``)."""
    verts: np.ndarray
    """``(V, 3)`` positions in metres."""
    faces: np.ndarray
    """``(F, 3)`` counter-clockwise (outward) triangles."""
    uv: np.ndarray | None = None
    """``(T, 2)`` texture coordinates, v = 0 at the top of the texture."""
    faces_uv: np.ndarray | None = None
    """``(F, 3)`` indices into ``uv`` (default: ``faces``)."""
    texture: np.ndarray | None = None
    """``(H, W, 3)`` uint8 colour texture, or ``(H, W, 4)`` with alpha (a GLB blends
    it: ``alphaMode`` ``BLEND``)."""
    colours: np.ndarray | None = None
    """``(V, 3)`` uint8 per-vertex colours (used when there is no texture)."""
    wrap_u: bool = False
    """The texture repeats in u (a hair shell's u runs round the head and its seam faces
    read just past 1); otherwise it is clamped at its edges."""
    targets: np.ndarray | None = None
    """``(K, V, 3)`` morph target displacements."""
    target_names: list[str] | None = None
    """``K`` names of the morph targets."""


def vertex_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(V, 3)`` unit area-weighted vertex normals (``(0, 0, 1)`` for lone vertices)."""
    v = np.asarray(verts, np.float64)
    tri = v[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    out = np.zeros_like(v)
    for c in range(3):
        np.add.at(out, faces[:, c], n)
    length = np.linalg.norm(out, axis=1, keepdims=True)
    out = np.where(length > 1e-12, out / np.maximum(length, 1e-12), [0.0, 0.0, 1.0])
    return out


def split_seams(faces: np.ndarray, faces_uv: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One vertex per distinct (position, UV) corner pair.

    Returns:
        ``(position index (N,), uv index (N,), faces (F, 3) into the N new vertices)``.
    """
    pairs = np.stack([np.asarray(faces).reshape(-1), np.asarray(faces_uv).reshape(-1)], 1)
    unique, inverse = np.unique(pairs, axis=0, return_inverse=True)
    return unique[:, 0], unique[:, 1], inverse.reshape(-1, 3)


def _png(image: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.asarray(image, np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


# --------------------------------------------------------------------------- OBJ


def obj_companions(path: str | os.PathLike[str], textured: list[str],
                   material: str | None = None) -> list[Path]:
    """The files :func:`write_obj` writes beside the OBJ at ``path`` for parts named
    ``textured`` (those with a texture and UVs): ``<material>.mtl``, then
    ``<material>_<part>.png`` for each (``material`` defaults to the OBJ's stem)."""
    path = Path(path)
    stem = material or path.stem
    return [path.with_name(f"{stem}.mtl"),
            *(path.with_name(f"{stem}_{name}.png") for name in textured)]


def write_obj(path: str | os.PathLike[str], parts: list[MeshPart],
              material: str | None = None, write_material: bool = True,
              comment: str = "") -> list[Path]:
    """Write parts to ``path`` (OBJ). Parts with UVs get ``vt`` lines; parts with a
    texture also get a material in ``<material>.mtl`` and their texture in
    ``<material>_<part>.png`` beside the OBJ (``material`` defaults to the OBJ's stem).
    Per-vertex colours are written as ``v x y z r g b`` (read by Blender, MeshLab and
    trimesh). A sequence of OBJs can share one material: write it with the first and pass
    ``write_material=False`` for the others.

    Returns:
        The paths written.
    """
    from head360cli.io.atomic import atomic_paths

    path = Path(path)
    stem = material or path.stem
    textured = any(p.texture is not None and p.uv is not None for p in parts)
    written: list[Path] = []
    textures: list[tuple[Path, np.ndarray]] = []
    mtl_lines: list[str] = []
    lines = [f"# {line}" for line in comment.splitlines()]
    if textured:
        lines.append(f"mtllib {stem}.mtl")
    base_v = base_vt = 0
    for part in parts:
        verts = np.asarray(part.verts, np.float64)
        lines.append(f"o {part.name}")
        if part.colours is not None and part.texture is None:
            c = np.asarray(part.colours, np.float64) / 255.0
            lines += [f"v {x:.6f} {y:.6f} {z:.6f} {r:.4f} {g:.4f} {b:.4f}"
                      for (x, y, z), (r, g, b) in zip(verts, c, strict=True)]
        else:
            lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in verts]
        f = np.asarray(part.faces) + 1 + base_v
        if textured:
            mtl_lines += [f"newmtl {part.name}", "Kd 1.000 1.000 1.000", "Ka 0 0 0",
                          "Ks 0 0 0", "d 1", "illum 1"]
            lines.append(f"usemtl {part.name}")
        if part.uv is not None:
            uv = np.asarray(part.uv, np.float64)
            lines += [f"vt {u:.6f} {1.0 - v:.6f}" for u, v in uv]  # OBJ: v = 0 at the bottom
            fu = (part.faces if part.faces_uv is None else np.asarray(part.faces_uv)
                  ) + 1 + base_vt
            lines += [f"f {a}/{ta} {b}/{tb} {c}/{tc}" for (a, b, c), (ta, tb, tc)
                      in zip(f, fu, strict=True)]
            base_vt += len(uv)
        else:
            lines += [f"f {a} {b} {c}" for a, b, c in f]
        if part.texture is not None and part.uv is not None:
            png = obj_companions(path, [part.name], material)[1]
            mtl_lines.append(f"map_Kd {png.name}")
            if write_material:
                textures.append((png, part.texture))
        base_v += len(verts)
    # All are renamed into place only once every one is complete, so a full disk leaves
    # neither a texture without its OBJ nor an earlier export's files mixed with these.
    if textured and write_material:
        written = obj_companions(path, [], material) + [png for png, _ in textures]
    with atomic_paths(*written, path) as tmps:
        if textured and write_material:
            tmps[0].write_text("\n".join(mtl_lines) + "\n")
            for tmp, (_, texture) in zip(tmps[1:-1], textures, strict=True):
                tmp.write_bytes(_png(texture))
        tmps[-1].write_text("\n".join(lines) + "\n")
    return [path, *written]


# --------------------------------------------------------------------------- GLB

_FLOAT, _UINT32 = 5126, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963


class _Bin:
    """The GLB binary chunk under construction, with its views and accessors."""

    def __init__(self) -> None:
        self.data = bytearray()
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def view(self, raw: bytes, target: int | None = None) -> int:
        while len(self.data) % 4:
            self.data.append(0)
        entry = {"buffer": 0, "byteOffset": len(self.data), "byteLength": len(raw)}
        if target is not None:
            entry["target"] = target
        self.data += raw
        self.views.append(entry)
        return len(self.views) - 1

    def accessor(self, array: np.ndarray, kind: str, target: int | None,
                 bounds: bool = False) -> int:
        is_index = array.dtype.kind in "iu"
        a = np.ascontiguousarray(array, np.uint32 if is_index else np.float32)
        entry = {"bufferView": self.view(a.tobytes(), target),
                 "componentType": _UINT32 if is_index else _FLOAT,
                 "count": int(a.shape[0]) if kind != "SCALAR" else int(a.size), "type": kind}
        if bounds:
            entry["min"] = a.reshape(len(a), -1).min(0).tolist()
            entry["max"] = a.reshape(len(a), -1).max(0).tolist()
        self.accessors.append(entry)
        return len(self.accessors) - 1


def write_glb(path: str | os.PathLike[str], parts: list[MeshPart],
              generator: str = "head360") -> Path:
    """Write parts to one binary glTF 2.0 file (textures embedded as PNG, morph targets
    named in ``mesh.extras.targetNames``, all morph weights 0)."""
    from head360cli.io.atomic import atomic_path

    buf = _Bin()
    meshes, nodes, materials, textures, images, samplers = [], [], [], [], [], []
    for part in parts:
        faces = np.asarray(part.faces, np.int64)
        if part.uv is not None:
            pos_idx, uv_idx, new_faces = split_seams(
                faces, faces if part.faces_uv is None else part.faces_uv)
        else:
            pos_idx = np.arange(len(part.verts))
            uv_idx, new_faces = None, faces
        verts = np.asarray(part.verts, np.float64)[pos_idx]
        attributes = {
            "POSITION": buf.accessor(verts, "VEC3", _ARRAY_BUFFER, bounds=True),
            "NORMAL": buf.accessor(vertex_normals(verts, new_faces), "VEC3", _ARRAY_BUFFER),
        }
        material: dict = {"name": part.name, "pbrMetallicRoughness": {
            "metallicFactor": 0.0, "roughnessFactor": 0.8}}
        if uv_idx is not None:
            attributes["TEXCOORD_0"] = buf.accessor(np.asarray(part.uv)[uv_idx], "VEC2",
                                                    _ARRAY_BUFFER)
        if part.texture is not None and uv_idx is not None:
            images.append({"bufferView": buf.view(_png(part.texture)),
                           "mimeType": "image/png", "name": part.name})
            sampler = {"magFilter": 9729, "minFilter": 9987,
                       "wrapS": 10497 if part.wrap_u else 33071, "wrapT": 33071}
            if sampler not in samplers:
                samplers.append(sampler)
            textures.append({"source": len(images) - 1, "sampler": samplers.index(sampler)})
            material["pbrMetallicRoughness"]["baseColorTexture"] = {
                "index": len(textures) - 1}
            if np.asarray(part.texture).shape[-1] == 4:
                material["alphaMode"] = "BLEND"
        elif part.colours is not None:
            c = (np.asarray(part.colours, np.float64)[pos_idx] / 255.0) ** 2.2  # linear
            attributes["COLOR_0"] = buf.accessor(c, "VEC3", _ARRAY_BUFFER)
        primitive = {"attributes": attributes,
                     "indices": buf.accessor(new_faces.reshape(-1).astype(np.uint32),
                                             "SCALAR", _ELEMENT_ARRAY_BUFFER),
                     "material": len(materials), "mode": 4}
        materials.append(material)
        mesh: dict = {"name": part.name, "primitives": [primitive]}
        if part.targets is not None and len(part.targets):
            targets = np.asarray(part.targets, np.float64)[:, pos_idx]
            primitive["targets"] = [{"POSITION": buf.accessor(t, "VEC3", _ARRAY_BUFFER,
                                                              bounds=True)} for t in targets]
            mesh["weights"] = [0.0] * len(targets)
            names = part.target_names or [f"target_{i}" for i in range(len(targets))]
            mesh["extras"] = {"targetNames": list(names)}
        meshes.append(mesh)
        nodes.append({"name": part.name, "mesh": len(meshes) - 1})
    gltf: dict = {
        "asset": {"version": "2.0", "generator": generator},
        "scene": 0, "scenes": [{"nodes": list(range(len(nodes)))}],
        "nodes": nodes, "meshes": meshes, "materials": materials,
        "accessors": buf.accessors, "bufferViews": buf.views,
        "buffers": [{"byteLength": len(buf.data)}],
    }
    if images:
        gltf.update(images=images, textures=textures, samplers=samplers)
    text = json.dumps(gltf, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    data = bytes(buf.data) + b"\0" * (-len(buf.data) % 4)
    total = 12 + 8 + len(text) + 8 + len(data)
    blob = (struct.pack("<4sII", b"glTF", 2, total)
            + struct.pack("<I4s", len(text), b"JSON") + text
            + struct.pack("<I4s", len(data), b"BIN\0") + data)
    path = Path(path)
    with atomic_path(path) as tmp:
        Path(tmp).write_bytes(blob)
    return path

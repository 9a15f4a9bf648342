"""Mesh export: seams, normals, OBJ and GLB written and read back by trimesh."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from head360cli.io.mesh import MeshPart, split_seams, vertex_normals, write_glb, write_obj


def _quad():
    verts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0], [0.5, 0.5]], float)
    faces_uv = np.array([[0, 1, 2], [4, 2, 3]])  # vertex 0 has two UVs: a seam
    return verts, faces, uv, faces_uv


def _glb_json(path):
    data = path.read_bytes()
    magic, version, total = struct.unpack("<4sII", data[:12])
    assert (magic, version, total) == (b"glTF", 2, len(data))
    length, kind = struct.unpack("<I4s", data[12:20])
    assert kind == b"JSON" and length % 4 == 0
    return json.loads(data[20:20 + length])


def test_split_seams_and_normals():
    verts, faces, uv, faces_uv = _quad()
    pos, uvi, new = split_seams(faces, faces_uv)
    assert len(pos) == 5  # vertex 0 twice
    np.testing.assert_array_equal(verts[pos][new], verts[faces])
    np.testing.assert_array_equal(uv[uvi][new], uv[faces_uv])
    n = vertex_normals(verts, faces)
    np.testing.assert_allclose(n, np.tile([0, 0, 1.0], (4, 1)))
    lone = vertex_normals(np.vstack([verts, [[5, 5, 5]]]), faces)
    np.testing.assert_allclose(lone[4], [0, 0, 1.0])


def test_glb_round_trip_with_morph_targets(tmp_path):
    import trimesh

    verts, faces, uv, faces_uv = _quad()
    targets = np.zeros((3, 4, 3))
    targets[1, 2] = [0, 0, 0.5]
    tex = np.zeros((8, 8, 3), np.uint8)
    tex[:, :4] = 200
    parts = [MeshPart("head", verts, faces, uv, faces_uv, tex, targets=targets,
                      target_names=["a", "b", "c"]),
             MeshPart("hair", verts + 2, faces, colours=np.full((4, 3), 90, np.uint8))]
    path = write_glb(tmp_path / "x.glb", parts)
    g = _glb_json(path)
    prim = g["meshes"][0]["primitives"][0]
    assert len(prim["targets"]) == 3 and g["meshes"][0]["extras"]["targetNames"] == [
        "a", "b", "c"]
    acc = g["accessors"][prim["targets"][1]["POSITION"]]
    assert acc["max"] == [0, 0, 0.5] and acc["count"] == 5
    assert "COLOR_0" in g["meshes"][1]["primitives"][0]["attributes"]
    scene = trimesh.load(path)
    head = scene.geometry["head"]
    assert len(head.vertices) == 5 and len(head.faces) == 2
    assert head.metadata["targetNames"] == ["a", "b", "c"]
    img = np.asarray(head.visual.material.baseColorTexture)
    assert img.shape[:2] == (8, 8)
    assert len(scene.geometry["hair"].vertices) == 4


def test_obj_round_trip(tmp_path):
    import trimesh

    verts, faces, uv, faces_uv = _quad()
    files = write_obj(tmp_path / "m.obj", [MeshPart("head", verts, faces, uv, faces_uv,
                                                     np.zeros((4, 4, 3), np.uint8))])
    assert [f.name for f in files] == ["m.obj", "m.mtl", "m_head.png"]
    text = (tmp_path / "m.obj").read_text()
    assert "vt 0.500000 0.500000" in text and "f 1/5 3/3 4/4" in text
    mesh = trimesh.load(tmp_path / "m.obj", force="mesh")
    assert len(mesh.faces) == 2
    # a sequence shares the first file's material
    files = write_obj(tmp_path / "n.obj", [MeshPart("head", verts, faces, uv, faces_uv,
                                                     np.zeros((4, 4, 3), np.uint8))],
                      material="m", write_material=False)
    assert [f.name for f in files] == ["n.obj"]
    assert "mtllib m.mtl" in (tmp_path / "n.obj").read_text()


def test_a_full_disk_leaves_an_obj_export_as_it_was(tmp_path, monkeypatch):
    """The texture and material were renamed into place one by one before the OBJ was
    written, so a full disk at the OBJ left them beside no OBJ (or beside an earlier
    export's OBJ that they no longer match)."""
    import errno
    import os
    from pathlib import Path

    verts, faces, uv, faces_uv = _quad()

    def export(level):
        return write_obj(tmp_path / "m.obj", [MeshPart(
            "head", verts, faces, uv, faces_uv, np.full((4, 4, 3), level, np.uint8))])

    export(10)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    real = Path.write_text

    def full_at_the_obj(self, *args, **kwargs):
        if self.suffix == ".obj":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self))
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", full_at_the_obj)
    with pytest.raises(OSError, match="No space left"):
        export(200)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    monkeypatch.undo()
    (tmp_path / "m.obj").unlink()
    (tmp_path / "m.mtl").unlink()
    (tmp_path / "m_head.png").unlink()
    monkeypatch.setattr(Path, "write_text", full_at_the_obj)
    with pytest.raises(OSError, match="No space left"):
        export(200)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_exported_head_has_the_52_arkit_targets(head_file, tmp_path, run_cli):
    import trimesh

    from head360cli.mesh.arkit52 import ARKIT52

    out = tmp_path / "head.glb"
    r = run_cli("export-mesh", head_file, "-o", out, "--texture-size", "128", "--json")
    assert r.code == 0, r.err
    scene = trimesh.load(out)
    head = scene.geometry["head"]
    assert head.metadata["targetNames"] == list(ARKIT52)
    # the counts reported are the file's: the GLB splits the head at its UV seams (6,399
    # vertices from the template's 5,968)
    import json

    res = json.loads(r.out)
    g = _glb_json(out)
    in_file = {m["name"]: g["accessors"][m["primitives"][0]["attributes"]["POSITION"]]["count"]
               for m in g["meshes"]}
    assert res["part_vertices"] == in_file and res["vertices"] == in_file["head"]
    assert res["faces"] == len(head.faces)
    g = _glb_json(out)
    prim = g["meshes"][0]["primitives"][0]
    assert len(prim["targets"]) == 52 and g["meshes"][0]["weights"] == [0.0] * 52
    # jawOpen moves vertices, and by centimetres, not metres
    jaw = g["accessors"][prim["targets"][ARKIT52.index("jawOpen")]["POSITION"]]
    span = np.subtract(jaw["max"], jaw["min"])
    assert 0.005 < np.abs(span).max() < 0.1
    tex = np.asarray(head.visual.material.baseColorTexture)
    assert tex.shape[:2] == (128, 128) and 60 < tex.mean() < 250  # skin, not black
    # the hair carries its strands as a texture that repeats round the head in u (its
    # seam's faces read just past 1), the head's is clamped
    hair_mesh = next(m for m in g["meshes"] if m["name"] == "hair")
    attributes = hair_mesh["primitives"][0]["attributes"]
    assert "TEXCOORD_0" in attributes and "COLOR_0" not in attributes
    u_max = g["accessors"][attributes["TEXCOORD_0"]].get("max")
    hair_material = g["materials"][hair_mesh["primitives"][0]["material"]]
    sampler = g["samplers"][g["textures"][hair_material["pbrMetallicRoughness"][
        "baseColorTexture"]["index"]]["sampler"]]
    assert sampler["wrapS"] == 10497 and sampler["wrapT"] == 33071
    head_material = g["materials"][prim["material"]]
    assert g["samplers"][g["textures"][head_material["pbrMetallicRoughness"][
        "baseColorTexture"]["index"]]["sampler"]]["wrapS"] == 33071
    hair_tex = np.asarray(scene.geometry["hair"].visual.material.baseColorTexture)
    assert hair_tex.std() > 1 and 5 < hair_tex[..., :3].mean() < 250  # coloured
    assert u_max is None or u_max[0] <= 1.1
    # its strands' ends blend: an alpha channel, clear at the ends and opaque elsewhere
    assert hair_material["alphaMode"] == "BLEND" and "alphaMode" not in head_material
    assert hair_tex.shape[-1] == 4
    alpha = hair_tex[..., 3]
    assert alpha.min() == 0 and np.median(alpha) == 255 and (alpha < 255).mean() < 0.3
    r = run_cli("export-mesh", head_file, "-o", tmp_path / "head.stl")
    assert r.code == 3 and "glb or .obj" in r.err


def test_obj_without_texture_has_no_material(tmp_path):
    verts, faces, uv, faces_uv = _quad()
    files = write_obj(tmp_path / "g.obj", [MeshPart("head", verts, faces, uv, faces_uv)],
                      comment="two\nlines")
    assert [f.name for f in files] == ["g.obj"]
    text = (tmp_path / "g.obj").read_text()
    assert text.startswith("# two\n# lines\n") and "mtllib" not in text
    assert "f 1/1 2/2 3/3" in text

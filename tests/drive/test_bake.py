"""Baking: push-pull filling, the baked texture, the mesh sequence."""

from __future__ import annotations

import numpy as np
import pytest

from head360cli.drive.bake import grow_fill


def test_grow_fill_keeps_known_pixels_and_fills_the_rest():
    colour = np.zeros((9, 13, 3))
    weight = np.zeros((9, 13))
    colour[2, 3] = [1, 0, 0]
    colour[7, 10] = [0, 0, 1]
    weight[2, 3] = weight[7, 10] = 1
    out = grow_fill(colour, weight)
    np.testing.assert_allclose(out[2, 3], [1, 0, 0])
    np.testing.assert_allclose(out[7, 10], [0, 0, 1])
    assert np.isfinite(out).all()
    assert out[1, 2, 0] > out[1, 2, 2]  # near the red pixel: redder
    assert out[8, 12, 2] > out[8, 12, 0]
    np.testing.assert_allclose(out.sum(-1), 1.0, atol=1e-9)  # mixes of the two
    np.testing.assert_allclose(grow_fill(colour, np.zeros((9, 13))), colour.mean((0, 1))
                               [None, None].repeat(9, 0).repeat(13, 1))


@pytest.mark.slow
def test_mesh_sequence_shares_one_texture(head_file, tmp_path, run_cli):
    import trimesh

    from head360cli.io.arkit import ArkitStream, write_arkit_csv
    from head360cli.mesh.arkit52 import INDEX

    w = np.zeros((3, 52), np.float32)
    w[:, INDEX["jawOpen"]] = [0, 0.5, 1]
    path = tmp_path / "s.csv"
    write_arkit_csv(ArkitStream(w, np.arange(3) / 30, 30.0), path)
    # the texture is baked from renders: small ones keep the test short (the meshes and
    # files do not depend on the renders' size)
    small = ("--size", "64", "--samples", "4")
    r = run_cli("animate", head_file, "--arkit", path, "--mesh-sequence", tmp_path / "m",
                *small)
    assert r.code == 0, r.err
    names = sorted(p.name for p in (tmp_path / "m").iterdir())
    assert names == ["frame_00000.obj", "frame_00001.obj", "frame_00002.obj", "head.mtl",
                     "head_head.png"]
    meshes = [trimesh.load(tmp_path / "m" / n, force="mesh", process=False)
              for n in names[:3]]
    moved = [np.abs(m.vertices - meshes[0].vertices).max() for m in meshes]
    assert 0 == moved[0] < moved[1] < moved[2]
    r = run_cli("animate", head_file, "--arkit", path, "--mesh-sequence", tmp_path / "m")
    assert r.code == 3 and "holding files" in r.err
    # with the stream's head pose the meshes turn; without hair there is one object
    rot = np.zeros((3, 3), np.float32)
    rot[:, 0] = [0.0, 0.0, 0.5]
    write_arkit_csv(ArkitStream(w, np.arange(3) / 30, 30.0, head_rotation=rot), path)
    r = run_cli("animate", head_file, "--arkit", path, "--mesh-sequence", tmp_path / "p",
                "--head-pose", "--no-hair", *small)
    assert r.code == 0, r.err
    turned = trimesh.load(tmp_path / "p" / "frame_00002.obj", force="mesh", process=False)
    still = trimesh.load(tmp_path / "p" / "frame_00001.obj", force="mesh", process=False)
    assert turned.vertices[:, 0].mean() > still.vertices[:, 0].mean() + 0.005
    assert "o hair" not in (tmp_path / "p" / "frame_00000.obj").read_text()


@pytest.mark.slow
def test_a_mesh_sequence_the_disk_has_no_room_for_stops_after_its_first_frame(
        head_file, tmp_path, monkeypatch):
    """A 3046-frame take is about 3.9 GB of OBJs; on a disk with less it ran minutes
    before the disk filled. The first OBJ's size tells: the rest are refused then."""
    import shutil

    from head360cli.drive.bake import write_mesh_sequence
    from head360cli.errors import BadInputError
    from head360cli.fitting.pipeline import load_head_renderer

    renderer = load_head_renderer(head_file, samples=2, size=32)
    usage = shutil.disk_usage(tmp_path)
    written = []

    def progress(stage, done, total):
        written.append(done)

    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage._replace(free=10_000_000))
    with pytest.raises(BadInputError, match=r"expected room for 40 OBJ frames of about "
                                            r"1\.\d MB each \(\d\d MB\) for .*seq', "
                                            r"found 10 MB free: write them elsewhere"):
        write_mesh_sequence(renderer, np.zeros((40, 52), np.float32), tmp_path / "seq",
                            texture_size=32, progress=progress)
    assert written == [] and sorted(p.name for p in tmp_path.iterdir()) == []
    # room for the rest (at 98 % of the first one's size each): written
    room = 8 * 1_500_000
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage._replace(free=room))
    write_mesh_sequence(renderer, np.zeros((9, 52), np.float32), tmp_path / "seq",
                        texture_size=32, progress=progress)
    assert len(list((tmp_path / "seq").glob("*.obj"))) == 9


def test_baking_from_no_views_is_refused_before_any_work():
    """Before, an empty view list reached torch.cat's own message after the texel pass."""
    from head360cli.drive.bake import bake_head

    with pytest.raises(ValueError, match=r"at least one \(yaw, pitch\) view"):
        bake_head(None, size=32, views=[])


def test_an_obj_whose_texture_name_is_too_long_is_refused_before_the_bake(
        head_file, tmp_path, monkeypatch):
    """``-o <247 characters>.obj`` fits the file system, its ``_head.png`` texture's name
    does not: it was refused only after the texture was baked (10 s at the defaults)."""
    import os

    import head360cli.drive.bake as bake
    from head360cli.errors import BadInputError
    from head360cli.fitting.pipeline import load_head_renderer
    from head360cli.io.mesh import obj_companions

    baked = []
    monkeypatch.setattr(bake, "bake_head", lambda *a, **k: baked.append(1) or 1 / 0)
    limit = os.pathconf(tmp_path, "PC_NAME_MAX")
    out = tmp_path / ("m" * (limit - 8) + ".obj")  # 4 bytes under the limit
    assert [p.name[-9:] for p in obj_companions(out, ["head"])] == ["mmmmm.mtl", "_head.png"]
    r = load_head_renderer(head_file, samples=2, size=32)
    with pytest.raises(BadInputError, match=f"at most {limit} bytes"):
        bake.export_head(r, out)
    assert baked == [] and list(tmp_path.iterdir()) == []


def test_texels_of_triangles_without_area_are_filled_not_baked(head_file):
    """The template's seams are closed by triangles of no area (a ring at mouth height,
    the neck) that have room in the UV layout: their texels took grey and white streaks
    beside the mouth. They are filled from the skin around them, as smooth as the rest."""
    import torch

    from head360cli.drive.bake import _texels, bake_head
    from head360cli.fitting.pipeline import load_head_renderer
    from head360cli.geometry.rasterize import rasterize
    from head360cli.geometry.texels import DEGENERATE_AREA

    r = load_head_renderer(head_file, samples=2, size=64, precision="fp32")
    size = 256
    gen = r.gen
    faces, uv, faces_uv = gen.faces.cpu(), gen.uv.cpu(), gen.faces_uv.cpu()
    frags = rasterize((uv * size)[None], torch.ones(1, len(uv)), faces_uv, size, size,
                      perspective_correct=False, near=float("-inf"))
    tri = r.vertices(np.zeros(52)).cpu()[faces]
    area = torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]).norm(dim=-1)
    flat = (frags.mask[0] & (area[frags.face_id[0].clamp_min(0)] <= DEGENERATE_AREA)).numpy()
    assert flat.sum() > 1000  # the seams' band is there to be filled
    _, _, baked, _ = _texels(r, size)
    assert not (baked.numpy() & flat).any()
    texture, _ = bake_head(r, size)
    step = np.abs(np.diff(texture.astype(int), axis=1)).max(-1)
    in_flat = flat[:, 1:] & flat[:, :-1]
    rest = ~flat[:, 1:] & ~flat[:, :-1] & frags.mask[0].numpy()[:, 1:]
    assert np.percentile(step[in_flat], 99) <= np.percentile(step[rest], 99)


def test_the_glb_blends_the_pieces_with_strand_ends_and_keeps_the_others_opaque():
    """The faces of connected pieces holding a strand end (the shell) are told apart
    from the rest (tails, buns), which share the texture's colour but not its alpha."""
    from head360cli.drive.bake import _with_ends

    faces = np.array([[0, 1, 2], [1, 3, 2], [4, 5, 6], [7, 8, 9]])
    ends = np.zeros(10, bool)
    ends[3] = True
    assert _with_ends(faces, 10, ends).tolist() == [True, True, False, False]
    ends[9] = True
    assert _with_ends(faces, 10, ends).tolist() == [True, True, False, True]

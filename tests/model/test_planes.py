"""Hex-plane rasterization and sampling."""

from __future__ import annotations

import torch

from head360cli.model.planes import (
    PLANE_SETS,
    plane_coordinates,
    plane_raster,
    rasterize_planes,
    sample_planes,
    texel_reads,
    texture_planes,
)

CENTRE, HALF = (0.0, 0.0, 0.0), 0.2


def cube(side: float = 0.1):
    """A closed axis-aligned cube (8 vertices, 12 outward triangles) and per-corner UVs."""
    h = side / 2
    v = torch.tensor([[x, y, z] for x in (-h, h) for y in (-h, h) for z in (-h, h)])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4),
             (1, 5, 7, 3)]
    faces = torch.tensor([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    uv = torch.tensor([[0.25, 0.25], [0.75, 0.25], [0.75, 0.75]])
    faces_uv = torch.tensor([[0, 1, 2]] * len(faces))
    return v, faces, uv, faces_uv


def test_plane_coordinates_follow_the_table():
    p = torch.tensor([[[0.02, -0.04, 0.1]]])
    uv, h = plane_coordinates(p, ("front", "back", "left", "top"), CENTRE, HALF)
    assert torch.allclose(uv[0, 0, 0], torch.tensor([0.1, 0.2]))  # x, -y
    assert torch.allclose(h[0, :, 0], torch.tensor([0.1, -0.1, 0.02, -0.04]))


def test_a_cube_shows_its_faces_on_every_plane():
    v, faces, uv, faces_uv = cube()
    texture = torch.arange(2.0).view(1, 2, 1, 1).expand(1, 2, 8, 8).contiguous()
    planes = rasterize_planes(v[None], faces, uv, faces_uv, texture, PLANE_SETS["hex"], 32,
                              CENTRE, HALF)
    assert planes.shape == (1, 6, 4, 32, 32)
    cover = planes[0, :, -1]
    # The cube spans a quarter of each plane's side: 8 x 8 of 32 x 32 pixels.
    assert torch.allclose(cover.sum((1, 2)), torch.full((6,), 64.0))
    height = planes[0, :, -2][cover > 0]
    assert torch.allclose(height, torch.full_like(height, 0.05), atol=1e-5)
    assert torch.allclose(planes[0, :, 1][cover > 0], torch.ones(6 * 64))  # the texture


def test_points_on_a_face_weigh_the_plane_that_sees_it():
    v, faces, uv, faces_uv = cube()
    tex = torch.zeros(1, 6, 4, 4)
    planes = rasterize_planes(v[None], faces, uv, faces_uv, tex, PLANE_SETS["hex"], 64,
                              CENTRE, HALF)
    # Mark each plane's features with its own index, so the mix shows who contributed.
    ids = torch.arange(6.0).view(1, 6, 1, 1, 1)
    planes[:, :, :6] = torch.nn.functional.one_hot(ids.long().view(6), 6).float().view(
        1, 6, 6, 1, 1) * planes[:, :, -1:]
    pts = torch.tensor([[[0.0, 0.0, 0.05], [0.05, 0.0, 0.0], [0.0, 0.0, 0.3]]])
    got = sample_planes(pts, planes, PLANE_SETS["hex"], CENTRE, HALF, tau=0.01)
    feat, offset, total = got[0, :, :6], got[0, :, 6:12], got[0, :, 12]
    assert feat[0].argmax() == 0 and feat[0, 0] > 0.95  # front face: the front plane
    assert feat[1].argmax() == 2 and feat[1, 2] > 0.95  # +x face: the left plane
    assert abs(offset[0, 0]) < 0.1 and offset[0, 1] < -4 + 1e-6  # behind the back face
    assert total[2] < 1e-6  # far outside: no plane claims it
    assert torch.isfinite(got).all()


def test_tri_planes_are_a_subset():
    v, faces, uv, faces_uv = cube()
    tex = torch.rand(1, 3, 4, 4)
    hexp = rasterize_planes(v[None], faces, uv, faces_uv, tex, PLANE_SETS["hex"], 16,
                            CENTRE, HALF)
    tri = rasterize_planes(v[None], faces, uv, faces_uv, tex, PLANE_SETS["tri"], 16,
                           CENTRE, HALF)
    assert torch.equal(tri[0, 0], hexp[0, 0]) and torch.equal(tri[0, 1], hexp[0, 2])


def test_texel_reads_give_the_planes_of_grid_sample():
    """Planes read through :func:`texel_reads` (gathers) equal ``grid_sample``'s, values
    and texture gradients, over a batch of two meshes whose UVs reach the texture's
    border (where the read is clamped), and a texture of another size falls back to
    ``grid_sample``."""
    v, faces, _, faces_uv = cube()
    uv = torch.tensor([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])  # to the texture's edges
    verts = torch.stack([v, v * torch.tensor([1.3, 0.8, 1.1]) + 0.01])
    raster = plane_raster(verts, faces, uv, faces_uv, PLANE_SETS["hex"], 24, CENTRE, HALF)
    fast = texel_reads(raster, 8)
    assert len(fast.reads.pixel) == int(raster.mask.sum())
    torch.manual_seed(0)
    texture = torch.randn(2, 3, 8, 8, requires_grad=True)
    got, want = texture_planes(texture, fast), texture_planes(texture, raster)
    assert got.shape == want.shape == (2, 6, 5, 24, 24)
    torch.testing.assert_close(got, want, atol=1e-6, rtol=1e-6)
    assert (want[:, :, :3].abs() > 0).any()
    weights = torch.randn_like(want)
    g_got, = torch.autograd.grad((got * weights).sum(), texture)
    g_want, = torch.autograd.grad((want * weights).sum(), texture)
    torch.testing.assert_close(g_got, g_want, atol=1e-5, rtol=1e-5)
    assert g_want[:, :, 0, 0].abs().min() > 0  # the clamped corner texel is read
    other = torch.randn(2, 3, 16, 16)
    assert torch.equal(texture_planes(other, fast), texture_planes(other, raster))


def test_culling_back_faces_leaves_a_closed_meshs_planes_as_they_are():
    v, faces, uv, faces_uv = cube()
    v = v @ torch.tensor([[0.9, 0.3, 0.3], [-0.3, 0.95, 0.0], [-0.3, -0.1, 0.95]])  # turned
    tex = torch.rand(1, 4, 8, 8)
    args = (v[None], faces, uv, faces_uv, tex, PLANE_SETS["hex"], 32, CENTRE, HALF)
    plain = rasterize_planes(*args)
    culled = rasterize_planes(*args, cull_backfaces=True)
    # the same coverage and surface everywhere, the same texture but at the silhouette,
    # where a back face shares its edge with the front face and won the depth tie
    torch.testing.assert_close(culled[:, :, -2:], plain[:, :, -2:])
    differ = (culled - plain).abs().amax(2)[0] > 1e-5  # (P, res, res)
    cover = plain[0, :, -1] > 0
    edge = torch.nn.functional.max_pool2d((~cover).float()[:, None], 3, 1, 1)[:, 0] > 0
    assert differ.sum() <= 0.05 * cover.sum()
    assert not (differ & ~edge).any()
    # the culling is real: the same cube turned inside out shows its far side
    inside_out = rasterize_planes(v[None], faces.flip(1), *args[2:], cull_backfaces=True)
    depth_gap = (plain[0, :, -2] - inside_out[0, :, -2])[cover]  # metres
    assert depth_gap.mean() > 0.05 and depth_gap.min() >= -1e-6


def test_the_head_template_is_closed_so_its_planes_may_cull():
    """The generator culls the head's back faces on the planes (``HEAD_CLOSED``): that is
    only the same picture for a closed mesh whose triangles face outwards."""
    import numpy as np
    import trimesh

    from head360cli.mesh.bilinear import load_bilinear
    from head360cli.model.generator import HEAD_CLOSED

    model = load_bilinear()
    verts = model.vertices(np.zeros(model.rank), np.zeros(52))
    mesh = trimesh.Trimesh(verts, model.faces, process=False)
    assert HEAD_CLOSED
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    v = torch.as_tensor(verts, dtype=torch.float32)[None]
    f = torch.as_tensor(model.faces, dtype=torch.long)
    uv = torch.rand(len(verts), 2)
    args = (v, f, uv, f, torch.rand(1, 4, 16, 16), PLANE_SETS["hex"], 64, (0.0, -0.04, 0.0),
            0.2)
    plain = rasterize_planes(*args)
    culled = rasterize_planes(*args, cull_backfaces=True)
    cover = plain[:, :, -1] > 0
    assert torch.equal(cover, culled[:, :, -1] > 0)
    differ = (plain - culled).abs().amax(2) > 1e-5
    # a few silhouette pixels where a back face had won the depth tie at a shared edge
    assert differ.sum() <= 0.002 * cover.sum()


def test_renders_gather_the_texture_and_exports_and_training_sample_it(monkeypatch):
    """Without gradients the planes read the texture as gathers (texel_reads): the same
    planes; with gradients, and in an exported graph, grid_sample reads it."""
    from head360cli.model import planes as planes_mod

    v, faces, uv, faces_uv = cube()
    tex = torch.rand(1, 4, 8, 8)
    args = (v[None], faces, uv, faces_uv, tex, PLANE_SETS["hex"], 32, CENTRE, HALF)
    calls = []
    real = planes_mod.texel_reads
    monkeypatch.setattr(planes_mod, "texel_reads",
                        lambda *a: calls.append(1) or real(*a))
    with torch.no_grad():
        gathered = rasterize_planes(*args)
    assert calls == [1]
    sampled = rasterize_planes(*args)  # gradients on
    assert calls == [1]
    torch.testing.assert_close(gathered, sampled.detach(), atol=1e-6, rtol=0)
    monkeypatch.setattr(torch.onnx, "is_in_onnx_export", lambda: True)
    with torch.no_grad():
        rasterize_planes(*args)
    assert calls == [1]

"""The torch rasterizer against trimesh ray casting, plus its contract on edge cases."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from head360cli.geometry.cameras import camera_on_sphere, intrinsics_from_fov, project
from head360cli.geometry.rasterize import interpolate, rasterize


def scene():
    """A sphere partly hidden behind a box: occlusion, curved and flat surfaces."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    box = trimesh.creation.box(extents=(0.08, 0.08, 0.08))
    box.apply_translation((0.06, 0.03, 0.1))
    return trimesh.util.concatenate([sphere, box])


def render(mesh, yaw, pitch, size=64, fov=30.0, distance=0.6):
    c2w = camera_on_sphere(torch.tensor([yaw]), torch.tensor([pitch]), distance,
                           target=(0.0, 0.0, 0.0)).double()
    k = intrinsics_from_fov(fov, size, size, dtype=torch.float64)
    verts = torch.tensor(mesh.vertices, dtype=torch.float64)[None]
    faces = torch.tensor(mesh.faces, dtype=torch.long)
    pix, depth = project(verts, c2w, k)
    return rasterize(pix, depth, faces, size, size), c2w[0].numpy(), k.numpy()


def ray_cast(mesh, c2w, k, size):
    import trimesh

    jj, ii = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5)
    dirs_cam = np.stack([(jj - k[0, 2]) / k[0, 0], (ii - k[1, 2]) / k[1, 1],
                         np.ones_like(jj)], -1).reshape(-1, 3)
    dirs = dirs_cam @ c2w[:3, :3].T
    origins = np.repeat(c2w[None, :3, 3], len(dirs), axis=0)
    caster = trimesh.ray.ray_triangle.RayMeshIntersector(mesh)
    tri, ray = caster.intersects_id(origins, dirs, multiple_hits=False)[:2]
    out = np.full(size * size, -1)
    out[ray] = tri
    return out.reshape(size, size)


@pytest.mark.parametrize("yaw, pitch", [(0.0, 0.0), (35.0, 10.0), (180.0, -30.0)])
def test_agrees_with_trimesh_ray_casting(yaw, pitch):
    mesh = scene()
    frags, c2w, k = render(mesh, yaw, pitch)
    ours = frags.face_id[0].numpy()
    theirs = ray_cast(mesh, c2w, k, 64)
    agree = (ours == theirs).mean()
    assert agree >= 0.99, agree
    assert (ours >= 0).mean() > 0.2  # the scene fills a good part of the view


def test_depth_and_barycentrics_are_consistent():
    mesh = scene()
    frags, c2w, k = render(mesh, 20.0, 5.0)
    m = frags.mask[0]
    assert torch.allclose(frags.bary[0][m].sum(-1), torch.ones(int(m.sum()), dtype=torch.float64))
    assert (frags.bary >= 0).all()
    # Interpolating camera-space depth per vertex reproduces the z-buffer depth.
    verts = torch.tensor(mesh.vertices, dtype=torch.float64)[None]
    _, vdepth = project(verts, torch.tensor(c2w)[None], torch.tensor(k))
    z = interpolate(vdepth[..., None], torch.tensor(mesh.faces), frags)[0, ..., 0]
    assert torch.allclose(z[m], frags.depth[0][m], atol=1e-6)
    assert (frags.depth[0][~m] == 0).all()


def test_single_triangle_coverage_follows_pixel_centres():
    # A right triangle covering the lower-left half of a 4x4 image, edge through centres.
    screen = torch.tensor([[[0.0, 0.0], [0.0, 4.0], [4.0, 4.0]]])
    frags = rasterize(screen, torch.ones(1, 3), torch.tensor([[0, 1, 2]]), 4, 4)
    expected = torch.tensor([[1, 0, 0, 0], [1, 1, 0, 0], [1, 1, 1, 0], [1, 1, 1, 1]]).bool()
    assert torch.equal(frags.mask[0], expected)


def test_shared_edges_leave_no_cracks():
    # A quad split in two along its diagonal: every pixel is covered exactly by one face.
    screen = torch.tensor([[[0.3, 0.2], [9.7, 0.2], [9.7, 9.9], [0.3, 9.9]]])
    faces = torch.tensor([[0, 1, 2], [0, 2, 3]])
    frags = rasterize(screen, torch.ones(1, 4), faces, 10, 10)
    assert frags.mask[0, 0:10, 1:10].all()


def test_degenerate_offscreen_and_behind_camera_triangles_are_ignored():
    screen = torch.tensor([[[1.0, 1.0], [5.0, 5.0], [9.0, 9.0],  # zero area
                            [-50.0, -50.0], [-40.0, -50.0], [-45.0, -40.0],  # off screen
                            [1.0, 1.0], [9.0, 1.0], [5.0, 9.0]]])  # behind the camera
    depth = torch.tensor([[1.0, 1.0, 1.0, 1.0, 1.0, 1.0, -1.0, 1.0, 1.0]])
    faces = torch.tensor([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    frags = rasterize(screen, depth, faces, 10, 10)
    assert not frags.mask.any()
    nan = screen.clone()
    nan[0, 7] = float("nan")
    assert not rasterize(nan, depth.abs(), faces, 10, 10).mask.any()


def test_nearer_triangle_wins_and_batches_are_independent():
    quad = torch.tensor([[0.0, 0.0], [8.0, 0.0], [0.0, 8.0]])
    screen = torch.cat([quad, quad]).expand(2, 6, 2).clone()
    depth = torch.tensor([[2.0, 2.0, 2.0, 1.0, 1.0, 1.0], [1.0, 1.0, 1.0, 2.0, 2.0, 2.0]])
    faces = torch.tensor([[0, 1, 2], [3, 4, 5]])
    frags = rasterize(screen, depth, faces, 8, 8)
    assert (frags.face_id[0][frags.mask[0]] == 1).all()
    assert (frags.face_id[1][frags.mask[1]] == 0).all()


def test_large_and_small_triangles_together():
    # One triangle larger than the image plus many tiny ones in front of it.
    big = torch.tensor([[-100.0, -100.0], [300.0, -100.0], [-100.0, 300.0]])
    rng = np.random.default_rng(0)
    centres = torch.tensor(rng.uniform(5, 95, (200, 2)))
    small = (centres[:, None, :] + torch.tensor([[0.0, 0.0], [1.5, 0.0], [0.0, 1.5]])).reshape(
        -1, 2)
    screen = torch.cat([big.double(), small])[None]
    depth = torch.cat([torch.full((3,), 5.0), torch.ones(600)]).double()[None]
    faces = torch.arange(603).reshape(201, 3)
    frags = rasterize(screen, depth, faces, 100, 100)
    assert frags.mask.all()
    assert (frags.face_id > 0).sum() > 200  # the small ones show through


def test_gradients_flow_to_vertices():
    screen = torch.tensor([[[1.0, 1.0], [15.0, 2.0], [3.0, 14.0]]], requires_grad=True)
    frags = rasterize(screen, torch.ones(1, 3), torch.tensor([[0, 1, 2]]), 16, 16)
    colour = torch.tensor([[[1.0], [0.0], [0.0]]])
    out = interpolate(colour, torch.tensor([[0, 1, 2]]), frags)
    out.sum().backward()
    assert screen.grad is not None and screen.grad.abs().sum() > 0


@pytest.mark.parametrize("yaw, pitch", [(0.0, 0.0), (123.0, 40.0)])
def test_backface_culling_changes_nothing_on_closed_meshes(yaw, pitch):
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    c2w = camera_on_sphere(torch.tensor([yaw]), torch.tensor([pitch]), 0.6,
                           target=(0.0, 0.0, 0.0))
    k = intrinsics_from_fov(30.0, 64, 64)
    pix, depth = project(torch.tensor(mesh.vertices, dtype=torch.float32)[None], c2w, k)
    faces = torch.tensor(mesh.faces)
    full = rasterize(pix, depth, faces, 64, 64)
    culled = rasterize(pix, depth, faces, 64, 64, cull_backfaces=True)
    assert torch.equal(full.face_id, culled.face_id)
    # Turned inside out, the near half is culled and the far half shows from inside:
    # the same silhouette, farther away.
    inside_out = rasterize(pix, depth, faces.flip(1), 64, 64, cull_backfaces=True)
    assert torch.equal(inside_out.mask, full.mask)
    m = full.mask
    assert (inside_out.depth[m] > full.depth[m]).all()


@pytest.mark.slow
@pytest.mark.parametrize("yaw", [0.0, 100.0, 215.0])
def test_agrees_with_ray_casting_on_the_head(yaw):
    """The synthetic head, with eyes, ears, teeth and the folded mouth, from three sides."""
    import trimesh

    from head360cli.synth.identity import sample_identity
    from head360cli.synth.sculpt import build_head, topology

    verts, _ = build_head(sample_identity(4))
    topo = topology()
    tri = verts[topo.faces]
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    mesh = trimesh.Trimesh(verts, topo.faces[area > 1e-12], process=False)
    frags, c2w, k = render(mesh, yaw, 10.0, size=64, fov=20.0, distance=0.8)
    ours = frags.face_id[0].numpy()
    theirs = ray_cast(mesh, c2w, k, 64)
    assert (ours >= 0).mean() > 0.3
    assert (ours == theirs).mean() >= 0.99


def test_static_windows_give_the_same_fragments():
    """The export path (fixed window sizes, no data-dependent control flow) draws what the
    eager path draws, and drops only triangles larger than its last window."""
    from head360cli.geometry.rasterize import rasterize, static_windows

    g = torch.Generator().manual_seed(3)
    screen = torch.rand(2, 60, 2, generator=g) * 40
    depth = torch.rand(2, 60, generator=g) + 1
    faces = torch.randint(0, 60, (80, 3), generator=g)
    a = rasterize(screen, depth, faces, 40, 40)
    with static_windows():
        b = rasterize(screen, depth, faces, 40, 40)
    assert torch.equal(a.face_id, b.face_id)
    torch.testing.assert_close(a.bary, b.bary, atol=1e-6, rtol=0)
    torch.testing.assert_close(a.depth, b.depth, atol=1e-6, rtol=0)
    with static_windows():  # nothing on screen: empty, finite, no index set to fail on
        empty = rasterize(screen + 1000, depth, faces, 40, 40)
    assert (empty.face_id == -1).all() and (empty.depth == 0).all()
    assert torch.isfinite(empty.bary).all()
    with static_windows((1, 2, 4)):
        small = rasterize(screen, depth, faces, 40, 40)
    assert (small.face_id >= 0).sum() < (a.face_id >= 0).sum()


def test_static_windows_are_finite_where_the_first_triangle_is_not():
    """Uncovered pixels of the export path are computed from a well-formed stand-in
    triangle and masked by a product: a non-finite first triangle, which uncovered pixels
    once read, must not leak NaN into them."""
    from head360cli.geometry.rasterize import rasterize, static_windows

    screen = torch.tensor([[[float("inf"), 1.0], [5.0, float("nan")], [9.0, 9.0],
                            [2.0, 2.0], [12.0, 2.0], [2.0, 12.0]]])
    depth = torch.tensor([[1.0, 1.0, 1.0, 2.0, 2.0, 2.0]])
    faces = torch.tensor([[0, 1, 2], [3, 4, 5]])
    a = rasterize(screen, depth, faces, 16, 16)
    with static_windows():
        b = rasterize(screen, depth, faces, 16, 16)
    for frags in (a, b):
        assert torch.isfinite(frags.bary).all() and torch.isfinite(frags.depth).all()
        assert (frags.face_id[frags.mask] == 1).all() and frags.mask.sum() > 20
    assert torch.equal(a.face_id, b.face_id)
    torch.testing.assert_close(a.bary, b.bary, atol=1e-6, rtol=0)
    assert (b.bary[~b.mask] == 0).all() and (b.depth[~b.mask] == 0).all()


@pytest.mark.parametrize("perspective", [True, False])
def test_drawing_over_a_kept_zbuffer_equals_drawing_everything(perspective):
    """Triangles that never move drawn once, the others drawn over their depth test each
    frame: the same fragments as drawing all at once, ties (coplanar duplicates) included."""
    g = torch.Generator().manual_seed(5)
    screen = torch.rand(2, 60, 2, generator=g) * 40
    depth = torch.rand(2, 60, generator=g) + 1
    faces = torch.randint(0, 60, (80, 3), generator=g)
    faces = torch.cat([faces, faces[:10]])  # exact ties between a still and a moving one
    still = torch.rand(90, generator=g) < 0.5
    still[:10], still[80:] = True, False
    kw = {} if perspective else {"perspective_correct": False, "near": float("-inf")}
    full = rasterize(screen, depth, faces, 40, 40, **kw)
    under = rasterize(screen, depth, faces, 40, 40, draw=still, **kw).zbuffer
    over = rasterize(screen, depth, faces, 40, 40, draw=~still, under=under, **kw)
    assert torch.equal(over.face_id, full.face_id)
    assert torch.equal(over.bary, full.bary) and torch.equal(over.depth, full.depth)
    assert (full.face_id >= 80).any()  # the tie rule (larger id) was exercised
    # drawing nothing new over it gives the kept triangles' own fragments
    alone = rasterize(screen, depth, faces, 40, 40, draw=still, **kw)
    none = rasterize(screen, depth, faces, 40, 40, draw=torch.zeros_like(still),
                     under=under, **kw)
    assert torch.equal(none.face_id, alone.face_id)
    assert (alone.face_id >= 0).sum() < (full.face_id >= 0).sum()

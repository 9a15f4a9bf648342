"""The near-surface volume renderer."""

from __future__ import annotations

import math

import torch

from head360cli.geometry.cameras import camera_on_sphere, intrinsics_from_fov
from head360cli.model.render import EMPTY, composite, samples_around, surface_samples
from tests.model.test_planes import cube


def test_samples_straddle_the_rasterized_surface():
    v, faces, _, _ = cube(0.2)
    c2w = camera_on_sphere(torch.tensor([0.0]), torch.tensor([0.0]), 1.0,
                           target=(0.0, 0.0, 0.0))
    k = intrinsics_from_fov(24.0, 32, 32)[None]
    pts, depths, near = surface_samples(v[None], faces, c2w, k, 32, 4, 0.02)
    assert pts.shape == (1, 1024, 4, 3) and depths.shape == (1, 1024, 4)
    centre = 16 * 32 + 16  # the middle pixel looks at the front face, 0.9 m away
    assert near[0, centre] == 1 and near[0, 0] == 0
    assert torch.allclose(depths[0, centre], torch.tensor([0.885, 0.895, 0.905, 0.915]),
                          atol=1e-4)
    # Its points lie on its ray: half a pixel right of and below the principal point
    # (OpenCV camera y is down, the world's is up), through z = 0.1 (the front face).
    off = 0.5 / k[0, 0, 0] * depths[0, centre]
    assert torch.allclose(pts[0, centre, :, 0], off, atol=1e-5)
    assert torch.allclose(pts[0, centre, :, 1], -off, atol=1e-5)
    assert torch.allclose(pts[0, centre, :, 2], 1.0 - depths[0, centre], atol=1e-5)


def test_covered_pixels_keep_their_depth_and_the_border_borrows_the_nearest():
    # A near surface (0.5 m) over columns 0-2, a far one (0.9 m) over 3-5, nothing at 6-7.
    depth = torch.full((1, 8, 8), EMPTY)
    depth[:, :, :3], depth[:, :, 3:6] = 0.5, 0.9
    c2w = torch.eye(4)[None]
    k = intrinsics_from_fov(30.0, 8, 8)[None]
    _, t, near = samples_around(depth, c2w, k, 2, 0.01)
    mid = t.view(1, 8, 8, 2).mean(-1)[0, 4]
    # Column 3 sits beside the near surface's edge but is covered by the far one: its
    # samples stay around 0.9 m (borrowing 0.5 m left a background seam behind ears and
    # hair); column 6, uncovered, borrows its neighbour's depth for a soft silhouette.
    assert torch.allclose(mid[:6], torch.tensor([0.5, 0.5, 0.5, 0.9, 0.9, 0.9]))
    assert mid[6] == 0.9 and near.view(8, 8)[4].tolist() == [1] * 7 + [0]


def test_samples_behind_go_around_the_surface_under_the_hair():
    depth = torch.full((1, 8, 8), EMPTY)
    depth[:, :, :6] = 0.5  # hair over columns 0-5
    behind = torch.full((1, 8, 8), EMPTY)
    behind[:, :, :3], behind[:, :, 3:5] = 0.5, 0.6  # the head: on it at 0-2, 10 cm back at 3-4
    c2w = torch.eye(4)[None]
    k = intrinsics_from_fov(30.0, 8, 8)[None]
    _, plain, near = samples_around(depth, c2w, k, 4, 0.01)
    _, t, near_b = samples_around(depth, c2w, k, 4, 0.01, behind=behind)
    t, plain = t.view(8, 8, 4)[4], plain.view(8, 8, 4)[4]
    assert torch.equal(near_b, near)
    # Where the head is the hair's surface, or where no head lies behind (columns 5-6
    # borrow, column 5 from its neighbour at 0.6), the samples are the plain ones.
    assert torch.allclose(t[:3], plain[:3]) and torch.allclose(t[6], plain[6])
    # Where it lies behind, half the samples stay on the hair and half go to the head,
    # sorted along the ray.
    assert torch.allclose(t[3], torch.tensor([0.4925, 0.5025, 0.5975, 0.6075]))
    assert torch.allclose(t[5], torch.tensor([0.4925, 0.5025, 0.5975, 0.6075]))
    assert (t[:7].diff(dim=-1) >= 0).all()


def test_compositing_of_known_densities():
    depths = torch.tensor([[[1.0, 1.1, 1.2]]])
    feats = torch.tensor([[[[1.0], [2.0], [3.0]]]])
    near = torch.ones(1, 1)
    dens = torch.tensor([[[0.0, math.log(2) / 0.1, 1e6]]])  # nothing, half, everything
    f, a, d = composite(dens, feats, depths, near, shell=0.15)
    assert torch.allclose(a, torch.tensor([[1.0]]))
    assert torch.allclose(f, torch.tensor([[[0.5 * 2 + 0.5 * 3]]]))
    assert torch.allclose(d, torch.tensor([[1.15]]))
    f0, a0, _ = composite(dens, feats, depths, torch.zeros(1, 1), shell=0.15)
    assert a0.item() == 0 and f0.item() == 0  # rays that pass no surface stay empty


def test_lit_scales_the_head_and_leaves_the_backdrop_white():
    """A pixel of colour c and coverage a composited on white, ``a c + 1 - a``, comes
    out as ``a g c + 1 - a``: an empty pixel stays white, an opaque one is ``g c``."""
    from head360cli.model.render import lit

    alpha = torch.tensor([0.0, 0.5, 1.0]).view(1, 1, 1, 3)
    colour = torch.tensor([0.2, 0.4, 0.6]).view(1, 3, 1, 1)
    rgb = colour * alpha + (1 - alpha)
    gain = torch.tensor([0.5, 1.0, 1.5])
    out = lit(rgb, alpha, gain)
    torch.testing.assert_close(out, gain.view(1, 3, 1, 1) * colour * alpha + (1 - alpha))
    assert torch.equal(out[..., 0], torch.ones(1, 3, 1))
    torch.testing.assert_close(out[0, :, 0, 2], torch.tensor([0.1, 0.4, 0.9]))
    # a (B, 3, 1, 1) gain works as well as a (3,) one
    torch.testing.assert_close(lit(rgb, alpha, gain.view(1, 3, 1, 1)), out)

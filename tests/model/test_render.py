"""The near-surface volume renderer."""

from __future__ import annotations

import math

import torch

from head360cli.geometry.cameras import camera_on_sphere, intrinsics_from_fov
from head360cli.model.render import composite, surface_samples
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

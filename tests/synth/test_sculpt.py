"""The procedural head: topology, closed parts, mirror symmetry, UV atlas, determinism."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest
import torch

from head360cli.geometry.rasterize import rasterize
from head360cli.synth.identity import mean_identity, sample_identity
from head360cli.synth.sculpt import build_head, topology

IDENTITIES = [mean_identity()] + [sample_identity(s) for s in (1, 2, 3)]


def test_vertex_budget_and_part_layout():
    topo = topology()
    assert 2500 <= topo.num_vertices <= 6000
    assert topo.faces.min() == 0 and topo.faces.max() == topo.num_vertices - 1
    ranges = sorted(topo.parts.values())
    assert all(a[1] == b[0] for a, b in itertools.pairwise(ranges))


@pytest.mark.parametrize("identity", IDENTITIES, ids=lambda p: f"seed{p.deform_seed}")
def test_every_part_is_closed_and_faces_outwards(identity):
    import trimesh

    topo = topology()
    verts, _ = build_head(identity)
    assert np.isfinite(verts).all()
    for k, name in enumerate(topo.part_names):
        mesh = trimesh.Trimesh(verts, topo.faces[topo.face_parts == k], process=False)
        assert mesh.is_watertight, name
        assert mesh.is_winding_consistent, name
        assert mesh.volume > 0, name


def test_same_parameters_give_identical_bytes():
    a, _ = build_head(sample_identity(7))
    b, _ = build_head(sample_identity(7))
    assert a.tobytes() == b.tobytes()
    c, _ = build_head(sample_identity(8))
    assert np.abs(a - c).max() > 1e-3


def test_mirror_map_is_an_involution_and_exact_on_a_symmetric_head():
    topo = topology()
    assert (topo.mirror[topo.mirror] == np.arange(topo.num_vertices)).all()
    verts, _ = build_head(mean_identity())
    mirrored = verts[topo.mirror] * np.array([-1.0, 1.0, 1.0])
    assert np.abs(mirrored - verts).max() < 1e-12


def test_random_deformation_is_smooth_and_small():
    p = sample_identity(4)
    a, _ = build_head(p)
    b, _ = build_head(dataclasses.replace(p, deform_amplitude=0.0))
    d = np.linalg.norm(a - b, axis=1)
    assert 0 < d.max() < 4 * p.deform_amplitude


def test_uv_atlas_has_no_overlaps():
    """Rasterize the UV layout twice with opposite depth orders: where two triangles
    overlapped, the visible one would change."""
    topo = topology()
    size = 1024
    uv = torch.tensor(topo.uv, dtype=torch.float64) * size
    faces = torch.tensor(topo.faces_uv)
    corners = uv[faces].reshape(-1, 2)
    tri = torch.arange(len(corners)).reshape(-1, 3)
    order = torch.arange(len(faces), dtype=torch.float64).repeat_interleave(3)
    ids = []
    for depth in (1.0 + order, 1.0 + order.flip(0)):
        frags = rasterize(corners[None], depth[None], tri, size, size,
                          perspective_correct=False, eps=-1e-6)
        ids.append(frags.face_id[0])
    covered = (ids[0] >= 0) & (ids[1] >= 0)
    assert covered.float().mean() > 0.5
    assert (ids[0][covered] == ids[1][covered]).float().mean() > 0.9995
    assert uv.min() >= 0 and uv.max() <= size

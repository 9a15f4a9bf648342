"""Mesh functions: the distance along a hair shell's strands to their ends."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from head360cli.geometry.mesh_ops import edge_distance


@pytest.fixture(scope="module")
def head():
    from head360cli.mesh.bilinear import load_bilinear

    model = load_bilinear()
    return model.vertices(np.zeros(model.rank), np.zeros(52))


def _mesh(head, style):
    from head360cli.synth.hair import fit_hair, style_index

    m = fit_hair(head, style_index(style), soft=True)
    return (torch.tensor(m.verts, dtype=torch.float32), torch.tensor(m.faces),
            torch.tensor(m.uv, dtype=torch.float32), m.shell)


def test_strands_end_at_the_shells_tips_not_at_the_crown_or_a_staircase(head):
    verts, faces, uv, _ = _mesh(head, "bob")
    d = edge_distance(verts, faces, uv, 0.025)
    used = torch.zeros(len(verts), dtype=torch.bool)
    used[faces.reshape(-1)] = True
    assert d.min() == 0 and d.max() == pytest.approx(0.025)
    assert 0 < int((d[used] < 0.025).sum()) < 0.3 * int(used.sum())
    # the lowest vertices (the tips) are ends; the crown's ring is not
    low = used & (verts[:, 1] < verts[used, 1].min() + 0.003)
    assert float(d[low].mean()) < 0.005
    crown = used & (uv[:, 1] == 0)
    assert bool((d[crown] == 0.025).all())
    # a distance grows by at most the edge between two vertices of a column
    a, b = faces[:, 0], faces[:, 1]
    along = (uv[a, 0] - uv[b, 0]).abs() < 1e-9
    step = (verts[a] - verts[b]).norm(dim=-1)
    assert bool(((d[a] - d[b]).abs() <= step + 1e-6)[along].all())


def test_tails_have_no_ends_and_padding_changes_nothing(head):
    verts, faces, uv, shell = _mesh(head, "twin_tails")
    d = edge_distance(verts, faces, uv, 0.025)
    assert bool((d[shell:] == 0.025).all()) and float(d[:shell].min()) == 0
    # an exported graph pads the mesh with (0, 0, 0) faces and unused vertices
    pv = torch.cat([verts, torch.zeros(7, 3)])
    pf = torch.cat([faces, torch.zeros(11, 3, dtype=faces.dtype)])
    puv = torch.cat([uv, torch.zeros(7, 2)])
    assert torch.equal(edge_distance(pv, pf, puv, 0.025)[:len(verts)], d)

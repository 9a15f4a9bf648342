"""The corpus renderer and the painted appearance."""

from __future__ import annotations

import numpy as np
import torch

from head360cli.geometry.cameras import (
    RIG_DISTANCE,
    RIG_FOV_DEG,
    camera_on_sphere,
    intrinsics_from_fov,
)
from head360cli.synth.appearance import paint_texture, sample_appearance, texel_positions
from head360cli.synth.identity import mean_identity, sample_identity
from head360cli.synth.render import render_mesh
from head360cli.synth.sculpt import build_head, topology


def render(verts, texture, yaws, size=64, samples=4):
    topo = topology()
    eye_parts = (topo.part_names.index("eye_l"), topo.part_names.index("eye_r"))
    c2w = camera_on_sphere(torch.tensor(yaws), torch.zeros(len(yaws)), RIG_DISTANCE)
    v = torch.tensor(verts, dtype=torch.float32)[None].expand(len(yaws), -1, -1)
    return render_mesh(v, torch.tensor(topo.faces), c2w,
                       intrinsics_from_fov(RIG_FOV_DEG, size, size), size,
                       uv=torch.tensor(topo.uv), faces_uv=torch.tensor(topo.faces_uv),
                       texture=torch.tensor(texture).permute(2, 0, 1)[None],
                       face_labels=torch.tensor(topo.face_parts), label_sets=(eye_parts,),
                       normal_groups=torch.tensor(topo.normal_groups), samples=samples)


def test_front_and_back_views():
    verts, _frame = build_head(mean_identity())
    tex = np.full((16, 16, 3), 0.6, dtype=np.float32)
    out = render(verts, tex, [0.0, 180.0])
    assert out.rgb.shape == (2, 3, 64, 64) and out.alpha.shape == (2, 1, 64, 64)
    assert ((out.rgb >= 0) & (out.rgb <= 1)).all()
    coverage = out.alpha.mean(dim=(1, 2, 3))
    assert ((coverage > 0.12) & (coverage < 0.6)).all()
    # Antialiased edges have partial coverage; the corners are background.
    assert ((out.alpha > 0.05) & (out.alpha < 0.95)).any()
    assert torch.allclose(out.rgb[:, :, 0, 0], torch.ones(2, 3))
    eyes = out.labels[:, 0].sum(dim=(1, 2))
    assert eyes[0] > 0.5 and eyes[1] == 0  # eyes show from the front, not from behind
    # Depth is about the camera distance where the head is.
    d = out.depth[0, 0][out.depth[0, 0] > 0]
    assert (d > RIG_DISTANCE - 0.2).all() and (d < RIG_DISTANCE + 0.2).all()


def test_rendering_is_deterministic():
    verts, _ = build_head(sample_identity(3))
    tex = np.random.default_rng(0).uniform(0, 1, (32, 32, 3)).astype(np.float32)
    a = render(verts, tex, [30.0])
    b = render(verts, tex, [30.0])
    assert torch.equal(a.rgb, b.rgb)


def test_texel_positions_cover_every_part():
    topo = topology()
    verts, _ = build_head(mean_identity())
    pos, part = texel_positions(verts, topo, 256)
    for k in range(len(topo.part_names)):
        assert (part == k).sum() > 20, topo.part_names[k]
    skin = part == topo.part_names.index("skin")
    # A texel's 3D position lies on the head (within its bounding box).
    assert (np.abs(pos[skin]) < 0.25).all()


def test_painted_texture_is_deterministic_and_varied():
    topo = topology()
    texs = []
    for seed in (1, 2):
        p = sample_identity(seed)
        verts, frame = build_head(p)
        look = sample_appearance(seed, p)
        t1 = paint_texture(verts, topo, frame, p, look, 128)
        t2 = paint_texture(verts, topo, frame, p, look, 128)
        assert t1.tobytes() == t2.tobytes()
        assert t1.shape == (128, 128, 3) and t1.min() >= 0 and t1.max() <= 1
        texs.append(t1)
    assert np.abs(texs[0] - texs[1]).mean() > 0.005


def test_skin_tones_span_light_to_deep():
    tones = [sample_appearance(s, sample_identity(s)).skin_tone for s in range(100)]
    assert min(tones) < 0.1 and max(tones) > 0.8

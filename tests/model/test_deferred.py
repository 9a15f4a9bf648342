"""The deferred generator: outputs, coverage against the corpus renderer, locality of the
texture, kept G-buffers, hair."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from head360cli.geometry.cameras import intrinsics_from_fov, rig72
from head360cli.mesh.bilinear import BilinearHead, load_bilinear
from head360cli.model.config import GeneratorConfig
from head360cli.model.generator import hair_for
from head360cli.model.train import build_generator

TINY = GeneratorConfig(texture_res=32, render_res=16, image_res=64, hidden=16,
                       refine_width=8, generator_width=32, hair_texture_res=8)


@pytest.fixture(scope="module")
def parts():
    model = load_bilinear()
    head = BilinearHead(model)
    verts = head.vertices(torch.zeros(2, model.rank), torch.zeros(2, 52))
    c2w = rig72()[0][[24, 30]]  # front, and turned 90 degrees
    return model, verts, c2w, intrinsics_from_fov(24.0, 64, 64)


def _gen(cfg=TINY, seed=0):
    torch.manual_seed(seed)
    return build_generator(cfg).eval()


def test_outputs_and_gradients(parts):
    _, verts, c2w, k = parts
    gen = _gen()
    assert gen.kind == "deferred"
    code = torch.randn(2, TINY.code_dim, requires_grad=True)
    out = gen(verts, c2w, k, code=code)
    assert out["rgb"].shape == (2, 3, 64, 64) and out["alpha"].shape == (2, 1, 64, 64)
    assert out["rgb_low"].shape == (2, 3, 16, 16)
    assert torch.isfinite(out["rgb"]).all()
    assert out["alpha"][0, 0, 32, 32] == 1 and out["alpha"][0, 0, 0, 0] == 0
    # the backdrop is white
    assert torch.allclose(out["rgb"][:, :, 0, 0], torch.ones(2, 3))
    out["rgb"].mean().backward()
    assert code.grad is not None and code.grad.abs().sum() > 0
    assert all(p.grad is not None and torch.isfinite(p.grad).all()
               for p in gen.shader.parameters())


def test_coverage_is_the_corpus_renderers(parts):
    """Two samples a pixel at the corpus renderer's offsets: the same antialiased
    coverage, pixel for pixel, so training never fights the targets' edges."""
    from head360cli.synth.render import render_mesh

    model, verts, c2w, k = parts
    gen = _gen()
    with torch.no_grad():
        out = gen(verts, c2w, k, texture=torch.zeros(2, 16, 32, 32))
    tex = torch.full((1, 3, 8, 8), 0.5)
    ref = render_mesh(verts, torch.as_tensor(model.faces), c2w, k, 64,
                      uv=torch.as_tensor(model.uv, dtype=torch.float32),
                      faces_uv=torch.as_tensor(model.faces_uv), texture=tex, samples=2)
    assert torch.equal(out["alpha"] > 0, ref.alpha > 0)
    assert (out["alpha"] - ref.alpha).abs().max() < 1e-6


def test_a_texel_changes_only_where_its_surface_is_seen(parts):
    """Locality: a patch of the texture changed, a view that cannot see it does not
    change at all, and a view that sees it changes only within the image network's
    reach of the pixels that read it."""
    _, verts, c2w, k = parts
    gen = _gen()
    torch.manual_seed(1)
    with torch.no_grad():  # a trained image network spreads changes; a new one does not
        torch.nn.init.normal_(gen.refine.net[-1].weight, std=0.1)
    tex = torch.rand(1, 16, 32, 32)
    changed = tex.clone()
    # the patch: texels of the left ear's island in the UV layout
    patch = (slice(5, 9), slice(25, 31))
    changed[:, :, patch[0], patch[1]] += 1.0
    with torch.no_grad():
        buf = gen.gbuffer(verts, c2w, k.expand(2, 3, 3))
        hit = torch.zeros(len(buf.index), dtype=torch.bool)
        px = (buf.uv * 32 - 0.5).floor().long()
        for dy in (0, 1):
            for dx in (0, 1):
                x, y = (px[:, 0] + dx).clamp(0, 31), (px[:, 1] + dy).clamp(0, 31)
                hit |= (y >= 5) & (y < 9) & (x >= 25) & (x < 31)
        reads = torch.zeros(buf.mask.numel(), dtype=torch.bool)
        reads[buf.index[hit]] = True
        reads = reads.view(buf.samples, 2, 64, 64).any(0)
        a = gen(verts, c2w, k, texture=tex.expand(2, -1, -1, -1))["rgb"]
        b = gen(verts, c2w, k, texture=changed.expand(2, -1, -1, -1))["rgb"]
    diff = (a - b).abs().amax(1) > 0
    for view in range(2):
        near = torch.nn.functional.max_pool2d(
            reads[view][None, None].float(), 2 * gen.refine.reach + 1, 1,
            gen.refine.reach)[0, 0] > 0
        assert not (diff[view] & ~near).any()
    # the views differ in what they see of the patch: one sees it, and changes
    assert diff.any()
    assert int(reads[0].sum()) != int(reads[1].sum())


def test_a_kept_gbuffer_renders_the_same_without_rasterizing(parts, monkeypatch):
    _, verts, c2w, k = parts
    gen = _gen()
    tex = torch.rand(2, 16, 32, 32)
    kept: dict = {}
    with torch.no_grad():
        a = gen(verts, c2w, k, texture=tex, view_rays=kept)["rgb"]
    import head360cli.model.deferred as deferred

    def fail(*args, **kwargs):
        raise AssertionError("rasterized again")

    monkeypatch.setattr(deferred, "gbuffer", fail)
    with torch.no_grad():
        b = gen(verts, c2w, k, texture=tex, view_rays=kept)["rgb"]
    assert torch.equal(a, b)


def test_hair_is_drawn_and_items_sharing_it_render_as_one_by_one(parts):
    model, verts, c2w, k = parts
    gen = _gen()
    neutral = model.vertices(np.zeros(model.rank), np.zeros(52))
    hair = hair_for(neutral, [3], np.array([[0.3, 0.2, 0.1]]))
    tex = torch.rand(1, 16, 32, 32)
    with torch.no_grad():
        both = gen(verts, c2w, k, texture=tex.expand(2, -1, -1, -1), hair=hair.repeat(2))
        one = [gen(verts[i:i + 1], c2w[i:i + 1], k, texture=tex, hair=hair)
               for i in range(2)]
        bald = gen(verts, c2w, k, texture=tex.expand(2, -1, -1, -1))
    assert both["hair_alpha"].sum() > 0 and bald["hair_alpha"].sum() == 0
    assert both["alpha"].sum() > bald["alpha"].sum()
    for i in range(2):
        assert torch.allclose(both["rgb"][i], one[i]["rgb"][0], atol=1e-6)
    # the network's 8 texels a side (this tiny config's), enlarged for renders
    from head360cli.model.deferred import HAIR_TEXTURE_SIDE

    side = HAIR_TEXTURE_SIDE
    assert gen.cfg.hair_texture_res == 8 and both["hair_texture"].shape == (2, 16, side, side)


def test_hair_takes_any_colour_asked_for_in_renders_and_learns_in_training(parts):
    """Rendering (eval mode), the hair's albedo channels are the colour of the corpus's
    strand texture of the colour asked for (any colour, green too) times the network's
    strand shading; the other channels are the network's, all enlarged to the side
    renders read. Training leaves all to it."""
    from head360cli.model.deferred import enlarged, exact_hair_colour

    model, _, _, _ = parts
    neutral = model.vertices(np.zeros(model.rank), np.zeros(52))
    gen = _gen()
    hair = hair_for(neutral, [3], np.array([[0.0, 1.0, 0.0]]))
    with torch.no_grad():
        made = gen.prepare_hair(hair).planes[0]
        gen.train()
        learnt = gen.prepare_hair(hair).planes[0]
        gen.eval()
    torch.testing.assert_close(made, enlarged(exact_hair_colour(learnt, hair.colour)))
    assert not torch.equal(made[:, :3], enlarged(learnt)[:, :3])
    # the function itself, on a texture whose strands are known
    torch.manual_seed(0)
    tex = torch.rand(2, 6, 8, 8)
    colours = torch.tensor([[0.0, 0.4, 0.0], [0.035, 0.03, 0.028]])
    out = exact_hair_colour(tex, colours)
    torch.testing.assert_close(out[:, :3].mean((-2, -1)),
                               torch.tensor([[0.0, 0.4, 0.0], [0.065, 0.06, 0.058]]),
                               atol=1e-6, rtol=0)  # near-black hair: + 0.03, as the corpus
    bright = tex[:, :3].mean(1)
    torch.testing.assert_close(out[1, 0], 0.065 * bright[1] / bright[1].mean())
    assert torch.equal(out[:, 3:], tex[:, 3:])


def test_gbuffer_normals_and_view_directions(parts):
    """Unit vectors; the view direction points at the camera, and a visible surface
    faces it."""
    _, verts, c2w, k = parts
    gen = _gen()
    buf = gen.gbuffer(verts, c2w, k.expand(2, 3, 3))
    n = len(buf.index)
    assert n == int(buf.mask.sum())
    assert torch.allclose(buf.normal.norm(dim=-1), torch.ones(n), atol=1e-4)
    assert torch.allclose(buf.view.norm(dim=-1), torch.ones(n), atol=1e-5)
    assert ((buf.normal * buf.view).sum(-1) > -0.05).float().mean() > 0.99
    # the front camera looks along -z at the face: its points see +z
    front = buf.view[buf.index == 32 * 64 + 32][0]
    assert front[2] > 0.99


def test_pixel_samples_and_sizes_are_scoped(parts):
    gen = _gen()
    with gen.pixel_samples(1), gen.image_size(128):
        assert gen.cfg.pixel_samples == 1 and gen.cfg.image_res == 128
    assert gen.cfg.pixel_samples == 2 and gen.cfg.image_res == 64
    with pytest.raises(ValueError, match="1, 2 or 4"):
        gen.pixel_samples(3)
    with pytest.raises(ValueError, match="head planes"):
        gen(parts[1], parts[2], parts[3], texture=torch.zeros(2, 16, 32, 32),
            head_planes=torch.zeros(1))


def test_frames_of_a_still_camera_draw_what_no_frame_moves_once(parts, monkeypatch):
    """An animation seen by one still camera: the still triangles' depth test, the hair's
    fragments and the view directions are made for the first frame and reused; the
    frames are those rendered without reuse."""
    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.model.head_render import HeadRenderer

    gen = _gen()
    with torch.no_grad():
        torch.nn.init.normal_(gen.refine.net[-1].weight, std=0.1)
    r = HeadRenderer(gen, np.zeros(load_bilinear().rank), torch.rand(16, 32, 32), 11,
                     np.array([0.3, 0.2, 0.1]), precision="fp32", size=64)
    rng = np.random.default_rng(0)
    w = (rng.uniform(0, 1, (4, 52)) * (rng.uniform(0, 1, (4, 52)) < 0.3)).astype(np.float32)
    cams, k = view_cameras(30.0, 0.0).expand(4, 4, 4), view_intrinsics(64)
    import head360cli.model.gbuffer as gb

    drawn = []
    real = gb.rasterize
    monkeypatch.setattr(gb, "rasterize", lambda *a, **kw: drawn.append(kw.get("draw"))
                        or real(*a, **kw))
    reused = torch.cat([f for f in r.frames(cams, w, k, uint8=False)])
    calls = len(drawn)
    fresh = torch.cat([f for f in r.frames(cams, w, k, uint8=False, batch=4)])
    assert (reused - fresh).abs().max() < 1e-5
    # one still pass, one hair pass, then the moving triangles once a frame
    assert calls == 2 + 4 and sum(d is not None for d in drawn[:calls]) == 5


def test_hair_ends_are_see_through_over_the_head_and_ears_stay_under_it(parts):
    """Outside training the hair's strand ends blend over what is behind them (the
    head's own surface, shaded, or the backdrop), its hair alpha fractional there, and
    hair close behind an ear is drawn over it; training keeps the corpus's opaque hair
    with the ears drawn by depth alone."""
    model, verts, c2w, k = parts
    gen = _gen()
    neutral = model.vertices(np.zeros(model.rank), np.zeros(52))
    hair = hair_for(neutral, [3], np.array([[0.3, 0.2, 0.1]])).repeat(2)  # a bob
    tex = torch.rand(2, 16, 32, 32)
    with torch.no_grad():
        made = gen.prepare_hair(hair)
        buf = gen.gbuffer(verts, c2w, k, made)
        out = gen(verts, c2w, k, texture=tex, hair=hair)
        gen.train()
        opaque_buf = gen.gbuffer(verts, c2w, k, made)
        opaque = gen(verts, c2w, k, texture=tex, hair=hair)
        gen.eval()
    assert opaque_buf.alpha is None and buf.alpha is not None
    thin = buf.alpha[buf.hair] < 1
    assert 0 < int(thin.sum()) < 0.5 * int(buf.hair.sum())
    assert bool((buf.alpha[~buf.hair] == 1).all())
    # the head's surface is kept behind see-through hair points only
    assert len(buf.under) > 0 and bool((buf.alpha[buf.under] < 1).all())
    assert bool(buf.hair[buf.under].all()) and len(buf.under_uv) == len(buf.under)
    soft = (out["hair_alpha"] > 0.02) & (out["hair_alpha"] < 0.98)
    hard = (opaque["hair_alpha"] > 0.02) & (opaque["hair_alpha"] < 0.98)
    assert int(soft.sum()) > 1.5 * int(hard.sum())
    # the ears: drawn over by hair in the side view only where the hair is close behind
    ear_faces = gen.under_hair
    assert ear_faces is not None and 0 < int(ear_faces.sum()) < len(ear_faces) // 10
    with torch.no_grad():
        gen.under_hair = None
        pierced = gen.gbuffer(verts, c2w, k, made)
        gen.under_hair = ear_faces
    assert int(buf.hair_mask.sum()) > int(pierced.hair_mask.sum())
    assert bool((buf.hair_mask | ~pierced.hair_mask).all())  # hair only gains pixels


def test_strand_opacity_rises_from_the_end_and_is_dense_edge_on():
    from head360cli.model.gbuffer import FADE, STRANDS, strand_opacity

    u = torch.rand(500, generator=torch.Generator().manual_seed(0))
    square = torch.ones(500)
    assert bool((strand_opacity(torch.zeros(500), u, square) == 0).all())
    assert bool((strand_opacity(torch.full((500,), FADE), u, square) == 1).all())
    mid = strand_opacity(torch.full((500,), 0.6 * FADE), u, square)
    assert 0.1 < float(mid.mean()) < 0.9 and float(mid.std()) > 0.1  # staggered ends
    steps = torch.linspace(0, FADE, 20)[:, None].expand(20, 500)
    rising = strand_opacity(steps, u.expand(20, 500), torch.ones(20, 500))
    assert bool((rising.diff(dim=0) >= 0).all())
    assert bool((strand_opacity(torch.zeros(500), u, torch.zeros(500)) == 1).all())
    # u wraps round the head: the same strands at u and u + 1
    assert torch.allclose(strand_opacity(steps[5], u, square),
                          strand_opacity(steps[5], u + 1, square), atol=1e-4)
    assert STRANDS >= 100

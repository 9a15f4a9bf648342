"""The generator: shapes, gradients, configs and the shipped-weights loader."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from head360cli.errors import FileFormatError, ModelNotFoundError
from head360cli.geometry.cameras import intrinsics_from_fov, rig72
from head360cli.mesh.bilinear import BilinearHead, load_bilinear
from head360cli.model.config import GeneratorConfig
from head360cli.model.generator import Generator

TINY = GeneratorConfig(texture_res=16, plane_res=16, render_res=16, image_res=32, samples=4,
                       hidden=16, refine_width=8, generator_width=32, hair_texture_res=8)


@pytest.fixture(scope="module")
def parts():
    model = load_bilinear()
    head = BilinearHead(model)
    verts = head.vertices(torch.zeros(2, model.rank), torch.zeros(2, 52))
    c2w = rig72()[0][[24, 30]]
    return model, verts, c2w, intrinsics_from_fov(24.0, 32, 32)


@pytest.mark.parametrize("cfg", [TINY, dataclasses.replace(TINY, planes="tri"),
                                 dataclasses.replace(TINY, refine=False)])
def test_outputs_and_gradients(parts, cfg):
    model, verts, c2w, k = parts
    torch.manual_seed(0)
    gen = Generator(cfg, model.faces, model.uv, model.faces_uv)
    code = torch.randn(2, cfg.code_dim, requires_grad=True)
    out = gen(verts, c2w, k, code=code, jitter=True)
    assert out["rgb"].shape == (2, 3, 32, 32) and out["alpha"].shape == (2, 1, 32, 32)
    assert out["rgb_low"].shape == (2, 3, 16, 16)
    assert torch.isfinite(out["rgb"]).all()
    # The head covers the middle of a frontal view and not the corners.
    assert out["alpha_low"][0, 0, 8, 8] > 0.5 and out["alpha_low"][0, 0, 0, 0] == 0
    out["rgb"].mean().backward()
    assert code.grad is not None and code.grad.abs().sum() > 0
    grads = [p.grad for p in gen.decoder.parameters()]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)


def test_a_given_texture_replaces_the_code(parts):
    model, verts, c2w, k = parts
    gen = Generator(TINY, model.faces, model.uv, model.faces_uv).eval()
    code = torch.zeros(2, TINY.code_dim)
    with torch.no_grad():
        a = gen(verts, c2w, k, code=code)
        b = gen(verts, c2w, k, texture=gen.texture(code))
    assert torch.equal(a["rgb"], b["rgb"])
    with pytest.raises(ValueError, match="texture code"):
        gen(verts, c2w, k)


@pytest.fixture
def rastered(parts):
    """A tiny generator (seed 0), two generated textures and the parts' meshes' plane
    raster."""
    model, verts, _, _ = parts
    torch.manual_seed(0)
    gen = Generator(TINY, model.faces, model.uv, model.faces_uv).eval()
    with torch.no_grad():
        texture = gen.texture(torch.randn(2, TINY.code_dim))
        raster = gen.plane_raster(verts)
    return gen, texture, raster


def test_a_precomputed_plane_raster_renders_the_same(parts, rastered, monkeypatch):
    """A mesh rasterized onto the planes once (a texture inversion's fixed mesh) renders
    as when it is rasterized in every call, with the same texture gradients (to float
    rounding: the precomputed raster reads the texture by gathers, see
    ``test_texel_reads_give_the_planes_of_grid_sample``), and the call then rasterizes
    nothing onto the planes."""
    import head360cli.model.generator as generator

    _, verts, c2w, k = parts
    gen, texture, raster = rastered
    assert raster.grid.shape == (2, 6 * 16, 16, 2)
    assert raster.mask.shape == raster.surface.shape == (2, 1, 6, 16, 16)
    renders, grads = [], []
    for given in (None, raster):
        tex = texture.clone().requires_grad_(True)
        out = gen(verts, c2w, k, texture=tex, plane_raster=given)
        (out["rgb"] * torch.linspace(0, 1, 32)).sum().backward()
        renders.append(out["rgb"].detach())
        grads.append(tex.grad)
    assert raster.reads is not None and raster.reads.res == TINY.texture_res
    torch.testing.assert_close(renders[1], renders[0], atol=1e-6, rtol=1e-6)
    torch.testing.assert_close(grads[1], grads[0], atol=1e-6, rtol=1e-5)
    assert grads[0].abs().sum() > 0
    calls = []
    monkeypatch.setattr(generator, "rasterize_planes",
                        lambda *a, **kw: calls.append(1) or pytest.fail("rasterized"))
    with torch.no_grad():
        gen(verts, c2w, k, texture=texture, plane_raster=raster)
    assert not calls


@pytest.mark.parametrize("cull", [True, False])
def test_kept_view_rays_render_the_same_without_rasterizing(parts, rastered, monkeypatch,
                                                            cull):
    """A texture inversion's fixed camera: the rays kept from the first render give the
    same images and texture gradients, bit for bit, and the screen is not rasterized
    again; hair, jitter or reuse with kept rays are refused."""
    import head360cli.model.generator as generator

    _, verts, c2w, k = parts
    gen, texture, raster = rastered
    gen.cull_rays = cull
    kept: dict = {}
    renders, grads = [], []
    try:
        for view_rays in (None, kept, kept):
            if view_rays is kept and kept:  # the third render: from the kept rays alone
                monkeypatch.setattr(generator, "screen_depth",
                                    lambda *a, **kw: pytest.fail("rasterized the screen"))
                monkeypatch.setattr(generator, "samples_around",
                                    lambda *a, **kw: pytest.fail("sampled the rays"))
            tex = (texture + 0.1 * len(renders)).requires_grad_(True)
            out = gen(verts, c2w, k, texture=tex, plane_raster=raster, view_rays=view_rays)
            (out["rgb"] * torch.linspace(0, 1, 32)).sum().backward()
            renders.append(out["rgb"].detach())
            grads.append(tex.grad)
            assert not view_rays or {"depth", "points", "depths", "near"} <= set(view_rays)
        monkeypatch.undo()
        tex = (texture + 0.2).requires_grad_(True)  # the third texture, rays made afresh
        out = gen(verts, c2w, k, texture=tex, plane_raster=raster)
        (out["rgb"] * torch.linspace(0, 1, 32)).sum().backward()
        assert torch.equal(renders[2], out["rgb"].detach())
        assert torch.equal(grads[2], tex.grad)
        assert torch.equal(renders[1], gen(verts, c2w, k, texture=texture + 0.1,
                                           plane_raster=raster)["rgb"].detach())
        assert not torch.equal(renders[1], renders[2])  # the texture did change them
        with pytest.raises(ValueError, match="kept rays"):
            gen(verts, c2w, k, texture=texture, view_rays={}, jitter=True)
    finally:
        gen.cull_rays = True


def test_config_round_trip_and_checks():
    cfg = dataclasses.replace(TINY, plane_centre=(0.0, 0.1, 0.0))
    assert GeneratorConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ValueError, match="unknown"):
        GeneratorConfig.from_dict({"bogus": 1})
    model = load_bilinear()
    with pytest.raises(ValueError, match="power of two"):
        Generator(dataclasses.replace(TINY, texture_res=24), model.faces, model.uv,
                  model.faces_uv)
    with pytest.raises(ValueError, match="hex or tri"):
        Generator(dataclasses.replace(TINY, planes="quad"), model.faces, model.uv,
                  model.faces_uv)


def test_loading_weights_errors(tmp_path):
    from head360cli.model.train import load_generator

    with pytest.raises(ModelNotFoundError, match="head360 train"):
        load_generator(tmp_path / "none.pt")
    (tmp_path / "bad.pt").write_bytes(b"not torch")
    with pytest.raises(FileFormatError):
        load_generator(tmp_path / "bad.pt")
    torch.save({"format": "other"}, tmp_path / "other.pt")
    with pytest.raises(FileFormatError):
        load_generator(tmp_path / "other.pt")


@pytest.fixture(scope="module")
def hair(parts):
    from head360cli.model.generator import hair_for

    _, verts, _, _ = parts
    neutral = verts[0].numpy()
    return hair_for(neutral, [17, 0], [[0.2, 0.1, 0.05], [0.5, 0.5, 0.5]])


def test_hair_branch_adds_hair_and_skips_bald_items(parts, hair):
    from head360cli.model.generator import Hair

    model, verts, c2w, k = parts
    torch.manual_seed(0)
    gen = Generator(TINY, model.faces, model.uv, model.faces_uv)
    assert hair.meshes[1] is None  # style 0 is bald: no mesh, no hair branch
    code = torch.zeros(2, TINY.code_dim)
    out = gen(verts, c2w, k, code=code, hair=hair)
    assert out["hair_alpha"].shape == (2, 1, 32, 32) and torch.isfinite(out["rgb"]).all()
    # Long hair covers the top of the frontal view's head, and nothing of the bald one.
    assert out["hair_alpha_low"][0, 0, 2:5, 6:10].mean() > 0.3
    assert out["hair_alpha"][1].abs().max() == 0
    # A bald item renders exactly as without any hair.
    bald = gen(verts, c2w, k, code=code)
    assert torch.allclose(out["rgb"][1], bald["rgb"][1], atol=1e-6)
    assert not torch.allclose(out["rgb"][0], bald["rgb"][0], atol=1e-3)
    # Nothing is learnt from nowhere: gradients reach the hair embedding and decoder.
    out["rgb"].mean().backward()
    assert gen.hair_texture_generator.embedding.weight.grad[17].abs().sum() > 0
    assert gen.hair_texture_generator.embedding.weight.grad[3].abs().sum() == 0
    assert all(p.grad is not None for p in gen.hair_decoder.parameters())
    none = Hair([None, None], hair.style, hair.colour)
    with torch.no_grad():  # both renders without gradients: the same decoder path
        assert torch.equal(gen(verts, c2w, k, code=code, hair=none)["rgb"],
                           gen(verts, c2w, k, code=code)["rgb"])


def test_a_generator_without_hair_refuses_hair(parts, hair):
    model, verts, c2w, k = parts
    gen = Generator(dataclasses.replace(TINY, hair=False), model.faces, model.uv,
                    model.faces_uv)
    assert not hasattr(gen, "hair_decoder")
    with pytest.raises(ValueError, match="without a hair branch"):
        gen(verts, c2w, k, code=torch.zeros(2, TINY.code_dim), hair=hair)


def test_culling_far_rays_changes_nothing(parts, hair):
    """Decoding only the rays near a surface gives the same image as decoding all, and
    the same gradients."""
    from head360cli.model.generator import Hair, near_rays

    near = torch.tensor([[0.0, 1.0, 0.0, 1.0], [1.0, 0.0, 0.0, 0.0]])
    order, kept = near_rays(near)
    assert order.tolist() == [[1, 3], [0, 1]]
    assert kept.tolist() == [[True, True], [True, False]]
    order, kept = near_rays(near[:1])  # one item: nonzero, ray 0 always included
    assert order.tolist() == [[0, 1, 3]] and kept.tolist() == [[False, True, True]]
    order, kept = near_rays(torch.zeros(1, 4))
    assert order.tolist() == [[0]] and kept.tolist() == [[False]]
    model, verts, c2w, k = parts
    torch.manual_seed(0)
    gen = Generator(TINY, model.faces, model.uv, model.faces_uv)
    outs, grads = {}, {}
    for cull in (False, True):
        gen.cull_rays = cull
        code = torch.linspace(-1, 1, 2 * TINY.code_dim).view(2, -1).requires_grad_(True)
        outs[cull] = gen(verts, c2w, k, code=code, hair=hair)
        outs[cull]["rgb"].mean().backward()
        grads[cull] = code.grad
    for key in ("rgb", "alpha", "hair_alpha", "depth_low"):
        torch.testing.assert_close(outs[True][key], outs[False][key], atol=1e-6, rtol=0)
    torch.testing.assert_close(grads[True], grads[False], atol=1e-7, rtol=1e-4)
    first = Hair(hair.meshes[:1], hair.style[:1], hair.colour[:1])
    with torch.no_grad():  # one-item batches take the nonzero path
        one = {}
        for cull in (False, True):
            gen.cull_rays = cull
            one[cull] = gen(verts[:1], c2w[:1], k, code=code[:1].detach(),
                            hair=first)["rgb"]
    torch.testing.assert_close(one[True], one[False], atol=1e-6, rtol=0)


@pytest.mark.parametrize("cull", [True, False])
def test_items_sharing_hair_render_as_one_by_one(parts, hair, cull):
    """Frames of one head share its hair (``Hair.repeat``): they are drawn and decoded
    together, and each comes out as when rendered alone; with two hairs and a bald item
    in one batch as well."""
    from head360cli.model.generator import Hair, _hair_groups

    model, verts, c2w, k = parts
    torch.manual_seed(0)
    gen = Generator(TINY, model.faces, model.uv, model.faces_uv)
    gen.cull_rays = gen.hair_rays_only = cull
    one = gen.prepare_hair(Hair(hair.meshes[:1], hair.style[:1], hair.colour[:1]))
    # the same mesh with other planes (an untrained hair texture barely shows a colour)
    other = dataclasses.replace(one, planes=[one.planes[0] * 2.0 + 0.5])
    cams = torch.cat([c2w, c2w[:1]])  # three views
    v3 = torch.cat([verts, verts[:1]])
    code = torch.linspace(-1, 1, 3 * TINY.code_dim).view(3, -1)
    mixed = Hair([one.meshes[0], None, other.meshes[0], one.meshes[0]],
                 torch.tensor([17, 0, 17, 17]), torch.zeros(4, 3),
                 [one.planes[0], None, other.planes[0], one.planes[0]])
    assert _hair_groups(one.repeat(3), [0, 1, 2]) == [[0, 1, 2]]
    assert _hair_groups(mixed, [0, 2, 3]) == [[0, 3], [2]]
    with torch.no_grad():
        together = gen(v3, cams, k, code=code, hair=one.repeat(3))
        alone = [gen(v3[i:i + 1], cams[i:i + 1], k, code=code[i:i + 1], hair=one)
                 for i in range(3)]
        assert together["hair_alpha"][:2].amax() > 0.3  # the hair is there
        for key in ("rgb", "hair_alpha", "depth_low"):
            torch.testing.assert_close(together[key], torch.cat([a[key] for a in alone]),
                                       atol=1e-5, rtol=0)
        v4, c4 = torch.cat([v3, verts[:1]]), torch.cat([cams, c2w[:1]])
        code4 = torch.cat([code, code[:1]])
        out = gen(v4, c4, k, code=code4, hair=mixed)
        bald = gen(v4[1:2], c4[1:2], k, code=code4[1:2])
        last = gen(v4[2:3], c4[2:3], k, code=code4[2:3], hair=other)
        torch.testing.assert_close(out["rgb"][0], alone[0]["rgb"][0], atol=1e-5, rtol=0)
        torch.testing.assert_close(out["rgb"][3], alone[0]["rgb"][0], atol=1e-5, rtol=0)
        torch.testing.assert_close(out["rgb"][1], bald["rgb"][0], atol=1e-5, rtol=0)
        torch.testing.assert_close(out["rgb"][2], last["rgb"][0], atol=1e-5, rtol=0)
        wrong = gen(v4[2:3], c4[2:3], k, code=code4[2:3], hair=one)  # the first planes'
        assert (out["rgb"][2] - wrong["rgb"][0]).abs().max() > 1e-3


def test_samples_per_ray_is_scoped(parts):
    model = parts[0]
    gen = Generator(TINY, model.faces, model.uv, model.faces_uv)
    with gen.samples_per_ray(2):
        assert gen.cfg.samples == 2
    assert gen.cfg == TINY
    with pytest.raises(RuntimeError), gen.samples_per_ray(3):
        raise RuntimeError("boom")
    assert gen.cfg == TINY
    with gen.samples_per_ray(None):
        assert gen.cfg == TINY


def test_decoders_run_by_onednn_see_whole_blocks_of_points(parts, hair, monkeypatch):
    """Under bfloat16 on a CPU, and in float32 renders on a CPU, the decoders get their
    points padded to DECODE_BLOCK (one oneDNN primitive per shape, so few shapes), and
    the padding changes no pixel's value beyond bfloat16's rounding."""
    from head360cli.model import generator as generator_module
    from head360cli.model import networks

    model, verts, c2w, k = parts
    torch.manual_seed(0)
    gen = Generator(TINY, model.faces, model.uv, model.faces_uv).eval()
    gen.network_dtype = torch.bfloat16
    seen = []
    for net in (gen.decoder, gen.hair_decoder):
        net.register_forward_pre_hook(lambda _m, args: seen.append(args[0].shape[1]))
    code = torch.zeros(2, TINY.code_dim)
    with torch.no_grad():
        padded = gen(verts, c2w, k, code=code, hair=hair)["rgb"]
        assert seen and all(n % generator_module.DECODE_BLOCK == 0 for n in seen)
        monkeypatch.setattr(generator_module, "DECODE_BLOCK", 1)  # no padding
        seen.clear()
        plain = gen(verts, c2w, k, code=code, hair=hair)["rgb"]
    assert any(n % 4096 for n in seen)  # the tiny frames decode fewer points than a block
    torch.testing.assert_close(padded, plain, atol=2e-2, rtol=0)
    monkeypatch.setattr(generator_module, "DECODE_BLOCK", 4096)
    gen.network_dtype = None
    seen.clear()
    with torch.no_grad():
        gen(verts, c2w, k, code=code, hair=hair)
    # float32 renders run oneDNN's linear op too where torch has it: padded as well
    assert all(n % 4096 == 0 for n in seen) == networks._HAS_CPU_LINEAR
    seen.clear()
    gen(verts, c2w, k, code=code, hair=hair)  # with gradients (training): not padded
    assert any(n % 4096 for n in seen)


def test_a_sparse_texture_change_gives_the_planes_of_the_changed_texture(parts, rastered):
    """Planes of a texture plus a change on a few texels, made by adding the change where
    the planes read those texels, equal the changed texture's planes, with the same
    gradients; rendered through ``head_planes``, so do the images."""
    from head360cli.model.planes import add_texture_change, reading_pixels, texture_planes

    _, verts, c2w, k = parts
    gen, texture, raster = rastered
    texels = torch.zeros(16, 16, dtype=torch.bool)
    texels[5:9, 3:12] = True
    at = reading_pixels(raster, texels)
    assert 0 < len(at) < raster.mask.sum()
    for batch in (1, 2):  # one change for every item, or one per item
        change = (torch.randn(batch, TINY.texture_channels, 16, 16) * texels
                  ).requires_grad_(True)
        dense = texture_planes(texture + change, raster)
        sparse = add_texture_change(texture_planes(texture, raster), change, raster, at)
        torch.testing.assert_close(sparse, dense, atol=1e-5, rtol=1e-5)
        weights = torch.randn_like(dense)
        g_dense, = torch.autograd.grad((dense * weights).sum(), change)
        g_sparse, = torch.autograd.grad((sparse * weights).sum(), change)
        torch.testing.assert_close(g_sparse * texels, g_dense * texels, atol=1e-5,
                                   rtol=1e-5)
    with torch.no_grad():
        a = gen(verts, c2w, k, texture=texture + change.detach())
        b = gen(verts, c2w, k, head_planes=sparse.detach())
    torch.testing.assert_close(a["rgb"], b["rgb"], atol=1e-5, rtol=1e-5)


def test_soft_hair_is_the_configs_and_older_weights_have_stepped_hair(parts):
    """A generator trained on soft hairlines gets them at run time; a configuration
    saved before the setting existed reads as stepped."""
    import numpy as np

    from head360cli.model.generator import hair_for
    from head360cli.synth.hair import fit_hair

    saved = dataclasses.asdict(GeneratorConfig())
    saved.pop("soft_hair")
    assert GeneratorConfig.from_dict(saved).soft_hair is False
    neutral = parts[1][0].numpy()
    for soft in (False, True):
        verts = hair_for(neutral, [17], [[0.2, 0.1, 0.05]], soft=soft).meshes[0][0].numpy()
        expected = fit_hair(neutral, 17, soft=soft).verts
        np.testing.assert_allclose(verts, expected, atol=1e-6)
    assert not np.allclose(fit_hair(neutral, 17).verts, fit_hair(neutral, 17, soft=True).verts)

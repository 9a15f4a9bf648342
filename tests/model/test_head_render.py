"""HeadRenderer: blendshapes, cached hair planes, reduced precision, image size."""

from __future__ import annotations

import numpy as np
import pytest
import torch


@pytest.fixture(scope="module")
def renderer(head_file):
    from head360cli.fitting.pipeline import load_head_renderer

    return load_head_renderer(head_file, samples=4, size=64, precision="fp32")


def test_vertices_are_the_bilinear_model_linear_in_the_weights(renderer):
    rng = np.random.default_rng(0)
    w = rng.uniform(0, 1, (3, 52))
    v = renderer.vertices(w).numpy()
    for i in range(3):
        np.testing.assert_allclose(v[i], renderer.model.vertices(renderer.shape, w[i]),
                                   atol=2e-6)
    assert renderer.vertices(w[0]).shape == v.shape[1:]


def test_cached_hair_planes_give_the_same_image(renderer):
    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.model.generator import Hair

    gen = renderer.gen
    cams = view_cameras(np.array([0.0, 120.0]), 0.0)
    k = view_intrinsics(64)
    h = renderer.hair.repeat(2)
    fresh = Hair(h.meshes, h.style, h.colour)  # no planes: made inside the call
    verts = renderer.vertices(np.zeros((2, 52)))
    tex = renderer.texture.expand(2, -1, -1, -1)
    with torch.no_grad(), gen.samples_per_ray(4), gen.image_size(64):
        a = gen(verts, cams, k, texture=tex, hair=h)["rgb"]
        b = gen(verts, cams, k, texture=tex, hair=fresh)["rgb"]
    torch.testing.assert_close(a, b, atol=1e-6, rtol=0)


def test_hair_rays_only_is_a_close_approximation(renderer):
    from head360cli.drive.views import view_cameras, view_intrinsics

    gen = renderer.gen
    cams = view_cameras(np.array([0.0, 90.0, 200.0]), np.array([0.0, 10.0, -10.0]))
    k = view_intrinsics(64)
    w = np.zeros((3, 52))
    a = renderer.render(cams, k, w)
    gen.hair_rays_only = False
    try:
        b = renderer.render(cams, k, w)
    finally:
        gen.hair_rays_only = True
    assert (a - b).abs().max() < 2e-3


def test_bfloat16_networks_stay_close_to_float32(head_file):
    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.fitting.pipeline import load_head_renderer

    cams = view_cameras(np.array([0.0, 45.0]), 0.0)
    k = view_intrinsics(64)
    imgs = {p: load_head_renderer(head_file, samples=4, size=64, precision=p).render(
        cams, k) for p in ("fp32", "bf16")}
    mse = float(((imgs["fp32"] - imgs["bf16"]) ** 2).mean())
    assert 10 * np.log10(1 / mse) > 45  # measured 70.8 dB at 256 px, 12 samples
    assert (imgs["fp32"] - imgs["bf16"]).abs().max() < 0.05


def test_image_size_is_scoped_and_checked(renderer):
    gen = renderer.gen
    ratio = gen.cfg.image_res // gen.cfg.render_res  # the low-resolution copies keep it
    with gen.image_size(96):
        assert (gen.cfg.image_res, gen.cfg.render_res) == (96, 96 // ratio)
    assert gen.cfg.image_res == 256
    for bad in (97, 8):
        with pytest.raises(ValueError, match="multiple of 2"):
            gen.image_size(bad)


def test_hair_offset_moves_every_style_and_old_files_have_none(head_file, tmp_path):
    """A head file's ``hair_offset`` (a fit's hair placement) moves the hair mesh by
    exactly that, for a swapped style too; a file without one (older fits, sampled
    heads) wears the hair where the style's fit puts it."""
    from head360cli.fitting.pipeline import load_head_renderer
    from head360cli.io.headfile import read_head, write_head

    plain = load_head_renderer(head_file, samples=4, size=64, precision="fp32")
    assert not plain.hair_offset.any()
    head = read_head(head_file)
    head.arrays["hair_offset"] = np.array([0.0, 0.006, -0.003], np.float32)
    moved_file = write_head(head, tmp_path / "moved.h360")
    moved = load_head_renderer(moved_file, samples=4, size=64, precision="fp32")
    for a, b in ((plain, moved), (plain.with_hair(11, plain.hair_colour),
                                  moved.with_hair(11, moved.hair_colour))):
        va, fa, _ = a.hair.meshes[0]
        vb, fb, _ = b.hair.meshes[0]
        assert torch.equal(fa, fb)
        torch.testing.assert_close(vb - va, torch.tensor([[0.0, 0.006, -0.003]]).expand_as(va),
                                   atol=1e-6, rtol=0)


def test_hair_scale_shapes_the_fitted_style_only(head_file, tmp_path):
    """A head file's ``hair_scale`` (a fit's thickness by direction) and
    ``hair_end_shift`` (its length) shape the fitted style's mesh as
    :func:`~head360cli.synth.hair.fit_hair` does; another style put on wears its own
    shape, and malformed values are refused."""
    from head360cli.fitting.pipeline import load_head_renderer
    from head360cli.io.headfile import read_head, write_head
    from head360cli.model.head_render import HeadRenderer
    from head360cli.synth.hair import WARP_BINS, fit_hair

    head = read_head(head_file)
    style = int(head.arrays["hair_style"])
    scale = np.linspace(0.5, 2.0, WARP_BINS).astype(np.float32)
    head.arrays["hair_scale"] = scale
    shaped = load_head_renderer(write_head(head, tmp_path / "shaped.h360"), samples=4,
                                size=64, precision="fp32")
    plain = load_head_renderer(head_file, samples=4, size=64, precision="fp32")
    assert plain.hair_scale is None
    want = fit_hair(shaped.neutral, style, soft=True, scale=scale).verts
    np.testing.assert_allclose(shaped.hair.meshes[0][0].numpy(),
                               want + shaped.hair_offset, atol=1e-6)
    assert not np.allclose(shaped.hair.meshes[0][0].numpy(), plain.hair.meshes[0][0].numpy(),
                           atol=1e-4)
    other = (style % 29) + 1
    np.testing.assert_array_equal(shaped.with_hair(other, shaped.hair_colour).hair.meshes[0][0],
                                  plain.with_hair(other, plain.hair_colour).hair.meshes[0][0])
    for bad in (scale[:5], np.zeros(WARP_BINS)):
        with pytest.raises(ValueError, match=f"expected a hair scale of {WARP_BINS}"):
            HeadRenderer(shaped.gen, shaped.shape, shaped.texture[0], style,
                         shaped.hair_colour, size=64, hair_scale=bad)
    # the ends moved up by the fit's end shift: the style's own, as the scale
    head.arrays["hair_end_shift"] = np.array(-0.03, np.float32)
    raised = load_head_renderer(write_head(head, tmp_path / "raised.h360"), samples=4,
                                size=64, precision="fp32")
    want = fit_hair(raised.neutral, style, soft=True, scale=scale, end_shift=-0.03).verts
    np.testing.assert_allclose(raised.hair.meshes[0][0].numpy(),
                               want + raised.hair_offset, atol=1e-6)
    np.testing.assert_array_equal(raised.with_hair(other, raised.hair_colour).hair.meshes[0][0],
                                  plain.with_hair(other, plain.hair_colour).hair.meshes[0][0])
    with pytest.raises(ValueError, match="expected a hair end shift of one number"):
        HeadRenderer(shaped.gen, shaped.shape, shaped.texture[0], style,
                     shaped.hair_colour, size=64, hair_end_shift=[0.0, 0.1])


def test_the_deferred_generator_wears_soft_hairlines(renderer):
    """Whatever corpus it learnt, the deferred generator's run-time hair is the style's
    soft mesh (hairlines between grid rows), with the stepped mesh's strand UVs; a
    hex-plane generator keeps its corpus's kind."""
    from head360cli.model.generator import Generator
    from head360cli.synth.hair import fit_hair

    assert renderer.gen.kind == "deferred" and renderer.gen.soft_hairlines
    assert not renderer.gen.cfg.soft_hair  # the shipped weights learnt stepped hair
    neutral = renderer.neutral[0] if renderer.neutral.ndim == 3 else renderer.neutral
    soft = fit_hair(np.asarray(neutral), renderer.hair_style, soft=True)
    stepped = fit_hair(np.asarray(neutral), renderer.hair_style)
    verts, faces, _ = renderer.hair.meshes[0]
    np.testing.assert_allclose(verts.cpu().numpy(), soft.verts, atol=1e-6)
    np.testing.assert_array_equal(faces.cpu().numpy(), soft.faces)
    assert not np.allclose(soft.verts, stepped.verts, atol=1e-4)
    assert Generator.soft_hairlines.fget(renderer.gen) is False  # the hex-plane's rule


def test_a_malformed_hair_offset_is_refused(renderer):
    from head360cli.model.head_render import HeadRenderer

    for bad in ([0.0, 0.01], [0.0, np.nan, 0.0]):
        with pytest.raises(ValueError, match="expected a hair offset of 3 finite numbers"):
            HeadRenderer(renderer.gen, renderer.shape, renderer.texture[0], 1,
                         renderer.hair_colour, size=64, hair_offset=bad)


def test_frames_drive_the_eyes_from_the_heads_own(renderer):
    """Given weights move the eyes from the head's own openness (a fit's), the mouth and
    the rest as given; no weights give the own expression as it is."""
    from head360cli.io.headfile import driven_weights
    from head360cli.mesh.arkit52 import INDEX
    from head360cli.model.head_render import HeadRenderer

    own = np.zeros(52)
    own[[INDEX["eyeBlinkLeft"], INDEX["eyeWideRight"], INDEX["jawOpen"]]] = 0.6, 0.4, 0.5
    r = HeadRenderer(renderer.gen, renderer.shape, renderer.texture[0], 0, np.zeros(3),
                     own, samples=4, size=64, precision="fp32")
    model = renderer.model
    np.testing.assert_allclose(r.vertices().numpy(), model.vertices(r.shape, own), atol=2e-6)
    eyes = own.copy()
    eyes[INDEX["jawOpen"]] = 0.0
    np.testing.assert_allclose(r.vertices(np.zeros(52)).numpy(),
                               model.vertices(r.shape, eyes), atol=2e-6)
    w = np.zeros((2, 52))
    w[1, [INDEX["eyeBlinkLeft"], INDEX["eyeBlinkRight"], INDEX["jawOpen"]]] = 1.0
    np.testing.assert_allclose(r.vertices(w).numpy()[1],
                               model.vertices(r.shape, w[1]), atol=2e-6)  # closed: as given
    from head360cli.drive.views import view_cameras, view_intrinsics

    cam, k = view_cameras(0.0, 0.0), view_intrinsics(64)
    np.testing.assert_array_equal(  # render (driving) == frames of the driven weights as own
        r.render(cam, k, w[1]).numpy(),
        next(r.frames(cam, driven_weights(w[1:], own), k, uint8=False, drive=False)).numpy())


def test_driven_deltas_are_the_exported_morph_targets(renderer):
    """An exported mesh's base plus its morph targets gives the renderer's own meshes:
    the template's deltas for open own eyes, and for a head with half-closed eyes a full
    blink ends at the closed eye (not beyond it)."""
    from head360cli.mesh.arkit52 import INDEX
    from head360cli.model.head_render import HeadRenderer

    np.testing.assert_allclose(renderer.driven_deltas(), renderer.deltas, atol=1e-12)
    own = np.zeros(52)
    own[[INDEX["eyeBlinkLeft"], INDEX["eyeSquintLeft"], INDEX["eyeWideRight"]]] = \
        0.6, 0.3, 0.4
    r = HeadRenderer(renderer.gen, renderer.shape, renderer.texture[0], 0, np.zeros(3),
                     own, samples=4, size=64, precision="fp32")
    base = r.vertices(np.zeros(52)).numpy().astype(np.float64)
    targets = r.driven_deltas()
    rng = np.random.default_rng(1)
    w = rng.uniform(0, 1, (3, 52)) * (rng.uniform(0, 1, (3, 52)) < 0.3)
    w[:, [INDEX["eyeSquintRight"], INDEX["eyeWideLeft"], INDEX["eyeSquintLeft"],
          INDEX["eyeWideRight"]]] = 0  # away from the cap at 1
    w[0, [INDEX["eyeBlinkLeft"], INDEX["eyeBlinkRight"]]] = 1.0
    got = base + np.tensordot(w, targets, 1)
    np.testing.assert_allclose(got, r.vertices(w).numpy(), atol=2e-5)
    closed = np.zeros(52)
    closed[[INDEX["eyeBlinkLeft"], INDEX["eyeBlinkRight"]]] = 1.0
    np.testing.assert_allclose(got[0] - np.tensordot(w[0] - closed, targets, 1),
                               r.model.vertices(r.shape, closed), atol=2e-5)


def test_frames_check_their_inputs_before_rendering(renderer):
    """Shapes, counts and finiteness are checked at the library's rendering entry; before,
    a third row of weights was ignored, NaN weights rendered, and (N, 51) weights or numpy
    cameras failed deep inside with torch's or numpy's own messages."""
    from head360cli.drive.views import view_cameras, view_intrinsics

    cams, k = view_cameras([0.0, 30.0], 0.0), view_intrinsics(64)
    w = np.zeros((2, 52))
    bad = [
        ((cams, np.zeros((3, 52)), k), r"weights of shape \(2, 52\).*found \(3, 52\)"),
        ((cams, np.zeros((2, 51)), k), r"found \(2, 51\)"),
        ((cams, np.zeros(52), k), r"found \(52,\)"),
        ((cams, np.full((2, 52), np.nan), k), "finite ARKit weights"),
        ((cams[:, :3], w, k), r"cameras of shape \(N, 4, 4\), found \(2, 3, 4\)"),
        ((cams * float("inf"), w, k), "finite cameras"),
        ((cams, w, k[:2, :2]), r"intrinsics of shape \(3, 3\), found \(2, 2\)"),
    ]
    for args, message in bad:
        with pytest.raises(ValueError, match=message):
            next(renderer.frames(*args))
    # numpy cameras and intrinsics render as tensors do
    a = next(renderer.frames(cams[:1], w[:1], k))
    b = next(renderer.frames(cams[:1].numpy().astype(np.float64), w[:1], k.numpy()))
    assert a.shape == (1, 64, 64, 3) and np.array_equal(a, b)


def test_zero_size_or_samples_is_refused_not_taken_for_the_default(head_file):
    """``size=0`` and ``samples=0`` meant "the generator's own" (``size or default``);
    they are refused as other impossible values are."""
    from head360cli.fitting.pipeline import load_head_renderer

    with pytest.raises(ValueError, match="multiple of 2 and at least 16, found 0"):
        load_head_renderer(head_file, size=0)
    for samples in (0, -2, 2.5, 3):  # a deferred generator: 1, 2 or 4 a pixel
        with pytest.raises(ValueError, match=f"1, 2 or 4 samples a pixel or None, found "
                                             f"{samples}"):
            load_head_renderer(head_file, samples=samples)
    r = load_head_renderer(head_file, samples=np.int64(4), size=None)
    assert (r.samples, r.size) == (4, r.gen.cfg.image_res)


def _lit_copy(r, gain):
    from head360cli.model.head_render import HeadRenderer

    return HeadRenderer(r.gen, r.shape, r.texture[0], r.hair_style, r.hair_colour,
                        samples=4, size=64, precision="fp32", colour_gain=gain)


def test_a_heads_light_scales_its_pixels_and_leaves_the_backdrop_white(renderer):
    """``colour_gain`` (a fit's light): the green channel, at gain 1, is unchanged, red
    (0.6) darker and blue (1.4) lighter wherever the head is, and the backdrop stays
    white (but for a few pixels at the silhouette, where the RefineNet's white and its
    coverage disagree: 0.26 % of them moved by more than 1e-3 here, at most 0.23); a
    gain of 1 everywhere is no light at all."""
    from head360cli.drive.views import view_cameras, view_intrinsics

    cam, k = view_cameras(30.0, 0.0), view_intrinsics(64)
    plain = renderer.render(cam, k).numpy()[0]
    lit = _lit_copy(renderer, [0.6, 1.0, 1.4]).render(cam, k).numpy()[0]
    backdrop = plain.min(axis=0) > 0.999
    assert 0.3 < backdrop.mean() < 0.9
    assert (np.abs(lit - plain).max(axis=0)[backdrop] < 1e-3).mean() > 0.99
    np.testing.assert_allclose(lit[1], plain[1], atol=1e-6)
    head = plain.max(axis=0) < 0.9  # opaque enough to show the light
    assert head.mean() > 0.05
    assert (lit[0][head] < plain[0][head] - 0.02).mean() > 0.99  # 0.998 measured
    assert (lit[2][head] > plain[2][head]).mean() > 0.99  # 0.999
    assert _lit_copy(renderer, [1.0, 1.0, 1.0]).colour_gain is None


def test_a_heads_light_is_read_from_its_file_and_kept_by_a_hairstyle(head_file, tmp_path):
    from head360cli.fitting.pipeline import load_head_renderer
    from head360cli.io.headfile import read_head, write_head

    assert load_head_renderer(head_file, samples=4, size=64).colour_gain is None
    head = read_head(head_file)
    head.arrays["colour_gain"] = np.array([0.8, 1.0, 1.25], np.float32)
    r = load_head_renderer(write_head(head, tmp_path / "lit.h360"), samples=4, size=64)
    np.testing.assert_allclose(r.colour_gain.flatten().numpy(), [0.8, 1.0, 1.25])
    assert torch.equal(r.with_hair(9, r.hair_colour).colour_gain, r.colour_gain)


def test_a_malformed_light_is_refused(renderer):
    for bad in ([1.0, 1.0], [1.0, np.nan, 1.0], [1.0, 0.0, 1.0], [1.0, -1.0, 1.0]):
        with pytest.raises(ValueError, match="expected a colour gain of 3 positive finite"):
            _lit_copy(renderer, bad)


def test_render_gives_the_head_s_coverage_with_the_same_images(renderer):
    from head360cli.drive.views import view_cameras, view_intrinsics

    cams = view_cameras([0.0, 90.0], 0.0)
    k = view_intrinsics(renderer.size)
    plain = renderer.render(cams, k)
    rgb, alpha = renderer.render(cams, k, alpha=True)
    assert torch.equal(rgb, plain)
    assert alpha.shape == (2, 1, renderer.size, renderer.size)
    assert float(alpha.min()) >= 0.0 and float(alpha.max()) <= 1.0
    assert 0.1 < float((alpha > 0.5).float().mean()) < 0.9  # a head, and room around it
    off = (1.0 - rgb.permute(0, 2, 3, 1)[alpha[:, 0] < 0.01]).abs()
    assert float(off.mean()) < 0.01 and float(off.quantile(0.99)) < 0.1  # white


def test_render_gives_the_hair_s_coverage_inside_the_head_s(renderer):
    """The hair's coverage: within the head's, part of it from the front, nearly all of it
    from behind, none when the hair is left out; the images are a plain render's."""
    from head360cli.drive.views import view_cameras, view_intrinsics

    cams = view_cameras([0.0, 180.0], 0.0)
    k = view_intrinsics(renderer.size)
    rgb, alpha, hair = renderer.render(cams, k, alpha=True, hair_alpha=True)
    assert torch.equal(rgb, renderer.render(cams, k))
    assert hair.shape == alpha.shape and float(hair.min()) >= 0.0
    # the head's coverage is the image network's, the hair's the rasterizer's: measured
    # at most 0.0056 over
    assert bool((hair <= alpha + 0.01).all())
    # the hair's share of the head: measured 0.42 from the front (the face shows), 0.96
    # from behind
    front, back = ((hair > 0.5).sum((1, 2, 3)) / (alpha > 0.5).sum((1, 2, 3))).tolist()
    assert 0.3 < front < 0.55 and back > 0.9
    _, _, bald = renderer.render(cams, k, hair=False, hair_alpha=True)
    assert float(bald.max()) == 0.0

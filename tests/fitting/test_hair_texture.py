"""The hair's detail texture from the photo: its ratio, the patches, the projection, the
seam in u, and how the renderer wears it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from head360cli.fitting.hair_texture import (
    MAX_DETAIL,
    hair_detail,
    hair_ratio,
    project_hair,
    quilt_hair,
)


def _striped(size: int = 96) -> tuple[np.ndarray, np.ndarray]:
    """A ratio image whose hair (a disc) has vertical stripes of 0.5 and 2, with a
    background of 3.5 outside it, and the disc."""
    yy, xx = np.mgrid[:size, :size]
    hair = (yy - size / 2) ** 2 + (xx - size / 2) ** 2 < (0.45 * size) ** 2
    ratio = np.where((xx // 3) % 2 == 0, 0.5, 2.0)[..., None].repeat(3, -1)
    ratio = np.where(hair[..., None], ratio, 3.5).astype(np.float32)
    return ratio, hair


def test_the_ratio_is_the_hair_over_its_median_without_the_light():
    rng = np.random.default_rng(0)
    crop = rng.integers(0, 256, (40, 40, 3), dtype=np.uint8)
    hair = np.zeros((40, 40), bool)
    hair[5:30, 5:30] = True
    ratio = hair_ratio(crop, hair)
    np.testing.assert_allclose(np.median(ratio[hair], 0), 1.0, atol=0.02)
    assert ratio.max() <= MAX_DETAIL and ratio.min() >= 0
    # a light twice as bright in red is divided out: the ratio, a relative value, is the
    # same wherever the clip is not reached
    lit = hair_ratio(crop, hair, gain=np.array([2.0, 1.0, 1.0]))
    inside = ratio < MAX_DETAIL / 2
    np.testing.assert_allclose(lit[inside], ratio[inside], rtol=1e-4, atol=1e-5)


def test_patches_come_from_the_hair_alone_and_keep_its_strands():
    ratio, hair = _striped()
    # no light to take out here: the stripes are finer than its blur
    quilt = quilt_hair(ratio, hair, size=64, seed=1)
    assert quilt.shape == (64, 64, 3)
    assert quilt.max() < 3.0  # none of the background's 3.5
    # the stripes run down the photo, so along v: rows vary far more than columns
    across = np.abs(np.diff(quilt[..., 0], axis=1)).mean()
    along = np.abs(np.diff(quilt[..., 0], axis=0)).mean()
    assert across > 4 * along
    # u wraps round the head: the first and last columns join as neighbours do
    seam = np.abs(quilt[:, 0, 0] - quilt[:, -1, 0]).mean()
    assert seam < 2 * across
    np.testing.assert_array_equal(quilt, quilt_hair(ratio, hair, size=64, seed=1))


def test_no_room_for_a_patch_gives_plain_colour():
    ratio, _ = _striped()
    hair = np.zeros(ratio.shape[:2], bool)
    hair[10:14, 10:14] = True
    np.testing.assert_array_equal(quilt_hair(ratio, hair, size=32), np.ones((32, 32, 3)))


def test_projected_pixels_land_in_their_texels_and_nowhere_else():
    size, res = 64, 32
    ratio = np.full((res, res, 3), 1.0, np.float32)
    ratio[:, :16] = 2.0  # the left half of the photo's hair is brighter
    hair = np.ones((res, res), bool)
    rows, cols = np.mgrid[:res, :res]
    pixels = np.stack([rows.ravel(), cols.ravel()], 1)
    # pixel (r, c) shows texel (c, r) of the left half of the texture, facing the camera
    uv = np.stack([(cols.ravel() + 0.5) / size, (rows.ravel() + 0.5) / size], 1)
    seen, share = project_hair(ratio, hair, uv, pixels, np.ones(res * res), size)
    np.testing.assert_allclose(seen[4:28, 2:10], 2.0, atol=1e-3)
    np.testing.assert_allclose(seen[4:28, 22:28], 1.0, atol=1e-3)
    assert (share[9:23, 9:23] > 0.99).all()  # feathered towards the edges
    assert (share[:, 48:] < 0.01).all()
    np.testing.assert_array_equal(seen[:, 48:], 1.0)
    # pixels the parse does not call hair, or that face away, write nothing
    seen, share = project_hair(ratio, np.zeros_like(hair), uv, pixels, np.ones(res * res),
                               size)
    assert share.max() == 0
    seen, share = project_hair(ratio, hair, uv, pixels, np.full(res * res, -0.5), size)
    assert share.max() == 0


def test_a_face_across_the_seam_in_u_reads_across_it():
    from head360cli.geometry.mesh_ops import seam_uv

    uv = torch.tensor([[0.9, 0.0], [0.05, 0.0], [0.9, 1.0], [0.3, 1.0], [0.5, 0.5]])
    faces = torch.tensor([[0, 1, 2], [1, 3, 4]])
    wrapped, faces_uv = seam_uv(faces, uv)
    assert wrapped.shape == (10, 2)
    corners = wrapped[faces_uv]
    np.testing.assert_allclose(corners[0, :, 0].numpy(), [0.9, 1.05, 0.9], atol=1e-6)
    np.testing.assert_array_equal(corners[1].numpy(), uv[faces[1]].numpy())


@pytest.fixture(scope="module")
def worn(head_file):
    from head360cli.fitting.pipeline import load_head_renderer

    return load_head_renderer(head_file, samples=1, size=96, precision="fp32")


def test_a_head_wears_the_detail_on_its_hair_alone(worn):
    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.model.deferred import with_hair_detail

    plain = worn.hair.planes[0]
    detail = np.full((128, 128, 3), 1.0, np.float32)
    detail[:, ::2] = 0.4  # fine strands across u
    worn.set_hair_detail(detail)
    try:
        tex = worn.hair.planes[0]
        assert tex.shape[-1] == 128
        colour = torch.as_tensor(worn.hair_colour, dtype=tex.dtype)
        np.testing.assert_allclose(tex[0, :3, 5, 5].numpy(), colour.clamp(0, 1).numpy(),
                                   atol=1e-6)
        np.testing.assert_allclose(tex[0, :3, 5, 4].numpy(),
                                   (0.4 * colour).clamp(0, 1).numpy(), atol=1e-6)
        again = with_hair_detail(plain, torch.as_tensor(detail).permute(2, 0, 1), colour)
        torch.testing.assert_close(again, tex)
        cams = view_cameras([0.0, 180.0], 0.0)
        k = view_intrinsics(96)
        rgb, hair = worn.render(cams, k, hair_alpha=True)[0::2]
        worn.set_hair_detail(None)
        rgb0, hair0 = worn.render(cams, k, hair_alpha=True)[0::2]
    finally:
        worn.set_hair_detail(None)
    torch.testing.assert_close(hair, hair0)  # the same shape
    # the screen network reaches two pixels from the hair: beyond that, no change
    far = (torch.nn.functional.max_pool2d(hair0, 5, 1, 2) == 0).expand_as(rgb)
    assert far.any()
    torch.testing.assert_close(rgb[far], rgb0[far], atol=1e-5, rtol=0)
    on_hair = (hair0 > 0.99).expand_as(rgb)
    assert (rgb - rgb0).abs()[on_hair].mean() > 0.02


def test_the_fitted_detail_shows_the_photo_where_it_sees_the_hair(worn):
    """A photo made by rendering the head with striped hair: the detail fitted from it
    holds the stripes' contrast where the photo sees the hair, and patches of it
    elsewhere."""
    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.model.head_render import to_uint8

    detail = np.full((128, 128, 3), 1.6, np.float32)
    detail[:, ::4] = 0.4
    detail[:, 1::4] = 0.4
    own = worn.hair_colour
    worn.set_hair(worn.hair_style, np.array([0.1, 0.06, 0.04]))  # dark: room for 1.6
    worn.set_hair_detail(detail)
    try:
        cams = view_cameras([0.0], 0.0)
        k = view_intrinsics(96)
        rgb, hair = worn.render(cams, k, hair_alpha=True)[0::2]
        photo = to_uint8(rgb)[0]
        parsed = hair[0, 0].numpy() > 0.99
        worn.set_hair_detail(None)
        verts = worn.vertices(worn.expression)
        fitted = hair_detail(worn.gen, verts, cams[0], k, worn.hair, photo, parsed,
                             size=128)
    finally:
        worn.set_hair_detail(None)
        worn.set_hair(worn.hair_style, own)
    assert fitted.shape == (128, 128, 3)
    assert 0.5 < float(fitted.mean()) < 2.0 and fitted.max() <= MAX_DETAIL
    assert np.quantile(fitted, 0.9) > 2 * np.quantile(fitted, 0.1)  # the stripes' contrast
    # columns of the texture the photo saw (the front, around u = 0.5) hold the
    # stripes: neighbouring columns differ as the stripes do
    rows = slice(10, 60)
    front = fitted[rows, 48:80, 1].mean(0)
    assert np.abs(np.diff(front)).mean() > 0.15


def test_light_hair_keeps_its_hue_where_the_detail_would_pass_white():
    """In a near-white colour a detail's highlights pass white: its range is narrowed
    (the hue stays the colour's, warm), and in a dark colour it is left as it is."""
    from head360cli.model.deferred import with_hair_detail

    rng = np.random.default_rng(0)
    detail = torch.as_tensor(rng.lognormal(0.3, 0.4, (3, 64, 64)).astype(np.float32))
    texture = torch.zeros(1, 16, 64, 64)
    light = torch.tensor([0.98, 0.95, 0.85])
    albedo = with_hair_detail(texture, detail, light)[0, :3]
    assert albedo.max() <= 1.0
    assert torch.quantile(albedo.amax(0).flatten(), 0.9) < 0.999  # narrowed, not capped
    mean = albedo.mean((1, 2))
    assert mean[0] > mean[1] > mean[2]  # warm, as the colour
    dark = torch.tensor([0.1, 0.06, 0.04])
    torch.testing.assert_close(with_hair_detail(texture, detail, dark)[0, :3],
                               (detail * dark[:, None, None]).clamp(max=1.0))

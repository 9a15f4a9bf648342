"""Closed eyelids: the lid texels, the closed lid's target and the refit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from head360cli.fitting.lids import LidConfig, close_lids, closed_lid_target
from head360cli.mesh.eyelids import blink_weights, lid_texels


def test_closed_lid_target_fills_each_lid_with_its_ring_and_a_lash_line():
    h, w = 40, 60
    open_rgb = np.zeros((3, h, w), np.float32)
    open_rgb[:, :, :30] = np.array([0.8, 0.6, 0.5])[:, None, None]  # skin left
    open_rgb[:, :, 30:] = np.array([0.4, 0.3, 0.2])[:, None, None]  # skin right
    closed_rgb = np.full((3, h, w), 0.1, np.float32)
    closed = np.zeros((h, w), bool)
    closed[10:20, 5:20] = True  # left lid
    closed[12:22, 38:55] = True  # right lid
    closed[0, 29] = True  # a one-pixel sliver: left alone
    open_lid = np.zeros((h, w), bool)
    cfg = LidConfig(shade=1.0, lash=0.5, lash_width=2)
    target = closed_lid_target(open_rgb, closed_rgb, open_lid, closed, cfg)
    np.testing.assert_allclose(target[:, 10:18, 5:20], np.broadcast_to(
        np.array([0.8, 0.6, 0.5])[:, None, None], (3, 8, 15)), atol=1e-6)
    np.testing.assert_allclose(target[:, 18:20, 5:20], np.broadcast_to(
        np.array([0.4, 0.3, 0.25])[:, None, None], (3, 2, 15)), atol=1e-6)
    np.testing.assert_allclose(target[:, 12:20, 38:55], np.broadcast_to(
        np.array([0.4, 0.3, 0.2])[:, None, None], (3, 8, 17)), atol=1e-6)
    np.testing.assert_allclose(target[:, 20:22, 38:55], 0.5 * target[:, 12:14, 38:55],
                               atol=1e-6)
    outside = ~closed
    outside[0, 29] = True
    np.testing.assert_array_equal(target[:, outside], closed_rgb[:, outside])


def test_the_ring_leaves_out_the_open_lid():
    h, w = 30, 30
    open_rgb = np.full((3, h, w), 0.5, np.float32)
    open_rgb[:, :10] = 0.0  # dark open lid above
    open_lid = np.zeros((h, w), bool)
    open_lid[:10] = True
    closed = np.zeros((h, w), bool)
    closed[10:20, 10:20] = True
    target = closed_lid_target(open_rgb, open_rgb, open_lid, closed,
                               LidConfig(shade=1.0, lash=1.0))
    np.testing.assert_allclose(target[:, closed], 0.5)
    shaded = closed_lid_target(open_rgb, open_rgb, open_lid, closed,
                               LidConfig(shade=0.7, lash=0.7))
    np.testing.assert_allclose(shaded[:, closed], 0.35)


def test_lid_texels_cover_the_moved_triangles_only():
    # two triangles side by side in UV: only the left one's vertices move
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    uv = np.array([[0.05, 0.05], [0.45, 0.05], [0.05, 0.45],
                   [0.55, 0.55], [0.95, 0.55], [0.55, 0.95]])
    moved = np.array([True, False, False, False, False, False])
    tex = lid_texels(faces, uv, faces, moved, 32, grow=0)
    assert tex[:16, :16].sum() > 50 and not tex[16:, 16:].any()
    grown = lid_texels(faces, uv, faces, moved, 32, grow=2)
    assert grown.sum() > tex.sum() and (grown | ~tex).all()


def test_config_is_checked():
    for bad in ({"steps": -1}, {"stride": 0}, {"lash": 1.5}, {"shade": 0.0},
                {"ring": (3, 3)}):
        with pytest.raises(ValueError, match="expected"):
            LidConfig(**bad)


@pytest.fixture(scope="module")
def head():
    """The shipped generator and the mean head, open and closed, with a generated
    texture and its lid texels."""
    from head360cli.mesh.bilinear import load_bilinear
    from head360cli.model.train import load_generator

    gen, codes = load_generator()
    model = load_bilinear()
    neutral = model.vertices(np.zeros(model.rank), np.zeros(52))
    shut = model.vertices(np.zeros(model.rank), blink_weights())
    with torch.no_grad():
        texture = gen.texture(codes.mean(0)[None])[0]
    texels = lid_texels(model.faces, model.uv, model.faces_uv,
                        np.any(shut != neutral, axis=1), texture.shape[-1])
    return gen, model, torch.tensor(neutral, dtype=torch.float32), \
        torch.tensor(shut, dtype=torch.float32), texture, texels


def test_close_lids_fits_a_change_on_the_lid_texels_only(head):
    gen, model, neutral, shut, texture, texels = head
    cfg = dataclasses.replace(LidConfig(), steps=4)
    out = close_lids(gen, neutral, shut, texture, model.faces, texels, cfg)
    assert out.change.shape == texture.shape and torch.isfinite(out.change).all()
    assert out.texels == int(texels.sum()) > 1000
    changed = (out.change != 0).any(0).numpy()
    assert changed.sum() > 500 and not (changed & ~texels).any()
    assert out.loss_last < 0.8 * out.loss_first
    assert gen.cfg.pixel_samples == 2 and gen.cfg.image_res == 256  # settings restored


@pytest.mark.slow
def test_the_change_closes_the_eyes_for_dlib(head):
    """The closed eyes of the mean head with a generated texture: dlib's eye opening of
    a frontal render, 0.44 open, is 0.28 closed without the change and 0.23 with it (0.15
    with lids as bright as the skin, ``shade=1``, which on the fitted astronaut lost
    dlib's face detection at the most closed frames); the open eyes are not touched."""
    from head360cli.bench.animate import eye_opening
    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.fitting.landmarks import LandmarkDetector
    from head360cli.model.head_render import HeadRenderer, to_uint8

    gen, model, neutral, shut, texture, texels = head
    torch.manual_seed(0)
    out = close_lids(gen, neutral, shut, texture, model.faces, texels)
    det = LandmarkDetector("hog")
    cam, k = view_cameras(0.0, 0.0), view_intrinsics(256)
    openings = {}
    for name, change in (("without", None), ("with", out.change)):
        r = HeadRenderer(gen, np.zeros(model.rank), texture, 0, np.zeros(3),
                         precision="fp32", lid_change=change)
        for state, w in (("open", np.zeros(52)), ("closed", blink_weights())):
            lm = det.detect_one(to_uint8(r.render(cam, k, w))[0]).landmarks
            openings[name, state] = (eye_opening(lm, "left") + eye_opening(lm, "right")) / 2
    assert openings["with", "open"] == pytest.approx(openings["without", "open"], abs=1e-9)
    assert openings["with", "closed"] < openings["without", "closed"] - 0.03
    assert openings["with", "closed"] < 0.6 * openings["with", "open"]


def test_no_steps_or_no_texels_give_no_change(head):
    gen, model, neutral, shut, texture, texels = head
    for out in (close_lids(gen, neutral, shut, texture, model.faces, texels,
                           LidConfig(steps=0)),
                close_lids(gen, neutral, shut, texture, model.faces,
                           np.zeros_like(texels))):
        assert out.change.shape == texture.shape and not out.change.any()


def test_eye_texels_split_the_lids_left_and_right(head):
    from head360cli.mesh.eyelids import eye_texels

    _, model, _, _, texture, texels = head
    left, right = eye_texels(model, np.zeros(model.rank), texture.shape[-1])
    assert left.sum() > 500 and right.sum() > 500
    assert not (left & right).any()
    np.testing.assert_array_equal(left | right, texels)


def test_a_renderer_adds_each_eyes_change_as_far_as_it_is_closed(head):
    from head360cli.mesh.arkit52 import INDEX
    from head360cli.model.head_render import HeadRenderer

    gen, model, _, _, texture, texels = head
    change = torch.randn_like(texture) * torch.as_tensor(texels)
    r = HeadRenderer(gen, np.zeros(model.rank), texture, 0, np.zeros(3), lid_change=change)
    w = np.zeros((4, 52))
    w[1, INDEX["eyeBlinkLeft"]] = 1.0
    w[2, INDEX["eyeBlinkRight"]] = 0.3  # half of the way to LID_FULL_AT
    w[3] = blink_weights()
    tex = r.textures(w)
    assert torch.equal(tex[0], texture)
    assert torch.equal(r.textures(np.zeros((2, 52))), texture.expand(2, -1, -1, -1))
    left = (tex[1] != texture).any(0).numpy()
    right = (tex[2] != texture).any(0).numpy()
    assert left.any() and right.any() and not (left & right).any()
    torch.testing.assert_close(tex[3], texture + change)
    torch.testing.assert_close(tex[2] - texture, 0.5 * (change * torch.as_tensor(right)))
    with pytest.raises(ValueError, match="shaped like the texture"):
        HeadRenderer(gen, np.zeros(model.rank), texture, 0, np.zeros(3),
                     lid_change=change[:, :8])


def test_a_renderer_takes_the_lid_change_as_a_fit_hands_it_over(head):
    """``fit`` passes its lid change as a tensor on the fit's device, maybe still tied to
    the optimiser's graph: the renderer must not read it through numpy (which fails for a
    GPU's tensors: every ``fit --device cuda`` failed so before 2026-12-04, and for tensors
    that require grad), and holds the same change as from the head file's array."""
    from head360cli.model.head_render import HeadRenderer

    gen, model, _, _, texture, texels = head
    change = torch.randn_like(texture) * torch.as_tensor(texels)
    from_file = HeadRenderer(gen, np.zeros(model.rank), texture, 0, np.zeros(3),
                             lid_change=change.numpy())
    live = change.clone().requires_grad_(True)
    from_fit = HeadRenderer(gen, np.zeros(model.rank), texture, 0, np.zeros(3),
                            lid_change=live * 1.0)
    assert not from_fit.lids.requires_grad
    assert from_fit.lids.device == from_file.lids.device
    torch.testing.assert_close(from_fit.lids, from_file.lids, rtol=0, atol=0)
    assert from_fit.lids.abs().sum() > 0


def test_the_change_comes_in_from_the_heads_own_blink(head):
    """A fitted texture already shows the photo's half-closed eyes: its own weights (a
    render given none) show no change, and a stream's blink closes each eye from its own
    openness, bringing the change in as the stream blinks (all of it from 0.6 on)."""
    from head360cli.mesh.arkit52 import INDEX
    from head360cli.model.head_render import HeadRenderer

    gen, model, _, _, texture, texels = head
    change = torch.randn_like(texture) * torch.as_tensor(texels)
    own = 0.5 * blink_weights()
    r = HeadRenderer(gen, np.zeros(model.rank), texture, 0, np.zeros(3), own,
                     lid_change=change)
    assert torch.equal(r._textures(own[None])[0], texture)  # the head as fitted
    w = np.stack([np.zeros(52), 0.15 * blink_weights(), 0.45 * blink_weights(),
                  0.75 * blink_weights(), blink_weights()])
    tex = r.textures(w)
    assert torch.equal(tex[0], texture)
    torch.testing.assert_close(tex[1], texture + 0.25 * change)  # 0.15 / LID_FULL_AT 0.6
    torch.testing.assert_close(tex[2], texture + 0.75 * change)
    torch.testing.assert_close(tex[3], texture + change)  # all in from 0.6 on
    torch.testing.assert_close(tex[4], texture + change)
    one = np.zeros((1, 52))
    one[0, INDEX["eyeBlinkLeft"]] = 0.9  # the right eye stays at its own openness
    left = (r.textures(one)[0] != texture).any(0).numpy()
    assert left.any() and left.sum() < texels.sum()

"""The style's thickness fitted by direction to the parsed hair, and the ranking made
with it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from head360cli.fitting.hair_class import HAIR_AREA_CM2, classify_hair, style_silhouettes
from head360cli.fitting.hair_shape import (
    END_SHIFTS,
    SCALE_RANGE,
    _Scene,
    extras_support,
    fit_hair_end,
    fit_hair_scale,
    fit_hair_shape,
    rank_shaped,
    ray_directions,
)
from head360cli.synth.hair import HAIRSTYLES, WARP_BINS, style_index, warp_centre

RES = 96


@pytest.fixture(scope="module")
def front():
    """The model's mean head seen from the front (10 degrees yaw, 5 pitch) at 96 px."""
    from head360cli.geometry.cameras import (
        RIG_DISTANCE,
        RIG_FOV_DEG,
        camera_on_sphere,
        intrinsics_from_fov,
    )
    from head360cli.mesh.bilinear import load_bilinear

    model = load_bilinear()
    head = model.vertices(model.code_mean, np.zeros(52))
    c2w = camera_on_sphere(torch.tensor([10.0]), torch.tensor([5.0]), RIG_DISTANCE)[0]
    return head, model.faces, c2w.numpy(), intrinsics_from_fov(RIG_FOV_DEG, RES, RES).numpy()


def _silhouette(front, style: int, scale=None) -> np.ndarray:
    head, faces, c2w, k = front
    return _Scene(head, head, faces, c2w, k, RES).silhouette(style, np.zeros(3), scale)


def test_the_rays_leave_the_centre_towards_the_head_s_left_first(front):
    """Direction 0 is the head's +x (its left, the image's right from the front), and
    a quarter turn later the rays point up the image; in a profile the sideways
    directions are seen end on."""
    from head360cli.synth.sculpt import frame_from_vertices

    head, _, c2w, k = front
    origin, dirs, seen = ray_directions(warp_centre(frame_from_vertices(head)), c2w, k,
                                        WARP_BINS)
    assert 0 < origin[0] < RES and 0 < origin[1] < RES
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-9)
    assert dirs[0, 0] > 0.95 and dirs[WARP_BINS // 4, 1] < -0.95
    assert seen.max() == 1.0 and seen.min() > 0.9  # nearly frontal: all seen side on
    # from the head's left side (a profile) its sideways directions are seen end on
    from head360cli.geometry.cameras import RIG_DISTANCE, camera_on_sphere

    side = camera_on_sphere(torch.tensor([90.0]), torch.tensor([0.0]), RIG_DISTANCE)[0]
    _, _, seen = ray_directions(warp_centre(frame_from_vertices(head)), side.numpy(), k,
                                WARP_BINS)
    assert seen[0] < 0.1 and seen[WARP_BINS // 4] == pytest.approx(1.0, abs=0.05)


def test_a_thicker_style_is_recovered_from_its_silhouette(front):
    """The bob made 1.8 times as thick all round is the 'parsed' hair: the fit starts
    from the bob as built and ends with the thicker silhouette, and the scale it finds
    where the outline tells it (the sides and the top) is near 1.8."""
    head, faces, c2w, k = front
    bob = style_index("bob")
    truth = np.full(WARP_BINS, 1.8)
    target = _silhouette(front, bob, truth)
    shape = fit_hair_scale(head, head, faces, c2w, k, bob, target)
    assert shape.iou_before < 0.8 and shape.iou_after > 0.9
    assert shape.scale.shape == (WARP_BINS,)
    upper = np.r_[0:WARP_BINS // 2 + 1]  # from the left side over the top to the right
    assert np.median(shape.scale[upper]) == pytest.approx(1.8, rel=0.2)
    assert SCALE_RANGE[0] <= shape.scale.min() and shape.scale.max() <= SCALE_RANGE[1]


def test_the_photo_s_unknown_side_keeps_the_style_s_thickness(front):
    """With the image's right half outside the photo, the directions towards the head's
    left (the image's right) are not scaled, while the other side still grows."""
    head, faces, c2w, k = front
    bob = style_index("bob")
    target = _silhouette(front, bob, np.full(WARP_BINS, 1.8))
    valid = np.ones((RES, RES), bool)
    valid[:, RES // 2 + 12:] = False
    shape = fit_hair_scale(head, head, faces, c2w, k, bob, target, valid)
    assert shape.scale[0] == pytest.approx(1.0, abs=0.15)  # towards the image's right
    assert shape.scale[WARP_BINS // 2] > 1.4  # towards its left


def test_a_scale_that_gains_nothing_is_not_kept(front):
    """The style's own silhouette as the parsed hair: nothing to gain, scale ones; bald
    is never scaled."""
    head, faces, c2w, k = front
    crew = style_index("crew")
    shape = fit_hair_scale(head, head, faces, c2w, k, crew, _silhouette(front, crew))
    assert (shape.scale == 1).all() and shape.iou_after == shape.iou_before == 1.0
    bald = fit_hair_scale(head, head, faces, c2w, k, 0, np.ones((RES, RES), bool))
    assert (bald.scale == 1).all()


def test_tails_the_photo_does_not_show_are_contradicted(front):
    """Twin tails hang beside the neck: hair parsed as the bob alone leaves them
    unsupported, hair parsed with them supports them, and a style without extras has no
    such measure."""
    head, faces, c2w, k = front
    scene = _Scene(head, head, faces, c2w, k, RES)
    tails, bob = style_index("twin tails"), style_index("bob")
    valid = np.ones((RES, RES), bool)
    shift = np.zeros(3)
    # 0.21: the bob reaches part of the tails' tops
    assert extras_support(scene, tails, _silhouette(front, bob), valid, shift) < 0.3
    assert extras_support(scene, tails, _silhouette(front, tails), valid, shift) == 1.0
    assert extras_support(scene, bob, _silhouette(front, bob), valid, shift) is None


def test_the_ranking_demotes_contradicted_extras_and_judges_shaped_styles(front):
    """Hair parsed as twin tails whose tails end just below the ears: the tails rank
    first unshaped, but the photo contradicts most of them, so a style without them
    ranks first; every candidate's IoU is its shaped one, never below the unshaped."""
    head, faces, c2w, k = front
    tails = style_index("twin tails")
    full = _silhouette(front, tails)
    own = full & ~_Scene(head, head, faces, c2w, k, RES).silhouette(
        dataclasses.replace(HAIRSTYLES[tails], extras=()), np.zeros(3))
    rows = np.flatnonzero(own.any(1))
    hair = full & ~(own & (np.arange(RES)[:, None] > rows[0] + 0.3 * np.ptp(rows)))
    sil = style_silhouettes(head, head, faces, c2w, k, RES)
    guess = classify_hair(hair, sil, hair_area=HAIR_AREA_CM2)
    assert guess.ranking[0] == tails
    shaped = rank_shaped(guess, sil, head, head, faces, c2w, k, hair, soft=False,
                         hair_area=HAIR_AREA_CM2)
    assert shaped.contradicted == (tails,) and shaped.ranking[0] != tails
    assert shaped.ranking.index(tails) > 5
    assert len(shaped.shaped) == 5 and tails in shaped.shaped
    for style in shaped.shaped:
        assert shaped.iou[style] >= guess.iou[style]
    assert np.isclose(shaped.probability.sum(), 1.0)
    assert shaped.same_as_first[shaped.ranking[0]]


def test_a_shorter_bob_s_ends_are_found_and_long_hair_is_not_lengthened(front):
    """The bob ending 3 cm higher is the parsed hair: the fit raises the style's ends by
    3 cm, and the thickness fitted after it starts there. Hair longer than the style
    gives no shift down: the shifts only raise."""
    head, faces, c2w, k = front
    bob = style_index("bob")
    short = _Scene(head, head, faces, c2w, k, RES).silhouette(
        dataclasses.replace(HAIRSTYLES[bob], end_shift=-0.03), np.zeros(3))
    assert fit_hair_end(head, head, faces, c2w, k, bob, short) == pytest.approx(-0.03)
    shape = fit_hair_scale(head, head, faces, c2w, k, bob, short, end_shift=-0.03)
    assert (shape.scale == 1).all() and shape.iou_before == 1.0
    end, both = fit_hair_shape(head, head, faces, c2w, k, bob, short)  # the two on one scene
    assert end == pytest.approx(-0.03) and (both.scale == 1).all() and both.iou_after == 1.0
    longer = _silhouette(front, style_index("shoulder straight"))
    assert fit_hair_end(head, head, faces, c2w, k, bob, longer) == 0.0
    assert max(END_SHIFTS) == 0.0
    assert fit_hair_end(head, head, faces, c2w, k, 0, short) == 0.0

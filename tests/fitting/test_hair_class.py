"""Hairstyle classification by silhouettes, and the hair colour estimate."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from head360cli.fitting.hair_class import (
    COLOUR_MAP,
    TEMPERATURE,
    classify_hair,
    colour_samples,
    fit_colour_map,
    hair_colour,
    hidden_by_body,
    nearest_colour_name,
    nearest_colour_names,
    pick_colour_by_render,
    place_hair,
    style_silhouettes,
)


def _front_view(index: int):
    from head360cli.geometry.cameras import RIG_DISTANCE, camera_on_sphere
    from head360cli.model.data import Views

    views = Views(index + 1, split="test", size=96)
    c2w = camera_on_sphere(torch.tensor([10.0]), torch.tensor([5.0]), RIG_DISTANCE)
    batch = views.render(index, np.zeros(52, np.float32), c2w, with_hair=True)
    return views, batch, c2w[0].numpy()


@pytest.mark.slow
def test_silhouette_of_the_true_style_ranks_first():
    from head360cli.mesh.bilinear import load_bilinear

    faces = load_bilinear().faces
    views, batch, c2w = _front_view(11)  # style 11 (bob)
    head = views.head(11)
    sil = style_silhouettes(head.verts, batch.verts[0].numpy(), faces, c2w,
                            views.intrinsics.numpy(), 96)
    assert sil.shape == (30, 96, 96) and not sil[0].any()  # style 0 is bald
    guess = classify_hair(batch.hair_alpha[0, 0].numpy() > 0.5, sil)
    assert guess.ranking[0] == head.hair_style == 11
    assert guess.iou[11] > 0.85
    assert np.isclose(guess.probability.sum(), 1.0)
    top = guess.top(3)
    assert [t["id"] for t in top] == guess.ranking[:3] and top[0]["name"] == "bob"
    assert top[0]["same_silhouette_as_first"] and not top[1]["same_silhouette_as_first"]


def test_place_hair_finds_the_shift_of_the_hair():
    """A corpus head's hair, seen from the front, moved 8 mm up and 4 mm back: the
    placement finds that shift of the style's fitted mesh (the silhouettes are the same
    pixel for pixel), and leaves the unshifted hair where it is."""
    from head360cli.mesh.bilinear import load_bilinear

    faces = load_bilinear().faces
    views, batch, c2w = _front_view(11)  # style 11 (bob)
    head, k = views.head(11), views.intrinsics.numpy()
    posed = batch.verts[0].numpy()
    shift = np.array([[0.0, 0.008, -0.004]])
    moved = style_silhouettes(head.verts, posed, faces, c2w, k, 96, [11], shift)[0]
    plain = style_silhouettes(head.verts, posed, faces, c2w, k, 96, [11])[0]
    assert np.array_equal(
        plain, style_silhouettes(head.verts, posed, faces, c2w, k, 96, [11], 0 * shift)[0])
    assert (moved != plain).sum() > 20  # the shift shows at 96 px
    offset, iou, iou_plain = place_hair(head.verts, posed, faces, c2w, k, 11, moved)
    np.testing.assert_allclose(offset, shift[0], atol=1e-12)
    assert iou == 1.0 and iou_plain < 0.95
    offset, iou, iou_plain = place_hair(head.verts, posed, faces, c2w, k, 11, plain)
    assert not offset.any() and iou == iou_plain == 1.0


@pytest.mark.slow
def test_place_hair_lifts_hair_off_the_parsed_face():
    """The hair matches the unshifted silhouette exactly, but the strip it alone covers
    (not the silhouette lifted 12 mm) is parsed as face: with the face mask the placement
    lifts the hair off that skin, at a cost in IoU; without it the hair stays."""
    from head360cli.fitting.hair_class import PLACEMENT_UP
    from head360cli.mesh.bilinear import load_bilinear

    faces = load_bilinear().faces
    views, batch, c2w = _front_view(11)
    head, k = views.head(11), views.intrinsics.numpy()
    posed = batch.verts[0].numpy()
    plain = style_silhouettes(head.verts, posed, faces, c2w, k, 96, [11])[0]
    lifted = style_silhouettes(head.verts, posed, faces, c2w, k, 96, [11],
                               np.array([[0.0, max(PLACEMENT_UP), 0.0]]))[0]
    face = plain & ~lifted
    assert face.sum() > 20
    offset, iou, iou_plain = place_hair(head.verts, posed, faces, c2w, k, 11, plain,
                                        face=face)
    assert offset[1] > 0 and iou < iou_plain == 1.0
    chosen = style_silhouettes(head.verts, posed, faces, c2w, k, 96, [11], offset[None])[0]
    assert (chosen & face).sum() < 0.5 * face.sum()
    offset, _, _ = place_hair(head.verts, posed, faces, c2w, k, 11, plain)
    assert not offset.any()


def test_styles_with_the_same_silhouette_are_flagged():
    """Styles that look alike from this view (pixel for pixel where scored) tie, and the
    guess says which share the first one's silhouette."""
    hair = np.zeros((10, 10), bool)
    hair[:4] = True
    sil = np.zeros((30, 10, 10), bool)
    sil[19, :4] = sil[20, :4] = True  # two styles that differ only out of view
    sil[20, 9, 9] = True  # ... or only where the photo has no pixels
    sil[5, :3] = True  # close, not the same
    valid = np.ones((10, 10), bool)
    valid[9, 9] = False
    guess = classify_hair(hair, sil, valid)
    assert guess.ranking[:2] == [19, 20] and guess.iou[19] == guess.iou[20] == 1.0
    assert np.flatnonzero(guess.same_as_first).tolist() == [19, 20]
    assert [t["same_silhouette_as_first"] for t in guess.top(3)] == [True, True, False]
    # scored everywhere, the pixel at the corner tells them apart
    assert np.flatnonzero(classify_hair(hair, sil).same_as_first).tolist() == [19]


def test_styles_that_tie_rank_least_hair_first():
    """With ``hair_area`` the styles a view cannot tell apart rank by how much hair they
    add (least first); without it, the lower id first. Styles that do not tie keep
    their order whatever their area."""
    from head360cli.fitting.hair_class import HAIR_AREA_CM2

    hair = np.zeros((10, 10), bool)
    hair[:4] = True
    sil = np.zeros((30, 10, 10), bool)
    sil[[19, 20, 21, 23], :4] = True  # the ponytails, the bun and the braid: one view
    sil[1, :3] = True  # the buzz cut, less hair but a worse fit
    assert classify_hair(hair, sil).ranking[:4] == [19, 20, 21, 23]
    guess = classify_hair(hair, sil, hair_area=HAIR_AREA_CM2)
    assert guess.ranking[:4] == [21, 19, 20, 23] and guess.ranking[4] == 1
    assert np.flatnonzero(guess.same_as_first).tolist() == [19, 20, 21, 23]
    area = np.arange(30, 0, -1.0)  # any order of areas: highest id least hair
    assert classify_hair(hair, sil, hair_area=area).ranking[:5] == [23, 21, 20, 19, 1]
    with pytest.raises(ValueError, match=r"hair_area of shape \(30,\).*found \(29,\)"):
        classify_hair(hair, sil, hair_area=area[:29])


def test_hair_area_table_is_what_the_meshes_measure():
    from head360cli.fitting.hair_class import HAIR_AREA_CM2, measure_hair_areas

    np.testing.assert_allclose(measure_hair_areas(), HAIR_AREA_CM2, atol=0.2)
    assert HAIR_AREA_CM2[0] == 0.0  # bald
    assert HAIR_AREA_CM2[21] < HAIR_AREA_CM2[19] == HAIR_AREA_CM2[20] < HAIR_AREA_CM2[23]


def test_no_hair_pixels_rank_bald_first():
    sil = np.zeros((30, 8, 8), bool)
    sil[1:, 2:5, 2:5] = True
    guess = classify_hair(np.zeros((8, 8), bool), sil)
    assert guess.ranking[0] == 0 and guess.iou[0] == 1.0


def test_hair_that_no_style_matches_ranks_as_no_hair():
    """A parsed patch that every silhouette overlaps by under MIN_STYLE_IOU (a
    neighbour's hair, a piece of backdrop) is no evidence of a style: bald first with
    probability 1, the measured overlaps kept, the others ranked by them; at the floor
    the styles rank as before."""
    from head360cli.fitting.hair_class import MIN_STYLE_IOU

    sil = np.zeros((30, 20, 20), bool)
    sil[1:, 19, 0] = True  # every style but bald shows a pixel, away from the hair
    sil[9, :10] = True  # a wide style: 201 pixels
    sil[1, 12:14, :5] = True  # a short one, away from the hair
    hair = np.zeros((20, 20), bool)
    hair[9, 5:8] = True  # 3 pixels under the wide style
    hair[15:, 15:] = True  # 25 pixels under none
    guess = classify_hair(hair, sil)
    assert guess.iou[9] == 3 / 226 < MIN_STYLE_IOU and not guess.matched
    assert guess.ranking[:3] == [0, 9, 1]
    assert guess.probability[0] > 0.999 and guess.iou[0] == 0.0
    hair[:2, :10] = True  # now 20 + 3 of the wide style's pixels: IoU 23 / 226
    guess = classify_hair(hair, sil)
    assert guess.matched and guess.ranking[0] == 9
    assert guess.iou[9] == 23 / 226 >= MIN_STYLE_IOU
    assert guess.probability[9] == guess.probability.max()


def test_styles_that_cover_the_face_lose_near_ties():
    """Two styles overlap the hair equally; the one drawn over the parsed face skin
    loses FACE_COVER times the face's share it covers. Without a face mask the IoU alone
    ranks (the lower id first on a tie); a style far ahead in IoU still wins."""
    from head360cli.fitting.hair_class import FACE_COVER

    assert FACE_COVER > 0
    sil = np.zeros((30, 20, 20), bool)
    hair = np.zeros((20, 20), bool)
    hair[:4] = True  # 80 hair pixels on top
    face = np.zeros((20, 20), bool)
    face[8:16, 5:15] = True  # 80 face pixels
    sil[3, :4] = True
    sil[3, 8:10, 5:15] = True  # hair over the forehead: 20 face pixels
    sil[3, 18:20, :10] = True  # and 20 on the backdrop
    sil[7, :4] = True
    sil[7, 18:20] = True  # 40 pixels on the backdrop
    assert classify_hair(hair, sil).iou[3] == classify_hair(hair, sil).iou[7] == 80 / 120
    assert classify_hair(hair, sil).ranking[0] == 3
    guess = classify_hair(hair, sil, face=face)
    assert guess.ranking[:2] == [7, 3] and guess.iou[3] == 80 / 120
    assert guess.probability[7] == pytest.approx(
        guess.probability[3] * np.exp(FACE_COVER * 20 / 80 / TEMPERATURE))
    sil[7, 4:12, :5] = sil[7, 4:12, 15:] = True  # 80 more on the backdrop: IoU 0.4
    assert classify_hair(hair, sil, face=face).ranking[0] == 3


def test_hair_colour_linearises_the_median_and_names_it():
    rgb = np.zeros((4, 4, 3), np.uint8)
    rgb[:2] = (188, 188, 188)  # sRGB 188 -> linear 0.5
    mask = np.zeros((4, 4), bool)
    mask[:2] = True
    np.testing.assert_allclose(hair_colour(rgb, mask, colour_map=(1.0, 1.0)), 0.5029,
                               atol=2e-3)
    np.testing.assert_allclose(hair_colour(rgb, mask, colour_map=(4.0, 1.0)), 1.0)  # clipped
    # the shipped tone curve: 1.164 * 0.5029 ** 0.581
    np.testing.assert_allclose(hair_colour(rgb, mask), 0.780, atol=2e-3)
    assert nearest_colour_name(np.array([0.5, 0.49, 0.47])) == "grey"
    assert nearest_colour_name(np.array([0.03, 0.03, 0.03])) == "black"
    assert hair_colour(rgb, np.zeros((4, 4), bool)).shape == (3,)  # fallback


def test_pixels_beyond_the_photo_are_not_scored():
    hair = np.zeros((10, 10), bool)
    hair[:5] = True  # replicated hair above the photo's top edge would look like this
    sil = np.zeros((30, 10, 10), bool)
    sil[1, 3:5] = True  # a small style, matching the hair inside the photo
    sil[2, :5] = True  # a big style, matching hair that is not in the photo
    valid = np.zeros((10, 10), bool)
    valid[3:] = True
    assert classify_hair(hair, sil).ranking[0] == 2
    guess = classify_hair(hair, sil, valid)
    assert guess.ranking[0] in (1, 2) and guess.iou[1] == guess.iou[2] == 1.0


def _face_landmarks(angle_deg: float = 0.0) -> np.ndarray:
    """68 landmarks of which 4, 8, 12 and 27 matter: an upright face (nose bridge at
    (50, 30), chin at (50, 70), jaw corners 40 px apart), rolled by ``angle_deg``
    about the chin."""
    lm = np.full((68, 2), 50.0)
    lm[27], lm[8], lm[4], lm[12] = (50, 30), (50, 70), (30, 60), (70, 60)
    a = np.deg2rad(angle_deg)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return (lm - lm[8]) @ rot.T + lm[8]


def test_hidden_by_body_is_the_strip_below_the_chin():
    body = hidden_by_body(_face_landmarks(), (100, 100))
    # rows 71..99 below the chin, columns 31..69 within half the jaw's width of it
    assert body.sum() == 29 * 39
    assert body[71:, 31:70].all() and not body[:71].any()
    assert not body[:, :31].any() and not body[:, 70:].any()
    assert hidden_by_body(_face_landmarks(), (100, 100), width=2.0).sum() == 29 * 79
    # a face rolled by 90 degrees (nose bridge right of the chin): the strip runs to the
    # left, across the image's rows, to the image's edge
    rolled = hidden_by_body(_face_landmarks(90.0), (100, 100))
    assert rolled.sum() == 50 * 39 and rolled[51:90, :50].all()
    # degenerate landmarks (all on one point) hide nothing rather than fail
    assert not hidden_by_body(np.zeros((68, 2)), (100, 100)).any()


def test_hair_behind_the_neck_does_not_decide_the_style():
    """A long style shows hair behind the neck that a photo's body hides; left out of
    the score, the long style wins over a shorter one it would otherwise lose to."""
    lm = _face_landmarks()
    body = hidden_by_body(lm, (100, 100))
    sil = np.zeros((30, 100, 100), bool)
    sil[[14, 16], 20:35, 15:85] = True  # the top of the head
    sil[16, 35:100, 15:30] = sil[16, 35:100, 70:85] = True  # long: to the bottom
    sil[16, 70:100, 30:70] = True  # and behind the neck, which the render shows
    sil[14, 35:80, 15:30] = sil[14, 35:80, 70:85] = True  # shoulder length
    hair = sil[16] & ~body  # the photo: the body hides what is behind the neck
    assert classify_hair(hair, sil).ranking[0] == 14
    assert classify_hair(hair, sil, ~body).ranking[0] == 16


def test_fit_colour_map_recovers_a_tone_curve():
    rng = np.random.default_rng(0)
    pixels = rng.uniform(0.005, 0.5, (40, 3))
    albedos = 1.3 * pixels ** 0.6
    assert fit_colour_map(pixels, albedos) == (1.3, 0.6)


@pytest.mark.slow
def test_held_out_corpus_hair_colours_are_named_right():
    """Corpus heads not among those the map was fitted on (seed 1's test split), each in
    all 10 colours: the tone curve names 17 of 20 right, where one gain of 4 named 9."""
    pixels, names = colour_samples(3, seed=1, split="test")
    assert len(names) == 20  # head 0 is bald
    scale, exponent = COLOUR_MAP
    named = [nearest_colour_name(np.clip(scale * p ** exponent, 0, 1)) for p in pixels]
    assert sum(a == b for a, b in zip(named, names, strict=True)) >= 17
    gain = [nearest_colour_name(np.clip(4.0 * p, 0, 1)) for p in pixels]
    assert sum(a == b for a, b in zip(gain, names, strict=True)) <= 10


def test_nearest_colour_names_are_ordered_by_distance():
    from head360cli.synth.hair import HAIR_COLOURS

    names = nearest_colour_names(np.array(HAIR_COLOURS["light brown"]), 3)
    assert names[0] == "light brown" and len(set(names)) == 3
    assert nearest_colour_names(np.array([0.03, 0.03, 0.03]), 1) == ["black"]


@pytest.mark.parametrize("power", [1.0, 2.1, 3.0])
def test_match_colour_by_render_reaches_the_photo_s_hair_colour(power):
    """A fake renderer whose hair answers its albedo as ``0.5 * albedo ** power`` (linear;
    the shipped generator's slope was about 2): three renders from a named colour give
    the albedo whose render has the photo's median hair colour, a colour no name has;
    without overlap the start is kept."""
    from head360cli.fitting.hair_class import MATCH_RANGE, _srgb, match_colour_by_render
    from head360cli.synth.hair import HAIR_COLOURS

    hair = np.zeros((16, 16), bool)
    hair[:6] = True
    want = np.array([0.30, 0.12, 0.20])  # a plum no SynHead-P colour is
    photo = np.zeros((16, 16, 3))
    photo[hair] = _srgb(0.5 * want ** power)

    def render(rgb):
        image = np.zeros((16, 16, 3))
        image[:8] = _srgb(0.5 * np.asarray(rgb, np.float64) ** power)
        covered = np.zeros((16, 16), bool)
        covered[:8] = True
        return image, covered

    start = np.asarray(HAIR_COLOURS["brown"])
    got = match_colour_by_render(render, photo, hair, start)
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, want, rtol=0.02)
    assert MATCH_RANGE[0] <= got.min() and got.max() <= MATCH_RANGE[1]
    np.testing.assert_array_equal(
        match_colour_by_render(render, photo, np.zeros((16, 16), bool), start),
        start.astype(np.float32))


def test_pick_colour_by_render_takes_the_render_most_like_the_photo():
    """A fake renderer paints the hair region in the colour's sRGB value; the photo's hair
    is blonde's, so blonde wins over the tone curve's first guess."""
    from head360cli.fitting.hair_class import _srgb
    from head360cli.synth.hair import HAIR_COLOURS

    hair = np.zeros((16, 16), bool)
    hair[:6] = True
    photo = np.zeros((16, 16, 3))
    photo[hair] = _srgb(HAIR_COLOURS["blonde"])

    def render(rgb):
        image = np.zeros((16, 16, 3))
        image[:8] = _srgb(rgb)
        covered = np.zeros((16, 16), bool)
        covered[:8] = True
        return image, covered

    name, scores = pick_colour_by_render(render, photo, hair,
                                         ["light brown", "blonde", "brown"])
    assert name == "blonde" and set(scores) == {"light brown", "blonde", "brown"}
    assert scores["blonde"] < 1e-6 < scores["light brown"]  # float32 colours
    # no overlap between rendered and parsed hair: the first candidate, unscored
    name, scores = pick_colour_by_render(render, photo, np.zeros((16, 16), bool),
                                         ["light brown", "blonde"])
    assert (name, scores) == ("light brown", {})

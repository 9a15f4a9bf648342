"""Hair parsing: synthetic photos with known masks, and real masks when present. Most of
these test the GrabCut parser (``method="grabcut"``); the segmenter's tests are at the
end."""

from __future__ import annotations

import numpy as np
import pytest

from head360cli.fitting.hair_parse import mask_iou, parse_hair


def _grabcut(*args, **kwargs):
    """:func:`parse_hair` by GrabCut."""
    return parse_hair(*args, method="grabcut", **kwargs)


def test_mask_iou_golden_values():
    a = np.zeros((4, 4), bool)
    b = np.zeros((4, 4), bool)
    assert mask_iou(a, b) == 1.0
    a[:2] = True
    b[1:3] = True
    assert mask_iou(a, b) == pytest.approx(4 / 12)


def _synthetic_portrait():
    """A 200 x 200 'photo': grey wall, skin-coloured face ellipse, dark hair cap, with
    landmarks placed on the face ellipse (jaw on the lower outline, inner points inside)."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:200, 0:200]
    img = np.full((200, 200, 3), (170, 175, 180), np.float64)
    face = ((xx - 100) / 42) ** 2 + ((yy - 110) / 55) ** 2 <= 1
    hair = (((xx - 100) / 56) ** 2 + ((yy - 85) / 62) ** 2 <= 1) & ~face & (yy < 120)
    hair |= face & (yy < 70)
    img[face] = (215, 160, 130)
    img[hair] = (60, 40, 25)
    img += rng.normal(0, 4, img.shape)
    t = np.linspace(np.pi * 0.05, np.pi * 0.95, 17)
    jaw = np.stack([100 - 40 * np.cos(t), 110 + 52 * np.sin(t)], 1)
    inner = np.stack([rng.uniform(72, 128, 51), rng.uniform(80, 145, 51)], 1)
    brows = np.stack([np.linspace(70, 130, 10), np.full(10, 82.0)], 1)
    inner[:10] = brows
    return np.clip(img, 0, 255).astype(np.uint8), np.concatenate([jaw, inner]), hair, face


def test_seeded_parse_finds_the_synthetic_hair():
    """By colour and landmarks (the drawn portrait is no face to the learned prior, whose
    map is below 1e-4 everywhere on it: that case is the next test's)."""
    img, lm, hair, face = _synthetic_portrait()
    r = _grabcut(img, lm, prior=None)
    assert r.seeded
    assert r.hair.shape == face.shape and r.hair.dtype == bool
    assert mask_iou(r.hair, hair) > 0.7
    assert not (r.hair & r.face).any()
    assert (r.background == ~(r.hair | r.face)).all()
    assert r.face[face & (np.mgrid[0:200, 0:200][0] > 100)].mean() > 0.8  # lower face


def test_an_explicit_prior_never_overrides_the_certain_labels():
    """A prior map moves GrabCut's probable labels (and where it is sure, makes a pixel
    the person's), never the certain ones: a map that calls every pixel hair still
    leaves the inner face (brows, eyes, nose, mouth) out."""
    import cv2

    img, lm, hair, _ = _synthetic_portrait()
    without = _grabcut(img, lm, prior=None)
    with_map = _grabcut(img, lm, prior=hair.astype(np.float32))
    assert not without.prior and with_map.prior  # the parse says whether a prior was used
    alone, guided = mask_iou(without.hair, hair), mask_iou(with_map.hair, hair)
    assert guided >= alone - 0.01
    everywhere = _grabcut(img, lm, prior=np.ones(hair.shape, np.float32)).hair
    inner = np.zeros(hair.shape, np.uint8)
    cv2.fillPoly(inner, [cv2.convexHull(lm[17:68].astype(np.int32))], 1)
    assert everywhere.any() and not (everywhere & inner.astype(bool)).any()


def test_a_prior_sure_of_no_hair_vetoes_the_caps_seeds():
    """The cap above the brows is placed by the landmarks alone: above a bald head it lies
    on the backdrop, whose colour then seeded the hair. Where the prior is below
    PRIOR_NO_HAIR the cap seeds nothing: with a map of zeros the drawn hair has no seed
    and the parse is empty; a map of 0.1 everywhere keeps the seeds."""
    img, lm, hair, _ = _synthetic_portrait()
    assert not _grabcut(img, lm, prior=np.zeros(hair.shape, np.float32)).hair.any()
    kept = _grabcut(img, lm, prior=np.full(hair.shape, 0.1, np.float32)).hair
    assert mask_iou(kept, hair) > 0.7


def test_where_the_prior_is_sure_of_hair_it_seeds_the_hair(monkeypatch):
    """The cap's seeds miss hair that lies below it (a VOC photo's dark curls, whose cap
    lay on the backdrop above them); where the prior is above PRIOR_SURE and the colour
    is not the skin's, the second GrabCut pass (hair against skin and clothes) starts
    from certain hair, inside the person. Read off the labels that pass is given."""
    import cv2

    import head360cli.fitting.hair_parse as hair_parse

    img, lm, hair, face = _synthetic_portrait()
    yy = np.mgrid[0:200, 0:200][0]
    sides = hair & (yy > 60)  # below the cap (rows of about 30 to 54)
    labels = []
    grabcut = hair_parse._grabcut

    def recording(bgr, mask, iterations):
        labels.append(mask.copy())
        return grabcut(bgr, mask, iterations)

    monkeypatch.setattr(hair_parse, "_grabcut", recording)
    _grabcut(img, lm, prior=None)
    _grabcut(img, lm, prior=np.where(sides | face, 1.0, 0.1).astype(np.float32))
    (_, alone), (_, guided) = labels[:2], labels[2:]
    assert (alone[sides] == cv2.GC_FGD).mean() < 0.05
    assert (guided[sides] == cv2.GC_FGD).mean() > 0.9
    assert not (guided[face & (yy > 100)] == cv2.GC_FGD).any()  # sure, but skin


def test_parse_refuses_a_prior_of_the_wrong_shape_or_kind():
    from head360cli.errors import BadInputError

    img, lm, _, _ = _synthetic_portrait()
    with pytest.raises(BadInputError, match=r"photo's shape \(200, 200\), found \(100, 200\)"):
        _grabcut(img, lm, prior=np.zeros((100, 200)))
    with pytest.raises(BadInputError, match="expected prior 'learned'"):
        _grabcut(img, lm, prior="colour")


def test_unseeded_parse_runs_and_scales_back():
    img = _synthetic_portrait()[0]
    big = np.kron(img, np.ones((3, 3, 1), np.uint8))  # 600 x 600: parsed at work_size
    r = _grabcut(big, None, work_size=200)
    assert not r.seeded and r.hair.shape == (600, 600)
    assert not r.prior  # no face: the learned prior is not used
    assert not r.face.any()


def test_parse_refuses_photos_too_small_or_not_rgb():
    from head360cli.errors import BadInputError
    from head360cli.fitting.hair_parse import MIN_SIDE

    rng = np.random.default_rng(0)
    with pytest.raises(BadInputError, match=r"at least 16x16 pixels.*found 40x5"):
        _grabcut(rng.integers(0, 256, (5, 40, 3), dtype=np.uint8), None)
    with pytest.raises(BadInputError, match="uint8 RGB"):
        _grabcut(rng.random((40, 40, 3)), None)
    with pytest.raises(BadInputError, match=r"found shape \(40, 40\)"):
        _grabcut(np.zeros((40, 40), np.uint8), None)
    with pytest.raises(BadInputError, match=r"person pass size of at least 16 pixels, found 8"):
        _grabcut(rng.integers(0, 256, (40, 40, 3), dtype=np.uint8), None, person_size=8)
    # The smallest accepted size, and a thin strip, parse without numpy warnings (a 5-px
    # photo had divided by empty colour samples).
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for shape in [(MIN_SIDE, MIN_SIDE, 3), (MIN_SIDE, 400, 3)]:
            r = _grabcut(rng.integers(0, 256, shape, dtype=np.uint8), None)
            assert r.hair.shape == shape[:2]
            assert (r.background == ~(r.hair | r.face)).all()


def _strands(rng, shape):
    """Hair-like texture: dark brown with lighter vertical strands and noise."""
    h, w = shape
    lightness = 40 + 25 * np.sin(np.arange(w) * 0.9)[None, :] + rng.normal(0, 8, (h, w))
    return np.clip(np.stack([lightness * 1.3, lightness, lightness * 0.7], -1), 0, 255)


def test_unseeded_close_up_keeps_hair_that_runs_off_the_frame():
    """Hair fills the frame except a wall at the top right: the three hairy edges must not
    be seeded as background (they were, and the mask came out empty)."""
    rng = np.random.default_rng(0)
    img = _strands(rng, (160, 160))
    yy, xx = np.mgrid[0:160, 0:160]
    wall = (yy < 50) & (xx > 100)
    img[wall] = np.array([200.0, 205.0, 210.0]) + rng.normal(0, 3, (int(wall.sum()), 3))
    r = _grabcut(img.astype(np.uint8), None)
    assert mask_iou(r.hair, ~wall) > 0.9


def test_unseeded_back_view_keeps_the_wall_out():
    """A small head of hair in the middle of a plain wall: the edges are background."""
    rng = np.random.default_rng(1)
    yy, xx = np.mgrid[0:160, 0:160]
    head = ((xx - 80) / 32) ** 2 + ((yy - 72) / 40) ** 2 <= 1
    img = np.full((160, 160, 3), (150, 160, 170), np.float64) + rng.normal(0, 3, (160, 160, 3))
    img[head] = _strands(rng, (160, 160))[head]
    r = _grabcut(img.astype(np.uint8), None)
    assert mask_iou(r.hair, head) > 0.85


def test_unseeded_profile_leaves_the_skin_out():
    """A profile the detector missed: hair over a skin-coloured face that reaches into
    the centre of the frame (so the core's colours include skin), on a plain wall. The
    face is not hair (before the skin box it was)."""
    rng = np.random.default_rng(2)
    yy, xx = np.mgrid[0:160, 0:160]
    head = ((xx - 80) / 45) ** 2 + ((yy - 75) / 55) ** 2 <= 1
    face = head & (yy > 82) & (xx < 100)
    hair = head & ~face
    img = np.full((160, 160, 3), (150, 160, 170), np.float64) + rng.normal(0, 3, (160, 160, 3))
    img[hair] = _strands(rng, (160, 160))[hair]
    img[face] = np.array([215.0, 160.0, 130.0]) + rng.normal(0, 6, (int(face.sum()), 3))
    r = _grabcut(np.clip(img, 0, 255).astype(np.uint8), None)
    assert r.hair[face].mean() < 0.2
    assert mask_iou(r.hair, hair) > 0.8


def test_unseeded_close_up_leaves_a_plain_wall_out():
    """Hair on the right, a plain red wall on the left that reaches into the centre of
    the frame (so the core's colours include the wall): the smooth wall is not hair
    (before the texture rule it was)."""
    rng = np.random.default_rng(3)
    xx = np.mgrid[0:160, 0:160][1]
    hair = xx >= 75
    img = np.full((160, 160, 3), (190, 50, 45), np.float64) + rng.normal(0, 2, (160, 160, 3))
    img[hair] = _strands(rng, (160, 160))[hair]
    r = _grabcut(np.clip(img, 0, 255).astype(np.uint8), None)
    assert r.hair[~hair].mean() < 0.2
    assert mask_iou(r.hair, hair) > 0.8


@pytest.mark.parametrize("noise", [0.0, 1.0])
def test_a_featureless_photo_has_no_hair(noise):
    """A blank image (here white, as a transparent PNG is composited, or grey with a
    grey level of noise) has no face and no hair; the no-face parse took the centre's
    colours, which every pixel has, for hair: 100 % hair."""
    rng = np.random.default_rng(0)
    for level in (255.0, 128.0):
        img = np.clip(np.full((120, 160, 3), level) + rng.normal(0, noise, (120, 160, 3)),
                      0, 255).astype(np.uint8)
        r = _grabcut(img, None)
        assert not r.hair.any() and not r.face.any() and r.background.all()
    # a close-up of strands is not featureless: still hair
    hair = _grabcut(_strands(rng, (120, 160)).astype(np.uint8), None).hair
    assert hair.mean() > 0.5


@pytest.mark.slow
@pytest.mark.shared_data
def test_real_masks_mean_iou_floor(shared_data):
    """A regression floor on the real masks (measured 0.64 on CelebAMask); the goal of
    0.80 is reported by ``head360 bench fit``, not asserted."""
    import cv2

    from head360cli.fitting.landmarks import LandmarkDetector
    from head360cli.io.images import load_image

    det = LandmarkDetector("hog")
    ious = []
    for photo in sorted((shared_data / "hair" / "celebamask").glob("*.jpg"))[:4]:
        img = load_image(photo).pixels
        gt = cv2.imread(str(photo.with_name(photo.stem + "_hair.png")), 0)
        gt = cv2.resize(gt, img.shape[1::-1], interpolation=cv2.INTER_NEAREST) > 127
        ious.append(mask_iou(_grabcut(img, det.detect_one(img).landmarks).hair, gt))
    assert np.mean(ious) > 0.5


@pytest.mark.shared_data
def test_walls_above_bald_heads_are_not_hair(shared_data):
    """Development photos (not the bench's): the cap above a bald head lay on the
    backdrop and seeded it as hair, a wall of it: dlib's ``bald_guys`` (a yellow poster,
    3.2 % of the photo parsed as hair) and a VOC photo of a man with a receding
    hairline before a grey wall (5.6 %, fitted an afro). The learned prior, sure there
    is no hair there, vetoes those seeds: measured 0 % and 1.2 % (his thin hair)."""
    from head360cli.fitting.landmarks import LandmarkDetector
    from head360cli.io.images import load_image

    det = LandmarkDetector("hog")
    for name, most in (("bald_guys.jpg", 0.0), ("2009_004587.jpg", 0.02)):
        img = load_image(shared_data / "faces" / name).pixels
        hair = _grabcut(img, det.detect_one(img).landmarks).hair
        assert hair.mean() <= most, name


def test_a_dark_photo_is_parsed_as_its_bright_self(shared_data):
    """AFLW2000-3D 03614 (a development photo) at a tenth of its brightness: parsed as it
    was, its hair agreed with the bright photo's parse at IoU 0.847; on the stretched
    copy 0.989 (face 0.991, measured 2026-12-05)."""
    from head360cli.fitting.landmarks import LandmarkDetector
    from head360cli.io.images import load_image

    img = load_image(shared_data / "landmarks68" / "aflw2000" / "image03614.jpg").pixels
    dark = np.round(img * 0.1).astype(np.uint8)
    det = LandmarkDetector("hog")
    bright = _grabcut(img, det.detect_one(img).landmarks)
    parsed = _grabcut(dark, det.detect_one(dark).landmarks)
    assert mask_iou(parsed.hair, bright.hair) > 0.95, mask_iou(parsed.hair, bright.hair)
    assert mask_iou(parsed.face, bright.face) > 0.95, mask_iou(parsed.face, bright.face)


def test_skin_model_ignores_dark_outliers_in_the_cheek_samples():
    """Cheek polygons catch lashes and nostrils: 10 % dark samples must not widen the
    skin's lightness so far that dark hair passes for skin."""
    from head360cli.fitting.hair_parse import _colour_distance

    rng = np.random.default_rng(0)
    skin = rng.normal((150.0, 145.0, 140.0), 4.0, (540, 3))
    lashes = rng.normal((25.0, 130.0, 130.0), 4.0, (60, 3))
    samples = np.concatenate([skin, lashes])
    pixels = np.array([[[150.0, 145.0, 140.0], [30.0, 132.0, 133.0]]])  # skin, dark hair
    trimmed = _colour_distance(pixels, samples)
    assert trimmed[0, 0] < 1.0
    assert trimmed[0, 1] > 10.0
    # Without trimming the outliers, the same hair sits within 3 deviations of "skin".
    assert _colour_distance(pixels, samples, trims=0)[0, 1] < 3.0


@pytest.fixture(params=[None, "learned"])
def prior(request):
    """Each corpus case runs by colour and landmarks alone and with the shipped prior."""
    if request.param == "learned":
        from head360cli.fitting.hair_prior import default_hair_prior

        assert default_hair_prior() is not None, "models/hair_prior.pt is not installed"
    return request.param


def _corpus_portrait(index: int):
    """Held-out corpus head ``index`` of corpus seed 1 (the parse's development heads,
    not the bench's) seen as the bench sees them (yaw 10, pitch 5, 256 px, white
    backdrop): the photo, its 68 landmarks, the true hair mask and the head's
    silhouette."""
    import torch

    from head360cli.geometry.cameras import RIG_DISTANCE, camera_on_sphere, project
    from head360cli.mesh.bilinear import load_bilinear
    from head360cli.model.data import Views
    from head360cli.model.head_render import to_uint8

    views = Views(index + 1, split="test", seed=1, size=256)
    c2w = camera_on_sphere(torch.tensor([10.0]), torch.tensor([5.0]), RIG_DISTANCE)
    batch = views.render(index, np.zeros(52, np.float32), c2w, with_hair=True)
    px, _ = project(batch.verts[:1], c2w, views.intrinsics[None])
    lm = px[0].numpy()[load_bilinear().landmarks]
    return (to_uint8(batch.rgb)[0], lm, batch.hair_alpha[0, 0].numpy() > 0.5,
            batch.alpha[0, 0].numpy() > 0.5)


@pytest.mark.slow
def test_seeded_parse_keeps_light_hair_that_falls_past_the_face(prior):
    """Blond shoulder-length hair on a white backdrop: when only the face and neck
    seeded the person, GrabCut gave the hair to the backdrop and the parse was empty
    (IoU 0.0); with the cap's hair among the person's seeds it is found."""
    img, lm, truth, _ = _corpus_portrait(14)
    assert truth.mean() > 0.1  # the style covers a tenth of the frame
    # measured 0.988 alone, 0.984 with the prior
    assert mask_iou(_grabcut(img, lm, prior=prior).hair, truth) > 0.85


def test_seeded_parse_leaves_a_receding_scalp_out(prior):
    """A receding hairline: the scalp above the brows, lit brighter than the cheeks, is
    just outside the skin model; seeded as hair it was parsed as a pixie cut (IoU 0.28)."""
    img, lm, truth, _ = _corpus_portrait(26)
    hair = _grabcut(img, lm, prior=prior).hair
    assert hair.sum() < 1.5 * truth.sum()  # 3.5 times with the scalp as hair
    assert mask_iou(hair, truth) > 0.75  # measured 0.889 alone, 0.881 with the prior


def test_seeded_parse_of_a_bald_head_leaves_the_backdrop_out(prior):
    """Above a bald head the cap reaches into the white backdrop, which is far from the
    skin colour: seeded as the person's hair, a strip of backdrop became a buzz cut."""
    img, lm, truth, head = _corpus_portrait(0)
    assert not truth.any()  # style 0: bald
    hair = _grabcut(img, lm, prior=prior).hair
    assert not (hair & ~head).any()


def test_seeded_parse_follows_long_hair_off_the_bottom_of_the_frame(prior):
    """Long grey hair running off the bottom of the frame: with the whole frame edge
    certain backdrop, GrabCut's backdrop model held the hair's colour and the parse
    stopped at the chin (IoU 0.57); the bottom edge that has the hair's colours is left
    to GrabCut."""
    img, lm, truth, _ = _corpus_portrait(17)
    assert truth[-3:].any()  # the hair reaches the frame's bottom
    hair = _grabcut(img, lm, prior=prior).hair
    assert mask_iou(hair, truth) > 0.85  # measured 0.906 alone, 0.888 with the prior
    below = round(lm[8, 1]) + 5  # under the chin
    found = (hair & truth)[below:].sum() / truth[below:].sum()
    assert found > 0.5  # measured 0.69 alone, 0.62 with the prior; about 0 before


@pytest.mark.parametrize("index", [0, 30])
def test_seeded_parse_of_a_bald_head_finds_no_hair(index, prior):
    """Bald heads: lit spots on the scalp, unlike the cheeks, were parsed as a few small
    blobs of hair (1.3 % and 3.8 % of the face region for heads 0 and 30), and the
    classifier ranked a receding or buzz cut over bald; less hair than 5 % of the face
    region is no hair."""
    img, lm, truth, _ = _corpus_portrait(index)
    assert not truth.any()  # style 0: bald
    assert not _grabcut(img, lm, prior=prior).hair.any()


@pytest.mark.parametrize(("index", "alone", "learned"), [(24, 0.499, 0.994), (27, 0.284, 0.842)])
def test_learned_prior_finds_hair_that_colour_alone_gives_away(index, alone, learned):
    """Two development heads whose hair colour alone loses to the backdrop or the skin:
    the shipped prior's probable-hair labels recover it (IoU measured as given; head 27
    0.807 before the prior's sure hair also seeded it)."""
    from head360cli.fitting.hair_prior import default_hair_prior

    assert default_hair_prior() is not None, "models/hair_prior.pt is not installed"
    img, lm, truth, _ = _corpus_portrait(index)
    assert mask_iou(_grabcut(img, lm, prior=None).hair, truth) == pytest.approx(alone,
                                                                                  abs=0.02)
    assert mask_iou(_grabcut(img, lm).hair, truth) == pytest.approx(learned, abs=0.02)


def test_where_the_learned_prior_is_sure_the_pixel_is_the_persons(monkeypatch):
    """Development head 16 (long platinum hair on the white backdrop): its curtains have
    the backdrop's colours, and as probable person only, GrabCut's first pass gave them
    to the backdrop; where the prior is above PRIOR_SURE they are the person's."""
    import head360cli.fitting.hair_parse as hair_parse
    from head360cli.fitting.hair_prior import default_hair_prior

    assert default_hair_prior() is not None, "models/hair_prior.pt is not installed"
    img, lm, truth, _ = _corpus_portrait(16)
    sure = mask_iou(_grabcut(img, lm).hair, truth)
    monkeypatch.setattr(hair_parse, "PRIOR_SURE", 1.01)  # never sure: soft labels only
    soft = mask_iou(_grabcut(img, lm).hair, truth)
    assert sure == pytest.approx(0.925, abs=0.02)  # measured 0.925
    assert soft == pytest.approx(0.785, abs=0.02)  # measured 0.785


def test_the_person_pass_runs_at_person_side_and_finds_the_same_hair(monkeypatch):
    """The first GrabCut pass (the person against the background) runs on a copy at most
    PERSON_SIDE pixels long, the second at the working size; on a corpus head seen at
    512 px the hair is found as well as with both passes at the working size."""
    import cv2

    import head360cli.fitting.hair_parse as hp

    img, lm, hair, _ = _corpus_portrait(3)
    assert hair.sum() > 500  # a head with hair
    img = cv2.resize(img, (512, 512), interpolation=cv2.INTER_LINEAR)
    hair = cv2.resize(hair.astype(np.uint8), (512, 512), interpolation=cv2.INTER_NEAREST) > 0
    lm = lm * 2.0
    shapes = []
    real = hp._grabcut

    def spy(bgr, mask, iterations):
        shapes.append(mask.shape)
        return real(bgr, mask, iterations)

    monkeypatch.setattr(hp, "_grabcut", spy)
    fast = _grabcut(img, lm, prior=None)
    assert shapes == [(hp.PERSON_SIDE, hp.PERSON_SIDE), (384, 384)]
    shapes.clear()
    full = _grabcut(img, lm, prior=None, person_size=384)
    assert shapes == [(384, 384), (384, 384)]
    assert fast.hair.shape == hair.shape
    assert mask_iou(fast.hair, hair) > 0.93
    assert mask_iou(fast.hair, hair) > mask_iou(full.hair, hair) - 0.02
    assert mask_iou(fast.hair, full.hair) > 0.96


def _corpus_view(yaw: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(rgb, hair, head)`` of held-out corpus head 1 (white buzz cut, skin-coloured
    hair in the skin box) seen from ``yaw`` degrees, pitch 5, on a blue-grey wall, 256
    pixels."""
    import torch

    from head360cli.geometry.cameras import RIG_DISTANCE, camera_on_sphere
    from head360cli.model.data import Views

    data = Views(2, split="test", seed=0, size=256)
    cam = camera_on_sphere(torch.tensor([yaw]), torch.tensor([5.0]), RIG_DISTANCE)
    b = data.render(1, np.zeros(52, np.float32), cam, with_hair=True)
    alpha = b.alpha[0, 0].numpy()
    rgb = (b.rgb[0].permute(1, 2, 0).numpy() * alpha[..., None] * 255
           + np.array([120, 140, 160]) * (1 - alpha[..., None])).astype(np.uint8)
    return rgb, b.hair_alpha[0, 0].numpy() > 0.5, alpha > 0.5


@pytest.mark.parametrize("yaw", [65.0, -65.0])
def test_unseeded_profile_found_by_the_cascade_keeps_the_face_out(yaw):
    """A face in profile, light hair: the image's centre is the cheek and the ear, and
    the skin box holds the hair as well, so the parse took the whole head for hair
    (IoU 0.31 without the cascade). With the face in profile found, its cheek's colour
    is not hair: measured 0.986 / 0.972 (yaw 65 / -65), the face mask on the skin."""
    rgb, hair, head = _corpus_view(yaw)
    plain = _grabcut(rgb, None, profile=False)
    r = _grabcut(rgb, None)
    assert not plain.profile and r.profile and not r.seeded
    assert mask_iou(plain.hair, hair) < 0.5
    assert mask_iou(r.hair, hair) > 0.9
    assert r.face.any() and not (r.face & r.hair).any()
    assert (r.face & head & ~hair).sum() >= 0.95 * r.face.sum()


def test_unseeded_profile_needs_skin_colour_and_the_cascade(monkeypatch):
    """The same profile in grey levels has no skin colour, so the face the cascade finds
    is not believed; and where OpenCV has no profile cascade, the parse is the one
    without it, pixel for pixel."""
    from head360cli.fitting import landmarks

    rgb = _corpus_view(65.0)[0]
    grey = np.repeat(rgb.mean(2, keepdims=True).round().astype(np.uint8), 3, 2)
    assert landmarks.find_profile(grey[..., 0]) is not None  # the cascade finds it
    r = _grabcut(grey, None)
    assert not r.profile and not r.face.any()
    plain = _grabcut(rgb, None, profile=False)
    monkeypatch.setattr(landmarks, "_profile_cascade", lambda: None)
    r = _grabcut(rgb, None)
    assert not r.profile and np.array_equal(r.hair, plain.hair)


@pytest.mark.slow
def test_a_grey_photo_with_a_faint_cast_is_parsed_as_its_grey_self():
    """A black-and-white photo with a faint cast and noise (red and blue times 1.02 and
    0.98, noise of 2 grey levels) is greyscale to the fit and to the parse alike: its
    masks are the grey photo's (with the skin colour model, its face mask was 0.948 of
    them)."""
    from PIL import Image
    from skimage import data

    from head360cli.fitting.landmarks import find_faces, pick_face

    grey = np.asarray(Image.fromarray(data.astronaut()).convert("L").convert("RGB"))
    noise = np.random.default_rng(0).normal(0, 2, grey.shape)
    cast = np.clip(grey * (1.02, 1.0, 0.98) + noise, 0, 255).astype(np.uint8)
    face = pick_face(find_faces(grey, "hog"), 0, "hog", grey)
    a, b = (_grabcut(x, face.landmarks) for x in (grey, cast))
    assert mask_iou(b.face, a.face) > 0.99 and mask_iou(b.hair, a.hair) > 0.99


# ----------------------------------------------------------------- the segmenter


def _hair_photos(root):
    """``(name, photo, truth mask path)`` of the shared hair photos under ``root``."""
    for p in sorted((root / "figaro").glob("*-org.jpg")):
        yield "figaro", p, p.with_name(p.name.replace("-org.jpg", "-gt.pbm"))
    for p in sorted((root / "celebamask").glob("*.jpg")):
        yield "celebamask", p, p.with_name(p.stem + "_hair.png")


@pytest.mark.slow
def test_the_segmenter_parses_real_hair(shared_data):
    """Mean hair IoU over the 24 Figaro-1k and CelebAMask-HQ photos of ``hair/``: 0.770
    measured (over these and the 80 of ``hair_more/``: the segmenter 0.81, the GrabCut
    parser with the learned prior 0.58)."""
    import cv2

    from head360cli.fitting.landmarks import find_faces
    from head360cli.io.images import load_image

    ious = []
    for _, photo, truth in _hair_photos(shared_data / "hair"):
        img = load_image(photo).pixels
        gt = cv2.resize(cv2.imread(str(truth), 0), img.shape[1::-1],
                        interpolation=cv2.INTER_NEAREST) > 127
        faces = find_faces(img, "auto", only=0)
        ious.append(mask_iou(parse_hair(img, faces[0].landmarks if faces else None).hair, gt))
    assert len(ious) == 24
    assert np.mean(ious) > 0.75, ious


def test_the_segmenter_keeps_the_fitted_persons_hair_only():
    """Two astronauts side by side, the left one fitted: her hair is parsed, the other's
    is not; the face below the brows is never hair; the right one fitted, the mirror."""
    import skimage.data

    from head360cli.fitting.hair_parse import _face_outline, _poly
    from head360cli.fitting.landmarks import LandmarkDetector

    one = skimage.data.astronaut()
    pair = np.ascontiguousarray(np.concatenate([one, one[:, ::-1]], axis=1))
    faces = LandmarkDetector("auto").detect(pair)
    assert len(faces) == 2
    left = min(faces, key=lambda f: f.box[0])
    r = parse_hair(pair, left.landmarks)
    # the segmenter reads the 1024-wide pair at half scale: 1194 px of hair measured (9486
    # in the photo alone)
    assert r.hair[:, :512].sum() > 800 and r.hair[:, 512:].sum() == 0
    below_brows = _poly(r.hair.shape, _face_outline(left.landmarks.astype(np.float32), 0.0))
    assert not (r.hair & below_brows).any()
    assert (r.face & below_brows).mean() > 0.9 * below_brows.mean()
    right = max(faces, key=lambda f: f.box[0])
    mirrored = parse_hair(pair, right.landmarks).hair
    assert mirrored[:, :512].sum() == 0
    assert mask_iou(mirrored[:, 512:][:, ::-1], r.hair[:, :512]) > 0.9


def test_the_segmenter_without_a_face_parses_the_whole_photo():
    import skimage.data

    r = parse_hair(skimage.data.astronaut(), None)
    assert not r.seeded and r.hair.sum() > 2000 and not r.face.any()
    with pytest.raises(Exception, match="expected hair parser segmenter or grabcut"):
        parse_hair(skimage.data.astronaut(), None, method="scissors")

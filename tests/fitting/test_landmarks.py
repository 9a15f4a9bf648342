"""dlib landmarks: the mirror permutation and the averaged predictor."""

import numpy as np
import pytest

pytest.importorskip("dlib")


def _noisy(img: np.ndarray, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(img.astype(int) + rng.integers(-1, 2, img.shape), 0, 255).astype(np.uint8)


def test_mirror_is_an_involution_that_fixes_the_midline():
    from head360cli.fitting.landmarks import MIRROR_68

    assert sorted(MIRROR_68.tolist()) == list(range(68))
    np.testing.assert_array_equal(MIRROR_68[MIRROR_68], np.arange(68))
    fixed = {8, 27, 28, 29, 30, 33, 51, 57, 62, 66}  # chin, nose, lips' midpoints
    assert {i for i in range(68) if MIRROR_68[i] == i} == fixed
    # left eye's outer corner <-> right eye's outer corner, mouth corners swap
    assert MIRROR_68[36] == 45 and MIRROR_68[48] == 54 and MIRROR_68[0] == 16


def test_mirror_maps_the_predictor_on_a_flipped_photo_back():
    """Run on the mirror image and mapped back, the points land where the plain run put
    them (within a pixel); without the permutation the eyes would swap (tens of px)."""
    import skimage.data

    from head360cli.fitting.landmarks import MIRROR_68, LandmarkDetector, _points, _predictor

    img = skimage.data.astronaut()
    face = LandmarkDetector("hog", average=False).detect_one(img)
    x0, y0, x1, y1 = (int(v) for v in face.box)
    last = img.shape[1] - 1
    flipped = _points(_predictor(), np.ascontiguousarray(img[:, ::-1]),
                      (last - x1, y0, last - x0, y1))
    flipped[:, 0] = last - flipped[:, 0]
    err = np.linalg.norm(flipped[MIRROR_68] - face.landmarks, axis=1).mean()
    assert err < 1.0, err
    assert np.linalg.norm(flipped - face.landmarks, axis=1).mean() > 20.0


def test_averaged_landmarks_move_less_under_noise():
    """Astronaut and three copies one grey level off, the same box: the plain predictor's
    points spread by 0.24 px about their mean, the averaged ones' by 0.09 px (measured);
    the averaged points stay within a pixel of the plain ones."""
    import skimage.data

    from head360cli.fitting.landmarks import LandmarkDetector

    img = skimage.data.astronaut()

    def spread(average: bool) -> tuple[float, np.ndarray]:
        det = LandmarkDetector("hog", average=average)
        runs = np.array([det.detect_one(img if s == 0 else _noisy(img, s)).landmarks
                         for s in range(4)])
        return float(np.linalg.norm(runs - runs.mean(0), axis=-1).mean()), runs[0]

    plain, one = spread(False)
    averaged, mean = spread(True)
    assert averaged < 0.5 * plain, (averaged, plain)
    assert np.linalg.norm(mean - one, axis=1).mean() < 1.0
    assert mean.dtype == np.float64 and mean.shape == (68, 2)


def test_averaging_commutes_with_mirroring():
    """The averaged boxes are a mirror-symmetric set, so the mean on the mirrored photo
    is the mirror of the mean on the photo."""
    import skimage.data

    from head360cli.fitting.landmarks import MIRROR_68, _averaged, _predictor

    img = skimage.data.astronaut()
    mirrored = np.ascontiguousarray(img[:, ::-1])
    predictor = _predictor()
    last = img.shape[1] - 1
    box = (175, 76, 265, 166)
    a = _averaged(predictor, img, mirrored, box)
    b = _averaged(predictor, mirrored, img, (last - box[2], box[1], last - box[0], box[3]))
    b[:, 0] = last - b[:, 0]
    np.testing.assert_allclose(b[MIRROR_68], a, atol=1e-9)


def test_only_the_chosen_face_is_averaged():
    """Two astronauts (HOG finds a third, weak box too), ``only=1``: the second face's
    landmarks are the averaged ones, every other face's a single predictor run, the
    order by size unchanged."""
    import cv2
    import skimage.data

    from head360cli.fitting.landmarks import LandmarkDetector

    img = skimage.data.astronaut()
    small = cv2.resize(img, (384, 384), interpolation=cv2.INTER_AREA)
    pair = np.zeros((512, 896, 3), np.uint8)
    pair[:, :512], pair[:384, 512:] = img, small
    every = LandmarkDetector("hog").detect(pair)
    plain = LandmarkDetector("hog", average=False).detect(pair)
    chosen = LandmarkDetector("hog").detect(pair, only=1)
    assert len(every) == len(chosen) >= 2 and every[0].area > every[1].area
    assert [f.box for f in chosen] == [f.box for f in every] == [f.box for f in plain]
    np.testing.assert_array_equal(chosen[1].landmarks, every[1].landmarks)
    for rank in [0, *range(2, len(chosen))]:
        np.testing.assert_array_equal(chosen[rank].landmarks, plain[rank].landmarks)
    assert not np.array_equal(every[0].landmarks, plain[0].landmarks)


def test_the_face_mesh_reads_a_cut_face_as_it_reads_the_whole_photo():
    """The astronaut cut off above the brows (as hair close-ups cut faces): dlib's HOG
    finds no face; the default detector does, and its 68 landmarks land where the whole
    photo's do (measured 0.5 px mean), with the mesh's 478 points and 52 scores."""
    import skimage.data

    from head360cli.fitting.landmarks import LandmarkDetector

    img = skimage.data.astronaut()
    whole = LandmarkDetector("auto").detect(img)
    assert whole and whole[0].detector == "blazeface"
    cut = np.ascontiguousarray(img[100:350, 100:340])
    assert LandmarkDetector("hog").detect(cut) == []
    found = LandmarkDetector("auto").detect_one(cut)
    assert found.mesh.shape == (478, 3) and found.blendshapes.shape == (52,)
    err = np.linalg.norm(found.landmarks - (whole[0].landmarks - [100, 100]), axis=1).mean()
    assert err < 2.0, err


def test_scaled_detection_boxes_are_in_the_images_pixels():
    """``max_side`` detects on a smaller copy; its boxes are mapped back to the image
    (HOG's box sizes come in steps, so the box moves by up to 7 px of its 90, measured;
    boxes left at the copy's scale would be 58 px off) and the landmarks stay put."""
    import skimage.data

    from head360cli.fitting.landmarks import LandmarkDetector

    img = skimage.data.astronaut()
    full = LandmarkDetector("hog", average=False).detect_one(img)
    half = LandmarkDetector("hog", average=False, max_side=384).detect_one(img)
    assert np.abs(np.subtract(full.box, half.box)).max() < 0.12 * (full.box[2] - full.box[0])
    assert np.linalg.norm(full.landmarks - half.landmarks, axis=1).mean() < 3.0


def test_bad_detector_names_and_no_face_hints():
    from head360cli.errors import BadInputError, NoFaceError
    from head360cli.fitting.landmarks import LandmarkDetector

    with pytest.raises(BadInputError, match="expected detector auto, yunet, blazeface, hog, "
                                            "cnn, found 'x'"):
        LandmarkDetector("x")
    wall = np.full((120, 160, 3), 128, np.uint8)
    with pytest.raises(NoFaceError, match="neither YuNet nor BlazeFace"):
        LandmarkDetector("auto").detect_one(wall)
    with pytest.raises(NoFaceError, match="try --detector auto, or cnn"):
        LandmarkDetector("hog").detect_one(wall)



def test_a_negative_face_number_is_refused_not_taken_from_the_end():
    """pick_face(faces, -1) returned the smallest face (Python's indexing): classify-hair
    --face -1 classified it without a word."""
    from head360cli.errors import BadInputError
    from head360cli.fitting.landmarks import DetectedFace, pick_face

    faces = [DetectedFace((0.0, 0.0, 9.0, 9.0), 1.0, np.zeros((68, 2)), "hog")] * 2
    assert pick_face(faces, 1, "hog") is faces[1]
    with pytest.raises(BadInputError, match="expected a face number >= 0, found -1"):
        pick_face(faces, -1, "hog")
    # from Python, a fraction was a TypeError from list indexing
    assert pick_face(faces, np.int64(1), "hog") is faces[1]
    with pytest.raises(BadInputError, match=r"expected a face number >= 0, found 1\.5"):
        pick_face(faces, 1.5, "hog")


@pytest.mark.slow
@pytest.mark.parametrize("degrees, turn", [(60.0, -60.0), (-90.0, 90.0), (45.0, -30.0)])
def test_a_tilted_face_is_found_in_a_turned_copy(degrees, turn):
    """The astronaut tilted 45 to 90 degrees: HOG finds no face as it lies;
    ``detect_turned`` finds hers in the copy turned back nearest to upright (45 degrees:
    the -30 copy, where she leans 15 degrees; in the -60 one a false face on the
    repeated edges is larger), with landmarks within a pixel of the upright photo's
    turned (measured 0.42, 0.00 and 0.44 px)."""
    import skimage.data

    from head360cli.fitting.landmarks import LandmarkDetector, turned_image

    img = skimage.data.astronaut()
    upright = LandmarkDetector("hog").detect_one(img)
    tilted, forward = turned_image(img, degrees)
    assert LandmarkDetector("hog").detect(tilted) == []
    found = LandmarkDetector("hog").detect_turned(tilted)
    assert len(found) == 1 and found[0].turn == turn
    expected = upright.landmarks @ forward[:, :2].T + forward[:, 2]
    err = np.linalg.norm(found[0].landmarks - expected, axis=1).mean()
    assert err < 1.0, err
    centre = np.add(found[0].box[:2], found[0].box[2:]) / 2
    assert np.linalg.norm(centre - expected.mean(0)) < 0.25 * (upright.box[2] - upright.box[0])


def test_no_face_in_any_turn_of_a_photo_without_one():
    import skimage.data

    from head360cli.fitting.landmarks import LandmarkDetector

    assert LandmarkDetector("hog").detect_turned(skimage.data.coffee()) == []


def test_hog_detector_is_kept_in_the_cache_and_finds_the_same_faces(tmp_path, monkeypatch):
    """The detector read back from the cache is dlib's: same boxes, scores and sub-detector
    ids on a photo with a face and a weak second hit; the second process-like call reads the
    file instead of unpacking dlib's built-in copy."""
    import dlib
    import skimage.data

    from head360cli.fitting.landmarks import hog_detector

    monkeypatch.setenv("HEAD360_CACHE", str(tmp_path / "cache"))
    img = skimage.data.astronaut()
    reference = dlib.get_frontal_face_detector().run(img, 1, -0.5)
    first = hog_detector()
    files = list((tmp_path / "cache").iterdir())
    assert [f.name for f in files] == [f"dlib-{dlib.__version__}-frontal_face.svm"]

    def unpacked_again():
        raise AssertionError("the cached detector should have been read")

    monkeypatch.setattr(dlib, "get_frontal_face_detector", unpacked_again)
    second = hog_detector()
    for det in (first, second):
        boxes, scores, ids = det.run(img, 1, -0.5)
        assert len(boxes) == len(reference[0]) >= 2
        assert [(b.left(), b.top(), b.right(), b.bottom()) for b in boxes] == [
            (b.left(), b.top(), b.right(), b.bottom()) for b in reference[0]]
        np.testing.assert_allclose(scores, reference[1], rtol=0, atol=1e-12)
        assert list(ids) == list(reference[2])


def test_hog_detector_without_a_usable_cache(tmp_path, monkeypatch):
    import dlib
    import skimage.data

    from head360cli.fitting.landmarks import hog_detector

    img = skimage.data.astronaut()
    expected = len(dlib.get_frontal_face_detector()(img, 1))
    # a damaged file is made again and written over
    folder = tmp_path / "cache"
    folder.mkdir()
    damaged = folder / f"dlib-{dlib.__version__}-frontal_face.svm"
    damaged.write_bytes(b"not a detector")
    monkeypatch.setenv("HEAD360_CACHE", str(folder))
    assert len(hog_detector()(img, 1)) == expected
    assert dlib.fhog_object_detector(str(damaged)).num_detectors == 5
    # a cache that cannot be made (a file where the folder should be) costs only time
    blocked = tmp_path / "blocked"
    blocked.write_text("a file")
    monkeypatch.setenv("HEAD360_CACHE", str(blocked))
    assert len(hog_detector()(img, 1)) == expected
    assert blocked.read_text() == "a file"
    # an empty HEAD360_CACHE turns the cache off
    monkeypatch.setenv("HEAD360_CACHE", "")
    monkeypatch.chdir(tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    assert len(hog_detector()(img, 1)) == expected
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_an_image_without_a_face_does_not_load_the_predictor():
    """The 68-point predictor takes about 1 s to load; an image where the detector finds
    no face (a hair close-up, a back view) is searched without it."""
    import skimage.data

    from head360cli.fitting.landmarks import LandmarkDetector, _predictor, find_faces

    _predictor.cache_clear()
    blank = np.full((120, 160, 3), 200, np.uint8)
    assert LandmarkDetector("hog").detect(blank) == []
    assert find_faces(blank, "hog") == []
    assert _predictor.cache_info().misses == 0
    faces = LandmarkDetector("hog").detect(skimage.data.astronaut())
    assert faces and all(f.landmarks.shape == (68, 2) for f in faces)
    assert _predictor.cache_info().misses == 1


@pytest.mark.slow
def test_profile_cascade_finds_either_side_and_not_a_back_view():
    """A held-out corpus head (1) turned 65 degrees: found looking to the image's left;
    its mirror image, looking right, with the mirrored box; seen from behind, nothing."""
    import cv2

    from head360cli.fitting.landmarks import find_profile
    from tests.fitting.test_hair_parse import _corpus_view

    grey = cv2.cvtColor(_corpus_view(65.0)[0], cv2.COLOR_RGB2GRAY)
    left = find_profile(grey)
    right = find_profile(np.ascontiguousarray(grey[:, ::-1]))
    assert left is not None and right is not None
    assert (left.facing, right.facing) == (-1, 1)
    w = grey.shape[1]
    assert right.box == (w - left.box[2], left.box[1], w - left.box[0], left.box[3])
    assert find_profile(cv2.cvtColor(_corpus_view(180.0)[0], cv2.COLOR_RGB2GRAY)) is None
    assert find_profile(np.zeros((8, 8), np.uint8)) is None


@pytest.mark.slow
def test_an_upside_down_photo_is_named_as_such_when_no_face_is_found(run_cli, tmp_path):
    """No face upside down, nor in the turned copies (up to 90 degrees): the fit said only
    "no face found" of a photo whose EXIF orientation was lost."""
    import skimage.data
    from PIL import Image

    from head360cli.fitting.landmarks import upside_down

    img = skimage.data.astronaut()
    assert upside_down(np.ascontiguousarray(img[::-1, ::-1]))
    assert not upside_down(img[::-1, ::-1] * 0 + 128)  # nothing at all
    assert not upside_down(skimage.data.coffee())
    path = tmp_path / "turned.png"
    Image.fromarray(np.ascontiguousarray(img[::-1, ::-1])).save(path)
    r = run_cli("fit", path, "-o", tmp_path / "x.h360")
    assert r.code == 4 and "but one upside down: turn the photo upright" in r.err, r.err
    assert not (tmp_path / "x.h360").exists()


def test_a_full_range_photo_is_not_stretched():
    import skimage.data

    from head360cli.fitting.landmarks import stretched

    img = skimage.data.astronaut()
    assert stretched(img) is img


def test_a_nearly_blank_image_is_not_stretched():
    """A flat grey with a grey level or three of noise spans under ``FLAT_SPREAD``
    levels: stretched, its noise would fill the range (and the hair parse read it as
    hair everywhere)."""
    from head360cli.fitting.landmarks import stretched

    rng = np.random.default_rng(0)
    for noise in (1.0, 2.0):
        img = np.clip(128 + rng.normal(0, noise, (120, 160, 3)), 0, 255).astype(np.uint8)
        assert stretched(img) is img


def test_a_dark_photo_is_stretched_to_the_full_range_keeping_its_hue():
    """Brightness times 0.06 spans about 15 grey levels; the copy spans 0 to 255 at its
    0.5th and 99.5th percentiles, with the channels' order in each pixel kept."""
    import skimage.data

    from head360cli.fitting.landmarks import LOW_CONTRAST_SPREAD, stretched

    img = skimage.data.astronaut()
    dark = np.round(img * 0.06).astype(np.uint8)
    out = stretched(dark)
    assert out.shape == dark.shape and out.dtype == np.uint8
    y = out.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
    lo, hi = np.percentile(y, [0.5, 99.5])
    assert lo < 5 and hi > 250, (lo, hi)
    assert np.percentile(y, 99.5) - np.percentile(y, 0.5) >= LOW_CONTRAST_SPREAD
    # a map that rises with the level: a channel brighter than another stays so
    d = dark.astype(int)
    o = out.astype(int)
    assert not np.any((d[..., 0] > d[..., 1]) & (o[..., 0] < o[..., 1]))
    # and a grey image stays grey
    grey = np.repeat(dark[..., :1], 3, axis=2)
    g = stretched(grey)
    assert np.array_equal(g[..., 0], g[..., 1]) and np.array_equal(g[..., 1], g[..., 2])


def test_a_dark_photos_face_is_found_with_its_landmarks_in_place():
    """The astronaut at 0.06 of her brightness: HOG on the photo as it is finds no face
    (measured 2026-12-05; at 0.15 it found her with the points 1.4 px off on average);
    searched on the stretched copy, she is found with every point within 1 px of where
    it lies in the photo at full brightness (0.3 px measured)."""
    import skimage.data

    from head360cli.fitting.landmarks import LandmarkDetector

    img = skimage.data.astronaut()
    det = LandmarkDetector("hog", average=False)
    full = det.detect_one(img).landmarks
    dark = np.round(img * 0.06).astype(np.uint8)
    found = det.detect_one(dark).landmarks
    assert np.abs(found - full).mean() < 1.0, np.abs(found - full).mean()


def test_mouth_opening_is_the_lip_gap_over_the_eye_corners_distance():
    from head360cli.fitting.landmarks import mouth_opening

    lm = np.zeros((68, 2))
    lm[36], lm[45] = (10.0, 50.0), (90.0, 50.0)  # eye corners 80 px apart
    lm[61:64] = [(40.0, 100.0), (50.0, 100.0), (60.0, 100.0)]  # upper inner lip
    lm[65:68] = [(60.0, 108.0), (50.0, 108.0), (40.0, 108.0)]  # lower, right to left
    assert mouth_opening(lm) == pytest.approx(8 / 80)
    assert mouth_opening(lm * 3.0 + 7.0) == pytest.approx(8 / 80)  # any scale and place
    lm[65:68] = lm[[63, 62, 61]]
    assert mouth_opening(lm) == 0.0  # closed lips
    lm[45] = lm[36]
    assert np.isnan(mouth_opening(lm))  # no scale to measure by: never counted closed

"""The fit's stages as functions: the checks that say a fit went wrong."""

from __future__ import annotations

import numpy as np

from head360cli.fitting.stages import LOW_FACE_PSNR, MANY_AT_LIMIT, check_fit
from head360cli.mesh.arkit52 import ARKIT52, INDEX


def _weights(**named: float) -> np.ndarray:
    w = np.zeros(52)
    for name, value in named.items():
        w[INDEX[name]] = value
    return w


def test_a_good_fit_passes_its_checks_without_a_word():
    checks = check_fit(_weights(mouthSmileLeft=1.0, mouthSmileRight=0.8, jawOpen=0.2), 24.0)
    assert checks.face_psnr_low is False
    assert checks.weights_at_limit == ["mouthSmileLeft"]
    assert checks.opposed_pairs == []
    assert checks.warnings(24.0) == []


def test_a_fit_that_went_wrong_says_so():
    """A smiling portrait fitted at 16 dB, 16 of 52 weights at 1, a pucker beside a smile
    and wide eyes beside a squint: each is named."""
    w = np.zeros(52)
    w[:16] = 1.0
    w[INDEX["mouthPucker"]] = w[INDEX["mouthSmileLeft"]] = 1.0
    checks = check_fit(w, 16.2)
    assert checks.face_psnr_low is True
    assert checks.weights_at_limit == [n for n in ARKIT52 if w[INDEX[n]] == 1.0]
    assert ["eyeWideLeft", "eyeSquintLeft"] in checks.opposed_pairs
    assert ["mouthSmileLeft", "mouthPucker"] in checks.opposed_pairs
    said = checks.warnings(16.2)
    assert said[0].startswith(f"the fitted head matches the photo poorly at its own view "
                              f"(face PSNR 16.2 dB, under {LOW_FACE_PSNR:g})")
    assert said[1].startswith(f"the expression fit put {len(checks.weights_at_limit)} of 52 "
                              "blendshapes at their limit (eyeBlinkLeft,")
    assert said[2].startswith("the expression fit shows opposed blendshapes together "
                              "(eyeWideLeft with eyeSquintLeft")
    # the thresholds: one short of many at the limit says nothing of it
    from head360cli.mesh.arkit52 import OPPOSED

    unpaired = [n for n in ARKIT52 if not any(n in pair for pair in OPPOSED)]
    few = _weights(**dict.fromkeys(unpaired[:MANY_AT_LIMIT - 1], 1.0))
    assert check_fit(few, 30.0).warnings(30.0) == []
    many = _weights(**dict.fromkeys(unpaired[:MANY_AT_LIMIT], 1.0))
    assert len(check_fit(many, 30.0).warnings(30.0)) == 1


def test_only_skin_coloured_pixels_around_the_face_join_the_texture_loss():
    from head360cli.fitting.stages import skin_coloured

    crop = np.zeros((32, 32, 3), np.uint8)
    crop[:] = (40, 120, 130)  # a blue-green collar and backdrop
    crop[:16] = (200, 150, 130)  # skin above
    crop[16:20, :8] = (185, 138, 120)  # the neck's skin in shadow, a shade darker
    skin = np.zeros((32, 32), bool)
    skin[:12] = True
    around = np.zeros((32, 32), bool)
    around[12:] = True
    keep = skin_coloured(crop, skin, around)
    assert keep[12:16].all() and keep[16:20, :8].all()
    assert not keep[16:20, 8:].any() and not keep[20:].any()
    assert not keep[:12].any()  # only pixels of ``around``
    assert not skin_coloured(crop, np.zeros_like(skin), around).any()  # no skin seen


def test_the_face_next_to_the_hair_is_left_out_of_the_texture_fit():
    """The parsed hair's soft edge stays out of the fit: the face pixels within
    HAIR_MARGIN of the hair (3 at 256 pixels), and only face pixels."""
    from head360cli.fitting.stages import HAIR_MARGIN, hair_edge

    hair = np.zeros((256, 256), bool)
    hair[:80] = True  # a fringe down to row 80
    face = np.zeros((256, 256), bool)
    face[60:200, 60:200] = True  # the segmenter's face runs under the fringe
    edge = hair_edge(hair, face)
    reach = round(HAIR_MARGIN * 256)
    assert reach == 3
    rows = np.nonzero(edge.any(1))[0]
    assert rows.min() == 60 and rows.max() == 79 + reach  # under the hair, and 3 below
    assert not (edge & ~face).any()
    assert edge[79 + reach, 60:200].all() and not edge[80 + reach].any()
    assert not hair_edge(np.zeros_like(hair), face).any()  # no hair, nothing left out

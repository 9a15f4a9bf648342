"""The hair's measures of ``bench multiview``: colour difference, reading as hair and
stair steps on a silhouette."""

from __future__ import annotations

import numpy as np
import pytest

from head360cli.bench.hair import (
    hair_colour_difference,
    median_lab,
    reads_as_hair,
    silhouette_steps,
)

YY, XX = np.mgrid[:256, :256]


@pytest.mark.parametrize("mask", [
    (YY - 128) ** 2 + (XX - 128) ** 2 < 60 ** 2,  # a disk
    ((YY - 128) / 40) ** 2 + ((XX - 128) / 110) ** 2 < 1,  # a flat ellipse
    ((XX - 128) * np.sin(0.5) - (YY - 128) * np.cos(0.5) < 0)  # a slanted edge in a box
    & (np.abs(XX - 128) < 80) & (np.abs(YY - 128) < 80),
    (np.abs(XX - 128) < 60) & (np.abs(YY - 128) < 40),  # a box's corners
])
def test_smooth_edges_and_slopes_have_no_steps(mask):
    assert silhouette_steps(mask) == 0


@pytest.mark.parametrize(("rise", "steps"), [(1, 0), (2, 19), (3, 19), (5, 38)])
def test_a_staircase_counts_each_rise_of_two_pixels_or_more(rise, steps):
    """Treads of 8 px over 160 columns: 19 rises; a rise of 5 is also a run of 5 rows
    whose edge jumps 8 columns, so it counts from both sides."""
    top = 60 + rise * ((XX - 40) // 8)
    mask = (top <= YY) & (XX >= 40) & (XX < 200) & (YY < 220)
    assert silhouette_steps(mask) == steps


def test_median_colour_ignores_a_minority_of_stray_pixels():
    from skimage.color import rgb2lab

    img = np.zeros((20, 20, 3), np.uint8)
    img[:] = (120, 80, 40)  # brown hair
    img[:4] = (250, 220, 200)  # a fifth of it skin
    mask = np.ones((20, 20), bool)
    np.testing.assert_allclose(median_lab(img, mask),
                               rgb2lab(np.array([[[120, 80, 40]]], np.uint8))[0, 0],
                               atol=1e-6)


def test_hair_colour_difference_is_ciede2000_of_the_medians():
    a = np.full((16, 16, 3), (120, 80, 40), np.uint8)
    b = np.full((16, 16, 3), (60, 40, 20), np.uint8)
    mask = np.ones((16, 16), bool)
    assert hair_colour_difference(a, mask, a, mask) == pytest.approx(0.0, abs=1e-9)
    far = hair_colour_difference(a, mask, b, mask)
    # brown against a darker brown (L* 37.6 against 18.0): measured 16.27
    assert far == pytest.approx(16.27, abs=0.01)
    few = np.zeros((16, 16), bool)
    few[:2, :2] = True
    assert hair_colour_difference(a, few, b, mask) is None


def test_the_segmenter_reads_real_hair_and_not_a_grey_blob():
    from PIL import Image
    from skimage import data

    from head360cli.bench.hair import segmented_hair

    photo = np.asarray(Image.fromarray(data.astronaut()).resize((256, 256)))
    hair = segmented_hair(photo)
    assert 0.03 < hair.mean() < 0.07  # her short hair: measured 0.045 of the image
    assert reads_as_hair(photo, hair)
    blob = np.full((256, 256, 3), 255, np.uint8)
    disk = (YY - 100) ** 2 + (XX - 128) ** 2 < 70 ** 2
    blob[disk] = 128
    assert reads_as_hair(blob, disk) is False
    assert reads_as_hair(blob, np.zeros((256, 256), bool)) is None

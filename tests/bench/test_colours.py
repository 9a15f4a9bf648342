"""Colour outliers: render pixels whose colour the photo's skin and hair do not have."""

from __future__ import annotations

import numpy as np
import pytest

from head360cli.bench.colours import outlier_share
from head360cli.fitting.colours import palette as photo_palette


def test_colours_of_the_photo_are_not_outliers_and_others_are():
    photo = np.zeros((40, 40, 3), np.uint8)
    photo[:, :20] = (200, 150, 130)  # skin
    photo[:, 20:] = (60, 40, 30)  # hair
    photo[0, 0] = (0, 0, 255)  # outside the mask: not in the palette
    mask = np.ones((40, 40), bool)
    mask[0, 0] = False
    palette = photo_palette(photo, mask)
    render = np.zeros((2, 20, 20, 3), np.uint8)
    render[:] = (200, 150, 130)
    render[0, :5] = (0, 0, 255)  # a blue streak over a quarter of the head
    render[1, :, :10] = (61, 41, 31)  # hair, a level off
    alpha = np.ones((2, 20, 20))
    alpha[1, 10:] = 0.0  # half the second render is backdrop
    shares = outlier_share(render, alpha, palette)
    assert shares[0] == 0.25
    assert shares[1] == 0.0
    assert outlier_share(render[:1], np.zeros((1, 20, 20)), palette) == [None]


def test_palette_distance_is_cie76_to_the_nearest_colour():
    from head360cli.fitting.colours import palette_distance, to_lab

    colours = to_lab(np.array([[255, 255, 255], [0, 0, 0]], np.uint8))
    d = palette_distance(np.array([[255, 255, 255], [10, 10, 10], [255, 0, 0]], np.uint8),
                         colours)
    assert d[0] < 1e-3 and 0 < d[1] < 5
    red = to_lab(np.array([255, 0, 0], np.uint8))
    assert d[2] == pytest.approx(min(np.linalg.norm(red - c) for c in colours), rel=1e-6)
    assert palette_distance(np.zeros((0, 3), np.uint8), colours).shape == (0,)


def test_grey_renders_are_grey_in_every_channel():
    from head360cli.bench.colours import as_grey

    g = as_grey(np.array([[[255, 0, 0], [10, 200, 30]]], np.uint8))
    assert (g[..., 0] == g[..., 1]).all() and (g[..., 1] == g[..., 2]).all()
    assert g[0, 0, 0] == 76 and g[0, 1, 0] == round(0.299 * 10 + 0.587 * 200 + 0.114 * 30)

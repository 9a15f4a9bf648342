"""Colour outliers: render pixels whose colour the photo's skin and hair do not have."""

from __future__ import annotations

import numpy as np

from head360cli.bench.colours import outlier_share, photo_palette


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

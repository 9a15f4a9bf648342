"""Eyelid helpers: the mask growth that replaced scipy.ndimage in a fit."""

import numpy as np
import pytest
from scipy import ndimage

from head360cli.mesh.eyelids import grow_mask


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("steps", [0, 1, 3, 8])
def test_grow_mask_is_scipys_binary_dilation(seed, steps):
    rng = np.random.default_rng(seed)
    h, w = rng.integers(1, 50, 2)
    mask = rng.random((h, w)) < rng.uniform(0.005, 0.3)
    mask[0, 0] = True  # something at the border: grown inwards only
    expected = ndimage.binary_dilation(mask, iterations=steps) if steps else mask
    grown = grow_mask(mask, steps)
    assert grown.dtype == bool and grown.shape == mask.shape
    np.testing.assert_array_equal(grown, expected)


def test_grow_mask_grows_a_point_into_a_diamond():
    mask = np.zeros((9, 9), bool)
    mask[4, 4] = True
    grown = grow_mask(mask, 2)
    rows, cols = np.nonzero(grown)
    assert (np.abs(rows - 4) + np.abs(cols - 4) <= 2).all() and grown.sum() == 13

"""Colour spaces: ICC profiles made from primaries, and a HEIF's nclx code points."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image, ImageCms

from head360cli.io.colour import SRGB_TRC, matrix_profile, nclx_profile

SRGB_PRIMARIES = ((0.64, 0.33), (0.30, 0.60), (0.15, 0.06))
P3_PRIMARIES = ((0.68, 0.32), (0.265, 0.69), (0.15, 0.06))
D65 = (0.3127, 0.329)


def _nclx(primaries: int, transfer: int, xy=P3_PRIMARIES) -> dict:
    """pillow-heif's ``nclx_profile`` for these code points and primaries."""
    out = {"color_primaries": primaries, "transfer_characteristics": transfer,
           "matrix_coefficients": 6, "full_range_flag": 1,
           "color_primary_white_x": D65[0], "color_primary_white_y": D65[1]}
    for name, (x, y) in zip(("red", "green", "blue"), xy, strict=True):
        out[f"color_primary_{name}_x"], out[f"color_primary_{name}_y"] = x, y
    return out


def test_a_profile_of_srgb_s_primaries_and_curve_is_srgb():
    """Built from sRGB's primaries, white and curve, the profile converts no colour of a
    grid by more than one level: the colorants, the adaptation to D50 and the sampled
    curve are right."""
    ours = ImageCms.ImageCmsProfile(io.BytesIO(matrix_profile(SRGB_PRIMARIES, D65, SRGB_TRC,
                                                              "sRGB by head360")))
    assert ImageCms.getProfileDescription(ours).strip() == "sRGB by head360"
    srgb = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB"))
    levels = np.linspace(0, 255, 18).round().astype(np.uint8)
    grid = np.stack(np.meshgrid(levels, levels, levels), -1).reshape(1, -1, 3)
    moved = np.asarray(ImageCms.profileToProfile(Image.fromarray(grid), ours, srgb),
                       np.int16) - grid
    assert np.abs(moved).max() <= 1


def test_nclx_code_points_become_a_profile_or_none():
    assert nclx_profile(None) is None
    assert nclx_profile(_nclx(1, 13, SRGB_PRIMARIES)) is None  # sRGB's primaries
    assert nclx_profile(_nclx(2, 2)) is None  # unspecified
    p3 = ImageCms.ImageCmsProfile(io.BytesIO(nclx_profile(_nclx(12, 13))))
    assert ImageCms.getProfileDescription(p3).strip() == "Display P3 (nclx, transfer 13)"
    with pytest.raises(ValueError, match="transfer characteristics 16"):  # PQ: HDR
        nclx_profile(_nclx(9, 16))


def test_a_heif_in_display_p3_given_by_nclx_is_converted(tmp_path):
    """A HEIF that says its colour space with nclx code points (Display P3) and holds no
    ICC profile was read as sRGB, as photos with an embedded profile were before."""
    pytest.importorskip("pillow_heif")
    from head360cli.io.images import describe_image, load_image

    colours = np.array([[[200, 150, 120], [90, 160, 60], [230, 40, 40], [128, 128, 128],
                         [20, 40, 200], [250, 220, 180]]], np.uint8).repeat(32, 0).repeat(
                            32, 1)
    p3 = ImageCms.ImageCmsProfile(io.BytesIO(nclx_profile(_nclx(12, 13))))
    srgb = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB"))
    encoded = ImageCms.profileToProfile(Image.fromarray(colours), srgb, p3, outputMode="RGB")
    assert np.abs(np.asarray(encoded).astype(int) - colours).max() >= 15
    import pillow_heif

    pillow_heif.register_heif_opener()
    path = tmp_path / "p3.heic"
    encoded.save(path, quality=95, chroma=444, color_primaries=12,
                 transfer_characteristics=13, matrix_coefficients=6, full_range_flag=1)
    img = load_image(path)
    assert img.colour_profile == "Display P3 (nclx, transfer 13)"
    centres = img.pixels[16, 16::32].astype(int)
    assert np.abs(centres - colours[0, ::32]).max() <= 5, centres
    said = describe_image(path)
    assert (said["colour_profile"], said["converted"]) == (img.colour_profile, True)

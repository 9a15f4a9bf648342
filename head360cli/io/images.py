"""Loading photos: EXIF orientation, grey, RGBA, 16-bit, and guards against bad files.

Policy for large images (documented in the README):

- Images with more than :data:`MAX_PIXELS` pixels (default 100 megapixels) are refused
  with a :class:`~head360cli.errors.BadInputError` before any pixel is decoded, so a
  decompression bomb cannot exhaust memory.
- Images whose longer side exceeds ``max_side`` (default 4096) are downscaled on load;
  :attr:`LoadedImage.scale` records the factor so that results can be mapped back to the
  pixels of the image as given on disk. JPEGs are decoded at reduced size directly.

Colours: head360 works in sRGB and writes sRGB. A photo with an embedded colour profile
other than sRGB's (an iPhone's Display P3, a camera's Adobe RGB, a print's CMYK) is
converted to sRGB on load, as a colour-managed viewer shows it; without that its values
were read as sRGB ones, duller than the photo looks (:func:`_to_srgb`).
"""

from __future__ import annotations

import dataclasses
import functools
import io
import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from head360cli.errors import BadInputError, FileFormatError

if TYPE_CHECKING:
    from head360cli.io.sources import NamedBytes

__all__ = ["GREY_TOLERANCE", "MAX_PIXELS", "MAX_SIDE", "LoadedImage", "check_companion_png",
           "describe_image", "is_greyscale", "load_image", "png_info", "written_by_head360"]

MAX_PIXELS = 100_000_000
"""Images with more pixels than this are refused."""

MAX_SIDE = 4096
"""Default limit on the longer side after loading; larger images are downscaled."""

EXTENSIONS = (".jpg", ".jpeg", ".png", ".ppm", ".pgm", ".pbm", ".pnm", ".tif", ".tiff",
              ".webp", ".bmp", ".heic", ".heif")  # fmt: skip

HEIF_BRANDS = (b"heic", b"heix", b"hevc", b"hevx", b"heim", b"heis", b"mif1", b"msf1")
"""ISO base-media ``ftyp`` brands of HEIF stills (an iPhone's photos are ``heic``), read
through the optional ``pillow-heif`` (``pip install 'head360[heic]'``)."""

_ORIENTATION_TAG = 0x0112
_ORIENTATION_NAMES = {
    1: "normal", 2: "mirrored", 3: "rotated 180", 4: "mirrored vertically",
    5: "transposed", 6: "rotated 90 CW", 7: "transversed", 8: "rotated 90 CCW",
}  # fmt: skip


@dataclasses.dataclass
class LoadedImage:
    """A decoded image and what was done to it on the way in.

    Attributes:
        pixels: ``(H, W, 3)`` uint8 RGB, or ``(H, W, 4)`` RGBA with ``keep_alpha``,
            upright (EXIF orientation applied), possibly downscaled.
        source_size: ``(width, height)`` of the upright image at full resolution.
        scale: Factor from full-resolution pixels to ``pixels`` (1.0 unless downscaled).
        mode: The file's pixel mode as Pillow names it (``RGB``, ``L``, ``I;16``, ``RGBA``...).
        orientation: EXIF orientation code (1 when absent).
        format: File format (``JPEG``, ``PNG``, ...).
        path: Where it was read from.
        focal_35mm: EXIF ``FocalLengthIn35mmFilm`` in millimetres, ``None`` when absent.
        frames: Frames (or pages) in the file; the first is the one loaded.
        colour_profile: The embedded colour profile's description when the pixels were
            converted from it to sRGB; ``"unreadable"`` when a profile could not be used
            (its values are then taken as sRGB); ``None`` without one, or for sRGB's.
        bits: Bits per channel in the file (8 or 16).
        bits_used: Bits its values use (:func:`used_bits`): a 16-bit file holding 12-bit
            data (values up to 4095) is scaled by that range, not 16 bits'.
    """

    pixels: np.ndarray
    source_size: tuple[int, int]
    scale: float
    mode: str
    orientation: int
    format: str
    path: str
    focal_35mm: float | None = None
    frames: int = 1
    colour_profile: str | None = None
    bits: int = 8
    bits_used: int = 8

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)`` of :attr:`pixels`."""
        return int(self.pixels.shape[1]), int(self.pixels.shape[0])

    @functools.cached_property
    def greyscale(self) -> bool:
        """Whether the pixels are grey (:func:`is_greyscale`), worked out once."""
        return is_greyscale(self.pixels[..., :3])


GREY_TOLERANCE = 16
"""How far apart (grey levels) a pixel's channels may be in a photo :func:`is_greyscale`
calls grey, in all but one pixel in a hundred. A black-and-white photo with a faint cast
and noise (scikit-image's astronaut made grey, red and blue times 1.02 and 0.98, noise of
2 levels) reads 14 at its 99th percentile (the cast alone, as a JPEG at quality 85: 8); a
cast of 4 to 5 % 21-24; the colour development photos 58 to 178 and the corpus' renders
66 and over (a skin-coloured head on white), so none comes near it. A sepia print
(AFLW2000-3D's 00251: 42; the astronaut toned 1.1 / 1.0 / 0.8: 68) is fitted as a colour
photo under a light: its tone cannot be told from a one-coloured subject's
(``docs/decisions.md``, greyscale photos)."""


def is_greyscale(pixels: np.ndarray) -> bool:
    """Whether ``pixels (H, W, 3)`` uint8 are grey: in 99 % of them or more, the channels
    lie within :data:`GREY_TOLERANCE` of each other (scanned and noisy black-and-white
    photos carry a little colour; a logo or a few coloured pixels do not make a photo
    colour).

    OpenCV works in uint8 on whole planes: numpy's ``ptp`` over the channel axis of an
    int16 copy took 1.1 s and 100 MB for a photo decoded at 4096 x 4096 pixels."""
    import cv2

    r, g, b = cv2.split(np.ascontiguousarray(pixels))
    spread = cv2.absdiff(cv2.max(cv2.max(r, g), b), cv2.min(cv2.min(r, g), b))
    return cv2.countNonZero(cv2.compare(spread, GREY_TOLERANCE, cv2.CMP_GT)) \
        <= 0.01 * spread.size


def _open(path: str | os.PathLike[str] | NamedBytes) -> tuple[object, int, object]:
    """``(PIL.Image.Image, size in bytes, source)`` of an image file, a pipe or a pipe's
    content already read (:func:`~head360cli.io.sources.readable`), its pixels not decoded
    yet; ``source`` is the file's path or its bytes (for :func:`_deep_pixels`)."""
    from PIL import Image, UnidentifiedImageError

    from head360cli.io.sources import NamedBytes, existing, readable

    source, size = readable(existing(path, "an image file"))
    label = source.name if isinstance(source, NamedBytes) else str(source)
    if size == 0:
        raise FileFormatError(f"expected an image in {label!r}, found an empty file")
    # Our own limit is checked on the header below; switch Pillow's off meanwhile.
    Image.MAX_IMAGE_PIXELS = None
    if _is_heif(source):
        _register_heif(label)
    try:
        img = Image.open(source)
    except UnidentifiedImageError:
        raise FileFormatError(
            f"expected an image ({', '.join(e[1:] for e in EXTENSIONS)}) in {label!r}, "
            "found something unreadable"
        ) from None
    except OSError as exc:
        raise FileFormatError(f"cannot read image {label!r}: {exc}") from exc
    return img, size, source


def _is_heif(source) -> bool:
    """Whether a file (or a pipe's bytes) starts as a HEIF still does: ``ftyp`` at byte 4
    and one of :data:`HEIF_BRANDS`."""
    from head360cli.io.sources import NamedBytes

    if isinstance(source, NamedBytes):
        head = source.getvalue()[:12]
    else:
        with open(source, "rb") as f:
            head = f.read(12)
    return head[4:8] == b"ftyp" and head[8:12] in HEIF_BRANDS


def _register_heif(label: str) -> None:
    """Let Pillow open HEIF files through ``pillow-heif``.

    Raises:
        ModelNotFoundError: ``pillow-heif`` is not installed (exit 7, as other optional
            packages).
    """
    from head360cli.errors import ModelNotFoundError

    try:
        import pillow_heif
    except ImportError:
        raise ModelNotFoundError(
            f"{label!r} is a HEIF/HEIC photo (an iPhone's format), which needs the optional "
            f"pillow-heif: pip install 'head360[heic]', or save the photo as JPEG"
        ) from None
    pillow_heif.register_heif_opener()


_EXIF_IFD = 0x8769
_EXIF_FOCAL_35MM = 0xA405


def _focal_35mm(img) -> float | None:
    """``FocalLengthIn35mmFilm`` from an open image's EXIF, if present."""
    try:
        value = img.getexif().get_ifd(_EXIF_IFD).get(_EXIF_FOCAL_35MM)
        return float(value) if value else None
    except Exception:  # no or malformed EXIF
        return None


def _orientation(img) -> int:
    try:
        value = int(img.getexif().get(_ORIENTATION_TAG, 1))
    except Exception:  # malformed EXIF blocks are common; treat as upright
        return 1
    return value if value in _ORIENTATION_NAMES else 1


def _decode_problem(img, max_pixels: int) -> str | None:
    """Why :func:`load_image` would refuse an open image's pixels, or ``None``: over
    ``max_pixels`` (not decoded), or truncated or corrupted (a JPEG is decoded at an
    eighth of its size, which reads its whole stream at a fraction of the cost)."""
    w, h = img.size
    if w * h > max_pixels:
        return (f"not decoded: {w * h / 1e6:.0f} megapixels, over the "
                f"{max_pixels / 1e6:.0f} the commands take (downscale it first)")
    if img.format == "JPEG":
        img.draft("RGB", (max(1, w // 8), max(1, h // 8)))
    try:
        img.load()
    except (OSError, SyntaxError, ValueError) as exc:
        return f"truncated or corrupted: {exc}"
    return None


def describe_image(path: str | os.PathLike[str] | NamedBytes,
                   max_pixels: int = MAX_PIXELS) -> dict[str, object]:
    """What an image file is: its header, and whether its pixels decode.

    Args:
        path: The image file, a pipe, or a pipe's content already read.
        max_pixels: Images with more pixels are not decoded (the commands refuse them).

    Returns:
        ``format``, ``mode``, ``width`` and ``height`` as stored, ``orientation`` (code and
        name), upright ``display_size``, ``frames``, ``bytes``, ``megapixels``,
        ``colour_profile`` (the embedded ICC profile's description, ``"unreadable"``, or
        ``None`` without one), ``converted`` (whether loading converts the pixels to
        sRGB: a profile other than sRGB's), ``tone`` (``greyscale``, which ``fit`` fits
        in grey, or ``colour``; ``None`` when the pixels do not decode), and ``problem``:
        why the commands would refuse the pixels (over ``max_pixels``, truncated or
        corrupted), or ``None``.
    """
    from head360cli.io.sources import NamedBytes

    img, size, source = _open(path)
    sixteen = _sixteen_bit(img)  # first: loading (EXIF reads load a PNG) drops its raw mode
    name = path.name if isinstance(path, NamedBytes) else str(path)
    with img:
        w, h = img.size
        orient = _orientation(img)
        upright = (h, w) if orient in (5, 6, 7, 8) else (w, h)
        fmt, mode, frames = img.format, img.mode, int(getattr(img, "n_frames", 1))
        try:
            icc = _profile_of(img)
            profile = _profile_name(icc)
        except ValueError:  # nclx code points head360 does not convert
            icc, profile = None, "unreadable"
        converted = False
        if icc is not None and profile != "unreadable" and mode in ("RGB", "RGBA", "CMYK"):
            try:  # as load_image decides
                converted = _srgb_transform(icc, mode)[0] is not None
            except Exception:  # a profile of another colour space: not used
                profile = "unreadable"
        problem = _decode_problem(img, max_pixels)  # after the header: draft changes mode
        deep = None if problem else _deep_pixels(img, source, sixteen)
        bits_used = None if problem else 8 if deep is None else used_bits(int(deep.max()))
        tone = None if problem else _tone(
            img if deep is None else _eight_bit_from_deep(deep, bits_used, img, 1))
        return {
            "kind": "image",
            "path": name,
            "format": fmt,
            "mode": mode,
            "width": w,
            "height": h,
            "orientation": orient,
            "orientation_name": _ORIENTATION_NAMES[orient],
            "display_size": list(upright),
            "frames": frames,
            "bytes": size,
            "megapixels": round(w * h / 1e6, 3),
            "colour_profile": profile,
            "converted": converted,
            "bits": 16 if sixteen else 8,
            "bits_used": bits_used,
            "tone": tone,
            "problem": problem,
        }


def _tone(img) -> str:
    """``"greyscale"`` (:func:`is_greyscale`) or ``"colour"`` for a decoded image (a JPEG
    at the eighth of its size it was read at)."""
    if img.mode in ("1", "L", "LA", "F") or img.mode.startswith("I"):
        return "greyscale"
    return "greyscale" if is_greyscale(np.asarray(_eight_bit(img).convert("RGB"))) \
        else "colour"


def _eight_bit(img):  # PIL.Image -> PIL.Image in an 8-bit mode
    """16-bit and float greyscale to 8-bit by their full range; other modes unchanged."""
    from PIL import Image

    mode = img.mode
    if mode in ("I;16", "I;16B", "I;16L", "I;16N", "I"):
        a = np.asarray(img, dtype=np.float64)
        top = 65535.0 if mode.startswith("I;16") or a.max() > 255 else 255.0
        a = np.clip(np.round(a / top * 255.0), 0, 255).astype(np.uint8)
        img = Image.fromarray(a, mode="L")
    elif mode == "F":
        a = np.asarray(img, dtype=np.float64)
        top = 1.0 if a.max() <= 1.0 else 255.0
        img = Image.fromarray(np.clip(np.round(a / top * 255), 0, 255).astype(np.uint8), "L")
    elif mode not in ("RGB", "RGBA", "L", "LA", "P", "PA", "1"):
        img = img.convert("RGBA" if "A" in mode else "RGB")  # CMYK, YCbCr, LAB...
    return img


SIXTEEN_BIT_PNG = ("RGB;16B", "RGBA;16B", "LA;16B")
"""Pillow's raw modes of 16-bit colour PNGs, which it decodes to 8 bits by keeping each
value's high byte: 12-bit data (values up to 4095) came out nearly black."""


def used_bits(peak: int) -> int:
    """The fewest of 8, 10, 12, 14 and 16 bits that hold values up to ``peak``: the bit
    depth a 16-bit file's data uses (a camera's 12-bit raw, converted, leaves the top
    four bits empty)."""
    return next((bits for bits in (8, 10, 12, 14) if peak < 2 ** bits), 16)


def _sixteen_bit(img) -> bool:
    """Whether a Pillow image, opened and not yet loaded, holds 16 bits a channel (16-bit
    greyscale, or a PNG whose raw mode is one of :data:`SIXTEEN_BIT_PNG`)."""
    return img.mode in ("I;16", "I;16B", "I;16L", "I;16N") or getattr(
        getattr(img, "png", None), "im_rawmode", None) in SIXTEEN_BIT_PNG


def _deep_pixels(img, source, sixteen: bool) -> np.ndarray | None:
    """A 16-bit file's pixels at their full depth, ``(H, W[, C])`` uint16, RGB(A) order,
    as stored (before EXIF orientation); ``None`` unless ``sixteen`` (:func:`_sixteen_bit`,
    asked before the pixels were loaded). Pillow keeps 16-bit greyscale (``I;16``);
    16-bit colour PNGs are decoded again with OpenCV."""
    from head360cli.io.sources import NamedBytes

    if not sixteen:
        return None
    if img.mode in ("I;16", "I;16B", "I;16L", "I;16N"):
        return np.asarray(img, dtype=np.uint16)
    import cv2

    data = source.getvalue() if isinstance(source, NamedBytes) else \
        Path(source).read_bytes()
    deep = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if deep is None or deep.dtype != np.uint16:
        return None
    if deep.ndim == 3:  # OpenCV's BGR(A) to RGB(A)
        deep = deep[..., [2, 1, 0, 3][:deep.shape[2]]] if deep.shape[2] >= 3 else deep
    return deep


_TRANSPOSE = {2: "FLIP_LEFT_RIGHT", 3: "ROTATE_180", 4: "FLIP_TOP_BOTTOM", 5: "TRANSPOSE",
              6: "ROTATE_270", 7: "TRANSVERSE", 8: "ROTATE_90"}
"""The turn or mirror that puts an image of each EXIF orientation upright."""


def _eight_bit_from_deep(deep: np.ndarray, bits: int, like, orient: int):
    """An upright 8-bit PIL image from 16-bit pixels scaled by their ``bits``' range, with
    the colour profile of the Pillow image ``like``."""
    from PIL import Image

    top = float(2 ** bits - 1)
    a = np.clip(np.round(deep.astype(np.float64) / top * 255.0), 0, 255).astype(np.uint8)
    mode = "L" if a.ndim == 2 else {2: "LA", 3: "RGB", 4: "RGBA"}[a.shape[2]]
    out = Image.fromarray(a, mode)
    out.info.update({k: v for k, v in like.info.items() if k == "icc_profile"})
    if orient in _TRANSPOSE:
        out = out.transpose(getattr(Image.Transpose, _TRANSPOSE[orient]))
    return out


def _profile_name(icc: bytes | None) -> str | None:
    """The description of an embedded ICC profile, ``"unreadable"``, or ``None``."""
    if not icc:
        return None
    from PIL import ImageCms

    try:
        source = ImageCms.ImageCmsProfile(io.BytesIO(icc))
        return (ImageCms.getProfileDescription(source) or "").strip() or "unnamed"
    except Exception:  # littlecms's PyCMSError
        return "unreadable"


def _profile_of(img) -> bytes | None:
    """The ICC profile an image's colours are in: its embedded one, else one made from a
    HEIF's nclx code points (:func:`~head360cli.io.colour.nclx_profile`), else ``None``.

    Raises:
        ValueError: nclx code points head360 does not convert (HDR curves) or that are
            incomplete.
    """
    icc = img.info.get("icc_profile")
    if icc:
        return bytes(icc)
    nclx = img.info.get("nclx_profile")
    if not nclx:
        return None
    from head360cli.io.colour import nclx_profile

    try:
        return nclx_profile(nclx)
    except (KeyError, TypeError) as exc:
        raise ValueError(f"incomplete nclx code points: {exc}") from None


def _to_srgb(img):  # PIL.Image -> (PIL.Image, str | None)
    """``img`` converted to sRGB from its embedded ICC profile (or a HEIF's nclx code
    points, :func:`~head360cli.io.colour.nclx_profile`), and the profile's description
    (see :attr:`LoadedImage.colour_profile`). RGB, RGBA and CMYK images are converted; an
    image without a profile, one whose profile is sRGB's (the conversion changes no 8-bit
    value) or one of another mode is returned as it is, with ``None``."""
    if img.mode not in ("RGB", "RGBA", "CMYK"):
        return img, None
    try:
        icc = _profile_of(img)
    except ValueError:
        return img, "unreadable"
    if icc is None:
        return img, None
    try:
        transform, description = _srgb_transform(icc, img.mode)
    except Exception:  # littlecms's PyCMSError, or a profile for another colour space
        return img, "unreadable"
    if transform is None:
        return img, None
    out = transform.apply(img)
    out.info = {k: v for k, v in img.info.items() if k not in ("icc_profile", "nclx_profile")}
    return out, description


@functools.lru_cache(maxsize=8)
def _srgb_transform(icc: bytes, mode: str):  # -> (ImageCmsTransform | None, str)
    """A transform from the profile ``icc`` to sRGB for images of ``mode`` (to RGB for
    CMYK), and the profile's description; ``None`` for a profile that is sRGB's: one
    that changes no 8-bit value of a grid of colours by more than 1."""
    from PIL import Image, ImageCms

    source = ImageCms.ImageCmsProfile(io.BytesIO(icc))
    srgb = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB"))
    out_mode = "RGB" if mode == "CMYK" else mode
    transform = ImageCms.buildTransform(source, srgb, mode, out_mode)
    description = _profile_name(icc)
    if mode != "CMYK":
        levels = np.linspace(0, 255, 9).round().astype(np.uint8)
        grid = np.stack(np.meshgrid(levels, levels, levels), -1).reshape(1, -1, 3)
        if mode == "RGBA":
            grid = np.concatenate([grid, np.full((*grid.shape[:2], 1), 255, np.uint8)], -1)
        sample = Image.fromarray(grid, mode)
        moved = np.asarray(transform.apply(sample), np.int16) - grid
        if np.abs(moved).max() <= 1:
            return None, description
    return transform, description


def _has_alpha(img) -> bool:
    return img.mode in ("RGBA", "LA", "PA") or (img.mode == "P" and "transparency" in img.info)


def _to_rgb_array(img, keep_alpha: bool, background: tuple[int, int, int],
                  name: str) -> np.ndarray:
    if _has_alpha(img):
        rgba = np.asarray(img.convert("RGBA"))
        if keep_alpha:
            return np.ascontiguousarray(rgba)
        if not rgba[..., 3].any():
            # one colour once composited: the fit said "no face found" in a photo whose
            # faces show in a viewer that ignores transparency
            raise BadInputError(f"expected an image with visible pixels, found {name!r} "
                                f"fully transparent (alpha 0 everywhere)")
        alpha = rgba[..., 3:4].astype(np.float32) / 255.0
        bg = np.asarray(background, dtype=np.float32)
        rgb = rgba[..., :3].astype(np.float32) * alpha + bg * (1.0 - alpha)
        return np.clip(np.round(rgb), 0, 255).astype(np.uint8)
    rgb = np.asarray(img.convert("RGB"))
    if keep_alpha:
        full = np.full((*rgb.shape[:2], 1), 255, dtype=np.uint8)
        return np.concatenate([rgb, full], axis=2)
    return np.ascontiguousarray(rgb)


def load_image(
    path: str | os.PathLike[str],
    *,
    keep_alpha: bool = False,
    background: tuple[int, int, int] = (255, 255, 255),
    max_side: int | None = MAX_SIDE,
    max_pixels: int = MAX_PIXELS,
) -> LoadedImage:
    """Load a photo as upright 8-bit RGB (or RGBA).

    Args:
        path: jpg, png, ppm/pgm/pbm, tiff, webp or bmp file, or a pipe that holds one
            (``<(...)``, ``/dev/stdin``).
        keep_alpha: Return RGBA (opaque images get alpha 255) instead of compositing
            transparent pixels over ``background``.
        background: RGB colour transparent pixels are composited over.
        max_side: Downscale so that the longer side is at most this (``None``: never).
        max_pixels: Refuse images with more pixels than this.

    Returns:
        The image and how it was transformed.

    Raises:
        BadInputError: Missing file, more than ``max_pixels`` pixels, or (unless
            ``keep_alpha``) transparent everywhere.
        FileFormatError: Empty, unreadable or truncated file.
    """
    from PIL import Image, ImageOps

    img, _, source = _open(path)
    sixteen = _sixteen_bit(img)  # first: loading (EXIF reads load a PNG) drops its raw mode
    with img:
        w, h = img.size
        if w <= 0 or h <= 0:
            raise FileFormatError(f"expected a non-empty image in {str(path)!r}, found {w}x{h}")
        if w * h > max_pixels:
            raise BadInputError(
                f"image {str(path)!r} is {w}x{h} ({w * h / 1e6:.0f} megapixels); expected at "
                f"most {max_pixels / 1e6:.0f} megapixels: downscale it first"
            )
        orient = _orientation(img)
        focal_35mm = _focal_35mm(img)
        mode, fmt = img.mode, img.format or "unknown"
        frames = int(getattr(img, "n_frames", 1) or 1)
        longer = max(w, h)
        if max_side is not None and longer > max_side and fmt == "JPEG":
            # Decode a JPEG at 1/2, 1/4 or 1/8 scale directly: fast and memory-light.
            img.draft("RGB", (max(1, w * max_side // longer), max(1, h * max_side // longer)))
        try:
            img.load()
            deep = _deep_pixels(img, source, sixteen)
            upright = ImageOps.exif_transpose(img) if orient != 1 and deep is None else img
        except (OSError, SyntaxError, ValueError) as exc:
            raise FileFormatError(
                f"image {str(path)!r} is truncated or corrupted: {exc}"
            ) from exc
        full_w, full_h = (h, w) if orient in (5, 6, 7, 8) else (w, h)
        bits, bits_used = (8, 8) if deep is None else (16, used_bits(int(deep.max())))
        if deep is not None:  # 16 bits: scaled by the range its values use
            upright = _eight_bit_from_deep(deep, bits_used, img, orient)
        # CMYK first (the 8-bit step would convert it naively); RGB after the downscale,
        # on fewer pixels
        upright, profile = _to_srgb(upright) if upright.mode == "CMYK" else (upright, None)
        upright = _eight_bit(upright)
        if max_side is not None and max(upright.size) > max_side:
            f = max_side / max(upright.size)
            new = (max(1, round(upright.size[0] * f)), max(1, round(upright.size[1] * f)))
            if upright.mode not in ("RGB", "RGBA", "L", "LA"):
                upright = upright.convert("RGBA" if _has_alpha(upright) else "RGB")
            upright = upright.resize(new, Image.Resampling.LANCZOS)
        if profile is None:
            upright, profile = _to_srgb(upright)
        pixels = _to_rgb_array(upright, keep_alpha, background, str(path))
        scale = pixels.shape[1] / full_w
    return LoadedImage(
        pixels=pixels,
        source_size=(full_w, full_h),
        scale=scale,
        mode=mode,
        orientation=orient,
        format=fmt,
        path=str(path),
        focal_35mm=focal_35mm,
        frames=frames,
        colour_profile=profile,
        bits=bits,
        bits_used=bits_used,
    )


def png_info():
    """PNG text metadata that marks a picture as head360's (``Software: head360 x.y.z``),
    for the pictures a command names after its output (see
    :func:`check_companion_png`)."""
    from PIL.PngImagePlugin import PngInfo

    from head360cli.version import __version__

    info = PngInfo()
    info.add_text("Software", f"head360 {__version__}")
    return info


def written_by_head360(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is a PNG that head360 wrote with :func:`png_info`."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            return str(getattr(im, "text", {}).get("Software", "")).startswith("head360")
    except Exception:  # not an image, unreadable: not ours
        return False


def check_companion_png(path: str | os.PathLike[str], what: str) -> None:
    """Refuse to write a picture a command names after its output (``NAME.png`` beside
    ``NAME.h360``) over a file head360 did not write: it may be the user's photo.

    Raises:
        BadInputError: ``path`` exists and is not a PNG marked by :func:`png_info` or an
            empty file (:func:`~head360cli.io.atomic.empty_file`).
    """
    from head360cli.io.atomic import empty_file

    if os.path.lexists(path) and not written_by_head360(path) and not empty_file(path):
        raise BadInputError(f"expected to write the {what} as {str(path)!r}, found a file "
                            f"head360 did not write there: move it or give -o another name")

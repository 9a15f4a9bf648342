"""The ``.h360`` head file: a fitted or sampled head, safe to share.

Layout: a NumPy ``.npz`` archive (a zip of ``.npy`` arrays, stored without compression)
holding

- ``__meta__``: a 0-d unicode array with a JSON object: ``format`` (``"head360"``),
  ``format_version``, ``model_hash`` (SHA-256 of the generator it was made with, or
  ``"none"``), ``created_by``, ``created`` (UTC ISO time) and free ``info``.
- numeric arrays only, never Python objects. The names the pipeline uses are listed in
  :data:`KNOWN_ARRAYS` with their expected rank; others are allowed for extensions.

Files are read with ``allow_pickle=False``: a file that holds pickled objects is refused,
never unpickled. Every array is read in full on load, so zip CRC checks catch corrupted
bytes. Writing goes to a temporary name and is renamed into place.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import os
import zipfile
import zlib
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from head360cli.errors import BadInputError, FileFormatError, ModelMismatchError

if TYPE_CHECKING:
    from head360cli.io.sources import NamedBytes

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "HEAD_ARRAYS",
    "KNOWN_ARRAYS",
    "LID_FULL_AT",
    "MAX_ARRAY_BYTES",
    "HeadFile",
    "driven_weights",
    "lid_amounts",
    "lid_change_arrays",
    "lid_change_of",
    "read_head",
    "write_head",
]

FORMAT_NAME = "head360"
FORMAT_VERSION = 2
"""2 (0.5.0): textures of the deferred generator. 1: of the hex-plane generator, whose
heads this head360 does not render (:func:`read_head` says to fit the photo again)."""
META_KEY = "__meta__"

MAX_ARRAY_BYTES = 256 * 2**20
"""The most a head file's arrays may take once decompressed (a fitted head's take about
5 MB). A zip's entries can be decompressed to far more than the file holds: a 6.5 MB
file of 2 GiB of zeros took 2.6 GB of memory and 11 s to inspect."""

KNOWN_ARRAYS: dict[str, tuple[int, str]] = {
    "shape": (1, "f"),  # (S,) identity code of the bilinear model
    "expression": (1, "f"),  # (52,) ARKit weights of the fitted photo
    "pose": (2, "f"),  # (4, 4) camera-to-world of the photo's camera
    "intrinsics": (2, "f"),  # (3, 3) intrinsics of the photo's camera
    "texture": (3, "f"),  # (C, H, W) neural texture
    "texture_code": (1, "f"),  # (T,) texture code it started from
    "hair_style": (0, "i"),  # () hairstyle index
    "hair_color": (1, "f"),  # (3,) linear RGB hair colour
    "hair_offset": (1, "f"),  # (3,) metres the hair is moved by (optional; default 0)
    "hair_scale": (1, "f"),  # (32,) hair thickness by direction (optional; default 1)
    "hair_end_shift": (0, "f"),  # () metres the hair's ends move down (optional; 0)
    "hair_detail": (3, "f"),  # (A, A, 3) hair albedo over its colour (optional; none)
    "vertices": (2, "f"),  # (V, 3) fitted neutral mesh
    "lid_index": (1, "i"),  # (N,) flat texel indices of the lid change (optional)
    "lid_change": (2, "f"),  # (C, N) the texture's change there, eyes closed (optional)
    "colour_gain": (1, "f"),  # (3,) the photo's light on the head's pixels (optional)
}
"""Array name -> (rank, kind: ``f`` float, ``i`` integer) for the arrays the pipeline uses."""


@dataclasses.dataclass
class HeadFile:
    """The contents of a head file.

    Attributes:
        arrays: Named numeric arrays (see :data:`KNOWN_ARRAYS`).
        model_hash: SHA-256 hex digest of the model the head was made with, or ``"none"``.
        info: Free JSON-serialisable metadata (source photo, timings, hairstyle name...).
        format_version: Version of the layout the file was written in.
        created_by: Tool and version that wrote it.
        created: UTC time of writing, ISO 8601.
    """

    arrays: dict[str, np.ndarray]
    model_hash: str = "none"
    info: dict[str, Any] = dataclasses.field(default_factory=dict)
    format_version: int = FORMAT_VERSION
    created_by: str = ""
    created: str = ""

    def metadata(self) -> dict[str, Any]:
        """The JSON metadata object, as stored."""
        return {
            "format": FORMAT_NAME,
            "format_version": self.format_version,
            "model_hash": self.model_hash,
            "created_by": self.created_by,
            "created": self.created,
            "info": self.info,
        }


def _validate_arrays(arrays: dict[str, np.ndarray], where: str, error: type[Exception]) -> None:
    for name, value in arrays.items():
        if name == META_KEY:
            continue
        if not isinstance(value, np.ndarray):
            raise error(f"{where}: expected array {name!r} to be a numpy array, found "
                        f"{type(value).__name__}")
        if value.dtype.kind not in "biuf":
            raise error(
                f"{where}: expected array {name!r} to be numeric, found dtype {value.dtype}"
            )
        if name in KNOWN_ARRAYS:
            rank, kind = KNOWN_ARRAYS[name]
            if value.ndim != rank:
                raise error(
                    f"{where}: expected array {name!r} of rank {rank}, found shape "
                    f"{tuple(value.shape)}"
                )
            if kind == "f" and value.dtype.kind != "f":
                raise error(f"{where}: expected float array {name!r}, found {value.dtype}")
            if kind == "i" and value.dtype.kind not in "iu":
                raise error(f"{where}: expected integer array {name!r}, found {value.dtype}")
        if value.dtype.kind == "f" and not np.isfinite(value).all():
            raise error(f"{where}: array {name!r} holds NaN or infinite values")
        if name == "hair_style":
            from head360cli.synth.hair import HAIRSTYLES

            if not 0 <= int(value) < len(HAIRSTYLES):
                raise error(f"{where}: expected a hair_style id 0..{len(HAIRSTYLES) - 1}, "
                            f"found {int(value)}")


def lid_change_arrays(change: np.ndarray) -> dict[str, np.ndarray]:
    """The head-file arrays of a lid change ``(C, R, R)`` (see
    :func:`head360cli.fitting.lids.close_lids`): ``lid_index`` (its nonzero texels, flat)
    and ``lid_change (C, N)`` there, about 3000 of 65536 texels."""
    flat = np.asarray(change, np.float32).reshape(change.shape[0], -1)
    index = np.flatnonzero(np.any(flat != 0, axis=0)).astype(np.int32)
    return {"lid_index": index, "lid_change": flat[:, index]}


EYE_WEIGHTS = {side: tuple(f"eye{part}{side}" for part in ("Blink", "Squint", "Wide"))
               for side in ("Left", "Right")}
"""Per eye, the ARKit weights that open or close its lids (blink first)."""


def driven_weights(weights: np.ndarray, own: np.ndarray) -> np.ndarray:
    """The weights a head's mesh takes in frames driven by ARKit ``weights (B, 52)``,
    for a head whose own (fitted) expression is ``own (52,)``: each eye rests at its own
    openness, the one its texture was fitted to, and the stream's blink closes it from
    there. Per eye, with the stream's blink ``b``: ``eyeBlink = b + (1 - b) * own`` (own
    clipped to 0.95, as :func:`lid_amounts`), and the own ``eyeSquint`` and ``eyeWide``
    fade out as the eye closes, added to the stream's as ``(1 - b) * own`` (at most 1).
    All other weights are the stream's. A head with open eyes of its own (a sampled head,
    ``own`` zero there) takes the stream's weights unchanged.

    With the stream's eyes taken as they are, the lids of a fitted head move away from
    where the texture was painted and uncover it there: over a blink ramp of 0 to 0.6
    (where a Live Link Face take's blinks lie) the dlib eye opening of the front view of
    nine development photos' heads followed the blink at a mean r of -0.29 (0.60 to
    -0.94); driven from their own eyes, -0.68 (0.07 to -0.98; better on all nine), and
    over 0 to 1 at -0.85 against -0.80.

    Returns:
        ``(B, 52)`` float32.
    """
    from head360cli.mesh.arkit52 import INDEX

    w = np.array(weights, np.float32, copy=True, ndmin=2)
    own = np.asarray(own, np.float32)
    for names in EYE_WEIGHTS.values():
        blink, *others = (INDEX[n] for n in names)
        b = w[:, blink].copy()
        w[:, blink] = b + (1.0 - b) * min(max(float(own[blink]), 0.0), 0.95)
        for k in others:
            w[:, k] = np.minimum(w[:, k] + (1.0 - b) * max(float(own[k]), 0.0), 1.0)
    return w


LID_FULL_AT = 0.6
"""How far an eye has closed beyond its own openness when its lid change is all in (a
driving blink of 0.6 for any head, see :func:`driven_weights`). A lid that has covered
most of the eyeball by then still showed the texture's lid, stretched and dark, which
dlib reads as an open eye: on eleven development heads (nine fitted photos, two sampled)
the front view's eye opening over a blink ramp of 0 to 0.7 followed it at a mean r of
-0.73 with the change brought in up to a full blink, -0.84 with it in by 0.6 (-0.79 by
0.8); over 0 to 1, -0.85 and -0.83."""


def lid_amounts(blinks: np.ndarray, own: np.ndarray) -> np.ndarray:
    """How much of each eye's lid change frames show: ``(B, 2)`` in [0, 1] for their
    ``(B, 2)`` eyeBlinkLeft / eyeBlinkRight weights, ``(w - w0) / (1 - w0) /``
    :data:`LID_FULL_AT` (at most 1) above the head's own weights ``own (2,)`` (its
    texture already shows those), 0 below. ``own`` is clipped to 0.95."""
    own = np.clip(np.asarray(own, np.float32), 0.0, 0.95)
    closed = (np.asarray(blinks, np.float32) - own) / (1.0 - own)
    return np.clip(closed / LID_FULL_AT, 0.0, 1.0)


def lid_change_of(arrays: dict[str, np.ndarray]) -> np.ndarray | None:
    """The dense lid change ``(C, R, R)`` of a head file's arrays (shaped like its
    texture), or ``None`` if it has none.

    Raises:
        FileFormatError: The lid arrays do not fit the texture.
    """
    if "lid_index" not in arrays and "lid_change" not in arrays:
        return None
    index, values = arrays.get("lid_index"), arrays.get("lid_change")
    c, h, w = arrays["texture"].shape
    if index is None or values is None or values.shape != (c, len(index)) \
            or (len(index) and not 0 <= index.min() <= index.max() < h * w):
        raise FileFormatError(
            f"expected lid_index (N,) in [0, {h * w}) with lid_change ({c}, N), found "
            f"{None if index is None else tuple(index.shape)} and "
            f"{None if values is None else tuple(values.shape)}")
    dense = np.zeros((c, h * w), np.float32)
    dense[:, index] = values
    return dense.reshape(c, h, w)


def write_head(head: HeadFile, path: str | os.PathLike[str]) -> Path:
    """Write a head file atomically.

    Args:
        head: What to write. ``created_by`` and ``created`` are filled in if empty.
        path: Target path (conventionally ``*.h360``).

    Returns:
        The path written.

    Raises:
        BadInputError: When an array is not numeric, has the wrong rank or holds NaN.
    """
    from head360cli.io.atomic import atomic_path
    from head360cli.version import __version__

    arrays = {k: np.asarray(v) for k, v in head.arrays.items()}
    if META_KEY in arrays:
        raise BadInputError(f"array name {META_KEY!r} is reserved for the metadata")
    _validate_arrays(arrays, "head file to write", BadInputError)
    meta = head.metadata()
    meta["created_by"] = meta["created_by"] or f"head360 {__version__}"
    meta["created"] = meta["created"] or _dt.datetime.now(_dt.timezone.utc).isoformat(
        timespec="seconds"
    )
    try:
        text = json.dumps(meta, sort_keys=True, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise BadInputError(f"head file metadata is not plain JSON: {exc}") from exc
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        # Stored, not deflated: a fitted head's float32 texture (4 MiB) deflates by a
        # tenth, in 0.2 s, against 0.01 s to store it. Files written deflated by earlier
        # versions read the same.
        np.savez(f, **{META_KEY: np.array(text)}, **arrays)
    return path


HEAD_ARRAYS = ("shape", "texture", "hair_style", "hair_color", "expression")
"""The arrays every head that renders has (fitted or sampled): ``read_head``'s
``required`` for the commands that render or edit one."""


def read_head(
    path: str | os.PathLike[str] | NamedBytes, *, expected_model_hash: str | None = None,
    required: tuple[str, ...] = (),
) -> HeadFile:
    """Read and validate a head file.

    Args:
        path: The ``.h360`` file, a pipe that holds one (``<(...)``, ``/dev/stdin``), or
            a pipe's content already read.
        expected_model_hash: When given, the file must have been made with this model.
        required: Arrays the file must hold (for example :data:`HEAD_ARRAYS`); the format
            itself allows any subset.

    Returns:
        The head file's contents.

    Raises:
        BadInputError: The file does not exist.
        FileFormatError: Not a head file, truncated, corrupted, unsafe (pickled objects),
            written by a newer format version, or without a ``required`` array.
        ModelMismatchError: Made with another model than ``expected_model_hash``.
    """
    from head360cli.io.sources import NamedBytes, existing, readable

    source, _ = readable(existing(path, "a head file"))  # a pipe is read once, into memory
    where = f"head file {str(source.name if isinstance(source, NamedBytes) else source)!r}"
    if isinstance(source, Path):
        with open(source, "rb") as f:
            magic = f.read(4)
    else:
        magic = source.getvalue()[:4]
    if magic != b"PK\x03\x04":
        found = "an empty file" if not magic else f"bytes {magic!r}"
        raise FileFormatError(f"{where}: expected a head360 .h360 (zip) file, found {found}")
    try:
        with zipfile.ZipFile(source) as zf:  # the sizes its entries say, before any is read
            unpacked = sum(info.file_size for info in zf.infolist())
    except (zipfile.BadZipFile, OSError, EOFError) as exc:
        raise FileFormatError(f"{where}: truncated or corrupted ({exc})") from exc
    if unpacked > MAX_ARRAY_BYTES:
        raise FileFormatError(f"{where}: expected at most {MAX_ARRAY_BYTES >> 20} MiB of "
                              f"arrays, found {unpacked / 2**20:.0f} MiB once decompressed "
                              f"(not a head360 head)")
    if not isinstance(source, Path):
        source.seek(0)
    try:
        with np.load(source, allow_pickle=False) as npz:
            names = list(npz.files)
            if META_KEY not in names:
                raise FileFormatError(f"{where}: expected a {META_KEY!r} entry, found only "
                                      f"{', '.join(names[:6]) or 'nothing'}")
            arrays = {name: npz[name] for name in names}
    except FileFormatError:
        raise
    except ValueError as exc:
        if "pickle" in str(exc).lower():
            raise FileFormatError(
                f"{where}: holds pickled Python objects; refusing to load it (head files "
                "hold numeric arrays only)"
            ) from exc
        raise FileFormatError(f"{where}: corrupted ({exc})") from exc
    except (zipfile.BadZipFile, zlib.error, OSError, EOFError, KeyError) as exc:
        raise FileFormatError(f"{where}: truncated or corrupted ({exc})") from exc

    meta_arr = arrays.pop(META_KEY)
    if meta_arr.dtype.kind != "U" or meta_arr.ndim != 0:
        raise FileFormatError(f"{where}: expected JSON metadata text, found {meta_arr.dtype}")
    try:
        meta = json.loads(str(meta_arr))
    except json.JSONDecodeError as exc:
        raise FileFormatError(f"{where}: metadata is not valid JSON ({exc.msg})") from exc
    if not isinstance(meta, dict) or meta.get("format") != FORMAT_NAME:
        found = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
        raise FileFormatError(f"{where}: expected format {FORMAT_NAME!r}, found {found!r}")
    version = meta.get("format_version")
    if not isinstance(version, int) or version < 1:
        raise FileFormatError(f"{where}: expected an integer format_version, found {version!r}")
    if version > FORMAT_VERSION:
        raise FileFormatError(
            f"{where}: format version {version} is newer than this head360 reads "
            f"(up to {FORMAT_VERSION}); upgrade head360"
        )
    _validate_arrays(arrays, where, FileFormatError)
    model_hash = str(meta.get("model_hash", "none"))
    if expected_model_hash is not None and version < FORMAT_VERSION:
        raise ModelMismatchError(
            f"{where} is a format {version} head file, made for the hex-plane generator of "
            f"head360 0.4 and earlier; fit the photo again (head360 fit PHOTO)"
        )
    if expected_model_hash is not None and model_hash != expected_model_hash:
        raise ModelMismatchError(
            f"{where} was made with model {model_hash[:12]}, but the loaded model is "
            f"{expected_model_hash[:12]}; refit the photo or load the matching model"
        )
    missing = [name for name in required if name not in arrays]
    if missing:
        raise FileFormatError(f"{where}: expected a head with arrays {', '.join(required)}, "
                              f"found none named {', '.join(missing)} (it holds "
                              f"{', '.join(sorted(arrays)) or 'no arrays'})")
    info = meta.get("info", {})
    return HeadFile(
        arrays=arrays,
        model_hash=model_hash,
        info=info if isinstance(info, dict) else {"info": info},
        format_version=version,
        created_by=str(meta.get("created_by", "")),
        created=str(meta.get("created", "")),
    )

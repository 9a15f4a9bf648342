"""Reports about the environment and about files: what ``head360 info`` and
``head360 inspect`` print. Each function returns plain JSON-ready data; the CLI formats it.
"""

from __future__ import annotations

import hashlib
import platform
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from head360cli.errors import BadInputError

if TYPE_CHECKING:
    from head360cli.io.sources import NamedBytes

__all__ = ["environment_report", "file_kind", "inspect_file", "sha256_file"]

MODEL_SUFFIXES = (".pt", ".npz", ".onnx", ".json")
_IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".ppm", ".pgm", ".pbm", ".pnm", ".tif", ".tiff",
                   ".webp", ".bmp")  # fmt: skip
_STREAM_SUFFIXES = (".csv", ".tsv", ".txt")
_HEAD_SUFFIXES = (".h360", ".npz")


def sha256_file(path: str | Path, chunk: int = 1 << 20) -> str:
    """SHA-256 hex digest of a file, read in chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            digest.update(block)
    return digest.hexdigest()


def _version(module: str, attr: str = "__version__") -> str | None:
    import importlib

    try:
        return str(getattr(importlib.import_module(module), attr))
    except Exception:  # an optional dependency that is missing or broken
        return None


def environment_report(hash_models: bool = True) -> dict[str, Any]:
    """Versions, devices and model files, for ``head360 info``.

    Args:
        hash_models: Compute SHA-256 digests of the files in the models folder.

    Returns:
        ``head360``, ``python``, ``platform``, ``packages`` (versions or ``None`` when
        missing), ``devices``, ``models_dir``, ``models`` (name, bytes, sha256) and
        ``dlib_models`` (which dlib weights are installed), ``shared_data`` and
        ``cache`` (the folder of :mod:`head360cli.cache`, ``None`` when turned off).
    """
    from head360cli import __version__
    from head360cli.paths import cache_dir, dlib_model_files, models_dir, shared_data_dir

    packages = {
        "torch": _version("torch"),
        "onnxruntime": _version("onnxruntime"),
        "opencv": _version("cv2"),
        "dlib": _version("dlib"),
        "numpy": _version("numpy"),
        "scipy": _version("scipy"),
        "trimesh": _version("trimesh"),
        "scikit-image": _version("skimage"),
        "imageio": _version("imageio"),
        "onnx": _version("onnx"),
    }
    devices: list[dict[str, Any]] = [{"name": "cpu", "threads": None}]
    try:
        import torch

        devices[0]["threads"] = torch.get_num_threads()
        for i in range(torch.cuda.device_count() if torch.cuda.is_available() else 0):
            props = torch.cuda.get_device_properties(i)
            devices.append({"name": f"cuda:{i}", "model": props.name,
                            "memory_gib": round(props.total_memory / 2**30, 1)})
    except ImportError:
        pass
    try:
        import onnxruntime

        ort_providers = list(onnxruntime.get_available_providers())
    except ImportError:
        ort_providers = []

    mdir = models_dir()
    models = []
    if mdir.is_dir():
        for p in sorted(mdir.iterdir()):
            if p.is_file() and p.suffix in MODEL_SUFFIXES:
                entry: dict[str, Any] = {"name": p.name, "bytes": p.stat().st_size}
                if hash_models:
                    entry["sha256"] = sha256_file(p)
                    if p.name == "bilinear.npz":
                        # The model's identity, as head files record it (stable across
                        # rebuilds, unlike the zip's bytes).
                        try:
                            from head360cli.mesh.bilinear import load_bilinear

                            entry["model_hash"] = load_bilinear(p).meta["sha256"]
                        except Exception as exc:  # report, don't fail, on a bad file
                            entry["model_hash"] = f"unreadable: {exc}"
                models.append(entry)
    dlib_files = {
        k: (str(v) if v is not None else None) for k, v in dlib_model_files().items()
    }
    shared = shared_data_dir()
    cache = cache_dir()
    return {
        "head360": __version__,
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "packages": packages,
        "devices": devices,
        "onnxruntime_providers": ort_providers,
        "models_dir": str(mdir),
        "models": models,
        "dlib_models": dlib_files,
        "shared_data": str(shared) if shared else None,
        "cache": None if cache is None else str(cache),
    }


def file_kind(path: str | NamedBytes) -> str:
    """``"stream"``, ``"head"`` or ``"image"``, from the name and the first bytes (a
    pipe's content already read, :class:`~head360cli.io.sources.NamedBytes`: from its
    bytes alone, and what is neither a zip nor an image is taken for a stream). A file
    whose name says nothing is a stream when its first bytes are text."""
    from head360cli.io.sources import NamedBytes, existing

    if path == "-":
        return "stream"
    if isinstance(path, NamedBytes):
        p, source, magic = Path(path.name), path, path.getvalue()[:8]
    else:
        p = source = existing(path, "a file")
        with open(p, "rb") as f:
            magic = f.read(8)
    suffix = p.suffix.lower()
    if suffix in _HEAD_SUFFIXES or magic.startswith(b"PK\x03\x04"):
        return "head"
    if suffix in _STREAM_SUFFIXES:
        return "stream"
    if suffix in _IMAGE_SUFFIXES:
        return "image"
    try:
        from PIL import Image

        with Image.open(source):
            return "image"
    except Exception:
        pass
    finally:
        if isinstance(source, NamedBytes):
            source.seek(0)
    if isinstance(source, NamedBytes):
        return "stream"  # a pipe has no name to go by; the CSV reader says what is wrong
    with open(p, "rb") as f:
        start = f.read(4096)
    try:
        start.decode("utf-8-sig")
        text = b"\0" not in start
    except UnicodeDecodeError as exc:  # a character cut at the end of the read is text
        text = exc.start >= len(start) - 3 and b"\0" not in start
    if text and start.strip():
        return "stream"  # /dev/stdin redirected from a file has no suffix to go by
    raise BadInputError(
        f"expected an ARKit stream (.csv), an image or a head file (.h360), found {p.name!r}"
    )


def inspect_file(path: str, on_bad: str = "error", plot: str | None = None) -> dict[str, Any]:
    """Describe a file: ARKit stream, image or head file.

    Args:
        path: The file, or ``-`` for an ARKit stream on standard input.
        on_bad: Bad-cell policy for streams (``error``, ``skip``, ``hold``).
        plot: For a stream, also draw its curves into this PNG.

    Returns:
        A JSON-ready description whose ``kind`` says which of the three it is.
    """
    from head360cli.io.sources import is_pipe, readable

    shown = path  # the name in messages and output, a pipe's too
    if path == "-":  # standard input: a stream, a head file or an image, by its bytes
        import sys

        from head360cli.io.sources import NamedBytes, check_stdin

        check_stdin("a stream, a head file or an image")
        raw = sys.stdin.buffer.read() if hasattr(sys.stdin, "buffer") else (
            sys.stdin.read().encode("utf-8"))  # a text stream put in its place
        path, shown = NamedBytes(raw, "<stdin>"), "<stdin>"
    elif is_pipe(path):  # <(...), /dev/stdin: read once, looked at twice
        path, _ = readable(path)
    kind = file_kind(path)
    if plot is not None and kind != "stream":
        what = {"image": "an image", "head": "a head file"}[kind]
        raise BadInputError(f"--plot draws ARKit streams; expected a .csv, found {what}: {shown!r}")
    if kind == "image":
        from head360cli.io.images import describe_image

        return describe_image(path)
    if kind == "head":
        from head360cli.io.headfile import read_head

        head = read_head(path)
        return {
            "kind": "head",
            "path": shown,
            "metadata": head.metadata(),
            "arrays": {
                name: {"shape": list(a.shape), "dtype": str(a.dtype)}
                for name, a in sorted(head.arrays.items())
            },
            "bytes": readable(path)[1],
        }
    from head360cli.io.arkit import read_arkit_csv

    stream = read_arkit_csv(path, on_bad=on_bad)  # type: ignore[arg-type]
    out: dict[str, Any] = {
        "kind": "arkit_stream",
        "path": shown,
        "format": stream.source_format,
        "frames": stream.num_frames,
        "fps": round(stream.fps, 4),
        "nominal_fps": stream.nominal_fps,
        "duration_s": round(stream.duration, 4),
        "columns_found": stream.columns_found,
        "columns_missing": stream.columns_missing,
        "columns_ignored": stream.columns_ignored,
        "head_rotation": stream.head_rotation is not None,
        "eye_rotation": stream.eye_rotation is not None,
        "clamped": stream.clamped,
        "repaired": stream.repaired,
        "skipped_rows": stream.skipped_rows,
        "warnings": stream.warnings,
        "blendshapes": {k: {s: round(v, 6) for s, v in d.items()}
                        for k, d in stream.stats().items()},
    }
    if plot is not None:
        from head360cli.viz import plot_stream

        plot_stream(stream, plot)
        out["plot"] = plot
    if stream.head_rotation is not None:
        import numpy as np

        deg = np.degrees(stream.head_rotation.astype(np.float64))
        out["head_rotation_deg"] = {
            axis: {"min": round(float(deg[:, i].min()), 3),
                   "max": round(float(deg[:, i].max()), 3)}
            for i, axis in enumerate(("yaw", "pitch", "roll"))
        }
    return out

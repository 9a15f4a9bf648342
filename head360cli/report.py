"""Reports about the environment and about files: what ``head360 info`` and
``head360 inspect`` print. Each function returns plain JSON-ready data; the CLI formats it.
"""

from __future__ import annotations

import hashlib
import os
import platform
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from head360cli.errors import BadInputError

if TYPE_CHECKING:
    from head360cli.io.sources import NamedBytes

__all__ = ["describe_mesh", "describe_model", "environment_report", "file_kind",
           "inspect_file", "sha256_file"]

MODEL_SUFFIXES = (".pt", ".npz", ".onnx", ".json", ".tflite", ".task", ".obj")
_IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".ppm", ".pgm", ".pbm", ".pnm", ".tif", ".tiff",
                   ".webp", ".bmp", ".heic", ".heif")  # fmt: skip
_STREAM_SUFFIXES = (".csv", ".tsv", ".txt")
_HEAD_SUFFIXES = (".h360", ".npz")
_OTHER_SUFFIXES = (".json", ".jsonl", ".mtl", ".md", ".npy", ".pkl", ".pickle")  # fmt: skip
_VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".webm", ".mkv", ".avi", ".gif")
_KINDS = ("an ARKit stream (.csv), an image, a video or a head file (.h360), or a model "
          "file (.pt, .npz, .onnx) or mesh (.glb, .obj) head360 wrote")


def _perception_role(filename: str) -> str | None:
    """The perception role of a model file name, or ``None``."""
    from head360cli.perception.runtime import PERCEPTION_FILES

    return next((r for r, spec in PERCEPTION_FILES.items() if spec.filename == filename),
                None)


def _litert_version() -> str | None:
    """LiteRT's version, read from its distribution's metadata (importing it would load
    its native library)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("ai-edge-litert")
    except PackageNotFoundError:
        return None


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
        ``dlib_models`` (which dlib weights are installed), ``shared_data``, ``cache``
        (the folder of :mod:`head360cli.cache`, ``None`` when turned off) and
        ``onnxruntime_telemetry`` (whether onnxruntime may keep and send usage events;
        ``None`` without onnxruntime).
    """
    from head360cli.paths import cache_dir, dlib_model_files, models_dir, shared_data_dir
    from head360cli.version import __version__

    packages = {
        "torch": _version("torch"),
        "onnxruntime": _version("onnxruntime"),
        "ai-edge-litert": _litert_version(),
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

    from head360cli.perception.runtime import PERCEPTION_FILES

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
                    role = _perception_role(p.name)
                    if role is not None:
                        entry["licence"] = PERCEPTION_FILES[role].licence
                        entry["verified"] = entry["sha256"] == PERCEPTION_FILES[role].sha256
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
        # head360cli's import sets it to 1 unless the user chose (see its __init__)
        "onnxruntime_telemetry": None if packages["onnxruntime"] is None else
        os.environ.get("ORT_DISABLE_TELEMETRY", "").strip().lower()
        not in ("1", "true", "yes", "on", "y"),
        "models_dir": str(mdir),
        "models": models,
        "dlib_models": dlib_files,
        "shared_data": str(shared) if shared else None,
        "cache": None if cache is None else str(cache),
    }


def file_kind(path: str | NamedBytes) -> str:
    """``"stream"``, ``"head"``, ``"image"``, ``"model"`` (head360's weights, checkpoints,
    bilinear model or ONNX graphs) or ``"mesh"`` (glTF binary or OBJ), from the name and
    the first bytes (a pipe's content already read,
    :class:`~head360cli.io.sources.NamedBytes`: from its bytes alone, and what is neither
    a zip nor an image is taken for a stream). A file whose name says nothing is a
    stream when its first bytes are text."""
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
    if magic.startswith(b"glTF") or suffix in (".glb", ".obj"):
        return "mesh"
    if suffix in _OTHER_SUFFIXES:
        raise BadInputError(f"expected {_KINDS}, found {p.name!r}")
    if suffix in _VIDEO_SUFFIXES:
        return "video"
    if suffix == ".onnx":
        return "model"
    if suffix in _HEAD_SUFFIXES or magic.startswith(b"PK\x03\x04"):
        return _zip_kind(source)
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
    raise BadInputError(f"expected {_KINDS}, found {p.name!r}")


def _zip_kind(source) -> str:
    """``"model"`` for a torch file (its zip holds ``data.pkl``) or the bilinear model's
    ``.npz``, ``"head"`` for anything else zipped (a head file, or one to be refused as
    not a head file by the head reader)."""
    import zipfile

    try:
        with zipfile.ZipFile(source) as z:
            names = z.namelist()
            if any(n.endswith("data.pkl") for n in names):
                return "model"
            if _npz_format(z) == "head360-bilinear":
                return "model"
    except Exception:  # not a zip after all, or an odd one: the head reader says what
        pass
    finally:
        if hasattr(source, "seek"):
            source.seek(0)
    return "head"


def _npz_format(z) -> str | None:
    """The ``format`` in the ``__meta__`` entry of an open ``.npz`` zip (head files and
    the bilinear model have one), or ``None``."""
    import json

    import numpy as np

    if "__meta__.npy" not in z.namelist():
        return None
    with z.open("__meta__.npy") as f:
        meta = np.lib.format.read_array(f, allow_pickle=False)
    found = json.loads(str(meta))
    return found.get("format") if isinstance(found, dict) else None


def _count_parameters(state: dict[str, Any]) -> int:
    import torch

    return int(sum(v.numel() for v in state.values() if isinstance(v, torch.Tensor)))


def describe_model(path: str | NamedBytes, shown: str) -> dict[str, Any]:
    """What a model file holds: head360's generator weights, a training checkpoint, the
    hair prior, the bilinear head model or an exported ONNX graph (read as data only:
    no pickled code runs).

    Raises:
        FileFormatError: None of those, or unreadable.
    """
    from head360cli.errors import FileFormatError
    from head360cli.io.sources import NamedBytes

    data = path.getvalue() if isinstance(path, NamedBytes) else Path(path).read_bytes()
    out: dict[str, Any] = {"kind": "model", "path": shown, "bytes": len(data),
                           "sha256": hashlib.sha256(data).hexdigest()}
    name = Path(path.name if isinstance(path, NamedBytes) else path).name
    if name.lower().endswith(".onnx"):
        return {**out, **_describe_onnx(data, shown)}
    import io
    import zipfile

    try:
        with zipfile.ZipFile(io.BytesIO(data)) as z:
            fmt = _npz_format(z)
    except (zipfile.BadZipFile, ValueError):
        fmt = None
    if fmt == "head360-bilinear":
        from head360cli.mesh.bilinear import read_model_file

        arrays, meta = read_model_file(io.BytesIO(data))
        return {**out, "format": "head360-bilinear", "model_hash": meta.get("sha256"),
                "arrays": {k: list(v.shape) for k, v in sorted(arrays.items())},
                "meta": {k: v for k, v in meta.items() if k != "sha256"}}
    from head360cli.io.torchfile import load_data

    blob = load_data(io.BytesIO(data), "a head360 model file", name=shown)
    fmt = blob.get("format") if isinstance(blob, dict) else None
    if fmt == "head360-generator":
        from head360cli.paths import installed_generator

        try:
            installed = hashlib.sha256(installed_generator().read_bytes()).hexdigest()
        except Exception:  # none installed: the file is not it
            installed = None
        return {**out, "format": fmt, "format_version": blob.get("format_version"),
                "model_hash": out["sha256"], "installed": out["sha256"] == installed,
                "step": blob.get("step"),
                "identities": len(blob["codes"]) if "codes" in blob else None,
                "parameters": _count_parameters(blob.get("generator", {})),
                "generator_config": blob.get("generator_config")}
    if fmt == "head360-train":
        return {**out, "format": fmt, "step": blob.get("step"),
                "parameters": _count_parameters(blob.get("model", {})),
                "generator_config": blob.get("generator_config"),
                "train_config": blob.get("train_config")}
    from head360cli.fitting.hair_prior import FORMAT as PRIOR_FORMAT

    if fmt == PRIOR_FORMAT:
        return {**out, "format": fmt,
                "parameters": _count_parameters(blob.get("state_dict", {})),
                "config": blob.get("config"), "meta": blob.get("meta", {})}
    found = repr(fmt) if fmt else type(blob).__name__
    raise FileFormatError(f"{shown}: expected head360 generator weights, a training "
                          f"checkpoint or a hair prior, found {found}")


def _describe_onnx(data: bytes, shown: str) -> dict[str, Any]:
    """Inputs, outputs and head360's export metadata of an ONNX graph (onnxruntime reads
    it; no frame is run)."""
    import json

    from head360cli.errors import FileFormatError, ModelNotFoundError

    try:
        import onnxruntime as ort
    except ImportError:
        raise ModelNotFoundError("inspecting an ONNX graph needs onnxruntime: pip install "
                                 "'head360[export]'") from None
    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    opts.log_severity_level = 3
    try:
        sess = ort.InferenceSession(data, opts, providers=["CPUExecutionProvider"])
    except Exception as exc:
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise FileFormatError(f"{shown}: expected an ONNX graph, found one onnxruntime "
                              f"cannot load ({first[:200]})") from None
    from head360cli.export.onnx import META_KEY

    meta = sess.get_modelmeta().custom_metadata_map.get(META_KEY)
    return {"format": "onnx" if meta is None else "head360-onnx",
            "inputs": {i.name: list(i.shape) for i in sess.get_inputs()},
            "outputs": {o.name: list(o.shape) for o in sess.get_outputs()},
            "export": None if meta is None else json.loads(meta)}


def describe_mesh(path: str | NamedBytes, shown: str) -> dict[str, Any]:
    """What a glTF binary (``.glb``) holds: its meshes with their vertices, triangles
    and named morph targets, and its textures' sizes, read from the file's JSON chunk; for
    a Wavefront ``.obj``, counts of its records.

    Raises:
        FileFormatError: Not a glTF 2 binary or an OBJ, or truncated.
    """
    import io
    import json
    import struct

    from head360cli.errors import FileFormatError
    from head360cli.io.sources import NamedBytes

    data = path.getvalue() if isinstance(path, NamedBytes) else Path(path).read_bytes()
    if not data.startswith(b"glTF"):
        return _describe_obj(data, shown)
    try:
        magic, version, length = struct.unpack_from("<4sII", data, 0)
        chunk_len, chunk_type = struct.unpack_from("<II", data, 12)
        if magic != b"glTF" or version != 2 or chunk_type != 0x4E4F534A or length > len(data):
            raise ValueError("not a whole glTF 2 binary")
        gltf = json.loads(data[20:20 + chunk_len])
        binary = b""
        if 20 + chunk_len + 8 <= len(data):
            bin_len, _ = struct.unpack_from("<II", data, 20 + chunk_len)
            binary = data[28 + chunk_len:28 + chunk_len + bin_len]
        accessors = gltf.get("accessors", [])
        meshes = []
        for mesh in gltf.get("meshes", []):
            prims = mesh.get("primitives", [])
            verts = sum(accessors[p["attributes"]["POSITION"]]["count"] for p in prims)
            tris = sum(accessors[p["indices"]]["count"] // 3 if "indices" in p
                       else accessors[p["attributes"]["POSITION"]]["count"] // 3
                       for p in prims)
            names = (mesh.get("extras") or {}).get("targetNames") or []
            targets = max((len(p.get("targets", [])) for p in prims), default=0)
            meshes.append({"name": mesh.get("name"), "vertices": verts, "triangles": tris,
                           "morph_targets": targets, "morph_target_names": names})
        textures = []
        for image in gltf.get("images", []):
            size = None
            if "bufferView" in image:
                view = gltf["bufferViews"][image["bufferView"]]
                start = view.get("byteOffset", 0)
                from PIL import Image

                with Image.open(io.BytesIO(binary[start:start + view["byteLength"]])) as im:
                    size = list(im.size)
            textures.append({"mime": image.get("mimeType"), "size": size})
    except (ValueError, KeyError, IndexError, TypeError, struct.error, OSError) as exc:
        raise FileFormatError(f"{shown}: expected a glTF binary (.glb), found one that does "
                              f"not read ({exc})") from None
    return {"kind": "mesh", "path": shown, "bytes": len(data), "format": "glb",
            "generator": gltf.get("asset", {}).get("generator"), "meshes": meshes,
            "textures": textures}


def _describe_obj(data: bytes, shown: str) -> dict[str, Any]:
    """Counts of a Wavefront OBJ's records: vertices, texture coordinates, normals,
    triangles (a polygon of n corners counts n - 2), groups and material library."""
    from head360cli.errors import FileFormatError

    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise FileFormatError(f"{shown}: expected a Wavefront OBJ (text), found binary "
                              f"data") from None
    counts = {"v": 0, "vt": 0, "vn": 0, "o": 0, "g": 0}
    triangles, libraries = 0, []
    for line in text.splitlines():
        head, _, rest = line.strip().partition(" ")
        if head in counts:
            counts[head] += 1
        elif head == "f":
            triangles += max(0, len(rest.split()) - 2)
        elif head == "mtllib":
            libraries.append(rest.strip())
    if not counts["v"]:
        raise FileFormatError(f"{shown}: expected a Wavefront OBJ with vertices ('v' "
                              f"lines), found none")
    return {"kind": "mesh", "path": shown, "bytes": len(data), "format": "obj",
            "generator": None, "vertices": counts["v"], "uvs": counts["vt"],
            "normals": counts["vn"], "triangles": triangles,
            "objects": counts["o"] + counts["g"], "material_libraries": libraries}


def describe_video(path: str) -> dict[str, Any]:
    """What a video holds: frames, rate, size, duration, the rotation its metadata asks
    for, and the faces the detectors find in its first frame.

    Raises:
        FileFormatError: The file is empty or no frame of it decodes.
    """
    import cv2

    from head360cli.io.frames import open_frames

    with open_frames(path, None) as frames:  # its checks: empty, unreadable, no frame
        first = next(iter(frames.frames(None, None)))[2]
        fps, count, size = frames.fps, frames.count, frames.size
    from head360cli.io.frames import quiet_ffmpeg

    quiet_ffmpeg()
    cap = cv2.VideoCapture(path)
    try:
        rotation = int(cap.get(cv2.CAP_PROP_ORIENTATION_META) or 0)
    finally:
        cap.release()
    from head360cli.perception.faces import detect_blazeface, detect_yunet

    faces = max(len(detect_yunet(first)), len(detect_blazeface(first)))
    return {"kind": "video", "path": path, "frames": count, "fps": round(float(fps), 4),
            "width": int(size[0]), "height": int(size[1]),
            "duration_s": None if not count else round(count / float(fps), 4),
            "rotation_deg": rotation, "faces_in_frame_0": faces,
            "bytes": Path(path).stat().st_size}


def inspect_file(path: str, on_bad: str = "error", plot: str | None = None,
                 fps: float | None = None) -> dict[str, Any]:
    """Describe a file: ARKit stream, image or head file.

    Args:
        path: The file, or ``-`` for an ARKit stream on standard input.
        on_bad: Bad-cell policy for streams (``error``, ``skip``, ``hold``).
        fps: A stream's own frame rate, when its time column cannot tell it
            (:func:`~head360cli.io.arkit.read_arkit_csv`).
        plot: For a stream, also draw its curves into this PNG.

    Returns:
        A JSON-ready description whose ``kind`` says which of the three it is.
    """
    from head360cli.io.sources import is_pipe, readable

    shown = path  # the name in messages and output, a pipe's too
    if path == "-":  # standard input: a stream, a head file or an image, by its bytes
        import sys

        from head360cli.io.sources import NamedBytes, check_stdin, read_whole

        check_stdin("a stream, a head file or an image")
        raw = read_whole(sys.stdin.buffer, "<stdin>") if hasattr(sys.stdin, "buffer") else (
            sys.stdin.read().encode("utf-8"))  # a text stream put in its place
        path, shown = NamedBytes(raw, "<stdin>"), "<stdin>"
    elif is_pipe(path):  # <(...), /dev/stdin: read once, looked at twice
        path, _ = readable(path)
    kind = file_kind(path)
    if plot is not None and kind != "stream":
        what = {"image": "an image", "head": "a head file", "model": "a model file",
                "mesh": "a mesh", "video": "a video"}[kind]
        raise BadInputError(f"--plot draws ARKit streams; expected a .csv, found {what}: {shown!r}")
    if kind == "video":
        if not isinstance(path, str):
            raise BadInputError(f"expected a video in a file, found one on a pipe: {shown!r}")
        return describe_video(path)
    if kind == "model":
        return describe_model(path, shown)
    if kind == "mesh":
        return describe_mesh(path, shown)
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

    stream = read_arkit_csv(path, on_bad=on_bad, fps=fps)  # type: ignore[arg-type]
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

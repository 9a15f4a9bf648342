"""The perception models' files and the runtime that runs them.

The face detector, the 478-point landmarker, the blendshape scorer and the hair
segmenter are MediaPipe's TFLite files, run by LiteRT (the ``ai-edge-litert``
package: CPU wheels for Linux, Windows and macOS, no TensorFlow); YuNet is an ONNX file
that OpenCV's DNN module runs. Each file is checked against its SHA-256 the first time a
process opens it, so a damaged or replaced file is a one-line error, never a crash.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import platform
import zipfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from head360cli.errors import FileFormatError, ModelNotFoundError, UnsupportedPlatformError

__all__ = ["PERCEPTION_FILES", "PerceptionFile", "TfliteModel", "check_cpu", "model_bytes",
           "perception_file", "quiet_stderr", "tflite_model"]


@dataclasses.dataclass(frozen=True)
class PerceptionFile:
    """One third-party model file shipped in ``models/``."""

    filename: str
    """Its name in the models folder."""
    sha256: str
    """SHA-256 of the file as shipped (the upstream file, unchanged)."""
    what: str
    """What it does, in a few words."""
    licence: str
    """Its licence (the text is in the models folder)."""


PERCEPTION_FILES: dict[str, PerceptionFile] = {
    "face_landmarker": PerceptionFile(
        "face_landmarker.task",
        "64184e229b263107bc2b804c6625db1341ff2bb731874b0bcc2fe6544e0bc9ff",
        "MediaPipe Face Landmarker: short-range face detector, 478 landmarks, "
        "52 blendshape scores", "Apache-2.0"),
    "face_detector_full": PerceptionFile(
        "face_detection_full_range.tflite",
        "99bf9494d84f50acc6617d89873f71bf6635a841ea699c17cb3377f9507cfec3",
        "MediaPipe BlazeFace full range: faces small and large", "Apache-2.0"),
    "yunet": PerceptionFile(
        "face_detection_yunet_2023mar.onnx",
        "8f2383e4dd3cfbb4553ea8718107fc0423210dc964f9f4280604804ed2552fa4",
        "YuNet face detector (OpenCV Zoo), run by OpenCV", "MIT"),
    "hair_segmenter": PerceptionFile(
        "hair_segmentation.tflite",
        "d2c940c4fd80edeaf38f5d7387d1b4235ee320ed120080df67c663e749e77633",
        "MediaPipe hair segmentation, 512x512", "Apache-2.0"),
    "canonical_face": PerceptionFile(
        "canonical_face_model.obj",
        "8bac80443397e113f41a8b565ea72c59390bc031d9defab289dba7bc0c54e618",
        "MediaPipe canonical face mesh: where the 468 landmarks sit on a face",
        "Apache-2.0"),
}
"""The perception model files by role."""


@functools.lru_cache(maxsize=16)
def perception_file(role: str) -> Path:
    """The checked path of the model file for ``role`` (a key of :data:`PERCEPTION_FILES`).

    Raises:
        ModelNotFoundError: The file is missing.
        FileFormatError: Its SHA-256 is not the shipped file's (damaged or replaced).
    """
    from head360cli.paths import models_dir

    spec = PERCEPTION_FILES[role]
    path = models_dir() / spec.filename
    if not path.is_file():
        raise ModelNotFoundError(f"expected the model file {spec.filename} in {path.parent}, "
                                 f"found none: reinstall head360")
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    if digest != spec.sha256:
        raise FileFormatError(f"expected {path} with SHA-256 {spec.sha256[:12]}..., found "
                              f"{digest[:12]}...: the file is damaged or replaced; "
                              f"reinstall head360")
    return path


def model_bytes(role: str, member: str | None = None) -> bytes:
    """The bytes of a model file, or of ``member`` of a ``.task`` bundle (a zip)."""
    path = perception_file(role)
    if member is None:
        return path.read_bytes()
    with zipfile.ZipFile(path) as bundle:
        return bundle.read(member)


def check_cpu() -> None:
    """Refuse, before importing LiteRT, a CPU its wheels cannot run: an x86-64 CPU
    without AVX (read from ``/proc/cpuinfo`` on Linux; other systems are trusted), where
    the import would die of an illegal instruction instead of raising.

    Raises:
        UnsupportedPlatformError: The CPU lacks AVX.
    """
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return
    try:
        text = Path("/proc/cpuinfo").read_text(errors="replace")
    except OSError:
        return
    flags = next((line.split(":", 1)[1].split() for line in text.splitlines()
                  if line.startswith("flags")), None)
    if flags is not None and "avx" not in flags:
        raise UnsupportedPlatformError(
            "expected an x86-64 CPU with AVX for the face and hair models (LiteRT), found "
            "one without: run head360 on a newer CPU")


@contextlib.contextmanager
def quiet_stderr() -> Iterator[None]:
    """Silence what C++ libraries print to the process's standard error (file
    descriptor 2) inside the block; Python's own ``sys.stderr`` is untouched."""
    import os
    import sys

    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no descriptor 2 (a detached process): nothing to hide
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


class TfliteModel:
    """A TFLite model on LiteRT's CPU interpreter: ``model(x)`` runs it on one input.

    Args:
        content: The ``.tflite`` flatbuffer.
        threads: Interpreter threads.
    """

    def __init__(self, content: bytes, threads: int = 1) -> None:
        check_cpu()
        try:
            from ai_edge_litert.interpreter import Interpreter
        except ImportError as exc:
            raise ModelNotFoundError(
                "expected the package ai-edge-litert (runs the face and hair models), found "
                "none: pip install ai-edge-litert") from exc
        try:
            with quiet_stderr():  # LiteRT's C++ prints a line about its CPU delegate
                self._it = Interpreter(model_content=content,
                                       num_threads=max(1, int(threads)))
                self._it.allocate_tensors()
        except (ValueError, RuntimeError) as exc:
            raise FileFormatError(f"expected a TFLite model, found one LiteRT cannot load: "
                                  f"{exc}") from exc
        self._input = self._it.get_input_details()[0]
        self._outputs = [d["index"] for d in self._it.get_output_details()]
        self.input_shape = tuple(int(v) for v in self._input["shape"])

    def __call__(self, x: np.ndarray) -> list[np.ndarray]:
        """Outputs for one float32 input of :attr:`input_shape`, copied out."""
        self._it.set_tensor(self._input["index"], np.ascontiguousarray(x, np.float32))
        self._it.invoke()
        return [self._it.get_tensor(i).copy() for i in self._outputs]


MAX_THREADS = 2
"""LiteRT threads at most: the face mesh's pass takes 8.5 ms on one thread and 4.3 ms on
two (2-core Xeon); these small models gain little from more."""


def tflite_model(role: str, member: str | None = None, threads: int | None = None
                 ) -> TfliteModel:
    """The model for ``role`` (and ``member`` of a bundle), loaded once a process;
    ``threads`` default: the process's budget (:func:`head360cli.threads.thread_budget`),
    at most :data:`MAX_THREADS`."""
    if threads is None:
        from head360cli.threads import thread_budget

        threads = min(MAX_THREADS, thread_budget())
    return _tflite_model(role, member, threads)


@functools.lru_cache(maxsize=16)
def _tflite_model(role: str, member: str | None, threads: int) -> TfliteModel:
    return TfliteModel(model_bytes(role, member), threads)

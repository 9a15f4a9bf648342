"""Where head360 finds its model files and the real evaluation data."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

__all__ = ["cache_dir", "dlib_model_files", "installed_generator", "models_dir",
           "shared_data_dir", "use_generator"]

_PACKAGE = Path(__file__).resolve().parent


def models_dir() -> Path:
    """The folder with the shipped model files.

    In order: ``$HEAD360_MODELS``; the ``models/`` folder of a source checkout (next to
    the package); the copy installed with the package (``head360cli/_models``).
    """
    env = os.environ.get("HEAD360_MODELS")
    if env:
        return Path(env)
    checkout = _PACKAGE.parent / "models"
    if checkout.is_dir() and (_PACKAGE.parent / "pyproject.toml").is_file():
        return checkout
    return _PACKAGE / "_models"


_GENERATOR: Path | None = None
"""Weights that stand for the installed generator inside :func:`use_generator`."""


@contextlib.contextmanager
def use_generator(path: str | os.PathLike[str] | None) -> Iterator[None]:
    """Inside the ``with`` block, ``path`` is the installed generator (``None``: as it
    was): a bench runs the same pipeline with each weights file it compares."""
    global _GENERATOR
    own = _GENERATOR
    _GENERATOR = own if path is None else Path(path)
    try:
        yield
    finally:
        _GENERATOR = own


def installed_generator(path: str | os.PathLike[str] | None = None) -> Path:
    """The generator weights at ``path`` (default ``generator.pt`` in :func:`models_dir`,
    or the weights of :func:`use_generator`), once known to be there.

    Raises:
        ModelNotFoundError: No file there.
    """
    from head360cli.errors import ModelNotFoundError

    if path is None:
        path = _GENERATOR or models_dir() / "generator.pt"
    path = Path(path)
    if not path.is_file():
        raise ModelNotFoundError(f"generator weights not found at {str(path)!r}; train them "
                                 "with 'head360 train'")
    return path


def shared_data_dir() -> Path | None:
    """``../shared/data`` beside a source checkout (or ``$HEAD360_SHARED_DATA``), if present."""
    env = os.environ.get("HEAD360_SHARED_DATA")
    candidates = [Path(env)] if env else []
    candidates += [
        _PACKAGE.parent.parent / "shared" / "data",
        Path.cwd().parent / "shared" / "data",
    ]
    for c in candidates:
        if c.is_dir():
            return c
    return None


def dlib_model_files() -> dict[str, Path | None]:
    """Paths of the dlib weights shipped by the ``face-recognition-models`` package.

    The package is located without importing it (its import needs ``pkg_resources``,
    which new setuptools no longer has).

    Returns:
        ``{"shape_predictor_68": path, "cnn_face_detector": path, "face_descriptor": path,
        "shape_predictor_5": path}``; a value is ``None`` when the file is missing.
    """
    import importlib.util

    names = {
        "shape_predictor_68": "shape_predictor_68_face_landmarks.dat",
        "shape_predictor_5": "shape_predictor_5_face_landmarks.dat",
        "cnn_face_detector": "mmod_human_face_detector.dat",
        "face_descriptor": "dlib_face_recognition_resnet_model_v1.dat",
    }
    spec = importlib.util.find_spec("face_recognition_models")
    roots = list(spec.submodule_search_locations or []) if spec else []
    out: dict[str, Path | None] = {}
    for key, filename in names.items():
        found = [Path(r) / "models" / filename for r in roots]
        out[key] = next((p for p in found if p.is_file()), None)
    return out


def cache_dir() -> Path | None:
    """The folder for files head360 can always make again, kept to save time in later runs
    (:mod:`head360cli.cache`).

    In order: ``$HEAD360_CACHE`` (set but empty: no cache); ``$XDG_CACHE_HOME/head360``;
    ``~/.cache/head360`` (no cache when there is no home folder). The folder is made
    when a file is first written to it; deleting it is always safe.
    """
    env = os.environ.get("HEAD360_CACHE")
    if env is not None:
        return Path(env) if env else None
    xdg = os.environ.get("XDG_CACHE_HOME")
    if xdg:
        return Path(xdg) / "head360"
    try:
        return Path.home() / ".cache" / "head360"
    except RuntimeError:  # no home folder to be found: no cache
        return None


def generator_hash() -> str:
    """SHA-256 of the installed generator's weights, which head files record.

    Raises:
        ModelNotFoundError: No weights installed (as :func:`installed_generator` says).
    """
    import hashlib

    return hashlib.sha256(installed_generator().read_bytes()).hexdigest()

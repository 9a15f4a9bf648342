"""Files head360 can always make again, kept between runs to save their making time.

The folder is :func:`head360cli.paths.cache_dir`. Everything here is best effort: a
cache that cannot be read or written costs only the time, and a file that does not read
back as expected is made again and written over. Files are written to a temporary name
and renamed into place, so a reader never sees half a file.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

__all__ = ["cache_file", "cached_array", "store"]


def cache_file(name: str) -> Path | None:
    """The cache's path for ``name`` (a plain file name), or ``None`` with no cache."""
    from head360cli.paths import cache_dir

    folder = cache_dir()
    return None if folder is None else folder / name


def store(path: Path | None, write: Callable[[str], object]) -> bool:
    """Write a cache file with ``write(temporary path)``, then rename it into place.

    Returns:
        Whether the file is now in the cache; errors (a read-only or missing home, a
        full disk) are swallowed, as the next run can make the file again.
    """
    if path is None:
        return False
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write(str(tmp))
        os.replace(tmp, path)
        return True
    except (OSError, RuntimeError):  # dlib reports failed writes as RuntimeError
        with contextlib.suppress(OSError):
            tmp.unlink()
        return False


def cached_array(name: str, make: Callable[[], np.ndarray], shape: tuple[int, ...],
                 dtype: np.dtype | type) -> np.ndarray:
    """``make()``, or the array it gave before, read from the cache file ``name`` (``.npy``,
    read without pickles).

    Args:
        name: File name; it must change whenever ``make``'s result would (put a hash of
            its inputs in it).
        make: Makes the array.
        shape: The array's shape, and ``dtype`` its dtype: a file holding anything else
            is made again and written over.

    Returns:
        The array.
    """
    path = cache_file(name)
    if path is not None and path.is_file():
        try:
            found = np.load(path, allow_pickle=False)
            if found.shape == tuple(shape) and found.dtype == np.dtype(dtype):
                return found
        except (OSError, ValueError, EOFError):  # damaged: made again below
            pass
    array = np.ascontiguousarray(make())
    store(path, lambda tmp: _save_npy(tmp, array))
    return array


def _save_npy(path: str, array: np.ndarray) -> None:
    with open(path, "wb") as f:
        np.lib.format.write_array(f, array, allow_pickle=False)

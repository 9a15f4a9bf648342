"""Reading torch files (weights, checkpoints) as data only.

``torch.load`` with ``weights_only=True`` rebuilds tensors, numbers, strings and
containers, and refuses any other pickled object, so a file from elsewhere cannot run code
when head360 opens it. :func:`load_data` turns every way such a load fails into one
:class:`~head360cli.errors.FileFormatError` with a one-line message.
"""

from __future__ import annotations

import os
import re
from typing import IO, Any

__all__ = ["load_data"]

_ANSI = re.compile(r"\x1b\[[0-9;]*m")


def load_data(source: str | os.PathLike[str] | IO[bytes], expected: str,
              name: str | None = None) -> Any:
    """The content of a torch file, on the CPU, read as data only.

    Args:
        source: A path or a binary file object.
        expected: What the file should be, for the message (``"a training checkpoint"``).
        name: The file's name in the message (default: ``source`` as a string).

    Raises:
        FileFormatError: Not a torch file, truncated, or holding objects other than
            tensors and plain values (a pickle that would run code on load).
    """
    import pickle

    import torch

    from head360cli.errors import FileFormatError

    shown = name or str(source)
    try:
        return torch.load(source, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:  # weights_only refused an object: it could run code
        raise FileFormatError(f"{shown}: expected {expected}, found a torch file holding "
                              f"other objects than tensors and plain values (they could "
                              f"run code, so it is not loaded)") from None
    except Exception as exc:  # zip, EOF and storage errors alike
        text = _ANSI.sub("", str(exc)).strip()
        first = text.splitlines()[0][:200] if text else type(exc).__name__
        raise FileFormatError(f"{shown}: expected {expected}, found a file torch cannot "
                              f"read ({first})") from None

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
    except pickle.UnpicklingError as exc:
        text = _ANSI.sub("", str(exc))
        if "global" in text.lower():  # weights_only refused an object: it could run code
            raise FileFormatError(f"{shown}: expected {expected}, found a torch file "
                                  f"holding other objects than tensors and plain values "
                                  f"(they could run code, so it is not loaded)") from None
        # bytes that are no pickle at all ("Unsupported operand 110"): not a torch file
        detail = text.split("WeightsUnpickler error:")[-1].strip().splitlines()
        first = detail[0][:200] if detail and detail[0] else type(exc).__name__
        raise FileFormatError(f"{shown}: expected {expected}, found a file torch cannot "
                              f"read ({first})") from None
    except Exception as exc:  # zip, EOF and storage errors alike
        text = _ANSI.sub("", str(exc)).strip()
        first = text.splitlines()[0][:200] if text else type(exc).__name__
        raise FileFormatError(f"{shown}: expected {expected}, found a file torch cannot "
                              f"read ({first})") from None

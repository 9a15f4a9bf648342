"""JSON text that every JSON reader accepts.

Python's ``json`` writes a float NaN or infinity as the bare words ``NaN`` and
``Infinity``, which the JSON standard does not have: JavaScript's ``JSON.parse``, ``jq``
and most other readers refuse the whole document. head360 writes a number it could not
measure (a loss that overflowed, a correlation of no pairs) as ``null`` instead, the
value its outputs already use for "not measured".
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

__all__ = ["dumps", "finite"]


def finite(value: Any) -> Any:
    """``value`` with every non-finite float, at any depth of dicts, lists and tuples,
    replaced by ``None``; numpy scalars become Python numbers. Other values are kept."""
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def dumps(value: Any, **kwargs: Any) -> str:
    """``json.dumps`` of :func:`finite` ``(value)``, refusing anything still non-finite.

    Args:
        value: JSON-ready data (dicts, lists, strings, numbers, booleans, ``None``).
        **kwargs: Passed to ``json.dumps`` (``indent``, ``sort_keys``, ...).
    """
    return json.dumps(finite(value), allow_nan=False, **kwargs)

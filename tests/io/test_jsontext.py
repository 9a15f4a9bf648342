"""Strict JSON text: no bare NaN or Infinity in what head360 writes."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from head360cli.io.jsontext import dumps, finite


def _strict(text: str):
    """Parse as a standard JSON reader does: NaN and Infinity are errors."""
    def refuse(word):
        raise ValueError(f"not JSON: {word}")
    return json.loads(text, parse_constant=refuse)


def test_non_finite_numbers_become_null_at_any_depth():
    value = {"r": math.nan, "interval_95": [-math.inf, 0.5], "rows": [{"psnr": math.inf}],
             "kept": (1, "NaN", None, True), "np": np.float32("nan"), "n": np.int64(3),
             "f": np.float64(0.25)}
    assert _strict(dumps(value)) == {"r": None, "interval_95": [None, 0.5],
                                     "rows": [{"psnr": None}], "kept": [1, "NaN", None, True],
                                     "np": None, "n": 3, "f": 0.25}
    # What json.dumps alone writes, and a standard reader refuses:
    with pytest.raises(ValueError, match="not JSON"):
        _strict(json.dumps({"r": math.nan}))


def test_finite_keeps_ordinary_values_and_passes_options_on():
    value = {"b": [1, 2.5, "x"], "a": {"c": None}}
    assert finite(value) == value
    assert dumps(value, sort_keys=True, indent=1) == json.dumps(value, sort_keys=True,
                                                                indent=1)

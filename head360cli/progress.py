"""Progress bars for long work: shown on a terminal, silent with --quiet or in pipes."""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator
from typing import TypeVar

__all__ = ["progress_bar"]

T = TypeVar("T")


def progress_bar(iterable: Iterable[T], total: int | None = None, desc: str = "",
                 enabled: bool = True) -> Iterator[T]:
    """Wrap ``iterable`` in a tqdm bar on stderr when enabled and stderr is a terminal."""
    from tqdm import tqdm

    show = enabled and sys.stderr.isatty()
    yield from tqdm(iterable, total=total, desc=desc, disable=not show, unit="it",
                    dynamic_ncols=True, file=sys.stderr)

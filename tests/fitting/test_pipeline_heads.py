"""Loading head files for rendering: which heads the installed models can draw."""

from __future__ import annotations

import pytest


def test_a_head_made_with_another_parametric_head_is_refused(head_file, tmp_path):
    """Its identity code would shape another face: refit rather than render a stranger."""
    from head360cli.errors import ModelMismatchError
    from head360cli.fitting.pipeline import load_head_renderer
    from head360cli.io.headfile import read_head, write_head

    head = read_head(head_file)
    assert load_head_renderer(head_file, size=64).size == 64  # its own model: fine
    head.info["bilinear_model"] = "ab" * 32  # e.g. a model built with scanned expressions
    old = tmp_path / "old.h360"
    write_head(head, old)
    with pytest.raises(ModelMismatchError, match=r"parametric head abababababab.*fit the "
                                                 r"photo again"):
        load_head_renderer(old)

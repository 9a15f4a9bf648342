"""examples/python_api.py: the library calls the README's Python section shows run, and
each writes what it says."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from tests.conftest import REPO


def _example():
    spec = importlib.util.spec_from_file_location("python_api",
                                                  REPO / "examples" / "python_api.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_python_api_example_renders_animates_swaps_and_exports(head_file, tmp_path):
    import imageio.v3 as iio
    import imageio_ffmpeg
    import trimesh

    from head360cli.io.headfile import read_head

    files = _example().main(head_file, tmp_path / "out", size=64, end=0.1)
    assert set(files) == {"views", "video", "swapped", "mesh"}  # a head given: no fit
    views = iio.imread(files["views"])
    assert views.ndim == 3 and views.shape[1] == 2 * 64  # four views, two a row
    assert views.std() > 10  # a head, not a blank
    reader = imageio_ffmpeg.read_frames(files["video"])
    assert next(reader)["size"] == (64, 64)
    assert sum(1 for _ in reader) == 6  # 60 fps before 0.1 s (--end is exclusive)
    assert int(read_head(files["swapped"]).arrays["hair_style"]) == 11  # bob
    head = trimesh.load(files["mesh"]).geometry["head"]
    assert len(head.metadata["targetNames"]) == 52  # the ARKit blendshapes, by name
    assert "jawOpen" in head.metadata["targetNames"]
    assert np.isfinite(head.vertices).all()

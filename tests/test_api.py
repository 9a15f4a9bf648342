"""The public Python API (``head360cli.fit``, ``load_head``, ``render``, ``animate``):
the same heads, frames and errors as the command line."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import head360cli as h
from head360cli.errors import BadInputError
from tests.conftest import REPO


def test_importing_the_package_imports_nothing_heavy_and_the_api_lazily():
    code = ("import sys, head360cli; "
            "heavy = [m for m in ('torch', 'numpy', 'cv2', 'dlib') if m in sys.modules]; "
            "fit = head360cli.fit; "
            "print(heavy, 'head360cli.api' in sys.modules, fit.__module__)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=REPO)
    assert out.stdout.split() == ["[]", "True", "head360cli.api"]


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'fitt'"):
        h.fitt  # noqa: B018


@pytest.fixture(scope="module")
def small_head(head_file):
    return h.load_head(head_file, size=64, samples=4)


def test_render_gives_one_image_per_yaw(small_head):
    views = h.render(small_head, yaws=[0, 90, 180])
    assert views.shape == (3, 64, 64, 3) and views.dtype == np.uint8
    # the head fills part of each view, on white, and the three views differ
    assert all(0.05 < (v < 250).any(-1).mean() < 0.9 for v in views)
    assert np.abs(views[0].astype(int) - views[2]).mean() > 5


def test_render_expressions_by_dict_string_or_weights_agree(small_head):
    from head360cli.mesh.arkit52 import ARKIT52

    by_dict = h.render(small_head, expression={"jawOpen": 0.8})
    by_text = h.render(small_head, expression="JawOpen=0.8")
    weights = np.zeros(52, np.float32)
    weights[ARKIT52.index("jawOpen")] = 0.8
    by_weights = h.render(small_head, expression=weights)
    np.testing.assert_array_equal(by_dict, by_text)
    np.testing.assert_array_equal(by_dict, by_weights)
    # an open jaw changes the picture from the head's own expression
    own = h.render(small_head)
    assert np.abs(own.astype(int) - by_dict).max() > 30


def test_render_refuses_bad_expressions_and_angles(small_head):
    with pytest.raises(BadInputError, match="52 finite ARKit weights"):
        h.render(small_head, expression=np.zeros(51))
    with pytest.raises(BadInputError):
        h.render(small_head, expression="notAShape=1")
    with pytest.raises(BadInputError):
        h.render(small_head, yaws=[0.0], pitch=120.0)


def test_render_from_a_path_matches_the_loaded_head(head_file):
    loaded = h.render(h.load_head(head_file), yaws=30)
    from_path = h.render(head_file, yaws=30)
    np.testing.assert_array_equal(loaded, from_path)


def test_animate_writes_a_video_of_the_stream_s_frames(small_head, tmp_path):
    import imageio.v3 as iio

    stream = REPO / "examples" / "smile_blink_livelinkface.csv"
    out = tmp_path / "clip"  # a folder of PNG frames
    result = h.animate(small_head, stream, out, end=0.25)
    frames = sorted(out.glob("*.png"))
    assert result["frames"] == len(frames) > 0
    assert iio.imread(frames[0]).shape == (64, 64, 3)


def test_fit_options_are_checked_before_any_work(tmp_path):
    photo = tmp_path / "missing.jpg"
    with pytest.raises(BadInputError, match="preset fast or quality"):
        h.fit(photo, tmp_path / "me.h360", preset="best")
    with pytest.raises(BadInputError, match=r"hairstyle id between 0 and 29"):
        h.fit(photo, tmp_path / "me.h360", hair_style=30)
    with pytest.raises(TypeError, match="unexpected options colour"):
        h.fit(photo, tmp_path / "me.h360", colour="red")
    with pytest.raises(BadInputError, match="positive focal length"):
        h.fit(photo, tmp_path / "me.h360", h.FitConfig(focal=-1.0))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_fit_from_python_gives_the_command_line_s_head(fitted_astronaut, tmp_path):
    """A fit is deterministic on one machine: the API's fit of the photo the command line
    fitted gives the same summary, times and paths apart, and the same head."""
    from head360cli.io.headfile import read_head

    assert fitted_astronaut.code == 0, fitted_astronaut.err
    summary = h.fit(fitted_astronaut.photo, tmp_path / "api.h360", h.FitConfig())
    cli = fitted_astronaut.summary
    for key in ("timings", "files"):
        assert set(summary[key]) == set(cli[key])
    same = {k for k in cli if k not in ("timings", "files", "photo")}
    assert {k: summary[k] for k in same} == {k: cli[k] for k in same}
    a = read_head(tmp_path / "api.h360").arrays
    b = read_head(fitted_astronaut.head).arrays
    np.testing.assert_array_equal(a["texture"], b["texture"])

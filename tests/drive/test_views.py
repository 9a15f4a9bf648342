"""Views: cameras by yaw and pitch, option parsing, grids, turntables."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from head360cli.drive.views import (
    grid_image,
    parse_expression,
    parse_views,
    view_cameras,
    write_turntable,
)
from head360cli.errors import BadInputError
from head360cli.mesh.arkit52 import INDEX


def test_yaw_zero_is_the_rig_front_camera_and_positive_yaw_sees_the_left_side():
    from head360cli.geometry.cameras import rig72

    rig, yaw, pitch = rig72()
    front = rig[int(np.flatnonzero((yaw.numpy() == 0) & (pitch.numpy() == 0))[0])]
    torch.testing.assert_close(view_cameras(0.0, 0.0)[0], front, atol=1e-6, rtol=0)
    eye = view_cameras(90.0, 0.0)[0, :3, 3]
    assert eye[0] > 0.5  # on the head's left (+x), looking at it
    above = view_cameras(0.0, 60.0)[0, :3, 3]
    assert above[1] > 0.5


def test_cameras_and_intrinsics_refuse_impossible_views():
    """Library callers get the CLI's angle check; before, a pitch of 100 rendered past the
    pole and NaN gave NaN cameras."""
    from head360cli.drive.views import view_intrinsics

    assert view_cameras([0.0, 90.0, 720.0], [-90.0, 90.0, 0.0]).shape == (3, 4, 4)
    for yaw, pitch, found in ((0.0, 100.0, "0.0, 100.0"), ([0.0, np.nan], 0.0, "nan, 0.0"),
                              (np.inf, 0.0, "inf, 0.0"), (0.0, [10.0, -91.0], "0.0, -91.0")):
        with pytest.raises(BadInputError, match=f"pitch within [+]-90 degrees, found {found}"):
            view_cameras(yaw, pitch)
    with pytest.raises(ValueError, match="image size >= 1, found 0"):
        view_intrinsics(0)


def test_parse_expression_accepts_any_spelling_and_rejects_bad_items():
    w = parse_expression("JawOpen=0.8, eyeBlinkLeft=1,mouthSmile_L=0.25")
    assert w[INDEX["jawOpen"]] == pytest.approx(0.8)
    assert w[INDEX["eyeBlinkLeft"]] == 1.0
    assert w[INDEX["mouthSmileLeft"]] == 0.25
    assert w.sum() == pytest.approx(2.05)
    assert not parse_expression(None).any()
    halves = parse_expression("browInnerUp_L=0.2,browInnerUp_R=0.4")
    assert halves[INDEX["browInnerUp"]] == pytest.approx(0.3)
    assert halves.sum() == pytest.approx(0.3)
    for bad in ("JawOpen", "Nose=1", "JawOpen=1.5", "JawOpen=x", "JawOpen=0.5,jawOpen=0.2",
                "browInnerUp_L=0.2,browInnerUp_L=0.4", "browInnerUp=0.2,browInnerUp_R=0.4",
                "browInnerUp_R=0.4,browInnerUp=0.2"):
        with pytest.raises(BadInputError):
            parse_expression(bad)


def test_parse_views():
    assert parse_views("0,45, 90:20") == [(0.0, 0.0), (45.0, 0.0), (90.0, 20.0)]
    for bad in ("", "a", "0:95", "nan"):
        with pytest.raises(BadInputError):
            parse_views(bad)


def test_grid_image_tiles_in_rows():
    tiles = np.stack([np.full((8, 10, 3), i * 20, np.uint8) for i in range(5)])
    g = grid_image(tiles, cols=3)
    assert g.shape == (16, 30, 3)
    assert (g[8:, 10:20] == 80).all() and (g[8:, 20:] == 255).all()
    assert grid_image(tiles, ["a"] * 5, cols=5).shape[0] > 8
    # no images (a ZeroDivisionError before), float frames (cast to black), short labels
    for images, labels, message in ((tiles[:0], None, r"found \(0, 8, 10, 3\) uint8"),
                                    (tiles / 255.0, None, "float64"),
                                    (tiles[..., 0], None, r"\(5, 8, 10\)"),
                                    (tiles, ["a"], r"one label per image \(5\), found 1")):
        with pytest.raises(ValueError, match=message):
            grid_image(images, labels)


def test_turntable_streams_every_frame(head_file, tmp_path):
    import imageio.v3 as iio

    from head360cli.fitting.pipeline import load_head_renderer

    r = load_head_renderer(head_file, samples=4, size=64)
    out = write_turntable(r, tmp_path / "turn", frames=5)
    frames = sorted(out.iterdir())
    assert len(frames) == 5
    first = iio.imread(frames[0])
    assert first.shape == (64, 64, 3) and first.min() < 200  # a head, on white
    with pytest.raises(BadInputError):
        write_turntable(r, tmp_path / "none.gif", frames=0)


@pytest.mark.parametrize("fps", [0.5, 1e9, float("nan")])
def test_turntable_refuses_a_frame_rate_no_player_shows(tmp_path, fps):
    """--fps 1e9 wrote an mp4 that ffmpeg reads back as 0 fps and 0 s long."""
    with pytest.raises(BadInputError, match="frame rate of 1 to 240 frames per second"):
        write_turntable(None, tmp_path / "turn.mp4", frames=2, fps=fps)
    assert not list(tmp_path.iterdir())


def test_turntable_refuses_a_malformed_expression_before_opening_the_video(tmp_path):
    """A (51,) expression was a numpy broadcast error; nothing is written now."""
    out = tmp_path / "turn.gif"
    with pytest.raises(ValueError, match=r"shape \(52,\), found \(51,\)"):
        write_turntable(None, out, frames=2, expression=np.zeros(51))
    assert not out.exists() and not list(tmp_path.iterdir())


def test_check_grid_size_bounds_pixels_and_height():
    """render --views held every view in memory and saved one image: 30 views at 2048
    pixels made a 136-megapixel grid, and 9000 at 32 one 69000 pixels high, which JPEG
    cannot store."""
    from head360cli.drive.views import check_grid_size

    for views, size in ((1, 2048), (18, 2048), (5, 2048), (8000, 32)):
        check_grid_size(views, size)
    with pytest.raises(BadInputError, match=r"\(18 views at --size 2048\), found 19 views, "
                                            r"12288x8872 pixels"):
        check_grid_size(19, 2048)
    with pytest.raises(BadInputError, match=r"65535 pixels high .* 192x69000 pixels"):
        check_grid_size(9000, 32)


def test_views_frame_the_whole_head_with_its_hair(head_file):
    """The afro's top was cut by the frame at 0, 90 and 180 degrees and long styles' ends
    at the bottom of swap-hair's sheets: heads the rig's frame cuts are framed from their
    bounds, the others as before."""
    from head360cli.drive.views import head_framing, view_cameras, view_intrinsics
    from head360cli.fitting.pipeline import load_head_renderer
    from head360cli.geometry.cameras import RIG_DISTANCE, RIG_TARGET
    from head360cli.synth.hair import style_index

    r = load_head_renderer(head_file, size=64, samples=2, precision="fp32")
    k = view_intrinsics(64)

    def edges(renderer, framing):
        """Whether anything but the backdrop touches the top or bottom row."""
        img = renderer.render(view_cameras([0.0, 90.0, 180.0], 0.0, framing), k).numpy()
        drawn = (img < 0.97).any(1)  # (3, H, W)
        return bool(drawn[:, 0].any()), bool(drawn[:, -1].any())

    for name in ("afro", "long wavy"):
        styled = r.with_hair(style_index(name), r.hair_colour)
        target, distance = head_framing(styled)
        assert distance > RIG_DISTANCE
        assert edges(styled, None) != (False, False), name  # the rig's frame cuts it
        assert edges(styled, (target, distance)) == (False, False), name
    short = r.with_hair(style_index("pixie"), r.hair_colour)
    assert head_framing(short) == (RIG_TARGET, RIG_DISTANCE)  # as before
    assert head_framing(r.with_hair(style_index("afro"), r.hair_colour), hair=False) == (
        RIG_TARGET, RIG_DISTANCE)  # bald, the head alone fits


def test_the_photos_expression_leaves_the_eyes_to_the_heads_own_rest():
    """``--expr photo``: the head's own weights, with the eyes' at zero (every frame adds
    the head's own eye openness, so they would count twice)."""
    from head360cli.drive.views import photo_expression
    from head360cli.mesh.arkit52 import INDEX

    own = np.linspace(0.0, 1.0, 52)
    w = photo_expression(own)
    eyes = [INDEX[f"eye{p}{s}"] for p in ("Blink", "Squint", "Wide") for s in ("Left", "Right")]
    assert (w[eyes] == 0).all()
    others = np.setdiff1d(np.arange(52), eyes)
    np.testing.assert_array_equal(w[others], own[others])
    assert own[eyes].any()  # the input is untouched

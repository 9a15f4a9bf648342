"""Frames of videos and of folders: order, timing, cuts, and the inputs that do not read."""

from __future__ import annotations

import numpy as np
import pytest

from head360cli.errors import BadInputError, FileFormatError
from head360cli.io.frames import open_frames


def _clip(path, frames: int = 12, fps: float = 25.0, size=(96, 64)) -> None:
    """A clip whose frame i is grey level 20 i (so decoded frames can be told apart); 25
    frames per second, a rate GIF's centisecond delays hold exactly."""
    from head360cli.io.video import VideoWriter

    with VideoWriter(path, fps=fps) as writer:
        for i in range(frames):
            writer.write(np.full((size[1], size[0], 3), (20 * i) % 256, np.uint8))


@pytest.mark.parametrize("suffix", [".mp4", ".gif"])
def test_a_video_reads_in_order_at_its_rate(tmp_path, suffix):
    path = tmp_path / f"clip{suffix}"
    _clip(path)
    with open_frames(path) as src:
        # a GIF is read by Pillow, frame by frame as the format composes them
        assert src.kind == ("animation" if suffix == ".gif" else "video")
        assert src.size == (96, 64)
        assert src.fps == pytest.approx(25.0, rel=0.01)
        got = list(src.frames())
    assert [i for i, _, _ in got] == list(range(12))
    np.testing.assert_allclose([t for _, t, _ in got], np.arange(12) / src.fps)
    levels = [float(rgb.mean()) for _, _, rgb in got]
    np.testing.assert_allclose(levels, 20 * np.arange(12), atol=6)  # lossy codecs


def test_start_and_end_cut_a_video(tmp_path):
    _clip(tmp_path / "clip.mp4", fps=10.0)
    with open_frames(tmp_path / "clip.mp4") as src:
        # from 0.25 s, stopping before 0.6 s
        assert [i for i, _, _ in src.frames(0.25, 0.6)] == [3, 4, 5]


def test_a_folder_reads_in_name_order_and_refuses_a_frame_of_another_size(tmp_path):
    import cv2

    for i in (2, 0, 1):
        cv2.imwrite(str(tmp_path / f"f{i:03d}.png"), np.full((20, 30, 3), 50 * i, np.uint8))
    (tmp_path / "notes.txt").write_text("not a frame")
    with open_frames(tmp_path, fps=5.0) as src:
        got = list(src.frames())
    assert [round(float(rgb.mean())) for _, _, rgb in got] == [0, 50, 100]
    assert [t for _, t, _ in got] == [0.0, 0.2, 0.4]
    cv2.imwrite(str(tmp_path / "f003.png"), np.zeros((21, 30, 3), np.uint8))
    with open_frames(tmp_path) as src, pytest.raises(BadInputError,
                                                     match=r"30x20, found 'f003\.png' at 30x21"):
        list(src.frames())


def test_inputs_that_hold_no_frames_are_refused(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(BadInputError, match="image frames"):
        open_frames(tmp_path / "empty")
    (tmp_path / "text.mp4").write_bytes(b"this is not a video at all" * 10)
    with pytest.raises(FileFormatError, match=r"cannot open|no frame decodes"):
        open_frames(tmp_path / "text.mp4")
    with pytest.raises(BadInputError, match="found no"):
        open_frames(tmp_path / "missing.mp4")
    with pytest.raises(BadInputError, match="--fps"):
        open_frames(tmp_path / "empty", fps=0)


def test_a_truncated_video_reads_the_frames_it_holds(tmp_path):
    path = tmp_path / "clip.mp4"
    _clip(path, frames=60)
    data = path.read_bytes()
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[: len(data) // 2])
    try:
        src = open_frames(cut)
    except FileFormatError:
        return  # a cut that loses the index reads as no video at all: also a clear error
    with src:
        n = sum(1 for _ in src.frames())
    assert 0 < n <= 60


def test_end_stops_before_that_second_for_videos_folders_and_streams(tmp_path):
    """--end 0.2 of 25 fps: frames at 0, 0.04, ..., 0.16 (5 frames), for a video, a
    folder of frames and an ARKit stream alike; --start 0.08 starts at the frame there."""
    import cv2

    from head360cli.io.arkit import ArkitStream

    _clip(tmp_path / "clip.mp4", fps=25.0)
    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(12):
        cv2.imwrite(str(folder / f"{i:03d}.png"), np.full((16, 16, 3), i * 10, np.uint8))
    for source in (tmp_path / "clip.mp4", folder):
        with open_frames(source, 25.0 if source == folder else None) as src:
            got = [round(t, 3) for _, t, _ in src.frames(None, 0.2)]
            assert got == [0.0, 0.04, 0.08, 0.12, 0.16], source
            assert [round(t, 3) for _, t, _ in src.frames(0.08, 0.2)] == [0.08, 0.12, 0.16]
    stream = ArkitStream(np.zeros((12, 52), np.float32), np.arange(12) / 25.0, 25.0)
    assert stream.between(None, 0.2).num_frames == 5
    assert stream.between(0.08, 0.2).num_frames == 3


@pytest.mark.parametrize(("suffix", "fmt"), [(".gif", "GIF"), (".png", "PNG"),
                                             (".webp", "WEBP")])
def test_every_frame_of_an_animated_image_is_read(tmp_path, suffix, fmt):
    """A 19-frame animation written by Pillow (GIF, APNG, WebP) reads as 19 frames at its
    own rate, each the one written (OpenCV's FFmpeg read such a GIF as one frame)."""
    from PIL import Image

    frames = [Image.fromarray(np.full((24, 32, 3), 12 * i, np.uint8)) for i in range(19)]
    path = tmp_path / f"anim{suffix}"
    frames[0].save(path, format=fmt, save_all=True, append_images=frames[1:], duration=40,
                   loop=0, **({"lossless": True} if fmt == "WEBP" else {}))
    with open_frames(path) as src:
        assert src.kind == "animation" and src.count == 19 and src.size == (32, 24)
        assert src.fps == pytest.approx(25.0)
        got = list(src.frames())
    assert [i for i, _, _ in got] == list(range(19))
    assert [int(rgb[0, 0, 0]) for _, _, rgb in got] == [12 * i for i in range(19)]

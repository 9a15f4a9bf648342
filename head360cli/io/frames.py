"""Frames of a video, of a folder of images, or of a video on standard input, read one at
a time so that memory does not grow with the clip's length.

Videos (mp4, mov, webm, GIF and whatever else OpenCV's FFmpeg reads) are decoded by
OpenCV; a video on standard input (``-``) is first copied to a temporary file, since a
decoder needs to seek. A folder's images are taken in name order and must share one size.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import shutil
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from head360cli.errors import BadInputError, FileFormatError

__all__ = ["DEFAULT_FOLDER_FPS", "FRAME_SUFFIXES", "FrameSource", "open_frames"]

FRAME_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".webp", ".tif", ".tiff")
"""Image files a folder of frames may hold (others are ignored)."""
DEFAULT_FOLDER_FPS = 30.0
"""Frame rate of a folder of frames, and of a video that does not state one."""


@dataclasses.dataclass
class FrameSource:
    """Where frames come from; iterate :meth:`frames` for ``(index, seconds, rgb)``."""

    name: str
    """The input as the user gave it, for messages."""
    fps: float
    """Frames per second (the video's own, or the folder's given rate)."""
    size: tuple[int, int]
    """Width and height of every frame."""
    count: int | None
    """Frames the container says it holds (``None`` when unknown)."""
    kind: str
    """``video``, ``animation`` (an animated GIF, PNG or WebP, read by Pillow) or
    ``folder``."""
    _path: Path
    _files: list[Path] = dataclasses.field(default_factory=list)
    _temporary: bool = False
    decoded: int = 0
    """Frames handed out so far."""

    def frames(self, start: float | None = None, end: float | None = None
               ) -> Iterator[tuple[int, float, np.ndarray]]:
        """``(index, seconds, rgb (H, W, 3) uint8)`` for each frame at ``start <= t <
        end`` seconds (``--end`` stops before that second, as for a stream), in order.

        Raises:
            BadInputError: A folder's frame of another size, or one that does not read.
        """
        import cv2

        first = 0 if start is None else max(0, int(np.ceil(start * self.fps - 1e-9)))
        if self.kind == "animation":
            yield from self._animation_frames(first, end)
            return
        if self.kind == "folder":
            for i in range(first, len(self._files)):
                t = i / self.fps
                if end is not None and t >= end - 1e-9:
                    return
                img = cv2.imread(str(self._files[i]), cv2.IMREAD_COLOR)
                if img is None:
                    raise BadInputError(f"expected an image, found {self._files[i].name!r} "
                                        "that does not read")
                if (img.shape[1], img.shape[0]) != self.size:
                    raise BadInputError(
                        f"expected frames of one size, {self.size[0]}x{self.size[1]}, found "
                        f"{self._files[i].name!r} at {img.shape[1]}x{img.shape[0]}")
                self.decoded += 1
                yield i, t, np.ascontiguousarray(img[:, :, ::-1])
            return
        quiet_ffmpeg()
        cap = cv2.VideoCapture(str(self._path))
        try:
            i = 0
            while True:
                ok, img = cap.read()
                if not ok:
                    return
                t = i / self.fps
                if end is not None and t >= end - 1e-9:
                    return
                if i >= first:
                    self.decoded += 1
                    yield i, t, np.ascontiguousarray(img[:, :, ::-1])
                i += 1
        finally:
            cap.release()

    def close(self) -> None:
        """Remove the temporary copy of standard input, if any."""
        if self._temporary:
            with contextlib.suppress(OSError):
                self._path.unlink()
            self._temporary = False

    def __enter__(self) -> FrameSource:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


    def _animation_frames(self, first: int, end: float | None
                          ) -> Iterator[tuple[int, float, np.ndarray]]:
        """:meth:`frames` of an animated image, every frame composed by Pillow."""
        from PIL import Image

        with Image.open(self._path) as im:
            for i in range(first, self.count or 0):
                t = i / self.fps
                if end is not None and t >= end - 1e-9:
                    return
                im.seek(i)
                self.decoded += 1
                yield i, t, np.ascontiguousarray(np.asarray(im.convert("RGB")))


def _open_animation(path: Path, name: str, fps: float | None) -> FrameSource | None:
    """An animated GIF, PNG or WebP as frames read by Pillow, which composes each frame
    as the format says (OpenCV's FFmpeg read a 19-frame GIF written by Pillow as one
    frame); ``None`` for anything else."""
    from PIL import Image

    try:
        im = Image.open(path)
    except Exception:
        return None
    with im:
        count = int(getattr(im, "n_frames", 1))
        if im.format not in ("GIF", "PNG", "WEBP") or (count < 2 and im.format != "GIF"):
            return None
        durations = []
        for i in range(count):
            im.seek(i)
            im.load()  # WebP states a frame's duration once it is loaded
            durations.append(float(im.info.get("duration") or 0.0))
        size = im.size
    shown = [d for d in durations if d > 0]
    rate = 1000.0 / float(np.median(shown)) if shown else DEFAULT_FOLDER_FPS
    return FrameSource(name, fps or min(rate, 1000.0), size, count, "animation", path)


def open_frames(source: str | os.PathLike[str], fps: float | None = None) -> FrameSource:
    """Open a video file, a folder of frames or ``-`` (a video on standard input).

    Args:
        source: The input.
        fps: Frame rate of a folder of frames (default :data:`DEFAULT_FOLDER_FPS`), or of
            a video in place of its own.

    Raises:
        BadInputError: No such input, an empty folder, standard input a terminal.
        FileFormatError: A file no decoder reads (an unknown codec, not a video), or a
            video with no frame that decodes.
    """
    if fps is not None and not (np.isfinite(fps) and 0.01 <= fps <= 1000):
        raise BadInputError(f"expected --fps between 0.01 and 1000, found {fps}")
    name = str(source)
    if name == "-":
        from head360cli.io.sources import check_stdin

        check_stdin("a video")
        fd, tmp = tempfile.mkstemp(prefix="head360-video-", suffix=".bin")
        with os.fdopen(fd, "wb") as out:
            shutil.copyfileobj(sys.stdin.buffer, out, 1 << 20)
        try:
            found = _open_video(Path(tmp), "standard input", fps)
        except Exception:
            os.unlink(tmp)
            raise
        found._temporary = True
        return found
    path = Path(source)
    if path.is_dir():
        return _open_folder(path, fps)
    if not path.exists():
        raise BadInputError(f"expected a video, a folder of frames or '-', found no "
                            f"{name!r}")
    return _open_video(path, name, fps)


def _open_folder(path: Path, fps: float | None) -> FrameSource:
    import cv2

    files = sorted(p for p in path.iterdir() if p.suffix.lower() in FRAME_SUFFIXES)
    if not files:
        raise BadInputError(f"expected image frames ({', '.join(FRAME_SUFFIXES)}) in "
                            f"{str(path)!r}, found none")
    first = cv2.imread(str(files[0]), cv2.IMREAD_COLOR)
    if first is None:
        raise BadInputError(f"expected an image, found {files[0].name!r} that does not read")
    return FrameSource(str(path), fps or DEFAULT_FOLDER_FPS, (first.shape[1], first.shape[0]),
                       len(files), "folder", path, files)


FFMPEG_LOG = "OPENCV_FFMPEG_LOGLEVEL"
"""The variable by which OpenCV sets FFmpeg's log level: head360 sets it to quiet (-8)
where the user has not, so that a broken video gives head360's one line and not
FFmpeg's ("moov atom not found", [h264] lines); ``--debug`` lets FFmpeg speak."""


def quiet_ffmpeg() -> None:
    """Keep FFmpeg's log quiet (see :data:`FFMPEG_LOG`), before OpenCV opens a video."""
    os.environ.setdefault(FFMPEG_LOG, "-8")


def _open_video(path: Path, name: str, fps: float | None) -> FrameSource:
    import cv2

    if path.is_file() and path.stat().st_size == 0:
        raise FileFormatError(f"expected a video, found {name!r}, an empty file")
    animation = _open_animation(path, name, fps)
    if animation is not None:
        return animation
    quiet_ffmpeg()
    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise FileFormatError(f"expected a video OpenCV's FFmpeg can decode, found "
                                  f"{name!r} it cannot open (an unknown codec or not a video)")
        ok, img = cap.read()
        if not ok or img is None:
            raise FileFormatError(f"expected a video with frames, found {name!r} in which "
                                  "no frame decodes")
        rate = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
    finally:
        cap.release()
    if fps is None:
        fps = rate if np.isfinite(rate) and 0 < rate <= 1000 else DEFAULT_FOLDER_FPS
    return FrameSource(name, fps, (img.shape[1], img.shape[0]), count if count > 0 else None,
                       "video", path)

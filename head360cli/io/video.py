"""Streaming frame writers: mp4 (H.264), GIF, or a folder of PNGs, chosen by the name.

- ``*.mp4``, ``*.m4v``, ``*.mov``: H.264 through the ffmpeg binary that imageio-ffmpeg
  ships, ``yuv420p`` so that every player opens it; odd sizes are padded to even by
  repeating the last row/column.
- ``*.gif``: ffmpeg's GIF encoder with a palette per frame, looping forever.
- a name ending in ``/``, without a suffix, or an existing folder: ``frame_000000.png`` ...

Frames are sent to the encoder one at a time (the writer holds none of them), and the
output appears only when the writer is closed without error: it is written under a
temporary name beside the target and renamed.
"""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Iterable
from pathlib import Path
from types import TracebackType

import numpy as np

from head360cli.errors import BadInputError
from head360cli.io.atomic import (
    check_dir_target,
    check_name_length,
    check_replaceable,
    check_writable,
    commit_dir,
    replace_keeping_mode,
    temp_dir_beside,
    temp_name_beside,
    write_target,
)

__all__ = ["GIF_MAX_FPS", "MAX_FPS", "MIN_FPS", "VIDEO_SUFFIXES", "VideoWriter", "check_gif_rate",
           "check_video_target", "output_kind", "write_video"]

VIDEO_SUFFIXES = (".mp4", ".m4v", ".mov")

MIN_FPS, MAX_FPS = 1.0, 240.0
"""The frame rates head360 writes videos at (frames per second)."""

GIF_MAX_FPS = 50.0
"""The fastest GIF that plays at its speed: a GIF frame lasts whole hundredths of a second,
and browsers show a frame of one hundredth (or none) for a tenth, so a 60 fps take,
stored as frames of 2, 1, 2, 2, 1... hundredths, played several times too slowly."""


def check_gif_rate(path: str | os.PathLike[str], fps: float) -> None:
    """Refuse a GIF output at more than :data:`GIF_MAX_FPS` frames per second.

    Raises:
        BadInputError: ``path`` names a GIF and ``fps`` is above the limit.
    """
    if fps > GIF_MAX_FPS and output_kind(path) == "gif":
        raise BadInputError(f"expected at most {GIF_MAX_FPS:g} frames per second for a GIF "
                            f"(browsers slow shorter frames down), found {fps:g}: give "
                            f"--fps {GIF_MAX_FPS:g} or less, or write an .mp4")


def output_kind(path: str | os.PathLike[str]) -> str:
    """``"mp4"``, ``"gif"`` or ``"png"`` (a folder of PNGs), from the output name.

    Raises:
        BadInputError: For a suffix that is none of these.
    """
    text = os.fspath(path)
    p = Path(text)
    check_name_length(p)
    suffix = p.suffix.lower()
    if text.endswith(("/", os.sep)) or p.is_dir() or suffix == "":
        return "png"
    if suffix in VIDEO_SUFFIXES:
        return "mp4"
    if suffix == ".gif":
        return "gif"
    raise BadInputError(
        f"expected an output ending in .mp4 (.m4v, .mov), .gif or a folder name, found "
        f"{p.name!r}"
    )


def _as_uint8(frame: np.ndarray) -> np.ndarray:
    a = np.asarray(frame)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[2] not in (1, 3, 4):
        raise BadInputError(f"expected a frame of shape (H, W, 3), found {tuple(a.shape)}")
    if a.dtype != np.uint8:
        if a.dtype.kind == "f":
            a = np.round(np.clip(np.nan_to_num(a, nan=0.0), 0.0, 1.0) * 255.0)
        a = np.clip(a, 0, 255).astype(np.uint8)
    if a.shape[2] == 1:
        a = np.repeat(a, 3, axis=2)
    return a


def check_video_target(path: str | os.PathLike[str], overwrite: bool = False) -> None:
    """Refuse, before any frame is made, a video output :class:`VideoWriter` would refuse
    when it opens: a missing parent folder, a folder given for a file, or a non-empty
    folder for PNG frames (unless ``overwrite``)."""
    writer = VideoWriter(path, overwrite=overwrite)  # checks the parent, file vs folder
    if writer.kind == "png":
        check_dir_target(writer.path, overwrite)
    else:
        check_writable(writer.path.parent)


class VideoWriter:
    """Write frames to an mp4, a GIF or a PNG folder, streaming and atomically.

    Use as a context manager::

        with VideoWriter("turn.mp4", fps=30) as out:
            for frame in frames:          # (H, W, 3) uint8, or float in [0, 1]
                out.write(frame)

    Args:
        path: The output; its name picks the kind (see the module docstring).
        fps: Frames per second.
        quality: x264 constant rate factor for mp4 (lower is better; 18 is visually
            lossless).
        overwrite: Replace an existing non-empty PNG folder.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        fps: float = 30.0,
        *,
        quality: int = 18,
        overwrite: bool = False,
    ) -> None:
        if not (np.isfinite(fps) and fps > 0):
            raise BadInputError(f"expected a positive frame rate, found {fps!r}")
        self.path = Path(os.fspath(path).rstrip("/") or ".")
        self.kind = output_kind(path)
        check_gif_rate(path, fps)
        if isinstance(quality, bool) or not (isinstance(quality, int | np.integer)
                                             and 0 <= quality <= 51):
            raise BadInputError(f"expected an x264 quality (constant rate factor) from 0 to "
                                f"51, found {quality!r}")
        self.fps = float(fps)
        self.quality = int(quality)
        self.overwrite = overwrite
        self.count = 0
        self._size: tuple[int, int] | None = None  # (W, H) of the first frame
        self._encoder: _Encoder | None = None
        self._tmp: Path | None = None
        self._dest = self.path  # where the output goes (a link's file: __enter__)
        parent = self.path.parent
        if not parent.is_dir():
            raise BadInputError(f"output folder {str(parent)!r} does not exist")
        if self.kind != "png" and self.path.is_dir():
            raise BadInputError(f"expected a file name for {str(self.path)!r}, found a folder")
        if self.kind != "png":
            check_replaceable(write_target(self.path))  # where a link leads

    # -- context management
    def __enter__(self) -> VideoWriter:
        self._dest = write_target(self.path)  # a symbolic link's file, not the link
        if self.kind == "png":
            check_dir_target(self._dest, self.overwrite)
            self._tmp = temp_dir_beside(self._dest)
        else:
            self._tmp = temp_name_beside(self._dest)
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        failed = exc_type is not None
        try:
            if self._encoder is not None:
                if failed:
                    self._encoder.kill()
                else:
                    self._encoder.close()
            if not failed and self.count == 0:
                raise BadInputError(f"no frames were given for {str(self.path)!r}")
            if not failed and self._tmp is not None:
                if self.kind == "png":
                    commit_dir(self._tmp, self._dest)
                else:
                    replace_keeping_mode(self._tmp, self._dest)
        finally:
            # Whatever is left under the temporary name is a failed attempt.
            if self._tmp is not None and self._tmp.is_dir():
                shutil.rmtree(self._tmp, ignore_errors=True)
            elif self._tmp is not None:
                with contextlib.suppress(FileNotFoundError):
                    self._tmp.unlink()

    # -- writing
    def write(self, frame: np.ndarray) -> None:
        """Append one ``(H, W, 3)`` (or RGBA, or greyscale) frame."""
        if self._tmp is None:
            raise RuntimeError("VideoWriter.write() called outside its 'with' block")
        a = _as_uint8(frame)
        h, w = a.shape[:2]
        if self._size is None:
            self._size = (w, h)
        elif self._size != (w, h):
            raise BadInputError(
                f"frame {self.count} is {w}x{h}; expected {self._size[0]}x{self._size[1]} "
                "like the first frame"
            )
        if self.kind == "png":
            from PIL import Image

            Image.fromarray(a).save(self._tmp / f"frame_{self.count:06d}.png", compress_level=1)
        else:
            if a.shape[2] == 4:  # video has no alpha: composite over white
                alpha = a[..., 3:4].astype(np.float32) / 255.0
                a = np.round(a[..., :3] * alpha + 255.0 * (1 - alpha)).astype(np.uint8)
            if self.kind == "mp4":  # yuv420p needs even sizes
                a = np.pad(a, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
            if self._encoder is None:
                self._encoder = self._open_encoder(a.shape[1], a.shape[0])
            self._encoder.send(np.ascontiguousarray(a))
        self.count += 1

    def _open_encoder(self, width: int, height: int) -> _Encoder:
        assert self._tmp is not None
        if self.kind == "mp4":
            # ffmpeg's RGB to yuv420p conversion uses BT.601's matrix and limited range;
            # the stream says so, and that the pixels are sRGB, so that players do not
            # guess (many take an untagged HD video for BT.709, shifting its colours).
            # Through x264's own parameters: ffmpeg 9.0 left -color_primaries unwritten.
            args = ["-vcodec", "libx264", "-pix_fmt", "yuv420p", "-crf", str(self.quality),
                    "-x264-params", "colorprim=bt709:transfer=iec61966-2-1:"
                    "colormatrix=smpte170m:fullrange=off", "-movflags", "+faststart"]
            level = "warning"
        else:
            args = ["-vcodec", "gif", "-pix_fmt", "pal8", "-filter_complex",
                    "split[a][b];[a]palettegen=stats_mode=single[p];[b][p]paletteuse=new=1",
                    "-loop", "0"]
            # palettegen warns "Duped color" for every frame of a skin-toned head,
            # dozens of lines past --quiet; errors still show
            level = "error"
        return _Encoder(self._tmp, self.path, width, height, self.fps, args, level)


class _Encoder:
    """One ffmpeg process (the binary imageio-ffmpeg ships) encoding raw RGB frames from
    its standard input into a file, whose exit status is checked.

    imageio-ffmpeg's own writer does not check it, so an encoder that ran out of disk
    space, or was stopped by the shell's file-size limit, left a cut-off file that was
    renamed into place and reported as written. ffmpeg's messages are kept in a temporary
    file: on failure its last line is the error's, on success they are shown as before.
    ffmpeg runs in its own session, so a Ctrl-C reaches head360, which ends it and removes
    the temporary output, rather than cutting the file short on its own.

    Args:
        path: The file ffmpeg writes (the temporary name).
        shown: The name the error messages give (the output the user asked for).
        width: Frame width in pixels.
        height: Frame height in pixels.
        fps: Frames per second.
        args: Codec and output options.
        level: ffmpeg's ``-v`` log level.
    """

    def __init__(self, path: Path, shown: Path, width: int, height: int, fps: float,
                 args: list[str], level: str) -> None:
        import subprocess
        import tempfile
        from fractions import Fraction

        import imageio_ffmpeg

        self.shown = shown
        self.sent = 0
        self._log = tempfile.TemporaryFile()  # noqa: SIM115 (closed once ffmpeg is done)
        # ffmpeg's count of the frames it encoded: it can exit 0 having encoded none
        handle, progress = tempfile.mkstemp(prefix="head360-ffmpeg-", suffix=".txt")
        os.close(handle)
        self._progress = Path(progress)
        try:
            exe = imageio_ffmpeg.get_ffmpeg_exe()
        except RuntimeError as exc:  # imageio-ffmpeg without its binary, none on PATH
            from head360cli.errors import ModelNotFoundError

            self._log.close()
            self._progress.unlink(missing_ok=True)
            why = " ".join(str(exc).split())[:120]
            raise ModelNotFoundError(f"no ffmpeg to write videos ({why}): reinstall "
                                     f"imageio-ffmpeg, or name one in IMAGEIO_FFMPEG_EXE"
                                     ) from None
        cmd = [exe, "-y", "-f", "rawvideo", "-vcodec", "rawvideo",
               "-s", f"{width}x{height}", "-pix_fmt", "rgb24",
               "-r", str(Fraction(fps).limit_denominator()), "-i", "-", "-an", *args,
               "-v", level, "-progress", str(self._progress), str(path)]
        try:
            self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE,
                                          stdout=subprocess.DEVNULL, stderr=self._log,
                                          start_new_session=True)
        except BaseException as exc:
            self._log.close()
            self._progress.unlink(missing_ok=True)
            if isinstance(exc, OSError):  # missing, not executable, not a program
                from head360cli.errors import ModelNotFoundError

                why = exc.strerror or str(exc)
                if os.environ.get("IMAGEIO_FFMPEG_EXE"):
                    message = (f"cannot run ffmpeg {cmd[0]!r}, named by IMAGEIO_FFMPEG_EXE, "
                               f"to write videos ({why}): point it at an ffmpeg program "
                               f"or unset it")
                else:
                    message = (f"cannot run the ffmpeg that imageio-ffmpeg ships "
                               f"({cmd[0]!r}) to write videos ({why}): reinstall "
                               f"imageio-ffmpeg")
                raise ModelNotFoundError(message) from None
            raise

    def send(self, frame: np.ndarray) -> None:
        """Write one contiguous ``(H, W, 3)`` uint8 frame.

        Raises:
            BadInputError: ffmpeg stopped because the output could not be written.
            RuntimeError: ffmpeg stopped for another reason (its last message).
        """
        assert self._proc.stdin is not None
        try:
            self._proc.stdin.write(frame.data)
        except OSError:  # ffmpeg has stopped reading: it failed
            raise self._failure() from None
        self.sent += 1

    def close(self) -> None:
        """Let ffmpeg finish the file and wait for it.

        Raises:
            BadInputError, RuntimeError: As for :meth:`send`, including failures while
                ffmpeg writes the file's end (a full disk at the mp4's index).
        """
        self._close_stdin()
        code = self._proc.wait()
        encoded = self._encoded()  # read once ffmpeg has ended
        if code != 0 or (encoded is not None and encoded < self.sent):
            raise self._failure()
        text = self._messages()
        if text:
            import sys

            sys.stderr.write(text if text.endswith("\n") else text + "\n")

    def kill(self) -> None:
        """Stop ffmpeg at once (the caller removes what it wrote)."""
        with contextlib.suppress(OSError):
            self._proc.kill()
        self._proc.wait()
        self._close_stdin()
        self._log.close()
        self._progress.unlink(missing_ok=True)

    def _encoded(self) -> int | None:
        """The frames ffmpeg says it encoded (the last ``frame=`` of its progress
        report), or ``None`` without a report (a full temporary folder: then only the
        exit status is checked)."""
        try:
            lines = self._progress.read_text(encoding="utf-8", errors="replace")
        except OSError:
            return None
        counts = [line[6:].strip() for line in lines.splitlines()
                  if line.startswith("frame=")]
        return int(counts[-1]) if counts and counts[-1].isdigit() else None

    def _close_stdin(self) -> None:
        with contextlib.suppress(OSError):  # a broken pipe: the exit status tells
            if self._proc.stdin is not None:
                self._proc.stdin.close()

    def _messages(self) -> str:
        self._log.seek(0)
        text = self._log.read().decode("utf-8", "replace")
        self._log.close()
        self._progress.unlink(missing_ok=True)
        return text

    def _failure(self) -> Exception:
        """The error of a failed ffmpeg: a :class:`BadInputError` when the output could
        not be written (no space, a size limit, no permission), else a ``RuntimeError``
        with ffmpeg's last message."""
        import signal

        self._close_stdin()
        code = self._proc.wait()
        encoded = self._encoded()
        text = self._messages()
        lower = text.lower()
        where = str(self.shown)
        kept = "(nothing half-written was kept)"
        if code == -getattr(signal, "SIGXFSZ", 0) or "file too large" in lower:
            return BadInputError(f"cannot write {where!r}: it grew past the file system's "
                                 f"or the shell's file-size limit (ulimit -f): write "
                                 f"elsewhere {kept}")
        if "no space left" in lower or "quota exceeded" in lower:
            return BadInputError(f"cannot write {where!r}: no space left on device: free "
                                 f"space or write elsewhere {kept}")
        if "permission denied" in lower or "read-only file system" in lower:
            return BadInputError(f"cannot write {where!r}: permission denied or a read-only "
                                 f"file system: write elsewhere {kept}")
        if "resource temporarily unavailable" in lower:  # EAGAIN: threads refused
            return BadInputError(f"cannot write {where!r}: ffmpeg could not start its "
                                 f"threads (resource temporarily unavailable): the limit on "
                                 f"processes and threads (ulimit -u, a container's pids "
                                 f"limit) is reached; raise it or run fewer jobs {kept}")
        lines = [line.strip() for line in text.splitlines() if line.strip()]
        if lines:
            detail = lines[-1]
        elif code < 0:
            detail = f"stopped by signal {signal.Signals(-code).name}"
        else:
            detail = "no message"
        if code == 0:  # it exited as if all went well
            told = "an unknown number" if encoded is None else str(encoded)
            return RuntimeError(f"ffmpeg encoded {told} of the {self.sent} "
                                f"frames of {where!r}: {detail}")
        return RuntimeError(f"ffmpeg could not write {where!r} (exit status {code}): "
                            f"{detail}")


def write_video(
    frames: Iterable[np.ndarray], path: str | os.PathLike[str], fps: float = 30.0, **kwargs
) -> int:
    """Write every frame of an iterable (consumed lazily) and return how many there were.

    Args:
        frames: ``(H, W, 3)`` frames; a generator keeps memory flat.
        path: Output name (``.mp4``, ``.gif`` or a folder).
        fps: Frames per second.
        **kwargs: Passed to :class:`VideoWriter`.
    """
    with VideoWriter(path, fps, **kwargs) as out:
        for frame in frames:
            out.write(frame)
    return out.count

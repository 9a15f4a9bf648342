"""Drive a head with an ARKit-52 stream: a video, a mesh sequence, or both.

Per frame only the mesh changes (``HeadRenderer.frames`` recomputes the mesh, its
hex-planes and the volume render; the neural texture and the hair planes are made once).
With a still camera, frames also reuse the previous frame's work where the expression
left it unchanged (:class:`~head360cli.model.reuse.DecodeReuse`). On a CPU, long takes are
rendered by one process per core (:mod:`head360cli.drive.parallel`).
The stream's head rotation, when asked for, moves the camera instead of the head: the same
image on a white background, and the hair planes stay valid. Frames go to the encoder as
they are made, so memory does not grow with the length of the take.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from head360cli.errors import BadInputError
from head360cli.io.video import GIF_MAX_FPS, MAX_FPS, MIN_FPS, check_gif_rate

__all__ = ["HEAD_PIVOT", "AnimateConfig", "animate", "head_motion", "head_pose_cameras",
           "prepare_stream"]

HEAD_PIVOT = (0.0, -0.10, -0.02)
"""Head coordinates (metres) of the point the head turns about with ``--head-pose``: the
top of the neck."""


@dataclasses.dataclass
class AnimateConfig:
    """How to turn a stream into frames."""

    fps: float | None = None
    """Output frame rate; ``None`` keeps the stream's own (its frames are still put on a
    uniform time grid, so dropped frames do not shorten the video)."""
    start: float | None = None
    """Seconds into the stream to start at (``None``: its beginning)."""
    end: float | None = None
    """Seconds into the stream to stop before (``None``: its end)."""
    smooth: float = 0.0
    """Gaussian smoothing of the weights (and head rotation), sigma in seconds; 0: none."""
    head_pose: bool = False
    """Apply the stream's head yaw, pitch and roll."""
    yaw: float = 0.0
    """Camera yaw in degrees (0: the canonical frontal view)."""
    pitch: float = 0.0
    """Camera pitch in degrees."""
    batch: int | None = None
    """Frames rendered per generator call (``None``: the renderer's choice, one on CPU,
    where decoded points are then reused from frame to frame, 32 on a GPU); more than
    one renders in this process alone (no worker processes)."""
    hair: bool = True
    """Render the hair (False: the bald head)."""
    workers: int | None = None
    """Processes that render frames on a CPU (``None``: one per usable core, at most 4,
    when there are enough frames: :func:`~head360cli.drive.parallel.auto_workers`);
    1 renders in this process alone."""

    def __post_init__(self) -> None:
        """Refuse values no take can be rendered with (the CLI's options are checked with
        their own names first; these guard library callers).

        Raises:
            BadInputError: The first field out of range, expected against found.
        """
        from head360cli.drive.views import check_angles

        def finite(x) -> bool:
            return isinstance(x, int | float | np.number) and math.isfinite(x)

        if self.fps is not None and not (finite(self.fps) and MIN_FPS <= self.fps <= MAX_FPS):
            raise BadInputError(f"expected fps from {MIN_FPS:g} to {MAX_FPS:g} or None, found "
                                f"{self.fps!r}")
        for name in ("start", "end"):
            value = getattr(self, name)
            if value is not None and not (finite(value) and value >= 0):
                raise BadInputError(f"expected {name} >= 0 seconds or None, found {value!r}")
        if not (finite(self.smooth) and self.smooth >= 0):
            raise BadInputError(f"expected smooth >= 0 seconds, found {self.smooth!r}")
        check_angles(self.yaw, self.pitch)
        for name in ("batch", "workers"):
            value = getattr(self, name)
            if value is not None and not (isinstance(value, int | np.integer) and value >= 1):
                raise BadInputError(f"expected {name} >= 1 or None, found {value!r}")


def head_motion(rotation: np.ndarray, pivot=HEAD_PIVOT) -> np.ndarray:
    """``(F, 4, 4)`` rigid motions of the head for ``rotation (F, 3)``: yaw, pitch, roll
    in radians (ARKit order; yaw turns the face towards the head's left, pitch tips it
    down, roll tilts it towards its left shoulder), about ``pivot``."""
    r = np.asarray(rotation, np.float64)
    cy, sy = np.cos(r[:, 0]), np.sin(r[:, 0])
    cp, sp = np.cos(r[:, 1]), np.sin(r[:, 1])
    cr, sr = np.cos(r[:, 2]), np.sin(r[:, 2])
    one, zero = np.ones_like(cy), np.zeros_like(cy)
    ry = np.stack([cy, zero, sy, zero, one, zero, -sy, zero, cy], -1).reshape(-1, 3, 3)
    # Pitching down turns the face (+z) towards -y: a rotation about +x by +pitch.
    rx = np.stack([one, zero, zero, zero, cp, -sp, zero, sp, cp], -1).reshape(-1, 3, 3)
    # Rolling towards the left shoulder turns the head's up (+y) towards +x.
    rz = np.stack([cr, sr, zero, -sr, cr, zero, zero, zero, one], -1).reshape(-1, 3, 3)
    rot = ry @ rx @ rz
    motion = np.tile(np.eye(4), (len(r), 1, 1))
    p = np.asarray(pivot, np.float64)
    motion[:, :3, :3] = rot
    motion[:, :3, 3] = p - rot @ p
    return motion


def head_pose_cameras(rotation: np.ndarray, c2w, pivot=HEAD_PIVOT):
    """Cameras that see a fixed head as a still camera ``c2w (4, 4)`` sees the head
    turned by ``rotation (F, 3)`` (see :func:`head_motion`).

    Returns:
        ``(F, 4, 4)`` camera-to-world matrices: ``inverse(head motion) @ c2w``.
    """
    import torch

    inverse = np.linalg.inv(head_motion(rotation, pivot))
    base = np.asarray(c2w.detach().cpu() if hasattr(c2w, "detach") else c2w, np.float64)
    return torch.tensor(inverse @ base, dtype=torch.float32)


MAX_FRAMES = 2_000_000
"""The most frames one take may become (9 hours at 60 fps): resampling a stream whose
times are far apart (a typo, seconds for milliseconds) would otherwise fill memory."""


def prepare_stream(stream, cfg: AnimateConfig):
    """The stream cut to ``start``/``end``, smoothed and put on a uniform time grid."""
    from head360cli.io.arkit import resample, smooth

    if cfg.start is not None or cfg.end is not None:
        if cfg.start is not None and cfg.end is not None and cfg.end <= cfg.start:
            raise BadInputError(f"expected --end after --start, found start {cfg.start} s "
                                f"and end {cfg.end} s")
        stream = stream.between(cfg.start, cfg.end)
    if cfg.smooth > 0:
        stream = smooth(stream, cfg.smooth)
    fps = cfg.fps if cfg.fps is not None else stream.fps
    if not MIN_FPS <= fps <= MAX_FPS:  # only the stream's own rate can be out here
        raise BadInputError(
            f"expected a stream of {MIN_FPS:g} to {MAX_FPS:g} frames per second, found "
            f"{fps:.4g} (frames {1 / fps:.4g} s apart"
            + ("; a time column in milliseconds is named time_ms" if fps < MIN_FPS else "")
            + "): give --fps to resample it")
    if cfg.head_pose and stream.head_rotation is None:
        raise BadInputError("expected head rotation columns (HeadYaw, HeadPitch, HeadRoll) "
                            "for --head-pose, found none in the stream")
    span = float(stream.timestamps[-1] - stream.timestamps[0])
    if span * fps + 1 > MAX_FRAMES:
        raise BadInputError(f"expected a take of at most {MAX_FRAMES} frames, found "
                            f"{span * fps + 1:.4g} ({span:.4g} s at {fps:g} fps): cut it "
                            "with --start/--end")
    return stream if stream.num_frames < 2 else resample(stream, fps)


def animate(renderer, stream, out: str | Path | None, cfg: AnimateConfig | None = None,
            mesh_dir: str | Path | None = None, progress: Any = None) -> dict[str, Any]:
    """Render a head driven by an ARKit stream.

    Args:
        renderer: The head, or a function of no arguments that loads it: on a CPU,
            the processes that will render a long take's frames (see
            :class:`AnimateConfig` ``workers``) are then started before it is called,
            so that their start (seconds each: they import torch) overlaps the loading.
        stream: An :class:`~head360cli.io.arkit.ArkitStream`.
        out: Video path (mp4, gif, or a folder for PNG frames), or ``None`` for no video.
        cfg: Options.
        mesh_dir: Also write one OBJ per frame (plus the texture) into this new folder.
        progress: ``progress(stage, done, total)`` callback.

    Returns:
        A summary: frames, duration, fps, render seconds and frames per second, the share
        of points decoded when frames reused the previous ones (``decoded_share``), the
        GPU memory peak on a GPU (``gpu_peak_mib``), paths.
    """
    from head360cli.drive.parallel import Workers, auto_workers

    cfg = cfg or AnimateConfig()
    if out is None and mesh_dir is None:
        raise BadInputError("expected a video output or a mesh folder, found neither")
    _check_outputs(out, mesh_dir)
    notes = []
    gif_fps = None if out is None or cfg.fps is not None else _gif_rate(out, stream.fps)
    if gif_fps is not None:
        cfg = dataclasses.replace(cfg, fps=gif_fps)
        notes.append(f"a GIF plays at most {GIF_MAX_FPS:g} frames per second: the "
                     f"{stream.fps:g} fps take is resampled to {cfg.fps:g} (give --fps, or "
                     f"write an .mp4 for every frame)")
    if out is not None and cfg.fps is not None:
        check_gif_rate(out, cfg.fps)  # before any work
    stream = prepare_stream(stream, cfg)
    # processes for the frames on a CPU (one-frame batches only)
    workers = (cfg.workers or auto_workers(stream.num_frames, "cpu")
               if out is not None and cfg.batch in (None, 1) else 1)
    loader = not hasattr(renderer, "frames")
    pool = Workers(workers) if loader and workers > 1 else None  # before the loading
    try:
        if loader:
            renderer = renderer()
        result = _animate(renderer, stream, out, cfg, mesh_dir, progress, workers, pool)
    finally:
        if pool is not None:
            pool.close()
    if notes:
        result["warnings"] = notes + result.get("warnings", [])
    return result


def _gif_rate(out: str | Path, fps: float) -> float | None:
    """For a GIF output of a take at ``fps`` above :data:`GIF_MAX_FPS`, the rate to
    resample it to (the take's divided by the smallest whole number that brings it to
    the limit or under: 60 -> 30, 120 -> 40); otherwise ``None``."""
    from head360cli.io.video import output_kind

    if output_kind(out) != "gif" or fps <= GIF_MAX_FPS:
        return None
    return fps / math.ceil(fps / GIF_MAX_FPS - 1e-9)


def _check_outputs(out: str | Path | None, mesh_dir: str | Path | None) -> None:
    """Refuse outputs that cannot be written before any work (loading the head, baking
    its texture): see :func:`~head360cli.io.video.check_video_target`."""
    from head360cli.io.atomic import check_dir_target
    from head360cli.io.video import check_video_target

    if out is not None:
        check_video_target(out)
    if mesh_dir is not None:
        check_dir_target(Path(mesh_dir), overwrite=False)


def _animate(renderer, stream, out, cfg: AnimateConfig, mesh_dir, progress, workers: int,
             pool) -> dict[str, Any]:
    """:func:`animate` once the head is loaded and the stream prepared: ``workers``
    processes render the frames if the renderer is torch's on a CPU (``pool``: those
    started already, or ``None``)."""
    from head360cli.devices import gpu_peak_mib
    from head360cli.drive.views import head_framing, view_cameras, view_intrinsics
    from head360cli.io.video import VideoWriter

    n = stream.num_frames
    base = view_cameras(cfg.yaw, cfg.pitch, head_framing(renderer, cfg.hair))[0]
    cams = (head_pose_cameras(stream.head_rotation, base) if cfg.head_pose
            else base[None].expand(n, 4, 4))
    result: dict[str, Any] = {"frames": n, "fps": float(stream.fps),
                              "duration_s": n / float(stream.fps), "files": {}}
    if mesh_dir is not None:
        from head360cli.drive.bake import write_mesh_sequence

        t0 = time.perf_counter()
        motions = head_motion(stream.head_rotation) if cfg.head_pose else None
        result["files"]["mesh_sequence"] = str(write_mesh_sequence(
            renderer, stream.weights, mesh_dir, motions=motions, hair=cfg.hair,
            progress=progress))
        result["mesh_seconds"] = time.perf_counter() - t0
    if out is not None:
        from head360cli.drive.parallel import parallel_frames

        t0 = time.perf_counter()
        k = view_intrinsics(renderer.size)
        if getattr(renderer, "runner", None) is not None or renderer.device.type != "cpu":
            workers = 1  # onnxruntime or a GPU: this process batches frames
            if pool is not None:
                pool.close()
                pool = None
        counts: dict[str, Any] = {}
        frames = parallel_frames(renderer, cams, stream.weights, k, hair=cfg.hair,
                                 workers=workers, batch=cfg.batch, counts=counts,
                                 pool=pool)
        with VideoWriter(out, fps=stream.fps) as video:
            for done, frame in enumerate(frames, 1):
                video.write(frame)
                if progress:
                    progress("animate", done, n)
        seconds = time.perf_counter() - t0
        result.update(render_seconds=seconds, render_fps=n / seconds,
                      workers=counts["workers"])
        if counts.get("warnings"):
            result["warnings"] = counts["warnings"]
        if counts.get("peaks"):  # the rendering processes' own peak memory, summed
            result["worker_peak_rss_mib"] = round(sum(counts["peaks"].values()), 1)
        if counts.get("points"):  # the share of points decoded afresh
            result["decoded_share"] = round(counts["decoded"] / counts["points"], 4)
        device = getattr(renderer, "device", None)
        peak = None if device is None else gpu_peak_mib(device)
        if peak is not None:  # the command's peak on the GPU: loading and frames
            result["gpu_peak_mib"] = peak
        result["files"]["video"] = str(out)
    return result


VIDEO_CHUNK = 32
"""Frames tracked before they are rendered, in :func:`animate_video` (memory holds at most
this many input frames, whatever the clip's length)."""


def animate_video(renderer, video, out: str | Path, cfg: AnimateConfig | None = None,
                  track=None, side_by_side: bool = False, progress: Any = None
                  ) -> dict[str, Any]:
    """Track the face through a video and drive the head with it, in one streaming pass:
    frames are read, tracked, rendered (in this process) and written
    :data:`VIDEO_CHUNK` at a time, so that memory does not grow with the clip.

    Args:
        renderer: A :class:`~head360cli.model.head_render.HeadRenderer`.
        video: A video file, a folder of frames or ``-`` (see
            :func:`head360cli.io.frames.open_frames`).
        out: The video to write (mp4, gif, or a folder for PNG frames).
        cfg: Camera, hair and head pose (``fps``, ``start``, ``end``, ``smooth`` and
            ``workers`` are not used: the video's own rate, ``track``'s cut and filter).
        track: A :class:`~head360cli.perception.track.TrackConfig` (its cut, filter, face
            and policy for frames without a face: held frames before the first face show
            the head at rest; skipped ones are left out of the video).
        side_by_side: Put each input frame, scaled to the render's height, left of the
            head.
        progress: ``progress(stage, done, total)`` callback.

    Returns:
        A summary: frames, fps, the tracker's counts, seconds, frames per second.
    """
    from head360cli.drive.views import head_framing, view_cameras, view_intrinsics
    from head360cli.io.frames import open_frames
    from head360cli.io.video import VideoWriter, check_video_target
    from head360cli.perception.track import TrackConfig, track_frames

    cfg = cfg or AnimateConfig()
    track = track or TrackConfig()
    check_video_target(out)
    t0 = time.perf_counter()
    base = view_cameras(cfg.yaw, cfg.pitch, head_framing(renderer, cfg.hair))[0]
    k = view_intrinsics(renderer.size)
    counts: dict[str, Any] = {}
    written = 0
    with open_frames(video, track.fps) as frames:
        total = frames.count
        # (weights, head rotation, the input frame beside or None); weights None: a
        # skipped frame, written blank so that the video keeps the input's timing
        chunk: list[tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]] = []
        blank = np.full((renderer.size, renderer.size, 3), 255, np.uint8)
        with VideoWriter(out, fps=frames.fps) as writer:

            def flush() -> None:
                nonlocal written
                if not chunk:
                    return
                drawn = [c for c in chunk if c[0] is not None]
                rendered = iter(())
                if drawn:
                    weights = np.stack([c[0] for c in drawn])
                    rot = np.stack([c[1] for c in drawn])
                    cams = (head_pose_cameras(rot, base) if cfg.head_pose
                            else base[None].expand(len(drawn), 4, 4))
                    rendered = (f for batch in renderer.frames(cams, weights, k,
                                                               hair=cfg.hair)
                                for f in batch)
                for w, _, rgb in chunk:
                    frame = blank if w is None else next(rendered)
                    writer.write(frame if rgb is None else _beside(rgb, frame))
                    written += 1
                    if progress:
                        progress("animate", written, total or written)
                chunk.clear()

            for _, _, rgb, reading in track_frames(frames, track, None, counts):
                if reading is None and track.on_bad == "skip":
                    chunk.append((None, None, rgb if side_by_side else None))
                    if len(chunk) == VIDEO_CHUNK:
                        flush()
                    continue
                w = np.zeros(52, np.float32) if reading is None else reading.weights
                r = np.zeros(3, np.float32) if reading is None else reading.head
                chunk.append((w, r, rgb if side_by_side else None))
                if len(chunk) == VIDEO_CHUNK:
                    flush()
            flush()
            if counts["with_face"] == 0:  # a clip of the head at rest: not written
                from head360cli.errors import NoFaceError
                from head360cli.perception.track import no_face_message

                raise NoFaceError(no_face_message(track.face, {"decoded": 0, **counts},
                                                  frames.name))
        fps = frames.fps
    seconds = time.perf_counter() - t0
    result = {"frames": written, "fps": float(fps), "duration_s": written / float(fps),
              "frames_decoded": counts["decoded"], "frames_with_face": counts["with_face"],
              "frames_held": counts["held"], "frames_skipped": counts["skipped"],
              "seconds": seconds, "render_fps": written / max(seconds, 1e-9),
              "files": {"video": str(out)}}
    if counts["held"] or counts["skipped"]:
        verb = "held" if track.on_bad == "hold" else "skipped"
        result["warnings"] = [f"no face in {counts['held'] + counts['skipped']} of "
                              f"{counts['decoded']} frames ({verb})"]
    return result


def _beside(photo: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """The input frame scaled to the render's height (an even width) left of it."""
    import cv2

    h = frame.shape[0]
    w = max(2, round(photo.shape[1] * h / photo.shape[0] / 2) * 2)
    small = cv2.resize(photo, (w, h), interpolation=cv2.INTER_AREA)
    return np.concatenate([small, frame[..., :3]], axis=1)

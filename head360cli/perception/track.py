"""Tracking a face through frames: the 52 ARKit blendshape scores, the head's rotation and
the eyes' turns, frame after frame.

The face mesh (:mod:`head360cli.perception.mesh478`) reads each frame in one pass, cropped
about the previous frame's points as MediaPipe's tracker does; the detectors look for the
face again only when the mesh loses it (presence below :data:`TRACK_MIN_PRESENCE`). The
head's rotation is the best rotation of MediaPipe's canonical face onto the mesh's points;
the eyes' turns come from the eyeLook scores. A One Euro filter (Casiez et al., CHI 2012)
smooths the signals causally, so that a stream can be filtered as it is read.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

__all__ = ["EYE_PITCH_PER_SCORE", "EYE_YAW_PER_SCORE", "TRACK_MIN_PRESENCE", "FaceTracker",
           "OneEuroFilter", "TrackConfig", "TrackedFace", "eye_rotation", "head_rotation",
           "track_frames", "track_video"]

TRACK_MIN_PRESENCE = 0.5
"""Face presence below which the tracker counts the face as lost and detects again."""
EYE_YAW_PER_SCORE = 0.61
"""Radians of eye yaw per unit of eyeLookOut minus eyeLookIn, and
:data:`EYE_PITCH_PER_SCORE` of pitch per unit of eyeLookDown minus eyeLookUp: the
least-squares slopes between the scores and the eye rotations of the Live Link Face take
``livelinkface_happy.csv`` (correlations 0.96 and 0.996; its eyes turn mostly up and down)."""
EYE_PITCH_PER_SCORE = 0.526


@dataclasses.dataclass
class TrackedFace:
    """One frame's reading."""

    weights: np.ndarray
    """``(52,)`` ARKit blendshape scores in [0, 1] (head360's ARKit order)."""
    head: np.ndarray
    """``(3,)`` head yaw, pitch, roll in radians (ARKit's convention, see
    :func:`head360cli.drive.animate.head_motion`)."""
    eyes: np.ndarray
    """``(6,)`` left then right eye yaw, pitch, roll in radians."""
    presence: float
    """The face mesh's confidence that it holds a face."""
    points: np.ndarray
    """``(478, 3)`` the mesh's points in frame pixels."""
    detected: bool
    """Whether the detectors found the face in this frame (else it was tracked)."""


@functools.lru_cache(maxsize=1)
def _canonical() -> np.ndarray:
    """MediaPipe's canonical face, ``(468, 3)`` centimetres, x to the face's left, y up,
    z out of the face, centred."""
    from head360cli.paths import models_dir

    with open(models_dir() / "canonical_face_model.obj", encoding="utf-8") as fh:
        v = np.array([line.split()[1:4] for line in fh if line.startswith("v ")], float)
    return v - v.mean(0)


def head_rotation(points: np.ndarray) -> np.ndarray:
    """Head yaw, pitch and roll in radians, ``(3,)``, from the mesh's ``(478, 3)`` points:
    the rotation that best turns the canonical face onto them (orthographic, with scale).

    Yaw > 0 turns the face towards the head's left, pitch > 0 tips it down, roll > 0
    tilts it towards its left shoulder, as :func:`head360cli.drive.animate.head_motion`
    reads them."""
    seen = points[:468].astype(np.float64) * np.array([1.0, -1.0, -1.0])  # to x left, y up
    c = _canonical()
    a, b = c, seen - seen.mean(0)
    u, _, vt = np.linalg.svd(b.T @ a)
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    r = u @ d @ vt  # seen ~ s r canonical; r = Ry(yaw) Rx(pitch) Rz(roll)
    yaw = np.arctan2(r[0, 2], r[2, 2])
    pitch = np.arcsin(np.clip(-r[1, 2], -1.0, 1.0))
    roll = np.arctan2(-r[1, 0], r[1, 1])
    return np.array([yaw, pitch, roll], np.float32)


def eye_rotation(weights: np.ndarray) -> np.ndarray:
    """Left then right eye yaw, pitch, roll in radians, ``(6,)``, from the eyeLook scores
    of ``weights (52,)`` (see :data:`EYE_YAW_PER_SCORE`); roll is 0."""
    from head360cli.mesh.arkit52 import INDEX

    def w(name: str) -> float:
        return float(weights[INDEX[name]])

    out = np.zeros(6, np.float32)
    for k, side, sign in ((0, "Left", -1.0), (3, "Right", 1.0)):
        out[k] = sign * EYE_YAW_PER_SCORE * (w(f"eyeLookOut{side}") - w(f"eyeLookIn{side}"))
        out[k + 1] = EYE_PITCH_PER_SCORE * (w(f"eyeLookDown{side}") - w(f"eyeLookUp{side}"))
    return out


class FaceTracker:
    """Reads one face frame after frame (call it with each ``(H, W, 3)`` uint8 RGB frame).

    Args:
        face: Which face to follow when the detectors find several: 0 the largest, 1
            the next, ...
        threads: LiteRT threads (default: the process's budget, at most 2).
    """

    def __init__(self, face: int = 0, threads: int | None = None) -> None:
        self.face, self.threads = face, threads
        self._mesh = None
        self.most_faces = 0
        """The most faces a detector found in one frame so far (for the message when
        ``face`` asks for more)."""

    def reset(self) -> None:
        """Forget the face (the next frame is searched whole)."""
        self._mesh = None

    def __call__(self, rgb: np.ndarray) -> TrackedFace | None:
        """The face in this frame, or ``None`` when none is found."""
        from head360cli.perception.mesh478 import blendshape_scores, follow

        mesh, detected = None, False
        if self._mesh is not None:
            mesh = follow(rgb, self._mesh, self.threads)
            if mesh.presence < TRACK_MIN_PRESENCE:
                mesh = None
        if mesh is None:
            mesh, detected = self._detect(rgb), True
        self._mesh = mesh
        if mesh is None:
            return None
        weights = blendshape_scores(mesh.points, self.threads)
        return TrackedFace(weights, head_rotation(mesh.points), eye_rotation(weights),
                           mesh.presence, mesh.points, detected)

    def _detect(self, rgb: np.ndarray):
        from head360cli.perception.faces import detect_blazeface, detect_yunet
        from head360cli.perception.mesh478 import face_mesh

        for detect in (detect_blazeface, detect_yunet):
            boxes = sorted(detect(rgb), key=lambda b: -b.area)
            self.most_faces = max(self.most_faces, len(boxes))
            if len(boxes) > self.face:
                b = boxes[self.face]
                mesh = face_mesh(rgb, b.box, b.keypoints[:2], 2, self.threads)
                if mesh.presence >= TRACK_MIN_PRESENCE:
                    return mesh
        return None


class OneEuroFilter:
    """A causal One Euro filter over ``(C,)`` signals: a low-pass whose cutoff rises with
    the signal's speed, so that slow changes are steadied and fast ones (a blink) pass.

    Args:
        min_cutoff: Cutoff in Hz when the signal is still (lower: smoother).
        beta: How much the cutoff rises per unit of speed (higher: less lag).
        d_cutoff: Cutoff in Hz of the speed's own low-pass.
    """

    def __init__(self, min_cutoff: float = 1.5, beta: float = 2.0, d_cutoff: float = 1.0
                 ) -> None:
        self.min_cutoff, self.beta, self.d_cutoff = min_cutoff, beta, d_cutoff
        self._x: np.ndarray | None = None
        self._dx: np.ndarray | None = None
        self._t: float | None = None

    @staticmethod
    def _alpha(cutoff: np.ndarray | float, dt: float) -> np.ndarray:
        tau = 1.0 / (2.0 * np.pi * np.asarray(cutoff))
        return 1.0 / (1.0 + tau / dt)

    def __call__(self, t: float, x: np.ndarray) -> np.ndarray:
        """The filtered value of ``x (C,)`` at time ``t`` seconds (increasing)."""
        x = np.asarray(x, np.float64)
        if self._x is None or self._t is None or t <= self._t:
            self._x, self._dx, self._t = x.copy(), np.zeros_like(x), t
            return x.copy()
        dt = t - self._t
        dx = (x - self._x) / dt
        self._dx = self._dx + self._alpha(self.d_cutoff, dt) * (dx - self._dx)
        cutoff = self.min_cutoff + self.beta * np.abs(self._dx)
        self._x = self._x + self._alpha(cutoff, dt) * (x - self._x)
        self._t = t
        return self._x.copy()


@dataclasses.dataclass(frozen=True)
class TrackConfig:
    """What :func:`track_video` does."""

    face: int = 0
    """Which face to follow when several show (0: the largest)."""
    start: float | None = None
    """Seconds into the input where tracking starts (``None``: the first frame)."""
    end: float | None = None
    """Seconds into the input where it stops (``None``: the last frame)."""
    stills: bool = False
    """Treat every frame as unrelated to the one before (a folder of photos): each is
    searched whole and none is smoothed with another. Without it, cuts are found by
    :func:`is_cut`."""
    smooth: float = 1.5
    """The One Euro filter's cutoff in Hz when still (:class:`OneEuroFilter`); 0 turns the
    filter off."""
    beta: float = 2.0
    """The One Euro filter's speed coefficient."""
    on_bad: str = "hold"
    """A frame without a face: ``hold`` the last reading, ``skip`` the frame, or
    ``error`` (stop)."""
    fps: float | None = None
    """Frame rate of a folder of frames, or in place of a video's own."""

    def __post_init__(self) -> None:
        """Refuse settings no run can track with.

        Raises:
            BadInputError: The first field out of range, expected against found.
        """
        from head360cli.errors import BadInputError

        checks = [
            (self.face >= 0, f"--face >= 0, found {self.face}"),
            (np.isfinite(self.smooth) and self.smooth >= 0, f"--smooth >= 0 Hz (0: off), "
                                                            f"found {self.smooth}"),
            (np.isfinite(self.beta) and self.beta >= 0, f"a filter beta >= 0, found "
                                                        f"{self.beta}"),
            (self.on_bad in ("hold", "skip", "error"), f"--on-bad hold, skip or error, "
                                                       f"found {self.on_bad!r}"),
            (self.start is None or self.start >= 0, f"--start >= 0, found {self.start}"),
            (self.start is None or self.end is None or self.end > self.start,
             f"--end after --start, found start {self.start} and end {self.end}"),
        ]
        for ok, message in checks:
            if not ok:
                raise BadInputError(f"expected {message}")


def track_frames(source, cfg: TrackConfig, progress=None, frames=None):
    """Track the face through ``source`` (a :class:`head360cli.io.frames.FrameSource`),
    yielding ``(index, seconds, rgb, reading)`` frame by frame; ``reading`` is a
    :class:`TrackedFace` (after the filter, held under ``hold``) or ``None`` for a frame
    to skip. Counts go to ``frames`` (a dict), when given: ``decoded``, ``with_face``,
    ``held``, ``skipped``, ``detections``.

    Raises:
        NoFaceError: ``on_bad="error"`` and a frame without a face.
    """
    import time

    from head360cli.errors import NoFaceError

    counts = frames if frames is not None else {}
    counts.update(decoded=0, with_face=0, held=0, skipped=0, detections=0, seconds=0.0,
                  cuts=0)
    tracker = FaceTracker(cfg.face)
    filt = OneEuroFilter(cfg.smooth, cfg.beta) if cfg.smooth > 0 else None
    last: TrackedFace | None = None
    total = source.count
    seen = None  # the last frame's thumbnail
    for index, t, rgb in source.frames(cfg.start, cfg.end):
        t0 = time.perf_counter()
        small = thumbnail(rgb)
        if (cfg.stills and counts["decoded"]) or is_cut(seen, small):
            # a new shot: nothing of the last one carries over
            counts["cuts"] += 1
            tracker.reset()
            if filt is not None:
                filt = OneEuroFilter(cfg.smooth, cfg.beta)
            last = None
        seen = small
        reading = tracker(rgb)
        counts["seconds"] += time.perf_counter() - t0
        counts["decoded"] += 1
        counts["most_faces"] = tracker.most_faces
        if reading is not None:
            counts["with_face"] += 1
            counts["detections"] += int(reading.detected)
            if last is not None and face_jumped(last.points, reading.points):
                counts["cuts"] += 1  # another face, or the same one in another shot
                if filt is not None:
                    filt = OneEuroFilter(cfg.smooth, cfg.beta)
            if filt is not None:
                sig = filt(t, np.concatenate([reading.weights, reading.head, reading.eyes]))
                reading = dataclasses.replace(
                    reading, weights=np.clip(sig[:52], 0, 1).astype(np.float32),
                    head=sig[52:55].astype(np.float32), eyes=sig[55:61].astype(np.float32))
            last = reading
        elif cfg.on_bad == "error":
            raise NoFaceError(f"expected a face in every frame (--on-bad error), found none "
                              f"in frame {index} ({t:.3f} s) of {source.name}")
        elif cfg.on_bad == "skip" or last is None:  # hold, before the first face: None
            counts["skipped" if cfg.on_bad == "skip" else "held"] += 1
            yield index, t, rgb, None
            if progress:
                progress(counts["decoded"], total)
            continue
        else:
            counts["held"] += 1
        yield index, t, rgb, last
        if progress:
            progress(counts["decoded"], total)


CUT_DIFFERENCE = 0.12
"""Mean absolute difference (0 to 1) of two consecutive frames' 32 x 24 grey thumbnails
from which the second starts a new shot: the tracker searches it whole and the filter
starts again, so that unrelated photos or a cut in a video are not smoothed together.
A moving head in one shot stays far below it (the tests' moving astronaut: under 0.05)."""


def thumbnail(rgb: np.ndarray) -> np.ndarray:
    """``(24, 32)`` float32 grey in [0, 1]: what :func:`is_cut` compares."""
    import cv2

    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    return cv2.resize(grey, (32, 24), interpolation=cv2.INTER_AREA).astype(np.float32) / 255


def is_cut(before: np.ndarray | None, now: np.ndarray) -> bool:
    """Whether thumbnail ``now`` starts a new shot after ``before`` (:data:`CUT_DIFFERENCE`;
    the first frame is not a cut)."""
    return before is not None and float(np.abs(now - before).mean()) > CUT_DIFFERENCE


FACE_JUMP = 0.4
"""Share of the face's size by which its centre may move between two frames of one shot;
a larger move, or a size that changes by more than a factor of 1.4, starts a new shot."""


def face_jumped(before: np.ndarray, now: np.ndarray) -> bool:
    """Whether the face mesh's points ``now (478, 3)`` are too far from ``before`` for one
    shot (:data:`FACE_JUMP`): a cut to another face or another framing."""
    def frame(p: np.ndarray) -> tuple[np.ndarray, float]:
        lo, hi = p[:, :2].min(0), p[:, :2].max(0)
        return (lo + hi) / 2, float(max(hi - lo))

    (c0, s0), (c1, s1) = frame(before), frame(now)
    ratio = s1 / max(s0, 1e-6)
    return bool(np.linalg.norm(c1 - c0) > FACE_JUMP * s0 or not 1 / 1.4 <= ratio <= 1.4)


def no_face_message(face: int, counts: dict, name: str) -> str:
    """What to say when no frame of ``name`` gave face number ``face`` (``counts`` of
    :func:`track_frames`): that none was found, or, for ``--face N``, how many were."""
    most = counts.get("most_faces", 0)
    if face > 0 and most:
        return (f"expected face {face} (--face counts from 0, the largest), found at most "
                f"{most} face{'s' if most > 1 else ''} in a frame of the "
                f"{counts['decoded']} frames of {name}")
    return f"expected a face in some frame, found none in the {counts['decoded']} frames " \
           f"of {name}"


def track_video(source, cfg: TrackConfig | None = None, progress=None):
    """Track a face through a video, a folder of frames or ``-``, into an ARKit stream.

    Args:
        source: Path, folder or ``-`` (see :func:`head360cli.io.frames.open_frames`).
        cfg: Options.
        progress: ``progress(done, total or None)`` after each frame.

    Returns:
        ``(stream, summary)``: an :class:`head360cli.io.arkit.ArkitStream` with head and
        eye rotations at the input's frame rate (frames before the first face take its
        reading under ``hold``), and counts, frames per second and warnings.

    Raises:
        NoFaceError: No face in any frame, or (``on_bad="error"``) in one of them.
        BadInputError, FileFormatError: An input that does not read.
    """
    import time

    from head360cli.errors import BadInputError, NoFaceError
    from head360cli.io.arkit import ArkitStream
    from head360cli.io.frames import open_frames

    cfg = cfg or TrackConfig()
    t0 = time.perf_counter()
    counts: dict = {}
    times: list[float] = []
    rows: list[np.ndarray | None] = []  # weights, head, eyes (61,); None: no face yet
    with open_frames(source, cfg.fps) as frames:
        for _, t, _, reading in track_frames(frames, cfg, progress, counts):
            if reading is None and cfg.on_bad == "skip":
                continue
            times.append(t)
            rows.append(None if reading is None else np.concatenate(
                [reading.weights, reading.head, reading.eyes]).astype(np.float32))
        name, fps, count, size = frames.name, frames.fps, frames.count, frames.size
        folder = frames.kind == "folder"
    if counts["decoded"] == 0:
        raise BadInputError(f"expected frames between --start and --end, found none in "
                            f"{name} ({count or 'an unknown number of'} frames at {fps:g} fps)")
    first = next((r for r in rows if r is not None), None)
    if first is None:
        raise NoFaceError(no_face_message(cfg.face, counts, name))
    warnings = []
    if folder and not cfg.stills and counts["decoded"] > 1:
        warnings.append("a folder of frames is tracked as one shot, each frame smoothed with "
                        "the ones before; give --stills for separate photos")
    if counts["held"] or counts["skipped"]:
        verb = "held the last reading" if cfg.on_bad == "hold" else "skipped"
        warnings.append(f"no face in {counts['held'] + counts['skipped']} of "
                        f"{counts['decoded']} frames ({verb})")
    if count and cfg.start is None and cfg.end is None and counts["decoded"] < count - 1:
        warnings.append(f"decoded {counts['decoded']} of the {count} frames {name} lists: "
                        "the file may be cut short")
    table = np.stack([first if r is None else r for r in rows])  # leading frames held
    stamps = np.asarray(times, np.float64)
    stream = ArkitStream(weights=table[:, :52].copy(), timestamps=stamps - stamps[0],
                         fps=float(fps), head_rotation=table[:, 52:55].copy(),
                         eye_rotation=table[:, 55:61].copy(), source_format="tracked",
                         nominal_fps=float(fps), warnings=warnings)
    seconds = time.perf_counter() - t0
    summary = {"input": name, "size": list(size), "fps": round(float(fps), 3),
               "frames": counts["decoded"], "frames_with_face": counts["with_face"],
               "frames_held": counts["held"], "frames_skipped": counts["skipped"],
               "detections": counts["detections"], "cuts": counts["cuts"],
               "rows": len(rows),
               "tracking_fps": round(counts["decoded"] / max(counts["seconds"], 1e-9), 1),
               "fps_all_in": round(counts["decoded"] / max(seconds, 1e-9), 1),
               "seconds": round(seconds, 2), "warnings": warnings}
    return stream, summary

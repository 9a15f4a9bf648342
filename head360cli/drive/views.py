"""Cameras by yaw and pitch, single views, view grids and turntables of a head.

Yaw 0 and pitch 0 is the canonical frontal camera (the rig's front camera, which is also the
input photo's view after fitting); positive yaw shows the head's left side, positive pitch
looks from above.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from head360cli.errors import BadInputError

__all__ = ["grid_image", "parse_expression", "parse_views", "photo_expression", "view_cameras",
           "view_intrinsics", "write_turntable"]


def view_cameras(yaw_deg, pitch_deg, framing: tuple[tuple[float, float, float], float]
                 | None = None):
    """``(B, 4, 4)`` cameras for yaws and pitches ``(B,)`` in degrees (scalars broadcast),
    looking at ``framing``'s target from its distance (:func:`head_framing`; default the
    rig's target and distance).

    Raises:
        BadInputError: A yaw that is not finite or a pitch past a pole (as
            :func:`check_angles`).
    """
    import torch

    from head360cli.geometry.cameras import RIG_DISTANCE, RIG_TARGET, camera_on_sphere

    target, distance = framing if framing is not None else (RIG_TARGET, RIG_DISTANCE)
    yaw = np.atleast_1d(np.asarray(yaw_deg, np.float32))
    pitch = np.atleast_1d(np.asarray(pitch_deg, np.float32))
    yaw, pitch = np.broadcast_arrays(yaw, pitch)
    check_angles(yaw, pitch)
    return camera_on_sphere(torch.from_numpy(yaw.copy()), torch.from_numpy(pitch.copy()),
                            float(distance), tuple(float(c) for c in target))


FRAME_MARGIN = 0.04
"""Share of the frame's half-height kept clear around a head that the rig's framing cuts
(:func:`head_framing`)."""


def head_framing(renderer, hair: bool = True) -> tuple[tuple[float, float, float], float]:
    """``(target, distance)`` of cameras that show the whole head, with its ``hair``, from
    any yaw at the rig's field of view: the rig's own target and distance where they do
    (most heads: their renders stay as they were), else a target halfway between the
    lowest and highest point and a distance at which every point stays inside the frame,
    with :data:`FRAME_MARGIN`, however the head turns. An afro's top and long hair's ends
    were cut off by the rig's frame.

    Args:
        renderer: A :class:`~head360cli.model.head_render.HeadRenderer`.
        hair: Whether its hair is shown.
    """
    import math

    from head360cli.geometry.cameras import RIG_DISTANCE, RIG_FOV_DEG, RIG_TARGET

    points = [renderer.vertices(np.zeros(52)).detach().cpu().numpy().reshape(-1, 3)]
    if hair and renderer.hair is not None:
        points.append(renderer.hair.meshes[0][0].detach().cpu().numpy().reshape(-1, 3))
    p = np.concatenate(points).astype(np.float64)
    p = p[np.isfinite(p).all(1)]
    tx, ty0, tz = RIG_TARGET
    rho = np.hypot(p[:, 0] - tx, p[:, 2] - tz)  # how far a point comes towards a camera
    slope = math.tan(math.radians(RIG_FOV_DEG) / 2)

    def needed(ty: float, margin: float) -> float:
        """The least distance at which every point fits the frame about height ``ty``."""
        room = slope * (1.0 - margin)
        return float(np.max(rho + np.maximum(np.abs(p[:, 1] - ty), rho) / room))

    if needed(ty0, 0.0) <= RIG_DISTANCE:
        return RIG_TARGET, RIG_DISTANCE
    ty = 0.5 * (float(p[:, 1].min()) + float(p[:, 1].max()))
    return (tx, ty, tz), max(RIG_DISTANCE, needed(ty, FRAME_MARGIN))


def view_intrinsics(size: int):
    """``(3, 3)`` intrinsics of the rig's lens for a ``size`` x ``size`` image.

    Raises:
        ValueError: ``size`` is below 1.
    """
    from head360cli.geometry.cameras import RIG_FOV_DEG, intrinsics_from_fov

    if not size >= 1:
        raise ValueError(f"expected an image size >= 1, found {size}")
    return intrinsics_from_fov(RIG_FOV_DEG, size, size)


def photo_expression(own: np.ndarray) -> np.ndarray:
    """The ARKit weights ``(52,)`` that render a fitted head with its photo's expression
    (``--expr photo``): its own weights, with the eyes' left at zero, because every frame
    already rests each eye at its own openness
    (:func:`~head360cli.io.headfile.driven_weights`)."""
    from head360cli.io.headfile import EYE_WEIGHTS
    from head360cli.mesh.arkit52 import INDEX

    w = np.array(own, np.float64, copy=True)
    for names in EYE_WEIGHTS.values():
        w[[INDEX[n] for n in names]] = 0.0
    return w


def parse_expression(text: str | None) -> np.ndarray:
    """ARKit weights ``(52,)`` from ``"JawOpen=0.8,EyeBlinkLeft=1"`` (any spelling the
    stream readers accept; unnamed shapes are 0).

    The halves some rigs split a shape into (``browInnerUp_L`` and ``_R``) are averaged,
    as the stream readers do.

    Raises:
        BadInputError: An unknown name, a missing ``=``, a weight outside [0, 1], or a
            shape given twice.
    """
    from head360cli.mesh.arkit52 import INDEX, canonical_name, split_part

    w = np.zeros(52)
    if not text:
        return w
    given: dict[str, list[tuple[str | None, float]]] = {}  # name -> (half or None, weight)
    for item in text.split(","):
        if not item.strip():
            continue
        name, sep, value = item.partition("=")
        if not sep:
            raise BadInputError(f"expected NAME=WEIGHT in --expr, found {item.strip()!r}")
        canonical = canonical_name(name.strip())
        if canonical is None:
            raise BadInputError(f"expected an ARKit blendshape name in --expr, found "
                                f"{name.strip()!r} (e.g. JawOpen, EyeBlinkLeft)")
        try:
            weight = float(value)
        except ValueError:
            raise BadInputError(f"expected a number for {canonical}, found {value!r}"
                                ) from None
        if not 0.0 <= weight <= 1.0:
            raise BadInputError(f"expected a weight in [0, 1] for {canonical}, found "
                                f"{weight}")
        half = split_part(name.strip())
        earlier = given.setdefault(canonical, [])
        if any(h is None or h == half for h, _ in earlier) or (half is None and earlier):
            raise BadInputError(f"expected each blendshape once in --expr, found {canonical}"
                                f"{'' if half is None else ' (' + half + ')'} twice")
        earlier.append((half, weight))
    for canonical, values in given.items():
        w[INDEX[canonical]] = sum(v for _, v in values) / len(values)
    return w


def check_angles(yaw, pitch, found: str | None = None) -> None:
    """Refuse a view (degrees) with a yaw that is not finite or a pitch past a pole, as
    ``render``, ``animate`` and ``--views`` take them; ``yaw`` and ``pitch`` are numbers
    or arrays of one shape (the first bad pair is named). ``found`` names it in the
    message (default: the two numbers).

    Raises:
        BadInputError: Either is out of range.
    """
    yaw, pitch = np.asarray(yaw, np.float64), np.asarray(pitch, np.float64)
    bad = ~(np.isfinite(yaw) & np.isfinite(pitch) & (np.abs(pitch) <= 90))
    if bad.any():
        i = np.unravel_index(int(np.argmax(bad)), bad.shape)
        raise BadInputError(f"expected a finite yaw and a pitch within +-90 degrees, found "
                            f"{found or f'{float(yaw[i])}, {float(pitch[i])}'}")


def parse_views(text: str) -> list[tuple[float, float]]:
    """Views from ``"0,45,90"`` (yaws at pitch 0) or ``"0:0,45:20,180:-10"`` (yaw:pitch),
    in degrees.

    Raises:
        BadInputError: Not numbers, or a pitch beyond +-90 degrees.
    """
    views = []
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        yaw, _, pitch = item.partition(":")
        try:
            v = (float(yaw), float(pitch) if pitch else 0.0)
        except ValueError:
            raise BadInputError(f"expected YAW or YAW:PITCH in degrees, found {item!r}"
                                ) from None
        check_angles(*v, found=repr(item))
        views.append(v)
    if not views:
        raise BadInputError(f"expected at least one view, found {text!r}")
    return views


GRID_COLUMNS = 6
"""Views per row of ``render --views``' grid."""
MAX_GRID_PIXELS = 100_000_000
"""The largest grid ``render --views`` makes (as the largest photo read): its views are
held in memory together, and a JPEG is at most 65535 pixels high."""


def check_grid_size(views: int, size: int) -> None:
    """Refuse a grid of ``views`` tiles of ``size`` pixels over :data:`MAX_GRID_PIXELS`
    or 65535 pixels high.

    Raises:
        BadInputError: The grid would be larger.
    """
    cols = min(views, GRID_COLUMNS)
    rows = -(-views // cols)
    tile = size + (0 if views == 1 else max(14, size // 12))  # the label's band under it
    pixels = rows * tile * cols * size
    if pixels > MAX_GRID_PIXELS or rows * tile > 65535:
        most = GRID_COLUMNS * min(MAX_GRID_PIXELS // (tile * GRID_COLUMNS * size),
                                  65535 // tile)
        raise BadInputError(f"expected a grid of at most {MAX_GRID_PIXELS / 1e6:g} megapixels "
                            f"and 65535 pixels high ({most} views at --size {size}), found "
                            f"{views} views, {cols * size}x{rows * tile} pixels")


def grid_image(images: np.ndarray, labels: list[str] | None = None, cols: int | None = None
               ) -> np.ndarray:
    """Tile ``(N, H, W, 3)`` uint8 images into one image, ``cols`` per row (default: a
    near-square grid), with an optional label under each.

    Raises:
        ValueError: No images, images of another shape or type than ``(N, H, W, 3)``
            uint8, or not one label per image.
    """
    import cv2

    images = np.asarray(images)
    if images.ndim != 4 or images.shape[3] != 3 or images.dtype != np.uint8 or not len(images):
        raise ValueError(f"expected (N >= 1, H, W, 3) uint8 images, found {images.shape} "
                         f"{images.dtype}")
    if labels is not None and len(labels) != len(images):
        raise ValueError(f"expected one label per image ({len(images)}), found {len(labels)}")
    n, h, w = images.shape[:3]
    cols = cols or int(np.ceil(np.sqrt(n)))
    rows = int(np.ceil(n / cols))
    band = 0 if labels is None else max(14, h // 12)
    out = np.full((rows * (h + band), cols * w, 3), 255, np.uint8)
    for i, image in enumerate(images):
        y, x = (i // cols) * (h + band), (i % cols) * w
        out[y:y + h, x:x + w] = image
        if labels is not None:  # as large as fits the band and the tile's width
            font = cv2.FONT_HERSHEY_SIMPLEX
            scale = band / 30
            width = cv2.getTextSize(labels[i], font, scale, 1)[0][0]
            scale *= min(1.0, (w - 6) / max(width, 1))
            cv2.putText(out, labels[i], (x + 3, y + h + int(band * 0.75)), font, scale,
                        (40, 40, 40), 1, cv2.LINE_AA)
    return out


def write_turntable(renderer, out: str | Path, frames: int = 48, pitch: float = 0.0,
                    fps: float = 24.0, expression: np.ndarray | None = None,
                    progress: Any = None, hair: bool = True, yaw: float = 0.0) -> Path:
    """Render ``frames`` views turning once around a head (neutral expression unless one
    is given), starting at ``yaw`` degrees, with or without its ``hair``, into a video
    (mp4, GIF or PNG folder by name), streaming frames to the encoder."""
    from head360cli.io.video import MAX_FPS, MIN_FPS, VideoWriter

    if frames < 1:
        raise BadInputError(f"expected at least 1 frame, found {frames}")
    if not MIN_FPS <= fps <= MAX_FPS:  # ffmpeg wrote 1e9 fps as a video of 0 s at 0 fps
        raise BadInputError(f"expected a frame rate of {MIN_FPS:g} to {MAX_FPS:g} frames per "
                            f"second, found {fps:g}")
    w = np.zeros(52) if expression is None else np.asarray(expression)
    if w.shape != (52,):
        raise ValueError(f"expected ARKit weights of shape (52,), found {w.shape}")
    yaws = yaw + np.arange(frames) * (360.0 / frames)
    cams = view_cameras(yaws, np.full(frames, pitch), head_framing(renderer, hair))
    done = 0
    with VideoWriter(out, fps=fps) as video:
        for batch in renderer.frames(cams, np.broadcast_to(w, (frames, 52)),
                                     view_intrinsics(renderer.size), hair=hair):
            for frame in batch:
                video.write(frame)
            done += len(batch)
            if progress:
                progress("turntable", done, frames)
    return Path(out)

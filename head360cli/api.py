"""head360's public Python API: fit a photo, load a head, render it, animate it.

    import head360cli as h

    h.fit("photo.jpg", "me.h360", preset="quality")       # the summary `fit --json` prints
    head = h.load_head("me.h360")                          # device="cuda" on a GPU
    views = h.render(head, yaws=[0, 90, 180], expression={"jawOpen": 0.6})  # (3, S, S, 3)
    h.animate(head, "take.csv", "talk.mp4", head_pose=True)

Each function checks its arguments and raises the exceptions of :mod:`head360cli.errors`
with the command line's one-line messages. The package imports this module only when one
of these names is first used, so ``import head360cli`` stays instant.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from head360cli.errors import BadInputError
from head360cli.fitting.config import FitConfig

__all__ = ["FitConfig", "animate", "fit", "load_head", "render"]


def fit(photo: str | Path, out: str | Path | None = None, config: FitConfig | None = None,
        *, progress=None, **options: Any) -> dict[str, Any]:
    """Fit a head to ``photo`` and write ``out`` (default ``<photo stem>.h360`` beside the
    current folder), its preview PNG and JSON summary, as ``head360 fit`` does.

    Args:
        photo: The image (a path).
        out: The head file, ending in ``.h360``.
        config: A :class:`FitConfig`; ``**options`` replace its fields
            (``preset="quality"``, ``hair_style=7``, ``device="cuda"``).
        progress: ``progress(stage, step, total)``, called as the fit goes.

    Returns:
        The fit's summary (the JSON that ``head360 fit --json`` prints).
    """
    from head360cli.fitting.pipeline import fit_photo
    from head360cli.io.sources import input_stem

    target = Path(out) if out is not None else Path(f"{input_stem(photo)}.h360")
    return fit_photo(photo, target, config, progress=progress, **options)


def load_head(path: str | Path, *, device: str = "cpu", size: int | None = None,
              samples: int | None = None):
    """A head file ready to render: a :class:`~head360cli.model.head_render.HeadRenderer`
    with its blendshapes, texture and hair made once.

    Args:
        path: A ``.h360`` file made with the installed generator.
        device: Torch device (``cpu``, ``cuda``, ``cuda:N``).
        size: Image size of its renders (default: the generator's, 256).
        samples: Samples per ray (default: the generator's).

    Raises:
        FileFormatError: Not a head file, or one of a newer format.
        ModelMismatchError: Made with another generator.
    """
    from head360cli.devices import resolve_device
    from head360cli.fitting.pipeline import load_head_renderer

    return load_head_renderer(path, device=str(resolve_device(device)), samples=samples,
                              size=size)


def _weights(expression: Any) -> np.ndarray:
    """ARKit weights ``(52,)`` from ``None`` (the head's own), a ``{name: weight}`` dict,
    a ``"jawOpen=0.6,..."`` string or 52 numbers."""
    from head360cli.drive.views import parse_expression

    if isinstance(expression, dict):
        expression = ",".join(f"{k}={v}" for k, v in expression.items())
    if expression is None or isinstance(expression, str):
        return parse_expression(expression)
    weights = np.asarray(expression, np.float32)
    if weights.shape != (52,) or not np.isfinite(weights).all():
        raise BadInputError(f"expected 52 finite ARKit weights, found shape "
                            f"{weights.shape}")
    return weights


def render(head, yaws=(0.0,), pitch: float = 0.0, *, expression: Any = None,
           hair: bool = True) -> np.ndarray:
    """Views of a head from the rig's cameras, on white.

    Args:
        head: A loaded head (:func:`load_head`) or a ``.h360`` path (loaded on the CPU).
        yaws: Degrees, one view each; + shows the head's left side, 180 its back.
        pitch: Degrees for every view; + looks from above.
        expression: ``None`` (the photo's own expression), ``{"jawOpen": 0.6}``,
            ``"jawOpen=0.6,eyeBlinkLeft=1"`` or 52 weights in Apple's order.
        hair: ``False`` renders the head bald.

    Returns:
        ``(len(yaws), S, S, 3)`` uint8 RGB images.
    """
    from head360cli.drive.views import head_framing, view_cameras, view_intrinsics

    if isinstance(head, str | Path):
        head = load_head(head)
    yaws = np.atleast_1d(np.asarray(yaws, np.float32))
    cams = view_cameras(yaws, pitch, head_framing(head, hair))
    given = expression is not None
    weights = np.broadcast_to(_weights(expression) if given else head.expression,
                              (len(cams), 52))
    frames = head.frames(cams, weights, view_intrinsics(head.size), hair=hair,
                         drive=given)
    return np.concatenate(list(frames))


def animate(head, stream, out: str | Path, *, fps: float | None = None,
            head_pose: bool = False, start: float | None = None, end: float | None = None,
            smooth: float = 0.0, yaw: float = 0.0, pitch: float = 0.0,
            on_bad: str = "hold", progress=None) -> dict[str, Any]:
    """Drive a head with an ARKit-52 stream and write a video, as ``head360 animate``.

    Args:
        head: A loaded head (:func:`load_head`) or a ``.h360`` path.
        stream: An ARKit CSV path (Live Link Face, MediaPipe or any CSV with the 52
            names) or an :class:`~head360cli.io.arkit.ArkitStream`.
        out: ``.mp4``, ``.gif``, or a folder for PNG frames.
        fps: Output frame rate (default: the stream's).
        head_pose: Apply the stream's head rotation.
        start, end: Seconds of the stream to render.
        smooth: Gaussian smoothing of the weights, in seconds (0: none).
        yaw, pitch: The camera, degrees.
        on_bad: What a bad row of the CSV gets: ``hold`` (the previous frame), ``skip``
            or ``error``.
        progress: ``progress(stage, done, total)``.

    Returns:
        The summary ``head360 animate --json`` prints (frames, fps, render speed, files).
    """
    from head360cli.drive.animate import AnimateConfig
    from head360cli.drive.animate import animate as run
    from head360cli.io.arkit import ArkitStream, read_arkit_csv

    if not isinstance(stream, ArkitStream):
        stream = read_arkit_csv(stream, on_bad=on_bad)
    if isinstance(head, str | Path):
        path = head
        head = lambda: load_head(path)  # noqa: E731  (loaded once the workers start)
    cfg = AnimateConfig(fps=fps, start=start, end=end, smooth=smooth, head_pose=head_pose,
                        yaw=yaw, pitch=pitch)
    return run(head, stream, out, cfg, progress=progress)

"""Pictures for people: plots of ARKit streams (drawn with OpenCV, no plotting library)."""

from __future__ import annotations

import os

import numpy as np

from head360cli.io.arkit import ArkitStream
from head360cli.mesh.arkit52 import ARKIT52

__all__ = ["plot_fidelity", "plot_stream"]

# Distinct colours (BGR for OpenCV), one per plotted curve.
_COLOURS = [(180, 119, 31), (14, 127, 255), (44, 160, 44), (40, 39, 214), (189, 103, 148),
            (75, 86, 140), (194, 119, 227), (127, 127, 127), (34, 189, 188), (207, 190, 23)]


def _panel(img, box, t, curves, names, y_range, title) -> None:
    import cv2

    x0, y0, x1, y1 = box
    cv2.rectangle(img, (x0, y0), (x1, y1), (200, 200, 200), 1)
    lo, hi = y_range
    duration = max(float(t[-1]), 1e-9)
    for k in range(5):  # horizontal grid lines with labels
        v = lo + (hi - lo) * k / 4
        y = round(y1 - (v - lo) / (hi - lo) * (y1 - y0))
        cv2.line(img, (x0, y), (x1, y), (235, 235, 235), 1)
        cv2.putText(img, f"{v:g}", (x0 - 44, y + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.38,
                    (90, 90, 90), 1, cv2.LINE_AA)
    cv2.putText(img, title, (x0, y0 - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (40, 40, 40), 1,
                cv2.LINE_AA)
    for j, (curve, name) in enumerate(zip(curves, names, strict=True)):
        xs = x0 + t / duration * (x1 - x0)
        ys = y1 - (np.clip(curve, lo, hi) - lo) / (hi - lo) * (y1 - y0)
        pts = np.stack([xs, ys], axis=1).round().astype(np.int32)
        colour = _COLOURS[j % len(_COLOURS)]
        cv2.polylines(img, [pts], False, colour, 2, cv2.LINE_AA)
        cv2.putText(img, name, (x1 + 10, y0 + 16 + 18 * j), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                    colour, 1, cv2.LINE_AA)


def plot_stream(stream: ArkitStream, path: str | os.PathLike[str], top: int = 8) -> None:
    """Draw the most active blendshapes (and head rotation, if any) over time as a PNG.

    Args:
        stream: The stream to plot.
        path: Output ``.png`` path (written atomically).
        top: How many blendshapes to show, the ones with the largest range first.
    """
    import cv2

    from head360cli.errors import BadInputError
    from head360cli.io.atomic import atomic_path

    if not str(path).lower().endswith(".png"):
        raise BadInputError(f"expected a .png name for the plot, found {str(path)!r}")
    t = stream.timestamps
    if len(t) < 2:
        t = np.array([0.0, 1.0 / stream.fps])
        weights = np.repeat(stream.weights, 2, axis=0)
    else:
        weights = stream.weights
    spread = weights.max(0) - weights.min(0)
    order = [int(i) for i in np.argsort(-spread, kind="stable")[:top] if spread[i] > 0]
    has_pose = stream.head_rotation is not None
    width, height = 1000, 560 if has_pose else 340
    img = np.full((height, width, 3), 255, dtype=np.uint8)
    _panel(img, (60, 30, 800, 290), t, [weights[:, i] for i in order],
           [ARKIT52[i] for i in order], (0.0, 1.0),
           f"most active blendshapes ({stream.num_frames} frames, {stream.fps:g} fps)")
    if has_pose:
        assert stream.head_rotation is not None
        deg = np.degrees(stream.head_rotation.astype(np.float64))
        if len(deg) < 2:
            deg = np.repeat(deg, 2, axis=0)
        bound = max(5.0, float(np.ceil(np.abs(deg).max() / 5.0) * 5.0))
        _panel(img, (60, 340, 800, 520), t, [deg[:, 0], deg[:, 1], deg[:, 2]],
               ["yaw", "pitch", "roll"], (-bound, bound), "head rotation (degrees)")
    cv2.putText(img, f"time: 0 .. {float(t[-1]):.2f} s", (60, height - 10),
                cv2.FONT_HERSHEY_SIMPLEX, 0.45, (90, 90, 90), 1, cv2.LINE_AA)
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), img):
            raise BadInputError(f"could not write the plot to {str(path)!r}")


def plot_fidelity(series: dict, path: str | os.PathLike[str], title: str = "") -> None:
    """Draw driving and tracked weights over time, one panel per blendshape, as a PNG.

    Args:
        series: ``{"t": (N,) seconds, "names": [...], "driving": [(N,) ...],
            "tracked": [(N,) ...]}`` (see :func:`head360cli.bench.fidelity.head_fidelity`).
        path: Output ``.png`` path (written atomically).
        title: A line above the panels.
    """
    import cv2

    from head360cli.io.atomic import atomic_path

    t = np.asarray(series["t"], np.float64)
    if len(t) < 2:
        t = np.array([0.0, 1.0])
    names = list(series["names"])
    rows = max(1, len(names))
    width, height = 1000, 40 + 150 * rows
    img = np.full((height, width, 3), 255, dtype=np.uint8)
    cv2.putText(img, title, (60, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (40, 40, 40), 1,
                cv2.LINE_AA)
    for k, name in enumerate(names):
        d = np.asarray(series["driving"][k], np.float64)
        tr = np.asarray(series["tracked"][k], np.float64)
        if len(d) < 2:
            d, tr = np.repeat(d, 2), np.repeat(tr, 2)
        y0 = 60 + 150 * k
        _panel(img, (60, y0, 800, y0 + 110), t, [d, tr], ["driving", "tracked"], (0.0, 1.0),
               name)
    cv2.putText(img, f"time: 0 .. {float(t[-1]):.2f} s", (60, height - 8),
                cv2.FONT_HERSHEY_SIMPLEX, 0.45, (90, 90, 90), 1, cv2.LINE_AA)
    with atomic_path(path) as tmp:
        cv2.imwrite(str(tmp), img)

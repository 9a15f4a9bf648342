"""``head360 bench expressions``: each ARKit blendshape alone, rendered and read back.

A head (the fitted astronaut, or a head file) is rendered from the front with one
blendshape at a time at :data:`LEVELS`, every frame read by head360's face tracker as a
still (no filter, no following). A blendshape *rises* when the tracker's score for it
grows with its weight: at least :data:`MIN_RISE` from weight 0 to 1, never falling by
more than :data:`MAX_DIP` from one level to the next. ``mouthClose`` is swept with
``jawOpen`` at the same weight, since ARKit defines it as the lips closing over an open
jaw (alone it would push the lower lip through the upper). Beside it, a held-out SynHead-P
head drawn by the corpus renderer with the same weights: what the corpus teaches.

Which blendshapes the tracker reads on real faces at all is measured too: its highest
score for each over the real photos in ``../shared/data`` (portraits, landmark and hair
sets, head turns). A blendshape it never scores above :data:`REAL_MIN` there is one it
does not read, and the count of rising ones is also given over the others.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["LEVELS", "MAX_DIP", "MIN_RISE", "REAL_MIN", "bench_expressions", "real_reading",
           "rises", "sweep_weights"]

LEVELS = (0.25, 0.5, 0.75, 1.0)
"""The weights each blendshape is rendered at (beside the neutral face, weight 0)."""
MIN_RISE = 0.1
"""A blendshape rises when the tracker's score for it grows by at least this from 0 to 1."""
MAX_DIP = 0.05
"""... and never falls by more than this from one level to the next."""
REAL_MIN = 0.2
"""A blendshape the tracker never scores above this on the real photos is one it does not
read on real faces."""
REAL_FOLDERS = ("faces", "landmarks68", "hair", "hair_more", "multiview")
"""Folders of ``../shared/data`` whose photos (any depth) the real-face reading covers."""


def sweep_weights(levels: tuple[float, ...] = LEVELS) -> np.ndarray:
    """``(1 + 52 * L, 52)`` weights: the neutral face, then each blendshape alone at each
    level (blendshape-major; ``mouthClose`` with ``jawOpen`` beside it)."""
    from head360cli.mesh.arkit52 import INDEX

    w = np.zeros((1 + 52 * len(levels), 52), np.float32)
    for j in range(52):
        for k, level in enumerate(levels):
            w[1 + j * len(levels) + k, j] = level
            if j == INDEX["mouthClose"]:
                w[1 + j * len(levels) + k, INDEX["jawOpen"]] = level
    return w


def rises(curve: np.ndarray) -> bool:
    """Whether a ``(1 + L,)`` curve of scores (weight 0 first) rises with the weight."""
    steps = np.diff(curve)
    return bool(curve[-1] - curve[0] >= MIN_RISE and (steps >= -MAX_DIP).all())


def _read(frames) -> np.ndarray:
    """Scores ``(N, 52)`` of frames read as stills; NaN rows where no face was found."""
    from head360cli.perception.track import FaceTracker

    tracker = FaceTracker()
    out = []
    for frame in frames:
        tracker.reset()
        reading = tracker(np.ascontiguousarray(frame[..., :3]))
        out.append(np.full(52, np.nan, np.float32) if reading is None else reading.weights)
    return np.asarray(out, np.float32)


def _table(scores: np.ndarray, levels: tuple[float, ...]) -> dict[str, Any]:
    """Per blendshape: its own score at 0 and each level, and whether it rises."""
    from head360cli.mesh.arkit52 import ARKIT52

    per: dict[str, Any] = {}
    for j, name in enumerate(ARKIT52):
        rows = scores[1 + j * len(levels): 1 + (j + 1) * len(levels), j]
        curve = np.concatenate([[scores[0, j]], rows])
        ok = bool(np.isfinite(curve).all())
        per[name] = {"scores": [round(float(x), 3) if np.isfinite(x) else None
                                for x in curve],
                     "rises": ok and rises(curve)}
    risen = [n for n, v in per.items() if v["rises"]]
    return {"levels": [0.0, *levels], "rising": len(risen), "of": len(per),
            "not_rising": [n for n in per if n not in risen],
            "faces_missed": int(np.isnan(scores[:, 0]).sum()), "per_shape": per}


def head_sweep(head: str | Path, levels: tuple[float, ...] = LEVELS, size: int | None = None,
               device: str = "cpu") -> dict[str, Any]:
    """A head file rendered from the front (with its hair) with each blendshape alone."""
    from head360cli.drive.views import head_framing, view_cameras, view_intrinsics
    from head360cli.fitting.pipeline import load_head_renderer

    r = load_head_renderer(head, device=device, size=size)
    w = sweep_weights(levels)
    cams = view_cameras(0.0, 0.0, head_framing(r, True))[0][None].expand(len(w), 4, 4)
    scores = _read(f for batch in r.frames(cams, w, view_intrinsics(r.size)) for f in batch)
    return {"size": r.size, **_table(scores, levels)}


def corpus_sweep(levels: tuple[float, ...] = LEVELS, size: int = 256, index: int = 0
                 ) -> dict[str, Any]:
    """A held-out SynHead-P head (test split, bald) drawn by the corpus renderer with each
    blendshape alone: the corpus's own expressions, without the generator."""
    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.model.head_render import to_uint8
    from head360cli.synth.scene import make_head, prepare_render, render_head

    head = make_head(index, "test", 0)
    prepare_render(head, "cpu")
    cam, k = view_cameras(0.0, 0.0), view_intrinsics(size)
    scores = _read(to_uint8(render_head(head, wj, cam, k, size, with_hair=False).rgb)[0]
                   for wj in sweep_weights(levels))
    return {"head": f"SynHead-P test {index}", "size": size, **_table(scores, levels)}


def real_reading(data: str | Path) -> dict[str, Any] | None:
    """The tracker's highest score (and 99th percentile) for each blendshape over the
    photos under ``data``'s :data:`REAL_FOLDERS`, read as stills; ``None`` if none."""
    import cv2

    from head360cli.mesh.arkit52 import ARKIT52

    files = sorted(p for f in REAL_FOLDERS for p in (Path(data) / f).rglob("*")
                   if p.suffix.lower() in (".jpg", ".jpeg", ".png"))
    frames = (cv2.imread(str(p), cv2.IMREAD_COLOR) for p in files)
    scores = _read(img[:, :, ::-1] for img in frames if img is not None)
    scores = scores[np.isfinite(scores[:, 0])] if len(scores) else scores
    if not len(scores):
        return None
    top, p99 = scores.max(0), np.percentile(scores, 99, axis=0)
    return {"photos": len(files), "faces": len(scores),
            "max": {n: round(float(top[j]), 3) for j, n in enumerate(ARKIT52)},
            "p99": {n: round(float(p99[j]), 3) for j, n in enumerate(ARKIT52)},
            "not_read": [n for j, n in enumerate(ARKIT52) if top[j] < REAL_MIN]}


def bench_expressions(head_path: str | Path | None = None, size: int | None = None,
                      corpus: bool = True, real: bool = True, device: str = "cpu",
                      progress: Callable[[str], None] | None = None
                      ) -> tuple[dict[str, Any], str]:
    """Run the sweep on the fitted astronaut (or ``head_path``) and on a corpus head, and
    the tracker on the shared real photos (``real``).

    Returns:
        The result dict and its Markdown table.
    """
    say = progress or (lambda _t: None)
    t0 = time.perf_counter()
    result: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        if head_path is None:
            from head360cli.fitting.pipeline import run_demo

            say("fitting the astronaut (fast preset)")
            run_demo(Path(tmp), frames=4, device=device)
            head = Path(tmp) / "astronaut.h360"
        else:
            head = Path(head_path)
        say(f"each blendshape alone at {', '.join(map(str, LEVELS))}: the head, tracked")
        result["head"] = {"name": "astronaut, fitted (fast preset)" if head_path is None
                          else head.name, **head_sweep(head, LEVELS, size, device)}
    if corpus:
        say("the same on a SynHead-P head drawn by the corpus renderer")
        result["corpus"] = corpus_sweep(LEVELS, result["head"]["size"])
    from head360cli.paths import shared_data_dir

    if real and shared_data_dir() is not None:
        say("the tracker on the real photos in ../shared/data: which blendshapes it reads")
        result["real"] = real_reading(shared_data_dir())
        if result["real"] is not None:
            unread = set(result["real"]["not_read"])
            for p in ("head", "corpus"):
                if p in result:
                    result[p]["rising_of_read"] = sum(
                        v["rises"] for n, v in result[p]["per_shape"].items()
                        if n not in unread)
                    result[p]["read_on_real_faces"] = 52 - len(unread)
    result["seconds"] = round(time.perf_counter() - t0, 1)
    return result, _markdown(result)


def _markdown(result: dict[str, Any]) -> str:
    parts = [p for p in ("head", "corpus") if p in result]
    real = result.get("real")
    cols = [f"{result[p].get('name') or result[p].get('head')}: score at "
            f"{', '.join(f'{x:g}' for x in result[p]['levels'])}" for p in parts]
    if real:
        cols.append(f"highest score on {real['faces']} real faces")
    lines = ["# Each blendshape alone, read back by the face tracker", "",
             "| blendshape | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]
    for name in result["head"]["per_shape"]:
        cells = []
        for p in parts:
            s = result[p]["per_shape"][name]
            txt = " ".join("-" if x is None else f"{x:.2f}" for x in s["scores"])
            cells.append(f"{txt} {'rises' if s['rises'] else ''}".strip())
        if real:
            cells.append(f"{real['max'][name]:.2f}"
                         + (" (not read)" if name in real["not_read"] else ""))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines.append("")
    for p in parts:
        also = (f" ({result[p]['rising_of_read']} of the {result[p]['read_on_real_faces']} "
                f"the tracker reads on real faces)" if "rising_of_read" in result[p] else "")
        lines.append(f"- {p}: {result[p]['rising']} of {result[p]['of']} rise with their "
                     f"weight{also}; faces missed in {result[p]['faces_missed']} frames")
    return "\n".join(lines) + "\n"

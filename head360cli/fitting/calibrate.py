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

from head360cli.errors import BadInputError, FileFormatError
from head360cli.mesh.bilinear import BilinearModel

__all__ = ["DENSE_FILE", "build_ibug68_map", "calibrate_landmarks", "load_dense_points",
           "mesh_outline", "read_dlib_landmarks", "register_face_mesh"]

DENSE_FILE = "face_mesh_on_head.npz"
"""Where the face mesh's points sit on the head template, in the models folder."""
DENSE_MAX_ERROR = 0.02
"""Mesh points whose registration error (mean reprojection error over the photos, in face
sizes) is above this are not fitted: on the London set, 1 % of them."""

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


_DENSE_CACHE: dict = {}
"""Registrations read so far, by (path, model hash)."""


def load_dense_points(model: BilinearModel) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The face mesh's points the shape fit uses, as ``(mesh index (N,), tri (N, 3), bary
    (N, 3))`` on ``model``'s surface, or ``None`` when the file is missing or was made
    for another model (the fit then uses the 68 landmarks alone)."""
    from head360cli.paths import models_dir

    path = models_dir() / DENSE_FILE
    model_hash = model.meta.get("sha256")
    key = (str(path), model_hash)
    if key in _DENSE_CACHE:
        return _DENSE_CACHE[key]
    out = None
    if path.is_file():
        try:
            with np.load(path, allow_pickle=False) as data:
                if str(data["model"]) == model_hash:
                    keep = np.nonzero(data["use"])[0]
                    out = (keep, data["tri"][keep].astype(np.int64),
                           data["bary"][keep].astype(np.float64))
        except (OSError, ValueError, KeyError) as exc:
            raise FileFormatError(f"{path}: not a readable face-mesh registration "
                                  f"({exc})") from exc
    _DENSE_CACHE[key] = out
    return out


def build_ibug68_map(folder: str | Path, progress=None) -> dict:
    """Learn the 68 iBUG points as combinations of the face mesh's points
    (:func:`head360cli.perception.ibug68.fit_ibug68_map`) from the photos in ``folder``
    (``*.jpg``, ``*.png``, searched recursively), taking dlib's averaged 68-point
    predictions as the teacher: both read the same face (the largest, where the two
    detectors' boxes agree).

    Then places the face mesh's 468 points on the head template from the same photos
    (:func:`register_face_mesh`, each fitted to the 68 points the new map reads), for
    the dense shape fit; the face's outline and points placed worse than
    :data:`DENSE_MAX_ERROR` are left out of it.

    Returns:
        ``{"index", "weight", "faces", "train_nme", "tri", "bary", "error", "use",
        "model", "registration"}``: the map, the faces used, the mean NME of the map
        against the teacher on them, the registration and which points the fit uses,
        the bilinear model's hash and the registration's errors.
    """
    from head360cli.fitting.landmarks import MESH_PASSES, LandmarkDetector
    from head360cli.io.images import load_image
    from head360cli.perception.faces import detect_yunet
    from head360cli.perception.ibug68 import fit_ibug68_map, nme, to_ibug68
    from head360cli.perception.mesh478 import face_mesh

    photos = sorted(p for p in Path(folder).rglob("*") if p.suffix.lower() in
                    (".jpg", ".jpeg", ".png"))
    teacher = LandmarkDetector("hog")
    meshes, targets, sizes = [], [], []
    for i, photo in enumerate(photos):
        if progress is not None:
            progress(i, len(photos))
        rgb = load_image(photo).pixels
        dlib_faces, boxes = teacher.detect(rgb, only=0), detect_yunet(rgb)
        if not dlib_faces or not boxes:
            continue
        points = face_mesh(rgb, boxes[0].box, boxes[0].keypoints[:2], MESH_PASSES).points
        a = dlib_faces[0].landmarks
        span = a.max(0) - a.min(0)
        if np.linalg.norm(a.mean(0) - points[:468, :2].mean(0)) > 0.2 * np.sqrt(
                span[0] * span[1]):
            continue  # not the same face
        meshes.append(points)
        targets.append(a)
        sizes.append(rgb.shape[1::-1])
    if len(meshes) < 20:
        raise BadInputError(f"expected at least 20 photos in which both dlib and the face "
                            f"mesh find a face in {folder}, found {len(meshes)}")
    index, weight = fit_ibug68_map(meshes, targets)
    train = [nme(to_ibug68(m, (index, weight)), t) for m, t in zip(meshes, targets,
                                                                   strict=True)]
    # the mesh's points on the head, placed by fits to the 68 points the new map reads
    from head360cli.mesh.bilinear import load_bilinear
    from head360cli.perception.runtime import perception_file

    model = load_bilinear()
    tri, bary, error, stats = register_face_mesh(
        model, [(to_ibug68(m, (index, weight)), m, size) for m, size in zip(
            meshes, sizes, strict=True)])
    outline = mesh_outline(_obj_faces(perception_file("canonical_face")))
    use = (error <= DENSE_MAX_ERROR) & ~np.isin(np.arange(468), outline)
    return {"index": index, "weight": weight, "faces": len(meshes),
            "train_nme": float(np.mean(train)), "tri": tri, "bary": bary, "error": error,
            "use": use, "model": model.meta["sha256"], "registration": stats}


def _obj_faces(path: Path) -> np.ndarray:
    """``(F, 3)`` zero-based triangles of a Wavefront OBJ file (``f a/b c/d ...``)."""
    faces = []
    for line in path.read_text().splitlines():
        if line.startswith("f "):
            faces.append([int(p.split("/")[0]) - 1 for p in line.split()[1:4]])
    return np.array(faces, dtype=np.int64)


def mesh_outline(faces: np.ndarray) -> np.ndarray:
    """The vertices on the outer boundary of a triangle mesh ``faces (F, 3)``: those of
    its longest boundary loop (for the canonical face mesh, the face's oval; the eyes'
    and the mouth's holes are shorter loops)."""
    from collections import Counter

    edges = Counter(tuple(sorted(e)) for f in faces for e in ((f[0], f[1]), (f[1], f[2]),
                                                             (f[2], f[0])))
    boundary = [e for e, n in edges.items() if n == 1]
    nbrs: dict[int, list[int]] = {}
    for a, b in boundary:
        nbrs.setdefault(a, []).append(b)
        nbrs.setdefault(b, []).append(a)
    loops, seen = [], set()
    for start in nbrs:
        if start in seen:
            continue
        loop, stack = [], [start]
        while stack:
            v = stack.pop()
            if v in seen:
                continue
            seen.add(v)
            loop.append(v)
            stack.extend(nbrs[v])
        loops.append(loop)
    return np.array(sorted(max(loops, key=len)), dtype=np.int64)


def register_face_mesh(model: BilinearModel, faces, radius: float = 0.015, level: int = 4
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, float]]:
    """Where each of the face mesh's 468 points sits on the head template, learnt from
    photos read by both the fitter's 68 landmarks and the face mesh.

    Each photo is fitted to its 68 landmarks; each mesh point is lifted into the fitted
    head's frame (its pixel position on the line of sight, its depth from the mesh's
    relative depth at the head's scale), which gives a first guess on the mean head; the
    point then goes to the surface point within ``radius`` of the guess (a barycentric
    grid of ``level`` steps on each nearby triangle of the face, nose or lips)
    whose projection best matches the mesh's point over all photos, as
    :func:`calibrate_landmarks` places the 68.

    Args:
        model: The bilinear model.
        faces: ``(landmarks (68, 2), mesh (478, 3), (width, height))`` per photo.

    Returns:
        ``(tri (468, 3), bary (468, 3), error (468,), stats)``: the surface point of each
        mesh point, its mean reprojection error over the photos in face sizes, and the
        68-landmark fit's mean error.
    """
    from head360cli.fitting.shape import ShapeFitConfig, ShapeFitter

    fitter = ShapeFitter(model, ShapeFitConfig(opposed=0.0))
    fits = [fitter.fit(lm, size) for lm, _, size in faces]
    mean = model.neutral_mean.astype(np.float64)
    allowed = np.isin(model.region, [1, 2, 3])  # face, nose, lips (not the eyeballs)
    ok_tri = allowed[model.faces].all(1)
    centroids = mean[model.faces].mean(1)
    grid = _barycentric_grid(level)
    lifted = []
    for fit, (_, mesh, _) in zip(fits, faces, strict=True):
        verts = model.vertices(fit.shape, fit.expression)
        land = verts[fit.landmark_vertices]
        cam_land = land @ fit.rotation.T + fit.translation
        depth = float(cam_land[:, 2].mean())
        pts = mesh[:468]
        z = depth + (pts[:, 2] - pts[:, 2].mean()) * depth / fit.focal
        cam = np.stack([(pts[:, 0] - fit.centre[0]) * z / fit.focal,
                        (pts[:, 1] - fit.centre[1]) * z / fit.focal, z], 1)
        # back into the fitted head's frame, then by the fitted head's offset from the mean
        local = (cam - fit.translation) @ fit.rotation
        lifted.append(local - (land - mean[fit.landmark_vertices]).mean(0))
    guess = np.median(np.stack(lifted), axis=0)  # (468, 3) on the mean head
    scores = []  # per point: (triangles, (T, S) summed squared error)
    for k in range(468):
        near = ok_tri & (np.linalg.norm(centroids - guess[k], axis=1) < radius)
        if not near.any():
            near = ok_tri & (np.linalg.norm(centroids - guess[k], axis=1) <= np.min(
                np.linalg.norm(centroids[ok_tri] - guess[k], axis=1)) + 1e-9)
        scores.append((model.faces[near], np.zeros((int(near.sum()), len(grid)))))
    errs = []
    for fit, (lm, mesh, _) in zip(fits, faces, strict=True):
        verts = model.vertices(fit.shape, fit.expression)
        scale = np.sqrt(np.prod(lm.max(0) - lm.min(0)))
        errs.append(np.linalg.norm(fit.landmarks_fitted - lm, axis=1).mean() / scale)
        for k, (tris, score) in enumerate(scores):
            p = np.einsum("sj,tjc->tsc", grid, verts[tris])
            cam = p @ fit.rotation.T + fit.translation
            uv = fit.focal * cam[..., :2] / cam[..., 2:3] + fit.centre
            score += (np.linalg.norm(uv - mesh[k, :2], axis=-1) / scale) ** 2
    tri = np.zeros((468, 3), np.int64)
    bary = np.zeros((468, 3))
    error = np.zeros(468)
    for k, (tris, score) in enumerate(scores):
        t, g = np.unravel_index(int(np.argmin(score)), score.shape)
        tri[k], bary[k] = tris[t], grid[g]
        error[k] = np.sqrt(score[t, g] / len(faces))
    return tri, bary, error, {"fit_error": float(np.mean(errs)),
                              "mesh_error": float(np.mean(error))}

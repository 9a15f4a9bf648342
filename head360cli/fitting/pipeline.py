"""``head360 fit``: from a photo to fitted heads (so far: the shape stage)."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from head360cli.errors import BadInputError

__all__ = ["fit_shape_photo"]

_EXIF_FOCAL_35MM = 0xA405
_EXIF_IFD = 0x8769


def _focal_35mm(path: str | Path) -> float | None:
    """``FocalLengthIn35mmFilm`` from a photo's EXIF, if present."""
    from PIL import Image

    try:
        with Image.open(path) as img:
            value = img.getexif().get_ifd(_EXIF_IFD).get(_EXIF_FOCAL_35MM)
        return float(value) if value else None
    except Exception:  # no or malformed EXIF
        return None


def _overlay(rgb: np.ndarray, detected: np.ndarray, fitted: np.ndarray, verts2d: np.ndarray,
             faces: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """The photo with the mesh wireframe (front-facing triangles), detected landmarks
    (green) and fitted landmarks (red)."""
    import cv2

    img = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    wire = img.copy()
    shown = faces[visible]
    # Thin the wireframe so that each drawn triangle covers about 40 pixels.
    span = verts2d[shown.reshape(-1)].max(0) - verts2d[shown.reshape(-1)].min(0)
    stride = max(1, int(np.ceil(len(shown) * 40 / max(1.0, float(span[0] * span[1])))))
    tris = np.round(verts2d[shown[::stride]] * 4).astype(np.int32)  # 2 bits of subpixel
    cv2.polylines(wire, list(tris), True, (255, 200, 60), 1, cv2.LINE_AA, shift=2)
    img = cv2.addWeighted(wire, 0.35, img, 0.65, 0)
    r = max(1, round(max(img.shape[:2]) / 400))
    for (x, y) in detected:
        cv2.circle(img, (round(x), round(y)), r + 1, (60, 220, 60), -1, cv2.LINE_AA)
    for (x, y) in fitted:
        cv2.circle(img, (round(x), round(y)), r, (40, 40, 235), -1, cv2.LINE_AA)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def fit_shape_photo(photo: str | Path, out_dir: str | Path, *, face: int | str = 0,
                    detector: str = "hog", focal: float | None = None) -> dict[str, Any]:
    """Detect, fit the bilinear model, and write ``<stem>[_faceN]_shape.obj``,
    ``_overlay.png`` and ``_shape.json`` into ``out_dir``.

    Args:
        photo: The image.
        out_dir: Output folder (created).
        face: Face number (0 = largest) or ``"all"``.
        detector: ``hog``, or ``cnn`` for hard faces.
        focal: Focal length in pixels of the image on disk (default: EXIF, else a
            50 mm-equivalent lens).

    Returns:
        The result (for one face) or ``{"faces": [...]}`` (for ``"all"``); landmarks in the
        pixels of the image as given on disk.
    """
    from PIL import Image

    from head360cli.fitting.landmarks import LandmarkDetector
    from head360cli.fitting.shape import ShapeFitter, default_focal
    from head360cli.io.atomic import atomic_path
    from head360cli.io.images import load_image
    from head360cli.io.mesh import write_obj
    from head360cli.mesh.arkit52 import ARKIT52
    from head360cli.mesh.bilinear import load_bilinear

    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    img = load_image(photo)
    model = load_bilinear()
    fitter = ShapeFitter(model)
    timings["load"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    det = LandmarkDetector(detector)
    if face == "all":
        faces = det.detect(img.pixels)
        if not faces:
            det.detect_one(img.pixels)  # raises the no-face error
        chosen = list(enumerate(faces))
    else:
        if int(face) < 0:
            raise BadInputError(f"expected a face number >= 0, found {face}")
        chosen = [(int(face), det.detect_one(img.pixels, int(face)))]
    timings["detect"] = time.perf_counter() - t0

    full_w, full_h = img.source_size
    scale = img.scale  # loaded pixels per pixel on disk
    f_disk = focal if focal else default_focal(full_w, full_h, _focal_35mm(photo))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = Path(photo).stem
    results = []
    for index, found in chosen:
        t0 = time.perf_counter()
        fit = fitter.fit(found.landmarks, img.size, focal=f_disk * scale)
        t_fit = time.perf_counter() - t0
        t0 = time.perf_counter()
        verts = model.vertices(fit.shape, fit.expression)
        cam = verts @ fit.rotation.T + fit.translation
        v2d = fit.focal * cam[:, :2] / np.maximum(cam[:, 2:3], 1e-6) + fit.centre
        tri = cam[model.faces]
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        visible = (np.einsum("ij,ij->i", normal, tri[:, 0]) < 0) & (
            np.isin(model.region[model.faces[:, 0]], [0, 1, 2, 3, 6]))
        name = f"{stem}_face{index}" if face == "all" else stem
        paths = {"mesh": out / f"{name}_shape.obj", "overlay": out / f"{name}_overlay.png",
                 "params": out / f"{name}_shape.json"}
        write_obj(paths["mesh"], verts, model.faces, model.uv, model.faces_uv,
                  comment=f"head360 shape fit of {Path(photo).name}\nmetres, +y up, face +z")
        overlay = _overlay(img.pixels, found.landmarks, fit.landmarks_fitted, v2d,
                           model.faces, visible)
        with atomic_path(paths["overlay"]) as tmp:
            Image.fromarray(overlay).save(tmp)
        euler = fit.euler_degrees()
        result = {
            "photo": str(photo),
            "face": index,
            "image_size": [full_w, full_h],
            "face_box": [round(c / scale, 2) for c in found.box],
            "landmarks_detected": (found.landmarks / scale).round(2).tolist(),
            "landmarks_fitted": (fit.landmarks_fitted / scale).round(2).tolist(),
            "shape": fit.shape.round(6).tolist(),
            "expression": {n: round(float(w), 4) for n, w in zip(ARKIT52, fit.expression,
                                                                  strict=True)},
            "pose": {**{k: round(v, 3) for k, v in euler.items()},
                     "translation": fit.translation.round(5).tolist(),
                     "focal": round(f_disk, 2)},
            "model": model.meta["sha256"],
            "files": {k: str(v) for k, v in paths.items()},
        }
        t_write = time.perf_counter() - t0
        result["timings"] = {**{k: round(v, 4) for k, v in timings.items()},
                             "fit": round(t_fit, 4), "write": round(t_write, 4)}
        with atomic_path(paths["params"]) as tmp:
            tmp.write_text(json.dumps(result, indent=1))
        results.append(result)
    return results[0] if face != "all" else {"faces": results}

"""The photo pipelines behind ``head360 fit``, ``parse-hair``, ``classify-hair`` and
``demo``: they load, call the fitting modules in order, time each stage and write the
outputs atomically. The work itself lives in :mod:`head360cli.fitting.shape`,
:mod:`~head360cli.fitting.hair_parse`, :mod:`~head360cli.fitting.hair_class` and
:mod:`~head360cli.fitting.texture`."""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from head360cli.errors import BadInputError
from head360cli.io.atomic import check_folder_name
from head360cli.io.jsontext import dumps
from head360cli.io.sources import input_stem

__all__ = ["FIT_SUMMARY_KEYS", "check_fit_outputs", "check_head_sizes", "classify_photo",
           "fit_outputs", "fit_photo", "fit_shape_photo", "load_head_renderer",
           "parse_photo", "run_demo"]


def _timed(fn, *args, **kwargs) -> tuple[Any, float]:
    """``(fn(*args, **kwargs), its wall time in seconds)``."""
    t0 = time.perf_counter()
    return fn(*args, **kwargs), time.perf_counter() - t0


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
                    detector: str = "hog", focal: float | None = None,
                    distance: float | None = None) -> dict[str, Any]:
    """Detect, fit the bilinear model, and write ``<stem>[_faceN]_shape.obj``,
    ``_overlay.png`` and ``_shape.json`` into ``out_dir``.

    Args:
        photo: The image.
        out_dir: Output folder (created).
        face: Face number (0 = largest) or ``"all"``.
        detector: ``hog``, ``cnn`` for hard faces, or ``auto`` (HOG, then the CNN
            detector when HOG finds none); the search is ``fit``'s
            (:func:`~head360cli.fitting.landmarks.find_faces`).
        focal: Focal length in pixels of the image on disk (default: EXIF, else a
            50 mm-equivalent lens).
        distance: The camera's distance to the head in metres, when known.

    Returns:
        The result (for one face) or ``{"faces": [...]}`` (for ``"all"``); landmarks in the
        pixels of the image as given on disk.
    """
    from PIL import Image

    from head360cli.fitting.landmarks import find_faces, pick_face
    from head360cli.fitting.shape import ShapeFitter, check_camera, check_focal, default_focal
    from head360cli.io.atomic import atomic_paths
    from head360cli.io.images import load_image
    from head360cli.io.mesh import MeshPart, write_obj
    from head360cli.mesh.arkit52 import ARKIT52
    from head360cli.mesh.bilinear import load_bilinear

    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    if face != "all" and not (str(face).isdigit() or (isinstance(face, int | np.integer)
                                                     and face >= 0)):
        raise BadInputError(f"expected a face number >= 0 or 'all', found {face!r}")
    check_camera(focal, distance)  # before any work
    check_folder_name(out_dir)
    img = load_image(photo)
    check_focal(focal, *img.source_size)
    model = load_bilinear()
    fitter = ShapeFitter(model)
    timings["load"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    faces = find_faces(img.pixels, detector, only=None if face == "all" else int(face))
    if face == "all":
        pick_face(faces, 0, detector, img.pixels)  # raises the no-face error
        chosen = list(enumerate(faces))
    else:
        chosen = [(int(face), pick_face(faces, int(face), detector, img.pixels))]
    timings["detect"] = time.perf_counter() - t0

    full_w, full_h = img.source_size
    scale = img.scale  # loaded pixels per pixel on disk
    f_disk = focal if focal else default_focal(full_w, full_h, img.focal_35mm)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = input_stem(photo)
    results = []
    for index, found in chosen:
        t0 = time.perf_counter()
        fit = fitter.fit(found.landmarks, img.size, focal=f_disk * scale, distance=distance,
                         turn=found.turn)
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
        # the three files are renamed into place together, once all are written (the
        # mesh has no texture, so its temporary name names no material)
        with atomic_paths(paths["mesh"], paths["overlay"], paths["params"]) as (
                tmp_mesh, tmp_overlay, tmp_params):
            write_obj(tmp_mesh, [MeshPart("head", verts, model.faces, model.uv,
                                          model.faces_uv)],
                      comment=f"head360 shape fit of {Path(photo).name}\nmetres, +y up, "
                              "face +z")
            overlay = _overlay(img.pixels, found.landmarks, fit.landmarks_fitted, v2d,
                               model.faces, visible)
            Image.fromarray(overlay).save(tmp_overlay)
            euler = fit.euler_degrees()
            result = {
                "photo": str(photo),
                "face": index,
                "image_size": [full_w, full_h],
                "face_box": [round(c / scale, 2) for c in found.box],
                "face_turn_degrees": found.turn,
                "landmarks_detected": (found.landmarks / scale).round(2).tolist(),
                "landmarks_fitted": (fit.landmarks_fitted / scale).round(2).tolist(),
                "shape": fit.shape.round(6).tolist(),
                "expression": {n: round(float(w), 4) for n, w in zip(ARKIT52, fit.expression,
                                                                      strict=True)},
                "pose": {**{k: round(v, 3) for k, v in euler.items()},
                         "translation": fit.translation.round(5).tolist(),
                         "distance": round(fit.distance(), 5), "focal": round(f_disk, 2)},
                "model": model.meta["sha256"],
                "files": {k: str(v) for k, v in paths.items()},
            }
            t_write = time.perf_counter() - t0
            result["timings"] = {**{k: round(v, 4) for k, v in timings.items()},
                                 "fit": round(t_fit, 4), "write": round(t_write, 4)}
            tmp_params.write_text(dumps(result, indent=1))
        results.append(result)
    return results[0] if face != "all" else {"faces": results}


PREVIEW_YAWS = (-45.0, 45.0, 90.0, 180.0)
"""Yaw of the preview's other views (degrees, + = the subject's left), the back last."""


MIN_FACE_PX = 40
"""Faces narrower than this (pixels of the image as loaded) are refused: too few pixels
to fit a texture to."""

SMALL_FACE_PX = 60
"""Faces narrower than this are fitted with a warning (blurry texture): the fit's 256-pixel
crop shows a face about 90 pixels wide, so such a face is upsampled 1.5 times or more."""

CONFIDENT_FACE = 0.5
"""HOG detector score from which a face counts for the several-faces warning (the
astronaut's mission patch scores 0.12; the faces of dlib's example photos 0.4 to 3)."""

PROFILE_YAW = 40.0
"""Beyond this fitted yaw (degrees) a warning says the head is turned: the far side comes
from the model, and the pose and hairstyle may be off. It is the fit's yaw, which dlib's
landmarks hold to about two thirds of the true one on turned heads (AFLW2000-3D's
annotated 65.6 and -35.7 degrees fit as 42.9 and -24.3), so 40 stands for about 60 in
truth. At 60 the profile image00475 got no warning; at 40, of the other 31 real photos
with a face found in ../shared/data, one warns, a group photo whose largest face is
turned (fitted 48 degrees); the rest fit at 38 degrees or less."""


def _photo_stage(photo: str | Path, face: int, detector: str, focal: float | None,
                 timings: dict[str, float], warnings: list[str] | None = None,
                 distance: float | None = None,
                 on_face: Callable[[Any, Any], None] | None = None):
    """Load, detect and fit the shape; returns ``(image, found face, fit, model)``.

    Warnings for the user (several faces, a small face, a greyscale photo, a profile view)
    are appended to ``warnings``. ``on_face(image, found face)``, when given, is called
    once the face has passed its checks, before the shape fit (the callers start the
    hair parse there, which needs only the photo and its landmarks).

    Raises:
        NoFaceError: No face (by :func:`~head360cli.fitting.landmarks.find_faces`), or
            fewer faces than ``face + 1``.
        BadInputError: A face narrower than :data:`MIN_FACE_PX`.
    """
    from head360cli.errors import BadInputError
    from head360cli.fitting.landmarks import find_faces, pick_face
    from head360cli.fitting.shape import ShapeFitter, check_focal, default_focal
    from head360cli.io.images import load_image
    from head360cli.mesh.bilinear import load_bilinear

    warnings = [] if warnings is None else warnings
    t0 = time.perf_counter()
    img = load_image(photo)
    check_focal(focal, *img.source_size)
    warnings += photo_warnings(img)
    model = load_bilinear()
    timings["load"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    faces = find_faces(img.pixels, detector, only=face)
    timings["detect"] = time.perf_counter() - t0
    found = pick_face(faces, face, detector, img.pixels)
    confident = [f for f in faces if f.score >= CONFIDENT_FACE]
    if len(confident) > 1:
        warnings.append(f"{len(confident)} faces found; fitting face {face} "
                        f"({'the largest' if face == 0 else 'by size'}), choose with --face N")
    width = found.box[2] - found.box[0]
    if width < MIN_FACE_PX:
        raise BadInputError(f"expected a face at least {MIN_FACE_PX} pixels wide, found "
                            f"{width:.0f}: use a larger photo")
    if width < SMALL_FACE_PX:
        warnings.append(f"the face is only {width:.0f} pixels wide: the texture will be "
                        "blurry")
    if _grey_face(img, found):
        warnings.append("greyscale photo: the skin's colour comes from the model, the "
                        "hair's is the named colour nearest its grey")
    if on_face is not None:
        on_face(img, found)
    t0 = time.perf_counter()
    full_w, full_h = img.source_size
    f_disk = focal if focal else default_focal(full_w, full_h, img.focal_35mm)
    fit = ShapeFitter(model).fit(found.landmarks, img.size, focal=f_disk * img.scale,
                                 distance=distance, turn=found.turn)
    timings["shape"] = time.perf_counter() - t0
    yaw = fit.euler_degrees()["yaw"]
    if abs(yaw) > PROFILE_YAW:
        warnings.append(f"profile view (fitted yaw {yaw:.0f} degrees, likely turned further):"
                        " the far side of the face comes from the model, and the pose and "
                        "hairstyle may be off")
    return img, found, fit, model


def photo_warnings(img) -> list[str]:
    """The warnings for a loaded photo: a file of several frames or pages (an animated
    GIF, a TIFF stack), of which only the first is read; a colour profile that could not
    be used, so that its values are taken as sRGB's."""
    warnings = []
    if img.frames > 1:
        warnings.append(f"{Path(img.path).name} holds {img.frames} frames; the first is used")
    if img.colour_profile == "unreadable":
        warnings.append(f"{Path(img.path).name} has a colour profile head360 cannot use; "
                        f"its colours are taken as sRGB")
    return warnings


def prior_missing(learned_prior: bool) -> list[str]:
    """The warning for a parse asked to use the learned hair prior when none is
    installed (it then parses by colour and landmarks alone), else none."""
    from head360cli.paths import models_dir

    name = PRIOR_FILE  # hair_prior.FILE_NAME, named here to leave torch unimported
    if not learned_prior or (models_dir() / name).is_file():
        return []
    return [f"the hair prior is not installed ({name} in the models folder): the hair "
            "is parsed by colour and landmarks alone; 'head360 train-hair-prior' makes it"]


PRIOR_FILE = "hair_prior.pt"
"""The learned hair prior's file in the models folder (:data:`head360cli.fitting.
hair_prior.FILE_NAME`; a test keeps the two equal)."""


def face_to_parse(rgb: np.ndarray, face: int = 0, detector: str = "hog"):
    """The face ``parse-hair`` seeds its parse with: face ``face`` of
    :func:`~head360cli.fitting.landmarks.find_faces` (as ``fit``, but without the second
    search at twice the size); ``None`` when there is none (the photo is parsed without
    a face).

    Raises:
        NoFaceError: ``face`` > 0 and there are not that many faces.
    """
    from head360cli.fitting.landmarks import find_faces, pick_face

    # no search at twice the size: parse-hair reads hair photos, whose faces are large
    faces = find_faces(rgb, detector, only=face, small=False)
    if not faces and not face:
        return None
    return pick_face(faces, face, detector)


def parse_photo(photo: str | Path, out_dir: str | Path, *, face: int = 0,
                detector: str = "hog", learned_prior: bool = True) -> dict[str, Any]:
    """``head360 parse-hair``: hair and face masks of a photo (PNG, 255 inside, at the
    photo's size on disk) and an overlay (hair red, face blue).

    A photo without a detectable face (:func:`face_to_parse`) is parsed without
    landmarks (``"seeded": false``, ``"face_detector": null``; else the detector that
    found it, ``hog`` or ``cnn``, and ``face_turn_degrees``); ``"profile_face"`` says
    whether such a photo showed a face in profile, whose skin is then its face mask.
    ``learned_prior=False`` parses by colour and landmarks alone (no hair-prior network).
    """
    import cv2
    from PIL import Image

    from head360cli.fitting.hair_parse import MIN_SIDE, parse_hair
    from head360cli.io.atomic import atomic_paths, check_file_target, check_name_length
    from head360cli.io.images import MAX_SIDE, load_image

    check_folder_name(out_dir)
    out, stem = Path(out_dir), input_stem(photo)
    paths = {"hair_mask": out / f"{stem}_hair.png", "face_mask": out / f"{stem}_face.png",
             "overlay": out / f"{stem}_parse.png"}
    for target in paths.values():  # names too long, read-only files, pipes: before the work
        if out.is_dir():
            check_file_target(target)
        else:
            check_name_length(target)
    t0 = time.perf_counter()
    img = load_image(photo)
    if min(img.pixels.shape[:2]) < MIN_SIDE and img.size != tuple(img.source_size):  # as on disk
        (w, h), (lw, lh) = img.source_size, img.size
        raise BadInputError(f"expected a photo at least {MIN_SIDE}x{MIN_SIDE} pixels to parse "
                            f"hair, found {w}x{h} ({lw}x{lh} once its longer side is brought "
                            f"to {MAX_SIDE})")
    found = face_to_parse(img.pixels, face, detector)
    landmarks = None if found is None else found.landmarks
    found_by = None if found is None else found.detector
    parse = parse_hair(img.pixels, landmarks, prior="learned" if learned_prior else None)
    w, h = img.source_size
    out.mkdir(parents=True, exist_ok=True)
    overlay = img.pixels.astype(np.float32)
    overlay[parse.hair] = 0.45 * overlay[parse.hair] + 0.55 * np.array([235, 40, 40])
    overlay[parse.face] = 0.6 * overlay[parse.face] + 0.4 * np.array([40, 90, 235])
    # the three files are renamed into place together, once all are written
    with atomic_paths(paths["hair_mask"], paths["face_mask"], paths["overlay"]) as tmps:
        for tmp, mask in zip(tmps[:2], (parse.hair, parse.face), strict=True):
            full = cv2.resize(mask.astype(np.uint8) * 255, (w, h),
                              interpolation=cv2.INTER_NEAREST) if (w, h) != img.size else \
                mask.astype(np.uint8) * 255
            Image.fromarray(full).save(tmp)
        Image.fromarray(overlay.round().astype(np.uint8)).save(tmps[2])
    return {"photo": str(photo), "seeded": parse.seeded, "face_detector": found_by,
            "warnings": photo_warnings(img) + prior_missing(learned_prior),
            "face_turn_degrees": None if found is None else found.turn,
            "profile_face": parse.profile, "learned_prior": parse.prior,
            "hair_fraction": round(float(parse.hair.mean()), 4),
            "face_fraction": round(float(parse.face.mean()), 4),
            "seconds": round(time.perf_counter() - t0, 3),
            **{k: str(v) for k, v in paths.items()}}


def _aligned(img, fit, model, res: int):
    """Camera, crop and meshes of a shape fit: ``(c2w, K, affine, crop, posed, neutral)``."""
    from head360cli.fitting.texture import crop_image, photo_camera

    c2w, k, affine = photo_camera(fit.rotation, fit.translation, fit.focal, fit.centre, res)
    crop = crop_image(img.pixels, affine, res)
    posed = model.vertices(fit.shape, fit.expression)
    neutral = model.vertices(fit.shape, np.zeros(52))
    return c2w, k, affine, crop, posed, neutral


INNER_EYES = np.isin(np.arange(17, 68), np.arange(36, 48))
"""``(51,)`` bool: the eyes (iBUG 36-47) among :func:`_inner_landmarks`' points, which
the inversion's camera refinement holds closer than the rest
(:attr:`~head360cli.fitting.texture.InvertConfig.held_slack`)."""


def _inner_landmarks(model, posed: np.ndarray, detected: np.ndarray, affine: np.ndarray,
                     device) -> tuple:
    """The inner-face landmarks (17-67: brows, nose, eyes, mouth; not the jaw contour,
    which slides with the view) as ``(points on the posed mesh (51, 3), detected pixels
    in the crop (51, 2))``, the anchors of the inversion's camera refinement."""
    import torch

    points = model.landmark_points(posed)[17:]
    pixels = detected[17:] @ affine[:, :2].T + affine[:, 2]
    return (torch.tensor(points, dtype=torch.float32, device=device),
            torch.tensor(pixels, dtype=torch.float32, device=device))


def _outside_body(landmarks: np.ndarray, affine: np.ndarray, res: int) -> np.ndarray:
    """``(res, res)`` bool: the crop (``affine`` from the photo) without the strip below
    the chin that a body hides (:func:`~head360cli.fitting.hair_class.hidden_by_body`),
    from the detected ``landmarks (68, 2)``: where a hairstyle's silhouette is scored."""
    from head360cli.fitting.hair_class import hidden_by_body

    return ~hidden_by_body(landmarks @ affine[:, :2].T + affine[:, 2], (res, res))


CLASSIFY_RES = 128
"""Side in pixels of the crop the hairstyles' silhouettes are compared in."""


def _silhouettes(img, fit, model, res: int = CLASSIFY_RES) -> np.ndarray:
    """``(30, res, res)`` the hairstyles' silhouettes on the fitted head, seen from the
    photo's camera in its ``res``-pixel crop (they do not need the parse)."""
    from head360cli.fitting.hair_class import style_silhouettes

    c2w, k, _, _, posed, neutral = _aligned(img, fit, model, res)
    return style_silhouettes(neutral, posed, model.faces, c2w, k, res)


def _hair_guess(img, parse, fit, model, landmarks: np.ndarray,
                silhouettes: np.ndarray | None = None, res: int = CLASSIFY_RES):
    """Hairstyle ranking and hair colour of a parsed photo with its detected
    ``landmarks (68, 2)`` (and the styles' ``silhouettes`` when already made by
    :func:`_silhouettes`): ``(guess, colour estimate, nearest corpus colour name, its
    RGB)``."""
    from head360cli.fitting.hair_class import (
        HAIR_AREA_CM2,
        classify_hair,
        hair_colour,
        nearest_colour_name,
    )
    from head360cli.fitting.texture import crop_mask, photo_camera
    from head360cli.synth.hair import HAIR_COLOURS

    # the crop's affine only (no crop image or meshes: the silhouettes have them)
    affine = photo_camera(fit.rotation, fit.translation, fit.focal, fit.centre, res)[2]
    hair = crop_mask(parse.hair, affine, res)
    valid = crop_mask(np.ones(img.pixels.shape[:2], bool), affine, res)
    valid &= _outside_body(landmarks, affine, res)
    if silhouettes is None:
        silhouettes = _silhouettes(img, fit, model, res)
    guess = classify_hair(hair, silhouettes, valid, crop_mask(parse.face, affine, res),
                          HAIR_AREA_CM2)
    estimate = hair_colour(img.pixels, parse.hair)
    # The hair branch learnt the corpus' named colours: the head wears the nearest one.
    name = nearest_colour_name(estimate)
    return guess, estimate, name, np.asarray(HAIR_COLOURS[name], np.float32)


COLOUR_RENDER_SIZE = 128
"""Image size of the renders that compare candidate hair colours with the photo."""

COLOUR_CANDIDATES = 3
"""How many SynHead-P colours, nearest the tone curve's estimate first, are rendered and
compared with the photo. All 10 (0.8 s a fit instead of 0.2) named the same colours on 5
held-out synthetic heads of corpus seed 1 (all 5 right) and scored within 0.05 dB of 3 on
`bench fit`'s real photos, so the neighbours of the estimate are enough."""


def _colour_by_render(gen, verts, cam, k, code, neutral: np.ndarray, style: int,
                      crop: np.ndarray, hair: np.ndarray, estimate: np.ndarray,
                      gain=None) -> tuple[str, np.ndarray, str]:
    """The hair colour the fitted head wears: of the :data:`COLOUR_CANDIDATES` SynHead-P
    colours nearest the tone curve's ``estimate``, the one whose render in ``style`` from
    the photo's camera (``cam (4, 4)``, ``k (3, 3)`` for ``crop``) differs least from the
    photo's hair pixels (``crop (R, R, 3)`` uint8, ``hair (R, R)`` bool): ``(name, linear
    RGB, "render" or "tone curve")``. The generator renders a named colour close to, but
    not exactly as, the corpus renderer whose look the tone curve was fitted to. With
    ``gain (3,)`` (the photo's light, a tensor) the renders are drawn under it."""
    import dataclasses

    import cv2
    import torch

    from head360cli.fitting.hair_class import nearest_colour_names, pick_colour_by_render
    from head360cli.model.generator import hair_for
    from head360cli.model.render import lit
    from head360cli.synth.hair import HAIR_COLOURS

    size = COLOUR_RENDER_SIZE
    small_k = k.clone()
    small_k[:2] *= size / crop.shape[0]
    photo = cv2.resize(crop, (size, size), interpolation=cv2.INTER_AREA) / 255.0
    small_hair = cv2.resize(hair.astype(np.uint8), (size, size),
                            interpolation=cv2.INTER_NEAREST) > 0

    with torch.no_grad():
        texture = gen.texture(code[None])  # the same head under every candidate
    # the same hair mesh too: fitted to the head once, each candidate only recoloured
    shape = hair_for(neutral, [style], np.asarray(estimate, np.float32)[None]).to(verts.device)

    def render(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h = gen.prepare_hair(dataclasses.replace(shape, colour=torch.as_tensor(
            np.asarray(rgb, np.float32)[None], device=verts.device)))
        with torch.no_grad(), gen.image_size(size):
            out = gen(verts[None], cam[None], small_k[None], texture=texture, hair=h)
        rgb = out["rgb"].clamp(0, 1)
        if gain is not None:
            rgb = lit(rgb, out["alpha"], gain.to(rgb)).clamp(0, 1)
        return (rgb[0].permute(1, 2, 0).cpu().numpy(),
                out["hair_alpha"][0, 0].cpu().numpy() > 0.5)

    candidates = nearest_colour_names(estimate, COLOUR_CANDIDATES)
    name, scores = pick_colour_by_render(render, photo, small_hair, candidates)
    return (name, np.asarray(HAIR_COLOURS[name], np.float32),
            "render" if scores else "tone curve")


def classify_photo(photo: str | Path, *, face: int = 0, detector: str = "hog",
                   focal: float | None = None, top: int = 3,
                   learned_prior: bool = True) -> dict[str, Any]:
    """``head360 classify-hair``: the ``top`` SynHead-P hairstyles for a photo's hair, and
    its hair colour (``learned_prior=False``: the hair parsed without the learned prior)."""
    from head360cli.fitting.hair_parse import parse_hair

    timings: dict[str, float] = {}
    with ThreadPoolExecutor(max_workers=1) as pool:  # the parse beside the shape fit
        jobs = []

        def start_parse(img, found) -> None:
            jobs.append(pool.submit(_timed, parse_hair, img.pixels, found.landmarks,
                                    prior="learned" if learned_prior else None))

        warnings: list[str] = []
        img, found, fit, model = _photo_stage(photo, face, detector, focal, timings,
                                              warnings, on_face=start_parse)
        parse, timings["parse"] = jobs[0].result()
    t0 = time.perf_counter()
    guess, estimate, name, colour = _hair_guess(img, parse, fit, model, found.landmarks)
    timings["classify"] = time.perf_counter() - t0
    return {"photo": str(photo), "top": guess.top(top),
            "warnings": warnings + prior_missing(learned_prior),
            # False: no style overlaps the parsed hair enough (ranked as no hair)
            "hair_matches_a_style": guess.matched,
            "hair_color": [round(float(c), 4) for c in colour],
            "hair_color_name": name,
            # head360 fit checks the nearest colours by rendering the fitted head
            "hair_color_chosen_by": "tone curve",
            "hair_color_estimate": [round(float(c), 4) for c in estimate],
            "timings": {k: round(v, 4) for k, v in timings.items()}}


FIT_SUMMARY_KEYS = ("photo", "preset", "timings", "files")
"""Keys every ``head360 fit`` JSON summary has: a ``<stem>.json`` with them is a summary
an earlier fit wrote, which a new fit may replace."""


def fit_outputs(out: str | Path) -> dict[str, Path]:
    """The files a fit to head file ``out`` writes: ``head`` (``out``), ``preview``
    (``<stem>_preview.png``) and ``summary`` (``<stem>.json``)."""
    out = Path(out)
    stem = out.with_suffix("")
    return {"head": out, "preview": Path(f"{stem}_preview.png"),
            "summary": Path(f"{stem}.json")}


def check_fit_outputs(photo: Any, out: str | Path) -> None:
    """Refuse a fit whose outputs would replace its own photo, a ``<stem>_preview.png``
    head360 did not write, or a ``<stem>.json`` that an earlier fit did not write (a
    LabelMe annotation beside ``photo.jpg``, say): each would be lost without a word.
    An empty file holds nothing to lose and is replaced (the shell's, for ``head360
    --json fit photo.jpg -o me.h360 > me.json``).

    Raises:
        BadInputError: Either, naming the file and how to avoid it.
    """
    import os

    from head360cli.io.atomic import empty_file
    from head360cli.io.images import check_companion_png

    paths = fit_outputs(out)
    if isinstance(photo, str | os.PathLike) and Path(photo).is_file():
        for what, path in paths.items():
            if path.exists() and os.path.samefile(path, photo):
                raise BadInputError(f"expected outputs other than the photo, found the "
                                    f"{what} {str(path)!r} would replace it: give -o "
                                    f"another name")
    summary, found = paths["summary"], None
    if summary.exists() and not empty_file(summary):  # empty: ``--json > me.json``'s
        try:
            found = json.loads(summary.read_text(encoding="utf-8"))
        except (OSError, ValueError):  # unreadable, not UTF-8 or not JSON
            found = None
        if not (isinstance(found, dict) and all(k in found for k in FIT_SUMMARY_KEYS)):
            raise BadInputError(f"expected {str(summary)!r} to be an earlier fit's summary "
                                f"before replacing it, found another file: move it or give "
                                f"-o another name")
    # A preview an earlier fit wrote is named in its summary (versions before the PNG
    # mark included); any other picture of that name is refused.
    listed = found["files"].get("preview") if isinstance(found, dict) and isinstance(
        found.get("files"), dict) else None
    if not (listed and Path(listed).name == paths["preview"].name):
        check_companion_png(paths["preview"], "preview")


def fit_photo(photo: str | Path, out: str | Path, *, preset: str = "fast", face: int = 0,
              detector: str = "hog", focal: float | None = None, device: str = "cpu",
              hair_style: int | None = None, distance: float | None = None,
              progress: Any = None, learned_prior: bool = True,
              hair_placement: bool = True, closed_lids: bool = True,
              own_folder: bool = False) -> dict[str, Any]:
    """``head360 fit``: every stage, from a photo to a head file.

    Stages: detection and shape fit; hair parsing; hairstyle classification and hair
    colour; the bald target (hair replaced by the model's bald render, Poisson-blended);
    neural-texture inversion; closed lids (a texture change that the blinks bring in, so
    closed eyes show a lid: :func:`~head360cli.fitting.lids.close_lids`); hair placement
    (the style's mesh shifted to match the parsed hair from the fitted camera); preview.
    The parse runs in a second thread from the moment the landmarks are found, while the
    shape is fitted, the generator loaded, and the hairstyles' silhouettes, the
    inversion's mirror grid and the bald render of the starting code are made, so the
    summary's stage times add up to more than its total by that overlap. Writes ``out``
    (``.h360``), ``<out stem>_preview.png`` (photo crop | fitted front | three other
    views | back) and ``<out stem>.json``.

    Args:
        photo: The image.
        out: Head file path.
        preset: ``fast`` or ``quality`` (:data:`head360cli.fitting.texture.PRESETS`).
        face: Face number (0 = largest).
        detector: ``hog`` (for photos up to 2000 pixels, again at twice the size when
            it finds none), ``cnn``, or ``auto``: ``hog``, then the CNN detector on a
            copy at most ``FALLBACK_SIDE`` pixels long (not the default: see
            :mod:`head360cli.fitting.landmarks`).
        focal: Focal length in pixels of the photo on disk (default: EXIF or 50 mm).
        device: Torch device for the generator.
        hair_style: Force a hairstyle id instead of the classifier's choice.
        distance: The camera's distance to the head in metres, when known (fixes the
            head's size; see :meth:`~head360cli.fitting.shape.ShapeFitter.fit`).
        progress: Callable ``(stage, step, total)`` for progress display.
        learned_prior: Parse the hair with the learned hair prior (when installed).
        hair_placement: Shift the hairstyle's mesh to the parsed hair
            (:func:`~head360cli.fitting.hair_class.place_hair`); ``False`` leaves it
            where the style's fit to the head puts it.
        closed_lids: Fit the texture change that closed eyes show as a lid (stored in
            the head file as ``lid_index``/``lid_change``); ``False``: none.
        own_folder: The outputs' folder is the caller's own (``head360 demo``'s): skip
            :func:`check_fit_outputs`, which keeps a fit from replacing other programs'
            files beside the photo.

    Returns:
        The JSON summary (also written to ``<out stem>.json``).
    """
    import torch
    from PIL import Image

    from head360cli.errors import BadInputError
    from head360cli.fitting.hair_parse import parse_hair
    from head360cli.fitting.landmarks import mouth_opening
    from head360cli.fitting.shape import check_camera
    from head360cli.fitting.texture import (
        LUMA,
        PRESETS,
        bald_target,
        crop_mask,
        invert_texture,
        mirror_grid,
        region_texels,
    )
    from head360cli.io.atomic import atomic_paths, check_file_target
    from head360cli.io.headfile import HeadFile, lid_change_arrays, write_head
    from head360cli.io.images import png_info
    from head360cli.model.head_render import HeadRenderer, to_uint8
    from head360cli.model.train import load_generator
    from head360cli.synth.hair import HAIRSTYLES

    if preset not in PRESETS:
        raise BadInputError(f"expected preset {' or '.join(PRESETS)}, found {preset!r}")
    check_camera(focal, distance)  # before any work
    out = Path(out)
    if out.suffix.lower() != ".h360":
        raise BadInputError(f"expected an output name ending in .h360, found {str(out)!r}")
    for target in fit_outputs(out).values():  # the preview and summary too: before the fit
        check_file_target(target)
    if not own_folder:
        check_fit_outputs(photo, out)
    if hair_style is not None and not 0 <= hair_style < len(HAIRSTYLES):
        raise BadInputError(f"expected a hairstyle id 0..{len(HAIRSTYLES) - 1}, found "
                            f"{hair_style}")
    say = progress or (lambda *a: None)
    timings: dict[str, float] = {}
    warnings: list[str] = []
    t_all = time.perf_counter()
    say("shape", 0, 1)
    with ThreadPoolExecutor(max_workers=1) as pool:
        # GrabCut lets go of the interpreter: the parse runs on one core from the moment
        # the landmarks are found, while this thread makes what does not need it: the
        # shape fit, the generator, the hairstyles' silhouettes, the inversion's mirror
        # grid, and the bald render of the starting code that the bald target fills the
        # hair from (the stages' times overlap by as much)
        jobs = []

        def start_parse(img, found) -> None:
            jobs.append(pool.submit(_timed, parse_hair, img.pixels, found.landmarks,
                                    prior="learned" if learned_prior else None))

        img, found, fit, model = _photo_stage(photo, face, detector, focal, timings,
                                              warnings, distance, on_face=start_parse)
        t0 = time.perf_counter()
        gen, codes = load_generator(device=device)
        res = gen.cfg.image_res
        timings["load"] += time.perf_counter() - t0
        say("parse", 0, 1)
        dev = torch.device(device)
        t0 = time.perf_counter()
        silhouettes = _silhouettes(img, fit, model)
        classify_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        mirror_grid(gen.cfg.texture_res)
        mirror_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        c2w, k, affine, crop, posed, neutral = _aligned(img, fit, model, res)
        verts = torch.tensor(posed, dtype=torch.float32, device=dev)
        cam = torch.tensor(c2w, device=dev)
        kk = torch.tensor(k, device=dev)
        start = codes.mean(0)
        with torch.no_grad():
            first = gen(verts[None], cam[None], kk[None], code=start[None])
        first_s = time.perf_counter() - t0
        parse, timings["parse"] = jobs[0].result()
    t0 = time.perf_counter()
    guess, estimate, colour_name, colour = _hair_guess(img, parse, fit, model,
                                                       found.landmarks, silhouettes)
    style = guess.ranking[0] if hair_style is None else int(hair_style)
    warnings += prior_missing(learned_prior)
    if hair_style is None and not guess.matched:
        warnings.append(f"the parsed hair matches no hairstyle (best overlap "
                        f"{guess.iou.max():.3f}): fitted bald; choose a style with --hair")
    timings["classify"] = classify_s + time.perf_counter() - t0

    t0 = time.perf_counter()
    hair_crop = crop_mask(parse.hair, affine, res)
    face_crop = crop_mask(parse.face, affine, res)
    target = bald_target(crop, hair_crop, to_uint8(first["rgb"])[0])
    alpha = first["alpha"][0, 0].cpu().numpy() > 0.5
    weight = face_crop & alpha
    if weight.sum() < 50:
        raise BadInputError("expected a visible face region to fit the texture to, found "
                            f"{int(weight.sum())} pixels (is the face covered?)")
    valid = crop_mask(np.ones(img.pixels.shape[:2], bool), affine, res)
    mask = weight.astype(np.float32) + 0.25 * (alpha & ~weight & ~hair_crop & valid)
    timings["bald_target"] = first_s + time.perf_counter() - t0
    cfg = PRESETS[preset]
    if _grey_face(img, found):  # no light's colour, no skin's: its grey is fitted
        cfg = dataclasses.replace(cfg, gain=False, grey=True)
    # lips closed or nearly: the inside of the mouth keeps the generated texture
    lips = mouth_opening(found.landmarks)  # NaN for eye corners on one point: not closed
    keep = region_texels(gen.cfg.texture_res).to(dev) if lips < cfg.closed_mouth else None
    inv = invert_texture(
        gen, verts, cam, kk,
        torch.tensor(target, dtype=torch.float32, device=dev).permute(2, 0, 1) / 255.0,
        torch.tensor(mask, device=dev)[None], start, cfg,
        progress=lambda s, n, loss: say("texture", s, n),
        landmarks=_inner_landmarks(model, posed, found.landmarks, affine, dev),
        held=torch.as_tensor(INNER_EYES, device=dev), keep=keep)
    timings["invert"] = inv.seconds + mirror_s  # its mirror grid was made beside the parse

    # The hair's colour as it would look under white light: the photo's pixels without the
    # light the inversion found, and the candidates rendered under it (timed with the
    # classification, which it completes).
    t0 = time.perf_counter()
    colour_by = "tone curve"
    if inv.gain is not None:
        from head360cli.fitting.hair_class import hair_colour, nearest_colour_name
        from head360cli.synth.hair import HAIR_COLOURS

        # the hair pixels only: a 4096-pixel photo as float64 would take 400 MB
        gain = inv.gain.cpu().numpy().astype(np.float64)
        unlit = np.clip(img.pixels[parse.hair] / gain, 0, 255).round().astype(np.uint8)
        estimate = hair_colour(unlit[None], np.ones((1, len(unlit)), bool))
        colour_name = nearest_colour_name(estimate)
        colour = np.asarray(HAIR_COLOURS[colour_name], np.float32)
    if style != 0:
        colour_name, colour, colour_by = _colour_by_render(
            gen, verts, cam, kk, start, neutral, style, crop, hair_crop, estimate, inv.gain)
    timings["classify"] += time.perf_counter() - t0
    lids = None
    if closed_lids:
        from head360cli.fitting.lids import head_lids

        say("lids", 0, 1)
        lids = head_lids(gen, model, fit.shape, inv.texture)
    timings["lids"] = 0.0 if lids is None else lids.seconds

    t0 = time.perf_counter()
    offset, placed_iou, plain_iou = np.zeros(3), None, None
    if style != 0 and hair_placement:
        from head360cli.fitting.hair_class import place_hair

        offset, placed_iou, plain_iou = place_hair(
            neutral, posed, model.faces, inv.c2w.cpu().numpy(), k, style, hair_crop,
            valid & _outside_body(found.landmarks, affine, res),
            face=face_crop)
    timings["hair_placement"] = time.perf_counter() - t0

    say("preview", 0, 1)
    t0 = time.perf_counter()
    head = HeadRenderer(gen, fit.shape, inv.texture, style, colour, fit.expression,
                        samples=cfg.preview_samples, precision="fp32", hair_offset=offset,
                        lid_change=None if lids is None else lids.change,
                        colour_gain=inv.gain)
    from head360cli.geometry.cameras import RIG_DISTANCE, camera_on_sphere

    others = camera_on_sphere(torch.tensor(PREVIEW_YAWS), torch.zeros(len(PREVIEW_YAWS)),
                              RIG_DISTANCE)
    rig_k = _rig_intrinsics(res)
    front = to_uint8(head.render(inv.c2w[None], kk))[0]
    views = to_uint8(head.render(others, rig_k, expression=np.zeros(52)))
    # With its hair, as the user will see it: hair over the forehead counts as error.
    # A grey photo is compared in grey, the values it has (its colour is the model's).
    seen = (lambda x: x.astype(np.float64) @ np.array(LUMA)) if cfg.grey else (lambda x: x)
    psnr_face = _masked_psnr(seen(front), seen(crop), weight)
    # Bald, as the inversion saw it: the texture alone.
    bald = to_uint8(head.render(inv.c2w[None], kk, hair=False))[0]
    psnr_bald = _masked_psnr(seen(bald), seen(crop), weight)
    timings["preview"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    paths = fit_outputs(out)
    model_hash = generator_hash()
    head_file = HeadFile(
        arrays={"shape": fit.shape.astype(np.float32),
                "expression": fit.expression.astype(np.float32),
                "pose": inv.c2w.cpu().numpy().astype(np.float32), "intrinsics": k,
                "texture": inv.texture.cpu().numpy().astype(np.float32),
                "texture_code": inv.code.cpu().numpy().astype(np.float32),
                "hair_style": np.array(style, np.int64),
                "hair_color": colour.astype(np.float32),
                "hair_offset": offset.astype(np.float32),
                "vertices": neutral.astype(np.float32),
                **({} if lids is None else lid_change_arrays(lids.change.cpu().numpy())),
                **({} if inv.gain is None else
                   {"colour_gain": inv.gain.cpu().numpy().astype(np.float32)})},
        model_hash=model_hash,
        info={"photo": Path(photo).name, "preset": preset, "face": face,
              "hair_style_name": HAIRSTYLES[style].name,
              "bilinear_model": model.meta["sha256"]})
    sheet = np.concatenate([crop, front, *views], 1)
    # The head file, its preview and its summary are renamed into place together once all
    # three are written, so a full disk leaves an earlier fit's set as it was.
    with atomic_paths(paths["head"], paths["preview"], paths["summary"]) as (
            tmp_head, tmp_preview, tmp_summary):
        write_head(head_file, tmp_head)
        Image.fromarray(sheet).save(tmp_preview, format="PNG", pnginfo=png_info())
        timings["write"] = time.perf_counter() - t0
        timings["total"] = time.perf_counter() - t_all
        euler = fit.euler_degrees()
        summary = {
            "photo": str(photo), "preset": preset, "face": face,
            "pose": {**{k_: round(v, 2) for k_, v in euler.items()},
                     "distance": round(fit.distance(), 4)},
            "hair_style": {"id": style, "name": HAIRSTYLES[style].name,
                           "chosen_by": "classifier" if hair_style is None else "user",
                           # the placement: mm up and forward, and its silhouette's IoU
                           # with the parsed hair before and after
                           "offset_mm": {"up": round(float(offset[1]) * 1e3, 1),
                                         "forward": round(float(offset[2]) * 1e3, 1)},
                           "iou_unplaced": None if plain_iou is None else round(plain_iou, 4),
                           "iou_placed": None if placed_iou is None else round(placed_iou, 4)},
            "hair_candidates": guess.top(3),
            "hair_color": [round(float(c), 4) for c in colour],
            "hair_color_name": colour_name,
            "hair_color_chosen_by": colour_by,
            "hair_color_estimate": [round(float(c), 4) for c in estimate],
            "hair_parse": {"seeded": parse.seeded,
                           "learned_prior": parse.prior,
                           "hair_fraction": round(float(parse.hair.mean()), 4)},
            "inversion": {"steps": inv.steps, "loss_first": round(inv.losses[0], 5),
                          "loss_last": round(inv.losses[-1], 5),
                          # the lips' gap, and whether the mouth's inside was fitted
                          "mouth_opening": round(lips, 4) if np.isfinite(lips) else None,
                          "mouth_inside": "generated" if keep is not None else "fitted",
                          # a grey photo's grey is fitted; the colour is the model's
                          "fitted_in": "grey" if cfg.grey else "colour"},
            # the photo's light: the gain per channel on the head's pixels in every render
            "light": None if inv.gain is None else [round(float(g), 4) for g in inv.gain],
            "closed_lids": None if lids is None else {
                "loss_first": round(lids.loss_first, 5), "loss_last": round(lids.loss_last, 5),
                "texels": lids.texels},
            "psnr_face_input_view": round(psnr_face, 2),
            "psnr_face_input_view_bald": round(psnr_bald, 2),
            "image_size": list(img.source_size),
            "face_width": round(float(found.box[2] - found.box[0]) / img.scale, 1),
            "face_detector": found.detector,
            "face_turn_degrees": found.turn,
            "warnings": warnings,
            "device": str(dev),  # where the generator ran: the timings depend on it
            "timings": {k_: round(v, 3) for k_, v in timings.items()},
            "files": {k_: str(v) for k_, v in paths.items()},
        }
        tmp_summary.write_text(dumps(summary, indent=1))
    return summary


def _rig_intrinsics(res: int):
    from head360cli.geometry.cameras import RIG_FOV_DEG, intrinsics_from_fov

    return intrinsics_from_fov(RIG_FOV_DEG, res, res)


def _grey_face(img, found) -> bool:
    """Whether the photo (a :class:`~head360cli.io.images.LoadedImage`) is greyscale and
    so is the found face's box in it (:func:`~head360cli.io.images.is_greyscale`): a
    small face in a photo of grey and black and white is under 1 % of its pixels."""
    from head360cli.io.images import is_greyscale

    if not img.greyscale:
        return False
    h, w = img.pixels.shape[:2]
    x0, y0, x1, y1 = (int(np.rint(c)) for c in found.box)
    box = img.pixels[max(0, y0):min(h, y1), max(0, x0):min(w, x1), :3]
    return box.size == 0 or is_greyscale(box)


def _masked_psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    """PSNR in dB of images of values 0 to 255 (``(H, W[, 3])``) inside a boolean mask
    ``(H, W)``."""
    d = (a.astype(np.float64) - b.astype(np.float64))[mask] / 255.0
    mse = float(np.mean(d ** 2)) if d.size else 0.0
    return 10 * np.log10(1.0 / max(mse, 1e-10))


def generator_hash() -> str:
    """SHA-256 of the installed generator's weights, which head files record.

    Raises:
        ModelNotFoundError: No weights installed (as :func:`load_generator` says).
    """
    import hashlib

    from head360cli.paths import installed_generator

    return hashlib.sha256(installed_generator().read_bytes()).hexdigest()


def check_head_sizes(arrays: dict[str, np.ndarray], cfg, where: str) -> None:
    """Refuse a head whose arrays do not fit the installed model and generator ``cfg``
    (a :class:`~head360cli.model.config.GeneratorConfig`): a file edited or written by
    other code (a short ``expression`` had ended in an internal error).

    Raises:
        FileFormatError: An array of :data:`~head360cli.io.headfile.HEAD_ARRAYS` has
            another shape than the model's, the optional ``hair_offset`` or
            ``colour_gain`` is not 3 numbers, or the light's gain is not positive.
    """
    from head360cli.errors import FileFormatError
    from head360cli.mesh.bilinear import load_bilinear

    want = {"shape": (load_bilinear().rank,), "expression": (52,),
            "texture": (cfg.texture_channels, cfg.texture_res, cfg.texture_res),
            "hair_color": (3,), "hair_style": ()}
    for name, shape in want.items():
        found = tuple(np.shape(arrays[name]))
        if found != shape:
            raise FileFormatError(f"{where}: expected {name} of shape {shape} for the "
                                  f"installed model, found {found}")
    for name in ("hair_offset", "colour_gain"):
        if name in arrays and tuple(np.shape(arrays[name])) != (3,):
            raise FileFormatError(f"{where}: expected {name} of 3 numbers, found shape "
                                  f"{tuple(np.shape(arrays[name]))}")
    if "colour_gain" in arrays and not (np.asarray(arrays["colour_gain"]) > 0).all():
        raise FileFormatError(f"{where}: expected a colour_gain above 0 in every channel, "
                              f"found {np.asarray(arrays['colour_gain']).tolist()}")


def load_head_renderer(path: str | Path, device: str = "cpu", samples: int | None = None,
                       size: int | None = None, precision: str = "auto",
                       reuse: float | str | None = "default"):
    """A :class:`~head360cli.model.head_render.HeadRenderer` for a head file made with the
    installed generator (``samples`` per ray and image ``size``: default the generator's;
    ``precision`` and ``reuse`` as the renderer's, ``"default"``: its default).

    Raises:
        ModelMismatchError: The file was made with another generator.
    """
    import torch

    from head360cli.io.headfile import HEAD_ARRAYS, lid_change_of, read_head
    from head360cli.model.head_render import REUSE_TOL, HeadRenderer
    from head360cli.model.train import load_generator

    head = read_head(path, expected_model_hash=generator_hash(), required=HEAD_ARRAYS)
    gen, _ = load_generator(device=device)
    a = head.arrays
    check_head_sizes(a, gen.cfg, f"head file {str(path)!r}")
    return HeadRenderer(gen, a["shape"], torch.as_tensor(a["texture"]), int(a["hair_style"]),
                        a["hair_color"], a["expression"], samples=samples, size=size,
                        precision=precision,
                        reuse=REUSE_TOL if isinstance(reuse, str) else reuse,
                        hair_offset=a.get("hair_offset"), lid_change=lid_change_of(a),
                        colour_gain=a.get("colour_gain"))


def run_demo(out_dir: str | Path, preset: str = "fast", frames: int = 48,
             device: str = "cpu", progress: Any = None) -> dict[str, Any]:
    """``head360 demo``: fit scikit-image's astronaut photo and render a turntable."""
    from PIL import Image
    from skimage import data

    from head360cli.io.atomic import atomic_path

    check_folder_name(out_dir)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    photo = out / "astronaut.png"
    with atomic_path(photo) as tmp:
        Image.fromarray(data.astronaut()).save(tmp)
    fit = fit_photo(photo, out / "astronaut.h360", preset=preset, device=device,
                    progress=progress, own_folder=True)  # every file in it is the demo's
    from head360cli.drive.views import write_turntable

    renderer = load_head_renderer(out / "astronaut.h360", device)
    turn = write_turntable(renderer, out / "turntable.mp4", frames, progress=progress)
    return {"fit": fit, "turntable": str(turn)}

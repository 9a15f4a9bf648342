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

from head360cli.errors import BadInputError, ModelMismatchError
from head360cli.fitting.config import FitConfig
from head360cli.io.atomic import check_folder_name
from head360cli.io.jsontext import dumps
from head360cli.io.sources import input_stem
from head360cli.paths import generator_hash

__all__ = ["FIT_SUMMARY_KEYS", "FitConfig", "FitSummary", "check_fit_outputs",
           "check_head_sizes", "classify_photo", "fit_outputs", "fit_photo",
           "fit_shape_photo", "load_head_renderer", "parse_photo", "run_demo"]


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
                    detector: str = "auto", focal: float | None = None,
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
    from head360cli.fitting.shape import check_camera, check_focal, default_focal
    from head360cli.fitting.stages import fit_face
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
        fit = fit_face(model, found, img.size, f_disk * scale, distance)
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
                "landmarks_3d": (fit.landmarks_3d(model) / scale).round(2).tolist(),
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


def face_to_parse(rgb: np.ndarray, face: int = 0, detector: str = "auto"):
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
                detector: str = "auto", learned_prior: bool = True,
                hair_parser: str = "segmenter") -> dict[str, Any]:
    """``head360 parse-hair``: hair and face masks of a photo (PNG, 255 inside, at the
    photo's size on disk) and an overlay (hair red, face blue).

    A photo without a detectable face (:func:`face_to_parse`) is parsed without
    landmarks (``"seeded": false``, ``"face_detector": null``; else the detector that
    found it, ``hog`` or ``cnn``, and ``face_turn_degrees``); ``"profile_face"`` says
    whether such a photo showed a face in profile, whose skin is then its face mask.
    ``hair_parser`` is :func:`~head360cli.fitting.hair_parse.parse_hair`'s method; with
    ``grabcut``, ``learned_prior=False`` parses by colour and landmarks alone.
    """
    import cv2
    from PIL import Image

    from head360cli.fitting.hair_parse import MIN_SIDE, parse_hair
    from head360cli.fitting.stages import photo_warnings
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
    parse = parse_hair(img.pixels, landmarks, method=hair_parser,
                       prior="learned" if learned_prior else None)
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
            "warnings": photo_warnings(img) + prior_missing(
                learned_prior and hair_parser == "grabcut"),
            "hair_parser": hair_parser,
            "face_turn_degrees": None if found is None else found.turn,
            "profile_face": parse.profile, "learned_prior": parse.prior,
            "hair_fraction": round(float(parse.hair.mean()), 4),
            "face_fraction": round(float(parse.face.mean()), 4),
            "seconds": round(time.perf_counter() - t0, 3),
            **{k: str(v) for k, v in paths.items()}}


def classify_photo(photo: str | Path, *, face: int = 0, detector: str = "auto",
                   focal: float | None = None, top: int = 3,
                   learned_prior: bool = True, hair_parser: str = "segmenter"
                   ) -> dict[str, Any]:
    """``head360 classify-hair``: the ``top`` SynHead-P hairstyles for a photo's hair, and
    its hair colour (``learned_prior=False``: the hair parsed without the learned prior)."""
    from head360cli.fitting import stages
    from head360cli.fitting.hair_parse import parse_hair

    cfg = FitConfig(face=face, detector=detector, focal=focal, learned_prior=learned_prior,
                    hair_parser=hair_parser).check()
    timings: dict[str, float] = {}
    warnings: list[str] = []
    with ThreadPoolExecutor(max_workers=1) as pool:  # the parse beside the shape fit
        img, timings["load"] = _timed(stages.load_photo, photo, cfg, warnings)
        seen, timings["detect"] = _timed(stages.detect_face, img, cfg, warnings)
        job = pool.submit(_timed, parse_hair, seen.image.pixels, seen.face.landmarks,
                          method=hair_parser, prior="learned" if learned_prior else None)
        shape, timings["shape"] = _timed(stages.fit_shape, seen, cfg, warnings)
        parse, timings["parse"] = job.result()
    t0 = time.perf_counter()
    # soft hairlines, as the shipped (deferred) generator draws them
    guess, estimate, name, colour = stages.guess_hair(seen.image, parse, shape.fit,
                                                      shape.model, seen.face.landmarks,
                                                      soft=True)
    timings["classify"] = time.perf_counter() - t0
    return {"photo": str(photo), "top": guess.top(top),
            "warnings": warnings + prior_missing(learned_prior and hair_parser == "grabcut"),
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


@dataclasses.dataclass
class FitSummary:
    """What a fit did, as ``head360 fit --json`` prints it and ``<stem>.json`` keeps it
    (:meth:`to_dict`; the keys are the fields', in this order)."""

    photo: str
    """The photo as given."""
    preset: str
    """The inversion preset."""
    face: int
    """Which face of the photo (0 the largest)."""
    pose: dict[str, float]
    """``yaw``, ``pitch``, ``roll`` (degrees) and ``distance`` (metres) of the shape fit."""
    hair_style: dict[str, Any]
    """``id``, ``name``, ``chosen_by``, the placement's ``offset_mm`` (up, forward) and
    its silhouette's IoU with the parsed hair before and after (``iou_unplaced``,
    ``iou_placed``)."""
    hair_candidates: list
    """The classifier's top three hairstyles with their scores."""
    hair_color: list[float]
    """Linear RGB of the colour worn."""
    hair_color_name: str
    """Its SynHead-P name."""
    hair_color_chosen_by: str
    """``tone curve`` or ``render``."""
    hair_color_estimate: list[float]
    """Linear RGB the parsed hair reads as."""
    hair_parse: dict[str, Any]
    """``seeded``, ``learned_prior`` and the photo's ``hair_fraction``."""
    inversion: dict[str, Any]
    """``steps``, ``loss_first``, ``loss_last``, the lips' ``mouth_opening``,
    ``mouth_inside`` (``generated`` or ``fitted``) and ``fitted_in`` (``colour`` or
    ``grey``)."""
    light: list[float] | None
    """The photo's light: the gain per channel on the head's pixels (``None``: none)."""
    closed_lids: dict[str, Any] | None
    """The lid fit's ``loss_first``, ``loss_last`` and ``texels`` (``None``: skipped)."""
    psnr_face_input_view: float
    """PSNR (dB) of the render with hair on the photo's face."""
    psnr_face_input_view_bald: float
    """...and of the bald render."""
    image_size: list[int]
    """Width and height of the photo on disk."""
    crop: dict[str, Any]
    """Where the head file's ``pose`` and ``intrinsics`` see the photo: ``affine``, the
    ``(2, 3)`` map from the photo's pixels on disk to the ``size`` x ``size`` crop they
    render (``cv2.warpAffine`` of the photo with it gives the crop)."""
    face_width: float
    """The face box's width in pixels of the photo on disk."""
    face_detector: str
    """The detector that found the face."""
    face_turn_degrees: float | None
    """The face's turn as the detector saw it."""
    checks: dict[str, Any]
    """Signs that the fit went wrong (:class:`~head360cli.fitting.stages.FitChecks`):
    ``face_psnr_low``, ``weights_at_limit`` (names at 1) and ``opposed_pairs``; each that
    shows adds a warning."""
    warnings: list[str]
    """What the user should know (several faces, a profile view, a fit that went
    wrong, ...)."""
    device: str
    """Where the generator ran: the timings depend on it."""
    timings: dict[str, float]
    """Seconds per stage, and ``total``; the parse overlaps the stages before the
    classification, so the stages add up to more than the total."""
    files: dict[str, str]
    """``head``, ``preview`` and ``summary`` paths."""

    def to_dict(self) -> dict[str, Any]:
        """The JSON-ready summary."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}


def fit_photo(photo: str | Path, out: str | Path, config: FitConfig | None = None, *,
              progress: Callable[[str, int, int], None] | None = None,
              own_folder: bool = False, **options: Any) -> dict[str, Any]:
    """``head360 fit``: every stage, from a photo to a head file.

    The stages (:mod:`head360cli.fitting.stages`) run in order: load, face and landmarks,
    shape fit, hair parsing, hairstyle classification, bald target, texture inversion,
    hair colour, closed lids, hair placement, preview. The parse runs in a second thread
    from the moment the landmarks are found, while the shape is fitted, the generator
    loaded, and the hairstyles' silhouettes, the inversion's mirror grid and the bald
    render of the starting code are made, so the summary's stage times add up to more
    than its total by that overlap. Writes ``out`` (``.h360``),
    ``<out stem>_preview.png`` (photo crop | fitted front | three other views | back) and
    ``<out stem>.json``, renamed into place together once all three are written.

    Args:
        photo: The image.
        out: Head file path (``.h360``).
        config: What the fit does (default :class:`FitConfig`'s defaults).
        progress: Callable ``(stage, step, total)`` for progress display.
        own_folder: The outputs' folder is the caller's own (``head360 demo``'s): skip
            :func:`check_fit_outputs`, which keeps a fit from replacing other programs'
            files beside the photo.
        **options: :class:`FitConfig` fields that replace ``config``'s (``preset="quality"``).

    Returns:
        The JSON summary (:class:`FitSummary`, also written to ``<out stem>.json``).
    """
    import torch
    from PIL import Image

    from head360cli.fitting import stages
    from head360cli.fitting.hair_parse import parse_hair
    from head360cli.fitting.texture import PRESETS, mirror_grid
    from head360cli.io.atomic import atomic_paths, check_file_target
    from head360cli.io.headfile import HeadFile, lid_change_arrays, write_head
    from head360cli.io.images import png_info
    from head360cli.model.head_render import HeadRenderer
    from head360cli.model.train import load_generator
    from head360cli.synth.hair import HAIRSTYLES

    unknown = sorted(set(options) - {f.name for f in dataclasses.fields(FitConfig)})
    if unknown:
        raise TypeError(f"fit_photo() got unexpected options {', '.join(unknown)}")
    cfg = dataclasses.replace(config or FitConfig(), **options).check()  # before any work
    out = Path(out)
    if out.suffix.lower() != ".h360":
        raise BadInputError(f"expected an output name ending in .h360, found {str(out)!r}")
    for target in fit_outputs(out).values():  # the preview and summary too: before the fit
        check_file_target(target)
    if not own_folder:
        check_fit_outputs(photo, out)
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
        img, timings["load"] = _timed(stages.load_photo, photo, cfg, warnings)
        seen, timings["detect"] = _timed(stages.detect_face, img, cfg, warnings)
        job = pool.submit(_timed, parse_hair, img.pixels, seen.face.landmarks,
                          method=cfg.hair_parser,
                          prior="learned" if cfg.learned_prior else None)
        shape, timings["shape"] = _timed(stages.fit_shape, seen, cfg, warnings)
        (gen, codes), load_s = _timed(load_generator, device=cfg.device)
        timings["load"] += load_s
        res = gen.cfg.image_res
        say("parse", 0, 1)
        dev = torch.device(cfg.device)
        silhouettes, classify_s = _timed(stages.style_silhouettes, img, shape.fit,
                                         shape.model)
        _, mirror_s = _timed(mirror_grid, gen.cfg.texture_res)
        t0 = time.perf_counter()
        frame = stages.frame_photo(img, shape.fit, shape.model, res)
        start = codes.mean(0)
        with torch.no_grad():
            first = gen(torch.tensor(frame.posed, dtype=torch.float32, device=dev)[None],
                        torch.tensor(frame.c2w, device=dev)[None],
                        torch.tensor(frame.k, device=dev)[None], code=start[None])
        first_s = time.perf_counter() - t0
        parse, timings["parse"] = job.result()
    warnings += prior_missing(cfg.learned_prior and cfg.hair_parser == "grabcut")
    hair, t = _timed(stages.choose_hairstyle, seen, shape, parse, cfg, silhouettes, warnings,
                     soft=gen.soft_hairlines)
    timings["classify"] = classify_s + t

    bald, t = _timed(stages.make_bald_target, seen, frame, parse, first)
    timings["bald_target"] = first_s + t
    invert_cfg = PRESETS[cfg.preset]
    if seen.grey:  # no light's colour, no skin's: its grey is fitted
        invert_cfg = dataclasses.replace(invert_cfg, gain=False, grey=True)
    inv, lips, kept_inside = stages.invert(gen, seen, shape, frame, bald, start, invert_cfg,
                                           progress=say)
    timings["invert"] = inv.seconds + mirror_s  # its mirror grid was made beside the parse

    # timed with the classification, which it completes
    hair, t = _timed(stages.choose_hair_colour, gen, seen, frame, parse, bald, hair, inv,
                     start)
    timings["classify"] += t
    lids = None
    if cfg.closed_lids:
        say("lids", 0, 1)
        lids = stages.fit_closed_lids(gen, shape, inv)
    timings["lids"] = 0.0 if lids is None else lids.seconds

    placement = stages.HairPlacement(np.zeros(3), None, None)
    t0 = time.perf_counter()
    if hair.style != 0 and cfg.hair_placement:
        placement = stages.place_hairstyle(seen, shape, frame, bald, hair.style, inv,
                                           soft=gen.soft_hairlines)
    timings["hair_placement"] = time.perf_counter() - t0

    say("preview", 0, 1)
    t0 = time.perf_counter()
    head = HeadRenderer(gen, shape.fit.shape, inv.texture, hair.style, hair.colour,
                        shape.fit.expression,
                        samples=(invert_cfg.preview_samples if gen.kind == "hexplane"
                                 else None),
                        precision="fp32", hair_offset=placement.offset,
                        hair_scale=placement.scale, hair_end_shift=placement.end_shift,
                        lid_change=None if lids is None else lids.change,
                        colour_gain=inv.gain)
    timings["preview"] = time.perf_counter() - t0
    detail = None
    t0 = time.perf_counter()
    if head.hair is not None and gen.kind == "deferred" and cfg.hair_texture:
        detail = stages.texture_hair(gen, head, frame, bald, inv)
    timings["hair_texture"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    preview = stages.render_preview(head, frame, bald, inv, invert_cfg.grey)
    timings["preview"] += time.perf_counter() - t0
    checks = stages.check_fit(shape.fit.expression, preview.psnr_face)
    warnings += checks.warnings(preview.psnr_face)

    t0 = time.perf_counter()
    paths = fit_outputs(out)
    head_file = HeadFile(
        arrays={"shape": shape.fit.shape.astype(np.float32),
                "expression": shape.fit.expression.astype(np.float32),
                "pose": inv.c2w.cpu().numpy().astype(np.float32), "intrinsics": frame.k,
                "texture": inv.texture.cpu().numpy().astype(np.float32),
                "texture_code": inv.code.cpu().numpy().astype(np.float32),
                "hair_style": np.array(hair.style, np.int64),
                "hair_color": hair.colour.astype(np.float32),
                "hair_offset": placement.offset.astype(np.float32),
                **({} if placement.scale is None else
                   {"hair_scale": placement.scale.astype(np.float32)}),
                **({} if not placement.end_shift else
                   {"hair_end_shift": np.array(placement.end_shift, np.float32)}),
                **({} if detail is None else {"hair_detail": detail.astype(np.float16)}),
                "vertices": frame.neutral.astype(np.float32),
                **({} if lids is None else lid_change_arrays(lids.change.cpu().numpy())),
                **({} if inv.gain is None else
                   {"colour_gain": inv.gain.cpu().numpy().astype(np.float32)})},
        model_hash=generator_hash(),
        info={"photo": Path(photo).name, "preset": cfg.preset, "face": cfg.face,
              "hair_style_name": HAIRSTYLES[hair.style].name,
              "bilinear_model": shape.model.meta["sha256"]})
    # The head file, its preview and its summary are renamed into place together once all
    # three are written, so a full disk leaves an earlier fit's set as it was.
    with atomic_paths(paths["head"], paths["preview"], paths["summary"]) as (
            tmp_head, tmp_preview, tmp_summary):
        write_head(head_file, tmp_head)
        Image.fromarray(preview.sheet).save(tmp_preview, format="PNG", pnginfo=png_info())
        timings["write"] = time.perf_counter() - t0
        timings["total"] = time.perf_counter() - t_all
        summary = _summary(photo, cfg, seen, shape, frame, parse, hair, placement, inv, lips,
                           kept_inside, lids, preview, checks, warnings, dev, timings, paths)
        tmp_summary.write_text(dumps(summary.to_dict(), indent=1))
    return summary.to_dict()


def _summary(photo, cfg: FitConfig, seen, shape, frame, parse, hair, placement, inv,
             lips: float, kept_inside: bool, lids, preview, checks, warnings: list[str], dev,
             timings: dict[str, float], paths: dict[str, Path]) -> FitSummary:
    """The :class:`FitSummary` of a fit's stages' results, rounded for reading."""
    from head360cli.synth.hair import HAIRSTYLES

    def rounded(values, digits: int = 4) -> list[float]:
        return [round(float(v), digits) for v in values]

    euler = shape.fit.euler_degrees()
    offset = placement.offset
    on_disk = frame.affine.copy()  # the crop's map from the pixels fitted, which a large
    on_disk[:, :2] *= seen.image.scale  # photo's are fewer of than those on disk
    return FitSummary(
        photo=str(photo), preset=cfg.preset, face=cfg.face,
        pose={**{k: round(v, 2) for k, v in euler.items()},
              "distance": round(shape.fit.distance(), 4)},
        hair_style={"id": hair.style, "name": HAIRSTYLES[hair.style].name,
                    "chosen_by": hair.chosen_by,
                    # the placement: mm up and forward, and its silhouette's IoU with the
                    # parsed hair before and after
                    "offset_mm": {"up": round(float(offset[1]) * 1e3, 1),
                                  "forward": round(float(offset[2]) * 1e3, 1)},
                    # the ends at the sides and back moved down (negative: up), mm
                    "end_shift_mm": round(placement.end_shift * 1e3, 1),
                    "iou_unplaced": None if placement.iou_unplaced is None
                    else round(placement.iou_unplaced, 4),
                    "iou_placed": None if placement.iou_placed is None
                    else round(placement.iou_placed, 4),
                    # its thickness scaled by direction to the parsed hair's outline
                    "iou_scaled": None if placement.iou_scaled is None
                    else round(placement.iou_scaled, 4),
                    "scale_range": None if placement.scale is None
                    else rounded([placement.scale.min(), placement.scale.max()], 3)},
        hair_candidates=hair.guess.top(3),
        hair_color=rounded(hair.colour), hair_color_name=hair.colour_name,
        hair_color_chosen_by=hair.colour_by, hair_color_estimate=rounded(hair.estimate),
        hair_parse={"parser": cfg.hair_parser, "seeded": parse.seeded,
                    "learned_prior": parse.prior,
                    "hair_fraction": round(float(parse.hair.mean()), 4)},
        inversion={"steps": inv.steps, "loss_first": round(inv.losses[0], 5),
                   "loss_last": round(inv.losses[-1], 5),
                   # the lips' gap, and whether the mouth's inside was fitted
                   "mouth_opening": round(lips, 4) if np.isfinite(lips) else None,
                   "mouth_inside": "generated" if kept_inside else "fitted",
                   # a grey photo's grey is fitted; the colour is the model's
                   "fitted_in": "grey" if seen.grey else "colour"},
        light=None if inv.gain is None else rounded(inv.gain),
        closed_lids=None if lids is None else {
            "loss_first": round(lids.loss_first, 5), "loss_last": round(lids.loss_last, 5),
            "texels": lids.texels},
        psnr_face_input_view=round(preview.psnr_face, 2),
        psnr_face_input_view_bald=round(preview.psnr_bald, 2),
        image_size=list(seen.image.source_size),
        crop={"affine": [rounded(row, 6) for row in on_disk], "size": int(frame.crop.shape[0])},
        face_width=round(float(seen.face.box[2] - seen.face.box[0]) / seen.image.scale, 1),
        face_detector=seen.face.detector, face_turn_degrees=seen.face.turn,
        checks=dataclasses.asdict(checks), warnings=warnings, device=str(dev),
        timings={k: round(v, 3) for k, v in timings.items()},
        files={k: str(v) for k, v in paths.items()})


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
    from head360cli.synth.hair import MAX_END_SHIFT, WARP_BINS

    if "hair_end_shift" in arrays:
        shift = np.asarray(arrays["hair_end_shift"])
        if shift.shape != () or not np.isfinite(shift) or abs(float(shift)) > MAX_END_SHIFT:
            raise FileFormatError(f"{where}: expected hair_end_shift of one number within "
                                  f"{MAX_END_SHIFT} m, found {shift.tolist()}")
    if "hair_scale" in arrays:
        scale = np.asarray(arrays["hair_scale"])
        if scale.shape != (WARP_BINS,) or not (np.isfinite(scale) & (scale > 0)).all():
            raise FileFormatError(f"{where}: expected hair_scale of {WARP_BINS} positive "
                                  f"numbers, found shape {scale.shape}")
    if "hair_detail" in arrays:
        detail = np.asarray(arrays["hair_detail"])
        if detail.ndim != 3 or detail.shape[2] != 3 or detail.shape[0] != detail.shape[1] \
                or not 16 <= detail.shape[0] <= 1024 \
                or not (np.isfinite(detail) & (detail >= 0)).all():
            raise FileFormatError(f"{where}: expected hair_detail of (A, A, 3) numbers >= 0 "
                                  f"with A from 16 to 1024, found shape {detail.shape}")
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
        ModelMismatchError: The file was made with another generator, or with another
            parametric head (its identity code would shape another face).
    """
    import torch

    from head360cli.io.headfile import HEAD_ARRAYS, lid_change_of, read_head
    from head360cli.mesh.bilinear import load_bilinear
    from head360cli.model.head_render import REUSE_TOL, HeadRenderer
    from head360cli.model.train import load_generator

    head = read_head(path, expected_model_hash=generator_hash(), required=HEAD_ARRAYS)
    made_with, installed = head.info.get("bilinear_model"), load_bilinear().meta["sha256"]
    if made_with is not None and made_with != installed:
        raise ModelMismatchError(
            f"head file {str(path)!r} was made with parametric head {str(made_with)[:12]}, "
            f"but the installed one is {installed[:12]}; fit the photo again (head360 fit "
            "PHOTO)")
    gen, _ = load_generator(device=device)
    a = head.arrays
    check_head_sizes(a, gen.cfg, f"head file {str(path)!r}")
    return HeadRenderer(gen, a["shape"], torch.as_tensor(a["texture"]), int(a["hair_style"]),
                        a["hair_color"], a["expression"], samples=samples, size=size,
                        precision=precision,
                        reuse=REUSE_TOL if isinstance(reuse, str) else reuse,
                        hair_offset=a.get("hair_offset"), hair_scale=a.get("hair_scale"),
                        hair_end_shift=a.get("hair_end_shift"),
                        hair_detail=a.get("hair_detail"),
                        lid_change=lid_change_of(a),
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

"""The stages of a fit, in the order they run, each a function with a small typed result.

    photo -> :func:`load_photo` -> :func:`detect_face` (:class:`PhotoFace`)
          -> :func:`fit_shape` (:class:`Shape`)
          -> hair parse (:func:`~head360cli.fitting.hair_parse.parse_hair`, in a second
             thread from the moment the landmarks are found)
          -> :func:`choose_hairstyle` (:class:`HairChoice`)
          -> :func:`make_bald_target` (:class:`BaldTarget`)
          -> :func:`invert` (:class:`~head360cli.fitting.texture.Inversion`)
          -> :func:`choose_hair_colour` (:class:`HairChoice`, its colour completed)
          -> :func:`fit_closed_lids` (:class:`~head360cli.fitting.lids.LidResult`)
          -> :func:`place_hairstyle` (:class:`HairPlacement`)
          -> :func:`render_preview` (:class:`Preview`)

:func:`head360cli.fitting.pipeline.fit_photo` runs them and writes the head file; the
work inside each is in :mod:`~head360cli.fitting.landmarks`,
:mod:`~head360cli.fitting.shape`, :mod:`~head360cli.fitting.hair_parse`,
:mod:`~head360cli.fitting.hair_class`, :mod:`~head360cli.fitting.texture` and
:mod:`~head360cli.fitting.lids`."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from head360cli.errors import BadInputError
from head360cli.fitting.config import FitConfig

PREVIEW_YAWS = (-45.0, 45.0, 90.0, 180.0)
"""Yaw of the preview's other views (degrees, + = the subject's left), the back last."""


MIN_FACE_PX = 40
"""Faces narrower than this (pixels of the image as loaded; the larger extent of the 68
landmarks) are refused: too few pixels to fit a texture to."""

SMALL_FACE_PX = 60
"""Faces narrower than this are fitted with a warning (blurry texture): the fit's 256-pixel
crop shows a face about 90 pixels wide, so such a face is upsampled 1.5 times or more."""

CONFIDENT_FACE = 0.5
"""Detector score from which a found face counts towards the several-faces warning.
YuNet and BlazeFace score from 0 to 1; dlib's detectors, when chosen, on their own
scales."""

PROFILE_YAW = 40.0
"""Beyond this fitted yaw (degrees) a warning says the head is turned: the far side comes
from the model, and the pose and hairstyle may be off (how it was chosen: docs/
decisions.md)."""




@dataclasses.dataclass
class PhotoFace:
    """A loaded photo and the face a fit is about."""

    image: Any
    """The photo (:class:`~head360cli.io.images.LoadedImage`)."""
    face: Any
    """The chosen face (:class:`~head360cli.fitting.landmarks.FoundFace`): box, 68
    landmarks in the loaded image's pixels, detector, turn."""
    grey: bool
    """Whether the photo and the face's box in it are greyscale (:func:`grey_face`)."""


@dataclasses.dataclass
class Shape:
    """The bilinear model's fit to the face's landmarks."""

    fit: Any
    """:class:`~head360cli.fitting.shape.ShapeFit`: identity, expression, pose, camera."""
    model: Any
    """The :class:`~head360cli.mesh.bilinear.BilinearModel` it was fitted with."""


@dataclasses.dataclass
class Framing:
    """What the generator sees of the photo: its camera and its square crop."""

    c2w: np.ndarray
    """``(4, 4)`` camera to world of the photo's camera."""
    k: np.ndarray
    """``(3, 3)`` intrinsics of the crop."""
    affine: np.ndarray
    """``(2, 3)`` from the loaded photo's pixels to the crop's."""
    crop: np.ndarray
    """``(R, R, 3)`` uint8 crop of the photo."""
    posed: np.ndarray
    """``(V, 3)`` the fitted mesh with the photo's expression."""
    neutral: np.ndarray
    """``(V, 3)`` the fitted mesh without expression."""


@dataclasses.dataclass
class HairChoice:
    """The hairstyle and colour a fitted head wears."""

    style: int
    """Hairstyle id (0 bald)."""
    chosen_by: str
    """``classifier`` or ``user``."""
    guess: Any
    """The classifier's ranking (:class:`~head360cli.fitting.hair_class.HairGuess`)."""
    estimate: np.ndarray
    """``(3,)`` linear RGB the parsed hair's pixels read as."""
    colour_name: str
    """The SynHead-P colour name nearest the colour worn."""
    colour: np.ndarray
    """``(3,)`` its linear RGB."""
    colour_by: str = "tone curve"
    """How the colour was chosen: ``tone curve`` or ``render``."""


@dataclasses.dataclass
class BaldTarget:
    """The photo with its hair replaced by the model's bald head, and where the inversion
    compares it with the render."""

    target: np.ndarray
    """``(R, R, 3)`` uint8 crop, hair filled from a bald render (Poisson-blended)."""
    weight: np.ndarray
    """``(R, R)`` bool: the parsed face where the head covers it."""
    mask: np.ndarray
    """``(R, R)`` float32 loss weights: 1 on ``weight`` but the hair's edge
    (:func:`hair_edge`), 0.25 on the rest of the head that is neither hair nor outside
    the photo."""
    hair: np.ndarray
    """``(R, R)`` bool: the parsed hair in the crop."""
    face: np.ndarray
    """``(R, R)`` bool: the parsed face in the crop."""
    valid: np.ndarray
    """``(R, R)`` bool: the crop's pixels inside the photo."""


@dataclasses.dataclass
class HairPlacement:
    """The hairstyle's mesh shifted to the parsed hair."""

    offset: np.ndarray
    """``(3,)`` metres (x, up, forward)."""
    iou_placed: float | None
    """Silhouette IoU with the parsed hair after the shift (``None``: not placed)."""
    iou_unplaced: float | None
    """...and before it."""
    scale: np.ndarray | None = None
    """``(WARP_BINS,)`` the style's thickness by direction, fitted to the parsed hair's
    outline (:func:`~head360cli.fitting.hair_shape.fit_hair_scale`); ``None``: as built."""
    iou_scaled: float | None = None
    """Silhouette IoU with the parsed hair after the scale (``None``: not scaled, as the
    scale gained nothing)."""
    end_shift: float = 0.0
    """Metres the style's ends at the sides and back are moved down (negative: up),
    :func:`~head360cli.fitting.hair_shape.fit_hair_end`."""


@dataclasses.dataclass
class Preview:
    """The preview sheet and the input view's fidelity."""

    sheet: np.ndarray
    """``(R, 6 R, 3)`` uint8: photo crop | fitted front | three other views | back."""
    psnr_face: float
    """PSNR (dB) of the render with hair against the photo on the face."""
    psnr_bald: float
    """...and of the bald render, as the inversion saw it."""


def photo_warnings(img) -> list[str]:
    """The warnings for a loaded photo: a file of several frames or pages (an animated
    GIF, a TIFF stack), of which only the first is read; a colour profile that could not
    be used, so that its values are taken as sRGB's; 16-bit channels holding fewer bits'
    data (12-bit values up to 4095), scaled by the range they use."""
    warnings = []
    if img.frames > 1:
        warnings.append(f"{Path(img.path).name} holds {img.frames} frames; the first is used")
    if img.colour_profile == "unreadable":
        warnings.append(f"{Path(img.path).name} has a colour profile head360 cannot use; "
                        f"its colours are taken as sRGB")
    if img.bits_used < img.bits:
        warnings.append(f"{Path(img.path).name} has {img.bits}-bit channels whose values use "
                        f"{img.bits_used} bits (up to {2 ** img.bits_used - 1}): read as "
                        f"{img.bits_used}-bit data")
    return warnings





def load_photo(photo: str | Path, cfg: FitConfig, warnings: list[str]):
    """Read the photo (a :class:`~head360cli.io.images.LoadedImage`) and check the focal
    length given for it; a file of several frames or an unusable colour profile adds a
    warning to ``warnings``.

    Raises:
        BadInputError: A focal length no lens has for this photo's size.
    """
    from head360cli.fitting.shape import check_focal
    from head360cli.io.images import load_image

    img = load_image(photo)
    check_focal(cfg.focal, *img.source_size)
    warnings += photo_warnings(img)
    return img


def detect_face(img, cfg: FitConfig, warnings: list[str]) -> PhotoFace:
    """Find face ``cfg.face`` of the loaded photo ``img``; warnings for the user (several
    faces, a small face, a greyscale photo) are appended to ``warnings``.

    Raises:
        NoFaceError: No face (by :func:`~head360cli.fitting.landmarks.find_faces`), or
            fewer faces than ``cfg.face + 1``.
        BadInputError: A face narrower than :data:`MIN_FACE_PX`.
    """
    from head360cli.fitting.landmarks import find_faces, pick_face

    faces = find_faces(img.pixels, cfg.detector, only=cfg.face)
    found = pick_face(faces, cfg.face, cfg.detector, img.pixels)
    confident = [f for f in faces if f.score >= CONFIDENT_FACE]
    if len(confident) > 1:
        warnings.append(f"{len(confident)} faces found; fitting face {cfg.face} "
                        f"({'the largest' if cfg.face == 0 else 'by size'}), choose with "
                        f"--face N")
    # the landmarks' extent, not the box's: detectors' boxes differ in size (BlazeFace's
    # is 1.18 times dlib's on the astronaut), their landmarks agree (92.5 and 92.8 px)
    lm = found.landmarks
    width = float(max(np.ptp(lm[:, 0]), np.ptp(lm[:, 1])))
    if width < MIN_FACE_PX:
        raise BadInputError(f"expected a face at least {MIN_FACE_PX} pixels wide, found "
                            f"{width:.0f}: use a larger photo")
    if width < SMALL_FACE_PX:
        warnings.append(f"the face is only {width:.0f} pixels wide: the texture will be "
                        "blurry")
    grey = grey_face(img, found)
    if grey:
        warnings.append("greyscale photo: the skin's colour comes from the model, the "
                        "hair's is the named colour nearest its grey")
    return PhotoFace(img, found, grey)


_FITTERS: dict = {}


def fit_face(model, face, size: tuple[int, int], focal: float,
             distance: float | None = None):
    """The shape fit of one detected face (:class:`~head360cli.fitting.landmarks.
    DetectedFace`): with the face mesh (the default detectors), to its 68 landmarks and
    the mesh's points placed on the head (:func:`~head360cli.fitting.calibrate.
    load_dense_points`), the expression starting from the mesh's blendshape scores;
    with dlib's landmarks, to the 68 alone.

    On the first 20 people of the London set, the neutral heads fitted to a person's
    neutral and smiling portraits differed by 1.93 mm (mean over vertices) with the 68
    landmarks, 1.58 mm with the dense points and 1.35 mm with the blendshape scores too:
    less of the smile is taken for the person's shape.
    """
    from head360cli.fitting.calibrate import load_dense_points
    from head360cli.fitting.shape import ShapeFitter

    dense = load_dense_points(model) if face.mesh is not None else None
    key = (model.meta.get("sha256"), dense is not None)
    if key not in _FITTERS:
        _FITTERS[key] = ShapeFitter(model, dense=None if dense is None else dense[1:])
    fitter = _FITTERS[key]
    if dense is None:
        return fitter.fit(face.landmarks, size, focal=focal, distance=distance,
                          turn=face.turn)
    return fitter.fit(face.landmarks, size, focal=focal, distance=distance, turn=face.turn,
                      dense2d=face.mesh[dense[0], :2], expression0=face.blendshapes)


def fit_shape(seen: PhotoFace, cfg: FitConfig, warnings: list[str]) -> Shape:
    """Fit the bilinear model's identity, expression and pose to the face's landmarks;
    a profile view (fitted yaw beyond :data:`PROFILE_YAW`) adds a warning."""
    from head360cli.fitting.shape import default_focal
    from head360cli.mesh.bilinear import load_bilinear

    img = seen.image
    model = load_bilinear()
    full_w, full_h = img.source_size
    f_disk = cfg.focal if cfg.focal else default_focal(full_w, full_h, img.focal_35mm)
    fit = fit_face(model, seen.face, img.size, f_disk * img.scale, cfg.distance)
    yaw = fit.euler_degrees()["yaw"]
    if abs(yaw) > PROFILE_YAW:
        warnings.append(f"profile view (fitted yaw {yaw:.0f} degrees, likely turned further):"
                        " the far side of the face comes from the model, and the pose and "
                        "hairstyle may be off")
    return Shape(fit, model)


def choose_hairstyle(seen: PhotoFace, shape: Shape, parse, cfg: FitConfig,
                     silhouettes: np.ndarray | None, warnings: list[str],
                     soft: bool = False) -> HairChoice:
    """The classifier's hairstyle for the parsed hair (or ``cfg.hair_style``) and the
    colour its pixels read as; a parse that matches no style adds a warning (the head is
    then fitted bald). ``soft``: the generator's hairlines (:func:`guess_hair`)."""
    guess, estimate, name, colour = guess_hair(seen.image, parse, shape.fit, shape.model,
                                               seen.face.landmarks, silhouettes, soft=soft)
    style = guess.ranking[0] if cfg.hair_style is None else int(cfg.hair_style)
    if cfg.hair_style is None and not guess.matched:
        warnings.append(f"the parsed hair matches no hairstyle (best overlap "
                        f"{guess.iou.max():.3f}): fitted bald; choose a style with --hair")
    return HairChoice(style, "classifier" if cfg.hair_style is None else "user", guess,
                      estimate, name, colour)


def make_bald_target(seen: PhotoFace, frame: Framing, parse, first: dict) -> BaldTarget:
    """The inversion's target: the photo's crop with its hair replaced by ``first``, the
    generator's render of the starting code (``{"rgb", "alpha"}`` tensors).

    Raises:
        BadInputError: Under 50 face pixels are visible (a covered face).
    """
    from head360cli.fitting.texture import bald_target, crop_mask
    from head360cli.model.head_render import to_uint8

    res = frame.crop.shape[0]
    hair = crop_mask(parse.hair, frame.affine, res)
    face = crop_mask(parse.face, frame.affine, res)
    target = bald_target(frame.crop, hair, to_uint8(first["rgb"])[0])
    alpha = first["alpha"][0, 0].cpu().numpy() > 0.5
    weight = face & alpha
    if weight.sum() < 50:
        raise BadInputError("expected a visible face region to fit the texture to, found "
                            f"{int(weight.sum())} pixels (is the face covered?)")
    valid = crop_mask(np.ones(seen.image.pixels.shape[:2], bool), frame.affine, res)
    # the hair's soft edge reaches past the segmenter's mask: fitted there, its strands
    # were projected into the skin as a dark band along the hairline
    sure = weight & ~hair_edge(hair, weight)
    mask = sure.astype(np.float32) + 0.25 * skin_coloured(
        frame.crop, weight, alpha & ~weight & ~hair & valid)
    return BaldTarget(target, weight, mask, hair, face, valid)


HAIR_MARGIN = 0.013
"""Share of the crop's side (3 pixels at 256) by which the face next to the parsed hair
is left out of the texture's fit: the hair's soft edge, which the segmenter leaves to
the face (``docs/decisions.md``, the hairline)."""


def hair_edge(hair: np.ndarray, face: np.ndarray) -> np.ndarray:
    """``(R, R)`` bool: the ``face`` pixels within :data:`HAIR_MARGIN` of the parsed
    ``hair`` (both ``(R, R)`` bool)."""
    import cv2

    side = 2 * round(HAIR_MARGIN * hair.shape[0]) + 1
    return (cv2.dilate(hair.astype(np.uint8), np.ones((side, side), np.uint8)) > 0) & face


SKIN_DELTA_E = 15.0
"""CIE76 difference from every colour of the photo's face skin beyond which a pixel
around the face (the head's render covers it, the parse calls it neither face nor hair)
is kept out of the texture's loss: a collar, the backdrop, a microphone."""


def skin_coloured(crop: np.ndarray, skin: np.ndarray, around: np.ndarray) -> np.ndarray:
    """``(R, R)`` bool: the pixels of ``around`` whose colour in ``crop (R, R, 3)`` the
    ``skin (R, R)`` pixels have, within :data:`SKIN_DELTA_E`. The render's neck and
    sides cover the photo's shirt collar and backdrop; fitted to those, the texture put
    blue-green streaks on cheeks and collars on necks, seen from every side."""
    from head360cli.fitting.colours import palette, palette_distance

    keep = np.zeros_like(around)
    if skin.any() and around.any():
        keep[around] = palette_distance(crop[around], palette(crop, skin)) <= SKIN_DELTA_E
    return keep


def invert(gen, seen: PhotoFace, shape: Shape, frame: Framing, bald: BaldTarget, start,
           invert_cfg, progress=None):
    """Fit the neural texture (and refine the camera, and the photo's light) to the bald
    target from the code ``start``, keeping the mouth's inside generated when the lips are
    closed. Returns ``(inversion, lips opening, whether the inside was kept)``."""
    import torch

    from head360cli.fitting.landmarks import mouth_opening
    from head360cli.fitting.texture import invert_texture, region_texels

    dev = start.device
    verts = torch.tensor(frame.posed, dtype=torch.float32, device=dev)
    # lips closed or nearly: the inside of the mouth keeps the generated texture
    lips = mouth_opening(seen.face.landmarks)  # NaN for eye corners on one point
    keep = region_texels(gen.cfg.texture_res).to(dev) if lips < invert_cfg.closed_mouth \
        else None
    inv = invert_texture(
        gen, verts, torch.tensor(frame.c2w, device=dev), torch.tensor(frame.k, device=dev),
        torch.tensor(bald.target, dtype=torch.float32, device=dev).permute(2, 0, 1) / 255.0,
        torch.tensor(bald.mask, device=dev)[None], start, invert_cfg,
        progress=None if progress is None else (lambda s, n, loss: progress("texture", s, n)),
        landmarks=inner_landmarks(shape.model, frame.posed, seen.face.landmarks,
                                  frame.affine, dev),
        held=torch.as_tensor(INNER_EYES, device=dev), keep=keep)
    return inv, lips, keep is not None


def choose_hair_colour(gen, seen: PhotoFace, frame: Framing, parse, bald: BaldTarget,
                       hair: HairChoice, inv, start) -> HairChoice:
    """The hair's colour as it would look under white light: the photo's hair pixels
    without the light the inversion found, then, for a head with hair, the nearest named
    colours rendered under that light and compared with the photo
    (:func:`colour_by_render`)."""
    import torch

    estimate, name, colour, by = hair.estimate, hair.colour_name, hair.colour, "tone curve"
    if inv.gain is not None:
        from head360cli.fitting.hair_class import hair_colour, nearest_colour_name
        from head360cli.synth.hair import HAIR_COLOURS

        # the hair pixels only: a 4096-pixel photo as float64 would take 400 MB
        gain = inv.gain.cpu().numpy().astype(np.float64)
        pixels = seen.image.pixels[parse.hair]
        unlit = np.clip(pixels / gain, 0, 255).round().astype(np.uint8)
        estimate = hair_colour(unlit[None], np.ones((1, len(unlit)), bool))
        name = nearest_colour_name(estimate)
        colour = np.asarray(HAIR_COLOURS[name], np.float32)
    if hair.style != 0:
        dev = start.device
        name, colour, by = colour_by_render(
            gen, torch.tensor(frame.posed, dtype=torch.float32, device=dev),
            torch.tensor(frame.c2w, device=dev), torch.tensor(frame.k, device=dev), start,
            frame.neutral, hair.style, frame.crop, bald.hair, estimate, inv.gain)
    return dataclasses.replace(hair, estimate=estimate, colour_name=name, colour=colour,
                               colour_by=by)


def fit_closed_lids(gen, shape: Shape, inv):
    """The texture change that closed eyes show as a lid
    (:func:`~head360cli.fitting.lids.head_lids`)."""
    from head360cli.fitting.lids import head_lids

    return head_lids(gen, shape.model, shape.fit.shape, inv.texture)


def place_hairstyle(seen: PhotoFace, shape: Shape, frame: Framing, bald: BaldTarget,
                    style: int, inv, soft: bool = False) -> HairPlacement:
    """Shift the style's mesh so its silhouette from the refined camera best matches the
    parsed hair (:func:`~head360cli.fitting.hair_class.place_hair`), raise its ends
    where the parsed hair ends higher (:func:`~head360cli.fitting.hair_shape.
    fit_hair_end`), then scale its thickness by direction to the parsed hair's outline
    (:func:`~head360cli.fitting.hair_shape.fit_hair_scale`)."""
    from head360cli.fitting.hair_class import place_hair
    from head360cli.fitting.hair_shape import fit_hair_shape

    res = frame.crop.shape[0]
    c2w = inv.c2w.cpu().numpy()
    scored = bald.valid & outside_body(seen.face.landmarks, frame.affine, res)
    offset, placed, plain = place_hair(
        frame.neutral, frame.posed, shape.model.faces, c2w, frame.k, style,
        bald.hair, scored, face=bald.face)
    end, shaped = fit_hair_shape(frame.neutral, frame.posed, shape.model.faces, c2w,
                                 frame.k, style, bald.hair, scored, offset, bald.face,
                                 soft=soft)
    if (shaped.scale == 1).all():  # kept only where it gains (fit_hair_scale)
        return HairPlacement(offset, placed, plain, end_shift=end)
    return HairPlacement(offset, placed, plain, shaped.scale, shaped.iou_after, end)


DETAIL_MATCH_ROUNDS = 2
"""Renders that match the hair's brightness again once it wears the photo's texture."""
DETAIL_GAIN = (0.5, 2.0)
"""Limits of that match's gain on the texture."""


def texture_hair(gen, head, frame: Framing, bald: BaldTarget, inv) -> np.ndarray:
    """The fitted hair's detail texture from the photo
    (:func:`~head360cli.fitting.hair_texture.hair_detail`), ``(A, A, 3)``, scaled per
    channel until the ``head`` (a :class:`~head360cli.model.head_render.HeadRenderer`
    wearing the placed style) renders its hair as the photo's from the refined camera
    (:func:`~head360cli.fitting.hair_class.match_colour_by_render` on the texture's
    gain, :data:`DETAIL_MATCH_ROUNDS` renders): the photo's patches are its hair's
    inside, brighter than its median, and its spread of light and dark renders otherwise
    than the network's even strands (the astronaut's hair rendered 9.4 CIEDE2000 from
    her photo's unscaled, 3.4 with the network's strands). The hair colour stays the
    one matched with the network's strands: matched again it left the colours the
    network learnt (a blonde went to (1.0, 0.98, 0.70) and rendered green). One gain
    for the three channels (their geometric mean) cost the astronaut 1.3 -> 3.7."""
    import torch

    from head360cli.fitting.hair_class import match_colour_by_render
    from head360cli.fitting.hair_texture import MAX_DETAIL, hair_detail

    dev = inv.c2w.device
    k = torch.tensor(frame.k, device=dev)
    gain = None if inv.gain is None else inv.gain.cpu().numpy()
    detail = hair_detail(gen, torch.tensor(frame.posed, dtype=torch.float32, device=dev),
                         inv.c2w, k, head.hair, frame.crop, bald.hair, gain)

    def render(scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        head.set_hair_detail(np.clip(detail * scale, 0.0, MAX_DETAIL))
        image, _, covered = head.render(inv.c2w[None], k, alpha=True, hair_alpha=True)
        return (image[0].permute(1, 2, 0).cpu().numpy(), covered[0, 0].cpu().numpy() > 0.5)

    scale = match_colour_by_render(render, frame.crop / 255.0, bald.hair, np.ones(3),
                                   rounds=DETAIL_MATCH_ROUNDS, bounds=DETAIL_GAIN)
    detail = np.clip(detail * scale, 0.0, MAX_DETAIL).astype(np.float32)
    head.set_hair_detail(detail)
    return detail


def render_preview(head, frame: Framing, bald: BaldTarget, inv, grey: bool) -> Preview:
    """Render the fitted ``head`` (a :class:`~head360cli.model.head_render.HeadRenderer`)
    from the refined photo camera and :data:`PREVIEW_YAWS`, and measure the input view
    on the face, with hair and bald (in grey for a grey photo, the values it has)."""
    import torch

    from head360cli.drive.views import head_framing, view_cameras
    from head360cli.fitting.texture import LUMA
    from head360cli.model.head_render import to_uint8

    res = frame.crop.shape[0]
    kk = torch.tensor(frame.k, device=inv.c2w.device)
    others = view_cameras(PREVIEW_YAWS, 0.0, head_framing(head))
    front = to_uint8(head.render(inv.c2w[None], kk))[0]
    views = to_uint8(head.render(others, rig_intrinsics(res), expression=np.zeros(52)))
    # With its hair, as the user will see it: hair over the forehead counts as error.
    seen = (lambda x: x.astype(np.float64) @ np.array(LUMA)) if grey else (lambda x: x)
    psnr_face = masked_psnr(seen(front), seen(frame.crop), bald.weight)
    # Bald, as the inversion saw it: the texture alone.
    bald_render = to_uint8(head.render(inv.c2w[None], kk, hair=False))[0]
    psnr_bald = masked_psnr(seen(bald_render), seen(frame.crop), bald.weight)
    return Preview(np.concatenate([frame.crop, front, *views], 1), psnr_face, psnr_bald)


LOW_FACE_PSNR = 20.0
"""Face PSNR (dB) at the input view under which a fit warns that it matches the photo
poorly: of the bench's five real photos, the smiling portrait whose landmarks the shape
fit misses reads 16.2 dB, the others 21.5 to 42.1."""

MANY_AT_LIMIT = 8
"""How many of the 52 expression weights at their limit of 1 make a fit warn that its
landmarks were likely misread (the bench's portraits: 0 to 6, the smiling one 16)."""


@dataclasses.dataclass
class FitChecks:
    """Signs that a fit went wrong, kept in the summary (``checks``)."""

    face_psnr_low: bool
    """The face PSNR at the input view is under :data:`LOW_FACE_PSNR`."""
    weights_at_limit: list[str]
    """The ARKit weights the shape fit put at 1."""
    opposed_pairs: list[list[str]]
    """Pairs of opposed blendshapes (:data:`~head360cli.mesh.arkit52.OPPOSED`) both at
    0.5 or more."""

    def warnings(self, psnr: float) -> list[str]:
        """What the user is told of these checks."""
        out = []
        if self.face_psnr_low:
            out.append(f"the fitted head matches the photo poorly at its own view (face PSNR "
                       f"{psnr:.1f} dB, under {LOW_FACE_PSNR:g}): look at the preview; a "
                       f"strong expression, a turned or covered face, or misread landmarks")
        if len(self.weights_at_limit) >= MANY_AT_LIMIT:
            out.append(f"the expression fit put {len(self.weights_at_limit)} of 52 "
                       f"blendshapes at their limit ({', '.join(self.weights_at_limit[:4])}"
                       f"...): the landmarks were likely misread, and animations start "
                       f"from this expression")
        if self.opposed_pairs:
            shown = ", ".join(" with ".join(p) for p in self.opposed_pairs[:3])
            out.append(f"the expression fit shows opposed blendshapes together ({shown})")
        return out


def check_fit(expression: np.ndarray, psnr_face: float) -> FitChecks:
    """The :class:`FitChecks` of a fit's expression ``(52,)`` and face PSNR."""
    from head360cli.mesh.arkit52 import ARKIT52, INDEX, OPPOSED

    w = np.asarray(expression, np.float64)
    return FitChecks(
        face_psnr_low=bool(psnr_face < LOW_FACE_PSNR),
        weights_at_limit=[n for n in ARKIT52 if w[INDEX[n]] >= 0.999],
        opposed_pairs=[[a, b] for a, b in OPPOSED if w[INDEX[a]] >= 0.5 and w[INDEX[b]] >= 0.5])


def frame_photo(img, fit, model, res: int) -> Framing:
    """The photo's camera, crop and meshes for a shape ``fit`` (``res``-pixel crop)."""
    from head360cli.fitting.texture import crop_image, photo_camera

    c2w, k, affine = photo_camera(fit.rotation, fit.translation, fit.focal, fit.centre, res)
    return Framing(c2w, k, affine, crop_image(img.pixels, affine, res),
                   model.vertices(fit.shape, fit.expression),
                   model.vertices(fit.shape, np.zeros(52)))


INNER_EYES = np.isin(np.arange(17, 68), np.arange(36, 48))
"""``(51,)`` bool: the eyes (iBUG 36-47) among :func:`inner_landmarks`' points, which
the inversion's camera refinement holds closer than the rest
(:attr:`~head360cli.fitting.texture.InvertConfig.held_slack`)."""


def inner_landmarks(model, posed: np.ndarray, detected: np.ndarray, affine: np.ndarray,
                     device) -> tuple:
    """The inner-face landmarks (17-67: brows, nose, eyes, mouth; not the jaw contour,
    which slides with the view) as ``(points on the posed mesh (51, 3), detected pixels
    in the crop (51, 2))``, the anchors of the inversion's camera refinement."""
    import torch

    points = model.landmark_points(posed)[17:]
    pixels = detected[17:] @ affine[:, :2].T + affine[:, 2]
    return (torch.tensor(points, dtype=torch.float32, device=device),
            torch.tensor(pixels, dtype=torch.float32, device=device))


def outside_body(landmarks: np.ndarray, affine: np.ndarray, res: int) -> np.ndarray:
    """``(res, res)`` bool: the crop (``affine`` from the photo) without the strip below
    the chin that a body hides (:func:`~head360cli.fitting.hair_class.hidden_by_body`),
    from the detected ``landmarks (68, 2)``: where a hairstyle's silhouette is scored."""
    from head360cli.fitting.hair_class import hidden_by_body

    return ~hidden_by_body(landmarks @ affine[:, :2].T + affine[:, 2], (res, res))


CLASSIFY_RES = 128
"""Side in pixels of the crop the hairstyles' silhouettes are compared in."""


def style_silhouettes(img, fit, model, res: int = CLASSIFY_RES) -> np.ndarray:
    """``(30, res, res)`` the hairstyles' silhouettes on the fitted head, seen from the
    photo's camera in its ``res``-pixel crop (they do not need the parse)."""
    from head360cli.fitting.hair_class import style_silhouettes as silhouettes

    frame = frame_photo(img, fit, model, res)
    return silhouettes(frame.neutral, frame.posed, model.faces, frame.c2w, frame.k, res)


def guess_hair(img, parse, fit, model, landmarks: np.ndarray,
               silhouettes: np.ndarray | None = None, res: int = CLASSIFY_RES,
               soft: bool = False):
    """Hairstyle ranking and hair colour of a parsed photo with its detected
    ``landmarks (68, 2)`` (and the styles' ``silhouettes`` when already made by
    :func:`style_silhouettes`): ``(guess, colour estimate, nearest corpus colour name, its
    RGB)``. The first styles are ranked with their shape fitted to the parsed hair
    (:func:`~head360cli.fitting.hair_shape.rank_shaped`; ``soft``: the hairlines of the
    generator that will render them)."""
    from head360cli.fitting.hair_class import (
        HAIR_AREA_CM2,
        classify_hair,
        hair_colour,
        nearest_colour_name,
    )
    from head360cli.fitting.hair_shape import rank_shaped
    from head360cli.fitting.texture import crop_mask
    from head360cli.synth.hair import HAIR_COLOURS

    frame = frame_photo(img, fit, model, res)
    hair = crop_mask(parse.hair, frame.affine, res)
    valid = crop_mask(np.ones(img.pixels.shape[:2], bool), frame.affine, res)
    valid &= outside_body(landmarks, frame.affine, res)
    face = crop_mask(parse.face, frame.affine, res)
    if silhouettes is None:
        silhouettes = style_silhouettes(img, fit, model, res)
    guess = classify_hair(hair, silhouettes, valid, face, HAIR_AREA_CM2)
    guess = rank_shaped(guess, silhouettes, frame.neutral, frame.posed, model.faces,
                        frame.c2w, frame.k, hair, valid, face, soft, HAIR_AREA_CM2)
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


def colour_by_render(gen, verts, cam, k, code, neutral: np.ndarray, style: int,
                      crop: np.ndarray, hair: np.ndarray, estimate: np.ndarray,
                      gain=None) -> tuple[str, np.ndarray, str]:
    """The hair colour the fitted head wears: of the :data:`COLOUR_CANDIDATES` SynHead-P
    colours nearest the tone curve's ``estimate``, the one whose render in ``style`` from
    the photo's camera (``cam (4, 4)``, ``k (3, 3)`` for ``crop``) differs least from the
    photo's hair pixels (``crop (R, R, 3)`` uint8, ``hair (R, R)`` bool), then matched to
    their median colour by render (:func:`~head360cli.fitting.hair_class.
    match_colour_by_render`): ``(nearest colour name, linear RGB, "render" or "tone
    curve")``. The generator renders a named colour close to, but
    not exactly as, the corpus renderer whose look the tone curve was fitted to. With
    ``gain (3,)`` (the photo's light, a tensor) the renders are drawn under it."""
    import dataclasses

    import cv2
    import torch

    from head360cli.fitting.hair_class import (
        match_colour_by_render,
        nearest_colour_name,
        nearest_colour_names,
        pick_colour_by_render,
    )
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
    shape = hair_for(neutral, [style], np.asarray(estimate, np.float32)[None],
                     soft=gen.soft_hairlines).to(verts.device)

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
    if not scores:
        return name, np.asarray(HAIR_COLOURS[name], np.float32), "tone curve"
    # the nearest named colour's render is where the match starts: any colour can result
    colour = match_colour_by_render(render, photo, small_hair, HAIR_COLOURS[name])
    return nearest_colour_name(colour), colour, "render"



def rig_intrinsics(res: int):
    from head360cli.geometry.cameras import RIG_FOV_DEG, intrinsics_from_fov

    return intrinsics_from_fov(RIG_FOV_DEG, res, res)


def grey_face(img, found) -> bool:
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


def masked_psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    """PSNR in dB of images of values 0 to 255 (``(H, W[, 3])``) inside a boolean mask
    ``(H, W)``."""
    d = (a.astype(np.float64) - b.astype(np.float64))[mask] / 255.0
    mse = float(np.mean(d ** 2)) if d.size else 0.0
    return 10 * np.log10(1.0 / max(mse, 1e-10))



"""Bald-head neural-texture inversion: the photo's camera, its aligned crop, the bald
target and the optimisation of the neural texture with the generator frozen.

The shape fit gives the photo's camera (model-to-camera rotation, translation, focal and
principal point). :func:`photo_camera` turns it into the generator's camera for a square
crop in which the head has the size it has in the training rig's views, so the generator
sees the scale it was trained at. :func:`invert_texture` first fits the texture code
``t`` (a few steps: a plausible head everywhere), then the neural texture itself, with L1
on the face region and two regularisers that keep what the photo does not show plausible:
staying near the generated texture, and left-right symmetry in texture space. The
texture's change from the generated one is a coarse grid, upsampled, plus a fine layer
held smooth: the feature planes read the texture more sparsely than its texels, and a
change fitted texel by texel showed as blotches at every other expression. While the
code is fitted the camera is refined photometrically, held near the detected landmarks.
Throughout, the colour of the photo's light is fitted too: a gain per channel on the
head's pixels (``InvertConfig.gain``), which the renders of the head apply after. Where
the photo's lips are closed or nearly so, the inside of the mouth keeps the generated
texture (``InvertConfig.closed_mouth``, :func:`region_texels`): a narrow gap shows it in
too few pixels to tell teeth from the dark behind them.
Each step renders only the square of the crop around the loss's pixels
(:func:`loss_window`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import time
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

__all__ = [
    "LUMA",
    "MOUTH_INSIDE",
    "PRESETS",
    "Inversion",
    "InvertConfig",
    "bald_target",
    "crop_image",
    "invert_texture",
    "loss_window",
    "photo_camera",
]


@dataclasses.dataclass(frozen=True)
class InvertConfig:
    """Settings of one inversion."""

    code_steps: int = 20
    """Steps fitting the texture code ``t`` (and refining the camera) before the texture
    itself: the fast preset's 30 (at ``code_samples`` 4), the quality preset's 60. More
    steps let the camera refinement settle (``docs/decisions.md``, the inversion's code
    steps)."""
    steps: int = 24
    """Most steps optimising the neural texture (the fast preset's count). The stopping
    rule rarely ends a fast fit early, so more steps cost time in proportion (about
    0.14 s a step on a 2-core CPU); 24 is where the face's fidelity stopped gaining
    (``docs/decisions.md``, the inversion's texture steps)."""
    samples: int = 6
    """Samples per ray while fitting (the generator's own count is used for output)."""
    code_samples: int | None = None
    """Samples per ray while the code and camera are fitted (``None``: ``samples``). The
    code stage moves the camera and a 64-number code, which a coarser render serves as
    well: the fast preset's 20 steps at 6 samples -> 30 at 4 took three held-out heads of
    corpus seed 1 from 17.63 to 18.14 dB over 72 views (21.75 -> 21.84 at the input view)
    and three of seed 2 from 15.91 to 16.88 (19.13 -> 19.86), and eight development
    photos' bald face PSNR from 27.33 to 27.98 dB (descriptor distance at 0 degrees 0.409
    -> 0.401). The ten more steps cost 0.5-1 s a fit (the astronaut from the command
    line, runs alternating with the 20-step code: 9.8-10.7 s -> 11.3-11.6 s; inversion
    5.1-5.6 -> 6.0-6.5 s); 30 steps at 6 samples scored the same (18.16 dB, 27.90) for
    about 1.5 s more, and 40 at 3 samples 18.30 / 17.43 dB and 27.85 for about 2 s
    more."""
    lr_code: float = 0.05
    """Adam learning rate of the code."""
    lr_texture: float = 0.3
    """Adam learning rate of the texture."""
    texture_stride: int = 3
    """The texture's change from the generated one is fitted on a grid this many texels
    apart and upsampled bilinearly. The hex-planes read the texture about once per 4 mm,
    and a face texel is 2.4-3.1 mm, so fitted texel by texel (stride 1) only the texels
    the planes read moved: the change came out in stripes, which every other expression
    (its mesh reads other texels) showed as blotches. Astronaut, fast / quality preset,
    dlib on a Live Link Face take: mouth opening against jawOpen r = -0.01 / 0.30 at
    stride 1, 0.81 / 0.81 at 2, 0.86 / 0.79 at 3, 0.86 / 0.80 at 4; stride 3 also kept
    the blinks' sign (eye opening r -0.20 and -0.54 fast). Held-out synthetic heads of
    corpus seed 1, true mesh, texture fitted on a smile: PSNR at neutral, jaw open and
    blink 0.1-0.2 dB above stride 1 with the fast preset, within 0.1 dB with quality.
    (These figures are for the grid alone; see ``fine_smooth`` for the layer added.)"""
    fine_smooth: float = 0.1
    """Weight of the mean squared Laplacian of a second, texel-by-texel layer of the
    change (0: no such layer). The coarse grid alone lost input-view detail: bald face
    PSNR on 5 development faces (scikit-image's camera man and astronaut, dlib's
    bald_guys; not the bench's photos) 26.23 -> 25.52 dB fast, 30.83 -> 29.11 quality.
    This layer brings most of it back (26.15 fast with 0.1, 30.58 quality with 0.01)
    while its smoothness keeps the texels the planes do not read moving with their
    neighbours: the astronaut's jawOpen r stays 0.89 fast, 0.83 quality (a weight of
    0.01 in the fast preset let it fall to 0.55)."""
    lr_fine: float = 0.1
    """Adam learning rate of that layer (at the texture's 0.3 the fast preset's short run
    overshot on one development face: 31.5 -> 26.0 dB)."""
    near: float = 0.02
    """Weight of the mean squared distance to the generated texture."""
    symmetry: float = 0.1
    """Weight of the L1 difference between the texture and its mirror image."""
    patience: int = 5
    """Stop when the loss has not improved by ``min_gain`` for this many steps."""
    min_gain: float = 0.002
    """Relative improvement that counts."""
    pose: bool = True
    """Refine the camera (a rotation about and a shift of the head) photometrically
    while the code is fitted: landmarks leave a few degrees of pitch and millimetres of
    translation that show as misaligned silhouettes in every other view."""
    lr_rotation: float = 0.02
    """Adam learning rate of the rotation (radians): landmarks of synthetic renders leave
    up to 10 degrees of pitch to correct."""
    lr_translation: float = 0.003
    """Adam learning rate of the translation (metres)."""
    anchor: float = 1200.0
    """Weight of the landmark term of the camera refinement: the mean, over the inner-face
    landmarks (brows, nose, eyes, mouth), of the squared distance in crop widths by which
    each one, projected with the refined camera, lies more than ``anchor_slack`` from
    where it was detected. Photometric error alone let the camera turn the head under
    the face by 16-23 degrees and 40 pixels where a photo's colours mislead it (a
    greyscale photo); on synthetic photos the refinement turns 4-9 degrees and moves the
    landmarks 1-3 pixels (pitch with a compensating shift, which landmarks cannot see),
    and the slack leaves that free. Used only when :func:`invert_texture` is given
    landmarks. The deferred generator's texture lookups pull the camera harder than the
    hex-planes did: at the hex-planes' 300, a synthetic head's held eyes ended 2.1 pixels
    from where they were seen (the held slack is 1.3); at 1200, 1.0."""
    anchor_slack: float = 0.02
    """Distance in crop widths (5 pixels at 256) a landmark may move freely."""
    held_slack: float = 0.005
    """The same for the landmarks :func:`invert_texture` is told to hold (``held``; the
    eyes, in ``fit``): 1.3 pixels at 256. With the eyes as free as the rest, the
    refinement slid real photos' inner landmarks 3 to 5 pixels from where they were
    detected (0.8 to 1.5 before it; seven development photos), mostly upwards: the
    texture then painted each eye partly on the upper lid's texels, which a blink slides
    down, so the eye looked as open or more at a blink of 0.1-0.3. Holding the eyes took
    the blink ramp's correlation with dlib's eye opening from -0.82 to -0.92 on five of
    them (front view, blinks 0 to 1), the jaw's from 0.87 to 0.97 (six), face PSNR 24.46
    -> 24.67 dB; held-out synthetic heads, where the refinement corrects the pitch that
    dlib's landmarks leave, lost 0.2 dB over 72 views (17.22 -> 17.02, ten heads of
    corpus seeds 1 and 2) and gained 0.1 at the input view (19.85 -> 19.95); the bench's
    two heads lost 1.05 dB with the fast preset and none with the quality preset's 40
    code steps. Holding all the landmarks within 1.3 pixels, or their mean within 1,
    cost the ten heads 0.9 and 1.0 dB."""
    coverage: float = 0.5
    """Weight of the face pixels the render leaves uncovered (1 - alpha on the mask)."""
    preview_samples: int | None = 6
    """Samples per ray of the fit's preview (``None``: the generator's own)."""
    gain: bool = True
    """Fit the colour of the photo's light: a gain per colour channel on the head's
    pixels (the backdrop stays white), their geometric mean 1, with the code and then
    with the texture: :class:`Inversion` ``gain``, which a head file keeps as
    ``colour_gain`` and every render applies. The generator draws skin in the corpus'
    colours, and the texture's change from the generated one could not leave them
    (``docs/decisions.md``, the photo's light)."""
    lr_gain: float = 0.02
    """Adam learning rate of the gain's logarithm."""
    gain_prior: float = 0.1
    """Weight of the mean squared logarithm of the gain while the code is fitted. Chosen
    with the gain free in brightness too, on six development photos (four as they are,
    two under a blue light), fast preset, face PSNR 21.94 dB without the gain; with it
    fitted in the code steps only (kept while the texture is fitted) 24.57 without a
    prior (AFLW2000-3D 03614 2.5 dB below its fit without the gain), 24.66 at 0.1;
    fitted in both stages 25.07 without a prior and 25.18 at 0.1 (03614 1.0 dB
    above)."""
    project: bool = True
    """With a deferred generator, start the texture steps from the photo projected into
    the texture (:func:`~head360cli.fitting.project.project_photo`: the photo where it
    sees the surface, its mirror image where it sees the other side, the code's skin in
    the photo's tone elsewhere) instead of the code's texture. Colour photos only."""
    window: bool = True
    """Render only the square of the image that holds the loss's pixels (those where
    ``mask`` is not zero, with a border wider than the RefineNet's reach, so they come
    out as in the whole image). A photo's face region fills about a fifth of the crop:
    on the astronaut the square is 172 of 256 pixels wide, and its fast inversion took
    5.5-7.2 s instead of 7.8-9.4 s (alternating runs in one process, 2 cores).
    ``False``: the whole image (the same losses, to float rounding)."""
    closed_mouth: float = 0.09
    """The photo's lips count as closed below this gap (:func:`~head360cli.fitting.
    landmarks.mouth_opening`: the inner lips' gap over the outer eye corners' distance);
    ``fit`` then keeps the generated texture on the inside of the mouth
    (:data:`MOUTH_INSIDE`, the ``keep`` of :func:`invert_texture`): the few pixels a
    narrow gap shows had painted teeth and lips over the dark inside, which then filled
    the mouth at every jawOpen (``docs/decisions.md``, the closed mouth). ``0``: always
    fitted."""
    grey: bool = False
    """The photo is greyscale: the photometric loss compares the render's grey
    (:data:`LUMA`, as a greyscale conversion weighs the channels) with the photo's, so
    the texture fits the photo's shading and keeps the generated texture's colour, held
    there by ``near`` and ``symmetry``. ``fit`` sets it for a grey photo (and fits no
    light). Fitted in colour, a grey photo's face came out grey, some of it tinted green
    or pink, on a head whose unseen skin is the generator's colour."""

    def __post_init__(self) -> None:
        if self.texture_stride < 1:
            raise ValueError(f"expected texture_stride >= 1, found {self.texture_stride}")
        if self.fine_smooth < 0:
            raise ValueError(f"expected fine_smooth >= 0, found {self.fine_smooth}")
        if not 0 <= self.held_slack <= self.anchor_slack:
            raise ValueError(f"expected 0 <= held_slack <= anchor_slack "
                             f"({self.anchor_slack}), found {self.held_slack}")
        if self.closed_mouth < 0:
            raise ValueError(f"expected closed_mouth >= 0, found {self.closed_mouth}")
        if self.code_samples is not None and self.code_samples < 1:
            raise ValueError(f"expected code_samples >= 1 or None, found {self.code_samples}")


LUMA = (0.299, 0.587, 0.114)
"""Weights of red, green and blue in a grey value (ITU-R BT.601, what Pillow's and
OpenCV's greyscale conversions use)."""


DEFERRED_RATES = (0.2, 0.1)
"""What the texture steps' rates (``lr_texture``, ``lr_fine``, tuned for the hex-plane
generator) are multiplied by for the deferred generator. It reads each texel only where
its surface is seen, so Adam moved every texel the photo touches by the full rate at
once: at the presets' own rates its fast fits came out speckled (the astronaut 17.9 dB
at the input view). Chosen on the development photos AFLW2000-3D 00516 and 01322: 19.91
and 16.48 dB, against 19.69 and 16.37 at 0.67 and 0.5 times, 19.74 and 16.41 at 0.1 and
0.05 times."""

PRESETS: dict[str, InvertConfig] = {
    "fast": InvertConfig(code_steps=30, code_samples=4),
    "quality": InvertConfig(code_steps=60, steps=80, samples=12, lr_texture=0.2,
                            fine_smooth=0.01, lr_fine=0.2,
                            patience=10, min_gain=0.001, preview_samples=None),
}
"""The ``--preset`` choices of ``head360 fit``."""


@dataclasses.dataclass
class Inversion:
    """Result of :func:`invert_texture`.

    Attributes:
        texture: ``(C, R, R)`` the fitted neural texture.
        code: ``(code_dim,)`` the fitted texture code it started from.
        c2w: ``(4, 4)`` the camera, refined when the config says so.
        losses: Loss after each step (code steps first).
        steps: Steps run (code and texture).
        seconds: Wall time.
    """

    texture: torch.Tensor
    code: torch.Tensor
    c2w: torch.Tensor
    losses: list[float]
    steps: int
    seconds: float
    gain: torch.Tensor | None = None
    """``(3,)`` the colour of the photo's light: the gain per channel (geometric mean 1)
    on the head's pixels under which the texture was fitted (``None`` without
    ``InvertConfig.gain``)."""


def photo_camera(rotation: np.ndarray, translation: np.ndarray, focal: float,
                 centre: np.ndarray, res: int = 256
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The generator's camera for a ``res`` x ``res`` crop of a photo.

    Args:
        rotation: ``(3, 3)`` model-to-camera rotation (OpenCV axes) from the shape fit.
        translation: ``(3,)`` metres.
        focal: Focal length in the photo's pixels.
        centre: ``(2,)`` principal point in the photo's pixels.
        res: Crop resolution.

    Returns:
        ``c2w (4, 4)``, crop ``intrinsics (3, 3)`` and the ``(2, 3)`` affine map from photo
        pixels to crop pixels. The head fills the crop as it fills the rig's views.
    """
    from head360cli.geometry.cameras import RIG_DISTANCE, RIG_FOV_DEG, RIG_TARGET

    r = np.asarray(rotation, np.float64)
    t = np.asarray(translation, np.float64)
    c2w = np.eye(4)
    c2w[:3, :3] = r.T
    c2w[:3, 3] = -r.T @ t
    target = r @ np.asarray(RIG_TARGET) + t
    px = focal * target[:2] / target[2] + np.asarray(centre, np.float64)
    rig_focal = 0.5 * res / np.tan(np.radians(RIG_FOV_DEG) / 2)
    # Same pixels per metre at the head as the rig: side of the crop in photo pixels.
    side = res * (focal / target[2]) / (rig_focal / RIG_DISTANCE)
    s = res / side
    x0, y0 = px - side / 2
    affine = np.array([[s, 0.0, -x0 * s], [0.0, s, -y0 * s]])
    k = np.array([[focal * s, 0.0, (centre[0] - x0) * s],
                  [0.0, focal * s, (centre[1] - y0) * s], [0.0, 0.0, 1.0]])
    return c2w.astype(np.float32), k.astype(np.float32), affine


def crop_image(image: np.ndarray, affine: np.ndarray, res: int, *,
               nearest: bool = False) -> np.ndarray:
    """Warp ``image (H, W[, 3])`` with ``affine (2, 3)`` into ``res`` x ``res``.

    Photos (``nearest=False``) are interpolated bilinearly and their edges replicated
    beyond the photo; masks (``nearest=True``) are sampled nearest and are 0 beyond it.
    """
    import cv2

    if nearest:
        return cv2.warpAffine(image, affine, (res, res), flags=cv2.INTER_NEAREST,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return cv2.warpAffine(image, affine, (res, res), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)


def crop_mask(mask: np.ndarray, affine: np.ndarray, res: int) -> np.ndarray:
    """A boolean ``(H, W)`` mask warped like :func:`crop_image` (nearest; ``False`` beyond
    the photo). ``crop_mask(np.ones(shape, bool), ...)`` is where the crop has photo."""
    return crop_image(mask.astype(np.uint8), affine, res, nearest=True) > 0


def bald_target(crop: np.ndarray, hair: np.ndarray, bald_render: np.ndarray) -> np.ndarray:
    """The photo crop with its hair replaced by the model's bald render, Poisson-blended.

    Args:
        crop: ``(R, R, 3)`` uint8 aligned photo.
        hair: ``(R, R)`` bool hair mask in the crop.
        bald_render: ``(R, R, 3)`` uint8 bald render from the same camera.

    Returns:
        ``(R, R, 3)`` uint8, the crop where there is no hair.
    """
    import cv2

    m = cv2.dilate(hair.astype(np.uint8) * 255, np.ones((5, 5), np.uint8))
    m[:2] = 0  # seamlessClone needs a margin inside the image
    m[-2:] = 0
    m[:, :2] = 0
    m[:, -2:] = 0
    if not m.any():
        return crop.copy()
    x, y, w, h = cv2.boundingRect(m)
    # seamlessClone centres the mask's bounding box (its last pixel exclusive) here.
    centre = (x + (w - 1) // 2, y + (h - 1) // 2)
    blended = cv2.seamlessClone(np.ascontiguousarray(bald_render),
                                np.ascontiguousarray(crop), m.copy(), centre,
                                cv2.NORMAL_CLONE)  # it may overwrite the mask
    # OpenCV solves over the mask's whole bounding box; keep the photo outside the mask.
    return np.where(m[..., None] > 0, blended, crop)


def loss_window(mask: torch.Tensor, ratio: int, margin: int) -> tuple[int, int, int]:
    """The square of an image that holds every pixel where ``mask`` is not zero.

    Args:
        mask: ``(H, W)`` with ``H == W``, a multiple of ``ratio``.
        ratio: The square's corner and side are multiples of this (the generator's
            ``image_res / render_res``, so its low-resolution pixels are the image's).
        margin: Pixels kept around the mask's bounding box.

    Returns:
        ``(x0, y0, side)``: columns ``x0 .. x0 + side`` and rows ``y0 .. y0 + side``,
        inside the image; the whole image when the mask is empty or the square would be
        as large.
    """
    size = mask.shape[-1]
    rows = torch.nonzero(mask.any(1)).squeeze(1)
    cols = torch.nonzero(mask.any(0)).squeeze(1)
    if len(rows) == 0:
        return 0, 0, size
    span = []
    for hit in (cols, rows):  # [lo, hi) grown by the margin, out to multiples of ratio
        lo = max(0, int(hit[0]) - margin) // ratio * ratio
        hi = -(-min(size, int(hit[-1]) + 1 + margin) // ratio) * ratio
        span.append((lo, hi))
    side = max(max(hi - lo for lo, hi in span), 8 * ratio)
    if side >= size:
        return 0, 0, size
    x0, y0 = (min(lo, size - side) for lo, _ in span)
    return x0, y0, side


@functools.lru_cache(maxsize=4)
def mirror_grid(res: int) -> torch.Tensor:
    """``(1, res, res, 2)`` sampling grid that mirrors a ``res`` x ``res`` texture left to
    right on the head: each texel reads the texel whose surface point is its mirror image
    (x -> -x) on the mean head. Texels off the UV islands read themselves.

    Kept in head360's cache (:mod:`head360cli.cache`) under the bilinear model's hash:
    making it imports ``scipy.spatial``, about 0.5 s of a fit's first second."""
    from head360cli.cache import cached_array
    from head360cli.mesh.bilinear import load_bilinear

    model = load_bilinear()
    name = f"mirror-grid-{model.meta['sha256'][:16]}-{res}.npy"
    grid = cached_array(name, lambda: _make_mirror_grid(model, res), (res, res, 2),
                        np.float32)
    return torch.from_numpy(grid.copy())[None]


def _uv_fragments(model, res: int):
    """The bilinear ``model``'s UV layout rasterized onto a ``res`` x ``res`` texture:
    which triangle each texel lies on (``face_id`` -1 off the UV islands)."""
    from head360cli.geometry.rasterize import rasterize

    uv = torch.tensor(model.uv, dtype=torch.float32) * res
    return rasterize(uv[None], torch.ones(1, len(uv)), torch.as_tensor(model.faces_uv),
                     res, res, perspective_correct=False)


def _make_mirror_grid(model, res: int) -> np.ndarray:
    """:func:`mirror_grid`'s ``(res, res, 2)`` float32 grid for the bilinear ``model``."""
    from scipy.spatial import cKDTree

    from head360cli.geometry.rasterize import interpolate_face_corners

    verts = model.vertices(np.zeros(model.rank), np.zeros(52))
    frags = _uv_fragments(model, res)
    corners = torch.tensor(verts, dtype=torch.float32)[torch.as_tensor(model.faces)]
    pos = interpolate_face_corners(corners, frags)[0].numpy()
    part = frags.face_id[0].numpy()
    rows, cols = np.mgrid[0:res, 0:res]
    grid = np.stack([(cols + 0.5) / res, (rows + 0.5) / res], -1)
    valid = part >= 0
    mirrored = pos[valid] * np.array([-1.0, 1.0, 1.0])
    _, nearest = cKDTree(pos[valid]).query(mirrored)
    grid[valid] = grid[valid][nearest]
    return (grid * 2.0 - 1.0).astype(np.float32)


MOUTH_INSIDE = ("mouth_interior", "teeth", "tongue")
"""The template regions (:data:`~head360cli.mesh.template.REGION_NAMES`) inside the
mouth."""


@functools.lru_cache(maxsize=4)
def region_texels(res: int, regions: tuple[str, ...] = MOUTH_INSIDE) -> torch.Tensor:
    """``(res, res)`` bool: the texels of a ``res`` x ``res`` texture that lie on the
    template's triangles wholly inside the named ``regions``.

    Raises:
        ValueError: A name that is not a template region.
    """
    from head360cli.mesh.bilinear import load_bilinear
    from head360cli.mesh.template import REGION_NAMES

    unknown = [r for r in regions if r not in REGION_NAMES]
    if unknown:
        raise ValueError(f"expected template regions ({', '.join(REGION_NAMES)}), found "
                         f"{unknown}")
    model = load_bilinear()
    face = _uv_fragments(model, res).face_id[0].numpy()
    inside = np.isin(model.region[model.faces],
                     [REGION_NAMES.index(r) for r in regions]).all(1)
    return torch.from_numpy((face >= 0) & inside[np.clip(face, 0, None)])


def _laplacian(x: torch.Tensor) -> torch.Tensor:
    """``(..., R - 2, R - 2)`` discrete Laplacian (4 x centre - the 4 neighbours) of the
    inner texels of ``(..., R, R)``."""
    return 4 * x[..., 1:-1, 1:-1] - x[..., :-2, 1:-1] - x[..., 2:, 1:-1] \
        - x[..., 1:-1, :-2] - x[..., 1:-1, 2:]


def _mirror(texture: torch.Tensor) -> torch.Tensor:
    """``(B, C, R, R)`` texture mirrored left-right on the head."""
    grid = mirror_grid(texture.shape[-1]).to(texture)
    return torch.nn.functional.grid_sample(texture, grid.expand(len(texture), -1, -1, -1),
                                           mode="nearest", align_corners=False)


NO_DETERMINISTIC_KERNEL = r".* does not have a deterministic implementation"
"""Matches torch's warning for a kernel with no deterministic version (a regular
expression for :func:`warnings.filterwarnings`)."""


@contextlib.contextmanager
def _deterministic():
    """Deterministic torch kernels inside, the caller's setting restored after.

    Same photo, same fit: with several CPU threads some backward passes accumulate in a
    varying order, and 20 steps of camera refinement grew those last bits into fits
    0.2 dB apart. Deterministic kernels cost nothing measurable here (2 threads).

    The flag is set through ``torch._C`` where it exists: the public
    ``torch.use_deterministic_algorithms`` also sets the flag of the inductor compiler,
    which we never use, and importing it took 1.0-1.5 s of a 15 s fast fit.

    On a GPU some kernels have no deterministic version (CUDA's backward of
    ``grid_sample``): torch runs the usual one there and says so in a ``UserWarning``,
    which every ``fit --device cuda`` printed; it is silenced here. Two fits of one
    photo on a GPU may therefore differ in their last bits.
    """
    before = (torch.are_deterministic_algorithms_enabled(),
              torch.is_deterministic_algorithms_warn_only_enabled())
    setter = getattr(torch._C, "_set_deterministic_algorithms", None)
    if setter is None:  # a torch without the private setter
        setter = torch.use_deterministic_algorithms
    setter(True, warn_only=True)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=NO_DETERMINISTIC_KERNEL,
                                    category=UserWarning)
            yield
    finally:
        setter(before[0], warn_only=before[1])


def invert_texture(gen, verts: torch.Tensor, c2w: torch.Tensor, intrinsics: torch.Tensor,
                   target: torch.Tensor, mask: torch.Tensor, start_code: torch.Tensor,
                   cfg: InvertConfig = PRESETS["fast"],
                   progress: Callable[[int, int, float], None] | None = None,
                   landmarks: tuple[torch.Tensor, torch.Tensor] | None = None,
                   held: torch.Tensor | None = None,
                   keep: torch.Tensor | None = None) -> Inversion:
    """Fit the neural texture of a bald head to a photo, the generator frozen.

    Args:
        gen: The :class:`~head360cli.model.generator.Generator`.
        verts: ``(V, 3)`` the fitted mesh.
        c2w: ``(4, 4)`` and ``intrinsics (3, 3)``: the crop's camera.
        target: ``(3, H, W)`` bald target in [0, 1] at ``gen.cfg.image_res``.
        mask: ``(1, H, W)`` weights of the photometric loss (the face region).
        start_code: ``(code_dim,)`` where the code starts (the mean training code).
        cfg: Steps and weights.
        progress: Called with ``(step, total, loss)`` after each step.
        landmarks: Optional ``(points (L, 3), pixels (L, 2))``: landmark positions on
            ``verts`` and where the photo shows them in the crop; they anchor the camera
            refinement (``cfg.anchor``). Use landmarks fixed on the surface (not the jaw
            contour, which slides with the view).
        held: Optional ``(L,)`` bool: the landmarks held within ``cfg.held_slack``
            instead of ``cfg.anchor_slack`` (``fit`` holds the eyes).
        keep: Optional ``(R, R)`` bool: texels that keep the texture of the fitted code
            (``fit`` keeps the inside of a closed mouth: ``cfg.closed_mouth``).

    Returns:
        The fitted texture (the lowest-loss texture of the texture steps) and code.
    """
    _check_invert_inputs(gen, landmarks, held, keep)
    t0 = time.perf_counter()
    gen.requires_grad_(False)
    problem = _Problem.make(gen, verts, intrinsics, target, mask, cfg)
    slack = None
    if landmarks is not None:
        slack = torch.full_like(landmarks[1][:, 0], cfg.anchor_slack)
        if held is not None:
            slack = torch.where(held.to(slack.device), cfg.held_slack, slack)
    losses: list[float] = []
    total = cfg.code_steps + cfg.steps
    with torch.no_grad():  # the mesh stays put: rasterized onto the planes once
        raster = gen.plane_raster(problem.v)
    with gen.samples_per_ray(cfg.samples), gen.image_size(problem.side), _deterministic():
        code, cam, log_gain = _fit_code(problem, raster, start_code, c2w, intrinsics,
                                        landmarks, slack, losses, progress, total)
        start, seen = None, None
        if cfg.project and not cfg.grey and gen.kind == "deferred":
            start, seen = _projected(problem, code, cam, log_gain, keep)
        texture, log_gain = _fit_texture(problem, raster, code, cam, log_gain, keep, losses,
                                         progress, total, start, seen)
    return Inversion(texture[0], code.detach()[0], cam[0], losses, len(losses),
                     time.perf_counter() - t0, _light(log_gain) if cfg.gain else None)


def _check_invert_inputs(gen, landmarks, held, keep) -> None:
    """Refuse ``invert_texture`` arguments of the wrong shape or type.

    Raises:
        ValueError: Naming the argument, what was expected and what was found.
    """
    if landmarks is not None:
        shapes = tuple(tuple(x.shape) for x in landmarks)
        if len(shapes) != 2 or len(shapes[0]) != 2 or shapes[0][1:] != (3,) \
                or shapes[1] != (shapes[0][0], 2):
            raise ValueError(f"expected landmarks as (points (L, 3), pixels (L, 2)), "
                             f"found shapes {shapes}")
    if held is not None and (landmarks is None or tuple(held.shape) != (len(landmarks[0]),)
                             or held.dtype != torch.bool):
        found = "no landmarks" if landmarks is None else \
            f"{held.dtype} of shape {tuple(held.shape)} for {len(landmarks[0])} landmarks"
        raise ValueError(f"expected held as a (L,) bool tensor over the landmarks, found "
                         f"{found}")
    texels = gen.cfg.texture_res
    if keep is not None and (tuple(keep.shape) != (texels, texels)
                             or keep.dtype != torch.bool):
        raise ValueError(f"expected keep as a ({texels}, {texels}) bool tensor over the "
                         f"texels, found {keep.dtype} of shape {tuple(keep.shape)}")


def _reach_pixels(gen) -> int:
    """Output pixels around a change within which the generator's image network (the
    RefineNet or the deferred ScreenNet) can change its output."""
    if gen.kind == "deferred":
        return gen.refine.reach
    return gen.refine.reach * (gen.cfg.image_res // gen.cfg.render_res)


def _light(log: torch.Tensor) -> torch.Tensor:
    """The gain of logarithms ``log (3,)`` less their mean: a colour, its geometric mean 1
    (the brightness is the texture's to fit)."""
    return (log - log.mean()).exp()


@dataclasses.dataclass
class _Problem:
    """What both stages of an inversion compare the generator's renders with: the target
    and the loss's weights at both resolutions, cut to the loss's window."""

    gen: Any
    cfg: InvertConfig
    v: torch.Tensor
    """``(1, V, 3)`` the fitted mesh."""
    k: torch.Tensor
    """``(1, 3, 3)`` intrinsics of the window."""
    side: int
    """The window's side in pixels (the image's when the window is off)."""
    width: int
    """The whole crop's side in pixels."""
    tgt: torch.Tensor
    m: torch.Tensor
    area: torch.Tensor
    low_t: torch.Tensor
    low_m: torch.Tensor
    low_area: torch.Tensor
    luma: torch.Tensor

    @classmethod
    def make(cls, gen, verts: torch.Tensor, intrinsics: torch.Tensor, target: torch.Tensor,
             mask: torch.Tensor, cfg: InvertConfig) -> _Problem:
        v, k = verts[None], intrinsics[None]
        tgt, m = target[None], mask[None]
        area = m.sum().clamp_min(1.0)
        res = gen.cfg.render_res
        low_t = torch.nn.functional.interpolate(tgt, size=(res, res), mode="area")
        low_m = torch.nn.functional.interpolate(m, size=(res, res), mode="area")
        low_area = low_m.sum().clamp_min(1.0)
        size = target.shape[-1]
        ratio = size // res
        x0, y0, side = 0, 0, size
        if cfg.window and gen.refine is not None:
            # twice the RefineNet's reach: the square's own edges change nothing inside it
            x0, y0, side = loss_window(mask[0] != 0, ratio, 2 * _reach_pixels(gen))
        if side < size:  # the same camera, its image cut to the square
            k = k.clone()
            k[:, 0, 2] -= x0
            k[:, 1, 2] -= y0
            tgt, m = (x[..., y0:y0 + side, x0:x0 + side] for x in (tgt, m))
            lx, ly, ls = x0 // ratio, y0 // ratio, side // ratio
            low_t, low_m = (x[..., ly:ly + ls, lx:lx + ls] for x in (low_t, low_m))
        luma = torch.tensor(LUMA, dtype=target.dtype, device=target.device).view(1, 3, 1, 1)
        problem = cls(gen, cfg, v, k, side, size, tgt, m, area, low_t, low_m, low_area, luma)
        if cfg.grey:  # a grey photo: its grey against the render's, the colour left free
            problem.tgt, problem.low_t = problem.grey(tgt), problem.grey(low_t)
        return problem

    def grey(self, x: torch.Tensor) -> torch.Tensor:
        """``(B, 3, H, W)`` -> ``(B, 1, H, W)``, channels weighted by :data:`LUMA`."""
        return (x * self.luma).sum(1, keepdim=True)

    def photometric(self, out: dict, log_gain: torch.Tensor) -> torch.Tensor:
        """L1 between the render ``out`` (under the light ``log_gain`` when fitted) and
        the target, weighted, at both resolutions."""
        from head360cli.model.render import lit

        rgb, rgb_low = out["rgb"], out["rgb_low"]
        if self.cfg.gain:  # the head's pixels under the photo's light, the backdrop white
            g = _light(log_gain).view(1, 3, 1, 1)
            rgb = lit(rgb, out["alpha"], g)
            rgb_low = lit(rgb_low, out["alpha_low"], g)
        if self.cfg.grey:
            rgb, rgb_low = self.grey(rgb), self.grey(rgb_low)
        channels = 1 if self.cfg.grey else 3
        return ((rgb - self.tgt).abs() * self.m).sum() / (channels * self.area) + 0.5 * (
            (rgb_low - self.low_t).abs() * self.low_m).sum() / (channels * self.low_area)


def _turned(c2w: torch.Tensor, rot: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
    """``(1, 4, 4)``: the camera ``c2w`` turned by ``rot`` (axis-angle) about the head's
    origin and shifted across its line of sight. Not along it: a photo hardly shows the
    head's distance (its size stands in), and the few centimetres a refinement drifts
    there move the head by tens of pixels in side views."""
    forward = c2w[:3, 2]  # the line of sight
    shift = shift - (shift @ forward) * forward
    skew = torch.zeros(3, 3, dtype=rot.dtype, device=rot.device)
    skew[0, 1], skew[0, 2], skew[1, 2] = -rot[2], rot[1], -rot[0]
    skew = skew - skew.T
    delta = torch.eye(4, dtype=rot.dtype, device=rot.device)
    delta = torch.cat([torch.cat([torch.linalg.matrix_exp(skew), shift[:, None]], 1),
                       delta[3:]], 0)
    return (delta @ c2w)[None]


def _landmark_error(cam: torch.Tensor, landmarks, slack: torch.Tensor,
                    intrinsics: torch.Tensor, width: int) -> torch.Tensor:
    """Mean squared distance, in crop widths, by which the landmarks seen from ``cam``
    lie beyond their ``slack (L,)`` of where they were detected."""
    from head360cli.geometry.cameras import project

    points, pixels = landmarks
    seen, _ = project(points[None], cam, intrinsics[None])
    off = ((seen[0] - pixels) / width).norm(dim=-1)
    return (off - slack).clamp_min(0.0).square().mean()


def _fit_code(problem: _Problem, raster, start_code: torch.Tensor, c2w: torch.Tensor,
              intrinsics: torch.Tensor, landmarks, slack, losses: list[float], progress,
              total: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The code steps: the texture code, the camera (held by the landmarks) and the
    light. Returns ``(code (1, D), refined camera (1, 4, 4), light's log (3,))``."""
    from head360cli.fitting.adam import Adam

    gen, cfg = problem.gen, problem.cfg
    log_gain = torch.zeros(3, dtype=problem.tgt.dtype, device=problem.tgt.device,
                           requires_grad=cfg.gain)
    code = start_code.detach().clone()[None].requires_grad_(True)
    rot = torch.zeros(3, dtype=c2w.dtype, device=c2w.device, requires_grad=True)
    shift = torch.zeros(3, dtype=c2w.dtype, device=c2w.device, requires_grad=True)
    groups = [{"params": [code], "lr": cfg.lr_code}]
    if cfg.pose:
        groups += [{"params": [rot], "lr": cfg.lr_rotation},
                   {"params": [shift], "lr": cfg.lr_translation}]
    if cfg.gain:
        groups.append({"params": [log_gain], "lr": cfg.lr_gain})
    opt = Adam(groups)
    with gen.samples_per_ray(cfg.code_samples):
        for step in range(cfg.code_steps):
            cam = _turned(c2w, rot, shift)
            out = gen(problem.v, cam, problem.k, code=code, plane_raster=raster)
            loss = problem.photometric(out, log_gain) + 1e-3 * code.square().mean()
            if cfg.gain:
                loss = loss + cfg.gain_prior * _light(log_gain).log().square().mean()
            if cfg.pose:
                loss = loss + cfg.coverage * ((1.0 - out["alpha"]) * problem.m).sum() \
                    / problem.area
                if landmarks is not None:
                    loss = loss + cfg.anchor * _landmark_error(cam, landmarks, slack,
                                                                intrinsics, problem.width)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(float(loss.detach()))
            if progress:
                progress(step + 1, total, losses[-1])
    with torch.no_grad():
        cam = _turned(c2w, rot, shift)
    return code.detach(), cam, log_gain.detach()


def _projected(problem: _Problem, code: torch.Tensor, cam: torch.Tensor,
               log_gain: torch.Tensor, keep: torch.Tensor | None = None
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """``(1, C, R, R)``: the photo projected into the code's texture (see
    :attr:`InvertConfig.project`), the ``keep (R, R)`` texels left the code's (the inside
    of a closed mouth, which the photo shows only as the lips in front of it); and the
    ``(R, R)`` weight of each texel's own read of the photo."""
    from head360cli.fitting.project import project_photo
    from head360cli.mesh.bilinear import load_bilinear

    gen = problem.gen
    mirror = torch.as_tensor(load_bilinear().vertex_mirror, device=problem.v.device)
    with torch.no_grad():
        start = gen.texture(code)
    light = _light(log_gain) if problem.cfg.gain else None
    made = project_photo(gen, problem.v[0], mirror, cam[0], problem.k[0], problem.tgt[0],
                         problem.m[0], start, light)
    texture = made.texture
    if keep is not None:
        texture = torch.where(keep.to(texture.device), start, texture)
    return texture, made.photo


SEEN_FROM = 0.1
"""Weight of a texel's own read of the photo from which the texture steps fit it, at
their full rate (see :func:`_fit_texture`)."""
SEEN_REACH = 3
"""Texels by which the texture steps may reach past those the photo sees (see
:func:`_fit_texture`)."""


def _fit_texture(problem: _Problem, raster, code: torch.Tensor, cam: torch.Tensor,
                 log_gain: torch.Tensor, keep, losses: list[float], progress, total: int,
                 start: torch.Tensor | None = None, seen: torch.Tensor | None = None
                 ) -> tuple[torch.Tensor, torch.Tensor]:
    """The texture steps: the change of the ``start`` texture (default: the code's) on a
    coarse grid plus a smooth fine layer, and the light, with the camera fixed; stops
    when the loss stalls. With ``seen (R, R)`` (a projected start's weights of the
    photo's own reads) the change of each texel is scaled by it: a texel the photo sees
    edge-on or not at all keeps what the projection gave it. Returns ``(the lowest-loss
    texture (1, C, R, R), light's log (3,))``."""
    from head360cli.fitting.adam import Adam

    gen, cfg = problem.gen, problem.cfg
    if start is None:
        with torch.no_grad():
            start = gen.texture(code)
    log_gain = log_gain.requires_grad_(cfg.gain)
    side = start.shape[-1]
    delta = torch.zeros(*start.shape[:2], -(-side // cfg.texture_stride),
                        -(-side // cfg.texture_stride), dtype=start.dtype,
                        device=start.device, requires_grad=True)
    rates = DEFERRED_RATES if gen.kind == "deferred" else (1.0, 1.0)
    groups = [{"params": [delta], "lr": cfg.lr_texture * rates[0]}]
    if cfg.gain:  # the light may move with the texture, near what the code found
        groups.append({"params": [log_gain], "lr": cfg.lr_gain})
    fine = None  # the smooth texel-by-texel layer, when the config has one
    if cfg.fine_smooth > 0:
        fine = torch.zeros_like(start, requires_grad=True)
        groups.append({"params": [fine], "lr": cfg.lr_fine * rates[1]})
    opt = Adam(groups)

    free = None if keep is None else (~keep).to(start)  # the texels that may change
    if seen is not None:
        # Fitted everywhere, the change painted the few pixels of texels seen edge-on
        # (cheeks beside the ears, the hairline's border) over the many pixels they
        # cover from the side: dark blotches on a curly-haired woman's cheeks at 45-135
        # degrees, her fringe's outline on the forehead.
        # The weights grown by SEEN_REACH texels: the eroded ring at the face mask's
        # edge, which the projection leaves to the code, is still fitted.
        seen = torch.nn.functional.max_pool2d((seen > SEEN_FROM)[None, None].to(start),
                                              2 * SEEN_REACH + 1, stride=1,
                                              padding=SEEN_REACH)[0, 0]
        free = seen if free is None else free * seen

    def fitted() -> torch.Tensor:
        coarse = delta if cfg.texture_stride == 1 else torch.nn.functional.interpolate(
            delta, size=(side, side), mode="bilinear", align_corners=False)
        if free is not None:
            return start + (coarse if fine is None else fine + coarse) * free
        return (start if fine is None else start + fine) + coarse

    rays: dict[str, torch.Tensor] = {}  # the camera is fixed now: rasterized once

    def texture_loss(texture: torch.Tensor) -> torch.Tensor:
        loss = problem.photometric(gen(problem.v, cam, problem.k, texture=texture,
                                       plane_raster=raster, view_rays=rays), log_gain)
        loss = loss + cfg.near * (texture - start).square().mean() \
            + cfg.symmetry * (texture - _mirror(texture)).abs().mean()
        if fine is not None:
            loss = loss + cfg.fine_smooth * _laplacian(fine).square().mean()
        return loss

    best, since = float("inf"), 0
    kept, kept_loss = None, float("inf")  # the best texture seen, and its loss
    for step in range(cfg.steps):
        texture = fitted()
        loss = texture_loss(texture)
        value = float(loss.detach())
        if value < kept_loss:
            kept, kept_loss = texture.detach(), value
            kept_gain = log_gain.detach().clone()
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(value)
        if progress:
            progress(cfg.code_steps + step + 1, total, value)
        if value < best * (1.0 - cfg.min_gain):
            best, since = value, 0
        else:
            since += 1
            if since >= cfg.patience:
                break
    # The last update has not been scored yet; whichever scores lower is returned. The
    # first texture steps can overshoot (Adam moves every texel by the full rate at
    # once): on held-out synthetic heads with the true mesh the stopping rule ended
    # fast fits above where they started, 28.6 dB over 72 views against 31.5 kept.
    texture = fitted().detach()
    if kept is not None:
        with torch.no_grad():
            if float(texture_loss(texture)) > kept_loss:
                texture = kept
                log_gain = kept_gain
    return texture, log_gain.detach()

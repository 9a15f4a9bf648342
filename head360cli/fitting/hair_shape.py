"""The hairstyle's volume and length fitted to the photo's hair.

A SynHead-P style is one rule for everyone: a crew cut 1 cm thick, a bob that ends 1.2 cm
above the chin. A person's hair is thicker or thinner, longer or shorter. The fit scales
the style's thickness over the head by direction (:func:`head360cli.synth.hair.warp_hair`,
:data:`~head360cli.synth.hair.WARP_BINS` directions around the head's forward axis) so
that its silhouette from the photo's camera ends where the parsed hair ends: along each
direction's ray in the image, from the bald head's edge outwards, the style's hair and
the parsed hair are measured and the scale follows their ratio, a few times over.
Directions the photo cannot tell (beyond its edge, behind the body) keep the style's own
thickness. The scale holds all round the head, so the back and the sides the photo does
not show take the volume the photo's outline shows.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

__all__ = [
    "CANDIDATES",
    "END_SHIFTS",
    "EXTRA_SUPPORT",
    "ITERATIONS",
    "SCALE_RANGE",
    "HairShape",
    "extras_support",
    "fit_hair_end",
    "fit_hair_scale",
    "fit_hair_shape",
    "rank_shaped",
    "ray_directions",
]

SCALE_RANGE = (0.35, 3.0)
"""Smallest and largest scale of a style's thickness: a style never loses its shape to a
parse's error (hair parsed as background, a dark backdrop parsed as hair)."""

ITERATIONS = 3
"""Rounds of measure, scale and render again (the silhouette moves less than the scale
says, where the hair lies at a slant to the ray)."""

STEP = 0.5
"""Pixels between the samples along a ray."""

GAP = 2.0
"""Pixels of another label a run of hair may cross along a ray (a strand's gap)."""

JUMP = 0.04
"""Hair that starts further than this share of the image beyond the head's edge along a
ray is not the head's hair (a neighbour's, the backdrop's)."""

SIDE_ON = 0.5
"""A direction is measured only where it looks at least this long in the image against
the longest: one seen end on (the head's sideways directions in a profile) shows the
hair's outline in another direction than its own: scaled by it, Figaro's Frame00041 (a
profile) grew flaps of hair all round."""

MIN_GAIN = 0.005
"""IoU a scale must gain over none to be kept."""


@dataclasses.dataclass
class HairShape:
    """A fitted scale of a style's thickness and what it did to the silhouette."""

    scale: np.ndarray
    """``(WARP_BINS,)`` the scale per direction (ones: the style as it is)."""
    iou_before: float
    """Silhouette IoU with the parsed hair before (scored pixels only)."""
    iou_after: float
    """The same with the scale (equal to ``iou_before`` when the scale is not kept)."""


def ray_directions(centre: np.ndarray, c2w: np.ndarray, intrinsics: np.ndarray,
                   bins: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(origin (2,), directions (bins, 2), seen (bins,))``: the image point of the
    warp's ``centre``, the unit image direction of each warp direction (in the head's xy
    plane through the centre) seen by the camera, and how long each looks in the image
    against the longest (1: seen side on; near 0: seen end on, as the head's sideways
    directions are in a profile)."""
    from head360cli.geometry.cameras import project

    angle = 2 * np.pi * np.arange(bins) / bins
    ends = centre + 0.1 * np.column_stack([np.cos(angle), np.sin(angle), np.zeros(bins)])
    pts = torch.as_tensor(np.vstack([centre, ends]), dtype=torch.float64)[None]
    pix = project(pts, torch.as_tensor(c2w, dtype=torch.float64)[None],
                  torch.as_tensor(intrinsics, dtype=torch.float64))[0][0].numpy()
    d = pix[1:] - pix[0]
    length = np.linalg.norm(d, axis=1)
    return (pix[0], d / np.maximum(length, 1e-9)[:, None],
            length / max(float(length.max()), 1e-9))


def _sample(mask: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """``mask`` at the nearest pixel of ``pts (..., 2)``; ``False`` outside the image."""
    h, w = mask.shape
    x = np.rint(pts[..., 0]).astype(int)
    y = np.rint(pts[..., 1]).astype(int)
    inside = (x >= 0) & (x < w) & (y >= 0) & (y < h)
    out = np.zeros(pts.shape[:-1], bool)
    out[inside] = mask[y[inside], x[inside]]
    return out


def _run_end(on: np.ndarray, start: int, jump: int, gap: int) -> int | None:
    """Index where the run of ``on (S,)`` that begins near ``start`` (from 3 px inside
    it to ``jump`` samples beyond) ends, crossing gaps of up to ``gap`` samples; ``None``
    without one."""
    lo = max(start - int(3 / STEP), 0)
    idx = np.flatnonzero(on[lo:]) + lo
    if idx.size == 0 or idx[0] > start + jump:
        return None
    breaks = np.flatnonzero(np.diff(idx) > gap)
    return int(idx[breaks[0]] if breaks.size else idx[-1])


def _thickness_ratio(head: np.ndarray, style: np.ndarray, hair: np.ndarray,
                     valid: np.ndarray, origin: np.ndarray, dirs: np.ndarray
                     ) -> np.ndarray:
    """``(N,)`` log of (parsed hair's thickness / style's) beyond the head's edge along
    each ray, 0 where the photo cannot tell or neither has hair there."""
    res = head.shape[0]
    s = np.arange(0.0, 1.5 * res, STEP)
    pts = origin + s[None, :, None] * dirs[:, None, :]  # (N, S, 2)
    on_head, on_style, on_hair = (_sample(m, pts) for m in (head, style, hair))
    known = _sample(valid, pts)
    jump, gap = int(JUMP * res / STEP), int(GAP / STEP)
    out = np.zeros(len(dirs))
    for j in range(len(dirs)):
        edge_idx = np.flatnonzero(on_head[j])
        edge = int(edge_idx[-1]) if edge_idx.size else 0
        end_s = _run_end(on_style[j], edge, jump, gap)
        end_h = _run_end(on_hair[j], edge, jump, gap)
        if end_s is None and end_h is None:
            continue
        far = max(end_s or edge, end_h or edge) + gap + 1
        if not known[j, edge:far].all():
            continue  # the ray leaves what the photo shows before the hair ends
        thick_s = max((end_s - edge) * STEP if end_s is not None else 0.0, 1.0)
        thick_h = max((end_h - edge) * STEP if end_h is not None else 0.0, 0.5)
        out[j] = np.log(thick_h / thick_s)
    return out


def _smooth(log: np.ndarray) -> np.ndarray:
    """One pass of a circular [1, 2, 1] / 4 filter."""
    return 0.5 * log + 0.25 * (np.roll(log, 1) + np.roll(log, -1))


class _Scene:
    """A fitted head seen by one camera, made once for every style measured on it."""

    def __init__(self, neutral: np.ndarray, posed: np.ndarray, faces: np.ndarray,
                 c2w: np.ndarray, intrinsics: np.ndarray, res: int) -> None:
        from head360cli.model.render import EMPTY, screen_depth
        from head360cli.synth.hair import head_normals, warp_centre
        from head360cli.synth.sculpt import frame_from_vertices

        self.neutral, self.c2w, self.intrinsics, self.res = neutral, c2w, intrinsics, res
        self.cam = torch.as_tensor(c2w, dtype=torch.float32)[None]
        self.k = torch.as_tensor(intrinsics, dtype=torch.float32)[None]
        self.depth = screen_depth(torch.as_tensor(posed, dtype=torch.float32)[None],
                                  torch.as_tensor(faces, dtype=torch.long), self.cam,
                                  self.k, res)[0]
        self.head = (self.depth < EMPTY).numpy()
        self.frame = frame_from_vertices(neutral)
        self.normals = head_normals(neutral)
        self.centre = warp_centre(self.frame)
        self._meshes: dict = {}

    def silhouette(self, style, shift: np.ndarray, scale: np.ndarray | None = None,
                   soft: bool = False) -> np.ndarray:
        """``(R, R)`` bool: where ``style`` (an id or a
        :class:`~head360cli.synth.hair.HairStyle`), moved by ``shift`` and scaled by
        ``scale``, is the nearest surface. Each style's mesh and its shell's nearest head
        vertices are made once (the same mesh as
        :func:`~head360cli.synth.hair.build_hair` with ``scale``)."""
        from head360cli.model.render import EMPTY, screen_depth
        from head360cli.synth.hair import (
            HAIRSTYLES,
            build_hair,
            nearest_head_vertices,
            warp_hair,
        )

        style = HAIRSTYLES[int(style)] if isinstance(style, int | np.integer) else style
        if (style, soft) not in self._meshes:
            mesh = build_hair(self.neutral, self.frame, style, self.normals, soft=soft)
            near = nearest_head_vertices(mesh.verts[:mesh.shell], self.neutral)
            self._meshes[style, soft] = (mesh, near)
        mesh, near = self._meshes[style, soft]
        if len(mesh.faces) == 0:
            return np.zeros_like(self.head)
        verts = mesh.verts
        if scale is not None:
            verts = verts.copy()
            verts[:mesh.shell] = warp_hair(verts[:mesh.shell], self.neutral, scale,
                                           self.centre, near)
        d = screen_depth(torch.as_tensor(verts + shift, dtype=torch.float32)[None],
                         torch.as_tensor(mesh.faces, dtype=torch.long), self.cam, self.k,
                         self.res)[0]
        return ((d < EMPTY) & (d < self.depth + 1e-3)).numpy()


def _score(sil: np.ndarray, hair: np.ndarray, valid: np.ndarray, face: np.ndarray | None
           ) -> tuple[float, float]:
    """``(IoU, IoU less FACE_COVER times the share of the face covered)`` on ``valid``."""
    from head360cli.fitting.hair_class import FACE_COVER
    from head360cli.fitting.hair_parse import mask_iou

    iou = mask_iou(sil[valid], hair[valid])
    if face is None or not face[valid].any():
        return iou, iou
    return iou, iou - FACE_COVER * float((sil & face)[valid].sum() / face[valid].sum())


def _fit(scene: _Scene, style, hair: np.ndarray, valid: np.ndarray, shift: np.ndarray,
         face: np.ndarray | None, soft: bool, iterations: int
         ) -> tuple[HairShape, float, float]:
    """:func:`fit_hair_scale` on a made scene (``style`` an id or a
    :class:`~head360cli.synth.hair.HairStyle`): ``(shape, score before, score after)``."""
    from head360cli.synth.hair import HAIRSTYLES, WARP_BINS

    style = HAIRSTYLES[int(style)] if isinstance(style, int | np.integer) else style
    ones = np.ones(WARP_BINS)
    origin, dirs, seen = ray_directions(scene.centre + shift, scene.c2w, scene.intrinsics,
                                        WARP_BINS)
    side_on = seen >= SIDE_ON
    log = np.zeros(WARP_BINS)
    sil = plain = scene.silhouette(style, shift, None, soft)
    low, high = np.log(SCALE_RANGE[0]), np.log(SCALE_RANGE[1])
    for _ in range(iterations):
        step = _thickness_ratio(scene.head, sil, hair, valid, origin, dirs) * side_on
        log = np.clip(_smooth(log + np.clip(step, -1.0, 1.0)), low, high)
        sil = scene.silhouette(style, shift, np.exp(log), soft)
    (iou_0, score_0), (iou_1, score_1) = _score(plain, hair, valid, face), \
        _score(sil, hair, valid, face)
    if score_1 < score_0 + MIN_GAIN:
        return HairShape(ones, iou_0, iou_0), score_0, score_0
    return HairShape(np.exp(log), iou_0, iou_1), score_0, score_1


def fit_hair_scale(neutral: np.ndarray, posed: np.ndarray, faces: np.ndarray,
                   c2w: np.ndarray, intrinsics: np.ndarray, style: int, hair: np.ndarray,
                   valid: np.ndarray | None = None, offset: np.ndarray | None = None,
                   face: np.ndarray | None = None, soft: bool = False,
                   iterations: int = ITERATIONS, end_shift: float = 0.0) -> HairShape:
    """Scale a style's thickness by direction so that its silhouette ends where the
    parsed hair does.

    Args:
        neutral, posed, faces, c2w, intrinsics: As
            :func:`~head360cli.fitting.hair_class.style_silhouettes`, for an ``(R, R)``
            image.
        style: The style id.
        hair: ``(R, R)`` bool parsed hair.
        valid: ``(R, R)`` bool, the pixels the photo tells (default: all).
        offset: ``(3,)`` metres the style's mesh is moved by (its placement).
        face: ``(R, R)`` bool parsed face skin: the scale is kept only if its IoU, less
            :data:`~head360cli.fitting.hair_class.FACE_COVER` times the face it covers,
            gains :data:`MIN_GAIN`.
        soft: The soft hairlines of the generator that renders it.
        iterations: Rounds of measuring and scaling.
        end_shift: The style's ends moved by this (:func:`fit_hair_end`).

    Returns:
        The :class:`HairShape` (ones when the style is bald or the scale gains nothing).
    """
    from head360cli.synth.hair import HAIRSTYLES, WARP_BINS

    if int(style) == 0:
        return HairShape(np.ones(WARP_BINS), 0.0, 0.0)
    valid = np.ones_like(hair) if valid is None else valid
    shift = np.zeros(3) if offset is None else np.asarray(offset, np.float64)
    scene = _Scene(neutral, posed, faces, c2w, intrinsics, hair.shape[0])
    own = dataclasses.replace(HAIRSTYLES[int(style)], end_shift=float(end_shift))
    return _fit(scene, own, hair, valid, shift, face, soft, iterations)[0]


END_SHIFTS = (0.0, -0.01, -0.02, -0.03, -0.04, -0.06)
"""Metres :func:`fit_hair_end` tries moving a style's ends at the sides and back up by:
only up, so short hair stays short (a longer style is the ranking's to choose); 6 cm
takes a bob's ends from below the ear lobes to the top of the ears."""


def fit_hair_end(neutral: np.ndarray, posed: np.ndarray, faces: np.ndarray,
                 c2w: np.ndarray, intrinsics: np.ndarray, style: int, hair: np.ndarray,
                 valid: np.ndarray | None = None, offset: np.ndarray | None = None,
                 face: np.ndarray | None = None, soft: bool = False) -> float:
    """How far up a style's hair should end at the sides and back for its silhouette to
    match the parsed hair: of :data:`END_SHIFTS`, the one whose IoU less the face it
    covers (as :func:`fit_hair_scale` scores) is best, if it gains :data:`MIN_GAIN` over
    none; 0 for bald. Arguments as :func:`fit_hair_scale`'s; metres (negative: up).

    Scaling the thickness cannot shorten hair: it squeezes the ends onto the neck."""
    if int(style) == 0:
        return 0.0
    valid = np.ones_like(hair) if valid is None else valid
    shift = np.zeros(3) if offset is None else np.asarray(offset, np.float64)
    scene = _Scene(neutral, posed, faces, c2w, intrinsics, hair.shape[0])
    return _fit_end(scene, int(style), hair, valid, shift, face, soft)


def _fit_end(scene: _Scene, style: int, hair: np.ndarray, valid: np.ndarray,
             shift: np.ndarray, face: np.ndarray | None, soft: bool) -> float:
    """:func:`fit_hair_end` on a made scene."""
    from head360cli.synth.hair import HAIRSTYLES

    own = HAIRSTYLES[style]
    scores = [_score(scene.silhouette(dataclasses.replace(own, end_shift=e), shift,
                                      soft=soft), hair, valid, face)[1]
              for e in END_SHIFTS]
    best = int(np.argmax(scores))
    return float(END_SHIFTS[best]) if scores[best] >= scores[0] + MIN_GAIN else 0.0


def fit_hair_shape(neutral: np.ndarray, posed: np.ndarray, faces: np.ndarray,
                   c2w: np.ndarray, intrinsics: np.ndarray, style: int, hair: np.ndarray,
                   valid: np.ndarray | None = None, offset: np.ndarray | None = None,
                   face: np.ndarray | None = None, soft: bool = False
                   ) -> tuple[float, HairShape]:
    """:func:`fit_hair_end`, then :func:`fit_hair_scale` from the ends it found, on one
    scene (the head's render and each style mesh made once): ``(end shift, shape)``.
    Arguments as :func:`fit_hair_scale`'s."""
    from head360cli.synth.hair import HAIRSTYLES, WARP_BINS

    if int(style) == 0:
        return 0.0, HairShape(np.ones(WARP_BINS), 0.0, 0.0)
    valid = np.ones_like(hair) if valid is None else valid
    shift = np.zeros(3) if offset is None else np.asarray(offset, np.float64)
    scene = _Scene(neutral, posed, faces, c2w, intrinsics, hair.shape[0])
    end = _fit_end(scene, int(style), hair, valid, shift, face, soft)
    own = dataclasses.replace(HAIRSTYLES[int(style)], end_shift=end)
    return end, _fit(scene, own, hair, valid, shift, face, soft, ITERATIONS)[0]


CANDIDATES = 5
"""How many of the classifier's first styles are ranked again with their shape fitted
(:func:`rank_shaped`)."""

RANK_ITERATIONS = 2
"""Rounds of :func:`fit_hair_scale` for each candidate of :func:`rank_shaped`."""

SHAPE_COST = 0.1
"""Score a candidate of :func:`rank_shaped` loses per unit of its scale's mean absolute
log: any style can be scaled towards any outline, so the style that needs least
scaling is the likelier one. Chosen on 30 held-out heads of corpus seed 1 (not the
bench's seed 0) with their true hair masks: top-1 27 of 30 unshaped, 26 with shapes at
no cost (a scaled bun beat a buzz cut, a middle part long a long straight), 28 at 0.1
(the two left wear a ponytail that looks like the bun from the front)."""

EXTRA_SUPPORT = 0.5
"""Share of a style's extra pieces' own silhouette (where no other hair of the style is)
that the parsed hair must cover; below it the photo contradicts them."""

MIN_EXTRA = 0.003
"""Share of the scored pixels an extra piece's own silhouette must reach for the photo to
tell anything about it (a tail hidden behind the head tells nothing)."""


def extras_support(scene: _Scene, style: int, hair: np.ndarray, valid: np.ndarray,
                   shift: np.ndarray, soft: bool = False) -> float | None:
    """Share of ``style``'s extra pieces' own silhouette (bun, tails, braid, top knot:
    where the style with them shows hair and the style without them does not) that the
    parsed ``hair`` covers; ``None`` for a style without extras or extras the view does
    not show (:data:`MIN_EXTRA`)."""
    from head360cli.synth.hair import HAIRSTYLES

    own = HAIRSTYLES[int(style)]
    if not own.extras:
        return None
    part = scene.silhouette(own, shift, soft=soft) & ~scene.silhouette(
        dataclasses.replace(own, extras=()), shift, soft=soft) & valid
    if part.sum() < MIN_EXTRA * valid.sum():
        return None
    return float((part & hair).sum() / part.sum())


def rank_shaped(guess, silhouettes: np.ndarray, neutral: np.ndarray, posed: np.ndarray,
                faces: np.ndarray, c2w: np.ndarray, intrinsics: np.ndarray,
                hair: np.ndarray, valid: np.ndarray | None = None,
                face: np.ndarray | None = None, soft: bool = False,
                hair_area=None):
    """The classifier's ranking made again with each of its first :data:`CANDIDATES`
    styles' shape fitted to the hair (:func:`fit_hair_scale`), so that a style is judged
    by what it becomes on this head, not by its one rule's size; a style whose extra
    pieces the hair contradicts (:func:`extras_support` below :data:`EXTRA_SUPPORT`:
    twin tails beside a bob) loses 1 of score, more than any IoU is worth.

    Args:
        guess: :func:`~head360cli.fitting.hair_class.classify_hair`'s
            :class:`~head360cli.fitting.hair_class.HairGuess` for ``hair``.
        silhouettes: ``(30, R, R)`` the styles' silhouettes it ranked.
        neutral, posed, faces, c2w, intrinsics, hair, valid, face, soft: As
            :func:`fit_hair_scale`.
        hair_area: As :func:`~head360cli.fitting.hair_class.classify_hair`'s.

    Returns:
        A new :class:`~head360cli.fitting.hair_class.HairGuess` (``guess`` itself when
        it matched no style).
    """
    from head360cli.fitting.hair_class import ranked_guess

    if not guess.matched or guess.score is None:
        return guess
    valid = np.ones_like(hair) if valid is None else valid
    shift = np.zeros(3)
    scene = _Scene(neutral, posed, faces, c2w, intrinsics, hair.shape[0])
    iou, score = guess.iou.astype(np.float64).copy(), guess.score.astype(np.float64).copy()
    shaped, contradicted = [], []
    for style in [s for s in guess.ranking[:CANDIDATES] if s != 0]:
        support = extras_support(scene, style, hair, valid, shift, soft)
        fitted, before, after = _fit(scene, style, hair, valid, shift, face, soft,
                                     RANK_ITERATIONS)
        # the gain the shape brings, added to the classifier's own measure (its
        # silhouettes may have other hairlines than the renderer's)
        iou[style] += fitted.iou_after - fitted.iou_before
        score[style] += after - before - SHAPE_COST * float(
            np.abs(np.log(fitted.scale)).mean())
        shaped.append(style)
        if support is not None and support < EXTRA_SUPPORT:
            score[style] -= 1.0
            contradicted.append(style)
    return ranked_guess(score, iou, silhouettes, True, hair_area, tuple(shaped),
                        tuple(contradicted))

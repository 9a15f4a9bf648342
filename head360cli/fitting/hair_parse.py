"""Hair parsing without a pretrained face parser: landmark-seeded GrabCut plus skin colour.

No face-parsing network can be downloaded here, so the masks come from OpenCV's GrabCut,
seeded from what the 68 landmarks say about where hair can and cannot be:

- the inner face (eyes, brows, nose, mouth, jaw line) is never hair;
- the neck column under the chin is never hair;
- a cap above the brows is, where its colour is clearly not skin and the learned prior
  (below) does not rule hair out; these pixels seed the hair against the face, and,
  where they are also unlike the frame's edge (above a bald head the cap reaches into
  the backdrop), the person against the background: light hair on a light backdrop was
  otherwise given to the backdrop;
- the frame's edge is backdrop, except at the bottom where it has those seeds' colours
  (long hair running off the frame);
- a head ellipse around the face probably is;
- pixels whose colour matches the face's own skin (a Gaussian in Lab, estimated on the
  cheeks) probably are not;
- where a learned prior (:mod:`head360cli.fitting.hair_prior`, a small network trained
  on the synthetic corpus) says hair probably is, or is not, the soft labels follow it:
  colour alone gave hair beside the face that looks like the backdrop to the backdrop;
  where the prior is sure (:data:`PRIOR_SURE`), the pixel is part of the person, and,
  unless it has the skin's colour, a seed of the hair.

Without landmarks (a back view, a profile, a hair close-up), the photo is taken to be about
the hair: GrabCut separates the foreground (the centre of the image and what has its colours
are probably in it; an edge of the frame is not, unless it has those colours too, as in a
close-up where the hair runs off the frame; smooth regions and skin colours probably are
not) and that foreground is the hair. A face in profile, which dlib's frontal detectors
do not find, is looked for with OpenCV's Haar profile cascade
(:func:`~head360cli.fitting.landmarks.find_profile`): where one is found, its cheek gives
the face's own skin colour, which is then not hair, and the face mask.

Everything runs at a working resolution of at most ``work_size`` pixels and is scaled back
to the input's size; the first of the two GrabCut passes (the person against the
background) at most :data:`PERSON_SIDE`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["MIN_HAIR", "MIN_SIDE", "PERSON_SIDE", "PRIOR_NO_HAIR", "PRIOR_SURE", "HairParse",
           "mask_iou", "parse_hair"]

MIN_SIDE = 16
"""Photos with a side shorter than this many pixels are refused: a 2-pixel frame band on
each side leaves GrabCut no interior to separate, and below about 5 pixels its colour
models have too few samples to be estimated at all."""


PERSON_SIDE = 256
"""Longer side in pixels at most of the first GrabCut pass, the person (hair included)
against the background; its mask is scaled back up for the second pass, hair against
skin and clothes, which runs at the working size. The first pass is the parse's longer
one (0.45 to 2.4 s at 384 pixels on development photos), and ``fit`` waits for it. At
256 pixels it took 0.18 to 0.95 s (2.4 to 2.6 times less) on eight development photos
(AFLW2000-3D 00516/01322/02283/02545/03614, VOC 2008_001009, dlib's bald_guys, the
astronaut), their hair masks agreeing with the full-size pass at IoU 0.72 to 1.0 (five
of eight at 0.98 or more; the lowest, 01322, where both find only a patch of her
forehead); on 19 held-out synthetic heads of corpus seed 1 rendered at 512 pixels the
hair IoU went 0.9686 -> 0.9656 (2026-12-04). Measured afterwards on ``bench fit``'s real
masks: CelebAMask 0.721 -> 0.711 (one photo 0.801 -> 0.714), Figaro 0.742 -> 0.741."""


@dataclasses.dataclass
class HairParse:
    """Masks of one photo, each ``(H, W)`` bool at the photo's size.

    Attributes:
        hair: Hair pixels.
        face: Face skin (inside the face outline and its forehead, not hair).
        background: Neither hair nor face.
        seeded: Whether landmarks seeded the parse (``False``: the no-face fallback).
        prior: Whether a hair prior (learned or given) set GrabCut's soft labels.
        profile: Whether a face in profile guided the parse without landmarks (its skin
            is then the face mask).
    """

    hair: np.ndarray
    face: np.ndarray
    background: np.ndarray
    seeded: bool
    prior: bool = False
    profile: bool = False


def mask_iou(pred: np.ndarray, truth: np.ndarray) -> float:
    """Intersection over union of two boolean masks (1.0 when both are empty)."""
    pred, truth = np.asarray(pred, bool), np.asarray(truth, bool)
    union = np.logical_or(pred, truth).sum()
    return 1.0 if union == 0 else float(np.logical_and(pred, truth).sum() / union)


def _face_outline(lm: np.ndarray, forehead: float) -> np.ndarray:
    """Polygon ``(N, 2)``: the jaw line, closed over the brows raised by ``forehead`` times
    the brow-to-chin height."""
    jaw = lm[0:17]
    brows = lm[17:27]
    height = np.linalg.norm(lm[8] - brows.mean(0))
    up = brows.mean(0) - lm[8]
    up = up / max(np.linalg.norm(up), 1e-6)
    top = brows[::-1] + up * forehead * height
    return np.concatenate([jaw, top]).astype(np.float32)


MIN_SAMPLES = 20
"""Fewest pixels a colour model (:func:`_colour_distance`) or a seed set is fitted from."""

FLAT_STD = 3.0
"""A photo without a face whose every Lab channel (0-255 scale) varies by less than this
standard deviation is featureless (a blank wall, a transparent image over white): it
has no hair. The no-face parse takes the centre's colours for hair, and in such an
image every pixel has them: a blank image was parsed as 100 % hair."""

LIKE_DEVIATIONS = 3.0
"""Pixels within this Mahalanobis distance of a colour model (:func:`_colour_distance`)
have its colour: the cheeks' (skin), the frame's edge, or a no-face photo's centre."""

SEED_DEVIATIONS = 4.0
"""Cap pixels (above the brows) at least this far from the cheeks' colour seed the hair.
On 30 held-out synthetic heads (corpus seed 1, not the bench's seed 0) the bald scalp of a
receding hairline passed the 3.0 of :data:`LIKE_DEVIATIONS` and was seeded as hair (IoU
0.28); 4, 5 and 6 all parsed it right (mean IoU 0.871, 0.871, 0.870, before the frame's
edge was kept out of the seeds)."""


PRIOR_SURE = 0.95
"""Where the learned prior's hair probability is above this, the pixel is part of the
person in the first GrabCut pass (a hard label; the frame's backdrop stays backdrop), not
only probably so; whether it is hair is still the second pass's call. Chosen on held-out
heads of corpus seeds 1 and 2 (not the bench's seed 0, not photos): parsed hair IoU
0.9525 -> 0.9577 and 0.9538 -> 0.9574 (0.98, 0.90 and 0.80 gained less on one seed or
both); platinum and blonde curtains on the white backdrop were the gain."""

PRIOR_NO_HAIR = 0.05
"""Where the learned prior's hair probability is below this, a cap pixel does not seed
the hair, whatever its colour; and where it is above :data:`PRIOR_SURE` and the colour is
not the skin's, a pixel of the person seeds the hair in the second pass. The cap is
placed by the landmarks alone: above a bald or shaven head, or a small head near the
frame's top, it lies on the backdrop (a grey wall, a yellow poster), whose colour then
seeded the hair, and a bald man was parsed with a wall of hair and fitted an afro;
where the cap missed a head of dark curls, no seed was on the hair at all. Chosen on
development data (corpus seeds 1 and 2, not the bench's seed 0; real photos: the PASCAL
VOC group photos, ``bald_guys``, AFLW2000 images 01322, 02283 and 03614, none of them
the bench's): held-out heads' parsed hair IoU 0.9577 / 0.9574 -> 0.9590 / 0.9598 on the
plain backdrop and 0.9396 / 0.9342 -> 0.9480 / 0.9418 composited over photographs,
hairstyle top-1 unchanged (28 and 27 of 30); on the photos the walls above the bald
heads are no longer hair (``bald_guys`` parsed bald, VOC 2009_004587 a pixie instead of
an afro) and the dark hair of two VOC faces is found where the cap had missed it. The
veto alone (no prior seeds) lost those two; a threshold of 0.01 to 0.1 vetoed the same
walls."""

MIN_HAIR = 0.05
"""Less hair than this fraction of the face region (the jaw line closed over the
forehead) is no hair. On 60 held-out synthetic heads (corpus seed 1) two bald heads had
lit spots on the scalp parsed as 1.3 % and 3.8 % of it, which made a receding or buzz
cut outrank bald; the least hair among the others was a receding hairline at 16 %."""


def _mahalanobis(x: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Mahalanobis distance ``(N,)`` of ``x (N, 3)`` to a Gaussian."""
    d = x - mean
    return np.sqrt(np.einsum("ij,jk,ik->i", d, np.linalg.inv(cov), d))


def _colour_distance(lab: np.ndarray, samples: np.ndarray, trims: int = 2) -> np.ndarray:
    """Mahalanobis distance ``(H, W)`` of every pixel to a Gaussian fitted to ``samples``
    ``(N, 3)`` Lab values (a skin model from the cheeks, a hair model from the centre of a photo
    without a face).

    The fit is refitted ``trims`` times without the samples beyond 2.5 of its
    deviations: the cheek polygons also catch eyelashes, nostrils and shadows, which
    would otherwise widen the skin's lightness so far that dark hair passes for skin.
    """
    floor = np.diag([25.0, 4.0, 4.0])  # lighting and noise
    mean, cov = samples.mean(0), np.cov(samples.T) + floor
    for _ in range(trims):
        inside = samples[_mahalanobis(samples, mean, cov) < 2.5]
        if len(inside) < MIN_SAMPLES:
            break
        mean, cov = inside.mean(0), np.cov(inside.T) + floor
    return _mahalanobis(lab.reshape(-1, 3), mean, cov).reshape(lab.shape[:2])


def _skin_box(bgr: np.ndarray) -> np.ndarray:
    """``(H, W)`` bool: pixels in a fixed skin-colour box in YCrCb (Cr 138-173, Cb 77-127).

    The box is the classic one of Chai and Ngan (1999) with its red floor raised from 133
    to 138: at 133 the lighter strands of brown hair (Cr about 135) fall in it; on
    held-out synthetic back views and close-ups (``head360 bench fit``'s no-face rows)
    138 scored IoU 0.905 / 0.927 against 0.906 / 0.913 at 133. Skin-box pixels are only
    seeded as probable background: GrabCut's colour models have the last word, so hair
    strands inside the box are not cut out one by one.
    """
    import cv2

    ycc = cv2.cvtColor(bgr, cv2.COLOR_BGR2YCrCb)
    cr, cb = ycc[..., 1], ycc[..., 2]
    return (cr >= 138) & (cr <= 173) & (cb >= 77) & (cb <= 127)


def _texture_energy(lightness: np.ndarray, window: int) -> np.ndarray:
    """Local mean of the absolute Laplacian of ``lightness (H, W)`` over a ``window``."""
    import cv2

    lap = np.abs(cv2.Laplacian(lightness.astype(np.float32), cv2.CV_32F, ksize=3))
    return cv2.blur(lap, (window, window))


def _smooth(lab: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``(H, W)`` bool: pixels with less than a quarter of the median texture energy of
    the ``reference`` pixels (known hair): hair is textured, a plain wall or a defocused
    backdrop is not. The energy is taken over a window of 2% of the image."""
    window = max(3, round(0.02 * max(lab.shape[:2]))) | 1
    energy = _texture_energy(lab[..., 0], window)
    return energy < 0.25 * np.median(energy[reference])


def _poly(shape: tuple[int, int], points: np.ndarray) -> np.ndarray:
    """Boolean ``shape`` mask of a filled polygon ``(N, 2)`` in pixels."""
    import cv2

    out = np.zeros(shape, np.uint8)
    cv2.fillPoly(out, [np.round(np.asarray(points)).astype(np.int32)], 1)
    return out.astype(bool)


def _grabcut(bgr: np.ndarray, mask: np.ndarray, iterations: int) -> np.ndarray:
    import cv2

    fg, bg = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    m = mask.copy()
    cv2.setRNGSeed(0)  # GrabCut seeds its colour models with k-means: same input, same mask
    if not ((m == cv2.GC_FGD) | (m == cv2.GC_PR_FGD)).any() or not (
            (m == cv2.GC_BGD) | (m == cv2.GC_PR_BGD)).any():
        return (m == cv2.GC_FGD) | (m == cv2.GC_PR_FGD)
    cv2.grabCut(bgr, m, None, bg, fg, iterations, cv2.GC_INIT_WITH_MASK)
    return (m == cv2.GC_FGD) | (m == cv2.GC_PR_FGD)


def _clean(mask: np.ndarray, keep_near: np.ndarray | None, size: int) -> np.ndarray:
    """Open and close with a disc of about 1% of the image, then keep the components that
    touch ``keep_near`` (or the largest ones)."""
    import cv2

    k = max(3, round(size * 0.01) | 1)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    m = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_OPEN, disc)
    m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, disc)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    if n <= 1:
        return m.astype(bool)
    areas = stats[1:, cv2.CC_STAT_AREA]
    if keep_near is not None:
        touching = np.unique(labels[keep_near & (labels > 0)])
        keep = [i for i in touching if areas[i - 1] >= 0.02 * areas.max()]
    else:
        keep = [i + 1 for i in np.flatnonzero(areas >= 0.1 * areas.max())]
    return np.isin(labels, keep) if keep else np.zeros_like(m, bool)


def _learned_prior(rgb: np.ndarray, landmarks: np.ndarray | None) -> np.ndarray | None:
    """The shipped hair prior's map of ``rgb``, or ``None`` without landmarks or weights."""
    if landmarks is None:
        return None
    from head360cli.fitting.hair_prior import default_hair_prior

    net = default_hair_prior()
    return None if net is None else net.predict(rgb, landmarks)


PROFILE_SKIN = 0.3
"""Share of a profile face's cheek (see :func:`_profile_cheek`) that must fall in the
fixed skin box for the face to be believed. On development renders (corpus seeds 1 and 2,
256 pixels) the cheeks of faces found in profile had 0.42 to 1.0 of their pixels in it;
the one box the cascade put on the back views and close-ups of hair 0.0 (two more that a
looser search, 2 neighbours instead of 3, put there 0.08 and 0.18)."""


def _profile_cheek(bgr: np.ndarray, skin: np.ndarray, xx: np.ndarray, yy: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray] | None:
    """``(cheek, face)`` ``(H, W)`` bool masks of the largest face in profile in ``bgr``
    (:func:`~head360cli.fitting.landmarks.find_profile`), or ``None`` when there is none
    or its cheek is not skin-coloured (:data:`PROFILE_SKIN` of ``skin``, the fixed skin
    box); ``xx`` and ``yy`` are the ``(H, W)`` pixel coordinates.

    The cascade's box is sometimes the face and sometimes the whole head, but both have
    the nose at its front side, so the cheek is taken in the box's front half (0.1 to
    0.45 of its width from the front, 0.4 to 0.8 of its height) and the face, where its
    skin is sure, in 0 to 0.6 of the width and below 0.3 of the height; both only where
    the skin box is, since the front half also holds the backdrop before the face (with
    it, the skin model took a dark backdrop and the black hair as skin).
    """
    import cv2

    from head360cli.fitting.landmarks import find_profile

    found = find_profile(cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY))
    if found is None:
        return None
    x0, y0, x1, y1 = found.box
    across = (xx - x0) / (x1 - x0) if found.facing < 0 else (x1 - xx) / (x1 - x0)
    down = (yy - y0) / (y1 - y0)
    cheek = (across > 0.1) & (across < 0.45) & (down > 0.4) & (down < 0.8)
    if not cheek.any() or skin[cheek].mean() < PROFILE_SKIN:
        return None
    # The box's front half also catches the backdrop before the face.
    cheek &= skin
    if cheek.sum() < MIN_SAMPLES:
        return None
    return cheek, (across > 0) & (across < 0.6) & (down > 0.3) & (down < 1.0) & skin


def _grabcut_at(bgr: np.ndarray, mask: np.ndarray, iterations: int, side: int
                ) -> np.ndarray:
    """:func:`_grabcut` on a copy at most ``side`` pixels long (the image scaled by area,
    the labels by nearest neighbour), its mask scaled back to ``mask``'s size."""
    import cv2

    h, w = mask.shape
    if max(h, w) <= side:
        return _grabcut(bgr, mask, iterations)
    scale = side / max(h, w)
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    small = _grabcut(cv2.resize(bgr, size, interpolation=cv2.INTER_AREA),
                     cv2.resize(mask, size, interpolation=cv2.INTER_NEAREST), iterations)
    return cv2.resize(small.astype(np.uint8) * 255, (w, h),
                      interpolation=cv2.INTER_LINEAR) > 127


def parse_hair(rgb: np.ndarray, landmarks: np.ndarray | None = None, *,
               method: str = "segmenter", work_size: int = 384, iterations: int = 5,
               prior: np.ndarray | str | None = "learned",
               person_size: int = PERSON_SIDE, profile: bool = True) -> HairParse:
    """Hair, face and background masks of a photo.

    Args:
        rgb: ``(H, W, 3)`` uint8 RGB photo.
        landmarks: ``(68, 2)`` iBUG landmarks in its pixels, or ``None`` (no face found).
        method: ``segmenter`` (:func:`segment_hair`; the arguments below are GrabCut's
            and unused) or ``grabcut``.
        work_size: Longest side the segmentation runs at.
        iterations: GrabCut iterations.
        prior: Where hair probably is, used as GrabCut's soft labels when landmarks are
            given (and where it is above :data:`PRIOR_SURE`, as the person's hard label
            in the first pass, person against backdrop). ``"learned"`` runs the shipped
            hair prior (:mod:`head360cli.fitting.hair_prior`) when it is installed; an
            ``(H, W)`` float map of probabilities in [0, 1] at the photo's size is used
            as it is; ``None`` parses by colour and landmarks alone.
        person_size: Longest side of the first GrabCut pass with landmarks, the person
            against the background (:data:`PERSON_SIDE`; ``work_size`` or more: at the
            working size).
        profile: Without landmarks, whether to look for a face in profile and keep its
            skin out of the hair (:func:`_profile_cheek`).

    A photo whose brightness spans fewer than
    :data:`~head360cli.fitting.landmarks.LOW_CONTRAST_SPREAD` grey levels is parsed on a
    copy stretched to the full range (:func:`~head360cli.fitting.landmarks.stretched`):
    AFLW2000-3D 03614 (a development photo) at 0.1 of its brightness agreed with its own
    bright parse at hair IoU 0.847 (face 0.971) as it was, 0.989 (0.991) stretched.

    Returns:
        The masks at the photo's size.

    Raises:
        BadInputError: ``rgb`` is not an ``(H, W, 3)`` uint8 image with sides of at least
            :data:`MIN_SIDE` pixels, ``prior`` is neither ``"learned"``, ``None`` nor a
            map of the photo's size, or ``person_size`` is under :data:`MIN_SIDE`.
    """
    import cv2

    from head360cli.errors import BadInputError
    from head360cli.io.images import is_greyscale

    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise BadInputError(f"expected an (H, W, 3) uint8 RGB photo to parse, found shape "
                            f"{tuple(rgb.shape)} of {rgb.dtype}")
    if person_size < MIN_SIDE:
        raise BadInputError(f"expected a person pass size of at least {MIN_SIDE} pixels, "
                            f"found {person_size}")
    h, w = rgb.shape[:2]
    if min(h, w) < MIN_SIDE:
        raise BadInputError(f"expected a photo at least {MIN_SIDE}x{MIN_SIDE} pixels to parse "
                            f"hair, found {w}x{h}")
    # a dark or washed-out photo: its colours and edges on the full range (the masks
    # are what is returned, not its pixels)
    from head360cli.fitting.landmarks import stretched

    rgb = stretched(rgb)
    if method == "segmenter":
        return segment_hair(rgb, landmarks, refine=False)
    if method != "grabcut":
        raise BadInputError(f"expected hair parser segmenter or grabcut, found {method!r}")
    if isinstance(prior, str):
        if prior != "learned":
            raise BadInputError(f"expected prior 'learned', None or an (H, W) map, found "
                                f"{prior!r}")
        prior = _learned_prior(rgb, landmarks)
    elif prior is not None:
        prior = np.asarray(prior, np.float32)
        if prior.shape != (h, w):
            raise BadInputError(f"expected a hair prior of the photo's shape {(h, w)}, found "
                                f"{tuple(prior.shape)}")
    scale = min(1.0, work_size / max(h, w))
    sw, sh = max(1, round(w * scale)), max(1, round(h * scale))
    small = cv2.resize(rgb, (sw, sh), interpolation=cv2.INTER_AREA) if scale < 1 else rgb
    bgr = np.ascontiguousarray(small[..., ::-1])
    lab = cv2.cvtColor(bgr, cv2.COLOR_BGR2LAB).astype(np.float32)
    yy, xx = np.mgrid[0:sh, 0:sw].astype(np.float32)
    face = np.zeros((sh, sw), bool)
    side_face = None  # without landmarks: a face in profile's cheek and sure face
    size = max(sh, sw)
    band = max(2, round(0.02 * size))
    border = np.zeros((sh, sw), bool)
    border[:band] = border[-band:] = True
    border[:, :band] = border[:, -band:] = True
    if landmarks is not None:
        lm = np.asarray(landmarks, np.float32) * scale
        height = float(np.linalg.norm(lm[8] - lm[17:27].mean(0)))
        width = float(np.linalg.norm(lm[16] - lm[0]))
        brow_y = float(lm[17:27, 1].min())
        cx = float(lm[[0, 16, 8], 0].mean())
        outline = _poly((sh, sw), _face_outline(lm, 0.45))
        inner = _poly((sh, sw), cv2.convexHull(lm[17:68])[:, 0])
        jaw_in = _poly((sh, sw), _face_outline(lm, 0.05))
        never = inner | jaw_in
        # Skin model from the cheeks (below the eyes, beside the nose).
        cheeks = _poly((sh, sw), cv2.convexHull(lm[[1, 2, 3, 31, 39, 40, 41, 36]])[:, 0])
        cheeks |= _poly((sh, sw), cv2.convexHull(lm[[15, 14, 13, 35, 42, 47, 46, 45]])[:, 0])
        samples = lab[cheeks] if cheeks.sum() >= MIN_SAMPLES else lab[jaw_in]
        # A greyscale photo (faint casts and noise too, as the fit sees it) has no skin
        # colour: brightness alone would call blond or grey hair skin, so no pixel is
        # skin by colour there.
        grey = is_greyscale(small)
        modelled = len(samples) >= MIN_SAMPLES and not grey
        skin_distance = (_colour_distance(lab, samples) if modelled
                         else np.full(face.shape, np.inf))
        skin = skin_distance < LIKE_DEVIATIONS
        neck = ((np.abs(xx - lm[8, 0]) < 0.3 * width) & (yy > lm[8, 1] + 0.05 * height)
                & (yy < lm[8, 1] + 0.6 * height))
        cap = ((np.abs(xx - cx) < 0.35 * width) & (yy < brow_y - 0.35 * height)
               & (yy > brow_y - 0.65 * height))
        head = (((xx - cx) / (0.9 * width)) ** 2
                + ((yy - brow_y + 0.1 * height) / (1.2 * height)) ** 2) <= 1.0
        # The cap's pixels that are clearly not skin are the hair the parse starts from;
        # a bald scalp lit unlike the cheeks can fall just outside the skin model, so a
        # seed must lie further from it than a pixel that is merely not skin.
        cap_hair = cap & (skin_distance >= SEED_DEVIATIONS)
        # ... unless the learned prior is sure there is no hair (the cap can lie on the
        # backdrop above a bald head)
        small_prior = None
        if prior is not None:
            small_prior = cv2.resize(prior, (sw, sh), interpolation=cv2.INTER_AREA)
            cap_hair &= small_prior >= PRIOR_NO_HAIR
        # Stage 1: the person, their hair included, against the background. Only the
        # cap's hair unlike the frame's edge seeds the person: above a bald head the cap
        # reaches into the backdrop.
        edge_like = _colour_distance(lab, lab[border]) < LIKE_DEVIATIONS
        hair_seeds = cap_hair & ~edge_like
        # The frame's edge is backdrop, except where long hair runs off its bottom: there
        # the edge has the seeds' colours (clothes there stay backdrop).
        backdrop = border & ~head
        if hair_seeds.sum() >= MIN_SAMPLES:
            backdrop[-band:] &= (_colour_distance(lab[-band:], lab[hair_seeds])
                                 >= LIKE_DEVIATIONS)
        m = np.full((sh, sw), cv2.GC_PR_BGD, np.uint8)
        m[head] = cv2.GC_PR_FGD
        m[backdrop] = cv2.GC_BGD
        m[never | neck | hair_seeds] = cv2.GC_FGD
        likely = None
        if prior is not None:
            # The learned prior's hair is probably part of the person.
            likely = small_prior > 0.5
            m[likely & (m == cv2.GC_PR_BGD)] = cv2.GC_PR_FGD
            # Where it is sure, it is: light hair on a light backdrop has the backdrop's
            # colours, and the colour models gave it away even as a soft label.
            m[(small_prior > PRIOR_SURE) & (m != cv2.GC_BGD)] = cv2.GC_FGD
        person = _grabcut_at(bgr, m, iterations, person_size)
        # Stage 2: hair against skin and clothes, inside the person.
        m = np.full((sh, sw), cv2.GC_PR_BGD, np.uint8)
        m[head] = cv2.GC_PR_FGD
        m[head & skin] = cv2.GC_PR_BGD
        # Hair is textured; a smooth (defocused or plain) backdrop is not.
        seeds = cap_hair & person
        if small_prior is not None:  # where the prior is sure, and it is not skin
            seeds |= (small_prior > PRIOR_SURE) & ~skin & person & ~never
        if seeds.sum() >= MIN_SAMPLES:
            m[head & _smooth(lab, seeds)] = cv2.GC_PR_BGD
        m[seeds] = cv2.GC_FGD
        m[~person] = cv2.GC_BGD
        m[never | neck] = cv2.GC_BGD
        m[(yy > lm[8, 1] + 0.8 * height) & (np.abs(xx - cx) < 0.6 * width)] = cv2.GC_BGD
        if likely is not None:
            # Within the soft labels the prior decides which side GrabCut starts from;
            # the hard seeds above stay, and the colour models still have the last word.
            soft = (m == cv2.GC_PR_FGD) | (m == cv2.GC_PR_BGD)
            m[soft] = np.where(likely[soft], cv2.GC_PR_FGD, cv2.GC_PR_BGD)
        hair = _grabcut(bgr, m, iterations) & person & ~never
        hair = _clean(hair, cap | head, size)
        if hair.sum() < MIN_HAIR * outline.sum():
            hair[:] = False  # a few lit spots on a bald scalp
        face = outline & ~hair & (skin | jaw_in)
    else:
        # No face: a hair close-up or a back view. The foreground is the hair, and so
        # probably is whatever has the colours of a small core at the centre (small: a
        # back view's head fills little of the frame). An edge of the frame is background
        # only where few of its pixels have those colours: in a close-up the hair runs
        # off the frame, and seeding it as background made the whole mask empty.
        centre = (np.abs(xx / sw - 0.5) < 0.25) & (np.abs(yy / sh - 0.45) < 0.3)
        core = (np.abs(xx / sw - 0.5) < 0.1) & (np.abs(yy / sh - 0.45) < 0.12)
        skin = _skin_box(bgr)
        core_skin = skin[core].mean()
        # A face in profile: its cheek gives this face's skin colour, which is then not
        # hair, and the core's hair colours are taken without it (the centre of a profile
        # is often the cheek or the ear: the face was parsed as hair).
        side_face = _profile_cheek(bgr, skin, xx, yy) if profile else None
        face_like = face_sure = np.zeros((sh, sw), bool)
        if side_face is not None:
            cheek, sure = side_face
            face_like = _colour_distance(lab, lab[cheek]) < LIKE_DEVIATIONS
            face_sure = face_like & sure
            if (core & ~face_like).sum() >= MIN_SAMPLES:
                core = core & ~face_like
        like_core = _colour_distance(lab, lab[core]) < LIKE_DEVIATIONS
        m = np.full((sh, sw), cv2.GC_PR_BGD, np.uint8)
        m[centre | like_core] = cv2.GC_PR_FGD
        # Smooth regions, measured against the core's texture, are probably not hair.
        m[_smooth(lab, core) & ~core] = cv2.GC_PR_BGD
        # The neck, ears and face of a back or profile view are not hair: without
        # landmarks there is no cheek to learn the skin from (unless a face in profile
        # gave one, above), so a fixed skin box is used, unless the core's own colours
        # fall in it (blond or red hair).
        if core_skin < 0.5:
            m[skin & ~core] = cv2.GC_PR_BGD
        m[face_like & ~core] = cv2.GC_PR_BGD
        m[face_sure] = cv2.GC_BGD
        for edge in (np.s_[:band], np.s_[-band:], np.s_[:, :band], np.s_[:, -band:]):
            if like_core[edge].mean() < 0.3:
                m[edge] = cv2.GC_BGD
        flat = lab.reshape(-1, 3).std(0).max() < FLAT_STD
        hair = (np.zeros((sh, sw), bool) if flat
                else _clean(_grabcut(bgr, m, iterations), None, size))
        face = face_sure & ~hair
    if scale < 1:
        def up(m: np.ndarray) -> np.ndarray:
            return cv2.resize(m.astype(np.uint8) * 255, (w, h),
                              interpolation=cv2.INTER_LINEAR) > 127
        hair, face = up(hair), up(face)
    face &= ~hair
    return HairParse(hair, face, ~(hair | face), landmarks is not None,
                     prior is not None and landmarks is not None,
                     side_face is not None)


SEGMENTER_THRESHOLD = 0.5
"""Hair probability (the segmenter's, flip-averaged) above which a pixel is hair."""
SURE_HAIR, SURE_NOT = 0.95, 0.02
"""Probabilities above and below which GrabCut's refinement keeps the segmenter's label as
certain; between them it decides by colour."""
EDGE_EPS = 100.0
"""The guided filter's regularisation (grey levels squared) that makes the segmenter's
map follow the photo's edges (radius 1 % of the photo's longer side): over the 104
shared Figaro and CelebAMask photos, mean IoU 0.8093 without, 0.8107 at 100, 0.8056 at
650, 0.8021 at 2500."""
NEAR_FACE = 1.2
"""A hair region counts only if it comes within this many face sizes (the iBUG outline's
height) of the face being fitted: hair of another person is dropped."""


def segment_hair(rgb: np.ndarray, landmarks: np.ndarray | None = None, *,
                 refine: bool = True, work_size: int = 384) -> HairParse:
    """Hair, face and background masks from MediaPipe's hair segmenter
    (:func:`head360cli.perception.hair.hair_probability`), read on the photo and on its
    mirror image and averaged, made to follow the photo's edges by a guided filter
    (:data:`EDGE_EPS`); a face tilted by 15 degrees or more (by its eyes) is read in a
    copy turned upright, in steps of 30 degrees (the astronaut lying on her side: hair
    IoU with her upright parse 0.69 as she lies); with ``refine``, GrabCut decides the
    uncertain band by colour
    (the segmenter's sure labels kept); with ``landmarks`` (``(68, 2)``), the face below
    the brows is never hair and only hair near the face counts.

    Args:
        rgb: ``(H, W, 3)`` uint8 RGB photo (checked by :func:`parse_hair`).
        landmarks: The fitted face's iBUG landmarks, or ``None``.
        refine: Whether to refine by GrabCut.
        work_size: Longest side GrabCut runs at.
    """
    import cv2

    from head360cli.perception.hair import hair_probability

    h, w = rgb.shape[:2]
    turn = 0.0
    if landmarks is not None:  # the segmenter reads upright heads: a tilted one is turned
        eyes = np.mean(landmarks[42:48], 0) - np.mean(landmarks[36:42], 0)
        turn = 30.0 * round(float(np.degrees(np.arctan2(eyes[1], eyes[0]))) / 30.0)
    if turn:
        from head360cli.fitting.landmarks import turned_image

        upright, forward = turned_image(rgb, turn)
    else:
        upright = rgb
    prob = (hair_probability(upright) + hair_probability(
        np.ascontiguousarray(upright[:, ::-1]))[:, ::-1]) / 2
    if turn:
        prob = cv2.warpAffine(prob.astype(np.float32), forward, (w, h),
                              flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    radius = max(2, round(0.01 * max(h, w)))
    prob = np.clip(cv2.ximgproc.guidedFilter(rgb, prob.astype(np.float32), radius,
                                             EDGE_EPS), 0.0, 1.0)
    face = np.zeros((h, w), bool)
    if landmarks is not None:
        lm = np.asarray(landmarks, np.float32)
        prob = np.where(_poly((h, w), _face_outline(lm, 0.0)), 0.0, prob)
        face = _poly((h, w), _face_outline(lm, 0.45))
    hair = prob > SEGMENTER_THRESHOLD
    if refine and hair.any():
        scale = min(1.0, work_size / max(h, w))
        size = (max(1, round(w * scale)), max(1, round(h * scale)))
        small = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA) if scale < 1 else rgb
        p = cv2.resize(prob, size, interpolation=cv2.INTER_AREA)
        m = np.where(p > SEGMENTER_THRESHOLD, cv2.GC_PR_FGD, cv2.GC_PR_BGD).astype(np.uint8)
        m[p > SURE_HAIR] = cv2.GC_FGD
        m[p < SURE_NOT] = cv2.GC_BGD
        if landmarks is not None:
            m[_poly(m.shape, _face_outline(lm * scale, 0.0))] = cv2.GC_BGD
        refined = _grabcut(np.ascontiguousarray(small[..., ::-1]), m, 3)
        hair = cv2.resize(refined.astype(np.uint8), (w, h),
                          interpolation=cv2.INTER_NEAREST).astype(bool)
    if landmarks is not None and hair.any():
        height = float(np.linalg.norm(lm[8] - lm[17:27].mean(0)))
        away = cv2.distanceTransform((~face).astype(np.uint8), cv2.DIST_L2, 3)
        near = away <= NEAR_FACE * height
        _, labels = cv2.connectedComponents(hair.astype(np.uint8), connectivity=8)
        keep = np.unique(labels[near & (labels > 0)])
        hair = np.isin(labels, keep)
    face &= ~hair
    return HairParse(hair, face, ~(hair | face), landmarks is not None)

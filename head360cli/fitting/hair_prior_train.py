"""Training the learned hair prior (:mod:`head360cli.fitting.hair_prior`) on corpus renders.

The data are head360's own synthetic heads (``Views`` of a SynHead-P split): each head is
rendered from a few random cameras around the front (the prior is only used when a face
was found), with its own or a random hairstyle and colour and sometimes an expression,
and every view is warped to the aligned crop by its true landmarks. The renders have no
backdrop, and real photos do, so each batch composites the head over a random backdrop
(crops of scikit-image's bundled sample photos, smooth random colour fields, flat colours)
and jitters colour, geometry, lighting, blur and noise: what the network has to learn is
the shape of hair around a face, not the corpus's backdrop or palette.

``head360 train-hair-prior`` runs :func:`train_hair_prior`. Given a ``checkpoint`` path
(the command's is :func:`resume_path`, ``<out stem>.resume.pt``), training saves its
state there every :data:`CHECKPOINT_EVERY` steps and when stopped by Ctrl-C, SIGTERM or
SIGHUP, and a later run with the same settings resumes from it (rendering the same crops
again: they are drawn from the seed).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.nn import functional as F

from head360cli.fitting.hair_prior import (
    ALIGN_LANDMARKS,
    HairPrior,
    HairPriorConfig,
    HairPriorNet,
    align_matrix,
)

__all__ = ["BACKDROPS", "CHECKPOINT_EVERY", "RUN_FORMAT", "Augmenter", "HairPriorTrainConfig",
           "canonical_landmarks", "draw_hat", "render_crops", "resume_path",
           "train_hair_prior"]

RUN_FORMAT = "head360-hair-prior-run/1"
"""The ``format`` of a resumable training checkpoint (not a prior: ``fit`` cannot use it)."""
CHECKPOINT_EVERY = 100
"""Steps between resumable checkpoints (about 50 s of training at the defaults)."""
RESUMABLE = ("steps", "minutes")
"""The settings a resumed run may change; any other must be the interrupted run's."""

BACKDROPS = ("brick", "chelsea", "coffee", "coins", "grass", "gravel", "rocket", "page",
             "text", "moon", "colorwheel", "logo", "clock", "horse", "hubble_deep_field",
             "immunohistochemistry", "retina", "stereo_motorcycle", "cat")
"""scikit-image sample images used as backdrops (all bundled with it). ``astronaut`` and
``camera`` are left out: they are development photos of the parse."""


@dataclasses.dataclass
class HairPriorTrainConfig:
    """What the hair prior is trained on and how."""

    heads: int = 600
    """Corpus heads rendered (indices ``0 .. heads - 1``)."""
    views: int = 5
    """Random views per head."""
    split: str = "train"
    """Corpus split."""
    seed: int = 3
    """Corpus seed: 3 keeps the training heads apart from the bench's (0) and the
    parse's development heads (1 and 2)."""
    render_size: int = 192
    """Resolution the heads are rendered at before the crop."""
    yaw: float = 45.0
    """Cameras' yaw is uniform in +-this, degrees."""
    pitch: tuple[float, float] = (-15.0, 20.0)
    """Range of the cameras' pitch, degrees."""
    style_share: float = 0.7
    """Share of heads given a random hairstyle instead of their own."""
    colour_share: float = 0.7
    """Share of heads given a random hair colour instead of their own."""
    expression_share: float = 0.5
    """Share of heads given three random blendshapes at random weights."""
    shrink: float = 0.8
    """The canonical landmarks are the mean frontal ones shrunk by this about the crop's
    centre, so that the crop shows the hair around the face."""
    steps: int = 2400
    """Optimiser steps."""
    minutes: float = 0.0
    """Stop after this much training time as well (0: no limit)."""
    batch: int = 24
    """Crops per step."""
    lr: float = 2e-3
    """AdamW learning rate at the start; it decays linearly to 5 % of it."""
    weight_decay: float = 1e-4
    """AdamW weight decay."""
    frame_share: float = 0.0
    """Share of crops shown as if the photo ended inside the crop: beyond a random
    rectangle around the face the crop repeats the rectangle's edge pixels, as
    :meth:`head360cli.fitting.hair_prior.HairPrior.crop_photo` fills the part of a crop
    outside the photo (a face that fills the photo leaves most of its crop outside)."""
    init: str = ""
    """A hair-prior checkpoint whose network training starts from (fine-tuning; its
    network shape is kept); empty: random weights."""
    hat_share: float = 0.0
    """Share of crops with a hat drawn over the top of the head (:func:`draw_hat`): its
    pixels are not hair in the target, so the prior learns that a cap or beanie over
    the hair is not hair."""

    def __post_init__(self) -> None:
        """Refuse settings no run can train with (the CLI checks its options first, with
        their own names; this guards library callers).

        Raises:
            BadInputError: The first field out of range, expected against found.
        """
        import math

        from head360cli.errors import BadInputError

        def bad(name: str, expected: str) -> BadInputError:
            return BadInputError(f"expected HairPriorTrainConfig.{name} {expected}, found "
                                 f"{getattr(self, name)!r}")

        for name in ("heads", "views", "steps", "batch", "render_size"):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 1):
                raise bad(name, ">= 1")
        if not (isinstance(self.seed, int) and self.seed >= 0):
            raise bad("seed", ">= 0")
        for name in ("lr",):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise bad(name, "finite and > 0")
        for name in ("minutes", "weight_decay", "yaw"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise bad(name, "finite and >= 0")
        for name in ("style_share", "colour_share", "expression_share", "frame_share",
                     "hat_share"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise bad(name, "in [0, 1]")
        if not 0.0 < self.shrink <= 1.0:
            raise bad("shrink", "in (0, 1]")
        low, high = self.pitch
        if not -90.0 <= low <= high <= 90.0:
            raise bad("pitch", "a (low, high) range within -90..90 degrees")


def canonical_landmarks(views: Any, crop: int, shrink: float, heads: int = 20) -> np.ndarray:
    """Mean frontal positions ``(41, 2)`` of landmarks 27-67 in the crop's pixels.

    Args:
        views: A ``head360cli.model.data.Views`` of the training corpus.
        crop: Side of the crop.
        shrink: Scale about the crop's centre (below 1: more context around the face).
        heads: Heads averaged.
    """
    from head360cli.geometry.cameras import RIG_DISTANCE, camera_on_sphere, project
    from head360cli.mesh.bilinear import load_bilinear

    lm_index = load_bilinear().landmarks
    cam = camera_on_sphere(torch.tensor([0.0]), torch.tensor([0.0]), RIG_DISTANCE)
    points = []
    for i in range(min(heads, views.identities)):
        b = views.render(i, np.zeros(52, np.float32), cam)
        px, _ = project(b.verts[:1], cam, views.intrinsics[None])
        points.append(px[0].numpy()[lm_index][ALIGN_LANDMARKS] * crop / views.size)
    canon = np.mean(points, 0)
    return ((canon - crop / 2) * shrink + crop / 2).astype(np.float32)


def render_crops(cfg: HairPriorTrainConfig, crop: int, progress: Callable[[int, int], None]
                 | None = None) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Render the training views and warp them to aligned crops.

    Args:
        cfg: What to render.
        crop: Side of the crops.
        progress: Called with ``(heads done, heads)``.

    Returns:
        ``(canon (41, 2), {"rgb": (N, S, S, 3), "alpha": (N, S, S), "hair": (N, S, S)})``,
        all uint8, ``N = heads * views``.
    """
    import cv2

    from head360cli.geometry.cameras import RIG_DISTANCE, camera_on_sphere, project
    from head360cli.mesh.bilinear import load_bilinear
    from head360cli.model.data import Views
    from head360cli.synth.hair import HAIR_COLOURS, HAIRSTYLES

    lm_index = load_bilinear().landmarks
    rng = np.random.default_rng(cfg.seed)
    views = Views(cfg.heads, split=cfg.split, seed=cfg.seed, size=cfg.render_size)
    canon = canonical_landmarks(views, crop, cfg.shrink)
    colours = list(HAIR_COLOURS)
    out: dict[str, list[np.ndarray]] = {"rgb": [], "alpha": [], "hair": []}
    for i in range(cfg.heads):
        n = cfg.views
        yaw = torch.tensor(rng.uniform(-cfg.yaw, cfg.yaw, n), dtype=torch.float32)
        pitch = torch.tensor(rng.uniform(*cfg.pitch, n), dtype=torch.float32)
        cams = camera_on_sphere(yaw, pitch, RIG_DISTANCE)
        weights = np.zeros(52, np.float32)
        if rng.random() < cfg.expression_share:
            weights[rng.integers(0, 52, 3)] = rng.uniform(0, 1, 3)
        style = int(rng.integers(len(HAIRSTYLES))) if rng.random() < cfg.style_share else None
        colour = (colours[rng.integers(len(colours))] if rng.random() < cfg.colour_share
                  else None)
        b = views.render(i, weights, cams, with_hair=True, style=style, colour=colour)
        px, _ = project(b.verts, cams, views.intrinsics[None].expand(n, 3, 3))
        for v in range(n):
            m = align_matrix(px[v].numpy()[lm_index], canon)  # the true landmarks: never None

            def warp(image: np.ndarray, m: np.ndarray = m) -> np.ndarray:
                return cv2.warpAffine(image, m, (crop, crop), flags=cv2.INTER_LINEAR,
                                      borderValue=0)

            def u8(x: np.ndarray) -> np.ndarray:
                return (np.clip(x, 0, 1) * 255).round().astype(np.uint8)

            out["rgb"].append(u8(warp(b.rgb[v].permute(1, 2, 0).numpy())))
            out["alpha"].append(u8(warp(b.alpha[v, 0].numpy())))
            out["hair"].append(u8(warp(b.hair_alpha[v, 0].numpy())))
        views.forget()  # each head is rendered once
        if progress is not None:
            progress(i + 1, cfg.heads)
    return canon, {k: np.stack(v) for k, v in out.items()}


def _load_backdrops() -> list[torch.Tensor]:
    import skimage.data

    images = []
    for name in BACKDROPS:
        im = getattr(skimage.data, name)()
        if isinstance(im, tuple):  # stereo_motorcycle: (left, right, disparity)
            im = im[0]
        im = np.asarray(im, np.float32)
        im = im / (255.0 if im.max() > 1.5 else 1.0)
        if im.ndim == 2:
            im = np.repeat(im[..., None], 3, 2)
        images.append(torch.tensor(im[..., :3]).permute(2, 0, 1).contiguous())
    return images


def draw_hat(img: torch.Tensor, alpha: torch.Tensor, eyes: np.ndarray,
             rand: Callable[[], float], vivid: float = 1.0
             ) -> tuple[torch.Tensor, torch.Tensor]:
    """A hat over the top of a head: a dome from a line above the eyes to above the
    head's top, as wide as the head there, sometimes with a brim; one colour (vivid or
    neutral), shaded, sometimes knitted.

    Args:
        img: ``(3, H, W)`` image in [0, 1].
        alpha: ``(H, W)`` the head's coverage (hair included) in [0, 1].
        eyes: ``(12, 2)`` the eyes' landmarks (iBUG 36-47) in pixels.
        rand: Draws a uniform number in [0, 1).
        vivid: Chance of a saturated colour; otherwise a neutral one (black, grey,
            white, beige), which short dark or grey hair can look like.

    Returns:
        ``(image with the hat, hat coverage (H, W) in [0, 1])``; coverage all zero where
        the head has no pixels above the hat's line.
    """
    import colorsys

    _, h, w = img.shape
    d = float(np.linalg.norm(eyes[:6].mean(0) - eyes[6:].mean(0)))
    eye_y, eye_x = float(eyes[:, 1].mean()), float(eyes[:, 0].mean())
    cut = eye_y - d * (0.8 + 0.8 * rand())  # the hat's lower edge, above the brows
    head = alpha > 0.5
    above = head[:max(0, int(cut))]
    if d <= 0 or not above.any():
        return img, torch.zeros_like(alpha)
    rows = torch.nonzero(above.any(1))[:, 0]
    cols = torch.nonzero(above.any(0))[:, 0]
    top, x0, x1 = float(rows[0]), float(cols[0]), float(cols[-1])
    hc = 0.5 * (x0 + x1) + 0.1 * d * (rand() - 0.5) if x1 > x0 else eye_x
    half = max(0.5 * (x1 - x0), d) * (1.0 + 0.15 * rand())
    height = max(cut - top, 0.3 * d) * (1.05 + 0.3 * rand())
    yy, xx = torch.meshgrid(torch.arange(h, dtype=img.dtype) + 0.5,
                            torch.arange(w, dtype=img.dtype) + 0.5, indexing="ij")
    u, v = (xx - hc) / half, (yy - cut) / height
    lower = cut + d * (0.4 * rand() - 0.1) * u ** 2  # the edge bends down (or up) aside
    hat = (u ** 2 + v ** 2 <= 1.0) & (yy <= lower)
    if rand() < 0.5:  # a brim (a cap's peak seen from the front)
        bw, bh = half * (0.9 + 0.4 * rand()), d * (0.12 + 0.3 * rand())
        hat |= ((xx - hc) / bw) ** 2 + ((yy - lower) / bh) ** 2 <= 1.0
    if rand() < vivid:
        rgb = colorsys.hsv_to_rgb(rand(), 0.5 + 0.5 * rand(), 0.3 + 0.7 * rand())
    else:  # black, grey, white, beige, navy...
        rgb = colorsys.hsv_to_rgb(rand(), 0.3 * rand(), 0.05 + 0.9 * rand())
    colour = torch.tensor(rgb, dtype=img.dtype)[:, None, None]
    shade = 1.0 + 0.5 * (rand() - 0.5) * v + 0.4 * (rand() - 0.5) * u
    if rand() < 0.3:  # knitted rows
        shade = shade + 0.12 * torch.sin(yy * (2 * np.pi / (2.0 + 4.0 * rand())))
    painted = (colour * shade).clamp(0, 1)
    cover = F.avg_pool2d(hat.to(img.dtype)[None, None], 3, 1, 1)[0, 0]
    return img * (1 - cover) + painted * cover, cover


_YIQ = torch.tensor([[0.299, 0.587, 0.114], [0.596, -0.274, -0.322], [0.211, -0.523, 0.312]])


class Augmenter:
    """Random training batches from rendered crops: backdrop, colour, geometry, lighting
    and, for shares of them, a photo's edge (:meth:`_frame`) and a hat (:meth:`_hats`).

    Args:
        data: ``render_crops``'s arrays.
        seed: Seed of the augmentation's generator (the frames use ``seed + 1``, the
            hats ``seed + 2``).
        frame_share: Share of crops cut as by a photo's edge
            (:attr:`HairPriorTrainConfig.frame_share`).
        hat_share: Share of crops with a hat (:attr:`HairPriorTrainConfig.hat_share`).
        canon: ``(41, 2)`` the crops' canonical landmarks 27-67 (``render_crops``'s),
            which place the hats; needed when ``hat_share`` is above 0.

    Raises:
        ValueError: ``hat_share`` is above 0 and ``canon`` is missing.
    """

    def __init__(self, data: dict[str, np.ndarray], seed: int = 0,
                 frame_share: float = 0.0, hat_share: float = 0.0,
                 canon: np.ndarray | None = None) -> None:
        self.rgb = torch.tensor(data["rgb"]).permute(0, 3, 1, 2)
        self.alpha = torch.tensor(data["alpha"])[:, None]
        self.hair = torch.tensor(data["hair"])[:, None]
        self.size = self.rgb.shape[-1]
        self.gen = torch.Generator().manual_seed(seed)
        # the photo frames draw from their own generator: the other augmentations of a
        # batch are the same with and without them
        self.frame_share = frame_share
        self.frame_gen = torch.Generator().manual_seed(seed + 1)
        self.hat_share = hat_share
        self.hat_gen = torch.Generator().manual_seed(seed + 2)
        if hat_share > 0 and canon is None:
            raise ValueError("expected the canonical landmarks to place hats")
        # canon holds landmarks 27-67 (ALIGN_LANDMARKS); the eyes are landmarks 36-47
        eyes = slice(36 - ALIGN_LANDMARKS.start, 48 - ALIGN_LANDMARKS.start)
        self.eyes = None if canon is None else np.asarray(canon, np.float32)[eyes]
        self.backdrops = _load_backdrops()

    def generators(self) -> tuple[torch.Generator, ...]:
        """Every random generator the batches draw from (a checkpoint saves their states)."""
        return self.gen, self.frame_gen, self.hat_gen

    def _rand(self, *shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=self.gen)

    def _backdrop(self, n: int) -> torch.Tensor:
        s = self.size
        out = torch.empty(n, 3, s, s)
        for b in range(n):
            r = self._rand(1).item()
            if r < 0.45:  # a crop of a sample photo, half of them defocused
                im = self.backdrops[int(self._rand(1).item() * len(self.backdrops))]
                _, h, w = im.shape
                side = int(min(h, w) * (0.2 + 0.8 * self._rand(1).item()))
                y = int((h - side) * self._rand(1).item())
                x = int((w - side) * self._rand(1).item())
                out[b] = F.interpolate(im[None, :, y:y + side, x:x + side], size=(s, s),
                                       mode="bilinear", align_corners=False)[0]
                if self._rand(1).item() < 0.5:
                    out[b] = F.avg_pool2d(out[b][None], 5, 1, 2)[0]
            elif r < 0.8:  # a smooth random colour field
                k = int(2 + self._rand(1).item() * 6)
                field = self._rand(1, 3, k, k)
                out[b] = F.interpolate(field, size=(s, s), mode="bicubic",
                                       align_corners=False)[0].clamp(0, 1)
            else:
                out[b] = self._rand(3, 1, 1).expand(3, s, s)
        return out

    def _jitter(self, img: torch.Tensor, strength: float) -> torch.Tensor:
        """Brightness, contrast, saturation and hue (a rotation of YIQ's chroma)."""
        n = len(img)
        bright = 1 + strength * (self._rand(n, 1, 1, 1) - 0.5) * 0.8
        contrast = 1 + strength * (self._rand(n, 1, 1, 1) - 0.5) * 0.8
        sat = 1 + strength * (self._rand(n, 1, 1, 1) - 0.5) * 1.2
        mean = img.mean((1, 2, 3), keepdim=True)
        img = ((img - mean) * contrast + mean) * bright
        grey = img.mean(1, keepdim=True)
        img = grey + (img - grey) * sat
        angle = strength * (self._rand(n) - 0.5) * 0.6
        yiq = torch.einsum("ij,bjhw->bihw", _YIQ, img)
        c, s = torch.cos(angle)[:, None, None], torch.sin(angle)[:, None, None]
        i, q = yiq[:, 1] * c - yiq[:, 2] * s, yiq[:, 1] * s + yiq[:, 2] * c
        img = torch.einsum("ij,bjhw->bihw", torch.linalg.inv(_YIQ),
                           torch.stack([yiq[:, 0], i, q], 1))
        return img.clamp(0, 1)

    def batch(self, n: int) -> tuple[torch.Tensor, torch.Tensor]:
        """``n`` augmented crops ``(n, 3, S, S)`` in [0, 1] and their hair masks
        ``(n, 1, S, S)`` in {0, 1}."""
        s = self.size
        idx = torch.randint(0, len(self.rgb), (n,), generator=self.gen)
        x = self.rgb[idx].float() / 255
        a = self.alpha[idx].float() / 255
        h = self.hair[idx].float() / 255
        # hair and head get their own colour jitter (hair colours vary more)
        hair_x = self._jitter(x.clone(), 1.5)
        x = self._jitter(x, 1.0)
        x = x * (1 - h) + hair_x * h
        img = x * a + self._jitter(self._backdrop(n), 1.0) * (1 - a)
        if self.hat_share > 0:
            img, h = self._hats(img, a, h)
        # rotation, scale, shift and mirror
        ang = (self._rand(n) - 0.5) * 0.35
        sc = 1 + (self._rand(n) - 0.5) * 0.25
        tx, ty = (self._rand(n) - 0.5) * 0.15, (self._rand(n) - 0.5) * 0.15
        theta = torch.stack([
            torch.stack([sc * torch.cos(ang), -sc * torch.sin(ang), tx], 1),
            torch.stack([sc * torch.sin(ang), sc * torch.cos(ang), ty], 1)], 1)
        theta[self._rand(n) < 0.5, 0, :2] *= -1
        grid = F.affine_grid(theta, (n, 3, s, s), align_corners=False)
        img = F.grid_sample(img, grid, padding_mode="reflection", align_corners=False)
        h = F.grid_sample(h, grid, padding_mode="zeros", align_corners=False)
        # lighting gradient, gamma, blur, sensor noise, greyscale
        gy = torch.linspace(-1, 1, s)[None, None, :, None]
        gx = torch.linspace(-1, 1, s)[None, None, None, :]
        img = img * (1 + 0.3 * (self._rand(n, 1, 1, 1) - 0.5) * gx
                     + 0.3 * (self._rand(n, 1, 1, 1) - 0.5) * gy)
        img = img.clamp(1e-4, 1) ** (0.7 + 0.6 * self._rand(n, 1, 1, 1))
        blur = self._rand(n) < 0.3
        if blur.any():
            img[blur] = F.avg_pool2d(img[blur], 3, 1, 1)
        img = img + self._rand(n, 1, 1, 1) * 0.04 * torch.randn(img.shape, generator=self.gen)
        grey = self._rand(n) < 0.08
        img[grey] = img[grey].mean(1, keepdim=True).expand(-1, 3, -1, -1)
        if self.frame_share > 0:
            img = self._frame(img)
        return img.clamp(0, 1), (h > 0.5).float()

    def _hats(self, img: torch.Tensor, a: torch.Tensor, h: torch.Tensor
              ) -> tuple[torch.Tensor, torch.Tensor]:
        """A :attr:`hat_share` of the crops with a hat (:func:`draw_hat`) over the head,
        its pixels taken out of the hair target; from their own generator."""
        def rand() -> float:
            return torch.rand(1, generator=self.hat_gen).item()

        chosen = torch.rand(len(img), generator=self.hat_gen) < self.hat_share
        img, h = img.clone(), h.clone()
        for b in chosen.nonzero()[:, 0].tolist():
            img[b], cover = draw_hat(img[b], a[b, 0], self.eyes, rand)
            h[b, 0] = h[b, 0] * (cover < 0.5)
        return img, h

    FRAME_CUT = 0.7
    """Chance that each side of a framed crop is cut."""

    def _frame(self, img: torch.Tensor) -> torch.Tensor:
        """A :attr:`frame_share` of ``img (n, 3, S, S)`` cut to a random rectangle around
        the crop's face, the rest filled by repeating the rectangle's edge pixels (the
        photo's edge replicated, as at inference). Each side is cut with chance
        :attr:`FRAME_CUT`, at most 30 % of the crop in (25 % from the bottom): the face
        is always inside. The hair target is left whole."""
        n, _, s, _ = img.shape

        def rand(*shape: int) -> torch.Tensor:
            return torch.rand(*shape, generator=self.frame_gen)

        framed = rand(n) < self.frame_share
        cuts = (rand(n, 4) < self.FRAME_CUT) * rand(n, 4) * torch.tensor(
            [0.3, 0.3, 0.3, 0.25]) * s
        out = img.clone()
        ramp = torch.arange(s)
        for b in framed.nonzero()[:, 0].tolist():
            x0, y0 = int(cuts[b, 0]), int(cuts[b, 1])
            x1, y1 = s - int(cuts[b, 2]), s - int(cuts[b, 3])
            ix, iy = ramp.clamp(x0, x1 - 1), ramp.clamp(y0, y1 - 1)
            out[b] = img[b][:, iy][:, :, ix]
        return out


def hair_loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Binary cross-entropy plus soft Dice loss (per image, averaged), a scalar."""
    p = torch.sigmoid(logits)
    dice = (2 * (p * target).sum((1, 2, 3)) + 1) / ((p + target).sum((1, 2, 3)) + 1)
    return F.binary_cross_entropy_with_logits(logits, target) + 1 - dice.mean()


def resume_path(out: str | Path) -> Path:
    """Where ``head360 train-hair-prior -o out`` keeps its resumable checkpoint:
    ``<out stem>.resume.pt`` beside ``out``."""
    out = Path(out)
    return out.with_name(f"{out.stem}.resume.pt")


def train_hair_prior(cfg: HairPriorTrainConfig, net_cfg: HairPriorConfig,
                     log: Callable[[str], None] | None = None, progress: bool = True,
                     data: tuple[np.ndarray, dict[str, np.ndarray]] | None = None,
                     checkpoint: str | Path | None = None, stop_at: int | None = None,
                     ) -> tuple[HairPrior, dict[str, Any]]:
    """Render the training crops and train a hair prior on them (CPU or one device).

    Args:
        cfg: Data and optimisation settings.
        net_cfg: Network shape (with ``cfg.init``, the checkpoint's own is used; its crop
            must be the same).
        log: Called with a line of text now and then.
        progress: Show progress bars.
        data: ``render_crops``'s result, to skip rendering (tests).
        checkpoint: Where to keep a resumable checkpoint (every :data:`CHECKPOINT_EVERY`
            steps, and after the step it is on when Ctrl-C, SIGTERM or SIGHUP arrives:
            the signal then takes effect). One there already is resumed from; the caller
            removes it once the prior is saved. ``None``: no checkpoint, and signals act
            at once.
        stop_at: End after this step with a checkpoint, as an interruption would (the
            learning rate still decays towards ``cfg.steps``; tests).

    Returns:
        ``(prior, summary)``: the trained prior and what training did (steps, seconds,
        final loss, configs, the step it resumed from), which is also stored in the
        prior's file.

    Raises:
        BadInputError: The checkpoint is another run's: settings other than
            :data:`RESUMABLE` differ, named with both values.
        FileFormatError: The checkpoint or ``cfg.init`` cannot be read as one.
    """
    from head360cli.interrupts import catch_interrupts, restore_handlers
    from head360cli.progress import progress_bar

    say = log or (lambda _: None)
    torch.manual_seed(cfg.seed)
    start = None
    if cfg.init:  # read first: a file that is no prior fails before minutes of rendering
        from head360cli.fitting.hair_prior import load_hair_prior

        start = load_hair_prior(cfg.init)
        net_cfg = start.net.cfg
    state = None
    if checkpoint is not None and Path(checkpoint).is_file():  # before the rendering too
        state = _read_run(Path(checkpoint), cfg, net_cfg)
        say(f"resuming from step {state['step']} of {cfg.steps} ({checkpoint}); "
            f"the crops are rendered again")
    t0 = time.perf_counter()
    if data is None:
        bar = iter(progress_bar(range(cfg.heads), total=cfg.heads, desc="render",
                                enabled=progress))

        def tick(done: int, total: int) -> None:
            next(bar, None)
            if done % 100 == 0 or done == total:
                say(f"rendered {done}/{total} heads ({time.perf_counter() - t0:.0f} s)")

        data = render_crops(cfg, net_cfg.crop, tick)
        next(bar, None)
    canon, arrays = data
    render_s = time.perf_counter() - t0
    aug = Augmenter(arrays, seed=cfg.seed, frame_share=cfg.frame_share,
                    hat_share=cfg.hat_share, canon=canon)
    if start is not None:
        from head360cli.errors import BadInputError

        if not np.allclose(start.canon, canon, atol=1e-3):
            raise BadInputError(f"expected {cfg.init} to align its crops as these renders "
                                f"do, found canonical landmarks up to "
                                f"{np.abs(start.canon - canon).max():.2f} px apart")
        net = start.net.train()
    else:
        net = HairPriorNet(net_cfg).train()
    opt = torch.optim.AdamW(net.parameters(), cfg.lr, weight_decay=cfg.weight_decay)
    losses: list[float] = []
    first, trained_s = 0, 0.0  # the step to go on from, and the seconds trained before
    if state is not None:
        net.load_state_dict(state["net"])
        opt.load_state_dict(state["optimizer"])
        for gen, saved in zip(aug.generators(), state["generators"], strict=True):
            gen.set_state(saved)
        torch.set_rng_state(state["torch_rng"])
        losses = list(state["losses"])
        first, trained_s = int(state["step"]), float(state["train_seconds"])
    t1 = time.perf_counter() - trained_s  # a resumed run's minutes count the earlier ones
    step = first
    interrupted: list[int] = []
    previous = catch_interrupts(interrupted) if checkpoint is not None else {}
    try:
        for step in progress_bar(range(first + 1, cfg.steps + 1), total=cfg.steps - first,
                                 desc="train", enabled=progress):
            elapsed = time.perf_counter() - t1
            if cfg.minutes and elapsed > cfg.minutes * 60:
                step -= 1
                break
            done = (step - 1) / cfg.steps
            if cfg.minutes:
                done = max(done, elapsed / (cfg.minutes * 60))
            for group in opt.param_groups:
                group["lr"] = cfg.lr * max(0.05, 1 - done)
            img, target = aug.batch(cfg.batch)
            loss = hair_loss(net(img), target)
            if not torch.isfinite(loss):  # diverged: every later step is NaN too
                from head360cli.errors import BadInputError

                anew = (f" and delete {checkpoint} to start anew" if checkpoint is not None
                        and Path(checkpoint).is_file() else "")
                raise BadInputError(f"expected the training loss to stay finite, found "
                                    f"{loss.item()} at step {step} (the weights diverged): "
                                    f"lower --lr (now {cfg.lr:g}){anew}")
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses = [*losses[-99:], loss.item()]  # the last 100: the logged mean's
            if step % 100 == 0:
                say(f"step {step}: loss {np.mean(losses):.4f} "
                    f"({time.perf_counter() - t1:.0f} s)")
            stop = bool(interrupted) or step == stop_at
            if checkpoint is not None and (stop or (step % CHECKPOINT_EVERY == 0
                                                    and step < cfg.steps)):
                _write_run(Path(checkpoint), cfg, net, opt, aug, step, losses,
                           time.perf_counter() - t1)
            if stop:
                break
    finally:
        restore_handlers(previous)
    if interrupted:
        import signal

        say(f"stopped after step {step}: run the same command to resume from it")
        signal.raise_signal(interrupted[0])  # handled as it would have been, now saved
    summary = {"steps": step, "render_seconds": round(render_s, 1),
               "train_seconds": round(time.perf_counter() - t1, 1),
               "final_loss": round(float(np.mean(losses)), 4) if losses else None,
               "crops": len(arrays["rgb"]), "train_config": dataclasses.asdict(cfg)}
    if state is not None:
        summary["resumed_from"] = first
    return HairPrior(net.eval(), canon, summary), summary


def _write_run(path: Path, cfg: HairPriorTrainConfig, net: HairPriorNet, opt: Any,
               aug: Augmenter, step: int, losses: list[float], seconds: float) -> None:
    """Write a resumable checkpoint of the run (atomically: a kill mid-write keeps the
    previous one)."""
    from head360cli.io.atomic import atomic_path

    blob = {"format": RUN_FORMAT, "train_config": dataclasses.asdict(cfg),
            "net_config": dataclasses.asdict(net.cfg), "step": step,
            "net": net.state_dict(), "optimizer": opt.state_dict(),
            "generators": [g.get_state() for g in aug.generators()],
            "torch_rng": torch.get_rng_state(), "losses": list(losses),
            "train_seconds": seconds}
    with atomic_path(path) as tmp:
        torch.save(blob, tmp)


def _read_run(path: Path, cfg: HairPriorTrainConfig, net_cfg: HairPriorConfig
              ) -> dict[str, Any]:
    """Read a checkpoint :func:`_write_run` wrote, as data only, and check that it is this
    run's: the same settings but for :data:`RESUMABLE`, the same network shape."""
    from head360cli.errors import BadInputError, FileFormatError
    from head360cli.io.torchfile import load_data

    blob = load_data(path, f"a {RUN_FORMAT} checkpoint")
    if not isinstance(blob, dict) or blob.get("format") != RUN_FORMAT:
        raise FileFormatError(f"{path}: expected a {RUN_FORMAT} checkpoint, found "
                              f"{blob.get('format') if isinstance(blob, dict) else 'none'}")
    ours = {k: v for k, v in dataclasses.asdict(cfg).items() if k not in RESUMABLE}
    theirs = {k: v for k, v in blob["train_config"].items() if k not in RESUMABLE}
    ours["network"], theirs["network"] = dataclasses.asdict(net_cfg), blob["net_config"]
    differ = [k for k in sorted(ours.keys() | theirs.keys())
              if _plain(ours.get(k)) != _plain(theirs.get(k))]
    if differ:
        k = differ[0]
        raise BadInputError(f"expected the settings of the interrupted run in {path} to "
                            f"resume it, found {k} {ours.get(k)!r} where it has "
                            f"{theirs.get(k)!r}: give its settings, or delete the file "
                            f"to start anew")
    if blob["step"] > cfg.steps:
        raise BadInputError(f"expected at least the {blob['step']} steps the interrupted "
                            f"run in {path} has done, found --steps {cfg.steps}")
    return blob


def _plain(value: Any) -> Any:
    """A config value compared as saved and as given (tuples and lists alike)."""
    return list(value) if isinstance(value, tuple | list) else value

"""A learned hair prior: a small U-Net that says where hair probably is in a face photo.

GrabCut (:mod:`head360cli.fitting.hair_parse`) separates hair by colour alone, and on
real photos the sides of the head are where it fails: hair beside the face often has the
colours of the backdrop or the shoulders. This network adds what colour cannot: the shape
of hair around a face. It sees a ``crop x crop`` RGB crop aligned by the inner-face
landmarks (brows, nose, eyes, mouth: iBUG 27-67) to canonical positions, and returns the
probability of hair per pixel, which is warped back to the photo. The parse then uses it
as GrabCut's soft labels (probable hair or probable not), so colour still has the last
word on what is hair; only where it is sure (``hair_parse.PRIOR_SURE``) does it make a
pixel certainly part of the person.

It is trained only on head360's own synthetic heads
(:mod:`head360cli.fitting.hair_prior_train`, ``head360 train-hair-prior``); the weights
ship as ``models/hair_prior.pt``. Without that file the parse runs without a prior.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

__all__ = ["FORMAT", "HairPrior", "HairPriorConfig", "HairPriorNet", "align_matrix",
           "default_hair_prior", "load_hair_prior", "save_hair_prior"]

FORMAT = "head360-hair-prior/1"
"""Tag of a hair-prior checkpoint; a file without it is refused."""

FILE_NAME = "hair_prior.pt"
"""Name of the shipped weights in the models folder."""

ALIGN_LANDMARKS = slice(27, 68)
"""The iBUG landmarks the crop is aligned by: nose, eyes and mouth (the jaw line and brows
move with pose and expression more than these)."""


@dataclasses.dataclass
class HairPriorConfig:
    """Shape of the hair-prior network and of its input."""

    width: int = 16
    """Channels of the first level; each level down doubles them, up to 8 times ``width``."""
    levels: int = 4
    """Down-sampling steps (each halves the resolution)."""
    crop: int = 128
    """Side of the aligned square crop the network sees, pixels. Must be divisible by
    ``2 ** levels``."""


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=1), nn.BatchNorm2d(cout),
                         nn.ReLU(inplace=True), nn.Conv2d(cout, cout, 3, padding=1),
                         nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class HairPriorNet(nn.Module):
    """U-Net from an RGB crop to hair logits.

    Args:
        cfg: Network shape.
    """

    def __init__(self, cfg: HairPriorConfig) -> None:
        super().__init__()
        self.cfg = cfg
        widths = [cfg.width * 2 ** min(i, 3) for i in range(cfg.levels)]
        self.down = nn.ModuleList()
        cin = 3
        for c in widths:
            self.down.append(_block(cin, c))
            cin = c
        self.bottom = _block(cin, cin)
        self.up = nn.ModuleList()
        for i in reversed(range(cfg.levels)):
            cout = widths[i - 1] if i > 0 else widths[0]
            self.up.append(_block(cin + widths[i], cout))
            cin = cout
        self.head = nn.Conv2d(cin, 1, 1)

    def forward(self, rgb: torch.Tensor) -> torch.Tensor:
        """Hair logits.

        Args:
            rgb: ``(B, 3, S, S)`` RGB in [0, 1], ``S`` divisible by ``2 ** levels``.

        Returns:
            ``(B, 1, S, S)`` logits (sigmoid: probability of hair).
        """
        x = (rgb - 0.5) / 0.25
        skips = []
        for block in self.down:
            x = block(x)
            skips.append(x)
            x = F.max_pool2d(x, 2)
        x = self.bottom(x)
        for block, skip in zip(self.up, reversed(skips), strict=True):
            x = F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=False)
            x = block(torch.cat([x, skip], 1))
        return self.head(x)


def align_matrix(landmarks: np.ndarray, canon: np.ndarray) -> np.ndarray | None:
    """Similarity transform ``(2, 3)`` taking a photo's landmarks onto the canonical crop.

    Args:
        landmarks: ``(68, 2)`` iBUG landmarks in the photo's pixels.
        canon: ``(41, 2)`` canonical positions of landmarks 27-67 in the crop's pixels.

    Returns:
        The matrix, or ``None`` when the landmarks do not determine one (degenerate).
    """
    import cv2

    cv2.setRNGSeed(0)  # least-median-of-squares samples at random: same input, same crop
    m, _ = cv2.estimateAffinePartial2D(np.asarray(landmarks, np.float32)[ALIGN_LANDMARKS],
                                       np.asarray(canon, np.float32), method=cv2.LMEDS)
    if m is None or not np.isfinite(m).all() or abs(np.linalg.det(m[:, :2])) < 1e-8:
        return None
    return m


class HairPrior:
    """A trained hair-prior network with the canonical landmarks its crops are aligned to.

    Args:
        net: The network (evaluated in eval mode).
        canon: ``(41, 2)`` canonical crop positions of landmarks 27-67.
        meta: What the checkpoint says about its training (shown by tools).
    """

    def __init__(self, net: HairPriorNet, canon: np.ndarray,
                 meta: dict[str, Any] | None = None) -> None:
        self.net = net.eval()
        self.canon = np.asarray(canon, np.float32)
        self.meta = meta or {}

    @property
    def crop(self) -> int:
        return self.net.cfg.crop

    def crop_photo(self, rgb: np.ndarray, landmarks: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray] | None:
        """The aligned crop of a photo.

        Args:
            rgb: ``(H, W, 3)`` uint8 RGB photo.
            landmarks: ``(68, 2)`` landmarks in its pixels.

        Returns:
            ``(crop (S, S, 3) float32 in [0, 1], matrix (2, 3))``, or ``None`` when the
            landmarks are degenerate.
        """
        import cv2

        m = align_matrix(landmarks, self.canon)
        if m is None:
            return None
        crop = cv2.warpAffine(rgb.astype(np.float32) / 255.0, m, (self.crop, self.crop),
                              flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return crop, m

    @torch.no_grad()
    def predict_crops(self, crops: np.ndarray) -> np.ndarray:
        """Hair probabilities of aligned crops.

        Args:
            crops: ``(B, S, S, 3)`` float RGB in [0, 1].

        Returns:
            ``(B, S, S)`` float32 probabilities.
        """
        p = next(self.net.parameters())
        x = torch.as_tensor(np.asarray(crops, np.float32), device=p.device).permute(0, 3, 1, 2)
        return torch.sigmoid(self.net(x.to(p.dtype)))[:, 0].float().cpu().numpy()

    def predict(self, rgb: np.ndarray, landmarks: np.ndarray) -> np.ndarray | None:
        """Probability of hair at every pixel of a photo.

        Args:
            rgb: ``(H, W, 3)`` uint8 RGB photo.
            landmarks: ``(68, 2)`` landmarks in its pixels.

        Returns:
            ``(H, W)`` float32 in [0, 1]; 0 outside the crop. ``None`` when the landmarks
            are degenerate.
        """
        import cv2

        cropped = self.crop_photo(rgb, landmarks)
        if cropped is None:
            return None
        crop, m = cropped
        prob = self.predict_crops(crop[None])[0]
        h, w = rgb.shape[:2]
        return cv2.warpAffine(prob, cv2.invertAffineTransform(m), (w, h),
                              flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                              borderValue=0)


def save_hair_prior(prior: HairPrior, path: str | os.PathLike[str],
                    meta: dict[str, Any] | None = None) -> None:
    """Write a hair prior (network configuration, weights, canonical landmarks, ``meta``)
    atomically to ``path``."""
    from head360cli.io.atomic import atomic_path

    state = {k: v.detach().cpu() for k, v in prior.net.state_dict().items()}
    blob = {"format": FORMAT, "config": dataclasses.asdict(prior.net.cfg),
            "canon": torch.tensor(prior.canon), "state_dict": state, "meta": meta or {}}
    with atomic_path(path) as tmp:
        torch.save(blob, tmp)


def load_hair_prior(path: str | os.PathLike[str], device: str = "cpu") -> HairPrior:
    """Read a hair prior written by :func:`save_hair_prior`, as data only.

    Raises:
        BadInputError: The file is missing.
        FileFormatError: It is not a hair-prior checkpoint: unreadable, truncated, of
            another kind, holding objects that could run code, or with weights that do
            not fit its configuration (exit 5, as for the other model files).
    """
    from head360cli.errors import BadInputError, FileFormatError
    from head360cli.io.torchfile import load_data

    path = Path(path)
    if not path.is_file():
        raise BadInputError(f"hair prior {str(path)!r} does not exist")
    blob = load_data(path, f"a {FORMAT} checkpoint")
    if not isinstance(blob, dict) or blob.get("format") != FORMAT:
        found = blob.get("format") if isinstance(blob, dict) else type(blob).__name__
        raise FileFormatError(f"expected a {FORMAT} checkpoint in {str(path)!r}, found "
                              f"{found}")
    try:
        net = HairPriorNet(HairPriorConfig(**blob["config"]))
        net.load_state_dict(blob["state_dict"])
        canon = blob["canon"].numpy()
    except (KeyError, TypeError, RuntimeError, AttributeError) as exc:
        first = " ".join(str(exc).split())[:160]
        raise FileFormatError(f"{str(path)!r}: a {FORMAT} checkpoint whose contents do not "
                              f"fit together ({type(exc).__name__}: {first})") from None
    bad = [name for name, value in net.state_dict().items()
           if value.is_floating_point() and not torch.isfinite(value).all()]
    if bad or not np.isfinite(canon).all():  # a run that diverged: its masks are noise
        raise FileFormatError(f"{str(path)!r}: a {FORMAT} checkpoint with non-finite "
                              f"values ({', '.join(bad[:3]) or 'canon'}): retrain it")
    return HairPrior(net.to(device), canon, blob.get("meta", {}))


@functools.lru_cache(maxsize=1)
def default_hair_prior() -> HairPrior | None:
    """The shipped hair prior (``models/hair_prior.pt``), or ``None`` when it is not
    installed."""
    from head360cli.paths import models_dir

    path = models_dir() / FILE_NAME
    return load_hair_prior(path) if path.is_file() else None

"""Closed eyelids: a change of the neural texture that the blinks bring in.

The generator saw few closed eyes in training (a blink above 0.8 in about 0.6 % of its
views), and a texture fitted to a photo of open eyes draws a closed lid as a dark smudge,
which dlib reads as an eye about as open as the open one. This stage fits a *lid change*
of the texture, on the texels of the triangles a blink moves, so that with both eyes
closed the front view shows, over those triangles, the colour of the skin around the eye
with a dark lash line along the lid's lower edge. A renderer adds the change as the
eyes close: ``texture + a_left * left part + a_right * right part``, each amount ``a``
rising with the eye's blink until it is all in at a blink of 0.6
(:func:`~head360cli.io.headfile.lid_amounts`,
:class:`~head360cli.model.head_render.HeadRenderer`), the way wrinkle maps follow
blendshape weights in games. Open eyes (and the photo's view) render exactly as before,
so the change only has to be right for closed eyes; a change fitted into the texture
itself, held to the open eyes and the photo at the same time, closed the eyes less and
cost the astronaut's input view 0.4 dB.

Only one view is rendered, a window of :attr:`LidConfig.crop` pixels around the eyes, and
the planes are made once (each step adds the change where they read the lid texels,
:func:`~head360cli.model.planes.add_texture_change`): about 1 s on 2 CPU cores.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import torch

from head360cli.mesh.eyelids import blink_weights, grow_mask, lid_texels

__all__ = ["LidConfig", "LidResult", "close_lids", "closed_lid_target", "head_lids"]


@dataclasses.dataclass(frozen=True)
class LidConfig:
    """Settings of :func:`close_lids`."""

    steps: int = 12
    """Adam steps."""
    lr: float = 0.3
    """Adam learning rate of the change."""
    stride: int = 3
    """The change is fitted on a grid this many texels apart and upsampled bilinearly
    (as the inversion's, :attr:`~head360cli.fitting.texture.InvertConfig.texture_stride`):
    texel by texel, the texels the closed front view does not read move at random and
    show as dark blotches at other expressions and views."""
    crop: int = 96
    """Side in pixels of the rendered window around the eyes, at the generator's own
    scale (a multiple of ``image_res / render_res``; a blink's triangles span about 76
    x 18 pixels of a frontal 256-pixel view)."""
    samples: int = 4
    """Samples per ray while fitting; the samples are jittered, so the change does not
    fit one set of sample positions (fitted at fixed positions it showed as speckles in
    frames rendered with another number of samples)."""
    shade: float = 0.7
    """Brightness of the closed lid as a fraction of the skin's colour. With the skin's
    own colour, dlib's face detector missed the fitted astronaut's face in the 10 most
    closed of the bundled stream's 240 frames (lids as bright as the cheeks: no eyes to
    find); at 0.7 it found all 32 frames around the two blinks, and its eye opening
    followed eyeBlink there at r = -0.90 (-0.85 at 1.0 over the 22 it found); sampled
    heads 0 and 1: -0.85 and -0.69 (-0.79, -0.66 at 1.0)."""
    lash: float = 0.1
    """Brightness of the lash line as a fraction of the skin's colour. The dark line is
    what dlib reads as a closed lid: on eight development heads (fast-preset
    fits of AFLW2000-3D 01322, 02283, 02545, 03614, VOC 2008_001322, 2008_002506,
    2009_004587 and bald_guys; front view, blink ramps of 21 frames, dlib's eye opening
    against the blink, both eyes) the mean correlation over blinks 0 to 0.6 was -0.81 /
    -0.83 at 0.25, -0.86 / -0.84 at 0.1, -0.87 / -0.84 at 0, and fell to
    -0.60 / -0.58 at 0.5; over 0 to 1 it was -0.90 / -0.91 at 0.25 and -0.91 / -0.90 at
    0.1. A thinner line (2 pixels) lost as much as a lighter one (-0.60 / -0.56), a 4-pixel
    one gained nothing (-0.81 / -0.81)."""
    lash_width: int = 3
    """Height in pixels of the lash line at the lid's lower edge."""
    seed: int = 0
    """Seed of the jittered samples (the caller's random state is left as it was), so a
    head gets the same change every time."""
    ring: tuple[int, int] = (2, 5)
    """The skin colour is the median of the open render over pixels this many pixels
    (from, to) outside the closed lid, and not on the open lid's triangles."""

    def __post_init__(self) -> None:
        if self.steps < 0:
            raise ValueError(f"expected steps >= 0, found {self.steps}")
        if self.stride < 1:
            raise ValueError(f"expected stride >= 1, found {self.stride}")
        if not 0 <= self.lash <= 1:
            raise ValueError(f"expected a lash brightness in [0, 1], found {self.lash}")
        if not 0 < self.shade <= 1:
            raise ValueError(f"expected a lid shade in (0, 1], found {self.shade}")
        if not 0 <= self.ring[0] < self.ring[1]:
            raise ValueError(f"expected a ring (inner, outer) with 0 <= inner < outer, "
                             f"found {self.ring}")


@dataclasses.dataclass
class LidResult:
    """Result of :func:`close_lids`.

    Attributes:
        change: ``(C, R, R)`` the texture's change with both eyes closed (zero outside
            the lid texels).
        loss_first: L1 of the closed view's eye window before the first step.
        loss_last: The same at the last step.
        texels: Texels allowed to change.
        seconds: Wall time.
    """

    change: torch.Tensor
    loss_first: float
    loss_last: float
    texels: int
    seconds: float


def closed_lid_target(open_rgb: np.ndarray, closed_rgb: np.ndarray, open_lid: np.ndarray,
                      closed_lid: np.ndarray, cfg: LidConfig = LidConfig()) -> np.ndarray:
    """What the closed eyes should look like.

    Args:
        open_rgb: ``(3, H, W)`` render of the open eyes.
        closed_rgb: ``(3, H, W)`` render of the closed eyes (kept outside the lids).
        open_lid: ``(H, W)`` bool, pixels of the blink's triangles with the eyes open.
        closed_lid: ``(H, W)`` bool, the same with the eyes closed.
        cfg: Lash line and skin ring.

    Returns:
        ``(3, H, W)``: each closed lid (a connected region of ``closed_lid``) filled with
        ``cfg.shade`` times the median colour of the open render in a ring around it, and
        a lash line of ``cfg.lash`` times that colour along its lower edge.
    """
    import cv2

    target = closed_rgb.copy()
    # the lids as regions joined along rows and columns (scipy.ndimage.label's default)
    count, labels = cv2.connectedComponents(closed_lid.astype(np.uint8), connectivity=4)
    count -= 1  # label 0 is the background
    for j in range(1, count + 1):
        lid = labels == j
        if lid.sum() < 20:  # a sliver at the window's edge
            continue
        ring = grow_mask(lid, cfg.ring[1]) & ~grow_mask(lid, cfg.ring[0]) & ~open_lid
        if not ring.any():
            continue
        skin = np.median(open_rgb[:, ring], axis=1)
        target[:, lid] = (cfg.shade * skin)[:, None]
        # lid pixels with a pixel of no lid within lash_width below them
        below = np.zeros_like(lid)
        for dy in range(1, cfg.lash_width + 1):
            below[:-dy] |= ~lid[dy:]
        target[:, lid & below] = (cfg.lash * skin)[:, None]
    return target


def close_lids(gen, neutral: torch.Tensor, blink: torch.Tensor, texture: torch.Tensor,
               faces: np.ndarray, texels: np.ndarray, cfg: LidConfig = LidConfig()
               ) -> LidResult:
    """Fit the texture change that closes the eyes' lids.

    Args:
        gen: The :class:`~head360cli.model.generator.Generator` (frozen here).
        neutral: ``(V, 3)`` the head's mesh with its eyes open (no expression).
        blink: ``(V, 3)`` the same mesh with both eyes closed.
        texture: ``(C, R, R)`` neural texture.
        faces: ``(F, 3)`` the mesh's triangles.
        texels: ``(R, R)`` bool, the texels that may change (:func:`lid_texels`).
        cfg: Steps and target.

    Returns:
        The change; zero if the front view shows no lid.
    """
    from head360cli.fitting.adam import Adam
    from head360cli.fitting.texture import _deterministic
    from head360cli.geometry.cameras import (
        RIG_DISTANCE,
        RIG_FOV_DEG,
        camera_on_sphere,
        intrinsics_from_fov,
        project,
    )
    from head360cli.geometry.rasterize import rasterize
    from head360cli.model.planes import add_texture_change, reading_pixels

    t0 = time.perf_counter()
    dev, dt = texture.device, texture.dtype
    res, s = gen.cfg.image_res, cfg.crop
    moved = (blink - neutral).norm(dim=-1) > 0
    verts = torch.stack([neutral, blink])  # open (for the skin colour), closed
    cams = camera_on_sphere(torch.zeros(2), torch.zeros(2), RIG_DISTANCE).to(dev, dt)
    k = intrinsics_from_fov(RIG_FOV_DEG, res, res, dtype=dt, device=dev)
    if moved.any():  # a window of s x s pixels centred on the eyes
        centre, _ = project(neutral[moved][None], cams[:1], k)
        k = k.clone()
        k[:2, 2] -= centre[0].mean(0) - s / 2
    pix, depth = project(verts, cams, k)
    frags = rasterize(pix, depth, torch.as_tensor(faces, device=dev), s, s)
    fid = frags.face_id.cpu().numpy()
    lid_faces = moved.cpu().numpy()[faces].any(1)
    lid_pix = (fid >= 0) & lid_faces[np.clip(fid, 0, None)]
    zero = torch.zeros_like(texture)
    if cfg.steps == 0 or not lid_pix[1].any() or not texels.any():
        return LidResult(zero, 0.0, 0.0, int(texels.sum()), time.perf_counter() - t0)
    keep = torch.as_tensor(texels, device=dev)
    gen.requires_grad_(False)
    deferred = gen.kind == "deferred"
    rays: dict = {}  # the deferred generator's G-buffer of the closed item, made once
    with torch.no_grad(), gen.image_size(s), gen.samples_per_ray(cfg.samples):
        if deferred:  # each pixel reads its own texels: the change is added to them
            before = gen(verts, cams, k, texture=texture[None].expand(2, -1, -1, -1))["rgb"]
        else:
            # the mesh stays put and only the lid texels change: the planes are made
            # once, and each step adds the change where they read those texels
            raster = gen.plane_raster(verts)
            planes = gen.planes(verts, texture[None].expand(2, -1, -1, -1), raster)
            before = gen(verts, cams, k, head_planes=planes)["rgb"]
            # the closed item's raster (its gathered reads, made for both, dropped)
            raster = dataclasses.replace(raster, grid=raster.grid[1:],
                                         mask=raster.mask[1:], surface=raster.surface[1:],
                                         reads=None)
            planes = planes[1:]
            at = reading_pixels(raster, keep)
    rgb = before.float().cpu().numpy()
    target = closed_lid_target(rgb[0], rgb[1], lid_pix[0], lid_pix[1], cfg)
    window = grow_mask(lid_pix[0] | lid_pix[1], 8)
    target = torch.as_tensor(target, device=dev, dtype=dt)[None]
    weight = torch.as_tensor(window, device=dev, dtype=dt)[None, None]
    area = 3 * weight.sum()
    keep = keep.to(dt)[None, None]
    side = texture.shape[-1]
    coarse = -(-side // cfg.stride)
    change = torch.zeros(1, texture.shape[0], coarse, coarse, device=dev, dtype=dt,
                         requires_grad=True)

    def lid_change() -> torch.Tensor:
        up = change if cfg.stride == 1 else torch.nn.functional.interpolate(
            change, size=(side, side), mode="bilinear", align_corners=False)
        return up * keep

    # the deferred generator reads each lid texel where it is seen: the texture steps'
    # rate scale (fitting.texture.DEFERRED_RATES) keeps Adam from overshooting there too
    from head360cli.fitting.texture import DEFERRED_RATES

    opt = Adam([change], lr=cfg.lr * (DEFERRED_RATES[0] if deferred else 1.0))
    losses = []
    with gen.image_size(s), gen.samples_per_ray(cfg.samples), _deterministic(), \
            torch.random.fork_rng(devices=[dev] if dev.type == "cuda" else []):
        torch.manual_seed(cfg.seed)
        for _ in range(cfg.steps):
            if deferred:
                out = gen(verts[1:], cams[1:], k, texture=texture[None] + lid_change(),
                          view_rays=rays)
            else:
                out = gen(verts[1:], cams[1:], k, jitter=True,
                          head_planes=add_texture_change(planes, lid_change(), raster, at))
            loss = ((out["rgb"] - target).abs() * weight).sum() / area
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(float(loss.detach()))
    with torch.no_grad():
        fitted = lid_change()[0]
    return LidResult(fitted, losses[0], losses[-1], int(texels.sum()),
                     time.perf_counter() - t0)


def head_lids(gen, model, shape: np.ndarray, texture: torch.Tensor,
              cfg: LidConfig = LidConfig()) -> LidResult:
    """:func:`close_lids` for the head of identity ``shape`` of the bilinear ``model``
    wearing ``texture (C, R, R)``: its open and closed meshes and lid texels made here."""
    neutral = model.vertices(shape, np.zeros(52))
    shut = model.vertices(shape, blink_weights())
    texels = lid_texels(model.faces, model.uv, model.faces_uv,
                        np.any(shut != neutral, axis=1), texture.shape[-1])
    dev = texture.device
    return close_lids(gen, torch.tensor(neutral, dtype=torch.float32, device=dev),
                      torch.tensor(shut, dtype=torch.float32, device=dev), texture,
                      model.faces, texels, cfg)

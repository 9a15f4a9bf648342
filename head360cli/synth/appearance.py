"""Appearance of the synthetic heads: a texture atlas painted from 3D positions.

The mesh is rasterized in UV space so that every texel knows its 3D position and part;
skin tone, lips, eyebrows, stubble, age folds, irises, teeth, tongue and the mouth's
interior are then painted as functions of that position and the identity's feature frame.
Skin tones span a light-to-deep range (a simple two-pigment mix).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from head360cli.geometry.rasterize import interpolate_face_corners, rasterize
from head360cli.synth.fields import smoothstep
from head360cli.synth.identity import IdentityParams
from head360cli.synth.sculpt import HeadFrame, Topology

__all__ = ["Appearance", "paint_texture", "sample_appearance", "texel_positions"]

_IRIS = {
    "brown": (0.32, 0.18, 0.08), "dark brown": (0.18, 0.10, 0.05), "hazel": (0.42, 0.32, 0.14),
    "green": (0.28, 0.40, 0.22), "blue": (0.28, 0.44, 0.62), "grey": (0.45, 0.50, 0.52),
}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class Appearance:
    """Colours and marks of one identity."""

    skin_tone: float
    """0 lightest to 1 deepest skin."""
    redness: float
    """Warmth of the skin (haemoglobin), about 0 to 1."""
    iris: tuple[float, float, float]
    """Iris colour (linear-ish RGB in [0, 1])."""
    brow_colour: tuple[float, float, float]
    """Eyebrow (and stubble) colour."""
    stubble: float
    """0 none to 1 a dark short beard."""
    age: float
    """Years: folds and wrinkles deepen with it."""
    lip_tint: float
    """0 skin-coloured to 1 strongly red lips."""
    seed: int
    """Seed of the fine noise."""


def sample_appearance(seed: int, identity: IdentityParams) -> Appearance:
    """Draw an appearance for an identity (same seed, same appearance)."""
    rng = np.random.default_rng([seed, 0xA99])
    tone = float(rng.beta(1.3, 1.6))
    if tone > 0.55:
        iris = _IRIS["dark brown"] if rng.random() < 0.8 else _IRIS["brown"]
    else:
        iris = list(_IRIS.values())[int(rng.integers(0, len(_IRIS)))]
    hair_dark = float(np.clip(0.15 + 0.6 * tone + rng.normal(0, 0.15), 0, 1))
    brow = tuple(float(c) for c in np.array([0.36, 0.25, 0.16]) * (1 - 0.8 * hair_dark) + 0.02)
    stubble = float(rng.uniform(0.2, 1.0)) if identity.sex > 0.5 and rng.random() < 0.5 else 0.0
    return Appearance(
        skin_tone=tone,
        redness=float(rng.uniform(0.2, 0.8)),
        iris=tuple(float(c) for c in iris),
        brow_colour=brow,
        stubble=stubble,
        age=identity.age,
        lip_tint=float(rng.uniform(0.3, 1.0)) * (1.0 if identity.sex < 0.5 else 0.6),
        seed=int(rng.integers(0, 2**31)),
    )


def texel_positions(verts: np.ndarray, topo: Topology, size: int
                    ) -> tuple[np.ndarray, np.ndarray]:
    """3D position and part of every texel of a ``size x size`` atlas.

    Returns:
        ``(positions (size, size, 3), part (size, size) int: -1 where no triangle)``.
    """
    uv = torch.tensor(topo.uv, dtype=torch.float64) * size
    faces_uv = torch.tensor(topo.faces_uv)
    frags = rasterize(uv[None], torch.ones(1, len(uv), dtype=torch.float64), faces_uv,
                      size, size, perspective_correct=False)
    corners = torch.tensor(verts, dtype=torch.float64)[torch.tensor(topo.faces)]
    pos = interpolate_face_corners(corners, frags)[0].numpy()
    fid = frags.face_id[0].numpy()
    part = np.where(fid >= 0, topo.face_parts[np.clip(fid, 0, None)], -1)
    return pos, part


def _noise(rng: np.random.Generator, size: int, scale: int) -> np.ndarray:
    """Smooth value noise in [-1, 1] at roughly ``scale`` texels per feature."""
    import cv2

    coarse = rng.uniform(-1, 1, (max(2, size // scale), max(2, size // scale)))
    return cv2.resize(coarse, (size, size), interpolation=cv2.INTER_CUBIC)


def paint_texture(verts: np.ndarray, topo: Topology, frame: HeadFrame,
                  identity: IdentityParams, look: Appearance, size: int = 512,
                  scan: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """The albedo atlas of one identity.

    Args:
        scan: ``(fine, mid)`` layers of a scanned skin on this atlas
            (:func:`head360cli.synth.skin.skin_layers`): the skin takes their detail and
            the face their slower colour changes, on the identity's own tone; ``None``
            paints noise instead.

    Returns:
        ``(size, size, 3)`` float32 in [0, 1].
    """
    pos, part = texel_positions(verts, topo, size)
    names = topo.part_names
    x, y, z = pos[..., 0], pos[..., 1], pos[..., 2]
    lv = frame.levels
    rng = np.random.default_rng([look.seed, 7])
    fine = _noise(rng, size, 4)
    blotch = _noise(rng, size, 24)

    light = np.array([0.94, 0.78, 0.68])
    deep = np.array([0.30, 0.18, 0.12])
    base = light * (1 - look.skin_tone) + deep * look.skin_tone
    red = np.array([0.06, -0.03, -0.02]) * look.redness
    skin = np.broadcast_to(base + red, pos.shape).copy()
    noise = 1.0 if scan is None else 0.3  # a scan brings its own detail
    skin *= (1 + noise * (0.035 * fine + 0.05 * blotch))[..., None]
    front = smoothstep(0.02, 0.06, z)

    # Cheeks and nose a little warmer; the ear's inside darker.
    for sgn in (1, -1):
        cheek = np.exp(-0.5 * (((x - sgn * 0.045) / 0.018) ** 2
                               + ((y - lv["nose_base"]) / 0.015) ** 2)) * front
        skin += cheek[..., None] * np.array([0.05, -0.01, -0.01]) * look.redness
    # Lips.
    mw = frame.mouth_half_width
    lip_x = smoothstep(1.0, 0.85, np.abs(x) / mw)
    lip_y = (smoothstep(lv["lip_bottom"] - 0.002, lv["lip_bottom"] + 0.0015, y)
             * smoothstep(lv["lip_top"] + 0.0015, lv["lip_top"] - 0.0015, y))
    lips = lip_x * lip_y * front
    lip_colour = base * np.array([0.86, 0.62, 0.62]) + np.array([0.10, 0.0, 0.02]) * look.lip_tint
    skin = skin * (1 - lips[..., None]) + lip_colour * lips[..., None]
    # Age: forehead lines, crow's feet and nasolabial folds darken with the years.
    age = np.clip((look.age - 25.0) / 45.0, 0, 1)
    if age > 0:
        lines = 0.5 + 0.5 * np.cos((y - lv["brow"]) / 0.0045 * np.pi * 2)
        forehead = smoothstep(lv["brow"] + 0.008, lv["brow"] + 0.014, y) * smoothstep(
            lv["forehead"] + 0.02, lv["forehead"], y) * smoothstep(0.05, 0.03, np.abs(x))
        fold = np.zeros_like(x)
        for sgn in (1, -1):
            # A line from beside the nose to beside the mouth corner.
            t = np.clip((lv["nose_base"] + 0.005 - y) / (lv["nose_base"] - lv["seam"] + 0.01),
                        0, 1)
            line_x = sgn * (0.020 + t * (mw + 0.004 - 0.020))
            fold += np.exp(-0.5 * ((x - line_x) / 0.0022) ** 2) * (t > 0) * (t < 1)
            crow = np.exp(-0.5 * (((x - sgn * (frame.eye_half_width + abs(
                frame.eye_centres[0, 0]) + 0.006)) / 0.004) ** 2
                + ((y - lv["eye"]) / 0.006) ** 2))
            fold += 0.6 * crow * (0.5 + 0.5 * np.cos((y - lv["eye"]) / 0.002 * np.pi))
        wrinkle = age * (0.07 * lines * forehead + 0.12 * fold) * front
        skin *= (1 - wrinkle)[..., None]
    if scan is not None:
        scan_fine, scan_mid = scan
        # The scan's slower colour changes on the face's front, but not where the
        # painted lips, brows and eyes go (the scan's own sit a little elsewhere on this head).
        brow_zone = smoothstep(0.012, 0.004, np.abs(y - lv["brow"] - 0.004))
        eye_zone = np.zeros_like(x)
        for c in frame.eye_centres:
            eye_zone = np.maximum(eye_zone, smoothstep(0.026, 0.016, np.hypot(
                x - c[0], (y - c[1]) * 1.4)))
        keep_mid = front * (1 - lips) * (1 - brow_zone) * (1 - eye_zone)
        skin *= 1 + (scan_mid - 1) * keep_mid[..., None]
        # The scan's stubble shows in its detail: shaved heads keep a third of it.
        beard = (smoothstep(lv["nose_base"] - 0.004, lv["nose_base"] - 0.012, y)
                 * smoothstep(lv["throat"] - 0.01, lv["menton"], y) * (1 - lips))
        keep = 1 - beard * (1 - max(look.stubble, 0.35))
        skin *= 1 + (scan_fine - 1) * keep[..., None]
    # Eyebrows: an arched band of short hairs above each eye.
    brow = np.zeros_like(x)
    for c in frame.eye_centres:
        dx = (x - c[0]) * np.sign(c[0])  # > 0 towards the temple
        u = (dx + 0.022) / 0.046  # 0 at the inner end, 1 at the outer end
        centre_y = lv["brow"] + 0.003 + 0.006 * np.sin(np.clip(u, 0, 1) * np.pi * 0.8)
        half = (0.0032 + 0.0012 * identity.sex) * (1.1 - 0.5 * u)
        band = smoothstep(half, half * 0.4, np.abs(y - centre_y)) * smoothstep(-0.05, 0.05, u) \
            * smoothstep(1.05, 0.9, u)
        brow = np.maximum(brow, band)
    hairs = np.clip(0.6 + 0.8 * _noise(rng, size, 2), 0, 1)
    brow = brow * hairs * front
    browc = np.array(look.brow_colour)
    skin = skin * (1 - 0.9 * brow[..., None]) + browc * 0.9 * brow[..., None]
    # Stubble: a shadow over jaw, chin and upper lip (not on the lips or the neck's back).
    if look.stubble > 0:
        area = (smoothstep(lv["nose_base"] - 0.004, lv["nose_base"] - 0.010, y)
                * smoothstep(lv["throat"] - 0.01, lv["menton"], y) * (1 - lips)
                * smoothstep(-0.03, 0.0, z))
        cheeks = smoothstep(lv["eye_bottom"] - 0.012, lv["nose_base"], y) * smoothstep(
            0.035, 0.055, np.abs(x)) * smoothstep(-0.01, 0.02, z) * smoothstep(
            lv["eye_bottom"] - 0.03, lv["nose_base"] - 0.02, y)
        area = np.clip(area + cheeks, 0, 1)
        dots = np.clip(0.5 + _noise(rng, size, 1), 0, 1)
        s = look.stubble * area * (0.55 + 0.45 * dots)
        skin = skin * (1 - 0.55 * s[..., None]) + browc * 0.55 * s[..., None]

    out = np.ones(pos.shape, dtype=np.float64) * 0.5
    skin_like = np.isin(part, [names.index("skin"), names.index("ear_l"), names.index("ear_r")])
    out[skin_like] = skin[skin_like]
    # Mouth interior: the pocket rows; darker further in.
    skin_part = part == names.index("skin")
    seam_z = np.interp(x, [-mw, 0, mw], [0.07, 0.095, 0.07])
    inner = skin_part & (z < seam_z - 0.004) & (np.abs(y - lv["seam"]) < 0.016) & (
        np.abs(x) < mw) & (z > 0.0)
    depth_in = np.clip((seam_z - z) / 0.05, 0, 1)
    mouth = np.array([0.55, 0.18, 0.18]) * (1 - 0.7 * depth_in[..., None])
    out[inner] = mouth[inner]
    # Ears: slightly redder and darker inside the cup.
    for name in ("ear_l", "ear_r"):
        m = part == names.index(name)
        out[m] *= np.array([1.0, 0.93, 0.92])
    # Eyes: sclera, limbus, iris with radial streaks, pupil, by angle from the gaze axis.
    for name, c in (("eye_l", frame.eye_centres[0]), ("eye_r", frame.eye_centres[1])):
        m = part == names.index(name)
        d = pos[m] - c
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        ang = np.degrees(np.arccos(np.clip(d[:, 2], -1, 1)))
        spokes = 0.85 + 0.15 * np.cos(np.arctan2(d[:, 1], d[:, 0]) * 24)
        col = np.tile(np.array([0.92, 0.90, 0.87]), (len(d), 1))
        col *= (1 - 0.15 * smoothstep(50, 90, ang))[:, None]  # shadowed towards the back
        iris = np.array(look.iris) * spokes[:, None]
        in_iris = smoothstep(31.0, 27.0, ang)[:, None]
        col = col * (1 - in_iris) + iris * in_iris
        limbus = np.exp(-0.5 * ((ang - 29.0) / 1.6) ** 2)[:, None]
        col *= 1 - 0.5 * limbus
        pupil = smoothstep(12.0, 10.0, ang)[:, None]
        col = col * (1 - pupil) + 0.02 * pupil
        out[m] = col
    out[part == names.index("teeth_upper")] = (0.93, 0.91, 0.84)
    out[part == names.index("teeth_lower")] = (0.90, 0.88, 0.80)
    tongue = part == names.index("tongue")
    out[tongue] = np.array([0.78, 0.38, 0.38]) * (1 + 0.05 * fine[tongue])[:, None]
    # Pad the atlas: copy each empty texel from its nearest painted one, so that bilinear
    # lookups at chart borders never pick up the grey.
    import cv2

    empty = (part < 0).astype(np.uint8)
    if empty.any():
        _, labels = cv2.distanceTransformWithLabels(empty, cv2.DIST_L2, 3,
                                                    labelType=cv2.DIST_LABEL_PIXEL)
        filled = np.argwhere(empty == 0)
        order = np.zeros(labels.max() + 1, dtype=np.int64)
        order[labels[empty == 0]] = np.arange(len(filled))
        src = filled[order[labels]]
        out = out[src[..., 0], src[..., 1]]
    return np.clip(out, 0, 1).astype(np.float32)

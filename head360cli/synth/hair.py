"""30 hairstyles as closed meshes that fit any identity's scalp, and hair colours.

A style is a declarative :class:`HairStyle`: where the hairline runs (at the front, the
sides and the back), how thick the hair is, how long it falls, and its surface (waves,
curls, locks, spikes), plus optional extra pieces (bun, ponytail, braid, tails, top knot).

Geometry: the style is built over the identity's own skin grid (the same columns, the
rows from the crown down, continued below the neck for long hair). Each covered grid cell
becomes a cell of a closed shell: an inner surface 1.5 mm outside the skin and an outer
surface at the hair's thickness, joined by walls along the hairline. Below the widest part
of the head, hair falls as a vertical curtain instead of following the neck inwards. So the
hair never enters the head, and any style fits any identity.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from head360cli.synth.sculpt import HeadFrame, _column_angles, topology

__all__ = [
    "FIGARO_CLASSES",
    "HAIRSTYLES",
    "HAIR_COLOURS",
    "LONG_EXTRAS",
    "MAX_END_SHIFT",
    "WARP_BINS",
    "HairMesh",
    "HairStyle",
    "build_hair",
    "figaro_class",
    "fit_hair",
    "fit_hairs",
    "hair_length",
    "head_normals",
    "nearest_head_vertices",
    "style_index",
    "warp_centre",
    "warp_hair",
]

INNER_GAP = 0.0015
"""Distance between the scalp and the hair shell's inner surface, metres."""

HAIR_COLOURS: dict[str, tuple[float, float, float]] = {
    "black": (0.035, 0.030, 0.028),
    "dark brown": (0.12, 0.075, 0.045),
    "brown": (0.24, 0.15, 0.085),
    "light brown": (0.40, 0.27, 0.16),
    "auburn": (0.36, 0.13, 0.06),
    "red": (0.55, 0.20, 0.07),
    "blonde": (0.70, 0.55, 0.32),
    "platinum": (0.86, 0.82, 0.72),
    "grey": (0.50, 0.49, 0.47),
    "white": (0.85, 0.85, 0.83),
}
"""Named hair colours (albedo)."""


@dataclasses.dataclass(frozen=True)
class HairStyle:
    """One hairstyle. Heights are relative to the identity's feature levels."""

    name: str
    """Style name (unique)."""
    front: float = 0.012
    """Front hairline: metres above the forehead level (negative: bangs reach lower)."""
    side: str = "ear_top"
    """Lowest point at the sides: a level name (``ear_top``, ``eye``, ``menton`` ...) or
    ``"length"`` to use :attr:`length`."""
    back: str = "nape"
    """Lowest point at the back: a level name or ``"length"``."""
    length: float = 0.0
    """For ``"length"``: how far below the chin (metres) the hair ends."""
    top: float = 0.012
    """Thickness on top of the head."""
    sides: float = 0.008
    """Thickness over the sides."""
    rear: float = 0.010
    """Thickness at the back."""
    front_volume: float = 0.0
    """Extra thickness over the front of the top (pompadour, quiff)."""
    strip: float = 0.0
    """If > 0, only a front-to-back strip this many radians wide is covered (mohawk)."""
    part: float | None = None
    """Azimuth (radians) of a parting line on top, or ``None``."""
    sweep: float = 0.0
    """Fringe swept to the subject's left (+) or right (-): lowers the hairline there."""
    waves: float = 0.0
    """Amplitude of waves along the length (metres)."""
    curls: float = 0.0
    """Amplitude of curls all over (metres)."""
    locks: float = 0.0
    """Amplitude of vertical locks (dreadlocks, braids) around the head (metres)."""
    recede: float = 0.0
    """Receding temples: how far back (metres) the hairline goes at the temples."""
    extras: tuple[str, ...] = ()
    """Extra pieces: ``bun``, ``top_knot``, ``ponytail_high``, ``ponytail_low``,
    ``braid``, ``twin_tails``."""
    end_shift: float = 0.0
    """Metres the hair's ends at the sides and the back are moved down (negative: up): a
    fit's length for one person, 0 in every style of the catalogue, at most
    :data:`MAX_END_SHIFT` either way."""


HAIRSTYLES: tuple[HairStyle, ...] = (
    HairStyle("bald", top=0.0, sides=0.0, rear=0.0),
    HairStyle("buzz", front=0.008, top=0.003, sides=0.0025, rear=0.003),
    HairStyle("crew", front=0.008, top=0.010, sides=0.004, rear=0.005),
    HairStyle("side part", front=0.006, top=0.016, sides=0.007, rear=0.010, part=0.45,
              sweep=-0.006),
    HairStyle("slicked back", front=0.010, top=0.009, sides=0.006, rear=0.010),
    HairStyle("pompadour", front=0.006, top=0.022, sides=0.006, rear=0.010,
              front_volume=0.035),
    HairStyle("undercut", front=0.006, side="eye_top", top=0.022, sides=0.002, rear=0.003,
              front_volume=0.012),
    HairStyle("mohawk", front=0.0, top=0.040, sides=0.0, rear=0.020, strip=0.28, back="nape"),
    HairStyle("curly short", front=0.004, top=0.026, sides=0.018, rear=0.020, curls=0.005),
    HairStyle("afro", front=0.0, side="ear_bottom", top=0.060, sides=0.050, rear=0.055,
              curls=0.006),
    HairStyle("pixie", front=-0.012, top=0.015, sides=0.007, rear=0.008, sweep=0.010),
    HairStyle("bob", front=0.002, side="length", back="length", length=-0.012, top=0.014,
              sides=0.014, rear=0.016),
    HairStyle("lob", front=0.004, side="length", back="length", length=0.035, top=0.013,
              sides=0.013, rear=0.015),
    HairStyle("bangs", front=-0.028, side="length", back="length", length=0.06, top=0.013,
              sides=0.013, rear=0.015),
    HairStyle("shoulder straight", front=0.006, side="length", back="length", length=0.10,
              top=0.012, sides=0.012, rear=0.014, part=0.0),
    HairStyle("shoulder wavy", front=0.006, side="length", back="length", length=0.10,
              top=0.015, sides=0.016, rear=0.018, waves=0.006, part=0.35),
    HairStyle("long straight", front=0.006, side="length", back="length", length=0.19,
              top=0.012, sides=0.012, rear=0.015, part=0.35),
    HairStyle("long wavy", front=0.006, side="length", back="length", length=0.19,
              top=0.016, sides=0.018, rear=0.020, waves=0.008, part=-0.35),
    HairStyle("long curly", front=0.004, side="length", back="length", length=0.17,
              top=0.024, sides=0.028, rear=0.030, curls=0.007, waves=0.004),
    HairStyle("ponytail high", front=0.008, top=0.007, sides=0.005, rear=0.007,
              extras=("ponytail_high",)),
    HairStyle("ponytail low", front=0.008, top=0.007, sides=0.005, rear=0.007,
              extras=("ponytail_low",)),
    HairStyle("bun", front=0.008, top=0.007, sides=0.005, rear=0.007, extras=("bun",)),
    HairStyle("top knot", front=0.010, top=0.008, sides=0.004, rear=0.006,
              extras=("top_knot",)),
    HairStyle("braid", front=0.008, top=0.007, sides=0.005, rear=0.007, part=0.0,
              extras=("braid",)),
    HairStyle("twin tails", front=-0.01, top=0.008, sides=0.006, rear=0.008, part=0.0,
              extras=("twin_tails",)),
    HairStyle("mullet", front=0.004, side="ear_top", back="length", length=0.08, top=0.016,
              sides=0.006, rear=0.016),
    HairStyle("receding", front=0.030, top=0.006, sides=0.005, rear=0.007, recede=0.035),
    HairStyle("middle part long", front=0.008, side="length", back="length", length=0.16,
              top=0.010, sides=0.012, rear=0.014, part=0.0),
    HairStyle("side swept", front=-0.006, top=0.018, sides=0.008, rear=0.010, sweep=0.018,
              part=-0.45),
    HairStyle("dreadlocks", front=0.006, side="length", back="length", length=0.12,
              top=0.022, sides=0.024, rear=0.026, locks=0.007),
)
"""The 30 SynHead-P hairstyles, in their canonical order (the style id is the index)."""

assert len(HAIRSTYLES) == 30 and len({s.name for s in HAIRSTYLES}) == 30


def style_index(name_or_id: str | int) -> int:
    """Style id from a name (case-insensitive) or an id."""
    import re

    from head360cli.errors import BadInputError

    top = len(HAIRSTYLES) - 1
    expected = (f"expected a hairstyle id between 0 and {top} or one of: "
                + ", ".join(s.name for s in HAIRSTYLES))
    if isinstance(name_or_id, int) or re.fullmatch(r"\s*[+-]?\d+\s*", str(name_or_id)):
        k = int(name_or_id)
        if 0 <= k <= top:
            return k
        raise BadInputError(f"{expected}; found {k}")
    key = str(name_or_id).strip().lower().replace("_", " ").replace("-", " ")
    for k, style in enumerate(HAIRSTYLES):
        if style.name == key:
            return k
    raise BadInputError(f"{expected}; found {str(name_or_id)!r}")


FIGARO_CLASSES: dict[str, tuple[str, ...]] = {
    "straight": ("bob", "lob", "bangs", "shoulder straight", "long straight",
                 "ponytail high", "ponytail low", "bun", "top knot", "middle part long"),
    "wavy": ("shoulder wavy", "long wavy"),
    "curly": ("curly short", "long curly"),
    "kinky": ("afro",),
    "braids": ("braid", "twin tails"),
    "dreadlocks": ("dreadlocks",),
    "short-men": ("bald", "buzz", "crew", "side part", "slicked back", "pompadour",
                  "undercut", "mohawk", "pixie", "mullet", "receding", "side swept"),
}
"""Figaro-1k's 7 coarse classes, each as the SynHead-P styles that belong to it (every
style in exactly one class; tied-back long hair counts as straight)."""


def figaro_class(style: int) -> str:
    """The Figaro-1k class of a SynHead-P style id."""
    name = HAIRSTYLES[style].name
    return next(k for k, names in FIGARO_CLASSES.items() if name in names)


LONG_EXTRAS = ("ponytail_high", "ponytail_low", "braid", "twin_tails")
"""Extra pieces that hang below the chin: a style with one of them is long."""


def hair_length(style: int) -> str:
    """``"long"`` where a SynHead-P style's hair hangs below the chin (at the sides or the
    back, or as a tail or braid), else ``"short"`` (a bob that ends above it too)."""
    s = HAIRSTYLES[style]
    hangs = "length" in (s.side, s.back) and s.length > 0.0
    return "long" if hangs or any(e in LONG_EXTRAS for e in s.extras) else "short"


@dataclasses.dataclass
class HairMesh:
    """A hairstyle fitted to one head.

    Attributes:
        verts: ``(V, 3)`` positions.
        faces: ``(F, 3)`` outward-facing triangles (several closed pieces).
        uv: ``(V, 2)`` coordinates for the strand texture (u across, v along the hair).
        shell: How many of the first vertices are the shell over the head (the rest are
            the extra pieces).
    """

    verts: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    shell: int = 0


def _level(name: str, frame: HeadFrame, style: HairStyle) -> float:
    lv = frame.levels
    ear_top = frame.ear_centres[:, 1].mean() + 0.028
    table = {
        "ear_top": ear_top,
        "ear_bottom": frame.ear_centres[:, 1].mean() - 0.03,
        "eye_top": lv["eye_top"] + 0.012,
        "eye": lv["eye"],
        "nape": lv["nose_base"] - 0.012,
        "menton": lv["menton"],
        "length": lv["menton"] - style.length,
    }
    return table[name]


def head_normals(verts: np.ndarray) -> np.ndarray:
    """``(V, 3)`` outward vertex normals of a head of the template's topology (its normal
    groups kept apart), as the hair is grown along them."""
    import torch

    from head360cli.geometry.mesh_ops import vertex_normals

    topo = topology()
    return vertex_normals(torch.tensor(verts)[None], torch.tensor(topo.faces),
                          torch.tensor(topo.normal_groups))[0].numpy()


def _base_grid(verts: np.ndarray, frame: HeadFrame, bottom: float,
               normals: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Skin rows from the crown to the neck (no pocket rows), continued straight down
    below the neck to ``bottom``; and the outward normals of those points (``normals``:
    :func:`head_normals` of ``verts``, when already made)."""
    topo = topology()
    keep = [i for i, n in enumerate(topo.row_names) if not n.startswith(("pocket", "seam_l"))]
    rows = topo.skin_rows[keep]
    if normals is None:
        normals = head_normals(verts)
    pts, nrm = verts[rows], normals[rows]
    last = pts[-1]
    extra = []
    y = last[0, 1] - 0.02
    while y > bottom - 0.02:
        extra.append(np.column_stack([last[:, 0], np.full(len(last), y), last[:, 2]]))
        y -= 0.02
    if extra:
        ext = np.stack(extra)
        pts = np.concatenate([pts, ext])
        horiz = last * np.array([1.0, 0.0, 1.0])
        horiz /= np.linalg.norm(horiz, axis=1, keepdims=True)
        nrm = np.concatenate([nrm, np.repeat(horiz[None], len(ext), axis=0)])
    return pts, nrm


def _coverage_and_thickness(pts: np.ndarray, frame: HeadFrame, style: HairStyle,
                            soft: bool = False
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which grid points the style covers and how thick its hair is there.

    Returns:
        ``(covered (R, C) bool, thick (R, C), pts (R, C, 3))``: with ``soft``, the points
        just outside the hairline (lifted half a row) moved onto it, their hair a quarter
        as thick.
    """
    lv = frame.levels
    phi = np.broadcast_to(_column_angles()[None], pts.shape[:2])
    y = pts[..., 1]
    c = np.cos(phi)
    # Hairline height around the head: front, temples, sides, back.
    front_y = lv["forehead"] + style.front + style.sweep * np.sin(phi) * (c > 0)
    front_y = front_y + style.recede * np.exp(-0.5 * ((np.abs(phi) - 0.55) / 0.18) ** 2)
    side_y = _level(style.side, frame, style) - style.end_shift
    back_y = _level(style.back, frame, style) - style.end_shift
    temple = np.clip((np.abs(phi) - 0.75) / 0.45, 0, 1)  # 0 on the face, 1 at the ears
    behind = np.clip((np.abs(phi) - math.pi / 2) / (math.pi / 2), 0, 1)
    face_line = front_y
    side_line = np.minimum(face_line, side_y)
    line = face_line * (1 - temple) + (side_line * (1 - behind) + back_y * behind) * temple
    covered = y >= line
    if soft:
        # The stepped edge is the last row above the line: on average half a row above
        # it. The soft line is lifted by that half row, so that it covers as much.
        edge = np.zeros_like(covered)
        edge[:-1] = covered[:-1] & ~covered[1:]
        r, j = np.nonzero(edge)
        lift = np.zeros(covered.shape[1])
        lift[j] = 0.5 * (y[r, j] - y[r + 1, j])
        line = line + lift[None]
        covered = y >= line
        # One more row below each column's hairline, its points slid up onto the line
        # (the zero of y - line between the rows): the edge follows the line between
        # grid rows instead of stepping from row to row, and tapers to a thin edge.
        f = y - line
        below = np.zeros_like(covered)
        below[1:] = covered[:-1] & ~covered[1:]
        r, j = np.nonzero(below)
        t = np.clip(f[r - 1, j] / np.maximum(f[r - 1, j] - f[r, j], 1e-9), 0.0, 1.0)
        pts = pts.copy()
        pts[r, j] = pts[r - 1, j] + t[:, None] * (pts[r, j] - pts[r - 1, j])
        covered = covered | below
        # Where the line falls steeply from column to column (temples, sides), a row
        # lower is not enough: a point beside a covered one slides sideways onto the line.
        right, left = np.roll(covered, -1, axis=1), np.roll(covered, 1, axis=1)
        side = ~covered & (right ^ left)
        r, j = np.nonzero(side)
        nb = np.where(right[r, j], (j + 1) % covered.shape[1], j - 1)
        t = np.clip(f[r, nb] / np.maximum(f[r, nb] - f[r, j], 1e-9), 0.0, 1.0)
        pts[r, j] = pts[r, nb] + t[:, None] * (pts[r, j] - pts[r, nb])
        below |= side
        covered = covered | side
        y = pts[..., 1]
    if style.strip > 0:
        # A band across the top: within strip * 8 cm of the midplane.
        covered &= (np.abs(pts[..., 0]) < style.strip * 0.08) & (y >= lv["nose_base"])
    thick = style.top * np.clip((y - lv["eye"]) / 0.06, 0, 1) + style.sides * np.clip(
        1 - (y - lv["eye"]) / 0.06, 0, 1) * (1 - behind) + style.rear * behind * np.clip(
        1 - (y - lv["eye"]) / 0.06, 0, 1)
    thick = thick + style.front_volume * np.clip(c, 0, 1) ** 2 * np.clip(
        (y - lv["forehead"]) / 0.04, 0, 1)
    if style.part is not None:
        thick = thick * (1 - 0.6 * np.exp(-0.5 * ((phi - style.part) / 0.06) ** 2)
                         * (y > lv["forehead"]))
    if soft:
        thick = np.where(below, 0.25 * thick, thick)
    return covered, thick, pts


def _shell(base: np.ndarray, normal: np.ndarray, covered: np.ndarray, thick: np.ndarray,
           style: HairStyle, frame: HeadFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A closed shell over the covered cells of a (R, C) grid that wraps in C."""
    rows, cols = covered.shape
    # Inner and outer surfaces; below the widest part the curtain falls straight down.
    radial = np.linalg.norm(base[..., [0, 2]], axis=-1)
    inner = base + normal * INNER_GAP
    outer = base + normal * (INNER_GAP + np.maximum(thick, 0.0015))[..., None]
    phi = _column_angles()[None]
    y = base[..., 1]
    lv = frame.levels
    rel = np.clip((lv["eye"] - y) / 0.1, 0, None)
    mod = style.waves * np.sin(2 * np.pi * rel * 3.0) * (rel > 0)
    rng = np.random.default_rng(len(style.name))
    if style.curls:
        k1, k2 = rng.uniform(9, 13), rng.uniform(20, 26)
        mod = mod + style.curls * np.sin(phi * k1 + y * 180.0) * np.sin(y * k2 * 10 + phi * 3)
    if style.locks:
        mod = mod + style.locks * np.abs(np.sin(phi * 14.0 + 0.3 * np.sin(y * 60)))
    outer = outer + normal * np.clip(mod, -0.5 * thick, None)[..., None]
    widest = np.maximum.accumulate(radial, axis=0)
    hang = y < lv["eye"]
    for surf, offset in ((inner, INNER_GAP), (outer, INNER_GAP + thick)):
        r = np.linalg.norm(surf[..., [0, 2]], axis=-1)
        floor = widest + offset
        scale = np.where(hang & (r < floor), floor / np.maximum(r, 1e-9), 1.0)
        surf[..., 0] *= scale
        surf[..., 2] *= scale
    idx = np.arange(rows * cols).reshape(rows, cols)
    n = rows * cols
    cell = covered[:-1] & covered[1:] & covered[:-1, np.r_[1:cols, 0]] & covered[
        1:, np.r_[1:cols, 0]]
    faces = []
    r_, c_ = np.nonzero(cell)
    a = idx[r_, c_]
    b = idx[r_, (c_ + 1) % cols]
    cc = idx[r_ + 1, c_]
    d = idx[r_ + 1, (c_ + 1) % cols]
    faces += [np.stack([a, cc, b], 1), np.stack([b, cc, d], 1)]  # outer (outward)
    faces += [np.stack([n + a, n + b, n + cc], 1), np.stack([n + b, n + d, n + cc], 1)]
    # Walls along the boundary: every cell edge with a covered cell on one side only.
    padded = np.zeros((rows + 1, cols), dtype=bool)
    padded[1:rows] = cell
    # Horizontal edges (between row r and r+1 of cells): edge row k joins grid row k.
    for k in range(rows):
        above = padded[k]  # cell rows k-1
        below = padded[k + 1] if k + 1 <= rows - 1 else np.zeros(cols, dtype=bool)
        # The outer face above a bottom edge runs p -> q along it, so that wall must run
        # q -> p; the face below a top edge runs q -> p, so that wall runs p -> q.
        for cols_on, flip in ((above & ~below, True), (below & ~above, False)):
            j = np.nonzero(cols_on)[0]
            p, q = idx[k, j], idx[k, (j + 1) % cols]
            quad = [np.stack([p, q, n + q], 1), np.stack([p, n + q, n + p], 1)]
            if flip:
                quad = [f[:, ::-1] for f in quad]
            faces += quad
    # Vertical edges (between columns j-1 and j).
    left_cell = np.roll(cell, 1, axis=1)
    for cols_on, flip in ((cell & ~left_cell, False), (left_cell & ~cell, True)):
        r, j = np.nonzero(cols_on)
        p, q = idx[r, j], idx[r + 1, j]
        quad = [np.stack([p, q, n + q], 1), np.stack([p, n + q, n + p], 1)]
        if not flip:
            quad = [f[:, ::-1] for f in quad]
        faces += quad
    verts = np.concatenate([outer.reshape(-1, 3), inner.reshape(-1, 3)])
    f = np.concatenate(faces) if faces else np.zeros((0, 3), dtype=np.int64)
    u = np.broadcast_to(np.arange(cols)[None] / cols, (rows, cols))
    v = np.broadcast_to(np.arange(rows)[:, None] / max(rows - 1, 1), (rows, cols))
    uv = np.stack([u, v], -1).reshape(-1, 2)
    return verts, f.astype(np.int64), np.concatenate([uv, uv])


def _tube(path: np.ndarray, radii: np.ndarray, ring: int = 10, bumps: float = 0.0
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A closed tube along ``path (N, 3)`` with radius per point."""
    n = len(path)
    tangent = np.gradient(path, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    ref = np.array([1.0, 0.0, 0.0])
    side = np.cross(tangent, ref)
    side /= np.linalg.norm(side, axis=1, keepdims=True).clip(1e-9)
    up = np.cross(side, tangent)
    ang = 2 * np.pi * np.arange(ring) / ring
    r = radii[:, None] * (1 + bumps * np.abs(np.sin(np.arange(n)[:, None] * 1.3 + ang[None])))
    pts = path[:, None] + r[..., None] * (np.cos(ang)[None, :, None] * side[:, None]
                                          + np.sin(ang)[None, :, None] * up[:, None])
    grid = pts.reshape(-1, 3)
    verts = np.concatenate([grid, path[:1], path[-1:]])
    idx = np.arange(n * ring).reshape(n, ring)
    right = np.roll(idx, -1, axis=1)
    faces = np.concatenate([
        np.stack([idx[:-1], right[:-1], idx[1:]], -1).reshape(-1, 3),
        np.stack([right[:-1], right[1:], idx[1:]], -1).reshape(-1, 3),
        np.stack([np.full(ring, n * ring), right[0], idx[0]], -1),
        np.stack([np.full(ring, n * ring + 1), idx[-1], right[-1]], -1),
    ])
    u = np.broadcast_to(ang[None] / (2 * np.pi), (n, ring))
    v = np.broadcast_to(np.arange(n)[:, None] / max(n - 1, 1), (n, ring))
    uv = np.concatenate([np.stack([u, v], -1).reshape(-1, 2), [[0.5, 0.0], [0.5, 1.0]]])
    return verts, faces.astype(np.int64), uv


def _orient_outward(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Flip a closed piece whose signed volume is negative."""
    tri = verts[faces]
    vol = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum()
    return faces if vol >= 0 else faces[:, ::-1].copy()


def _extras(style: HairStyle, frame: HeadFrame, head_top: float, back_z: float
            ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    lv = frame.levels
    pieces = []
    clear = 0.012  # pieces start this far outside the head
    for extra in style.extras:
        if extra in ("bun", "top_knot"):
            from head360cli.synth.sculpt import _latlong_faces, _latlong_unit

            g, poles = _latlong_unit(8, 12)
            unit = np.concatenate([g, poles])
            if extra == "bun":
                centre = np.array([0.0, lv["eye"] + 0.045, back_z - 0.025 - clear])
                radius = np.array([0.032, 0.028, 0.022])
            else:
                centre = np.array([0.0, head_top + 0.022 + clear * 0.3, -0.02])
                radius = np.array([0.026, 0.022, 0.026])
            verts = unit * radius + centre
            faces = _latlong_faces(8, 12, 0, 96, 97)
            uv = np.column_stack([np.arctan2(unit[:, 0], unit[:, 1]) / (2 * np.pi) + 0.5,
                                  0.5 - 0.5 * unit[:, 2]])
            pieces.append((verts, _orient_outward(verts, faces), uv))
        elif extra in ("ponytail_high", "ponytail_low", "braid"):
            start_y = lv["eye"] + (0.05 if extra == "ponytail_high" else -0.02)
            t = np.linspace(0, 1, 14)
            length = 0.20 if extra != "braid" else 0.24
            path = np.column_stack([np.zeros_like(t), start_y - length * t ** 1.2,
                                    back_z - clear - 0.012 - 0.045 * np.sin(t * np.pi * 0.6)])
            radii = (0.022 if extra != "braid" else 0.016) * (1.0 - 0.55 * t) + 0.004
            pieces.append(_tube(path, radii, bumps=0.35 if extra == "braid" else 0.05))
        elif extra == "twin_tails":
            for sgn in (1, -1):
                t = np.linspace(0, 1, 12)
                side = abs(frame.ear_centres[0, 0]) + 0.02
                path = np.column_stack([sgn * (side + 0.012 * np.sin(t * np.pi * 0.8)),
                                        lv["eye"] + 0.035 - 0.17 * t,
                                        -0.035 - 0.02 * t])
                pieces.append(_tube(path, 0.018 * (1 - 0.5 * t) + 0.004, bumps=0.08))
    return pieces


MAX_END_SHIFT = 0.3
"""Largest :attr:`HairStyle.end_shift` a head may carry, metres either way (a head file's
``hair_end_shift`` beyond it is refused: no hair ends 30 cm from its style's end)."""

WARP_BINS = 32
"""Directions around the head's forward axis (every 11.25 degrees, the first towards the
head's left, +x, counter-clockwise seen from the front) at which a fit scales the hair's
thickness (:func:`warp_hair`)."""

WARP_AXIS = 0.03
"""Metres from the forward axis within which the hair's scale fades to the mean of all
directions: behind and in front of the centre a direction is ill defined."""


def warp_centre(frame: HeadFrame) -> np.ndarray:
    """``(3,)`` the point a hair warp's directions are taken from: on the head's midline
    at eye level, as deep as the ears, so that every ray from it leaves the head and the
    hair once."""
    return np.array([0.0, frame.levels["eye"], float(frame.ear_centres[:, 2].mean())])


def warp_hair(hair: np.ndarray, head: np.ndarray, scale: np.ndarray, centre: np.ndarray,
              nearest: np.ndarray | None = None) -> np.ndarray:
    """Hair whose thickness over the head is scaled by direction.

    Each hair vertex moves along the line from its nearest head vertex, its distance from
    that vertex beyond :data:`INNER_GAP` multiplied by ``scale`` at the vertex's
    direction around the head's forward (z) axis seen from ``centre`` (interpolated
    between the bins, in log space). So a scale of 2 towards the temples doubles the
    hair's volume there, all the way round to the back; below 1 the hair lies flatter
    (it does not end higher: that is :attr:`HairStyle.end_shift`).

    Args:
        hair: ``(H, 3)`` hair vertices fitted to ``head``.
        head: ``(V, 3)`` the head's vertices (neutral).
        scale: ``(WARP_BINS,)`` positive factors (ones: unchanged).
        centre: ``(3,)`` from :func:`warp_centre`.
        nearest: ``(H,)`` each hair vertex's nearest head vertex, when already found
            (:func:`nearest_head_vertices`).

    Returns:
        ``(H, 3)`` the warped vertices.
    """
    log = np.log(np.asarray(scale, np.float64))
    if len(hair) == 0 or not np.any(log):
        return hair
    if nearest is None:
        nearest = nearest_head_vertices(hair, head)
    rel = hair - centre
    angle = np.arctan2(rel[:, 1], rel[:, 0])
    pos = np.mod(angle / (2 * np.pi) * len(log), len(log))
    lo = np.floor(pos).astype(int)
    frac = pos - lo
    at = (1 - frac) * log[lo % len(log)] + frac * log[(lo + 1) % len(log)]
    near_axis = np.clip(np.hypot(rel[:, 0], rel[:, 1]) / WARP_AXIS, 0.0, 1.0)
    factor = np.exp(near_axis * at + (1 - near_axis) * log.mean())
    anchor = head[nearest]
    away = hair - anchor
    dist = np.linalg.norm(away, axis=1, keepdims=True)
    # the part beyond the inner gap scales: the shell's inner surface stays off the skin
    beyond = np.maximum(dist - INNER_GAP, 0.0)
    return anchor + away / np.maximum(dist, 1e-12) * (dist - beyond
                                                      + factor[:, None] * beyond)


def nearest_head_vertices(hair: np.ndarray, head: np.ndarray) -> np.ndarray:
    """``(H,)`` index of the nearest of the ``head (V, 3)`` vertices to each of ``hair
    (H, 3)``."""
    from scipy.spatial import cKDTree

    return cKDTree(head).query(hair)[1]


def build_hair(verts: np.ndarray, frame: HeadFrame, style: HairStyle | int,
               normals: np.ndarray | None = None, soft: bool = False,
               scale: np.ndarray | None = None) -> HairMesh:
    """Fit a hairstyle to a head.

    Args:
        verts: ``(V, 3)`` the head's vertices (neutral).
        frame: The head's feature frame.
        style: A :class:`HairStyle` or its index in :data:`HAIRSTYLES`.
        normals: ``(V, 3)`` :func:`head_normals` of ``verts``, when already made (for
            several styles on one head); made here otherwise.
        soft: Hairlines that follow the style's line (lifted half a row, as high as
            the steps reach on average) between grid rows and thin out at the edge;
            ``False`` steps from row to row (the hair the shipped generator learnt, and
            what the deferred generator is not shown).
        scale: ``(WARP_BINS,)`` a fit's scale of the hair's thickness by direction
            (:func:`warp_hair`) over the head; the extra pieces keep their shape.
            Default none.

    Returns:
        The hair mesh (empty for ``bald``).
    """
    if isinstance(style, int):
        style = HAIRSTYLES[style]
    if style.top <= 0 and not style.extras:
        return HairMesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros((0, 2)))
    bottom = min(frame.levels["menton"] - style.length - max(style.end_shift, 0.0),
                 frame.levels["neck_bottom"])
    base, normal = _base_grid(verts, frame, bottom, normals)
    covered, thick, base = _coverage_and_thickness(base, frame, style, soft)
    shell = _shell(base, normal, covered, thick, style, frame)
    if scale is not None:  # the extras keep their shape: a photo shows a tail or none
        shell = (warp_hair(shell[0], verts, scale, warp_centre(frame)), *shell[1:])
    pieces = [shell]
    head_top = float(verts[:, 1].max())
    back_z = float(verts[:, 2].min())
    pieces += _extras(style, frame, head_top, back_z)
    all_v, all_f, all_uv, offset = [], [], [], 0
    for v, f, uv in pieces:
        all_v.append(v)
        all_f.append(f + offset)
        all_uv.append(uv)
        offset += len(v)
    return HairMesh(np.concatenate(all_v), np.concatenate(all_f), np.concatenate(all_uv),
                    len(shell[0]))


def fit_hair(verts: np.ndarray, style: HairStyle | int, soft: bool = False,
             scale: np.ndarray | None = None, end_shift: float = 0.0) -> HairMesh:
    """Fit a hairstyle to any head of this topology, its frame read off the vertices
    (:func:`head360cli.synth.sculpt.frame_from_vertices`); for a corpus head this is the
    same mesh as :func:`build_hair` with the head's own frame (``scale``: a fit's
    thickness by direction, :func:`warp_hair`; ``end_shift``: a fit's
    :attr:`HairStyle.end_shift`)."""
    from head360cli.synth.sculpt import frame_from_vertices

    if isinstance(style, int | np.integer):
        style = HAIRSTYLES[int(style)]
    if end_shift:
        style = dataclasses.replace(style, end_shift=float(end_shift))
    return build_hair(verts, frame_from_vertices(verts), style, soft=soft, scale=scale)


def fit_hairs(verts: np.ndarray, styles: list[int]) -> dict[int, HairMesh]:
    """:func:`fit_hair` for several styles on one head, its frame and normals made once:
    ``{style: mesh}``, the same meshes."""
    from head360cli.synth.sculpt import frame_from_vertices

    frame = frame_from_vertices(verts)
    normals = head_normals(verts)
    return {s: build_hair(verts, frame, s, normals) for s in dict.fromkeys(styles)}


def hair_texture(colour: tuple[float, float, float], size: int = 256, seed: int = 0
                 ) -> np.ndarray:
    """A strand texture: streaks along v (the hair's length), tinted by ``colour``.

    Returns:
        ``(size, size, 3)`` float32 albedo in [0, 1].
    """
    import cv2

    rng = np.random.default_rng([seed, 0x4A1])
    streaks = rng.uniform(-1, 1, (8, size))  # many strands across, few samples along
    streaks = cv2.resize(streaks, (size, size), interpolation=cv2.INTER_CUBIC)
    fine = cv2.resize(rng.uniform(-1, 1, (size // 8, size // 2)), (size, size),
                      interpolation=cv2.INTER_LINEAR)
    shade = 1.0 + 0.22 * streaks + 0.08 * fine
    base = np.asarray(colour, dtype=np.float64)
    tex = base[None, None] * shade[..., None] + 0.03 * (base.max() < 0.1) * shade[..., None]
    return np.clip(tex, 0, 1).astype(np.float32)

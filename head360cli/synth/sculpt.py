"""The procedural full head: one fixed topology, vertex positions from identity parameters.

The head is built from parts that share one vertex array:

- ``skin``: a closed grid of rows (crown to the bottom of the neck) by 80 columns (around
  the head, denser in front), with a pole at each end. Rows are *semantic*: each sits at a
  named level (brow, eye, nose tip, lip seam...) whose height comes from the identity. At
  the lip seam the grid folds inwards into a pocket that forms the mouth cavity, so the skin
  stays one closed surface and ``jawOpen`` opens a real mouth. The eye openings are almond
  shaped dents that let the eyeballs show through; closing the lids moves that skin over
  the eyeballs.
- ``eye_l``/``eye_r`` (eyeballs that rotate), ``ear_l``/``ear_r``, ``teeth_upper``,
  ``teeth_lower`` and ``tongue``: closed surfaces of their own.

Because every identity is built by the same function on the same grid, vertex ``k`` is the
same anatomical point on every head. Coordinates: +y up, the face looks along +z, +x is the
subject's left, metres, origin at the head centre.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from head360cli.synth.fields import gauss2d, smoothstep
from head360cli.synth.identity import IdentityParams

__all__ = ["N_COLS", "HeadFrame", "Topology", "build_head", "frame_from_vertices", "topology"]

N_COLS = 80
"""Columns of the skin grid."""
_WARP = 0.6
"""Column density in front is (1 + WARP) / (1 - WARP) times that at the back."""

# Skin rows strictly between consecutive key levels. At the seam level the grid first
# folds into the mouth pocket (upper seam row, pocket rows, lower seam row).
_LEVELS = ["cap_end", "forehead", "brow", "eye_top", "eye_bottom", "nose_tip", "nose_base",
           "lip_top", "seam", "lip_bottom", "chin", "menton", "throat", "neck_bottom"]
_BETWEEN = [2, 3, 3, 6, 5, 3, 3, 3, 3, 3, 3, 3, 1, 3]
_CAP_ANGLES_DEG = (14.0, 28.0, 42.0, 56.0, 69.0)
_CAP_END_DEG = 80.0
_POCKET = 5  # rows inside the mouth, between the upper and lower seam rows
EYE_RADIUS = 0.0118


@dataclasses.dataclass(frozen=True)
class Topology:
    """Everything about the head mesh that does not depend on the identity.

    Attributes:
        faces: ``(F, 3)`` int64 vertex indices, outward-facing (counter-clockwise).
        uv: ``(T, 2)`` texture coordinates in [0, 1]^2, one atlas without overlaps.
        faces_uv: ``(F, 3)`` int64 indices into ``uv`` (seams need their own corners).
        parts: part name -> ``(start, stop)`` range of vertex indices.
        face_parts: ``(F,)`` int64 index into ``part_names`` for each face.
        part_names: the part names in order.
        skin_rows: ``(R, N_COLS)`` vertex ids of the skin grid rows (without the poles).
        row_names: the semantic level of every skin row (e.g. ``"seam_upper"``).
        mirror: ``(V,)`` index of each vertex's left/right mirror image.
        normal_groups: ``(N_COLS, 2 + pocket rows)`` per column the upper seam, pocket and
            lower seam vertices, which coincide where the lips are closed (see
            :func:`head360cli.geometry.mesh_ops.vertex_normals`).
    """

    faces: np.ndarray
    uv: np.ndarray
    faces_uv: np.ndarray
    parts: dict[str, tuple[int, int]]
    face_parts: np.ndarray
    part_names: tuple[str, ...]
    skin_rows: np.ndarray
    row_names: tuple[str, ...]
    mirror: np.ndarray
    normal_groups: np.ndarray

    @property
    def num_vertices(self) -> int:
        return max(stop for _, stop in self.parts.values())


@dataclasses.dataclass
class HeadFrame:
    """Where the identity's features are (used by blendshapes, landmarks and hair).

    All points are ``(3,)`` arrays in metres; ``levels`` maps each key level to its height.
    """

    levels: dict[str, float]
    eye_centres: np.ndarray  # (2, 3): left (+x) then right (-x)
    eye_half_width: float
    eye_half_height_up: float
    eye_half_height_down: float
    mouth_half_width: float
    jaw_pivot: np.ndarray  # (3,) on the axis the jaw turns about (parallel to x)
    ear_centres: np.ndarray  # (2, 3)
    nose_tip: np.ndarray
    face_half_width: float = 0.065  # widest |x| of the face in front of the ears, eye level


# --------------------------------------------------------------------------- topology


def _column_angles() -> np.ndarray:
    t = -1.0 + 2.0 * np.arange(N_COLS) / N_COLS
    return np.pi * t - _WARP * np.sin(np.pi * t)


def _row_layout() -> list[tuple[str, str, float]]:
    """Skin rows as (name, level, fraction of the way to the next level)."""
    rows: list[tuple[str, str, float]] = []
    for k, deg in enumerate(_CAP_ANGLES_DEG):
        rows.append((f"cap{k}", "cap", deg))
    for i, level in enumerate(_LEVELS):
        if level == "seam":
            rows.append(("seam_upper", "seam", 0.0))
            rows.extend((f"pocket{k}", "pocket", float(k)) for k in range(_POCKET))
            rows.append(("seam_lower", "seam", 0.0))
        else:
            rows.append((level, level, 0.0))
        between = _BETWEEN[i]
        if between and i + 1 < len(_LEVELS):
            rows.extend((f"{level}+{k + 1}", level, (k + 1) / (between + 1))
                        for k in range(between))
    return rows


def _latlong_faces(rows: int, cols: int, offset: int, top: int, bottom: int) -> np.ndarray:
    """Triangles of a closed grid: ``rows`` x ``cols`` (wrapping) with two pole vertices."""
    idx = offset + np.arange(rows * cols).reshape(rows, cols)
    right = np.roll(idx, -1, axis=1)
    a, b = idx[:-1], right[:-1]
    c, d = idx[1:], right[1:]
    quads = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3),
                            np.stack([b, c, d], -1).reshape(-1, 3)])
    cap_top = np.stack([np.full(cols, top), idx[0], right[0]], -1)
    cap_bottom = np.stack([np.full(cols, bottom), right[-1], idx[-1]], -1)
    return np.concatenate([cap_top, quads, cap_bottom]).astype(np.int64)


def _latlong_uv(rows: int, cols: int, rect: tuple[float, float, float, float],
                faces_local: np.ndarray, uv_offset: int) -> tuple[np.ndarray, np.ndarray]:
    """UVs for a lat-long grid in ``rect = (u0, v0, u1, v1)``: a seam column and poles."""
    u0, v0, u1, v1 = rect
    # Corners: (rows + 2) x (cols + 1) grid incl. pole rows; poles get one UV per column.
    uu = np.linspace(u0, u1, cols + 1)
    vv = np.linspace(v0, v1, rows + 2)
    uv = np.stack(np.meshgrid(uu, vv), -1).reshape(-1, 2)
    faces_uv = np.empty_like(faces_local)
    # Map each face corner (local vertex id, with poles as -1/-2) to its UV row/column.
    n_top, n_quad = cols, 2 * (rows - 1) * cols
    col = np.arange(cols)
    nxt = col + 1
    grid = lambda r, c: uv_offset + (r + 1) * (cols + 1) + c  # noqa: E731
    faces_uv[:n_top] = np.stack([uv_offset + 0 * (cols + 1) + col + 0 * nxt,
                                 grid(0, col), grid(0, nxt)], -1)
    r = np.repeat(np.arange(rows - 1), cols)
    c = np.tile(col, rows - 1)
    q1 = np.stack([grid(r, c), grid(r + 1, c), grid(r, c + 1)], -1)
    q2 = np.stack([grid(r, c + 1), grid(r + 1, c), grid(r + 1, c + 1)], -1)
    faces_uv[n_top:n_top + n_quad // 2] = q1
    faces_uv[n_top + n_quad // 2:n_top + n_quad] = q2
    faces_uv[n_top + n_quad:] = np.stack([uv_offset + (rows + 1) * (cols + 1) + col,
                                          grid(rows - 1, nxt), grid(rows - 1, col)], -1)
    return uv, faces_uv


def _tube_faces(segments: int, ring: int, offset: int) -> np.ndarray:
    """A tube of ``segments`` rings of ``ring`` vertices, closed by two centre vertices
    (``offset + segments * ring`` and the next)."""
    return _latlong_faces(segments, ring, offset, offset + segments * ring,
                          offset + segments * ring + 1)


# Parts whose grid, as built, faces inwards (their faces are flipped). The right ear is a
# mirror image of the left one, which flips its orientation back.
_INWARD = ("eye_l", "eye_r", "ear_l", "tongue")
_EYE_ROWS, _EYE_COLS = 9, 14
_EAR_ROWS, _EAR_COLS = 8, 14
_TEETH_SEGS, _TEETH_RING = 14, 4
_TONGUE_ROWS, _TONGUE_COLS = 7, 12


def _part_specs(skin_rows: int) -> list[tuple[str, int, int, tuple[float, float, float, float]]]:
    return [
        ("skin", skin_rows, N_COLS, (0.0, 0.0, 0.74, 1.0)),
        ("eye_l", _EYE_ROWS, _EYE_COLS, (0.76, 0.0, 0.87, 0.11)),
        ("eye_r", _EYE_ROWS, _EYE_COLS, (0.88, 0.0, 0.99, 0.11)),
        ("ear_l", _EAR_ROWS, _EAR_COLS, (0.76, 0.13, 0.99, 0.30)),
        ("ear_r", _EAR_ROWS, _EAR_COLS, (0.76, 0.32, 0.99, 0.49)),
        ("teeth_upper", _TEETH_SEGS, _TEETH_RING, (0.76, 0.51, 0.99, 0.58)),
        ("teeth_lower", _TEETH_SEGS, _TEETH_RING, (0.76, 0.60, 0.99, 0.67)),
        ("tongue", _TONGUE_ROWS, _TONGUE_COLS, (0.76, 0.69, 0.99, 0.84)),
    ]


@functools.lru_cache(maxsize=1)
def topology() -> Topology:
    """The head's topology (cached; identical for every identity)."""
    layout = _row_layout()
    specs = _part_specs(len(layout))
    faces, faces_uv, uvs, face_parts = [], [], [], []
    parts: dict[str, tuple[int, int]] = {}
    offset = uv_offset = 0
    for p, (name, rows, cols, rect) in enumerate(specs):
        count = rows * cols + 2
        f = _latlong_faces(rows, cols, offset, offset + rows * cols, offset + rows * cols + 1)
        local = f - offset
        uv, fuv = _latlong_uv(rows, cols, rect, local, uv_offset)
        if name in _INWARD:
            f, fuv = f[:, ::-1].copy(), fuv[:, ::-1].copy()
        faces.append(f)
        faces_uv.append(fuv)
        uvs.append(uv)
        face_parts.append(np.full(len(f), p, dtype=np.int64))
        parts[name] = (offset, offset + count)
        offset += count
        uv_offset += len(uv)
    skin_rows = np.arange(len(layout) * N_COLS).reshape(len(layout), N_COLS)
    mirror = np.arange(offset)
    # Skin: column j mirrors to (N - j) mod N. Parts: left and right swap.
    cols = np.arange(N_COLS)
    mirror[skin_rows] = skin_rows[:, (N_COLS - cols) % N_COLS]
    # Ears are built from the same local grid with x negated: vertex k mirrors vertex k.
    (a0, a1), (b0, b1) = parts["ear_l"], parts["ear_r"]
    mirror[a0:a1], mirror[b0:b1] = np.arange(b0, b1), np.arange(a0, a1)
    for left, right, ncols in (("eye_l", "eye_r", _EYE_COLS),):
        (a0, a1), (b0, b1) = parts[left], parts[right]
        local = np.arange(a1 - a0)
        ring, col = local // ncols, local % ncols
        grid = local < (a1 - a0 - 2)
        mirrored = np.where(grid, ring * ncols + (ncols - col) % ncols, local)
        mirror[a0:a1] = b0 + mirrored
        mirror[b0:b1] = a0 + mirrored
    for name, ncols in (("teeth_upper", _TEETH_RING), ("teeth_lower", _TEETH_RING),
                        ("tongue", _TONGUE_COLS)):
        a0, a1 = parts[name]
        local = np.arange(a1 - a0)
        grid = local < (a1 - a0 - 2)
        if name.startswith("teeth"):  # segments run left to right: mirror the segment index
            seg, k = local // ncols, local % ncols
            mirror[a0:a1] = a0 + np.where(grid, (_TEETH_SEGS - 1 - seg) * ncols + k,
                                          np.where(local == a1 - a0 - 2, a1 - a0 - 1,
                                                   a1 - a0 - 2))
        else:
            ring, col = local // ncols, local % ncols
            mirror[a0:a1] = a0 + np.where(grid, ring * ncols + (ncols - col) % ncols, local)
    return Topology(
        faces=np.concatenate(faces),
        uv=np.concatenate(uvs).astype(np.float32),
        faces_uv=np.concatenate(faces_uv),
        parts=parts,
        face_parts=np.concatenate(face_parts),
        part_names=tuple(s[0] for s in specs),
        skin_rows=skin_rows,
        row_names=tuple(r[0] for r in layout),
        mirror=mirror,
        normal_groups=skin_rows[[r[0] for r in layout].index("seam_upper"):
                                [r[0] for r in layout].index("seam_lower") + 1].T.copy(),
    )


# --------------------------------------------------------------------------- geometry


def _levels(p: IdentityParams) -> dict[str, float]:
    menton = -p.head_height / 2
    lip_bottom = menton + p.chin_height
    seam = lip_bottom + 0.0095 * p.lip_fullness
    lip_top = seam + 0.0085 * p.lip_fullness
    nose_base = seam + 0.021
    nasion = nose_base + p.nose_length
    eye = nasion - 0.009
    return {
        "crown": p.head_height / 2,
        "forehead": nasion + 0.036,
        "brow": nasion + 0.008,
        "nasion": nasion,
        "eye_top": eye + 0.0065 * p.eye_size,
        "eye": eye,
        "eye_bottom": eye - 0.0055 * p.eye_size,
        "nose_tip": nose_base + 0.011,
        "nose_base": nose_base,
        "lip_top": lip_top,
        "seam": seam,
        "lip_bottom": lip_bottom,
        "chin": menton + 0.016,
        "menton": menton,
        "throat": menton - 0.022,
        "neck_bottom": menton - 0.090,
    } | {"cap_end": nasion + 0.036 + 0.022}


def _section_table(p: IdentityParams, lv: dict[str, float]) -> dict[str, tuple[float, ...]]:
    """Cross-section (half width a, front zf, back zb, front and back exponents) per level."""
    ac = p.head_breadth / 2
    zf_brow = 0.097 + 0.5 * p.brow_ridge
    zb = p.head_length - zf_brow  # head length is measured at the brow
    slope = p.forehead_slope
    jw, nw = p.jaw_width / 2, p.neck_width / 2
    face = p.face_width / 2
    # Cheek width sets how square the face is in front: a larger exponent, a wider face.
    pf_mid = 2.2 + 2.0 * (face / ac - 0.87)
    # A wide jaw squares the lower face (a larger front exponent), a narrow one rounds it;
    # the same shift on every lower-face row, so it makes no ridge between rows.
    jaw = 0.05 * (jw - 0.051) / 0.003
    # Keys at well-spaced heights only: keys a few millimetres apart would bend the
    # surface sharply between them and show as rings around the head.
    return {
        "cap_end": (0.985 * ac, 0.082 - 0.012 * slope, 0.98 * zb, 2.2, 2.0),
        "forehead": (ac, 0.092 - 0.006 * slope, zb, 2.4, 2.0),
        "brow": (ac, zf_brow, 0.985 * zb, pf_mid + 0.2, 2.0),
        "eye": (0.99 * ac, 0.095, 0.955 * zb, pf_mid + 0.15, 2.02),
        "nose_base": (0.93 * ac, 0.097, 0.82 * zb, pf_mid - 0.1, 2.1),
        "seam": (0.87 * ac + 0.2 * (jw - 0.051), 0.096, 0.71 * zb, pf_mid - 0.25 + jaw, 2.2),
        "chin": (0.5 * (nw + 0.8 * ac), 0.092 + p.chin_projection, 0.62 * zb,
                 max(1.3, pf_mid - 0.8 + jaw), 2.2),
        "menton": (nw, 0.078 + p.chin_projection, 0.60 * zb, 1.35, 2.2),
        "throat": (nw, 0.050, 0.58 * zb, 2.0, 2.2),
        "neck_bottom": (nw + 0.006, 0.055, 0.57 * zb, 2.0, 2.0),
    }


def _section_radius(phi: np.ndarray, a, zf, zb, pf, pb) -> np.ndarray:
    c, s = np.cos(phi), np.sin(phi)
    front = c >= 0
    depth = np.where(front, zf, zb)
    expo = np.where(front, pf, pb)
    return (np.abs(c / depth) ** expo + np.abs(s / a) ** expo) ** (-1.0 / expo)


def _features(x, y, p: IdentityParams, lv: dict[str, float]) -> np.ndarray:
    """Outward displacement of the face surface at face coordinates (x, y)."""
    h = np.zeros_like(x)
    # Nose: a ridge from the nasion to the tip, falling steeply to the base; alae.
    t_ridge = np.clip((lv["nasion"] - y) / (lv["nasion"] - lv["nose_tip"]), 0, None)
    ridge = np.where(t_ridge <= 1.0, 0.22 + 0.78 * t_ridge ** 1.4,
                     np.exp(-((y - lv["nose_tip"]) / (0.45 * (lv["nose_tip"]
                                                          - lv["nose_base"]))) ** 2))
    ridge = ridge * smoothstep(lv["nasion"] + 0.012, lv["nasion"] - 0.002, y)
    width = 0.0065 + 0.0035 * np.clip(t_ridge, 0, 1.2)
    h += p.nose_projection * ridge * np.exp(-0.5 * (x / width) ** 2)
    ala_x = p.nose_width / 2 - 0.0045
    for sgn in (1, -1):
        h += 0.0085 * gauss2d(x, y, sgn * ala_x, lv["nose_base"] + 0.0055, 0.0055, 0.0055)
    # Eye sockets and the brow ridge above them.
    for sgn in (1, -1):
        h -= 0.0065 * gauss2d(x, y, sgn * p.eye_spacing / 2, lv["eye"], 0.017, 0.011)
        h += (0.004 + 0.004 * p.cheek_fullness) * gauss2d(
            x, y, sgn * 0.049, lv["eye"] - 0.024, 0.015, 0.013)
        h += (p.cheek_fullness - 0.5) * 0.008 * gauss2d(x, y, sgn * 0.045, lv["seam"] + 0.006,
                                                        0.014, 0.014)
    h += p.brow_ridge * np.exp(-0.5 * ((y - lv["brow"]) / 0.0065) ** 2
                               - 0.5 * (x / 0.042) ** 4)
    # Lips, the dent under them and the chin.
    mw = p.mouth_width / 2
    lip_x = np.exp(-0.5 * (x / (0.8 * mw)) ** 4)
    upper_mid = 0.5 * (lv["seam"] + lv["lip_top"])
    lower_mid = 0.5 * (lv["seam"] + lv["lip_bottom"])
    h += 0.0045 * p.lip_fullness * lip_x * np.exp(
        -0.5 * ((y - upper_mid) / (0.5 * (lv["lip_top"] - lv["seam"]))) ** 2)
    h += 0.0055 * p.lip_fullness * lip_x * np.exp(
        -0.5 * ((y - lower_mid) / (0.5 * (lv["seam"] - lv["lip_bottom"]))) ** 2)
    h -= 0.0028 * gauss2d(x, y, 0.0, lv["lip_bottom"] - 0.006, 0.014, 0.004)
    h += (0.004 + p.chin_projection) * gauss2d(x, y, 0.0, lv["chin"] + 0.004, 0.016, 0.011)
    # Philtrum groove.
    h -= 0.0012 * gauss2d(x, y, 0.0, 0.5 * (lv["nose_base"] + lv["lip_top"]), 0.003, 0.005)
    return h


def _row_heights(p: IdentityParams, lv: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """Height and cap scale (1 below the cap) of every skin row."""
    layout = _row_layout()
    ys, scales = [], []
    cap_end = lv["cap_end"]
    by = (lv["crown"] - cap_end) / (1 - math.cos(math.radians(_CAP_END_DEG)))
    order = {name: i for i, name in enumerate(_LEVELS)}
    for _, level, frac in layout:
        if level == "cap":
            theta = math.radians(frac)
            ys.append(lv["crown"] - by * (1 - math.cos(theta)))
            scales.append(math.sin(theta) / math.sin(math.radians(_CAP_END_DEG)))
        elif level == "pocket":
            ys.append(lv["seam"])
            scales.append(1.0)
        else:
            nxt = _LEVELS[min(order[level] + 1, len(_LEVELS) - 1)]
            ys.append(lv[level] + frac * (lv[nxt] - lv[level]))
            scales.append(1.0)
    return np.array(ys), np.array(scales)


def _interp_sections(ys: np.ndarray, table: dict[str, tuple[float, ...]],
                     lv: dict[str, float]) -> np.ndarray:
    """Cross-section parameters at heights ``ys``: smooth (C1, shape-preserving) through
    the key levels, so the surface has no creases between them."""
    from scipy.interpolate import PchipInterpolator

    keys = list(table)
    key_y = np.array([lv[k] for k in keys])[::-1]
    vals = np.array([table[k] for k in keys])[::-1]
    return PchipInterpolator(key_y, vals, axis=0, extrapolate=True)(
        np.clip(ys, key_y[0], key_y[-1]))


def _skin(p: IdentityParams, lv: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """Skin grid positions ``(R, N_COLS, 3)`` without the eye dents, and the poles."""
    phi = _column_angles()
    ys, scales = _row_heights(p, lv)
    table = _section_table(p, lv)
    sec = _interp_sections(np.minimum(ys, lv["cap_end"]), table, lv)
    r = _section_radius(phi[None, :], *(sec[:, i:i + 1] for i in range(5)))
    r = r * scales[:, None]
    x = r * np.sin(phi)[None]
    z = r * np.cos(phi)[None]
    y = np.broadcast_to(ys[:, None], x.shape)
    # Facial features live on the front: fade them out well before the sides of the head.
    h = _features(x, y, p, lv) * smoothstep(0.3, 0.8, np.cos(phi))[None]
    x = x + h * np.sin(phi)[None]
    z = z + h * np.cos(phi)[None]
    pts = np.stack([x, y.copy(), z], -1)
    top = np.array([0.0, lv["crown"], pts[0, :, 2].mean()])
    bottom = np.array([0.0, lv["neck_bottom"] - 0.004, pts[-1, :, 2].mean()])
    return pts, np.stack([top, bottom])


def _pocket(pts: np.ndarray, p: IdentityParams) -> None:
    """Fold the rows between the two seam rows inwards into a mouth cavity (in place)."""
    names = topology().row_names
    su, sl = names.index("seam_upper"), names.index("seam_lower")
    seam = pts[su]
    mw = p.mouth_width / 2
    taper = np.sqrt(np.clip(1 - (seam[:, 0] / mw) ** 2, 0, 1)) * (seam[:, 2] > 0)
    # (x scale, dy, dz) of each pocket row relative to the seam, at full depth.
    shape = [(0.95, 0.010, -0.007), (0.85, 0.012, -0.030), (0.75, 0.000, -0.050),
             (0.85, -0.013, -0.030), (0.95, -0.012, -0.008)]
    for k, (sx, dy, dz) in enumerate(shape):
        row = pts[su + 1 + k]
        row[:, 0] = seam[:, 0] * (1 - (1 - sx) * taper)
        row[:, 1] = seam[:, 1] + dy * taper
        row[:, 2] = seam[:, 2] + dz * taper
    pts[sl] = seam


def _eye_frame(pts: np.ndarray, p: IdentityParams, lv: dict[str, float]) -> np.ndarray:
    """Eyeball centres (left, right), in front of the socket so the cornea shows."""
    names = topology().row_names
    row = pts[names.index("eye_top"):names.index("eye_bottom") + 1]
    centres = []
    flat = row.reshape(-1, 3)
    flat = flat[flat[:, 2] > 0.02]  # the face, not the back of the head
    for sgn in (1, -1):
        ex = sgn * p.eye_spacing / 2
        near = flat[np.argmin(np.abs(flat[:, 0] - ex) + np.abs(flat[:, 1] - lv["eye"]))]
        centres.append([ex, lv["eye"], near[2] + 0.0030 - EYE_RADIUS])
    return np.array(centres)


def _almond(x, y, ex, ey, hw, up, down):
    """Signed inside-ness of the eye opening: > 0 inside, 0 on the lid margin."""
    u = np.clip(1 - ((x - ex) / hw) ** 2, 0, None)
    top = ey + up * np.sqrt(u) * (1 + 0.15 * (x - ex) / hw * np.sign(ex))
    bottom = ey - down * np.sqrt(u)
    return np.minimum(top - y, y - bottom)


def _eye_dents(pts: np.ndarray, p: IdentityParams, lv: dict[str, float],
               centres: np.ndarray) -> None:
    """Push the skin of the eye openings behind the eyeballs (in place).

    The dent is shallow under the upper lid and deep at the lower lid, so when the
    ``eyeBlink`` shape moves this skin over the eyeball, the lid comes down from the top.
    """
    hw = 0.0150 * p.eye_size
    up, down = lv["eye_top"] - lv["eye"], lv["eye"] - lv["eye_bottom"]
    for c in centres:
        inside = _almond(pts[..., 0], pts[..., 1], c[0], c[1], hw, up, down)
        w = smoothstep(-0.0003, 0.0012, inside) * (pts[..., 2] > 0)
        frac = np.clip((c[1] + up - pts[..., 1]) / (up + down), 0, 1)  # 0 top, 1 bottom
        sphere_z = c[2] + np.sqrt(np.clip(EYE_RADIUS ** 2 - (pts[..., 0] - c[0]) ** 2
                                          - (pts[..., 1] - c[1]) ** 2, 0, None))
        target = sphere_z - (0.0020 + 0.0080 * frac)
        pts[..., 2] = np.where(w > 0, (1 - w) * pts[..., 2] + w * np.minimum(pts[..., 2],
                                                                           target), pts[..., 2])


def _latlong_unit(rows: int, cols: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit sphere grid (poles excluded) with its first pole at +z; and the two poles."""
    theta = np.linspace(0, np.pi, rows + 2)[1:-1]
    lon = 2 * np.pi * np.arange(cols) / cols
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    grid = np.stack([st * np.sin(lon)[None], st * np.cos(lon)[None], ct * np.ones((1, cols))],
                    -1)
    return grid.reshape(-1, 3), np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])


def _eyeball(centre: np.ndarray) -> np.ndarray:
    g, poles = _latlong_unit(_EYE_ROWS, _EYE_COLS)
    return np.concatenate([g, poles]) * EYE_RADIUS + centre


def _ear(sgn: float, p: IdentityParams, lv: dict[str, float], side_x: float) -> np.ndarray:
    """A flattened, cupped ear, hinged at its front edge and turned out by its angle."""
    g, poles = _latlong_unit(_EAR_ROWS, _EAR_COLS)
    unit = np.concatenate([g, poles])  # first pole at +z; rotate so it points outward (x)
    local = np.stack([unit[:, 2], unit[:, 0], unit[:, 1]], -1)  # (thickness, height, depth)
    half_h, half_d, half_t = p.ear_size / 2, 0.31 * p.ear_size, 0.0045
    x = local[:, 0] * half_t
    # Cup the outer face (the concha) and thicken the rim.
    radial = np.clip(local[:, 1] ** 2 + local[:, 2] ** 2, 0, 1)
    x = x - 0.0032 * (1 - radial) * (local[:, 0] > 0)
    y = local[:, 1] * half_h * (1 - 0.12 * local[:, 2])  # narrower lobe at the front-bottom
    z = local[:, 2] * half_d
    # Hinge at the front edge, turn the back outwards.
    ang = p.ear_protrusion
    z_rel = z - half_d
    x2 = x * math.cos(ang) - z_rel * math.sin(ang)
    z2 = x * math.sin(ang) + z_rel * math.cos(ang) + half_d
    centre_y = 0.5 * (lv["eye"] + lv["nose_base"]) + 0.004
    out = np.stack([sgn * (side_x + 0.0015 + x2), centre_y + y, -0.006 + z2 - half_d], -1)
    return out


def _teeth(lower: bool, seam_mid: np.ndarray, p: IdentityParams) -> np.ndarray:
    """An arch of teeth behind the lips, as a closed swept rectangle."""
    half_w = 0.85 * p.mouth_width / 2 + 0.004
    depth = 0.022
    ang = np.linspace(-1.25, 1.25, _TEETH_SEGS)  # left to right across the front
    cx = -half_w * np.sin(ang)
    cz = seam_mid[2] - 0.0065 - depth * (1 - np.cos(ang)) - (0.0015 if lower else 0.0)
    top, bottom = (-0.0007, -0.0095) if lower else (0.0095, 0.0007)
    thick = 0.0055
    normal = np.stack([-np.sin(ang), np.zeros_like(ang), np.cos(ang)], -1)  # outwards
    centre = np.stack([cx, np.full_like(cx, seam_mid[1]), cz], -1)
    # Ring order: outer-top, outer-bottom, inner-bottom, inner-top.
    ring = [(0.0, top), (0.0, bottom), (-thick, bottom), (-thick, top)]
    pts = np.stack([centre + normal * o + np.array([0, 1.0, 0]) * dy for o, dy in ring], 1)
    grid = pts.reshape(-1, 3)
    ends = np.stack([pts[0].mean(0), pts[-1].mean(0)])
    return np.concatenate([grid, ends])


def _tongue(seam_mid: np.ndarray) -> np.ndarray:
    g, poles = _latlong_unit(_TONGUE_ROWS, _TONGUE_COLS)
    unit = np.concatenate([g, poles])
    scale = np.array([0.020, 0.0055, 0.028])
    centre = seam_mid + np.array([0.0, -0.0085, -0.036])
    return unit * scale + centre


def _smooth_deformation(skin: np.ndarray, p: IdentityParams, centres: np.ndarray,
                        lv: dict[str, float]) -> np.ndarray:
    """A smooth random outward displacement of the skin, mostly symmetric, kept away
    from the eyes and lips so that eyeballs and teeth stay covered correctly."""
    if p.deform_amplitude <= 0:
        return np.zeros(skin.shape[:-1])
    rng = np.random.default_rng([p.deform_seed, 0xDEF])
    d = np.zeros(skin.shape[:-1])
    for _ in range(7):
        c = rng.normal(size=3)
        c = c / np.linalg.norm(c) * np.array([0.07, 0.09, 0.09])
        sigma = rng.uniform(0.03, 0.06)
        amp = rng.normal() * p.deform_amplitude
        asym = 0.15 * rng.normal()
        for sgn, weight in ((1, 1 + asym), (-1, 1 - asym)):
            cc = c * np.array([sgn, 1, 1])
            d += 0.5 * weight * amp * np.exp(-0.5 * np.sum((skin - cc) ** 2, -1) / sigma ** 2)
    keep = np.ones(skin.shape[:-1])
    for c in centres:
        keep *= 1 - np.exp(-0.5 * np.sum((skin - c) ** 2, -1) / 0.018 ** 2)
    mouth = np.array([0.0, lv["seam"], 0.09])
    keep *= 1 - np.exp(-0.5 * np.sum((skin - mouth) ** 2, -1) / 0.022 ** 2)
    return d * keep


def build_head(p: IdentityParams) -> tuple[np.ndarray, HeadFrame]:
    """Vertex positions of one identity's neutral head.

    Args:
        p: The identity's sculpt parameters.

    Returns:
        ``(vertices (V, 3) float64, frame)``: positions in :func:`topology` order and where
        the identity's features are.
    """
    topo = topology()
    lv = _levels(p)
    grid, poles = _skin(p, lv)
    _pocket(grid, p)
    centres = _eye_frame(grid, p, lv)
    _eye_dents(grid, p, lv, centres)
    # Random smooth deformation along the horizontal normal.
    phi = _column_angles()
    n = np.stack([np.sin(phi), np.zeros_like(phi), np.cos(phi)], -1)[None]
    grid = grid + _smooth_deformation(grid, p, centres, lv)[..., None] * n
    names = topo.row_names
    seam = grid[names.index("seam_upper")]
    seam_mid = seam[N_COLS // 2]
    ear_row = grid[names.index("eye_bottom") + 2]
    side_x = float(np.abs(ear_row[:, 0]).max())
    parts = {
        "skin": np.concatenate([grid.reshape(-1, 3), poles]),
        "eye_l": _eyeball(centres[0]),
        "eye_r": _eyeball(centres[1]),
        "ear_l": _ear(1.0, p, lv, side_x),
        "ear_r": _ear(-1.0, p, lv, side_x),
        "teeth_upper": _teeth(False, seam_mid, p),
        "teeth_lower": _teeth(True, seam_mid, p),
        "tongue": _tongue(seam_mid),
    }
    verts = np.concatenate([parts[name] for name in topo.part_names])
    ear_c = np.stack([parts["ear_l"].mean(0), parts["ear_r"].mean(0)])
    frame = HeadFrame(
        levels=lv,
        eye_centres=centres,
        eye_half_width=0.0150 * p.eye_size,
        eye_half_height_up=lv["eye_top"] - lv["eye"],
        eye_half_height_down=lv["eye"] - lv["eye_bottom"],
        mouth_half_width=p.mouth_width / 2,
        jaw_pivot=np.array([0.0, 0.5 * (lv["eye_bottom"] + lv["nose_base"]) - 0.004,
                            -0.012]),
        ear_centres=ear_c,
        nose_tip=verts[topo.skin_rows[names.index("nose_tip"), N_COLS // 2]],
        face_half_width=float(np.abs(grid[names.index("eye_bottom")][:, 0][
            grid[names.index("eye_bottom")][:, 2] > 0.03]).max()),
    )
    return verts, frame


def frame_from_vertices(verts: np.ndarray) -> HeadFrame:
    """Recover a head's feature frame from its vertices alone.

    Works for any mesh in this topology (a corpus head, or the parametric model's head
    after a fit): each key level is the median height of the skin row built at it, ears
    and eyes are the centres of their parts. For a corpus head's neutral mesh the levels
    and the ear centres, which is what hair needs, come out exactly as
    :func:`build_head` made them; the eye and mouth sizes are estimates.

    Args:
        verts: ``(V, 3)`` neutral head vertices in :func:`topology` order.

    Returns:
        The frame.
    """
    topo = topology()
    names = topo.row_names
    verts = np.asarray(verts, dtype=np.float64)
    rows = {n: float(np.median(verts[topo.skin_rows[names.index(n)], 1]))
            for n in _LEVELS if n in names}
    rows["seam"] = float(np.median(verts[topo.skin_rows[names.index("seam_upper")], 1]))
    skin = verts[slice(*topo.parts["skin"])]
    eye_size = (rows["eye_top"] - rows["eye_bottom"]) / 0.012
    eye = rows["eye_top"] - 0.0065 * eye_size
    lv = dict(rows, crown=float(skin[:, 1].max()), eye=eye, nasion=eye + 0.009)
    part_mean = {k: verts[slice(*topo.parts[k])].mean(0) for k in
                 ("eye_l", "eye_r", "ear_l", "ear_r")}
    eb = verts[topo.skin_rows[names.index("eye_bottom")]]
    seam = verts[topo.skin_rows[names.index("seam_upper")]]
    return HeadFrame(
        levels=lv,
        eye_centres=np.stack([part_mean["eye_l"], part_mean["eye_r"]]),
        eye_half_width=0.0150 * eye_size,
        eye_half_height_up=lv["eye_top"] - eye,
        eye_half_height_down=eye - lv["eye_bottom"],
        mouth_half_width=float(np.abs(seam[seam[:, 2] > 0.03][:, 0]).max()) * 0.5,
        jaw_pivot=np.array([0.0, 0.5 * (lv["eye_bottom"] + lv["nose_base"]) - 0.004,
                            -0.012]),
        ear_centres=np.stack([part_mean["ear_l"], part_mean["ear_r"]]),
        nose_tip=verts[topo.skin_rows[names.index("nose_tip"), N_COLS // 2]],
        face_half_width=float(np.abs(eb[eb[:, 2] > 0.03][:, 0]).max()),
    )

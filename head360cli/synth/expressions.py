"""The 52 ARKit blendshapes of a synthetic identity, in two kinds.

- ``procedural`` (the default, what the shipped model and generator learnt): displacement
  fields anchored at the identity's own features (jaw pivot, eye centres and lid margins,
  mouth corners, brows), so identity and expression interact as in a real rig.
- ``scanned``: skin, lips and jaw move as ICT-FaceKit's scanned expressions do
  (:mod:`head360cli.synth.ict` carries them onto the template once;
  ``models/expressions.npz``), scaled to each head; the eyeballs' turns (added to ICT's
  lids that follow the gaze), the blinks and ``tongueOut`` stay the procedural ones. An
  option of ``build-model`` until it fits photos as well as the procedural kind (see
  ``docs/decisions.md``).

A face with weights ``w`` is ``neutral + sum_k w_k * delta_k``.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from head360cli.mesh.arkit52 import ARKIT52, INDEX
from head360cli.synth.fields import gauss2d, smoothstep
from head360cli.synth.sculpt import EYE_RADIUS, HeadFrame, topology

__all__ = ["EXPRESSION_KINDS", "FIELDS_FORMAT", "FROM_TEMPLATE", "JAW_OPEN_RAD",
           "blendshape_deltas", "load_fields", "procedural_deltas",
           "save_fields", "scanned_deltas", "shipped_fields"]

EXPRESSION_KINDS = ("procedural", "scanned")
"""The kinds of blendshapes :func:`blendshape_deltas` makes."""

JAW_OPEN_RAD = math.radians(17.0)
"""The procedural jaw's turn (ICT's scanned jaw turns 25 degrees)."""
FROM_TEMPLATE = ("eyeBlinkLeft", "eyeBlinkRight", "tongueOut")
"""Shapes the template makes itself: each head's lids must meet exactly; ICT has no
tongueOut."""
EYE_TURNS = ("eyeLookUpLeft", "eyeLookDownLeft", "eyeLookInLeft", "eyeLookOutLeft",
             "eyeLookUpRight", "eyeLookDownRight", "eyeLookInRight", "eyeLookOutRight")
"""Shapes whose eyeball turn the template adds to ICT's lids."""
FIELDS_FORMAT = 1


def _bump(v: np.ndarray, cx: float, cy: float, sx: float, sy: float) -> np.ndarray:
    """A Gaussian bump over the vertices' face-plane coordinates (x, y)."""
    return gauss2d(v[:, 0], v[:, 1], cx, cy, sx, sy)


def _rot_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _rot_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


class _Masks:
    """Per-vertex helpers shared by the shapes of one identity."""

    def __init__(self, v: np.ndarray, frame: HeadFrame) -> None:
        topo = topology()
        self.v = v
        nv = len(v)
        names = topo.row_names
        self.row = np.full(nv, -1)
        self.row[topo.skin_rows] = np.arange(len(names))[:, None]
        su, sl = names.index("seam_upper"), names.index("seam_lower")
        pocket = [names.index(f"pocket{k}") for k in range(5)]
        skin = self.row >= 0
        lv = frame.levels
        # Which side of the lip seam a skin vertex belongs to (pocket rows split 2/1/2).
        self.lower = skin & ((self.row >= sl) | np.isin(self.row, pocket[3:]))
        self.lower_half = np.isin(self.row, pocket[2:3])
        self.upper = skin & ~self.lower & ~self.lower_half
        # How far inside the mouth width a column is (1 in the middle, 0 at the corners).
        seam = v[topo.skin_rows[su]]
        col_taper = np.sqrt(np.clip(1 - (seam[:, 0] / frame.mouth_half_width) ** 2, 0, 1)) * (
            seam[:, 2] > 0)
        self.taper = np.zeros(nv)
        self.taper[topo.skin_rows] = col_taper[None, :]
        self.front = smoothstep(0.02, 0.05, v[:, 2])
        self.skin = skin
        part = np.zeros(nv, dtype=np.int64)
        for k, name in enumerate(topo.part_names):
            a, b = topo.parts[name]
            part[a:b] = k
        self.part = part
        self.names = topo.part_names
        self.lv = lv
        self.frame = frame
        self.seam_y = lv["seam"]

    def is_part(self, *names: str) -> np.ndarray:
        return np.isin(self.part, [self.names.index(n) for n in names])


def _jaw_weight(m: _Masks) -> np.ndarray:
    """How much each vertex follows the lower jaw (1 chin and lower lip, 0 skull)."""
    v, lv, f = m.v, m.lv, m.frame
    cheek = smoothstep(m.seam_y + 0.004, m.seam_y - 0.018, v[:, 1])  # skin stretches smoothly
    inside = m.taper
    w = np.where(m.lower, inside + (1 - inside) * cheek, 0.0)
    w = np.where(m.lower_half, 0.5 * inside + (1 - inside) * cheek, w)
    w = np.where(m.upper, (1 - inside) * cheek * (v[:, 1] < m.seam_y + 0.004), w)
    # Only in front of the jaw's hinge; the neck below the chin stretches.
    w = w * smoothstep(f.jaw_pivot[2] - 0.005, f.jaw_pivot[2] + 0.03, v[:, 2])
    w = w * smoothstep(lv["menton"] - 0.04, lv["menton"] - 0.004, v[:, 1])
    w = np.where(m.skin, w, 0.0)
    w = np.where(m.is_part("teeth_lower", "tongue"), 1.0, w)
    return w


def _left_shapes(m: _Masks, jaw_open: np.ndarray, jaw_w: np.ndarray
                 ) -> dict[str, np.ndarray]:
    """Displacements of the shapes of the subject's left side (and central ones)."""
    v, lv, f = m.v, m.lv, m.frame
    out: dict[str, np.ndarray] = {}
    front_skin = (m.front * m.skin)[:, None]
    mw = f.mouth_half_width
    corner = (mw, m.seam_y)
    lips_zone = smoothstep(mw * 1.6, mw * 0.6, np.abs(v[:, 0])) * smoothstep(
        lv["lip_bottom"] - 0.012, lv["lip_bottom"], v[:, 1]) * smoothstep(
        lv["lip_top"] + 0.012, lv["lip_top"], v[:, 1])
    mouth_region = (lips_zone * m.skin * m.front)[:, None]

    def local(cx, cy, sx, sy, d, mask=None):
        g = _bump(v, cx, cy, sx, sy)[:, None] * front_skin
        if mask is not None:
            g = g * mask[:, None]
        return g * np.asarray(d, dtype=np.float64)

    # Jaw.
    out["jawOpen"] = jaw_open
    out["jawLeft"] = jaw_w[:, None] * np.array([0.006, 0.0, 0.0])
    out["jawForward"] = jaw_w[:, None] * np.array([0.0, 0.0, 0.005])
    # Lips sealed while the jaw is open: undo the jaw's motion on the lower lip.
    lower_lip = m.lower & (v[:, 1] > lv["lip_bottom"] - 0.004)
    close_w = (np.where(lower_lip | m.lower_half, 1.0, 0.0) * np.maximum(m.taper, 0.0)
               * m.skin)
    out["mouthClose"] = -jaw_open * smoothstep(0.0, 0.3, close_w)[:, None]
    # Funnel and pucker: lips forward and rounded towards the middle.
    centre_pull = -v[:, 0:1] * np.array([[1.0, 0.0, 0.0]])
    out["mouthFunnel"] = mouth_region * (0.25 * centre_pull + np.array([0.0, 0.0, 0.006]))
    funnel_open = np.where(m.upper, 1.0, -1.0)[:, None] * np.array([0.0, 0.0025, 0.0])
    out["mouthFunnel"] += mouth_region * funnel_open * m.taper[:, None]
    out["mouthPucker"] = mouth_region * (0.38 * centre_pull + np.array([0.0, 0.0, 0.009]))
    # Whole mouth to the left.
    out["mouthLeft"] = local(0.0, m.seam_y, 0.028, 0.018, (0.007, 0.0, 0.0))
    # Corner shapes of the left side.
    out["mouthSmileLeft"] = local(*corner, 0.013, 0.013, (0.004, 0.006, -0.003)) + local(
        mw + 0.012, lv["nose_base"], 0.015, 0.012, (0.001, 0.003, 0.002))
    out["mouthFrownLeft"] = local(*corner, 0.011, 0.012, (0.001, -0.005, 0.0))
    out["mouthDimpleLeft"] = local(*corner, 0.008, 0.009, (0.002, 0.0, -0.004))
    out["mouthStretchLeft"] = local(*corner, 0.013, 0.012, (0.006, -0.002, -0.002))
    # Press: the lips on that side flatten back and squeeze towards the seam.
    out["mouthPressLeft"] = local(mw * 0.5, m.seam_y, 0.012, 0.006, (0.0, 0.0, -0.0025)) + (
        local(mw * 0.5, m.seam_y, 0.012, 0.008, (0.0, 1.0, 0.0)) * (m.seam_y - v[:, 1:2])
        * 0.35)
    out["mouthLowerDownLeft"] = local(mw * 0.45, lv["lip_bottom"], 0.012, 0.008,
                                      (0.0, -0.005, 0.0), mask=m.lower.astype(float))
    out["mouthUpperUpLeft"] = local(mw * 0.45, lv["lip_top"], 0.012, 0.007, (0.0, 0.004, 0.0),
                                    mask=m.upper.astype(float))
    # Central lip shapes.
    lower_lip_f = (m.lower & (v[:, 1] > lv["lip_bottom"] - 0.006)).astype(float)
    upper_lip_f = (m.upper & (v[:, 1] < lv["lip_top"] + 0.006)).astype(float)
    out["mouthRollLower"] = local(0.0, lv["lip_bottom"] + 0.003, mw * 0.8, 0.007,
                                  (0.0, 0.002, -0.004), mask=lower_lip_f)
    out["mouthRollUpper"] = local(0.0, lv["lip_top"] - 0.003, mw * 0.8, 0.007,
                                  (0.0, -0.002, -0.004), mask=upper_lip_f)
    out["mouthShrugLower"] = local(0.0, lv["lip_bottom"], 0.02, 0.014, (0.0, 0.004, 0.002),
                                   mask=m.lower.astype(float))
    out["mouthShrugUpper"] = local(0.0, lv["lip_top"], 0.018, 0.008, (0.0, 0.003, 0.001),
                                   mask=m.upper.astype(float))
    # Brows.
    ex = f.eye_centres[0, 0]
    out["browDownLeft"] = local(ex, lv["brow"] + 0.004, 0.015, 0.01, (-0.002, -0.005, 0.001))
    out["browInnerUp"] = local(0.014, lv["brow"] + 0.004, 0.011, 0.012, (0.0, 0.006, 0.0)) + \
        local(-0.014, lv["brow"] + 0.004, 0.011, 0.012, (0.0, 0.006, 0.0))
    out["browOuterUpLeft"] = local(ex + 0.014, lv["brow"] + 0.004, 0.013, 0.012,
                                   (0.0, 0.006, 0.0))
    # Cheeks and nose.
    normal_h = v * np.array([1.0, 0.0, 1.0])
    normal_h /= np.linalg.norm(normal_h, axis=1, keepdims=True).clip(1e-9)
    puff = sum(_bump(v, s * 0.045, m.seam_y + 0.008, 0.016, 0.016) for s in (1, -1))
    out["cheekPuff"] = (puff * m.front * m.skin)[:, None] * normal_h * 0.008
    out["cheekSquintLeft"] = local(ex + 0.006, lv["eye_bottom"] - 0.014, 0.013, 0.009,
                                   (0.0, 0.004, 0.001))
    out["noseSneerLeft"] = local(0.012, lv["nose_base"] + 0.008, 0.007, 0.008,
                                 (0.0005, 0.004, 0.0))
    # Tongue out, forward and a little down.
    tongue = m.is_part("tongue")[:, None]
    out["tongueOut"] = tongue * np.array([0.0, -0.004, 0.03])
    # Eyes.
    out.update(_eye_shapes(m, 0))
    return out


def _eye_shapes(m: _Masks, side: int) -> dict[str, np.ndarray]:
    """Lids and gaze of the left eye (side 0)."""
    v, f = m.v, m.frame
    c = f.eye_centres[side]
    hw, up, down = f.eye_half_width, f.eye_half_height_up, f.eye_half_height_down
    dx = v[:, 0] - c[0]
    u = np.clip(1 - (dx / hw) ** 2, 0, None)
    top = c[1] + up * np.sqrt(u)
    bottom = c[1] - down * np.sqrt(u)
    near_x = smoothstep(hw + 0.004, hw, np.abs(dx)) * m.skin * m.front
    inside = ((v[:, 1] < top + 0.0004) & (v[:, 1] > bottom - 0.0004)) * near_x
    above = smoothstep(top + 0.009, top, v[:, 1]) * (v[:, 1] >= top + 0.0004) * near_x
    below = smoothstep(bottom - 0.007, bottom, v[:, 1]) * (v[:, 1] <= bottom - 0.0004) * near_x
    out: dict[str, np.ndarray] = {}
    # Blink: the upper lid slides down to the lower one. Skin inside the opening and the
    # lid above it are compressed towards the lower lid line and laid on a shell just over
    # the eyeball, so the closed lid covers it; the shallow upper dent crosses it first.
    shell_r = EYE_RADIUS + 0.0012
    lid = np.maximum(inside, above)
    closed_y = bottom + (v[:, 1] - bottom) * 0.1
    closed_y = np.where(above > 0, np.minimum(v[:, 1], bottom + 0.1 * (top - bottom)
                                              + (v[:, 1] - top) * 0.5), closed_y)
    dz2 = shell_r ** 2 - dx ** 2 - (closed_y - c[1]) ** 2
    shell_z = c[2] + np.sqrt(np.clip(dz2, 0, None))
    closed = np.stack([v[:, 0], closed_y, np.maximum(np.where(inside > 0, shell_z, v[:, 2]),
                                                     shell_z)], axis=1)
    blink = lid[:, None] * (closed - v)
    out["eyeBlinkLeft"] = blink
    out["eyeSquintLeft"] = below[:, None] * np.array([0.0, 0.002, 0.001]) + (
        inside * (v[:, 1] < c[1]))[:, None] * np.array([0.0, 0.0012, 0.0])
    out["eyeWideLeft"] = above[:, None] * np.array([0.0, 0.002, 0.0]) + (
        inside * (v[:, 1] > c[1]))[:, None] * np.array([0.0, 0.0015, 0.0])
    eyeball = m.is_part("eye_l" if side == 0 else "eye_r")
    ev = v[eyeball] - c
    gaze = {
        "eyeLookUpLeft": _rot_x(-math.radians(18.0)),
        "eyeLookDownLeft": _rot_x(math.radians(22.0)),
        "eyeLookInLeft": _rot_y(-math.radians(22.0)),  # the left eye turns to -x (the nose)
        "eyeLookOutLeft": _rot_y(math.radians(22.0)),
    }
    for name, rot in gaze.items():
        d = np.zeros_like(v)
        d[eyeball] = ev @ rot.T - ev
        out[name] = d
    return out


def save_fields(fields: dict[str, Any], out: str | Path) -> str:
    """Write displacement fields ``{"deltas": (N, V, 3), "meta": {...}}`` sparsely (vertex
    ids and float16 displacements per field); returns the file's SHA-256."""
    from head360cli.io.atomic import atomic_path

    d = fields["deltas"]
    shape_ids, vert_ids = np.nonzero(np.linalg.norm(d, axis=2) > 0)
    with atomic_path(out) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, shape=shape_ids.astype(np.int16),
                            vertex=vert_ids.astype(np.int32),
                            delta=d[shape_ids, vert_ids].astype(np.float16),
                            vertices=np.int64(d.shape[1]),
                            meta=np.array(json.dumps(fields["meta"], sort_keys=True)))
    return hashlib.sha256(Path(out).read_bytes()).hexdigest()


def load_fields(path: str | Path, kind: str = "expressions") -> dict[str, Any]:
    """Read a file written by :func:`save_fields`: ``deltas (N, V, 3)`` float64 (``N``:
    52 expressions, or the meta's ``count``), meta. ``kind``: what the file must hold,
    ``expressions`` or ``identities`` (:func:`head360cli.synth.ict.build_identities`)."""
    from head360cli.errors import FileFormatError

    try:
        data = np.load(path, allow_pickle=False)
        meta = json.loads(str(data["meta"]))
        deltas = np.zeros((int(meta.get("count", len(ARKIT52))), int(data["vertices"]), 3))
        deltas[data["shape"].astype(np.int64), data["vertex"].astype(np.int64)] = \
            data["delta"].astype(np.float64)
    except (KeyError, ValueError, OSError, IndexError) as exc:
        raise FileFormatError(f"{path}: not a head360 {kind} file ({exc})") from None
    if meta.get("format") != FIELDS_FORMAT or meta.get("kind", "expressions") != kind:
        raise FileFormatError(f"{path}: expected {kind} format {FIELDS_FORMAT}, found "
                              f"{meta.get('kind', 'expressions')} format {meta.get('format')}")
    return {"deltas": deltas, "meta": meta}


@functools.lru_cache(maxsize=2)
def shipped_fields(kind: str = "expressions") -> np.ndarray:
    """The shipped fields of ``kind`` (``models/expressions.npz``: ``(52, V, 3)``;
    ``models/identities.npz``: ``(100, V, 3)``), metres on the mean head, read once."""
    from head360cli.errors import ModelNotFoundError
    from head360cli.paths import models_dir

    path = models_dir() / f"{kind}.npz"
    if not path.is_file():
        raise ModelNotFoundError(f"{kind} fields not found at {str(path)!r}; make them with "
                                 f"'head360 build-{kind} ../shared/data/ict-facekit'")
    return load_fields(path, kind)["deltas"]


def _eye_span(frame: HeadFrame) -> float:
    """Distance between the eye centres: the size the fields are scaled by."""
    return float(np.linalg.norm(frame.eye_centres[0] - frame.eye_centres[1]))


@functools.lru_cache(maxsize=1)
def _mean_eye_span() -> float:
    from head360cli.synth.identity import mean_identity
    from head360cli.synth.sculpt import build_head

    return _eye_span(build_head(mean_identity())[1])


def blendshape_deltas(verts: np.ndarray, frame: HeadFrame, kind: str = "procedural"
                      ) -> np.ndarray:
    """The 52 ARKit displacement fields of one identity, of a kind in
    :data:`EXPRESSION_KINDS`: ``(52, V, 3)`` float64 deltas in
    :data:`~head360cli.mesh.arkit52.ARKIT52` order."""
    if kind == "scanned":
        return scanned_deltas(verts, frame)
    return procedural_deltas(verts, frame)


def scanned_deltas(verts: np.ndarray, frame: HeadFrame, span: float | None = None
                   ) -> np.ndarray:
    """The shipped scanned fields scaled by the identity's eye span, with the eyeballs'
    turns, the blinks and ``tongueOut`` of its own (procedural).

    Args:
        verts: ``(V, 3)`` neutral vertices from :func:`~head360cli.synth.sculpt.build_head`.
        frame: The identity's feature frame from the same call.
        span: The head's eye span (metres), where it is not the frame's (a head that
            :mod:`head360cli.synth.scanned` moved after sculpting).

    Returns:
        ``(52, V, 3)`` float64 deltas in :data:`~head360cli.mesh.arkit52.ARKIT52` order.
    """
    own = procedural_deltas(verts, frame)
    deltas = shipped_fields("expressions") * ((span or _eye_span(frame)) / _mean_eye_span())
    for name in FROM_TEMPLATE:
        deltas[INDEX[name]] = own[INDEX[name]]
    for name in EYE_TURNS:
        deltas[INDEX[name]] += own[INDEX[name]]
    return deltas


def procedural_deltas(verts: np.ndarray, frame: HeadFrame) -> np.ndarray:
    """The template's own 52 displacement fields of one identity, anchored at its features
    (jaw pivot, eye centres and lid margins, mouth corners, brows); the left side's shapes
    are mirrored for the right. ``jawOpen`` turns the jaw by 17 degrees, eyes turn by up to
    22 degrees.

    Args:
        verts: ``(V, 3)`` neutral vertices from :func:`~head360cli.synth.sculpt.build_head`.
        frame: The identity's feature frame from the same call.

    Returns:
        ``(52, V, 3)`` float64 deltas in :data:`~head360cli.mesh.arkit52.ARKIT52` order.
    """
    topo = topology()
    m = _Masks(verts, frame)
    jaw_w = _jaw_weight(m)
    pivot = frame.jaw_pivot
    rotated = (verts - pivot) @ _rot_x(JAW_OPEN_RAD).T + pivot
    jaw_open = jaw_w[:, None] * (rotated - verts)
    left = _left_shapes(m, jaw_open, jaw_w)
    # Right side: the mirror image of the left shape, computed on the mirrored head so that
    # it acts on this identity's own right side.
    flip = np.array([-1.0, 1.0, 1.0])
    mirror = topo.mirror
    mirrored_frame = HeadFrame(
        levels=frame.levels, eye_centres=frame.eye_centres[::-1] * flip,
        eye_half_width=frame.eye_half_width, eye_half_height_up=frame.eye_half_height_up,
        eye_half_height_down=frame.eye_half_height_down,
        mouth_half_width=frame.mouth_half_width, jaw_pivot=frame.jaw_pivot * flip,
        ear_centres=frame.ear_centres[::-1] * flip, nose_tip=frame.nose_tip * flip,
        face_half_width=frame.face_half_width)
    mv = verts[mirror] * flip
    mm = _Masks(mv, mirrored_frame)
    m_jaw_w = _jaw_weight(mm)
    m_rot = (mv - mirrored_frame.jaw_pivot) @ _rot_x(JAW_OPEN_RAD).T + mirrored_frame.jaw_pivot
    right_src = _left_shapes(mm, m_jaw_w[:, None] * (m_rot - mv), m_jaw_w)
    deltas = np.zeros((len(ARKIT52), len(verts), 3))
    for name in ARKIT52:
        if name in left:
            deltas[INDEX[name]] = left[name]
        elif name.endswith("Right"):
            src = name[: -len("Right")] + "Left"
            # Shape built on the mirrored head, mapped back vertex by vertex and in x.
            deltas[INDEX[name]] = right_src[src][mirror] * flip
        elif name == "jawRight":
            deltas[INDEX[name]] = right_src["jawLeft"][mirror] * flip
        elif name == "mouthRight":
            deltas[INDEX[name]] = right_src["mouthLeft"][mirror] * flip
        else:
            raise AssertionError(f"no shape for {name}")
    return deltas


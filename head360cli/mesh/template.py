"""The head template: topology, UV atlas, named vertex regions and the 68 iBUG landmarks.

The topology comes from the procedural head (:mod:`head360cli.synth.sculpt`); regions and
landmark vertices are chosen once on the mean identity and are the same for every head,
since every head shares the topology.

Landmarks follow the iBUG 68-point scheme: 0-16 jawline (from the subject's right, which is
the image's left, round the chin to the left), 17-21 right brow, 22-26 left brow, 27-30 nose
bridge, 31-35 nose base, 36-41 right eye, 42-47 left eye, 48-59 outer lips, 60-67 inner
lips. The jawline points 0-16 are *contour* points: on a turned face the visible jaw
outline is elsewhere on the mesh, so fitting slides them along the jaw.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

__all__ = ["CONTOUR_LANDMARKS", "REGION_NAMES", "Template", "template"]

REGION_NAMES = ("scalp", "face", "nose", "lips", "mouth_interior", "ears", "neck", "eyes",
                "teeth", "tongue")
CONTOUR_LANDMARKS = tuple(range(17))


@dataclasses.dataclass(frozen=True)
class Template:
    """The shared mesh structure of every head.

    Attributes:
        faces: ``(F, 3)`` vertex ids.
        uv: ``(T, 2)`` texture coordinates; ``faces_uv`` ``(F, 3)`` indexes them.
        faces_uv: ``(F, 3)``.
        region: ``(V,)`` index into :data:`REGION_NAMES` per vertex.
        landmarks: ``(68,)`` vertex ids of the iBUG landmarks.
        contour: ids into ``landmarks`` that are contour (sliding) points.
        mirror: ``(V,)`` left/right mirror vertex of each vertex.
    """

    faces: np.ndarray
    uv: np.ndarray
    faces_uv: np.ndarray
    region: np.ndarray
    landmarks: np.ndarray
    contour: tuple[int, ...]
    mirror: np.ndarray

    def region_vertices(self, name: str) -> np.ndarray:
        """Vertex ids of a named region."""
        return np.nonzero(self.region == REGION_NAMES.index(name))[0]


def _regions(v: np.ndarray, frame, topo) -> np.ndarray:
    lv = frame.levels
    nv = len(v)
    region = np.full(nv, REGION_NAMES.index("face"))
    part = np.zeros(nv, dtype=np.int64)
    for k, name in enumerate(topo.part_names):
        a, b = topo.parts[name]
        part[a:b] = k
    for names, label in ((("eye_l", "eye_r"), "eyes"), (("ear_l", "ear_r"), "ears"),
                         (("teeth_upper", "teeth_lower"), "teeth"), (("tongue",), "tongue")):
        region[np.isin(part, [topo.part_names.index(n) for n in names])] = REGION_NAMES.index(
            label)
    skin = part == topo.part_names.index("skin")
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    row = np.full(nv, -1)
    row[topo.skin_rows] = np.arange(len(topo.row_names))[:, None]
    pocket = np.isin(row, [topo.row_names.index(f"pocket{k}") for k in range(5)])
    su = topo.skin_rows[topo.row_names.index("seam_upper")]
    seam_pos = np.zeros_like(v)
    seam_pos[topo.skin_rows] = v[su][None, :, :]
    inside = pocket & (np.linalg.norm(v - seam_pos, axis=1) > 1e-6)
    ear_z = frame.ear_centres[:, 2].mean()
    scalp = skin & ((y > lv["forehead"] + 0.012) | ((z < ear_z + 0.015) & (y > lv["eye"]))
                    | ((z < ear_z - 0.01) & (y > lv["nose_base"] - 0.01)))
    neck = skin & ((y < lv["menton"] - 0.004) | ((z < ear_z - 0.01) & (y <= lv["nose_base"]
                                                                        - 0.01)))
    mw = frame.mouth_half_width
    lips = skin & (np.abs(x) < mw * 1.05) & (y > lv["lip_bottom"] - 0.003) & (
        y < lv["lip_top"] + 0.003) & (z > 0.04)
    # The nose widens from the bridge (1 cm) to the alae (about 4 cm).
    down = np.clip((lv["nasion"] - y) / (lv["nasion"] - lv["nose_base"]), 0, 1)
    nose = skin & (np.abs(x) < 0.005 + 0.016 * down ** 1.5) & (
        y > lv["nose_base"] - 0.003) & (y < lv["nasion"]) & (z > 0.085)
    region[scalp] = REGION_NAMES.index("scalp")
    region[neck & ~scalp] = REGION_NAMES.index("neck")
    region[nose] = REGION_NAMES.index("nose")
    region[lips] = REGION_NAMES.index("lips")
    region[inside] = REGION_NAMES.index("mouth_interior")
    return region


def _landmark_targets(frame) -> list[tuple[float, float, str]]:
    """(x, y, which rows) of the 68 points on the mean head."""
    lv = frame.levels
    targets: list[tuple[float, float, str]] = []
    # Jawline: an arc from the right cheek (level with the lower lids) round the chin to the
    # left cheek; its half width is the face's width at the top of the arc.
    top = lv["eye_bottom"] - 0.006
    for k in range(17):
        ang = -np.pi / 2 + np.pi * k / 16
        targets.append((np.sin(ang) * frame.face_half_width,
                        top - (top - lv["menton"]) * np.cos(ang), "jaw"))
    ex = frame.eye_centres[0, 0]
    # Brows: right (-x) from outer to inner, then left from inner to outer.
    for k in range(5):
        u = k / 4
        targets.append((-(ex + 0.022 - 0.040 * u), lv["brow"] + 0.004 + 0.004 * np.sin(
            (1 - u) * np.pi * 0.8), "face"))
    for k in range(5):
        u = k / 4
        targets.append((ex - 0.018 + 0.040 * u, lv["brow"] + 0.004 + 0.004 * np.sin(
            u * np.pi * 0.8), "face"))
    # Nose bridge and tip, then the nose base from right to left.
    for k in range(4):
        targets.append((0.0, lv["nasion"] - (lv["nasion"] - lv["nose_tip"]) * k / 3, "nose"))
    for x in (-0.011, -0.0055, 0.0, 0.0055, 0.011):
        targets.append((x, lv["nose_base"] + 0.0015 + 0.002 * (abs(x) > 0.008), "nose"))
    # Eyes: right eye (36-41) then left eye (42-47). In the image both run from the corner
    # at the smaller x over the upper lid to the other corner and back under the lower lid.
    hw, up, down = frame.eye_half_width, frame.eye_half_height_up, frame.eye_half_height_down
    for cx in (-ex, ex):
        for a, t in ((-0.92, 0.0), (-0.35, 1.0), (0.35, 1.0), (0.92, 0.0), (0.35, -1.0),
                     (-0.35, -1.0)):
            height = up if t > 0 else down
            targets.append((cx + a * hw, lv["eye"] + t * height * np.sqrt(1 - a * a), "eye"))
    # Outer lips: 48 right corner, over the upper lip to 54, back under the lower lip.
    mw = frame.mouth_half_width
    upper = [(-1.0, 0.0), (-0.6, 0.75), (-0.22, 1.0), (0.0, 0.92), (0.22, 1.0), (0.6, 0.75),
             (1.0, 0.0)]
    lower = [(0.6, -0.8), (0.25, -1.0), (0.0, -1.0), (-0.25, -1.0), (-0.6, -0.8)]
    for a, t in upper + lower:
        y = lv["seam"] + (lv["lip_top"] - lv["seam"]) * t if t >= 0 else lv["seam"] + (
            lv["seam"] - lv["lip_bottom"]) * t
        targets.append((a * mw, y, "lips"))
    # Inner lips: 60 right corner, upper inner 61-63, 64 left corner, lower inner 65-67.
    # (The inner corners sit a little inside the outer ones, on their own vertices.)
    for a, rows in ((-0.8, "seam_upper"), (-0.4, "seam_upper"), (0.0, "seam_upper"),
                    (0.4, "seam_upper"), (0.8, "seam_upper"), (0.4, "seam_lower"),
                    (0.0, "seam_lower"), (-0.4, "seam_lower")):
        targets.append((a * mw, lv["seam"], rows))
    return targets


@functools.lru_cache(maxsize=1)
def template() -> Template:
    """The template (cached)."""
    from head360cli.synth.identity import mean_identity
    from head360cli.synth.sculpt import build_head, topology

    topo = topology()
    v, frame = build_head(mean_identity())
    region = _regions(v, frame, topo)
    skin_ids = topo.skin_rows.reshape(-1)
    row_of = np.repeat(np.arange(len(topo.row_names)), topo.skin_rows.shape[1])
    names = topo.row_names
    pocket = {names.index(f"pocket{k}") for k in range(5)}
    front = v[skin_ids, 2] > 0.0
    outer = front & np.array([r not in pocket and names[r] not in ("seam_lower",)
                              for r in row_of])
    landmarks = []
    for x, y, rows in _landmark_targets(frame):
        if rows in ("seam_upper", "seam_lower"):
            cand = front & (row_of == names.index(rows))
        elif rows == "jaw":  # the face's outline, not the neck below the chin
            cand = outer & (v[skin_ids, 1] >= frame.levels["menton"] - 1e-4)
        else:
            cand = outer
        ids = skin_ids[cand]
        d = (v[ids, 0] - x) ** 2 + (v[ids, 1] - y) ** 2
        landmarks.append(int(ids[np.argmin(d)]))
    return Template(
        faces=topo.faces, uv=topo.uv, faces_uv=topo.faces_uv, region=region,
        landmarks=np.array(landmarks, dtype=np.int64), contour=CONTOUR_LANDMARKS,
        mirror=topo.mirror,
    )

"""ICT-FaceKit's scanned expressions and identity components carried onto the head
template.

ICT-FaceKit (MIT) registers light-stage scans of real faces to one topology and gives 53
ARKit-style expressions on it. Here they become displacement fields on the template's own
vertices, once, on the mean head:

1. ICT's neutral face is brought onto the template by a similarity on 52 iBUG landmarks
   (the chin's lowest point, brows, nose, eyes, lips; the rest of the jawline is a
   silhouette on the template), then warped by a biharmonic spline so that they meet.
2. Each template skin vertex takes the displacement of its nearest ICT vertices, searched
   in position *and* in how much each point moves with the jaw and with each blink, so
   that the upper lip takes the upper lip's motion and the lower lip the lower one's even
   where the closed lips touch (likewise the lids).
   The blend is evened out over the template's skin, its closed seams welded except
   where the jaw parts them (the lips).
3. Shapes ICT splits (``browInnerUp``, ``cheekPuff``) are the sums of their halves; left
   and right shapes are made exact mirror images. The lower teeth and tongue follow the
   jaw shapes rigidly, by the motion of ICT's lower teeth. What ICT does not model is
   left to :mod:`head360cli.synth.expressions`: the eyeballs' turns and ``tongueOut``
   (ICT has none), and the blinks, which must close each head's own lids exactly.

The fields are stored in ``models/expressions.npz`` (``head360 build-expressions``) so
that the corpus is made without ICT-FaceKit's files; :mod:`head360cli.synth.expressions`
reads them and adds what the template makes itself.

ICT's 100 identity components go the same way (:func:`build_identities`, steps 1 and 2,
``models/identities.npz``, ``head360 build-identities``), with the eyeballs, lids, teeth,
tongue and ears moved rigidly; :mod:`head360cli.synth.scanned` draws heads from them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from head360cli.mesh.arkit52 import ARKIT52, INDEX, MIRROR_INDEX
from head360cli.mesh.corpora import read_ict
from head360cli.synth.expressions import FIELDS_FORMAT, FROM_TEMPLATE

__all__ = ["build_expressions", "build_identities"]

FEATURE_SCALE = 0.03
"""Metres a unit of difference in jaw or blink motion counts as when matching points: an
upper-lip point never takes a lower-lip point 1 mm away for its match."""
NEIGHBOURS = 4
"""ICT vertices each template vertex blends (inverse distance)."""
KEEP = 5e-4
"""Displacements shorter than this (metres) at weight 1 are dropped from the stored file."""
ICT_FACE = slice(0, 13294)
"""ICT's face, head and neck, and mouth socket vertices: where template skin finds its
matches."""
ICT_TEETH = slice(17039, 21451)
ICT_LANDMARKS = np.arange(8, 68)[np.r_[0, 9:60]]
"""The iBUG landmarks the alignment uses: the chin's lowest point and all inside the
jawline (the rest of the jawline is a silhouette on the template)."""
SMOOTHING = 3
"""Rounds of neighbour averaging over the template's skin that even out the blend of
matches (ICT's vertices are 1-3 mm apart, the template's 3-12 mm)."""
JAW_SHAPES = ("jawOpen", "jawForward", "jawLeft", "jawRight")
ICT_EYEBALL_L = slice(21451, 23021)
ICT_EYEBALL_R = slice(23021, 24591)
NECK_FADE = 0.04
"""Metres down the template's neck over which ICT's fields fade out: the scans' neck ends
above the template's, and its bend with the head would compete with the fit's pitch."""
LID_FADE = 0.008
"""Metres over which skin goes from moving with the eyeball (the lids, as far as the
template's own lid shapes reach) to following ICT's fields."""
EAR_ROOT = 0.006
"""Skin this close (metres) to an ear is its root, whose mean motion the ear takes."""


def _similarity(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Scale, rotation and translation taking ``src (N, 3)`` nearest to ``dst`` (Umeyama)."""
    ms, md = src.mean(0), dst.mean(0)
    a, b = src - ms, dst - md
    u, sig, vt = np.linalg.svd(b.T @ a)
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    rot = u @ d @ vt
    scale = float((sig * np.diag(d)).sum() / (a ** 2).sum())
    return scale, rot, md - scale * rot @ ms


def _place(ict: dict[str, Any], verts: np.ndarray) -> dict[str, Any]:
    """ICT's whole mesh brought onto the template head ``verts (V, 3)``: ``placed`` by the
    similarity on the inner landmarks (``to_template``, the 3x3 scale times rotation, and
    ``shift``), ``warped`` further by the biharmonic spline that makes those landmarks
    meet; both ``(V_ict, 3)``. ``landmark_error``: their mean distance before the warp."""
    from scipy.interpolate import RBFInterpolator

    from head360cli.mesh.template import template

    src = ict["neutral"][ict["landmarks"][ICT_LANDMARKS]]
    dst = verts[template().landmarks[ICT_LANDMARKS]]
    scale, rot, shift = _similarity(src, dst)
    placed = ict["neutral"] @ (scale * rot).T + shift
    moved = placed[ict["landmarks"][ICT_LANDMARKS]]
    warp = RBFInterpolator(moved, dst, kernel="linear", degree=1, smoothing=1e-6)
    return {"scale": scale, "to_template": scale * rot, "shift": shift, "placed": placed,
            "warped": warp(placed),
            "landmark_error": float(np.linalg.norm(moved - dst, axis=1).mean())}


def _mean_head_and_placement(ict_path: str | Path
                             ) -> tuple[dict[str, Any], np.ndarray, np.ndarray, dict]:
    """ICT-FaceKit's arrays (:func:`~head360cli.mesh.corpora.read_ict`), the template's
    mean head ``(V, 3)``, its procedural shapes ``(52, V, 3)`` (the motion cues of
    :func:`_matches`) and ICT placed on it (:func:`_place`)."""
    from head360cli.synth.expressions import procedural_deltas
    from head360cli.synth.identity import mean_identity
    from head360cli.synth.sculpt import build_head

    ict = read_ict(ict_path)
    verts, frame = build_head(mean_identity())
    return ict, verts, procedural_deltas(verts, frame), _place(ict, verts)


def _matches(ict: dict[str, Any], warped: np.ndarray, verts: np.ndarray, own: np.ndarray,
             ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For the template vertices ``ids``: their :data:`NEIGHBOURS` matches among ICT's face
    vertices ``warped (13294, 3)`` (indices into :data:`ICT_FACE`) and inverse-distance
    weights, both ``(len(ids), k)``. Searched in position and in jaw and blink motion
    (``own (52, V, 3)``, the template's procedural shapes), so that lips and lids that
    touch take the motion of their own side."""
    from scipy.spatial import cKDTree

    face = np.arange(ICT_FACE.start, ICT_FACE.stop)
    cues = ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight")
    ict_feat = np.concatenate([warped] + [FEATURE_SCALE * _motion(ict["deltas"], face, c)[:, None]
                                          for c in cues], 1)
    own_feat = np.concatenate([verts[ids]] + [FEATURE_SCALE * _motion(own, ids, c)[:, None]
                                               for c in cues], 1)
    dist, idx = cKDTree(ict_feat).query(own_feat, k=NEIGHBOURS)
    w = 1.0 / np.maximum(dist, 1e-5)
    return idx, w / w.sum(1, keepdims=True)


def _motion(deltas: np.ndarray, ids: np.ndarray, name: str) -> np.ndarray:
    """How far each of ``ids`` moves in shape ``name``, over the most any of them moves."""
    m = np.linalg.norm(deltas[INDEX[name]][ids], axis=1)
    return m / max(float(m.max()), 1e-9)


def _rigid(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and translation taking points ``p (N, 3)`` to ``q``."""
    rot = _similarity(p, q)[1]
    return rot, q.mean(0) - rot @ p.mean(0)


def _smooth(d: np.ndarray, ids: np.ndarray, verts: np.ndarray, faces: np.ndarray,
            jaw: np.ndarray) -> np.ndarray:
    """:data:`SMOOTHING` rounds of halfway averaging with the mesh neighbours of ``d
    (S, len(ids), 3)`` over the vertices ``ids``. The template closes its seams with
    triangles of no area between vertices at one place: those are welded (they move as
    one) unless the jaw parts them (``jaw (V, 3)``, a jaw motion: the lips' seam)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = len(ids)
    p = verts[ids]
    pairs = cKDTree(p).query_pairs(1e-6, output_type="ndarray")
    apart = np.linalg.norm(jaw[ids[pairs[:, 0]]] - jaw[ids[pairs[:, 1]]], axis=1) > 5e-4
    pairs = pairs[~apart]
    weld = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    groups, rep = connected_components(weld, directed=False)
    area = np.linalg.norm(np.cross(verts[faces[:, 1]] - verts[faces[:, 0]],
                                   verts[faces[:, 2]] - verts[faces[:, 0]]), axis=1)
    where = np.full(len(verts), -1)
    where[ids] = rep
    f = where[faces[area > 1e-10]]
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e = e[(e >= 0).all(1) & (e[:, 0] != e[:, 1])]
    adj = sp.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]],
                                               np.r_[e[:, 1], e[:, 0]])),
                        shape=(groups, groups)).tocsr()
    adj.data[:] = 1.0
    deg = np.asarray(adj.sum(1)).ravel()
    avg = sp.diags(1.0 / np.maximum(deg, 1)) @ adj
    flat = d.transpose(1, 0, 2).reshape(n, -1)
    count = np.bincount(rep, minlength=groups)[:, None]
    out = np.zeros((groups, flat.shape[1]))
    np.add.at(out, rep, flat)
    out /= count
    for _ in range(SMOOTHING):
        out = np.where(deg[:, None] > 0, 0.5 * out + 0.5 * (avg @ out), out)
    return out[rep].reshape(n, d.shape[0], 3).transpose(1, 0, 2)


def build_expressions(ict_path: str | Path) -> dict[str, Any]:
    """The 52 displacement fields on the template's mean head, from ICT-FaceKit.

    Returns:
        ``{"deltas": (52, V, 3) float64 metres (zero for :data:`FROM_TEMPLATE`),
        "meta": {...}}``, the meta with the source's SHA-256 and the alignment's residuals.
    """
    from head360cli.synth.sculpt import topology

    # 1. similarity and a biharmonic warp on the inner landmarks
    ict, verts, own, placement = _mean_head_and_placement(ict_path)
    topo = topology()
    to_template, placed = placement["to_template"], placement["placed"]
    face = np.arange(ICT_FACE.start, ICT_FACE.stop)
    warped = placement["warped"][face]
    # 2. matches in position and motion
    skin = np.concatenate([np.arange(*topo.parts[p]) for p in ("skin", "ear_l", "ear_r")])
    idx, w = _matches(ict, warped, verts, own, skin)
    deltas = np.zeros((len(ARKIT52), len(verts), 3))
    for name in ARKIT52:
        if name in FROM_TEMPLATE:
            continue
        d = ict["deltas"][INDEX[name]][face][idx]  # (S, k, 3)
        deltas[INDEX[name], skin] = np.einsum("sk,skc->sc", w, d) @ to_template.T
    deltas[:, skin] = _smooth(deltas[:, skin], skin, verts, topo.faces,
                              own[INDEX["jawOpen"]])
    # 3. lower teeth and tongue follow the jaw rigidly
    teeth = np.arange(ICT_TEETH.start, ICT_TEETH.stop)
    lower = teeth[np.linalg.norm(ict["deltas"][INDEX["jawOpen"]][teeth], axis=1) > 1e-3]
    follow = np.concatenate([np.arange(*topo.parts["teeth_lower"]),
                             np.arange(*topo.parts["tongue"])])
    jaw_angles = {}
    for name in JAW_SHAPES:
        moved = placed[lower] + ict["deltas"][INDEX[name]][lower] @ to_template.T
        r, t = _rigid(placed[lower], moved)
        deltas[INDEX[name], follow] = verts[follow] @ r.T + t - verts[follow]
        jaw_angles[name] = round(float(np.degrees(np.arccos(np.clip(
            (np.trace(r) - 1) / 2, -1, 1)))), 2)
    # ICT's halves are near mirror images, not exact ones: make each pair exact (and each
    # central shape symmetric), as the template's mirror map expects
    flip = np.array([-1.0, 1.0, 1.0])
    deltas = 0.5 * (deltas + deltas[list(MIRROR_INDEX)][:, topo.mirror] * flip)
    deltas[np.linalg.norm(deltas, axis=2) < KEEP] = 0.0
    meta = {"format": FIELDS_FORMAT, "source": "ICT-FaceKit light (MIT), ict_facekit_light_f16.npz",
            "source_sha256": ict["sha256"], "scale": round(placement["scale"], 5),
            "landmark_error_mm_before_warp": round(placement["landmark_error"] * 1000, 2),
            "jaw_rotation_degrees": jaw_angles, "from_template": list(FROM_TEMPLATE),
            "neighbours": NEIGHBOURS, "feature_scale_m": FEATURE_SCALE}
    return {"deltas": deltas, "meta": meta}


def build_identities(ict_path: str | Path) -> dict[str, Any]:
    """ICT-FaceKit's 100 identity components as displacement fields on the template's
    mean head (a coefficient of 1 is one standard deviation).

    ICT's mean face is not carried over: where its landmarks and the template's differ
    most (inner eye corners 15 mm, chin 12 mm) they mark different points, not different
    proportions. Skin takes its matches' displacement, fading out down the neck;
    eyeballs, teeth and tongue move rigidly as ICT's do, the lids with their eyeball (so
    each head's own blink still closes them), the ears with the skin at their root.

    Returns:
        ``{"deltas": (100, V, 3) float64 metres, "meta": {...}}``.
    """
    from scipy.spatial import cKDTree

    from head360cli.mesh.template import REGION_NAMES, template
    from head360cli.synth.fields import smoothstep
    from head360cli.synth.sculpt import topology

    ict, verts, own, placement = _mean_head_and_placement(ict_path)
    topo = topology()
    to_template, warped = placement["to_template"], placement["warped"]
    ict_fields = ict["identity_deltas"] @ to_template.T  # (100, V_ict, 3)
    face = np.arange(ICT_FACE.start, ICT_FACE.stop)
    skin = np.arange(*topo.parts["skin"])
    idx, w = _matches(ict, warped[face], verts, own, skin)
    fields = np.zeros((len(ict_fields), len(verts), 3))
    fields[:, skin] = np.einsum("sk,nskc->nsc", w, ict_fields[:, face][:, idx])
    fields[:, skin] = _smooth(fields[:, skin], skin, verts, topo.faces, own[INDEX["jawOpen"]])
    # the fields fade down the neck (see NECK_FADE)
    neck = template().region[skin] == REGION_NAMES.index("neck")
    below = cKDTree(verts[skin][~neck]).query(verts[skin])[0]
    fields[:, skin] *= smoothstep(NECK_FADE, 0.0, below)[None, :, None]

    def rigid(ict_ids: np.ndarray) -> np.ndarray:
        return ict_fields[:, ict_ids].mean(1)  # (100, 3)

    # eyeballs and the lids that close over them move as one
    for side, part in enumerate(("eye_l", "eye_r")):
        ids = np.arange(*topo.parts[part])
        ball = min((ICT_EYEBALL_L, ICT_EYEBALL_R), key=lambda r: np.linalg.norm(
            warped[r].mean(0) - verts[ids].mean(0)))
        move = rigid(np.arange(ball.start, ball.stop))
        lid_shapes = [INDEX[f"eye{s}{('Left', 'Right')[side]}"]
                      for s in ("Blink", "Squint", "Wide")]
        lid = skin[np.linalg.norm(own[lid_shapes][:, skin], axis=2).max(0) > 0]
        near = cKDTree(verts[lid]).query(verts[skin])[0]
        b = smoothstep(LID_FADE, 0.0, near)[None, :, None]
        fields[:, skin] = b * move[:, None] + (1 - b) * fields[:, skin]
        fields[:, ids] = move[:, None]
    # teeth and tongue as ICT's upper and lower teeth
    teeth = np.arange(ICT_TEETH.start, ICT_TEETH.stop)
    lower = np.linalg.norm(ict["deltas"][INDEX["jawOpen"]][teeth], axis=1) > 1e-3
    for parts, ict_ids in ((("teeth_upper",), teeth[~lower]),
                           (("teeth_lower", "tongue"), teeth[lower])):
        for part in parts:
            fields[:, slice(*topo.parts[part])] = rigid(ict_ids)[:, None]
    # ears as the skin at their root
    for part in ("ear_l", "ear_r"):
        ids = np.arange(*topo.parts[part])
        root = skin[cKDTree(verts[ids]).query(verts[skin])[0] < EAR_ROOT]
        fields[:, ids] = fields[:, root].mean(1)[:, None]
    meta = {"format": FIELDS_FORMAT, "kind": "identities", "count": len(fields),
            "source": "ICT-FaceKit light (MIT), ict_facekit_light_f16.npz",
            "source_sha256": ict["sha256"], "scale": round(placement["scale"], 5),
            "landmark_error_mm_before_warp": round(placement["landmark_error"] * 1000, 2),
            "neighbours": NEIGHBOURS, "neck_fade_m": NECK_FADE}
    return {"deltas": fields, "meta": meta}

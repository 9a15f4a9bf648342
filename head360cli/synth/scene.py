"""A synthetic head ready to render: identity, appearance, blendshapes, hair, textures.

:func:`make_head` derives everything about corpus head ``k`` of a split from one seed;
:func:`render_head` renders it with an expression, with or without hair, from cameras.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from head360cli.mesh.template import REGION_NAMES, template
from head360cli.synth.appearance import Appearance, paint_texture, sample_appearance
from head360cli.synth.expressions import blendshape_deltas
from head360cli.synth.hair import HAIR_COLOURS, HAIRSTYLES, HairMesh, build_hair, hair_texture
from head360cli.synth.identity import IdentityParams, sample_identity
from head360cli.synth.render import RenderOutput, render_mesh
from head360cli.synth.sculpt import HeadFrame, build_head, topology

__all__ = ["LABEL_FACE", "LABEL_HAIR", "SynthHead", "head_seed", "make_head", "prepare_render",
           "render_head"]

LABEL_HAIR = 0
LABEL_FACE = 1
LABEL_OTHER = 2
_FACE_REGIONS = ("face", "nose", "lips", "mouth_interior", "eyes", "teeth", "tongue")
SPLITS = {"train": 0, "test": 1}


def head_seed(seed: int, split: str, index: int) -> int:
    """The seed of head ``index`` of a split: train and test never share one."""
    return (seed * 2 + SPLITS[split]) * 1_000_003 + index


@dataclasses.dataclass
class SynthHead:
    """Everything needed to render one corpus head."""

    index: int
    split: str
    identity: IdentityParams
    look: Appearance
    verts: np.ndarray  # (V, 3) neutral
    frame: HeadFrame
    deltas: np.ndarray  # (52, V, 3)
    texture: np.ndarray  # (S, S, 3) skin atlas
    hair_style: int
    hair_colour: str
    hair: HairMesh
    hair_tex: np.ndarray  # (S, S, 3)


def make_head(index: int, split: str = "train", seed: int = 0, texture_size: int = 512,
              hair_style: int | None = None, hair_colour: str | None = None,
              skin_scan: str | None = None, soft_hair: bool = False) -> SynthHead:
    """Build corpus head ``index``: balanced sex (even = female), ages spread over 16-70.

    Args:
        index: Position in the split.
        split: ``"train"`` or ``"test"`` (held-out identities from other seeds).
        seed: Corpus seed.
        texture_size: Atlas size.
        hair_style: Style id (default: ``index % 30``).
        hair_colour: Colour name (default: drawn, greyer with age).
        skin_scan: Folder of a head scan whose skin detail the texture takes
            (:func:`head360cli.synth.skin.scan_skin`); ``None`` paints noise.
        soft_hair: Soft hairlines (:func:`head360cli.synth.hair.build_hair`).
    """
    s = head_seed(seed, split, index)
    rng = np.random.default_rng([s, 0x5EED])
    # Stratified ages: each block of 10 heads covers 16..70 evenly.
    age = 16.0 + (((index * 7) % 10) + rng.uniform()) * 5.4
    identity = sample_identity(s, sex=float(index % 2), age=age)
    look = sample_appearance(s, identity)
    verts, frame = build_head(identity)
    deltas = blendshape_deltas(verts, frame)
    scan = None
    if skin_scan:
        from head360cli.synth.skin import scan_skin

        scan = scan_skin(skin_scan, texture_size)
    texture = paint_texture(verts, topology(), frame, identity, look, texture_size, scan)
    style = index % len(HAIRSTYLES) if hair_style is None else hair_style
    if hair_colour is None:
        names = list(HAIR_COLOURS)
        if age > 55 and rng.random() < 0.6:
            hair_colour = "grey" if rng.random() < 0.6 else "white"
        elif look.skin_tone > 0.55:
            hair_colour = "black" if rng.random() < 0.7 else "dark brown"
        else:
            hair_colour = names[int(rng.integers(0, 8))]
    hair = build_hair(verts, frame, style, soft=soft_hair)
    hair_tex = hair_texture(HAIR_COLOURS[hair_colour], texture_size // 2, s)
    return SynthHead(index, split, identity, look, verts, frame, deltas, texture, style,
                     hair_colour, hair, hair_tex)


def _face_labels() -> np.ndarray:
    t = template()
    face_ids = [REGION_NAMES.index(r) for r in _FACE_REGIONS]
    first = t.region[t.faces[:, 0]]
    return np.where(np.isin(first, face_ids), LABEL_FACE, LABEL_OTHER)


def _render_inputs(head: SynthHead, with_hair: bool) -> dict[str, torch.Tensor]:
    """Faces, UVs, labels and the texture atlas of a head, built once and cached on it."""
    cache = head.__dict__.setdefault("_render_cache", {})
    if with_hair in cache:
        return cache[with_hair]
    topo = topology()
    faces, uv, faces_uv = topo.faces, topo.uv * np.array([0.5, 1.0]), topo.faces_uv
    labels = _face_labels()
    if "atlas" not in cache:
        tex = head.texture
        hair_tex = torch.nn.functional.interpolate(
            torch.tensor(head.hair_tex).permute(2, 0, 1)[None], size=tex.shape[:2],
            mode="bilinear", align_corners=False)
        cache["atlas"] = torch.cat([torch.tensor(tex).permute(2, 0, 1)[None], hair_tex], 3)
    hair_verts = np.zeros((0, 3))
    if with_hair and len(head.hair.faces):
        n = len(head.verts)
        hair_verts = head.hair.verts
        faces = np.concatenate([faces, head.hair.faces + n])
        faces_uv = np.concatenate([faces_uv, head.hair.faces + len(uv)])
        uv = np.concatenate([uv, head.hair.uv * np.array([0.5, 1.0]) + np.array([0.5, 0.0])])
        labels = np.concatenate([labels, np.full(len(head.hair.faces), LABEL_HAIR)])
    cache[with_hair] = {
        "faces": torch.tensor(faces), "uv": torch.tensor(uv, dtype=torch.float32),
        "faces_uv": torch.tensor(faces_uv), "labels": torch.tensor(labels),
        "hair_verts": torch.tensor(hair_verts, dtype=torch.float32),
        "groups": torch.tensor(topo.normal_groups),
    }
    if "neutral" not in cache:
        cache["neutral"] = torch.tensor(head.verts, dtype=torch.float32)
        cache["deltas"] = torch.tensor(head.deltas, dtype=torch.float32).reshape(52, -1)
    return cache[with_hair]


def prepare_render(head: SynthHead, device: torch.device | str = "cpu") -> None:
    """Build a head's render inputs (with and without hair) once, on ``device``; later
    renders run there."""
    for with_hair in (False, True):
        _render_inputs(head, with_hair)
    cache = head.__dict__["_render_cache"]
    for key, value in cache.items():
        if isinstance(value, dict):
            cache[key] = {k: v.to(device) for k, v in value.items()}
        else:
            cache[key] = value.to(device)


def render_head(head: SynthHead, weights: np.ndarray, c2w: torch.Tensor,
                intrinsics: torch.Tensor, size: int, *, with_hair: bool = True,
                samples: int = 2) -> RenderOutput:
    """Render a head with ARKit ``weights (52,)`` from cameras ``c2w (B, 4, 4)``.

    The output's ``labels`` are ``(B, 2, H, W)``: hair coverage, then face coverage.
    """
    inputs = _render_inputs(head, with_hair)
    cache = head.__dict__["_render_cache"]
    w = torch.as_tensor(np.asarray(weights, dtype=np.float32), device=cache["neutral"].device)
    verts = cache["neutral"] + (w @ cache["deltas"]).view(-1, 3)
    v = torch.cat([verts, inputs["hair_verts"]])
    b = c2w.shape[0]
    return render_mesh(
        v[None].expand(b, -1, -1), inputs["faces"], c2w, intrinsics, size,
        uv=inputs["uv"], faces_uv=inputs["faces_uv"], texture=_atlas(head),
        face_labels=inputs["labels"], label_sets=((LABEL_HAIR,), (LABEL_FACE,)),
        normal_groups=inputs["groups"], samples=samples)


def _atlas(head: SynthHead) -> torch.Tensor:
    """``(1, 3, S, 2S)`` skin atlas beside the hair strand texture (cached)."""
    return head.__dict__["_render_cache"]["atlas"]

"""The generator's configuration (stored in every checkpoint)."""

from __future__ import annotations

import dataclasses
from typing import Any

__all__ = ["GeneratorConfig"]


@dataclasses.dataclass(frozen=True)
class GeneratorConfig:
    """Sizes of the generator's parts. The defaults are the CPU configuration of the
    deferred renderer; fields marked *hex-plane* serve only ``renderer="hexplane"``."""

    renderer: str = "deferred"
    """``deferred``: meshes rasterized once per view, the neural texture read at each
    pixel's surface point and decoded there (:mod:`head360cli.model.deferred`);
    ``hexplane``: the paper's hex-planes and near-surface volume rendering
    (:mod:`head360cli.model.generator`). Weights without the field are hex-plane."""
    pixel_samples: int = 2
    """Deferred: subpixel samples per pixel (1, 2 or 4), averaged: the antialiasing."""
    shader_extra: int = 4
    """Deferred: feature channels the pixel shader passes to the image network besides
    colour."""
    code_dim: int = 64
    """Length of the texture code ``t``."""
    texture_channels: int = 16
    """Channels ``C`` of the UV neural texture."""
    texture_res: int = 256
    """Width and height of the neural texture."""
    generator_width: int = 128
    """Channels of the texture generator's first (4x4) block; halved as it upsamples."""
    planes: str = "hex"
    """*Hex-plane.* ``hex``: six orthographic feature planes (front, back, left, right,
    top, bottom); ``tri``: three (front, left, top), the tri-plane ablation."""
    plane_res: int = 96
    """*Hex-plane.* Width and height of each feature plane."""
    plane_half_size: float = 0.2
    """*Hex-plane.* Half the side (metres) of the cube the planes cover, centred on
    ``plane_centre``."""
    plane_centre: tuple[float, float, float] = (0.0, -0.04, 0.0)
    """*Hex-plane.* Centre of that cube in head coordinates."""
    surface_tau: float = 0.01
    """*Hex-plane.* Metres: how fast a plane's feature fades with distance from its
    visible surface."""
    hidden: int = 64
    """Width of the decoder MLP."""
    feature_channels: int = 16
    """*Hex-plane.* Channels rendered by the volume renderer; the first three are colour."""
    render_res: int = 64
    """Deferred: resolution of the low-resolution copies of the output (the fit's
    coarse loss); hex-plane: resolution of the volume-rendered feature image."""
    samples: int = 8
    """*Hex-plane.* Samples per ray, placed around the rasterized surface."""
    shell: float = 0.02
    """*Hex-plane.* Metres in front of and behind the rasterized surface the samples
    cover."""
    image_res: int = 256
    """Output image resolution (the RefineNet upsamples ``render_res`` to it)."""
    refine: bool = True
    """Use the RefineNet; without it the low-resolution colour is upsampled bilinearly
    (the no-RefineNet ablation)."""
    refine_width: int = 16
    """Channels of the RefineNet (hex-plane) or of the image network (deferred)."""
    hair: bool = True
    """Build the hair branch (hairstyle and colour -> hair planes on the style's mesh)."""
    hair_styles: int = 30
    """Hairstyles the hair branch knows (the corpus's style library)."""
    soft_hair: bool = False
    """The corpus it was trained on had hairstyle meshes with soft hairlines
    (:func:`head360cli.synth.hair.build_hair`); ``False``: hairlines stepped from grid
    row to grid row. The hex-plane generator renders the same at run time; the deferred
    one always renders soft hairlines (``soft_hairlines``)."""
    hair_embed_dim: int = 16
    """Length of a hairstyle's learnt embedding; the hair colour (RGB) is appended."""
    hair_texture_res: int = 64
    """Width and height of the hair neural texture (over the hair mesh's strand UVs)."""
    hair_plane_centre: tuple[float, float, float] = (0.0, -0.07, 0.0)
    """*Hex-plane.* Centre of the hair planes' cube (long hair falls below the head's cube)."""
    hair_plane_half_size: float = 0.25
    """*Hex-plane.* Half the side (metres) of the hair planes' cube."""

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> GeneratorConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"unknown generator settings {sorted(unknown)}")
        data = dict(data)
        data.setdefault("renderer", "hexplane")  # weights from before the field
        for key in ("plane_centre", "hair_plane_centre"):
            if key in data:
                data[key] = tuple(data[key])
        return cls(**data)

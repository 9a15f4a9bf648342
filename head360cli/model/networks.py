"""The generator's networks: they hold the parameters; geometry and rendering live in
:mod:`planes` and :mod:`render`."""

from __future__ import annotations

import contextlib
import dataclasses
import math
from collections.abc import Iterator
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from head360cli.geometry.rasterize import exporting
from head360cli.model.config import GeneratorConfig

__all__ = ["Decoder", "GeneratorBase", "HairTextureGenerator", "PixelShader", "RefineNet",
           "ScreenNet", "TextureGenerator", "onednn_decodes"]


class GeneratorBase(nn.Module):
    """What both generators do alike: settings changed inside a ``with`` block
    (:meth:`_override`), and networks run in :attr:`network_dtype` (:meth:`_net`)."""

    def __init__(self, cfg: GeneratorConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.network_dtype: torch.dtype | None = None
        """Run the networks of a render in this dtype under autocast (``None``:
        float32); bfloat16 on hardware that has it renders faster on a CPU. Rendering
        only, not training."""

    @contextlib.contextmanager
    def _override(self, **changes: Any) -> Iterator[None]:
        """The config changed by ``changes`` inside the block, restored after (errors
        included)."""
        own = self.cfg
        self.cfg = dataclasses.replace(own, **changes)
        try:
            yield
        finally:
            self.cfg = own

    def _net(self, net: nn.Module, *args: torch.Tensor):
        """``net(*args)``, in :attr:`network_dtype` when one is set; float32 outputs
        (a tensor or a tuple of them, as ``net`` gives)."""
        if self.network_dtype is None:
            return net(*args)
        with torch.autocast(args[0].device.type, dtype=self.network_dtype):
            out = net(*args)
        return tuple(o.float() for o in out) if isinstance(out, tuple) else out.float()


class TextureGenerator(nn.Module):
    """Texture code ``t`` -> UV neural texture: a learnt mean texture plus a convolutional
    generator's code-dependent part (4x4, doubled until ``texture_res``)."""

    def __init__(self, code_dim: int, channels: int, res: int, width: int) -> None:
        super().__init__()
        c = channels
        steps = round(math.log2(res / 4))
        if 4 * 2 ** steps != res:
            raise ValueError(f"expected texture_res = 4 x a power of two, found {res}")
        self.width = width
        self.mapping = nn.Sequential(nn.Linear(code_dim, 256), nn.LeakyReLU(0.2),
                                     nn.Linear(256, width * 16))
        blocks = []
        ch = width
        for _ in range(steps):
            out = max(ch // 2, 32)
            blocks += [nn.Upsample(scale_factor=2, mode="bilinear", align_corners=False),
                       nn.Conv2d(ch, out, 3, padding=1), nn.LeakyReLU(0.2)]
            ch = out
        self.blocks = nn.Sequential(*blocks)
        self.out = nn.Conv2d(ch, c, 3, padding=1)
        self.mean = nn.Parameter(torch.zeros(1, c, res, res))

    def forward(self, code: torch.Tensor) -> torch.Tensor:
        """``(B, code_dim)`` -> ``(B, C, R, R)``."""
        x = self.mapping(code).view(code.shape[0], self.width, 4, 4)
        return self.mean + self.out(self.blocks(x))

    @classmethod
    def from_config(cls, cfg: GeneratorConfig) -> TextureGenerator:
        """The head branch's texture generator."""
        return cls(cfg.code_dim, cfg.texture_channels, cfg.texture_res, cfg.generator_width)


class HairTextureGenerator(nn.Module):
    """Hairstyle id and hair colour -> the hair mesh's neural texture: a learnt embedding
    per style, the colour appended, through a :class:`TextureGenerator`."""

    def __init__(self, cfg: GeneratorConfig) -> None:
        super().__init__()
        self.embedding = nn.Embedding(cfg.hair_styles, cfg.hair_embed_dim)
        nn.init.normal_(self.embedding.weight, std=0.1)
        self.generator = TextureGenerator(cfg.hair_embed_dim + 3, cfg.texture_channels,
                                          cfg.hair_texture_res, cfg.generator_width // 2)

    def forward(self, style: torch.Tensor, colour: torch.Tensor) -> torch.Tensor:
        """``style (B,)`` ids and ``colour (B, 3)`` linear RGB in [0, 1] ->
        ``(B, C, R, R)``."""
        code = torch.cat([self.embedding(style), colour.to(self.embedding.weight.dtype)], -1)
        return self.generator(code)


def _softplus_unit(z: torch.Tensor) -> torch.Tensor:
    """``log(1 + exp(z))`` from operators onnxruntime computes quickly: ``relu(z) -
    log(sigmoid(|z|))`` (finite for every finite ``z``; within 6e-7 of the exact value,
    as torch's own float32 softplus)."""
    return torch.relu(z) - torch.log(torch.sigmoid(z.abs()))


def softplus(x: torch.Tensor, beta: float = 1.0) -> torch.Tensor:
    """``log(1 + exp(beta x)) / beta``. Traced for export through :func:`_softplus_unit`
    (equal to within float rounding): onnxruntime's CPU Softplus kernel was the largest
    cost of an exported frame (75 ms of 180 at 256 px, 8 samples)."""
    if not exporting():
        return F.softplus(x, beta=beta)
    if beta == 1.0:
        return _softplus_unit(x)
    return _softplus_unit(x * beta) / beta


_SOFTPLUS_TABLES: dict[torch.device, torch.Tensor] = {}
"""Per device, torch's bfloat16 softplus of every bfloat16 value (:func:`softplus_table`)."""


def softplus_table(device: torch.device | str = "cpu") -> torch.Tensor:
    """``(65536,)`` bfloat16: ``F.softplus`` of every bfloat16 value, at its bit pattern
    read as an int16 plus 32768 (made once per device, 128 KiB)."""
    device = torch.device(device)
    if device not in _SOFTPLUS_TABLES:
        bits = torch.arange(-32768, 32768, dtype=torch.int32, device=device)
        _SOFTPLUS_TABLES[device] = F.softplus(bits.to(torch.int16).view(torch.bfloat16))
    return _SOFTPLUS_TABLES[device]


_LOOKUP_CHUNK = 1 << 18
"""Values :func:`render_softplus` looks up at a time: its int32 index stays at 1 MiB and
is reused from the heap (a frame's whole 37k x 128 activations at once made an 18 MiB
index whose fresh pages cost more than the lookup: 124.5 -> 119.3 and 132.3 -> 123.7 ms
a turning-head frame on one core, alternating in one process, two runs)."""


def render_softplus(z: torch.Tensor) -> torch.Tensor:
    """``F.softplus(z)`` for renders (no gradients). A bfloat16 tensor on a CPU looks its
    values up in :func:`softplus_table`: bit for bit torch's own result, for a fifth of a
    frame's time on one core (a turning-head frame of a fitted photo, 256 px, 8 samples,
    alternating in one process: 143 -> 117 ms median; on two cores 95 -> 86), since
    torch's bfloat16 softplus works out ``exp`` and ``log1p`` for every value. Other
    dtypes and devices call ``F.softplus``."""
    if z.dtype != torch.bfloat16 or z.device.type != "cpu":
        return F.softplus(z)
    table = softplus_table(z.device)
    flat = z.reshape(-1)
    out = torch.empty_like(flat)
    for start in range(0, flat.numel(), _LOOKUP_CHUNK):
        part = slice(start, start + _LOOKUP_CHUNK)
        index = flat[part].view(torch.int16).to(torch.int32)
        index += 32768
        torch.index_select(table, 0, index, out=out[part])
    return out.view(z.shape)


_HAS_CPU_LINEAR = (torch.backends.mkldnn.is_available()
                   and hasattr(torch.ops.mkldnn, "_linear_pointwise"))
"""Whether this torch build has oneDNN's linear op (:func:`_cpu_linear`)."""
_ONEDNN_BF16 = (_HAS_CPU_LINEAR and hasattr(torch.ops.mkldnn, "_is_mkldnn_bf16_supported")
                and bool(torch.ops.mkldnn._is_mkldnn_bf16_supported()))
"""Whether oneDNN runs bfloat16 on this CPU: without AVX-512 (an AVX2-only CPU) its
linear op has no bfloat16 primitive and raises, where ``F.linear`` still computes it."""


def _cpu_linear(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """``F.linear`` for a render on a CPU (no gradients): oneDNN's linear op, a quarter to
    a third faster on 2 cores (41k points, 128 -> 128: 6.1 -> 4.6 ms in bfloat16, 15.8 ->
    11.0 in float32), the same values (bit for bit in float32; in bfloat16 a few an ulp
    apart), in autocast's dtype when autocast is on (the op has no autocast rule);
    ``F.linear`` for bfloat16 where oneDNN has none (:data:`_ONEDNN_BF16`)."""
    dtype = torch.get_autocast_dtype("cpu") if torch.is_autocast_enabled("cpu") else x.dtype
    if dtype == torch.bfloat16 and not _ONEDNN_BF16:
        return F.linear(x.to(dtype), weight.to(dtype), bias.to(dtype))
    return torch.ops.mkldnn._linear_pointwise(x.to(dtype), weight.to(dtype), bias.to(dtype),
                                              "none", [], "")


def onednn_decodes(x: torch.Tensor) -> bool:
    """Whether :class:`Decoder` runs its linear layers on ``x`` through oneDNN's op
    (:func:`_cpu_linear`): in a render (no gradients, no export) on a CPU whose torch has
    it. oneDNN keeps a primitive per input shape, so callers whose point counts change
    from call to call pad them (``generator.DECODE_BLOCK``)."""
    return (x.device.type == "cpu" and _HAS_CPU_LINEAR and not torch.is_grad_enabled()
            and not exporting())


class Softplus(nn.Module):
    """:func:`softplus` as a layer (no parameters, so checkpoints are unchanged)."""

    def __init__(self, beta: float = 1.0) -> None:
        super().__init__()
        self.beta = beta

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return softplus(x, self.beta)


class Decoder(nn.Module):
    """Point features -> density and ``feature_channels`` colour features (the first three
    are RGB in [0, 1])."""

    def __init__(self, cfg: GeneratorConfig, planes: int) -> None:
        super().__init__()
        inp = cfg.texture_channels + planes + 1
        self.net = nn.Sequential(nn.Linear(inp, cfg.hidden), Softplus(beta=10),
                                 nn.Linear(cfg.hidden, cfg.hidden), Softplus(beta=10),
                                 nn.Linear(cfg.hidden, 1 + cfg.feature_channels))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(..., D)`` -> ``(density (...), features (..., Cf))``; density per metre."""
        if exporting():
            out = self._folded(x, _softplus_unit)
        elif torch.is_grad_enabled():
            out = self.net(x)
        else:  # rendering: the folded layers save the betas' passes (a tenth of a decode)
            out = self._folded(x, render_softplus,
                               _cpu_linear if onednn_decodes(x) else F.linear)
            return self._heads(out, render_softplus)
        return self._heads(out, softplus)

    @staticmethod
    def _heads(out: torch.Tensor, unit) -> tuple[torch.Tensor, torch.Tensor]:
        """The last layer's ``out (..., 1 + Cf)`` -> density (per metre, through the
        softplus ``unit``) and colour features (RGB through a sigmoid)."""
        density = unit(out[..., 0] - 1.0) * 1000.0
        feats = torch.cat([torch.sigmoid(out[..., 1:4]), out[..., 4:]], -1)
        return density, feats

    def _folded(self, x: torch.Tensor, unit, linear=F.linear) -> torch.Tensor:
        """``self.net`` with each softplus's ``beta`` folded into the linear layers around
        it (``softplus_b(y) = softplus(b y) / b``): the same function with two fewer
        element-wise passes per hidden layer, ``unit`` computing ``softplus(z)``: for
        export :func:`_softplus_unit` (the scaled weights are constants in the graph),
        for renders without gradients torch's own values (:func:`render_softplus`; its
        threshold, ``z > 20`` -> ``z``, is the unfolded layer's ``b y > 20``), ``linear``
        the linear function (:func:`_cpu_linear` in renders on a CPU, see
        :func:`onednn_decodes`)."""
        scale = 1.0  # what the current activations must be multiplied by
        layers = list(self.net)
        for i, layer in enumerate(layers):
            if isinstance(layer, nn.Linear):
                nxt = layers[i + 1] if i + 1 < len(layers) else None
                beta = nxt.beta if isinstance(nxt, Softplus) else 1.0
                # beta (W (a / scale) + b) = (beta / scale) W a + beta b
                x = linear(x, layer.weight * (beta / scale), layer.bias * beta)
                scale = beta
            elif isinstance(layer, Softplus):
                x = unit(x)
            else:
                raise TypeError(f"expected Linear and Softplus layers, found "
                                f"{type(layer).__name__}")
        return x


class RefineNet(nn.Module):
    """Low-resolution feature image -> output image: a residual on the bilinearly upsampled
    colour and coverage."""

    def __init__(self, cfg: GeneratorConfig) -> None:
        super().__init__()
        steps = round(math.log2(cfg.image_res / cfg.render_res))
        if cfg.render_res * 2 ** steps != cfg.image_res:
            raise ValueError(f"expected image_res = render_res x a power of two, found "
                             f"{cfg.image_res} and {cfg.render_res}")
        w = cfg.refine_width
        layers: list[nn.Module] = [nn.Conv2d(cfg.feature_channels + 1, w, 3, padding=1),
                                   nn.LeakyReLU(0.2)]
        for i in range(steps):
            out = w if i < steps - 1 else max(w // 2, 8)
            layers += [nn.Upsample(scale_factor=2, mode="bilinear", align_corners=False),
                       nn.Conv2d(w, out, 3, padding=1), nn.LeakyReLU(0.2)]
            w = out
        layers.append(nn.Conv2d(w, 4, 3, padding=1))
        self.net = nn.Sequential(*layers)
        nn.init.zeros_(layers[-1].weight)
        nn.init.zeros_(layers[-1].bias)
        self.scale = 2 ** steps
        # how far (input pixels) an input pixel reaches into the output: the first
        # convolution 1 pixel; step i's bilinear upsampling 1 of its input pixels (1 / 2^i
        # of ours) and its convolution 1 of its output pixels (1 / 2^(i+1)); the last
        # convolution 1 / 2^steps (the skip's upsampling reaches 1, less than all that)
        self.reach = math.ceil(1 + sum(1.5 / 2 ** i for i in range(steps)) + 1 / 2 ** steps)
        """Input pixels around a change within which the output can change."""

    def forward(self, features: torch.Tensor, alpha: torch.Tensor, rgb: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """Features ``(B, Cf, h, w)``, coverage ``(B, 1, h, w)`` and the composited colour
        ``(B, 3, h, w)`` -> ``(rgb (B, 3, H, W), alpha (B, 1, H, W))``."""
        x = torch.cat([features, alpha], 1)
        if x.device.type == "cpu" and not exporting():
            # oneDNN's CPU convolutions run faster on channels-last input (this network at
            # 128 -> 256 px: 41 -> 31 ms on 2 cores; with its backward pass, a fit's
            # step, 112 -> 70 ms); the same function, rounded apart by 2e-5 at most.
            # The texture inversion's camera refinement turns on such rounding (its test
            # once ended 2.2, 5.2 or 6.1 degrees from the truth for it), so fits were
            # measured again with it (2026-12-01, `bench fit`)
            x = x.contiguous(memory_format=torch.channels_last)
        res = self.net(x).contiguous()
        up = F.interpolate(torch.cat([rgb, alpha], 1), scale_factor=self.scale,
                           mode="bilinear", align_corners=False)
        out = up + res
        return out[:, :3], out[:, 3:].clamp(0.0, 1.0)


SHADER_BLOCK = 32768
"""Points the pixel shader decodes at a time. Its hidden activations for a whole batch
(350k points x 64 channels: 90 MB) are larger than glibc's largest heap block, so each was
a fresh mapping whose page faults cost more than the arithmetic; in blocks of 32k points
(8 MB) the heap reuses them."""


def _mlp(net: nn.Sequential, x: torch.Tensor) -> torch.Tensor:
    """``net(x)`` for a stack of linear layers and ReLUs; in a render on a CPU (no
    gradients, see :func:`onednn_decodes`) through oneDNN's linear op, the ReLUs in
    place."""
    if not onednn_decodes(x):
        return net(x)
    for layer in net:
        x = (_cpu_linear(x, layer.weight, layer.bias) if isinstance(layer, nn.Linear)
             else x.relu_())
    return x


class PixelShader(nn.Module):
    """The deferred renderer's per-point decoder: ``colour = albedo x light + residual``.

    The albedo is the neural texture's first three channels; the light (positive, per
    channel) comes from the surface normal and view direction (head coordinates) and the
    hair flag alone, so it cannot undo the albedo; the residual and ``extra`` image
    features come from the other texture channels, never the albedo. So a photo's colours
    written into the albedo channels (a fit's projection) show as they are, under the
    studio light the network learnt, and training keeps the residual small.
    """

    def __init__(self, channels: int, hidden: int, extra: int) -> None:
        super().__init__()
        self.extra = extra
        half = max(hidden // 2, 4)
        self.light = nn.Sequential(nn.Linear(7, half), nn.ReLU(), nn.Linear(half, half),
                                   nn.ReLU(), nn.Linear(half, 3))
        self.net = nn.Sequential(nn.Linear(channels - 3 + 7, hidden), nn.ReLU(),
                                 nn.Linear(hidden, hidden), nn.ReLU(),
                                 nn.Linear(hidden, 3 + extra))
        with torch.no_grad():  # start as a plain albedo read: light 1, residual 0
            self.light[-1].weight.mul_(0.1)
            self.light[-1].bias.fill_(math.log(math.e - 1.0))
            self.net[-1].weight.mul_(0.1)
            self.net[-1].bias.zero_()

    def shading(self, normal: torch.Tensor, view: torch.Tensor, hair: torch.Tensor
                ) -> torch.Tensor:
        """``(n, 3)`` the light at points of ``normal``, ``view``, ``hair (n, 1)``."""
        x = torch.cat([normal, view, hair], -1)
        return softplus(_mlp(self.light, x))

    def forward(self, feats: torch.Tensor, normal: torch.Tensor, view: torch.Tensor,
                hair: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``feats (n, C)``, ``normal (n, 3)``, ``view (n, 3)``, ``hair (n, 1)`` ->
        ``(colour and extra features (n, 3 + extra), residual (n, 3))``."""
        x = torch.cat([feats[:, 3:], normal, view, hair], -1)
        if exporting():
            out = self.net(x)
            light = self.shading(normal, view, hair)
        else:  # blocks small enough for the allocator to reuse (see SHADER_BLOCK)
            out = torch.cat([_mlp(self.net, part) for part in x.split(SHADER_BLOCK)])
            light = torch.cat([self.shading(*parts) for parts in zip(
                normal.split(SHADER_BLOCK), view.split(SHADER_BLOCK),
                hair.split(SHADER_BLOCK), strict=True)])
        residual = out[:, :3]
        rgb = feats[:, :3] * light + residual
        return torch.cat([rgb, out[:, 3:]], -1), residual


class ScreenNet(nn.Module):
    """The deferred renderer's image network: two 3x3 convolutions over the shaded image
    (colour, extra features, coverage) that add a residual to colour and coverage, for
    edges and what one surface point alone cannot know. Its reach is two pixels, so a
    change of one texel changes the image only within two pixels of where it is seen."""

    reach = 2
    """Pixels around a change within which the output can change."""

    def __init__(self, inputs: int, width: int) -> None:
        super().__init__()
        self.net = nn.Sequential(nn.Conv2d(inputs, width, 3, padding=1), nn.ReLU(),
                                 nn.Conv2d(width, 4, 3, padding=1))
        nn.init.zeros_(self.net[-1].weight)
        nn.init.zeros_(self.net[-1].bias)

    def forward(self, image: torch.Tensor, coverage: torch.Tensor) -> tuple[torch.Tensor,
                                                                           torch.Tensor]:
        """``image (B, 3 + E, H, W)`` premultiplied by ``coverage (B, 1, H, W)`` ->
        ``(rgb on white (B, 3, H, W), alpha (B, 1, H, W))``."""
        x = torch.cat([image, coverage], 1)
        if x.device.type == "cpu" and not exporting():
            x = x.contiguous(memory_format=torch.channels_last)
        res = self.net(x).contiguous()
        alpha = (coverage + res[:, 3:]).clamp(0.0, 1.0)
        rgb = image[:, :3] + (1.0 - coverage) + res[:, :3]
        return rgb, alpha

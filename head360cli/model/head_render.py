"""Render a fitted head (its mesh, neural texture and hair) from any camera.

:class:`HeadRenderer` holds what does not change between frames: the generator, the head's
blendshapes (its neutral mesh and one delta per ARKit weight, since the bilinear model is
linear in the weights), the neural texture and the hair planes. A frame only recomputes
what an expression or a camera changes: the mesh (one small matrix product), its hex-planes
and the volume render. The turntable, the fit preview, views, animation and mesh export
build on it.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Iterator
from typing import Any

import numpy as np
import torch

__all__ = ["REUSE_TOL", "HeadRenderer", "check_frame_inputs", "to_uint8"]

REUSE_TOL = 1e-3
"""Default tolerance of reusing decoded points between frames seen by a still camera (see
:class:`~head360cli.model.reuse.DecodeReuse`): on the fitted astronaut driven by a Live
Link Face capture, 18 to 21 % of the points were decoded per frame and the frames stayed
within 4.6e-4 of those decoded afresh (tol 1e-4: 36 % decoded, equal to 1e-6)."""


def to_uint8(rgb: torch.Tensor) -> np.ndarray:
    """``(B, 3, H, W)`` in [0, 1] -> ``(B, H, W, 3)`` uint8."""
    return (rgb.clamp(0, 1) * 255).round().byte().permute(0, 2, 3, 1).cpu().numpy()


def check_frame_inputs(c2w, weights, intrinsics) -> tuple[torch.Tensor, np.ndarray,
                                                             torch.Tensor]:
    """Check what :meth:`HeadRenderer.frames` renders: cameras ``(N, 4, 4)``, ARKit
    weights ``(N, 52)`` and intrinsics ``(3, 3)``, all finite (tensors or arrays).

    Returns:
        ``c2w`` and ``intrinsics`` as float32 tensors (on their own device), ``weights`` as
        a float32 array.

    Raises:
        ValueError: Another shape, another number of weights than of cameras, or a value
            that is not finite; the message says which, expected against found.
    """
    c2w = torch.as_tensor(c2w, dtype=torch.float32)
    intrinsics = torch.as_tensor(intrinsics, dtype=torch.float32)
    weights = np.asarray(weights, np.float32)
    if c2w.ndim != 3 or c2w.shape[1:] != (4, 4):
        raise ValueError(f"expected cameras of shape (N, 4, 4), found {tuple(c2w.shape)}")
    if weights.shape != (len(c2w), 52):
        raise ValueError(f"expected ARKit weights of shape ({len(c2w)}, 52), one row per "
                         f"camera, found {weights.shape}")
    if intrinsics.shape != (3, 3):
        raise ValueError(f"expected intrinsics of shape (3, 3), found "
                         f"{tuple(intrinsics.shape)}")
    for name, values in (("cameras", c2w), ("intrinsics", intrinsics),
                         ("ARKit weights", torch.from_numpy(weights))):
        if not bool(torch.isfinite(values).all()):
            raise ValueError(f"expected finite {name}, found NaN or infinity")
    return c2w, weights, intrinsics


class HeadRenderer:
    """A head ready to render.

    Args:
        gen: The generator.
        shape: ``(K,)`` identity code of the bilinear model.
        texture: ``(C, R, R)`` neural texture.
        hair_style: Hairstyle id (0 = bald).
        hair_colour: ``(3,)`` linear RGB.
        expression: ``(52,)`` the head's own ARKit weights (a fit's, the photo's): used
            as they are when a render call gives none; weights a call gives drive the
            head from its own eyes (:meth:`drive`).
        samples: Samples per pixel (1, 2 or 4) of a deferred generator, per ray of a
            hex-plane one (default: the generator's own).
        size: Output image size (default: the generator's own, 256).
        precision: ``"fp32"``, ``"bf16"`` (decoders and RefineNet in bfloat16), or
            ``"auto"``: bf16 where the hardware has it (:func:`~head360cli.devices.
            fast_bfloat16`), else fp32.
        reuse: Tolerance of frame-to-frame reuse of decoded points when frames are
            rendered one by one by a still camera (an animation without head pose): a
            point whose decoder input moved by at most this keeps its last output (a
            moving camera reuses only the head planes' still triangles, which gives
            the same planes). ``None`` decodes every point of every frame and reuses
            nothing.
        hair_offset: ``(3,)`` metres, in the head's frame, that the hair is moved by
            (a head file's ``hair_offset``; default none).
        hair_scale: ``(WARP_BINS,)`` the fitted style's thickness by direction (a head
            file's ``hair_scale``, :func:`~head360cli.synth.hair.warp_hair`; default
            none). It is the fitted style's: another style put on by :meth:`set_hair`
            wears its own shape.
        hair_end_shift: Metres the fitted style's ends at the sides and back are moved
            down (negative: up; a head file's ``hair_end_shift``, default 0); the fitted
            style's, as ``hair_scale``.
        hair_detail: ``(A, A, 3)`` the hair's albedo over its colour in strand
            coordinates (a head file's ``hair_detail``,
            :mod:`~head360cli.fitting.hair_texture`): the photo's strands, worn by every
            style, recoloured by the hair colour; default none (the generator's own
            strand texture).
        lid_change: ``(C, R, R)`` the texture's change with both eyes closed
            (:func:`~head360cli.fitting.lids.close_lids`); a frame's texture adds the part
            on each eye's lid texels as far as that eye closes beyond the head's own
            ``expression`` (the photo's, which the texture was fitted to): for a driving
            ``eyeBlink`` weight ``b``, ``b / 0.6`` of it, all of it from 0.6 on
            (:func:`~head360cli.io.headfile.lid_amounts`). ``None``: the texture is the
            same in every frame.
        colour_gain: ``(3,)`` the photo's light (a head file's ``colour_gain``): the
            head's pixels are scaled by it per channel, the backdrop stays white
            (:func:`~head360cli.model.render.lit`). ``None``: none.
    """

    def __init__(self, gen, shape: np.ndarray, texture: torch.Tensor, hair_style: int,
                 hair_colour: np.ndarray, expression: np.ndarray | None = None,
                 samples: int | None = None, size: int | None = None,
                 precision: str = "auto", reuse: float | None = REUSE_TOL,
                 hair_offset: np.ndarray | None = None,
                 hair_scale: np.ndarray | None = None,
                 hair_end_shift: float | np.ndarray | None = None,
                 hair_detail: np.ndarray | None = None,
                 lid_change: torch.Tensor | np.ndarray | None = None,
                 colour_gain: np.ndarray | torch.Tensor | None = None) -> None:
        from head360cli.devices import fast_bfloat16
        from head360cli.mesh.bilinear import load_bilinear

        if precision not in ("auto", "fp32", "bf16"):
            raise ValueError(f"expected precision auto, fp32 or bf16, found {precision!r}")
        self.gen = gen
        deferred = gen.kind == "deferred"
        if deferred and samples is not None and samples not in (1, 2, 4):
            raise ValueError(f"expected 1, 2 or 4 samples a pixel or None, found {samples!r}")
        if samples is not None and not (isinstance(samples, int | np.integer) and samples >= 1):
            raise ValueError(f"expected samples per ray >= 1 or None, found {samples!r}")
        own = gen.cfg.pixel_samples if deferred else gen.cfg.samples
        self.samples = own if samples is None else int(samples)
        self.size = gen.cfg.image_res if size is None else size
        gen.image_size(self.size)  # raises ValueError now for a size it cannot make
        self.device = next(gen.parameters()).device
        if precision == "auto":
            precision = "bf16" if fast_bfloat16(self.device) else "fp32"
        self.precision = precision
        if reuse is not None and not reuse >= 0:
            raise ValueError(f"expected a reuse tolerance >= 0 or None, found {reuse}")
        self.reuse = reuse
        self.model = load_bilinear()
        self.shape = np.asarray(shape, np.float64)
        self.expression = (np.zeros(52) if expression is None
                           else np.asarray(expression, np.float64))
        self.neutral, deltas = self.model.deltas(self.shape)
        self.deltas = deltas
        """``(52, V, 3)`` float64: the mesh moves by ``w @ deltas`` for ARKit weights w."""
        self._base = torch.tensor(self.neutral, dtype=torch.float32, device=self.device)
        self._deltas = torch.tensor(deltas.reshape(52, -1), dtype=torch.float32,
                                    device=self.device)
        self._still_vertices = torch.as_tensor(~np.any(deltas != 0, axis=(0, 2)),
                                               device=self.device)
        # channels last: the deferred generator reads its texels row by row (a view)
        self.texture = texture.to(self.device)[None].contiguous(
            memory_format=torch.channels_last)
        self.last_reuse = None
        """The :class:`~head360cli.model.reuse.DecodeReuse` of the latest :meth:`frames`
        (its counts of points decoded and asked for), ``None`` if it reused nothing."""
        self.runner = None
        """A frame function that renders instead of the torch generator (see
        :meth:`use_runner`), or ``None``."""
        self.hair_offset = (np.zeros(3) if hair_offset is None
                            else np.asarray(hair_offset, np.float64))
        if self.hair_offset.shape != (3,) or not np.isfinite(self.hair_offset).all():
            raise ValueError("expected a hair offset of 3 finite numbers (metres), found "
                             f"{np.asarray(hair_offset).tolist()}")
        """``(3,)`` metres every hairstyle this head wears is moved by (its fit's
        placement, :func:`head360cli.fitting.hair_class.place_hair`)."""
        from head360cli.synth.hair import MAX_END_SHIFT, WARP_BINS

        self.hair_scale = None
        """``(WARP_BINS,)`` the thickness by direction of the style worn, or ``None``."""
        if hair_scale is not None:
            scale = np.asarray(hair_scale, np.float64)
            if scale.shape != (WARP_BINS,) or not (np.isfinite(scale) & (scale > 0)).all():
                raise ValueError(f"expected a hair scale of {WARP_BINS} positive finite "
                                 f"numbers, found shape {scale.shape}")
            self.hair_scale = scale
        shift = 0.0 if hair_end_shift is None else np.asarray(hair_end_shift, np.float64)
        if np.shape(shift) != () or not np.isfinite(shift) or abs(float(shift)) > MAX_END_SHIFT:
            raise ValueError(f"expected a hair end shift of one number within {MAX_END_SHIFT} "
                             f"m, found {np.asarray(hair_end_shift).tolist()}")
        self.hair_end_shift = float(shift)
        """Metres the fitted style's ends are moved down (negative: up)."""
        self._scaled_style = int(hair_style)
        self.hair_detail = None
        """``(3, A, A)`` tensor, the hair's albedo over its colour, or ``None``."""
        if hair_detail is not None:
            self.hair_detail = self._detail(hair_detail)
        self.colour_gain = None
        """``(1, 3, 1, 1)`` the photo's light on the head's pixels, or ``None``."""
        if colour_gain is not None:
            gain = (colour_gain.detach().cpu().double().numpy() if torch.is_tensor(colour_gain)
                    else np.asarray(colour_gain, np.float64))
            if gain.shape != (3,) or not np.isfinite(gain).all() or (gain <= 0).any():
                raise ValueError("expected a colour gain of 3 positive finite numbers, found "
                                 f"{gain.tolist()}")
            if not np.allclose(gain, 1.0, rtol=0, atol=1e-6):
                self.colour_gain = torch.tensor(gain, dtype=torch.float32,
                                                device=self.device).view(1, 3, 1, 1)
        self.lids = None
        """``(2, C, R, R)``: the lid change on the left and on the right eye's texels,
        or ``None``."""
        if lid_change is not None:
            from head360cli.mesh.eyelids import eye_texels

            # a fit hands over its tensor, on its device (numpy cannot read a GPU's)
            change = (lid_change.detach() if torch.is_tensor(lid_change)
                      else torch.as_tensor(np.asarray(lid_change, np.float32)))
            change = change.to(self.device, torch.float32)
            if change.shape != self.texture.shape[1:]:
                raise ValueError(f"expected a lid change shaped like the texture "
                                 f"{tuple(self.texture.shape[1:])}, found "
                                 f"{tuple(change.shape)}")
            sides = torch.as_tensor(np.stack(eye_texels(self.model, self.shape,
                                                        change.shape[-1])),
                                    device=self.device)
            self.lids = change[None] * sides[:, None].to(change.dtype)
        from head360cli.mesh.arkit52 import INDEX

        self.blink_index = [INDEX["eyeBlinkLeft"], INDEX["eyeBlinkRight"]]
        """Where eyeBlinkLeft and eyeBlinkRight are among the 52 weights."""
        self.lid_from = self.expression[self.blink_index].astype(np.float32)
        """``(2,)`` the own expression's eyeBlinkLeft / Right, from which the lid change
        comes in (:func:`~head360cli.io.headfile.lid_amounts`): added to a photo's
        half-closed eyes from 0 on, it darkened their lids and cost the bench's real
        photos 0.6 (fast) and 1.5 dB (quality) of face PSNR at the input view."""
        self.set_hair(hair_style, hair_colour)

    def use_runner(self, runner) -> None:
        """Render frames with ``runner`` instead of the torch generator: a callable
        ``runner(verts (1, V, 3), texture (1, C, R, R), c2w (1, 4, 4), intrinsics
        (1, 3, 3)[, hair_verts (1, H, 3), hair_faces (G, 3), hair_planes])`` of numpy
        arrays returning ``rgb (1, 3, S, S)`` in [0, 1], such as
        :class:`~head360cli.export.onnx.OnnxFrameRunner`. Its image size must be this
        renderer's (``runner.size``). The meshes still come from :meth:`vertices`, so both
        backends see the same input. A head with a light of its own (``colour_gain``)
        needs the coverage too: ``runner.frame(...)`` returning ``(rgb, alpha (1, 1, S,
        S))``, as the runner's ``has_alpha`` says.

        Raises:
            ValueError: A runner for another image size.
            FileFormatError: This head has a light and the runner gives no alpha.
        """
        size = getattr(runner, "size", self.size)
        if size != self.size:
            raise ValueError(f"expected a runner for {self.size} px images, found {size}")
        if self.colour_gain is not None and not getattr(runner, "has_alpha", False):
            from head360cli.errors import FileFormatError
            from head360cli.export.onnx import NO_ALPHA

            raise FileFormatError(NO_ALPHA)
        self.runner = runner

    def _detail(self, hair_detail: np.ndarray) -> torch.Tensor:
        detail = np.asarray(hair_detail, np.float32)
        if detail.ndim != 3 or detail.shape[2] != 3 or detail.shape[0] != detail.shape[1] \
                or not (np.isfinite(detail) & (detail >= 0)).all():
            raise ValueError("expected a hair detail of (A, A, 3) finite numbers >= 0, "
                             f"found shape {detail.shape}")
        return torch.tensor(detail.transpose(2, 0, 1).copy(), device=self.device)

    def set_hair_detail(self, hair_detail: np.ndarray | None) -> None:
        """Wear the hair detail ``(A, A, 3)`` (see the class's ``hair_detail``), or
        ``None``: the generator's own strands."""
        self.hair_detail = None if hair_detail is None else self._detail(hair_detail)
        if self.hair is None:
            return
        # the same mesh, its texture made again (building the mesh took 30 ms)
        with torch.no_grad():
            self.hair = self.gen.prepare_hair(dataclasses.replace(
                self.hair, planes=None,
                detail=None if self.hair_detail is None else [self.hair_detail]))

    def set_hair(self, hair_style: int, hair_colour: np.ndarray) -> None:
        """Put on another hairstyle and colour (its planes are made once, here); the
        fitted style keeps its fitted thickness, another style wears its own."""
        from head360cli.model.generator import hair_for

        self.hair_style = int(hair_style)
        self.hair_colour = np.asarray(hair_colour, np.float64).reshape(3)
        self.hair = None
        if self.gen.cfg.hair:
            own = self.hair_style == self._scaled_style
            scale = self.hair_scale if own else None
            hair = hair_for(self.neutral, [self.hair_style], self.hair_colour[None],
                            self.hair_offset[None], soft=self.gen.soft_hairlines,
                            scales=None if scale is None else scale[None],
                            end_shifts=[self.hair_end_shift if own else 0.0])
            if self.hair_detail is not None:
                hair = dataclasses.replace(hair, detail=[self.hair_detail])
            if hair.meshes[0] is not None:
                with torch.no_grad():
                    self.hair = self.gen.prepare_hair(hair.to(self.device))

    def with_hair(self, hair_style: int, hair_colour: np.ndarray) -> HeadRenderer:
        """A copy wearing another hairstyle (mesh, texture and generator are shared)."""
        other = copy.copy(self)
        other.set_hair(hair_style, hair_colour)
        return other

    def drive(self, weights: np.ndarray) -> np.ndarray:
        """The weights ``(B, 52)`` the mesh takes for driving ARKit weights ``(B, 52)``
        (a stream's frames, an ``--expr``): the stream's, with each eye resting at the
        head's own openness and closing from there as the stream blinks
        (:func:`~head360cli.io.headfile.driven_weights`; unchanged for a head whose
        own eyes are open as the template's)."""
        from head360cli.io.headfile import driven_weights

        return driven_weights(weights, self.expression)

    def driven_deltas(self) -> np.ndarray:
        """``(52, V, 3)`` float64: how the mesh moves per unit of each driving weight
        from its mesh at driving weights 0 (``vertices(np.zeros(52))``), the morph
        targets of an exported mesh. For a head whose own eyes are open as the
        template's these are :attr:`deltas`; otherwise an eye's blink target also takes
        out the head's own blink, squint and widening as it closes
        (:func:`~head360cli.io.headfile.driven_weights` is linear in each weight, up
        to its cap at 1), so a full blink ends at the closed eye."""
        from head360cli.io.headfile import driven_weights

        rest = driven_weights(np.zeros(52), self.expression)[0].astype(np.float64)
        per_unit = driven_weights(np.eye(52), self.expression).astype(np.float64) - rest
        return np.tensordot(per_unit, self.deltas, 1)

    def textures(self, weights: np.ndarray) -> torch.Tensor:
        """Neural textures ``(B, C, R, R)`` of frames driven by ARKit weights ``(B, 52)``
        (see :meth:`drive`): the texture, plus the lid change as far as each eye is
        closed beyond the head's own expression."""
        return self._textures(self.drive(weights))

    def _textures(self, weights: np.ndarray) -> torch.Tensor:
        """:meth:`textures` of the mesh's own weights (already driven)."""
        w = self._lid_amounts(weights)
        if w is None:
            return self.texture.expand(len(weights), -1, -1, -1)
        w = torch.as_tensor(w, device=self.device)
        return self.texture + torch.einsum("be,echw->bchw", w, self.lids)

    def _lid_amounts(self, weights: np.ndarray) -> np.ndarray | None:
        """``(B, 2)`` how much of each eye's lid change frames with weights ``(B, 52)``
        show, or ``None`` when none shows any (or the head has no lid change)."""
        if self.lids is None:
            return None
        from head360cli.io.headfile import lid_amounts

        w = lid_amounts(np.asarray(weights, np.float32)[:, self.blink_index], self.lid_from)
        return w if bool((w > 0).any()) else None

    def vertices(self, expression: np.ndarray | torch.Tensor | None = None) -> torch.Tensor:
        """Meshes ``(B, V, 3)`` for driving ARKit weights ``(B, 52)`` (see :meth:`drive`;
        or ``(V, 3)`` for one ``(52,)``; default: the head's own expression)."""
        if expression is None:
            return self._vertices(self.expression)
        w = np.asarray(expression.cpu() if torch.is_tensor(expression) else expression,
                       np.float32)
        out = self._vertices(self.drive(w.reshape(-1, 52)))
        return out[0] if w.ndim == 1 else out

    def _vertices(self, expression: np.ndarray) -> torch.Tensor:
        """:meth:`vertices` of the mesh's own weights (already driven)."""
        w = torch.as_tensor(np.asarray(expression, np.float32), device=self.device)
        one = w.dim() == 1
        v = self._base.reshape(1, -1) + w.reshape(-1, 52) @ self._deltas
        v = v.reshape(-1, *self._base.shape)
        return v[0] if one else v

    @torch.no_grad()
    def render(self, c2w: torch.Tensor, intrinsics: torch.Tensor,
               expression: np.ndarray | None = None, hair: bool = True,
               batch: int | None = None, alpha: bool = False, hair_alpha: bool = False
               ) -> torch.Tensor | tuple[torch.Tensor, ...]:
        """Views ``(B, 3, H, W)`` in [0, 1] on white from cameras ``c2w (B, 4, 4)`` with
        ``intrinsics (3, 3)`` for ``self.size`` images, ``batch`` at a time.
        ``expression``: ``(52,)`` for every view or ``(B, 52)``, one per view. With
        ``alpha``, also the head's coverage ``(B, 1, H, W)`` in [0, 1]; with
        ``hair_alpha`` (torch generators only), after it the share of each pixel where
        the hair is the nearest surface, ``(B, 1, H, W)``."""
        if expression is not None and np.ndim(expression) == 2:
            weights = np.asarray(expression)
        else:
            w = self.expression if expression is None else np.asarray(expression)
            weights = np.broadcast_to(w, (len(c2w), 52))
        alpha = alpha or hair_alpha  # the hair's coverage comes after the head's
        out = list(self.frames(c2w, weights, intrinsics, hair, batch, uint8=False,
                               drive=expression is not None, alpha=alpha,
                               hair_alpha=hair_alpha))
        if not alpha:
            return torch.cat([torch.as_tensor(f) for f in out])
        return tuple(torch.cat([torch.as_tensor(part[j]) for part in out])
                     for j in range(len(out[0])))

    @torch.no_grad()
    def frames(self, c2w: torch.Tensor, weights: np.ndarray, intrinsics: torch.Tensor,
               hair: bool = True, batch: int | None = None, uint8: bool = True,
               drive: bool = True, alpha: bool = False, hair_alpha: bool = False
               ) -> Iterator[Any]:
        """Render frame after frame (an animation): camera ``c2w[i] (4, 4)`` and ARKit
        weights ``weights[i] (52,)`` (driving weights, see :meth:`drive`; with
        ``drive=False`` the mesh's own), ``batch`` frames per generator call (default: 1 on
        CPU, where larger batches measured slower; 32 on a GPU, 2.3x the frames/s of 8
        with hair on an H100). One frame at a time, the head planes' still triangles
        are drawn once, and with one camera for all decoded points are reused between
        frames (see ``reuse``).

        Yields:
            Per batch, ``(b, H, W, 3)`` uint8 frames (or ``(b, 3, H, W)`` float tensors in
            [0, 1] with ``uint8=False``); with ``alpha``, pairs of float frames and the
            head's coverage ``(b, 1, H, W)`` in [0, 1]; with ``hair_alpha`` too (torch
            generators only), triples that add the hair's. Nothing is kept between batches,
            so memory does not grow with the number of frames.

        Raises:
            ValueError: The cameras, weights or intrinsics are not of those shapes, not
                as many weights as cameras, or not finite (on the first frame asked for);
                the hair's coverage asked of an exported graph.
        """
        c2w, weights, intrinsics = check_frame_inputs(c2w, weights, intrinsics)
        if hair_alpha and self.runner is not None:
            raise ValueError("expected a torch generator for the hair's coverage, found an "
                             "exported graph")
        k = intrinsics.to(self.device)
        batch = batch or (1 if self.device.type == "cpu" else 32)
        if drive:
            weights = self.drive(weights)
        own_dtype = self.gen.network_dtype
        self.gen.network_dtype = torch.bfloat16 if self.precision == "bf16" else None
        samples = (self.gen.pixel_samples if self.gen.kind == "deferred"
                   else self.gen.samples_per_ray)
        with samples(self.samples), self.gen.image_size(
                None if self.size == self.gen.cfg.image_res else self.size):
            try:
                yield from self._frames(c2w, weights, k, hair, batch, uint8, alpha,
                                        hair_alpha)
            finally:
                self.gen.network_dtype = own_dtype

    def _runner_frames(self, c2w, weights, k, hair, uint8, with_alpha):
        from head360cli.model.render import lit

        extra = ()
        if hair and self.hair is not None:
            hv, hf, huv = self.hair.meshes[0]
            extra = (hv[None].cpu().numpy(), hf.cpu().numpy(),
                     self.hair.planes[0].detach().cpu().numpy())
            if self.gen.kind == "deferred":
                extra += (huv[None].cpu().numpy(),)
        kk = k.reshape(1, 3, 3).cpu().numpy()
        plain = self.texture.detach().cpu().numpy()  # copied once: most frames use it
        for i in range(len(c2w)):
            w = np.asarray(weights[i:i + 1], np.float32)
            verts = self._vertices(w).cpu().numpy()
            tex = plain if self._lid_amounts(w) is None else \
                self._textures(w).detach().cpu().numpy()
            if self.colour_gain is None and not with_alpha:
                out = torch.from_numpy(self.runner(verts, tex, c2w[i:i + 1].cpu().numpy(), kk,
                                                   *extra))
            else:
                rgb, alpha = self.runner.frame(verts, tex, c2w[i:i + 1].cpu().numpy(), kk,
                                               *extra)
                out = torch.from_numpy(rgb)
                if self.colour_gain is not None:
                    out = lit(out, torch.from_numpy(alpha), self.colour_gain.cpu()).clamp(0, 1)
            if with_alpha:
                if alpha is None:
                    raise ValueError("expected a graph with an alpha output for the head's "
                                     "coverage, found one without (export it again)")
                yield out, torch.from_numpy(alpha).clamp(0, 1)
            else:
                yield to_uint8(out) if uint8 else out

    def _frames(self, c2w, weights, k, hair, batch, uint8, with_alpha, with_hair_alpha):
        if self.runner is not None:
            yield from self._runner_frames(c2w, weights, k, hair, uint8, with_alpha)
            return
        from head360cli.model.render import lit
        from head360cli.model.reuse import DecodeReuse

        moves = not bool((c2w == c2w[:1]).all())
        reuse = (DecodeReuse(self.reuse, self._still_vertices, camera_moves=moves)
                 if self.reuse is not None and batch == 1 and len(c2w) > 1
                 and self.gen.kind == "hexplane" else None)
        self.last_reuse = reuse
        if self.gen.kind == "deferred" and batch == 1 and len(c2w) > 1 and not moves:
            # a still camera: the deferred generator draws what no frame moves once
            reuse = {"still_faces": self._still_vertices[self.gen.faces].all(1)}
        for i in range(0, len(c2w), batch):
            cams = c2w[i:i + batch].to(self.device)
            n = len(cams)
            w = np.asarray(weights[i:i + n], np.float32)
            verts = self._vertices(w)
            h = self.hair.repeat(n) if hair and self.hair is not None else None
            res = self.gen(verts, cams, k, texture=self._textures(w), hair=h, reuse=reuse)
            out = res["rgb"].clamp(0, 1)  # RefineNet may overshoot
            if self.colour_gain is not None:  # as the exported graphs' runner does
                out = lit(out, res["alpha"], self.colour_gain.to(out.dtype)).clamp(0, 1)
            if with_hair_alpha:
                yield (out.cpu(), res["alpha"].clamp(0, 1).cpu(),
                       res["hair_alpha"].clamp(0, 1).cpu())
            elif with_alpha:
                yield out.cpu(), res["alpha"].clamp(0, 1).cpu()
            else:
                yield to_uint8(out) if uint8 else out.cpu()

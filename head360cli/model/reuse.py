"""Reuse of one frame's work in the next frame of an animation.

With a still camera, most of a head does not change between frames of an expression
stream: the back of the head, the hair, much of the face. The points there reach the
decoders with the same input features as in the frame before, so their density and colour
can be taken from that frame instead of being decoded again. :class:`DecodeReuse` keeps,
per decoder and per sample slot (ray index x samples + sample), the input last decoded
there and its output, and decodes only the points whose input moved by more than ``tol``
since. The cached output always belongs to the input it is compared with, so small
changes cannot pile up over frames: every point's input is within ``tol`` of the one its
output was decoded from.

It also keeps, for the same camera, the RefineNet's last output (recomputed on a crop
around the pixels whose input changed, :meth:`DecodeReuse.refine`), results that depend
only on still inputs such as the hair's screen depth (:meth:`DecodeReuse.kept`), and the
depth tests of the triangles no expression moves (drawn once, the others drawn over
them each frame). A moving camera keeps the last of these for the head's planes, which
do not depend on the camera, and the RefineNet's output where its input did not change
(the empty background around the head).

Holds tensors, no parameters; the generator consults it when one is passed to
:meth:`~head360cli.model.generator.Generator.forward`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch

__all__ = ["CROP_GRID", "DecodeReuse"]

CROP_GRID = 16
"""The RefineNet's crops start and end on multiples of this many input pixels (or at the
image's edges)."""


class _Slot:
    """What one decoder produced at each sample slot (inputs NaN: never decoded)."""

    def __init__(self, size: int, inputs: int, outputs: int, like: torch.Tensor) -> None:
        self.size = size
        self.inputs = torch.full((size, inputs), float("nan"), dtype=like.dtype,
                                 device=like.device)
        self.density = torch.zeros(size, dtype=like.dtype, device=like.device)
        self.colour = torch.zeros(size, outputs, dtype=like.dtype, device=like.device)


class DecodeReuse:
    """What a frame leaves for the next frame of one head, seen by one camera (or by a
    moving one, ``camera_moves``).

    Args:
        tol: Largest change of any input feature (absolute) for which a point keeps its
            previous output; 0 reuses only inputs equal to the last decoded ones.
        still_vertices: Optional ``(V,)`` bool, the vertices no expression moves.
        camera_moves: The camera changes from frame to frame (an animation with the
            stream's head pose): only what does not depend on it is kept, the depth
            test of the head planes' still triangles and the RefineNet's output where
            its input is unchanged (the RefineNet runs on a crop around the head, two
            thirds of the image on a fitted head at 256 px: 24.1 -> 18.9 ms a frame on
            one core); points are decoded afresh (comparing every point with its last
            input cost what reusing the 13 % that matched saved).

    Attributes:
        points: Points asked for so far.
        decoded: Of those, how many were decoded (the rest were reused).
    """

    def __init__(self, tol: float = 0.0, still_vertices: torch.Tensor | None = None,
                 camera_moves: bool = False) -> None:
        if not tol >= 0.0:
            raise ValueError(f"expected a tolerance >= 0, found {tol}")
        self.tol = float(tol)
        self.camera_moves = bool(camera_moves)
        self.still_vertices = still_vertices
        """``(V,)`` bool: the head's vertices that no expression moves (their triangles
        are rasterized once, the others drawn over them each frame), or ``None``."""
        self.still_index = (None if still_vertices is None
                            else torch.nonzero(still_vertices)[:, 0])
        """Their indices (made once, not every frame)."""
        self._slots: dict[str, _Slot] = {}
        self._kept: dict[str, tuple[tuple[torch.Tensor, ...], Any]] = {}
        self._refined: tuple[torch.Tensor, ...] | None = None
        self.refined_pixels = 0
        """Input pixels the RefineNet was run on by :meth:`refine` after its first frame."""
        self.points = 0
        self.decoded = 0

    def clear(self) -> None:
        """Forget every decoded point (the camera or the head changed)."""
        self._slots.clear()
        self._kept.clear()
        self._refined = None

    def kept(self, name: str, inputs: tuple[torch.Tensor, ...], make: Callable[[], Any]
             ) -> Any:
        """``make()``, or what it returned last time for equal ``inputs`` (the tensors
        it depends on), such as the screen depth of hair that does not move."""
        last = self._kept.get(name)
        if last is not None and len(last[0]) == len(inputs) and all(
                a.shape == b.shape and torch.equal(a, b) for a, b in zip(last[0], inputs,
                                                                          strict=True)):
            return last[1]
        out = make()
        self._kept[name] = (tuple(t.clone() for t in inputs), out)
        return out

    def decode(self, name: str, run: Callable[[torch.Tensor], tuple[torch.Tensor,
                                                                     torch.Tensor]],
               feats: torch.Tensor, keys: torch.Tensor, size: int
               ) -> tuple[torch.Tensor, torch.Tensor]:
        """Density and colour features of points, decoding only those that changed.

        Args:
            name: Which decoder (each has its own store).
            run: The decoder: ``(1, n, D)`` -> ``(density (1, n), colour (1, n, Cf))``.
            feats: ``(N, D)`` input features.
            keys: ``(N,)`` int64 sample slot of each point, distinct, in ``[0, size)``.
            size: Number of sample slots of this frame (rays x samples); a change of size
                starts the store afresh.

        Returns:
            ``(density (N,), colour (N, Cf))``.
        """
        slot = self._slots.get(name)
        if slot is not None and (slot.size != size or slot.inputs.shape[1] != feats.shape[1]
                                 or slot.inputs.dtype != feats.dtype):
            slot = None
        self.points += len(keys)
        if slot is None:
            todo = None  # all of them
        else:
            old = slot.inputs.index_select(0, keys)
            # a NaN (never decoded) compares as changed
            same = ((feats - old).abs() <= self.tol).all(-1)
            todo = torch.nonzero(~same).squeeze(1)
            if todo.numel() == len(keys):
                todo = None
        if todo is not None and todo.numel() == 0:
            return slot.density.index_select(0, keys), slot.colour.index_select(0, keys)
        f = feats if todo is None else feats.index_select(0, todo)
        k = keys if todo is None else keys.index_select(0, todo)
        density, colour = run(f[None])
        density, colour = density[0], colour[0]
        self.decoded += len(k)
        if slot is None:
            slot = _Slot(size, feats.shape[1], colour.shape[-1], feats)
            self._slots[name] = slot
        slot.inputs.index_copy_(0, k, f)
        slot.density.index_copy_(0, k, density.to(slot.density.dtype))
        slot.colour.index_copy_(0, k, colour.to(slot.colour.dtype))
        if todo is None:
            return density, colour
        return slot.density.index_select(0, keys), slot.colour.index_select(0, keys)

    def refine(self, run: Callable[..., tuple[torch.Tensor, torch.Tensor]],
               features: torch.Tensor, alpha: torch.Tensor, rgb: torch.Tensor,
               scale: int, reach: int) -> tuple[torch.Tensor, torch.Tensor]:
        """The RefineNet's output, recomputed only around the pixels whose input changed.

        The net runs on a crop of its input around the changed pixels (their bounding
        box grown by ``2 reach``, then out to the :data:`CROP_GRID`); the crop's output,
        less a ``reach`` border where the crop's own edges show, replaces the last
        frame's output there. Outside that border the output cannot have changed.

        Args:
            run: The RefineNet: ``(features, alpha, rgb)`` -> ``(rgb, alpha)`` at
                ``scale`` times their size.
            features: ``(1, Cf, h, w)``; alpha ``(1, 1, h, w)``; rgb ``(1, 3, h, w)``.
            scale: Output pixels per input pixel.
            reach: Input pixels around a change within which the output can change
                (:attr:`~head360cli.model.networks.RefineNet.reach`).

        Returns:
            ``(rgb (1, 3, h s, w s), alpha (1, 1, h s, w s))``.
        """
        x = torch.cat([features, alpha, rgb], 1)
        last = self._refined
        if last is None or last[0].shape != x.shape or last[0].dtype != x.dtype:
            out = run(features, alpha, rgb)
            self._refined = (x, *out)
            return out
        changed = (x != last[0]).any(1)[0]
        rows = torch.nonzero(changed.any(1)).squeeze(1)
        if rows.numel() == 0:
            self._refined = (x, *last[1:])
            return last[1].clone(), last[2].clone()
        cols = torch.nonzero(changed.any(0)).squeeze(1)
        h, w = changed.shape
        box = (int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1)
        # the crop's edges on a grid of CROP_GRID pixels: few distinct shapes, so oneDNN's
        # cache of convolutions made per input shape stays small (every exact crop size
        # was a new entry: the process grew by 100 MiB over 2000 frames)
        g = CROP_GRID
        y0, y1, x0, x1 = (max(box[0] - 2 * reach, 0) // g * g,
                          min(-(-(box[1] + 2 * reach) // g) * g, h),
                          max(box[2] - 2 * reach, 0) // g * g,
                          min(-(-(box[3] + 2 * reach) // g) * g, w))
        got = run(features[..., y0:y1, x0:x1], alpha[..., y0:y1, x0:x1],
                  rgb[..., y0:y1, x0:x1])
        # the part of the crop's output that is exact: ``reach`` inside the crop's edges,
        # unless that edge is the image's own
        p0, p1 = (y0 if y0 == 0 else y0 + reach), (y1 if y1 == h else y1 - reach)
        q0, q1 = (x0 if x0 == 0 else x0 + reach), (x1 if x1 == w else x1 - reach)
        s = scale
        outs = []
        for full, crop in zip(last[1:], got, strict=True):
            full = full.clone()
            full[..., p0 * s:p1 * s, q0 * s:q1 * s] = crop[
                ..., (p0 - y0) * s:(p1 - y0) * s, (q0 - x0) * s:(q1 - x0) * s]
            outs.append(full)
        self._refined = (x, *outs)
        self.refined_pixels += (y1 - y0) * (x1 - x0)
        return outs[0], outs[1]

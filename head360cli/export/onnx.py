"""ONNX export of the per-frame generator and a torch-free runner for it.

What changes per frame goes in; what a head keeps is made once by the caller (with torch,
or read from a head file and the exported extras):

    verts (1, V, 3), texture (1, C, R, R), c2w (1, 4, 4), intrinsics (1, 3, 3)
    [+ hair_verts (1, HAIR_VERTS, 3), hair_faces (HAIR_FACES, 3),
       hair_planes (1, P, C + 2, r, r)]
        -> rgb (1, 3, S, S) in [0, 1], alpha (1, 1, S, S)

(hair meshes are padded to fixed sizes, so one graph serves all 30 hairstyles).

Two graphs are written: ``NAME.onnx`` renders a head with hair, ``NAME_bald.onnx`` without
(the hair branch has no "no hair" input that would give the bald image). Rasterization is
inside the graphs (the rasterizer's ``static_windows`` mode), and so is ray culling: the
rays near a surface are found with ``NonZero``, so only they are decoded, as in torch.
The projection and the rasterizer's coverage test are written element by element, so
onnxruntime covers exactly the pixels torch covers (a matrix product rounds differently in
each, and one flipped pixel on a silhouette changed images by 7e-3). Samples per ray and
the image size are fixed at export. A fitted head's light (its ``colour_gain``) is
applied to the graph's output with its ``alpha``, outside the graph, as torch applies it
(:func:`~head360cli.model.render.lit`); graphs of format 1 (:data:`GRAPH_FORMAT`) have no
``alpha`` and cannot draw such a head.

:class:`OnnxFrameRunner` runs the graphs in onnxruntime with the same arguments as
:class:`FrameModel` (numpy arrays instead of tensors); it imports neither torch nor the
generator.
"""

from __future__ import annotations

import contextlib
import json
import logging
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["GRAPH_FORMAT", "HAIR_FACES", "HAIR_VERTS", "NO_ALPHA", "OnnxFrameRunner",
           "export_onnx", "head_inputs", "pad_hair", "pad_hair_uv"]

GRAPH_FORMAT = 3
"""Format version of the graphs :func:`export_onnx` writes, stored in their metadata
(``format_version``). Format 1 graphs (head360 0.1.0 before 2026-11, no version stored)
give ``rgb`` alone; format 2 adds the coverage ``alpha``; format 3 (the deferred
generator's) adds the hair's texture coordinates ``hair_uv`` as an input and reads its
texture from ``hair_planes``. A hex-plane generator's graphs are still written as format
2."""

NO_ALPHA = ("expected an ONNX graph with an alpha output to draw a fitted head's light, "
            "found a graph exported by an older head360 (graph format 1, rgb only): export "
            "it again with head360 export-onnx")
"""The error for a head with a light of its own and a graph without ``alpha``."""

META_KEY = "head360"
"""Metadata key of the export settings stored in each ONNX file."""

HAIR_VERTS = 12288
"""Hair meshes are padded to this many vertices (the largest style has about 10,400)..."""
HAIR_FACES = 16384
"""...and this many triangles (about 12,000), so one graph serves every hairstyle: the
padding triangles have zero area and are never drawn."""


def pad_hair_uv(uv: np.ndarray) -> np.ndarray:
    """``(1, HAIR_VERTS, 2)`` float32 from a hair mesh's texture coordinates ``(1, H, 2)``
    (the deferred graphs read the hair texture at them)."""
    u = np.asarray(uv, np.float32).reshape(-1, 2)
    out = np.zeros((HAIR_VERTS, 2), np.float32)
    out[:len(u)] = u[:HAIR_VERTS]
    return out[None]


def pad_hair(verts: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(1, HAIR_VERTS, 3)`` float32 and ``(HAIR_FACES, 3)`` int64 from a hair mesh
    ``(1, H, 3)``, ``(G, 3)``.

    Raises:
        BadInputError: The mesh is larger than the padding.
    """
    from head360cli.errors import BadInputError

    v = np.asarray(verts, np.float32).reshape(-1, 3)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    if len(v) > HAIR_VERTS or len(f) > HAIR_FACES:
        raise BadInputError(f"expected a hair mesh of at most {HAIR_VERTS} vertices and "
                            f"{HAIR_FACES} triangles, found {len(v)} and {len(f)}")
    pv = np.zeros((HAIR_VERTS, 3), np.float32)
    pv[:len(v)] = v
    pf = np.zeros((HAIR_FACES, 3), np.int64)  # (0, 0, 0): zero area, never drawn
    pf[:len(f)] = f
    return pv[None], pf


def _frame_model(gen, hair: bool):
    import torch

    from head360cli.model.generator import Hair

    class FrameModel(torch.nn.Module):
        """One frame of one head: the generator with its per-head parts as inputs."""

        def __init__(self) -> None:
            super().__init__()
            self.gen = gen

        def forward(self, verts, texture, c2w, intrinsics, hair_verts=None, hair_faces=None,
                    hair_planes=None, hair_uv=None):
            h = None
            if hair:
                # the hex-plane generator's planes are made: it reads no coordinates
                uv = hair_uv[0] if hair_uv is not None else torch.zeros_like(
                    hair_verts[0, :, :2])
                h = Hair([(hair_verts[0], hair_faces, uv)],
                         torch.zeros(1, dtype=torch.long), torch.zeros(1, 3),
                         [hair_planes])
            out = self.gen(verts, c2w, intrinsics, texture=texture, hair=h)
            return out["rgb"].clamp(0, 1), out["alpha"]

    return FrameModel().eval()


def _tidy(model) -> None:
    """Fold constants, drop dead nodes and lift the remaining constants to initializers in
    an exported ``onnx_ir`` model, in place.

    These are the parts of torch's default post-export optimisation (onnxscript's
    optimizer) that shrink the graph; its pattern rewriter, which took about 23 s of the
    65 s a 256-pixel hair graph took to export on 2 CPU cores, is left out (both graphs
    at 256 pixels and 8 samples: 73-80 s instead of 143 s). Measured (2026-12-03) on the
    hair graph: onnxruntime renders the same pixels as from the fully optimised one
    (largest difference 0) at the same speed (medians of 16 interleaved blocks of 4
    frames, two runs: 255 and 287 ms a frame against 251 and 281 ms, within this
    machine's noise). Without the folding, onnxruntime warns that it cannot fold
    ``CastLike`` nodes each time it loads the graph."""
    from onnx_ir.passes.common import DeduplicateInitializersPass, LiftConstantsToInitializersPass
    from onnxscript.optimizer import fold_constants, remove_unused_nodes

    fold_constants(model)
    remove_unused_nodes(model)
    LiftConstantsToInitializersPass(lift_all_constants=True, size_limit=0)(model)
    DeduplicateInitializersPass()(model)


@contextlib.contextmanager
def _quiet_exporter():
    """Silence what torch's exporter prints that a user cannot act on: a warning per
    torchvision operator when torchvision is not installed (head360 uses none), onnx_ir's
    note that it typed an empty attribute as integers (as it should), and a
    ``FutureWarning`` from inside torch's own tree utilities."""
    logs = [logging.getLogger(name) for name in ("torch.onnx", "onnx_ir")]
    levels = [log.level for log in logs]
    for log in logs:
        log.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            yield
    finally:
        for log, level in zip(logs, levels, strict=True):
            log.setLevel(level)


def _example(renderer, hair: bool) -> tuple:
    from head360cli.drive.views import view_cameras, view_intrinsics

    args = (renderer.vertices(np.zeros((1, 52))), renderer.texture,
            view_cameras(0.0, 0.0).to(renderer.device),
            view_intrinsics(renderer.size)[None].to(renderer.device))
    if hair:
        import torch

        hv, hf, huv = renderer.hair.meshes[0]
        pv, pf = pad_hair(hv[None].cpu().numpy(), hf.cpu().numpy())
        args += (torch.as_tensor(pv, device=renderer.device),
                 torch.as_tensor(pf, device=renderer.device), renderer.hair.planes[0])
        if renderer.gen.kind == "deferred":
            args += (torch.as_tensor(pad_hair_uv(huv.cpu().numpy()), device=renderer.device),)
    return args


def export_onnx(renderer, out: str | Path, progress: Any = None, cull: bool = True,
                parallel: bool | None = None,
                inputs: tuple[str | Path, dict[str, np.ndarray]] | None = None
                ) -> dict[str, Any]:
    """Export the generator as it renders ``renderer``'s head (its samples per ray and
    image size) to ``out`` (with hair) and ``<out stem>_bald.onnx``.

    With ``inputs``, a path and a head's arrays (:func:`head_inputs`), those are written
    there as ``.npz`` too. The files are one set: each is written under a temporary name,
    and all are renamed once all are complete, so a failure (a full disk at the last one)
    leaves an earlier export's set as it was.

    ``cull`` keeps the generator's ray culling in the graph (the rays near a surface are
    found with ``NonZero``, so the decoders see a data-dependent number of points);
    without it every ray is decoded (static shapes, slower, for runtimes that need them).

    Tracing is Python work on one core, about a minute a graph on a 2-core CPU, so with
    ``parallel`` (``None``: for a renderer on the CPU where two or more cores are
    usable) the bald graph is traced in a spawned process while this one traces the
    hair graph.

    Returns:
        ``{"files": [...], "seconds": ..., "samples": ..., "size": ..., "parallel": ...}``.
    """
    import importlib.util

    from head360cli.devices import usable_cpus
    from head360cli.errors import BadInputError, ModelNotFoundError
    from head360cli.io.atomic import atomic_paths, check_file_target
    from head360cli.paths import generator_hash

    missing = [m for m in ("onnx", "onnxscript") if importlib.util.find_spec(m) is None]
    if missing:
        raise ModelNotFoundError(f"exporting needs the optional packages onnx and "
                                 f"onnxscript, found {' and '.join(missing)} not installed: "
                                 f"pip install 'head360[export]'")
    out = Path(out)
    if out.suffix.lower() != ".onnx":
        raise BadInputError(f"expected an .onnx output, found {out.name!r}")
    bald = out.with_name(f"{out.stem}_bald.onnx")
    files = [out, bald] + ([Path(inputs[0])] if inputs is not None else [])
    for f in files:  # the names made from out's too, before a minute of tracing
        check_file_target(f)
    if renderer.hair is None:
        raise BadInputError("expected a head with hair to export the hair graph (a bald "
                            "head has no hair mesh to trace with)")
    gen = renderer.gen
    t0 = time.perf_counter()
    meta = {"format_version": GRAPH_FORMAT if gen.kind == "deferred" else 2,
            "generator": gen.kind,
            "samples": renderer.samples,
            "size": renderer.size, "cull": bool(cull),
            "generator_sha256": generator_hash(),
            "texture_channels": gen.cfg.texture_channels,
            "texture_res": gen.cfg.texture_res}
    if parallel is None:  # (a GPU renderer's tensors would have to cross by CUDA IPC)
        parallel = usable_cpus() >= 2 and renderer.device.type == "cpu"
    if progress:
        progress("export", 0, 2)
    with atomic_paths(*files) as tmps:
        if parallel:
            parallel = _export_pair(renderer, tmps[0], tmps[1], cull, meta, progress)
        else:
            _export_graph(renderer, True, tmps[0], cull, meta)
            if progress:
                progress("export", 1, 2)
            _export_graph(renderer, False, tmps[1], cull, meta)
        if inputs is not None:
            with open(tmps[2], "wb") as f:
                np.savez(f, **inputs[1])
    return {"files": [str(f) for f in files], "seconds": time.perf_counter() - t0,
            "parallel": parallel, **meta}


def _export_graph(renderer, hair: bool, path: Path, cull: bool, meta: dict[str, Any]
                  ) -> None:
    """Trace one graph (with or without hair) and write it to ``path`` (a temporary
    name: :func:`export_onnx` renames the set)."""
    import inspect

    import torch

    from head360cli.geometry.rasterize import static_windows

    gen = renderer.gen
    # An exporter with an ``optimize`` argument (torch 2.13 here) optimises the graph
    # afterwards unless told not to; _tidy does the part of that which matters, faster.
    tidy = "optimize" in inspect.signature(torch.onnx.export).parameters
    kwargs = {"optimize": False} if tidy else {}
    own = (gen.cull_rays, gen.hair_rays_only, gen.network_dtype)
    gen.cull_rays, gen.hair_rays_only, gen.network_dtype = cull, cull, None
    try:
        model = _frame_model(gen, hair)
        args = _example(renderer, hair)
        names = ["verts", "texture", "c2w", "intrinsics"]
        if hair:
            names += ["hair_verts", "hair_faces", "hair_planes"]
            if gen.kind == "deferred":
                names.append("hair_uv")
        samples = gen.pixel_samples if gen.kind == "deferred" else gen.samples_per_ray
        with torch.no_grad(), samples(renderer.samples), \
                gen.image_size(renderer.size), static_windows(), _quiet_exporter():
            program = torch.onnx.export(model, args, input_names=names,
                                        output_names=["rgb", "alpha"], dynamo=True,
                                        opset_version=18, verbose=False, **kwargs)
            if tidy:
                _tidy(program.model)
        program.model.metadata_props[META_KEY] = json.dumps({**meta, "hair": hair})
        program.save(path)
    finally:
        gen.cull_rays, gen.hair_rays_only, gen.network_dtype = own


def _graph_worker(conn) -> None:
    """A spawned process: receive a pickled job (renderer, hair, path, cull, meta), trace
    its graph and send back ``None``, or the exception and its traceback."""
    import pickle
    import traceback

    import torch

    try:
        renderer, hair, path, cull, meta = pickle.loads(conn.recv_bytes())
        torch.set_num_threads(1)
        _export_graph(renderer, hair, path, cull, meta)
        conn.send(None)
    except BaseException as exc:
        try:
            conn.send((exc, traceback.format_exc()))
        except Exception:  # an exception that does not pickle
            conn.send((RuntimeError(str(exc)), traceback.format_exc()))


def _export_pair(renderer, out: Path, bald: Path, cull: bool, meta: dict[str, Any],
                 progress: Any) -> bool:
    """Trace the hair graph here and the bald one in a spawned process at the same time.
    If the process cannot be started, the head does not fit in shared memory (a
    container's small ``/dev/shm``) or the process dies without an answer, the bald
    graph is traced here afterwards; an error it reports is raised here. Returns
    whether it made the bald graph."""
    import copy
    import multiprocessing
    from multiprocessing.reduction import ForkingPickler

    ctx = multiprocessing.get_context("spawn")
    here, there = ctx.Pipe()
    proc = ctx.Process(target=_graph_worker, args=(there,), daemon=True)
    done = False
    try:
        # the job goes through the pipe after the start, not as the process's argument:
        # a large argument is written while the child starts, and a child that dies
        # then would leave that write waiting for ever
        from head360cli.interrupts import sigint_ignored

        with sigint_ignored():  # Ctrl-C is this process's to handle: it ends the child
            proc.start()
        there.close()
        shipped = copy.copy(renderer)
        shipped.last_reuse = None  # a render's leftovers, not needed to trace
        here.send_bytes(bytes(ForkingPickler.dumps((shipped, False, bald, cull, meta))))
        spawned = True
    except Exception as exc:
        if proc.pid is not None:  # it waits for a job that will not come
            proc.terminate()
            proc.join(timeout=10)
        # not started, gone before it took the job, or no room in /dev/shm for the
        # head's tensors (torch's RuntimeError): traced here instead
        if not (isinstance(exc, OSError) or "shared memory" in str(exc)):
            raise
        spawned = False
    try:
        _export_graph(renderer, True, out, cull, meta)
        if progress:
            progress("export", 1, 2)
        got = None
        if spawned:
            try:
                got = here.recv()
            except (EOFError, OSError):
                spawned = False
        if not spawned:
            _export_graph(renderer, False, bald, cull, meta)
        elif got is not None:
            exc, text = got
            raise exc from RuntimeError(f"in the process tracing {bald.name}:\n{text}")
        done = True
        return spawned
    finally:
        if proc.pid is not None:
            proc.join(timeout=30 if done else 0)
            if proc.is_alive():
                proc.terminate()
                proc.join(timeout=10)
        here.close()
        there.close()  # closed at the start; here too if the process never started


def head_inputs(renderer) -> dict[str, np.ndarray]:
    """What a torch-free runner needs of one head: ``base (V, 3)`` and ``deltas
    (52, V, 3)`` (the mesh is ``base + w @ deltas`` for the weights ``w`` that the head's
    own ``expression (52,)`` drives, :func:`~head360cli.io.headfile.driven_weights`),
    ``texture (1, C, R, R)``, for a head
    with a lid change ``lids (2, C, R, R)`` (its left and right eye's parts), ``lid_from
    (2,)`` and ``lid_weights (2,)`` (the indices of eyeBlinkLeft / Right; see
    :meth:`~head360cli.model.head_render.HeadRenderer.textures`), and for a head with hair
    ``hair_verts (1, H, 3)``, ``hair_faces (G, 3)`` and ``hair_planes`` (for the deferred
    generator its hair texture, with ``hair_uv (1, H, 2)``); for a head with
    a light of its own (a fit's), ``colour_gain (3,)``."""
    out = {"base": renderer.neutral.astype(np.float32),
           "deltas": renderer.deltas.astype(np.float32),
           "expression": renderer.expression.astype(np.float32),
           "texture": renderer.texture.detach().cpu().numpy().astype(np.float32)}
    if renderer.lids is not None:
        out.update(lids=renderer.lids.detach().cpu().numpy().astype(np.float32),
                   lid_from=renderer.lid_from.astype(np.float32),
                   lid_weights=np.asarray(renderer.blink_index, np.int64))
    if renderer.colour_gain is not None:
        out["colour_gain"] = renderer.colour_gain.reshape(3).cpu().numpy().astype(np.float32)
    if renderer.hair is not None:
        hv, hf, huv = renderer.hair.meshes[0]
        out.update(hair_verts=hv[None].cpu().numpy().astype(np.float32),
                   hair_faces=hf.cpu().numpy().astype(np.int64),
                   hair_planes=renderer.hair.planes[0].detach().cpu().numpy()
                   .astype(np.float32))
        if renderer.gen.kind == "deferred":
            out["hair_uv"] = huv[None].cpu().numpy().astype(np.float32)
    return out


def _planes_for(sess, planes: np.ndarray) -> np.ndarray:
    """A deferred generator's hair texture ``(1, C, r, r)`` at the side the graph was
    exported with (a fit's hair detail makes it 256, the network's own is 64), bilinearly
    resized where they differ, so one graph renders every head."""
    import cv2

    shape = next((i.shape for i in sess.get_inputs() if i.name == "hair_planes"), None)
    side = shape[-1] if shape is not None and len(shape) == 4 else None
    if not isinstance(side, int) or planes.ndim != 4 or planes.shape[-1] == side:
        return planes
    inter = cv2.INTER_AREA if side < planes.shape[-1] else cv2.INTER_LINEAR
    moved = cv2.resize(np.ascontiguousarray(planes[0].transpose(1, 2, 0), np.float32),
                       (side, side), interpolation=inter)
    return moved.reshape(side, side, -1).transpose(2, 0, 1)[None]


class OnnxFrameRunner:
    """Render frames with an exported generator in onnxruntime (no torch needed).

    Args:
        path: The ``.onnx`` file with hair (its ``_bald.onnx`` sibling is found by name).
        threads: Intra-op threads (default: onnxruntime's choice).
        providers: onnxruntime execution providers, best first (default: the CPU's);
            those this onnxruntime build lacks are left out (``provider`` says which ran).
    """

    def __init__(self, path: str | Path, threads: int | None = None,
                 providers: list[str] | None = None) -> None:
        import onnxruntime as ort

        from head360cli.errors import FileFormatError

        path = Path(path)
        opts = ort.SessionOptions()
        if threads:
            opts.intra_op_num_threads = int(threads)
        have = set(ort.get_available_providers())
        chosen = [p for p in (providers or []) if p in have] or ["CPUExecutionProvider"]
        self.sessions = {}
        bald = path.with_name(f"{path.stem}_bald.onnx")
        if path.stem.endswith("_bald") and not bald.exists():
            raise FileFormatError(
                f"{path}: expected the graph with hair, NAME.onnx (its NAME_bald.onnx is "
                f"found beside it), found the bald one: give "
                f"{path.with_name(path.stem[:-5] + '.onnx')}")
        if not bald.exists():
            raise FileFormatError(f"{path}: expected its bald graph {bald.name} beside it "
                                  "(export-onnx writes both), found none")
        for hair, p in ((True, path), (False, bald)):
            try:
                self.sessions[hair] = ort.InferenceSession(
                    str(p), opts, providers=chosen)
            except Exception as exc:
                raise FileFormatError(f"{p}: expected an exported head360 generator "
                                      f"({exc})") from None
        meta = self.sessions[True].get_modelmeta().custom_metadata_map.get(META_KEY)
        if meta is None:
            raise FileFormatError(f"{path}: expected head360 export metadata, found none")
        self.meta = json.loads(meta)
        found = self.meta.get("format_version", 1)
        if not isinstance(found, int) or found > GRAPH_FORMAT:
            raise FileFormatError(f"{path}: expected an ONNX graph of format {GRAPH_FORMAT} "
                                  f"or older, found format {found!r}: it was exported by a "
                                  f"newer head360, upgrade head360 to run it")
        self.format_version = found
        """The graph's format version (1 for graphs that store none)."""
        self.size = int(self.meta["size"])
        self.provider = self.sessions[True].get_providers()[0]
        """The execution provider that runs the graph."""
        self.has_alpha = all(len(sess.get_outputs()) > 1 for sess in self.sessions.values())
        """Whether the graphs give ``alpha`` beside ``rgb`` (those of graph format 1 do
        not), which a head with a light of its own needs."""

    def __call__(self, verts: np.ndarray, texture: np.ndarray, c2w: np.ndarray,
                 intrinsics: np.ndarray, hair_verts: np.ndarray | None = None,
                 hair_faces: np.ndarray | None = None,
                 hair_planes: np.ndarray | None = None,
                 hair_uv: np.ndarray | None = None) -> np.ndarray:
        """``rgb (1, 3, S, S)`` in [0, 1]; the arguments of the torch ``FrameModel`` as
        float32 (faces int64) arrays; no hair arguments renders the bald head."""
        return self.frame(verts, texture, c2w, intrinsics, hair_verts, hair_faces,
                          hair_planes, hair_uv)[0]

    def frame(self, verts: np.ndarray, texture: np.ndarray, c2w: np.ndarray,
              intrinsics: np.ndarray, hair_verts: np.ndarray | None = None,
              hair_faces: np.ndarray | None = None, hair_planes: np.ndarray | None = None,
              hair_uv: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """As calling the runner, with the coverage: ``(rgb (1, 3, S, S), alpha (1, 1, S,
        S))``, ``alpha`` ``None`` from a graph without it (:attr:`has_alpha`)."""
        hair = hair_verts is not None
        feeds = {"verts": verts, "texture": texture, "c2w": c2w, "intrinsics": intrinsics}
        if hair:
            hair_verts, hair_faces = pad_hair(hair_verts, hair_faces)
            feeds.update(hair_verts=hair_verts, hair_faces=hair_faces,
                         hair_planes=hair_planes)
            if hair_uv is not None:
                feeds["hair_uv"] = pad_hair_uv(hair_uv)
        sess = self.sessions[hair]
        if hair and hair_planes is not None:
            feeds["hair_planes"] = _planes_for(sess, hair_planes)
        wanted = {i.name for i in sess.get_inputs()}
        feeds = {k: np.ascontiguousarray(v, np.int64 if k == "hair_faces" else np.float32)
                 for k, v in feeds.items() if k in wanted}
        outs = sess.run(None, feeds)
        return outs[0], (outs[1] if len(outs) > 1 else None)

    def render(self, inputs: dict[str, np.ndarray], weights: np.ndarray, c2w: np.ndarray,
               intrinsics: np.ndarray, hair: bool = True) -> np.ndarray:
        """One frame ``(1, 3, S, S)`` of a head given as :func:`head_inputs`, with ARKit
        ``weights (52,)`` (driving weights, as
        :meth:`~head360cli.model.head_render.HeadRenderer.frames` takes them) and a camera,
        in numpy and onnxruntime only."""
        from head360cli.io.headfile import driven_weights

        weights = driven_weights(np.asarray(weights, np.float32).reshape(1, 52),
                                 inputs.get("expression", np.zeros(52, np.float32)))[0]
        verts = inputs["base"] + np.tensordot(weights, inputs["deltas"], 1)
        extra = {}
        if hair and "hair_verts" in inputs:
            extra = {k: inputs[k] for k in ("hair_verts", "hair_faces", "hair_planes",
                                            "hair_uv") if k in inputs}
        texture = inputs["texture"]
        if "lids" in inputs:
            from head360cli.io.headfile import lid_amounts

            amount = lid_amounts(np.asarray(weights, np.float32)[inputs["lid_weights"]][None],
                                 inputs["lid_from"])[0]
            if (amount > 0).any():
                texture = texture + np.tensordot(amount, inputs["lids"], 1)[None]
        rgb, alpha = self.frame(verts[None], texture, np.asarray(c2w).reshape(1, 4, 4),
                                np.asarray(intrinsics).reshape(1, 3, 3), **extra)
        if "colour_gain" not in inputs:
            return rgb
        if alpha is None:
            from head360cli.errors import FileFormatError

            raise FileFormatError(NO_ALPHA)
        back = 1.0 - alpha
        gain = np.asarray(inputs["colour_gain"], np.float32).reshape(1, 3, 1, 1)
        return np.clip(gain * (rgb - back) + back, 0.0, 1.0)

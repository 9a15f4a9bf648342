"""``head360 bench animate``: animation, measured.

The head is the astronaut photo that ships with scikit-image, fitted with the fast preset
(what ``head360 demo`` makes), driven by the real Live Link Face captures in
``../shared/data/arkit`` when they are there (else by a synthetic stream), or by the
stream given with ``--stream``.

- Reuse: with a still camera, frames decode only the points whose inputs changed since
  the last frame; frames per second with and without, and the difference in the frames.
- Throughput: frames per second of 256 x 256 frames from the stream's weights, for samples
  per ray and float32/bfloat16 networks (bfloat16 where the CPU has it), with the PSNR of
  each against a 32-sample float32 render of the same frames (the converged answer), and
  the CLI's own frames per second with the video encoder; and against image size (128 to
  512 pixels), scored at its own size and, upsampled, against the 512-pixel converged
  render.
- Peak memory: the resident set of a ``head360 animate`` process (and of the processes it
  spawns to render frames) that renders a whole capture, against one that renders its
  first 10 seconds.
- A turning head: ``head360 animate --head-pose`` frames per second on the capture whose
  head rotation moves most (the camera moves every frame, so every point is decoded),
  against the same command without ``--head-pose``; each by default (a process per core)
  and with ``--workers 1``.
- Expression fidelity, read with the face tracker (:mod:`head360cli.bench.fidelity`):
  first the tracker itself (its frames per second on 640 x 480 frames; how well its
  mouthSmile separates the London set's neutral and smiling portraits), then each Live
  Link Face capture driving the fitted astronaut (every ``stride``-th frame, tracked):
  Pearson r per blendshape, for the six with goals and the mean over the 20 the capture
  moves most, beside held-out SynHead-P heads rendered by the corpus renderer with the
  same weights (faces exactly right: the tracker's own ceiling on these heads); a plot of
  the most active shapes over time.
- Hair swap: PSNR of the face (the landmarks' hull, less the pixels either hairstyle
  covers) between the head with its own hair and with each other style; and over the
  whole hull.
- On a GPU (``device`` other than the CPU): frames per second against frames per
  generator call (``animate --batch``), with and without hair, in each precision the
  device computes natively; reuse between frames, a CPU path (it decodes one frame a
  call), is left out.

Every part runs on ``device`` except the ground-truth fidelity column (the corpus
renderer, on the CPU). With ``head_path`` no photo is fitted.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["bench_animate", "correlation", "eye_opening"]

FIDELITY_REFERENCE = 2
"""Held-out SynHead-P heads rendered by the corpus renderer with each capture's weights:
the tracker's reading of faces that are exactly right."""

SWAP_STYLES = (0, 2, 7, 9, 12, 17, 22, 28)
"""Hairstyles the swap measurement puts on the head (bald, short, long, voluminous)."""


def eye_opening(lm: np.ndarray, which: str) -> float:
    """Eyelid gap over eye width of the image's ``left`` (iBUG 36-41, the subject's right
    eye) or ``right`` eye (42-47)."""
    i = 36 if which == "left" else 42
    e = lm[i:i + 6]
    gap = (np.linalg.norm(e[1] - e[5]) + np.linalg.norm(e[2] - e[4])) / 2
    return float(gap / np.linalg.norm(e[0] - e[3]))


def _stream(data: Path | None):
    from head360cli.io.arkit import ArkitStream

    if data is not None:
        from head360cli.io.arkit import read_arkit_csv

        caps = sorted((data / "arkit").glob("livelinkface_*.csv"))
        if caps:
            streams = [read_arkit_csv(p, on_bad="hold") for p in caps]
            return max(zip(streams, caps, strict=True), key=lambda s: s[0].num_frames)
    from head360cli.mesh.arkit52 import INDEX

    rng = np.random.default_rng(0)
    t = np.arange(600) / 60.0
    w = np.zeros((600, 52), np.float32)
    w[:, INDEX["jawOpen"]] = 0.5 + 0.5 * np.sin(2 * np.pi * 0.7 * t)
    blink = (np.sin(2 * np.pi * 0.4 * t) > 0.8).astype(np.float32)
    w[:, INDEX["eyeBlinkLeft"]] = w[:, INDEX["eyeBlinkRight"]] = blink
    w += rng.uniform(0, 0.05, w.shape).astype(np.float32)
    return ArkitStream(np.clip(w, 0, 1), t, 60.0), None


def _psnr(a, b) -> float:
    mse = float(((a - b) ** 2).mean())
    return 10 * np.log10(1 / max(mse, 1e-12))


def _render(r, weights: np.ndarray, size: int, hair: bool = True):
    """``(N, 3, S, S)`` float frames of ``weights`` seen from the front, on the CPU."""
    import torch

    from head360cli.drive.views import view_cameras, view_intrinsics

    cams = view_cameras(0.0, 0.0).expand(len(weights), 4, 4)
    return torch.cat([torch.as_tensor(f).cpu() for f in
                      r.frames(cams, weights, view_intrinsics(size), hair=hair,
                               uint8=False)])


def _timed(r, weights: np.ndarray, size: int, hair: bool = True,
           batch: int | None = None) -> dict[str, float]:
    """Frames per second of rendering ``weights`` as ``head360 animate`` does (uint8
    frames brought to the CPU, ``batch`` a generator call: default the renderer's), after
    a warm-up call of one batch."""
    from head360cli.drive.views import view_cameras, view_intrinsics

    cams = view_cameras(0.0, 0.0).expand(len(weights), 4, 4)
    k = view_intrinsics(size)
    warm = batch or (2 if r.device.type == "cpu" else 32)
    list(r.frames(cams[:warm], weights[:warm], k, hair=hair, batch=batch))  # warm up
    t0 = time.perf_counter()
    for _ in r.frames(cams, weights, k, hair=hair, batch=batch):
        pass
    seconds = time.perf_counter() - t0
    return {"fps": round(len(weights) / seconds, 2),
            "ms_per_frame": round(1000 * seconds / len(weights), 1)}


def _precisions(device: str) -> tuple[str, ...]:
    """float32, and bfloat16 where ``device`` computes it natively (emulated bfloat16 is
    many times slower and never chosen)."""
    from head360cli.devices import fast_bfloat16

    return ("fp32", "bf16") if fast_bfloat16(device) else ("fp32",)


def _sampling(head: Path, device: str) -> tuple[int, tuple[int, ...], int | None]:
    """``(reference samples, samples swept, animation default)`` of the installed
    generator: samples a pixel 4, (1, 2, 4) and its own for a deferred one; samples a ray
    32, (6, 8, 12) and 8 for a hex-plane one."""
    from head360cli.fitting.pipeline import load_head_renderer

    if load_head_renderer(head, device=device).gen.kind == "deferred":
        return 4, (1, 2, 4), None
    return 32, (6, 8, 12), 8


def _speed(head: Path, weights: np.ndarray, device: str = "cpu") -> list[dict[str, Any]]:
    """Throughput and error by samples (a pixel, or a ray), in each of
    :func:`_precisions`, against the most samples' float32 frames."""
    from head360cli.fitting.pipeline import load_head_renderer

    most, sweep, _ = _sampling(head, device)
    pick = weights[np.linspace(0, len(weights) - 1, 8).astype(int)]
    ref = _render(load_head_renderer(head, device=device, samples=most, precision="fp32",
                                     reuse=None), pick, 256)
    rows = []
    for samples in sweep:
        for precision in _precisions(device):
            r = load_head_renderer(head, device=device, samples=samples,
                                   precision=precision)
            rows.append({"samples": samples, "precision": precision,
                         **_timed(r, weights, 256), "reference_samples": most,
                         "psnr_vs_reference": round(_psnr(_render(r, pick, 256), ref), 2)})
    return rows


GPU_BATCHES = (8, 32, 64)
"""Frames per generator call that the GPU part times (32 is the GPU default)."""


def _batches(head: Path, weights: np.ndarray, device: str,
             batches: tuple[int, ...] = GPU_BATCHES, samples: int | None = None,
             size: int = 256) -> list[dict[str, Any]]:
    """Frames per second against frames per generator call (``animate --batch``), with
    and without hair, in each of :func:`_precisions`; each precision's frames scored
    against float32's (uint8 frames, as written)."""
    from head360cli.fitting.pipeline import load_head_renderer

    if samples is None:
        samples = _sampling(head, device)[2]
    pick = weights[np.linspace(0, len(weights) - 1, 8).astype(int)]
    rows, refs = [], {}
    for precision in _precisions(device):
        r = load_head_renderer(head, device=device, samples=samples, size=size,
                               precision=precision)
        for hair in (True, False):
            got = np.round(255 * _render(r, pick, size, hair=hair).numpy()) / 255
            ref = refs.setdefault(hair, got)
            for batch in batches:
                rows.append({"precision": r.precision, "hair": hair, "batch": batch,
                             "samples": samples, "size": size,
                             **_timed(r, weights, size, hair=hair, batch=batch),
                             "psnr_vs_fp32": round(_psnr(got, ref), 2)})
    return rows


RESOLUTION_SIZES = (128, 256, 384, 512)
"""Image sizes of the resolution sweep (multiples of the generator's upsampling ratio)."""


def _resolution(head: Path, weights: np.ndarray, sizes=RESOLUTION_SIZES,
                samples: int | None = None, device: str = "cpu") -> list[dict[str, Any]]:
    """Frames per second and error against image size at the animation defaults.

    Each size is scored twice against float32 renders of the same frames with the most
    samples (:func:`_sampling`): at its own size (the sampling error) and, bilinearly
    upsampled, against the largest size (what rendering fewer pixels loses)."""
    import torch.nn.functional as F

    from head360cli.fitting.pipeline import load_head_renderer

    most, _, default = _sampling(head, device)
    samples = default if samples is None else samples
    pick = weights[np.linspace(0, len(weights) - 1, 4).astype(int)]
    top = max(sizes)
    refs = {size: _render(load_head_renderer(head, device=device, samples=most, size=size,
                                             precision="fp32", reuse=None), pick, size)
            for size in sizes}
    rows = []
    for size in sizes:
        r = load_head_renderer(head, device=device, samples=samples, size=size)
        got = _render(r, pick, size)
        up = F.interpolate(got, size=(top, top), mode="bilinear", align_corners=False)
        rows.append({"size": size, "samples": r.samples, "precision": r.precision,
                     **_timed(r, weights, size), "reference_samples": most,
                     "psnr_vs_reference_same_size": round(_psnr(got, refs[size]), 2),
                     f"psnr_vs_reference_{top}px": round(_psnr(up, refs[top]), 2)})
    return rows


def _reuse(head: Path, weights: np.ndarray, samples: int = 8, size: int = 256,
           precision: str = "auto") -> dict[str, Any]:
    """Frame-to-frame reuse of decoded points (a still camera, consecutive frames): its
    frame rate against decoding every point, the share of points decoded, and how far its
    frames are from the exact ones (both in ``precision``, as the renderer takes it)."""
    from head360cli.fitting.pipeline import load_head_renderer
    from head360cli.model.head_render import REUSE_TOL

    on = load_head_renderer(head, samples=samples, size=size, precision=precision)
    off = load_head_renderer(head, samples=samples, size=size, reuse=None,
                             precision=precision)
    timed_on, timed_off = _timed(on, weights, size), _timed(off, weights, size)
    got, exact = _render(on, weights, size), _render(off, weights, size)
    psnr = [_psnr(a, b) for a, b in zip(got, exact, strict=True)]
    return {"tol": REUSE_TOL, "samples": samples, "size": size, "frames": len(weights),
            "precision": on.precision,
            "fps": timed_on["fps"], "ms_per_frame": timed_on["ms_per_frame"],
            "fps_exact": timed_off["fps"], "ms_per_frame_exact": timed_off["ms_per_frame"],
            "decoded_share": round(on.last_reuse.decoded / on.last_reuse.points, 3),
            "psnr_vs_exact_min": round(min(psnr), 2),
            "max_abs_vs_exact": float(f"{float((got - exact).abs().max()):.2e}")}


def _run_cli(args: list[str]) -> dict[str, Any]:
    """Run ``head360 ARGS --json`` in a new process; its JSON plus its peak RSS.

    The peak is the process's own high-water mark (``VmHWM``), plus those of the
    processes ``animate`` spawned to render frames, if any (``worker_peak_rss_mib``: a
    sum of peaks, so at least the peak of the sum; the model's weights, shared between
    them, count in each). Linux's ``ru_maxrss`` starts a child from its parent's
    resident size at the fork, so a bench process that had grown to 1.5 GB reported
    1.5 GB for every command it ran, whatever they used."""
    code = ("import json, resource, sys\n"
            "from head360cli.cli import main\n"
            "rc = main(sys.argv[1:])\n"
            "peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024\n"
            "try:\n"
            "    with open('/proc/self/status') as f:\n"
            "        peak = next(int(line.split()[1]) / 1024 for line in f\n"
            "                    if line.startswith('VmHWM:'))\n"
            "except (OSError, StopIteration):\n"
            "    pass\n"
            "print(json.dumps({'rc': rc, 'peak_rss_mib': peak}), file=sys.stderr)\n")
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-c", code, *args, "--json", "--quiet"],
                       capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    tail = json.loads(p.stderr.strip().splitlines()[-1])
    if tail["rc"] != 0:
        raise RuntimeError(f"head360 {' '.join(args)} failed: {p.stderr.strip()[-300:]}")
    out = json.loads(p.stdout.strip().splitlines()[-1])
    peak = tail["peak_rss_mib"] + out.get("worker_peak_rss_mib", 0.0)
    return {**out, "peak_rss_mib": round(peak, 1), "wall_s": round(wall, 1)}


def _memory(head: Path, capture: Path, work: Path, device: str = "cpu") -> dict[str, Any]:
    on = ["--device", device]
    short = _run_cli(["animate", str(head), "--arkit", str(capture), "--end", "10",
                      "-o", str(work / "short.mp4"), *on])
    full = _run_cli(["animate", str(head), "--arkit", str(capture),
                     "-o", str(work / "full.mp4"), *on])
    keep = ("frames", "render_fps", "peak_rss_mib", "wall_s", "workers", "gpu_peak_mib")
    return {"first_10_s": {k: short[k] for k in keep if k in short},
            "whole": {k: full[k] for k in keep if k in full}, "capture": capture.name}


def _turning_capture(data: Path) -> tuple[Path, float] | None:
    """The capture in ``data/arkit`` whose head turns most (range of yaw, pitch or roll,
    degrees), if one turns at all."""
    from head360cli.io.arkit import read_arkit_csv

    best = None
    for path in sorted((data / "arkit").glob("*.csv")):
        rot = read_arkit_csv(path, on_bad="hold").head_rotation
        turn = 0.0 if rot is None else float(np.degrees(np.ptp(rot, axis=0).max()))
        if turn > 1.0 and (best is None or turn > best[1]):
            best = (path, turn)
    return best


def _head_pose(head: Path, capture: Path, turn: float, work: Path,
               device: str = "cpu") -> dict[str, Any]:
    runs = {name: _run_cli(["animate", str(head), "--arkit", str(capture), *extra,
                            "-o", str(work / f"{name}.mp4"), "--device", device])
            for name, extra in (("head_pose", ["--head-pose"]), ("still", []),
                                ("head_pose_one", ["--head-pose", "--workers", "1"]),
                                ("still_one", ["--workers", "1"]))}
    return {"capture": capture.name, "head_turn_deg": round(turn, 1),
            "frames": runs["head_pose"]["frames"],
            "workers": runs["head_pose"].get("workers", 1),
            "fps_head_pose": round(runs["head_pose"]["render_fps"], 2),
            "fps_still": round(runs["still"]["render_fps"], 2),
            "fps_head_pose_one_process": round(runs["head_pose_one"]["render_fps"], 2),
            "fps_still_one_process": round(runs["still_one"]["render_fps"], 2)}


def correlation(a, b, rounds: int = 1000, seed: int = 0) -> dict[str, Any] | None:
    """Pearson correlation of ``a`` and ``b`` ``(N,)`` with its 95 % bootstrap interval
    (``rounds`` resamples of the N pairs, percentiles 2.5 and 97.5; ``rounds=0``: no
    interval); ``None`` below 3 pairs or when either is constant."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if len(a) < 3 or a.std() == 0 or b.std() == 0:
        return None
    r = round(float(np.corrcoef(a, b)[0, 1]), 4)
    if rounds == 0:
        return {"r": r, "interval_95": None}
    pick = np.random.default_rng(seed).integers(0, len(a), (rounds, len(a)))
    x, y = a[pick], b[pick]
    x, y = x - x.mean(1, keepdims=True), y - y.mean(1, keepdims=True)
    den = np.sqrt((x * x).sum(1) * (y * y).sum(1))
    boot = (x * y).sum(1)[den > 0] / den[den > 0]
    if not len(boot):  # every resample constant: no interval to give
        return {"r": r, "interval_95": None}
    lo, hi = np.percentile(boot, [2.5, 97.5])
    return {"r": r, "interval_95": [round(float(lo), 4), round(float(hi), 4)]}


def _swap(head: Path, device: str = "cpu") -> dict[str, Any]:
    import cv2
    import torch

    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.fitting.pipeline import load_head_renderer
    from head360cli.geometry.cameras import project
    from head360cli.synth.hair import HAIRSTYLES

    r = load_head_renderer(head, device=device, precision="fp32")
    yaws = np.array([0.0, 30.0, -30.0])
    cams = view_cameras(yaws, 0.0)
    k = view_intrinsics(r.size)
    w = np.zeros((len(yaws), 52))
    own = np.concatenate(list(r.frames(cams, w, k))).astype(np.float64) / 255
    bald = np.concatenate(list(r.frames(cams, w, k, hair=False))).astype(np.float64) / 255
    lm = torch.tensor(r.model.landmark_points(r.neutral), dtype=torch.float32)
    pix, _ = project(lm[None].expand(len(yaws), -1, -1), cams, k)
    hulls = []
    for p in pix.numpy():
        m = np.zeros((r.size, r.size), np.uint8)
        cv2.fillConvexPoly(m, cv2.convexHull(p[:27].astype(np.int32)), 1)
        hulls.append(m > 0)
    hull = np.stack(hulls)
    hair_own = np.abs(own - bald).max(-1) > 0.05
    rows = []
    for style in SWAP_STYLES:
        if style == r.hair_style:
            continue
        other = r.with_hair(style, r.hair_colour)
        img = np.concatenate(list(other.frames(cams, w, k))).astype(np.float64) / 255
        face = hull & ~hair_own & ~(np.abs(img - bald).max(-1) > 0.05)
        rows.append({"style": HAIRSTYLES[style].name,
                     "psnr_face": round(_psnr(img[face], own[face]), 2),
                     "psnr_hull": round(_psnr(img[hull], own[hull]), 2),
                     "face_pixels": int(face.sum())})
    return {"own_style": HAIRSTYLES[r.hair_style].name, "views_yaw": yaws.tolist(),
            "styles": rows,
            "mean_psnr_face": round(float(np.mean([x["psnr_face"] for x in rows])), 2),
            "mean_psnr_hull": round(float(np.mean([x["psnr_hull"] for x in rows])), 2)}


def bench_animate(frames: int = 120, stride: int = 3, memory: bool = True,
                  progress=None, fidelity_size: int | None = None,
                  stream_path: str | Path | None = None, device: str = "cpu",
                  head_path: str | Path | None = None,
                  fidelity: bool = True, plot: str | Path | None = None
                  ) -> tuple[dict[str, Any], str]:
    """Run every part; returns ``(result, markdown)``.

    Args:
        frames: Frames of the stream per throughput measurement.
        stride: Every ``stride``-th frame of the stream for expression fidelity.
        memory: Whether to run ``head360 animate`` over the whole capture for its peak
            memory (minutes on a CPU).
        progress: Called with a line of text as each part starts.
        fidelity_size: Image size of the expression-fidelity frames (default: the
            generator's, as ``head360 animate`` renders them).
        stream_path: An ARKit CSV to drive the heads with (default: the longest Live Link
            Face capture in ``../shared/data``, else a synthetic stream).
        device: Where the heads are rendered (``cpu``, ``cuda``, ``cuda:N``); on another
            device than the CPU the reuse part is replaced by the frames-per-call part.
        head_path: A head file to measure instead of fitting the astronaut photo (the fit
            needs dlib and its model files).
        fidelity: Whether to run the expression-fidelity parts (the face tracker).
        plot: Where to draw the driving and tracked weights of the first capture's most
            active blendshapes (a PNG), if anywhere.
    """
    import torch

    from head360cli.paths import shared_data_dir

    say = progress or (lambda text: None)
    data = shared_data_dir()
    if stream_path is None:
        stream, capture = _stream(data)
    else:
        from head360cli.io.arkit import read_arkit_csv

        capture = Path(stream_path)
        stream = read_arkit_csv(capture, on_bad="hold")
        if stream.num_frames < frames:
            from head360cli.errors import BadInputError

            raise BadInputError(f"expected a stream of at least {frames} frames (--frames), "
                                f"found {stream.num_frames} in {capture.name}")
    from head360cli.bench.report import device_fields

    on_cpu = torch.device(device).type == "cpu"
    result: dict[str, Any] = {"threads": torch.get_num_threads(), **device_fields(device),
                              "stream": capture.name if capture else "synthetic",
                              "stream_frames": stream.num_frames}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        if head_path is None:
            from head360cli.fitting.pipeline import run_demo

            say("fitting the astronaut (fast preset)")
            run_demo(work, frames=4, device=device)
            head = work / "astronaut.h360"
        else:
            head = Path(head_path)
        result["head"] = "astronaut, fitted (fast preset)" if head_path is None else head.name
        weights = stream.weights[:frames]
        say("throughput against samples and precision")
        result["speed"] = _speed(head, weights, device)
        if on_cpu and _sampling(head, device)[2] is not None:  # a hex-plane generator
            say("reuse of decoded points between frames")
            result["reuse"] = _reuse(head, weights)
        else:
            say("throughput against frames per generator call")
            result["batch"] = _batches(head, weights, device)
        say("throughput and error against image size")
        result["resolution"] = _resolution(head, weights, device=device)
        if fidelity:
            result.update(_fidelity(head, data, stream, capture, stride, fidelity_size,
                                    device, say, plot))
        say("hair swap: face before and after")
        result["swap"] = _swap(head, device)
        if memory and capture is not None:
            say(f"peak memory: head360 animate on {capture.name}")
            result["memory"] = _memory(head, capture, work, device)
        turning = _turning_capture(data) if data is not None else None
        if turning is not None:
            say(f"a turning head: head360 animate --head-pose on {turning[0].name}")
            result["head_pose"] = _head_pose(head, *turning, work, device)
    result["seconds"] = round(time.perf_counter() - t0, 1)
    return result, _markdown(result)


def _fidelity(head: Path, data: Path | None, stream, capture: Path | None, stride: int,
              size: int | None, device: str, say, plot: str | Path | None
              ) -> dict[str, Any]:
    """The tracker's speed and its reading of the London portraits, then each capture
    (every Live Link Face take in ``data``, else ``stream``) through the head and
    through the corpus renderer."""
    from head360cli.bench.fidelity import (
        corpus_fidelity,
        head_fidelity,
        smile_separation,
        tracking_speed,
    )

    out: dict[str, Any] = {}
    say("the tracker: frames per second on 640 x 480 frames")
    out["tracker_speed"] = tracking_speed()
    london = data / "faces" / "london" if data is not None else None
    if london is not None and london.is_dir():
        say("the tracker on the London set's neutral and smiling portraits")
        out["tracker_smile"] = smile_separation(london)
    unread: list[str] = []
    if data is not None:
        from head360cli.bench.expressions import real_reading

        say("the tracker on the shared real photos: which blendshapes it reads at all")
        real = real_reading(data)
        if real is not None:
            out["tracker_real"] = {k: real[k] for k in ("photos", "faces", "not_read")}
            unread = real["not_read"]
    takes = [(capture.name if capture else "synthetic", stream)]
    if data is not None:
        from head360cli.io.arkit import read_arkit_csv

        found = sorted((data / "arkit").glob("livelinkface_*.csv"))
        if found:
            takes = [(p.name, read_arkit_csv(p, on_bad="hold")) for p in found]
    out["fidelity"] = []
    for name, take in takes:
        say(f"expression fidelity: {name} through the head, tracked")
        fid = head_fidelity(head, take, stride, size, device, unread)
        say(f"expression fidelity: {name} through {FIDELITY_REFERENCE} SynHead-P heads "
            "(corpus renderer), tracked")
        ref = corpus_fidelity(take, stride, FIDELITY_REFERENCE, fid["size"], unread)
        out["fidelity"].append({"take": name, "head": fid, "reference": ref})
    if plot is not None and out["fidelity"]:
        from head360cli.viz import plot_fidelity

        first = out["fidelity"][0]
        Path(plot).parent.mkdir(parents=True, exist_ok=True)
        plot_fidelity(first["head"]["series"], plot, title=f"{first['take']}: driving "
                      "(blue) and tracked (orange) weights")
        out["plot"] = str(plot)
    return out


def _fidelity_markdown(r: dict[str, Any]) -> list[str]:
    """The expression-fidelity section of :func:`_markdown`."""
    from head360cli.bench.fidelity import NAMED, TOP_ACTIVE

    lines = ["", "## Expression fidelity, read with the face tracker", ""]
    sp = r.get("tracker_speed")
    if sp:
        lines += [f"The tracker on {sp['size'][0]} x {sp['size'][1]} frames: "
                  f"{sp['fps_tracking']:.1f} frames/s tracking, {sp['fps_with_decoding']:.1f} "
                  "with decoding an mp4 (goal 60).", ""]
    sm = r.get("tracker_smile")
    if sm:
        differ = ", ".join(f"{n} {sm['auc'][n]:.3f}" for n in sm["differ"][:8])
        lines += [f"On the London set's {sm['pairs']} neutral and smiling portrait pairs "
                  f"({sm['missed']} without a face found): mouthSmile's ROC AUC "
                  f"{sm['auc_mouth_smile']:.3f} (goal 0.95); the blendshapes that differ "
                  f"most: {differ}.", ""]
    for f in r.get("fidelity", []):
        h, refs = f["head"], f["reference"]
        cols = ["blendshape", f"head ({h['faces_found']} of {h['frames']} frames)"]
        cols += [f"{x['head']} (corpus renderer)" for x in refs]
        lines += [f"### {f['take']}: Pearson r, driving against tracked (one frame in "
                  f"{h['stride']}, {h['size']} px)", "",
                  "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]

        def cell(x, name):
            v = x["r"].get(name)
            return "-" if v is None else f"{v:.3f}"

        for name in NAMED:
            lines.append(f"| {name} | {cell(h, name)} |"
                         + "".join(f" {cell(x, name)} |" for x in refs))
        mean = h["mean_r_top_active"]
        lines.append(f"| mean over the {TOP_ACTIVE} most active | "
                     f"{'-' if mean is None else format(mean, '.3f')} |"
                     + "".join(f" {x['mean_r_top_active']:.3f} |" for x in refs))
        if h.get("mean_r_top_active_read") is not None:
            lines.append(f"| mean over the {TOP_ACTIVE} most active the tracker reads on "
                         f"real faces | {h['mean_r_top_active_read']:.3f} |"
                         + "".join(f" {x['mean_r_top_active_read']:.3f} |" for x in refs))
        lines += ["", "All 52 for the head: " + ", ".join(
            f"{n} {'-' if v is None else format(v, '.2f')}" for n, v in h["r"].items())
            + " ('-': constant in the capture or in the tracked frames).", ""]
    real = r.get("tracker_real")
    if real:
        lines += [f"Blendshapes the tracker never scores above 0.2 on the {real['faces']} "
                  f"faces of the shared real photos (not read): "
                  f"{', '.join(real['not_read']) or 'none'}.", ""]
    if r.get("plot"):
        lines += [f"Plot: {r['plot']}", ""]
    return lines


def _markdown(r: dict[str, Any]) -> str:
    where = r.get("gpu") or f"{r.get('device', 'cpu')}, {r['threads']} threads"
    head = f"Head: {r['head']}. " if "head" in r else ""
    lines = ["# head360 bench animate", "",
             f"{head}Stream: {r['stream']} ({r['stream_frames']} frames); on {where}.",
             "", "## Throughput, 256 x 256 (render only)", "",
             f"| samples | networks | frames/s | ms/frame | PSNR vs "
             f"{r['speed'][0]['reference_samples'] if r['speed'] else '-'} samples |",
             "|---|---|---|---|---|"]
    lines += [f"| {s['samples']} | {s['precision']} | {s['fps']:.1f} | "
              f"{s['ms_per_frame']:.0f} | {s['psnr_vs_reference']:.2f} |"
              for s in r["speed"]]
    if "reuse" in r:
        u = r["reuse"]
        lines += ["", f"## Reuse of decoded points between frames ({u['size']} px, "
                  f"{u['samples']} samples, {u.get('precision', 'fp32')} networks, "
                  f"{u['frames']} consecutive frames, tol {u['tol']:g})", "",
                  "| | frames/s | ms/frame |", "|---|---|---|",
                  f"| reuse (default) | {u['fps']:.1f} | {u['ms_per_frame']:.0f} |",
                  f"| every point decoded (--exact) | {u['fps_exact']:.1f} | "
                  f"{u['ms_per_frame_exact']:.0f} |", "",
                  f"{100 * u['decoded_share']:.0f} % of the points decoded; frames within "
                  f"{u['max_abs_vs_exact']:.1e} of the exact ones (lowest PSNR "
                  f"{u['psnr_vs_exact_min']:.1f} dB)."]
    if "batch" in r:
        lines += ["", "## Throughput against frames per generator call (render only, "
                  "`animate --batch`)", "",
                  "| frames a call | hair | networks | frames/s | ms/frame | "
                  "PSNR vs float32 |", "|---|---|---|---|---|---|"]
        lines += [f"| {b['batch']} | {'yes' if b['hair'] else 'no'} | {b['precision']} | "
                  f"{b['fps']:.1f} | {b['ms_per_frame']:.1f} | "
                  f"{'-' if b['psnr_vs_fp32'] >= 120 else format(b['psnr_vs_fp32'], '.1f')} |"
                  for b in r["batch"]]
    if "resolution" in r:
        top = max(s["size"] for s in r["resolution"])
        most = r["resolution"][0]["reference_samples"]
        lines += ["", "## Throughput and error against image size (render only)", "",
                  f"| size | samples | networks | frames/s | ms/frame | PSNR vs {most} "
                  f"samples, same size | PSNR vs {most} samples at {top} px |",
                  "|---|---|---|---|---|---|---|"]
        lines += [f"| {s['size']} | {s['samples']} | {s['precision']} | {s['fps']:.1f} | "
                  f"{s['ms_per_frame']:.0f} | {s['psnr_vs_reference_same_size']:.2f} | "
                  f"{s[f'psnr_vs_reference_{top}px']:.2f} |" for s in r["resolution"]]
    if "fidelity" in r:
        lines += _fidelity_markdown(r)
    s = r["swap"]
    lines += ["", f"## Hair swap (own style: {s['own_style']}; views at yaw "
              f"{', '.join(f'{y:g}' for y in s['views_yaw'])})", "",
              "| style | face PSNR | hull PSNR |", "|---|---|---|"]
    lines += [f"| {x['style']} | {x['psnr_face']:.2f} | {x['psnr_hull']:.2f} |"
              for x in s["styles"]]
    lines.append(f"| mean | {s['mean_psnr_face']:.2f} | {s['mean_psnr_hull']:.2f} |")
    if "memory" in r:
        m = r["memory"]
        gpu = "gpu_peak_mib" in m["whole"]
        lines += ["", f"## Peak memory of `head360 animate` ({m['capture']})", "",
                  "| run | frames | frames/s with encoding | peak RSS MiB | wall s |"
                  + (" GPU peak MiB |" if gpu else ""),
                  "|---|---|---|---|---|" + ("---|" if gpu else "")]
        for name, v in (("first 10 s", m["first_10_s"]), ("whole capture", m["whole"])):
            lines.append(f"| {name} | {v['frames']} | {v['render_fps']:.1f} | "
                         f"{v['peak_rss_mib']:.0f} | {v['wall_s']:.0f} |"
                         + (f" {v.get('gpu_peak_mib', 0):.0f} |" if gpu else ""))
    if "head_pose" in r:
        h = r["head_pose"]
        lines += ["", f"## A turning head: `head360 animate --head-pose` ({h['capture']}, "
                  f"{h['frames']} frames, the head turns through {h['head_turn_deg']:g} "
                  "degrees)", "",
                  f"| run | frames/s with encoding ({h['workers']} processes, the "
                  "default) | with `--workers 1` |", "|---|---|---|",
                  f"| `--head-pose` (every point decoded) | {h['fps_head_pose']:.1f} | "
                  f"{h['fps_head_pose_one_process']:.1f} |",
                  f"| without (a still camera, reuse) | {h['fps_still']:.1f} | "
                  f"{h['fps_still_one_process']:.1f} |"]
    return "\n".join(lines) + "\n"

"""``head360 bench onnx``: the exported generator against torch, in error and in speed.

- Parity: one graph pair is exported (the mean head wearing a bob traces it), then ``heads``
  random heads (:func:`~head360cli.drive.sample.sample_heads`: random shape, texture,
  hairstyle and colour; every fifth rendered bald, by the bald graph; every third under a
  random light, a fit's ``colour_gain``), each with a random
  ARKit expression (a few weights up to 1, some extreme) and a random camera (any yaw,
  pitch within +-75 degrees), are rendered by torch in float32 and by onnxruntime from the
  same mesh; the largest absolute difference per image and over all.
- Speed: milliseconds per frame of one head, with and without hair, for torch float32,
  torch with bfloat16 networks (where the CPU has them) and onnxruntime: the median of
  ``rounds`` blocks of ``repeats`` frames each, the backends' blocks taking turns (frame
  times on a 2-core machine drift by a third over minutes, which timing one backend after
  the other took for a difference between them), with a pause between blocks (torch's
  and onnxruntime's thread pools would slow each other if frames were interleaved).

float16 does not apply on this CPU: onnxruntime's CPU provider has no float16 kernels for
most of the graph's operators, and torch's CPU half precision is bfloat16 (measured).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["bench_onnx", "random_expression"]


def random_expression(rng: np.random.Generator) -> np.ndarray:
    """``(52,)`` ARKit weights: about one in five active, uniform in [0, 1]; one time in
    five, a third of them at exactly 1 (extreme)."""
    w = rng.uniform(0, 1, 52) * (rng.uniform(0, 1, 52) < 0.2)
    if rng.uniform() < 0.2:
        w[rng.uniform(0, 1, 52) < 0.33] = 1.0
    return w


def _frame_seconds(fn, repeats: int) -> list[float]:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return times


def bench_onnx(heads: int = 100, size: int = 256, samples: int | None = None,
               repeats: int = 10,
               seed: int = 0, graph: str | Path | None = None,
               progress: Any = None, rounds: int = 3, device: str = "cpu"
               ) -> tuple[dict[str, Any], str]:
    """Run the benchmark; returns the result and a Markdown summary.

    Args:
        heads: Random heads (and as many expressions and cameras) for parity.
        size: Image size of the exported graph.
        samples: Samples a pixel (per ray for hex-plane weights) of the exported graph
            (default: the generator's own).
        repeats: Timed frames per block.
        rounds: Blocks per backend and hair setting, taking turns.
        seed: Seed of heads, expressions and cameras.
        graph: An exported graph to use (its size and samples); default: export one.
        progress: ``progress(text)`` callback.
        device: Torch device of the timed torch rows (parity is always on the CPU);
            onnxruntime then runs on CUDA too where its build has that provider.
    """
    import torch

    from head360cli.bench.report import machine, markdown_table
    from head360cli.devices import fast_bfloat16
    from head360cli.drive.sample import sample_heads
    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.export.onnx import OnnxFrameRunner, export_onnx
    from head360cli.model.head_render import HeadRenderer
    from head360cli.model.train import load_generator

    say = progress or (lambda text: None)
    rounds = max(int(rounds), 1)
    gen, _ = load_generator()
    tmp = tempfile.TemporaryDirectory()
    export_s = None
    if graph is None:
        mean = sample_heads(1, scale=0.0, lids=False)[0].arrays
        r = HeadRenderer(gen, mean["shape"], torch.as_tensor(mean["texture"]), 11,
                         mean["hair_color"], samples=samples, size=size, precision="fp32")
        say(f"exporting the generator ({size} px, {r.samples} samples)")
        graph = Path(tmp.name) / "generator.onnx"
        export_s = round(export_onnx(r, graph)["seconds"], 1)
    runner = OnnxFrameRunner(graph)  # parity: the CPU's, against torch on the CPU
    size, samples = runner.size, int(runner.meta["samples"])
    k = view_intrinsics(size)
    rng = np.random.default_rng(seed)
    lights = np.random.default_rng(seed + 2)  # apart, so the heads' draws stay as they were
    rows, worst = [], 0.0
    for i, head in enumerate(sample_heads(heads, seed=seed + 1, lids=False)):
        a = head.arrays
        # every third head under a light of its own, as a fit's
        light = lights.uniform(0.6, 1.5, 3) if i % 3 == 2 else None
        r = HeadRenderer(gen, a["shape"], torch.as_tensor(a["texture"]),
                         int(a["hair_style"]), a["hair_color"], samples=samples, size=size,
                         precision="fp32", colour_gain=light)
        w = random_expression(rng)
        yaw, pitch = float(rng.uniform(-180, 180)), float(rng.uniform(-75, 75))
        cam = view_cameras(yaw, pitch)
        hair = i % 5 != 4
        ref = r.render(cam, k, w, hair=hair).numpy()
        r.use_runner(runner)
        got = r.render(cam, k, w, hair=hair).numpy()
        diff = float(np.abs(got - ref).max())
        worst = max(worst, diff)
        rows.append({"head": i, "hair_style": int(a["hair_style"]) if hair else 0,
                     "light": None if light is None else [round(float(g), 3) for g in light],
                     "yaw": round(yaw, 1), "pitch": round(pitch, 1),
                     "active_weights": int((w > 0).sum()),
                     "max_abs_diff": diff, "finite": bool(np.isfinite(got).all())})
        if (i + 1) % 10 == 0:
            say(f"parity: {i + 1}/{heads} heads, largest difference so far {worst:.2e}")

    say("timing torch and onnxruntime")
    dev = torch.device(device)
    timed_gen = gen if dev.type == "cpu" else load_generator(device=str(dev))[0]
    timed_runner = (runner if dev.type != "cuda" else
                    OnnxFrameRunner(graph, providers=["CUDAExecutionProvider"]))
    a = sample_heads(1, seed=seed + 1, lids=False)[0].arrays
    cam, w = view_cameras(20.0, 5.0), np.zeros(52)
    runs, where = {}, {}
    backends = [("torch", "fp32"), ("torch", "bf16"), ("onnxruntime", "fp32")]
    for backend, precision in backends:
        if precision == "bf16" and not fast_bfloat16(dev):
            continue
        r = HeadRenderer(timed_gen, a["shape"], torch.as_tensor(a["texture"], device=dev),
                         11, a["hair_color"], samples=samples, size=size,
                         precision=precision)
        where[backend] = str(dev)
        if backend == "onnxruntime":
            r.use_runner(timed_runner)
            where[backend] = timed_runner.provider.replace("ExecutionProvider", "")
        for hair in (True, False):
            runs[backend, precision, hair] = (
                lambda r=r, hair=hair: r.render(cam, k, w, hair=hair), [])
    for i in range(rounds):
        for fn, times in runs.values():
            time.sleep(0.5)  # let the other runtime's worker threads go idle
            if i == 0:
                fn()  # warm-up
            times.extend(_frame_seconds(fn, repeats))
    speed = []
    for (backend, precision, hair), (_, times) in runs.items():
        ms = round(1000 * float(np.median(times)), 1)
        speed.append({"backend": backend, "on": where[backend], "precision": precision,
                      "hair": "yes" if hair else "no", "ms_per_frame": ms,
                      "fps": round(1000 / ms, 2),
                      "spread_ms": [round(1000 * float(q), 1)
                                    for q in np.percentile(times, [10, 90])]})
    base = {s["hair"]: s["ms_per_frame"] for s in speed
            if s["backend"] == "torch" and s["precision"] == "fp32"}
    for s in speed:
        s["speed_vs_torch_fp32"] = round(base[s["hair"]] / s["ms_per_frame"], 2)
    tmp.cleanup()
    diffs = np.array([r["max_abs_diff"] for r in rows])
    result = {
        "machine": machine(), "size": size, "samples": samples, "export_s": export_s,
        "timing": {"rounds": rounds, "frames_per_block": repeats},
        "parity": {"heads": heads, "max_abs_diff": worst,
                   "median_max_abs_diff": float(np.median(diffs)),
                   "images_over_1e-3": int((diffs > 1e-3).sum()),
                   "all_finite": all(r["finite"] for r in rows), "rows": rows},
        "speed": speed,
        "fp16": "no float16 graph: onnxruntime's CPU provider lacks float16 kernels; "
                "torch's half precision row is bfloat16, where the device runs it fast",
    }
    md = (f"ONNX parity over {heads} random heads, expressions and cameras ({size} px, "
          f"{samples} samples): largest absolute difference {worst:.2e} "
          f"(median per image {np.median(diffs):.2e}; {result['parity']['images_over_1e-3']}"
          f" images over 1e-3)\n\n"
          + markdown_table([{**s, "10th-90th_ms": "{} - {}".format(*s["spread_ms"])}
                            for s in speed],
                           ["backend", "on", "precision", "hair", "ms_per_frame",
                            "10th-90th_ms",
                            "fps", "speed_vs_torch_fp32"])
          + f"\n\nMedian of {rounds} blocks of {repeats} frame(s) per row, the "
            f"backends taking turns.")
    return result, md

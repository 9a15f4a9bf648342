"""``head360 bench summary``: every stage's speed against error in one table and one plot.

It reads the JSON files the stage benchmarks wrote into one folder (``fit_shape.json``,
``fit.json``, ``generator.json``, ``animate.json``, ``onnx.json``, ``synth.json``; any may
be missing) and writes ``bench.json``, ``bench.md`` (one row per measured setting: stage,
setting, milliseconds, error) and ``bench.png`` (one panel per stage, error against time
on a logarithmic time axis). Nothing is measured here; ``head360 bench all`` runs the
stages first.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

__all__ = ["STAGE_FILES", "STAGE_RUNS", "collect", "plot", "summarize"]

STAGE_FILES = ("fit_shape", "fit", "generator", "animate", "onnx", "synth")
"""The stage benchmarks' result names, in pipeline order."""

STAGE_RUNS = {
    "fit-shape": ([], ["--trials", "20"]),
    "fit": ([], ["--identities", "1", "--preset", "fast", "--stability", "1"]),
    "generator": ([], ["--train-ids", "1", "--test-ids", "0", "--cameras", "2"]),
    "animate": ([], ["--frames", "24", "--no-memory", "--stride", "60"]),
    "onnx": ([], ["--heads", "10", "--size", "128", "--repeats", "5"]),
    "synth": ([], ["-n", "4"]),
}
"""``head360 bench all``'s stages: subcommand -> (arguments, arguments with --quick)."""


def _row(stage: str, setting: str, ms: float, metric: str, value: float | None,
         better: str) -> dict[str, Any]:
    return {"stage": stage, "setting": setting, "ms": round(float(ms), 2), "metric": metric,
            "value": None if value is None else round(float(value), 6), "better": better}


def collect(results: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """Rows ``{stage, setting, ms, metric, value, better}`` from the stage results (by
    name, as loaded from their JSON files)."""
    rows: list[dict[str, Any]] = []
    r = results.get("fit_shape")
    if r:
        for s in r.get("iterations_sweep", []):
            rows.append(_row("shape fit", f"{s['iterations']} iterations", s["fit_ms_median"],
                             "NME % (real photos, yaw 0-30)",
                             s.get("real_nme_fit_%_yaw0-30"), "lower"))
    r = results.get("fit")
    if r:
        for s in r.get("sweep", []):
            rows.append(_row("inversion", f"{s['texture_steps']} texture steps",
                             1000 * s["invert_s"], "face PSNR dB (photo)", s["psnr_face"],
                             "higher"))
    r = results.get("generator")
    if r:
        for s in r.get("sweep", []):
            setting = (f"{s['pixel_samples']} samples a pixel" if "pixel_samples" in s
                       else f"{s['samples']} samples, planes {s['plane_res']}")
            rows.append(_row("render (generator)", setting, s["ms_hair"],
                             "PSNR dB vs ground truth, with hair", s["psnr_hair"],
                             "higher"))
    r = results.get("animate")
    if r:
        for s in r.get("speed", []):
            most = s.get("reference_samples", 32)  # results from before 0.5.0: 32
            rows.append(_row("render (animation)", f"{s['samples']} samples, {s['precision']}",
                             s["ms_per_frame"], f"PSNR dB vs {most} samples",
                             s.get("psnr_vs_reference", s.get("psnr_vs_32_samples")),
                             "higher"))
        u = r.get("reuse")
        if u:  # reuse between frames: its time against how far it is from decoding all
            rows.append(_row("reuse between frames", f"tol {u['tol']:g}, {u['samples']} "
                             f"samples", u["ms_per_frame"], "lowest frame PSNR dB vs exact",
                             u["psnr_vs_exact_min"], "higher"))
            rows.append(_row("reuse between frames", f"exact, {u['samples']} samples",
                             u["ms_per_frame_exact"], "(the reference)", None, ""))
        sweep = r.get("resolution", [])
        top = max((s["size"] for s in sweep), default=0)
        for s in sweep:
            most = s.get("reference_samples", 32)
            rows.append(_row("render (image size)", f"{s['size']} px, {s['samples']} samples, "
                             f"{s['precision']}", s["ms_per_frame"],
                             f"PSNR dB vs {most} samples at {top} px",
                             s.get(f"psnr_vs_reference_{top}px",
                                   s.get(f"psnr_vs_32_samples_{top}px")), "higher"))
    r = results.get("onnx")
    if r:
        worst = r["parity"]["max_abs_diff"]
        for s in r.get("speed", []):
            onnx = s["backend"] == "onnxruntime"
            rows.append(_row("torch vs onnxruntime",
                             f"{s['backend']} {s['precision']} "
                             f"{'hair' if s['hair'] == 'yes' else 'bald'}",
                             s["ms_per_frame"], "largest abs difference from torch fp32",
                             worst if onnx else (0.0 if s["precision"] == "fp32" else None),
                             "lower"))
    r = results.get("synth")
    if r:
        for s in r.get("render", []):
            rows.append(_row("corpus renderer", f"{s['size']} px, {s['aa_samples']} AA, "
                             f"batch {s['batch']}", s["ms_per_view"], "", None, ""))
    return rows


def plot(rows: list[dict[str, Any]], path: str | Path, panel: int = 320) -> None:
    """Draw error against time (log axis), one panel per stage with numbers, as a PNG."""
    from PIL import Image, ImageDraw

    from head360cli.io.atomic import atomic_path

    stages = [s for s in dict.fromkeys(r["stage"] for r in rows)
              if any(r["value"] is not None for r in rows if r["stage"] == s)]
    cols = min(max(len(stages), 1), 3)
    nrows = max(math.ceil(len(stages) / cols), 1)
    img = Image.new("RGB", (cols * panel, nrows * panel), "white")
    draw = ImageDraw.Draw(img)
    left, top, pad = 52, 34, 16
    for n, stage in enumerate(stages):
        pts = [(r["ms"], r["value"], r["setting"]) for r in rows
               if r["stage"] == stage and r["value"] is not None and r["ms"] > 0]
        ox, oy = (n % cols) * panel, (n // cols) * panel
        x0, y0, x1, y1 = ox + left, oy + top, ox + panel - pad, oy + panel - 40
        draw.rectangle([x0, y0, x1, y1], outline=(120, 120, 120))
        metric = next(r["metric"] for r in rows if r["stage"] == stage)
        draw.text((ox + 8, oy + 6), stage, fill="black")
        draw.text((ox + 8, oy + 18), metric[:48], fill=(90, 90, 90))
        if not pts:
            continue
        lx = [math.log10(p[0]) for p in pts]
        vy = [p[1] for p in pts]
        xa, xb = min(lx) - 0.1, max(lx) + 0.1
        span = (max(vy) - min(vy)) or abs(max(vy)) or 1.0
        ya, yb = min(vy) - 0.1 * span, max(vy) + 0.1 * span
        placed: list[tuple[float, float]] = []
        for (_ms, v, label), lxv in zip(pts, lx, strict=True):
            px = x0 + (lxv - xa) / (xb - xa) * (x1 - x0)
            py = y1 - (v - ya) / (yb - ya) * (y1 - y0)
            draw.ellipse([px - 4, py - 4, px + 4, py + 4], fill=(30, 90, 200))
            ty = py - 6
            while any(abs(ty - qy) < 11 and abs(px - qx) < 110 for qx, qy in placed):
                ty += 12  # move the label below one it would overwrite
            placed.append((px, ty))
            text = label[:22]
            tx = px + 6
            if tx + draw.textlength(text) > ox + panel - 2:  # would leave the panel
                tx = px - 6 - draw.textlength(text)
            draw.text((tx, ty), text, fill=(60, 60, 60))
        draw.text((x0, y1 + 6), f"{10 ** xa:.3g} ms", fill="black")
        draw.text((x1 - 60, y1 + 6), f"{10 ** xb:.3g} ms", fill="black")
        draw.text((ox + 4, y0), f"{yb:.3g}", fill="black")
        draw.text((ox + 4, y1 - 10), f"{ya:.3g}", fill="black")
        draw.text((x0 + 60, y1 + 20), "time per call (log)", fill=(90, 90, 90))
    with atomic_path(path) as tmp:
        img.save(tmp, format="PNG")


def summarize(folder: str | Path, out_dir: str | Path | None = None
              ) -> tuple[dict[str, Any], str]:
    """Collect the stage results in ``folder`` and write ``bench.json``, ``bench.md`` and
    ``bench.png`` into ``out_dir`` (default: the same folder).

    Raises:
        BadInputError: The folder holds no stage results.
        FileFormatError: A stage's file is not JSON, or not what its benchmark writes.
    """
    from head360cli.bench.report import markdown_table, save
    from head360cli.errors import BadInputError, FileFormatError

    folder = Path(folder)
    results = {}
    for name in STAGE_FILES:
        path = folder / f"{name}.json"
        if path.is_file():
            try:
                results[name] = json.loads(path.read_text())
            except (ValueError, UnicodeDecodeError) as exc:
                raise FileFormatError(f"{path}: expected the JSON that head360 bench "
                                      f"writes, found unreadable text ({exc})") from None
    if not results:
        names = ", ".join(f + ".json" for f in STAGE_FILES)
        raise BadInputError(f"expected stage results ({names}) in {str(folder)!r}, found "
                            "none")
    rows = []
    for name, r in results.items():  # one stage at a time, to name the file at fault
        try:
            rows += collect({name: r})
        except (KeyError, TypeError, AttributeError) as exc:
            raise FileFormatError(
                f"{folder / (name + '.json')}: expected the results of head360 bench "
                f"{name.replace('_', '-')}, found another layout ({type(exc).__name__}: "
                f"{exc})") from None
    md = ("Speed against error, every stage (this machine; from "
          + ", ".join(f"{n}.json" for n in results) + ")\n\n"
          + markdown_table([{**r, "value": "" if r["value"] is None else f"{r['value']:.4g}"}
                            for r in rows],
                           ["stage", "setting", "ms", "metric", "value", "better"]))
    out = Path(out_dir or folder)
    result = {"stages": list(results), "rows": rows}
    files = save(result, md, out, "bench")
    plot(rows, out / "bench.png")
    result["files"] = [*files, str(out / "bench.png")]
    return result, md

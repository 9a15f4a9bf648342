"""Writing benchmark results: one JSON file and one Markdown table per benchmark."""

from __future__ import annotations

import platform
from pathlib import Path
from typing import Any

__all__ = ["device_fields", "machine", "markdown_table", "per_generator", "save"]


def machine() -> dict[str, Any]:
    """What the numbers were measured on."""
    import os

    import torch

    from head360cli.devices import fast_bfloat16

    cpu = platform.processor()
    try:  # the model name says more than the architecture; timings differ between CPUs
        with open("/proc/cpuinfo") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f
                        if line.startswith("model name")), cpu)
    except OSError:
        pass
    return {"cpu": cpu, "cpu_bf16": fast_bfloat16("cpu"),
            "cpu_cores": os.cpu_count(), "torch_threads": torch.get_num_threads(),
            "torch": torch.__version__, "platform": platform.platform(),
            "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None}


def per_generator(weights: tuple[str, ...], run) -> tuple[dict[str, Any], str]:
    """``run(label)`` -> ``(result, markdown)`` once per generator weights file, each
    standing for the installed one (:func:`~head360cli.paths.use_generator`); the
    results keyed by file name under ``generators``, the Markdown in sections. No
    weights: one run of the installed generator, as it returns."""
    from head360cli.paths import use_generator

    if not weights:
        return run(None)
    results: dict[str, Any] = {}
    parts = []
    for path in weights:
        label = Path(path).stem
        if label in results:
            label = f"{label} ({path})"
        with use_generator(path):
            result, md = run(label)
        results[label] = result
        parts.append(f"## Generator {label} ({path})\n\n{md}")
    return {"generators": results}, "\n\n".join(parts)


def device_fields(device: str) -> dict[str, Any]:
    """A result's ``device`` and, on a GPU, its ``gpu`` (the device's name)."""
    import torch

    out: dict[str, Any] = {"device": device}
    if torch.device(device).type != "cpu":
        out["gpu"] = torch.cuda.get_device_name(torch.device(device))
    return out


def markdown_table(rows: list[dict[str, Any]], columns: list[str]) -> str:
    """A Markdown table of ``rows`` with the given column keys."""
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    for row in rows:
        lines.append("| " + " | ".join(str(row.get(c, "")) for c in columns) + " |")
    return "\n".join(lines)


def save(result: dict[str, Any], markdown: str, out_dir: str | Path, name: str) -> list[str]:
    """Write ``<name>.json`` and ``<name>.md`` into ``out_dir`` (atomically)."""
    from head360cli.io.atomic import atomic_paths
    from head360cli.io.jsontext import dumps

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [str(out / f"{name}.json"), str(out / f"{name}.md")]
    with atomic_paths(*paths) as (tmp_json, tmp_md):  # renamed together once both are written
        tmp_json.write_text(dumps(result, indent=1))
        tmp_md.write_text(markdown + "\n")
    return paths

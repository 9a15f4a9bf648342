"""Collect the ``*.result.json`` files of a batch run into one CSV on stdout.

    python examples/batch/collect.py OUT_DIR > results.csv

One row per input: its name, whether it succeeded, the error type and message when not,
and the main numbers of a fit (hairstyle, hair colour, face PSNR, seconds) or of an
animation (frames, frames per second). Uses only the standard library.
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

COLUMNS = ["name", "ok", "error_type", "error", "hair_style", "hair_color",
           "psnr_face_input_view", "seconds", "frames", "render_fps", "files"]


def row(path: Path) -> dict[str, object]:
    name = path.name[: -len(".result.json")]
    try:
        r = json.loads(path.read_text() or "{}")
    except json.JSONDecodeError as exc:
        return {"name": name, "ok": False, "error_type": "BadJSON", "error": str(exc)}
    if r.get("ok") is False or "error" in r:
        e = r.get("error", {})
        return {"name": name, "ok": False, "error_type": e.get("type", ""),
                "error": e.get("message", "")}
    if not r:
        return {"name": name, "ok": False, "error_type": "NoOutput", "error": "empty"}
    files = r.get("files", {})
    return {"name": name, "ok": True,
            "hair_style": (r.get("hair_style") or {}).get("name", ""),
            "hair_color": r.get("hair_color_name", ""),
            "psnr_face_input_view": r.get("psnr_face_input_view", ""),
            "seconds": (r.get("timings") or {}).get("total", r.get("render_seconds", "")),
            "frames": r.get("frames", ""), "render_fps": r.get("render_fps", ""),
            "files": " ".join(files.values()) if isinstance(files, dict) else ""}


def main(argv: list[str]) -> int:
    if len(argv) != 1 or not Path(argv[0]).is_dir():
        print("usage: python examples/batch/collect.py OUT_DIR > results.csv",
              file=sys.stderr)
        return 2
    writer = csv.DictWriter(sys.stdout, COLUMNS, extrasaction="ignore")
    writer.writeheader()
    for path in sorted(Path(argv[0]).glob("*.result.json")):
        writer.writerow(row(path))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

"""Regenerate examples/figures/corpus_old_new.png: corpus heads as the shipped generator
learnt them (painted skin, stepped hairlines) beside the same heads with the options a
more human corpus adds (the skin detail of a real head scan, soft hairlines), from the
front, 45 and 90 degrees and behind.

The scan is Lee Perry-Smith's head ("Infinite, 3D Head Scan by Lee Perry-Smith is licensed
under a Creative Commons Attribution 3.0 Unported License. Based on a work at
www.triplegangers.com"), read from ``../shared/assets/lps_head_scan``. Run from the
repository root (about a minute on 2 CPU cores, more the first time, while the scan's
atlas is made):

    python examples/make_corpus_figure.py
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import torch

from head360cli.geometry.cameras import (
    RIG_DISTANCE,
    RIG_FOV_DEG,
    camera_on_sphere,
    intrinsics_from_fov,
)
from head360cli.synth.scene import make_head, render_head

OUT = Path("examples/figures/corpus_old_new.png")
SCAN = Path("../shared/assets/lps_head_scan")
HEADS = (1, 3, 6)
YAWS = (0.0, 45.0, 90.0, 180.0)
TILE, MARGIN = 192, 150


def _label(text: str) -> np.ndarray:
    pad = np.full((TILE, MARGIN, 3), 255, np.uint8)
    for i, line in enumerate(text.split("\n")):
        cv2.putText(pad, line, (8, TILE // 2 - 10 + 20 * i), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                    (30, 30, 30), 1, cv2.LINE_AA)
    return pad


def main() -> None:
    if not SCAN.is_dir():
        raise SystemExit(f"the head scan is not at {SCAN}")
    cams = camera_on_sphere(torch.tensor(YAWS), torch.zeros(len(YAWS)), 0.8 * RIG_DISTANCE)
    k = intrinsics_from_fov(RIG_FOV_DEG, TILE, TILE)
    rows = []
    for index in HEADS:
        for new in (False, True):
            head = make_head(index, skin_scan=str(SCAN) if new else None, soft_hair=new)
            out = render_head(head, np.zeros(52), cams, k, TILE, samples=4)
            tiles = [(img.clamp(0, 1).permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
                     for img in out.rgb]
            name = f"head {index}\n" + ("scan skin,\nsoft hair" if new else "painted,\nstepped")
            rows.append(np.hstack([_label(name), *tiles]))
    OUT.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(OUT), np.vstack(rows)[:, :, ::-1])
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()

"""Regenerate the README's animation, turntable and hairstyle pictures.

The head is scikit-image's astronaut fitted with the fast preset (``head360 demo``); the
stream is the bundled ``examples/smile_blink_livelinkface.csv``.

- ``examples/figures/animate_astronaut.gif``: the stream with its head rotation, 15 fps;
- ``examples/figures/turntable_astronaut.gif``: 36 views turning once around the head;
- ``examples/figures/styles_astronaut.png``: ``head360 swap-hair --list``'s contact sheet.

Run from the repository root (about 2 minutes on 2 CPU cores); name some of ``animate``,
``turntable`` and ``styles`` to regenerate only those:

    python examples/make_drive_figures.py
    python examples/make_drive_figures.py animate
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from PIL import Image
from skimage import data

from head360cli.drive.animate import AnimateConfig, prepare_stream
from head360cli.drive.hair_swap import style_sheet
from head360cli.drive.views import view_cameras, view_intrinsics
from head360cli.fitting.pipeline import fit_photo, load_head_renderer
from head360cli.io.arkit import read_arkit_csv

FIGURES = Path("examples/figures")
STREAM = Path("examples/smile_blink_livelinkface.csv")
SIZE = 176


def _gif(frames: list[np.ndarray], path: Path, fps: float) -> None:
    images = [Image.fromarray(f).resize((SIZE, SIZE), Image.Resampling.LANCZOS)
              for f in frames]
    images[0].save(path, save_all=True, append_images=images[1:], loop=0,
                   duration=round(1000 / fps), optimize=True)


PARTS = ("animate", "turntable", "styles")


def main(parts: tuple[str, ...] = PARTS) -> None:
    from head360cli.drive.animate import head_pose_cameras

    unknown = set(parts) - set(PARTS)
    if unknown:
        raise SystemExit(f"expected some of {', '.join(PARTS)}, found {sorted(unknown)}")

    with tempfile.TemporaryDirectory() as tmp:
        photo = Path(tmp) / "astronaut.png"
        Image.fromarray(data.astronaut()).save(photo)
        fit_photo(photo, Path(tmp) / "astronaut.h360")
        r = load_head_renderer(Path(tmp) / "astronaut.h360", samples=None)
        k = view_intrinsics(r.size)
        if "animate" in parts:
            stream = prepare_stream(read_arkit_csv(STREAM),
                                    AnimateConfig(fps=15.0, head_pose=True))
            cams = head_pose_cameras(stream.head_rotation, view_cameras(0.0, 0.0)[0])
            frames = [f for b in r.frames(cams, stream.weights, k) for f in b]
            _gif(frames, FIGURES / "animate_astronaut.gif", 15.0)
        if "turntable" in parts:
            yaws = np.arange(36) * 10.0
            turn = [f for b in r.frames(view_cameras(yaws, 5.0), np.zeros((36, 52)), k)
                    for f in b]
            _gif(turn, FIGURES / "turntable_astronaut.gif", 12.0)
        if "styles" in parts:
            style_sheet(load_head_renderer(Path(tmp) / "astronaut.h360"),
                        FIGURES / "styles_astronaut.png", size=112)
    print(f"wrote {', '.join(parts)} into {FIGURES}")


if __name__ == "__main__":
    import sys

    main(tuple(sys.argv[1:]) or PARTS)

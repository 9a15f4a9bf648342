"""Regenerate ``examples/figures/blink_dlib.png``: what dlib sees of an open and a closed
eye, on the corpus renderer's ground truth and on the generator's frames.

Rows: a held-out SynHead-P head (test split, corpus seed 0) rendered by the corpus
renderer (ground truth, no generator); the first head ``head360 sample --seed 0`` draws,
without and with its lid change (``--no-lid-fit``; see ``head360cli/fitting/lids.py``);
the astronaut fitted with the fast preset, without and with its lid change. Columns: eyes
open and both eyes closed (eyeBlinkLeft = eyeBlinkRight = 1), at 256 and at 512 pixels.
Each tile is the eye region of a frontal frame, scaled to one size, with dlib's 12 eye
landmarks drawn in and the mean eye opening (eyelid gap over eye width, as ``head360 bench
animate`` measures it) written below.

Run from the repository root (about 2 minutes on 2 CPU cores):

    python examples/make_blink_figure.py
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

FIGURE = Path("examples/figures/blink_dlib.png")
SIZES = (256, 512)
TILE = (320, 120)
"""Width and height of a tile: the eye band of a frontal frame, scaled."""
BAND = (0.33, 0.47, 0.30, 0.70)
"""The eye band as fractions of a frontal frame: top, bottom, left, right."""


def _frames(size: int, head_files: dict[str, Path]) -> dict[str, list[np.ndarray]]:
    """Open and closed frontal frames ``(size, size, 3)`` uint8 of every row."""
    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.fitting.pipeline import load_head_renderer
    from head360cli.mesh.arkit52 import INDEX
    from head360cli.model.head_render import to_uint8
    from head360cli.synth.scene import make_head, prepare_render, render_head

    closed = np.zeros(52, np.float32)
    closed[[INDEX["eyeBlinkLeft"], INDEX["eyeBlinkRight"]]] = 1.0
    weights = (np.zeros(52, np.float32), closed)
    cam, k = view_cameras(0.0, 0.0), view_intrinsics(size)
    truth = make_head(0, "test", 0)
    prepare_render(truth, "cpu")
    rows = {"SynHead-P ground truth": [
        to_uint8(render_head(truth, w, cam, k, size, with_hair=False).rgb)[0]
        for w in weights]}
    for name, path in head_files.items():
        r = load_head_renderer(path, size=size, precision="fp32")
        rows[name] = [to_uint8(r.render(cam, k, w))[0] for w in weights]
    return rows


def _tile(frame: np.ndarray) -> Image.Image:
    """The eye band of a frame with dlib's eye landmarks and the eye opening."""
    from head360cli.bench.animate import eye_opening
    from head360cli.errors import NoFaceError
    from head360cli.fitting.landmarks import LandmarkDetector

    size = frame.shape[0]
    top, bottom, left, right = (round(f * size) for f in BAND)
    band = Image.fromarray(frame[top:bottom, left:right]).resize(TILE, Image.LANCZOS)
    scale = TILE[0] / (right - left)
    draw = ImageDraw.Draw(band)
    try:
        lm = LandmarkDetector("hog").detect_one(frame).landmarks
    except NoFaceError:
        draw.text((4, TILE[1] - 14), "no face found", fill=(200, 0, 0))
        return band
    for x, y in lm[36:48]:
        u, v = (x - left) * scale, (y - top) * scale
        draw.ellipse((u - 2.5, v - 2.5, u + 2.5, v + 2.5), fill=(0, 220, 0))
    opening = (eye_opening(lm, "left") + eye_opening(lm, "right")) / 2
    draw.text((4, TILE[1] - 14), f"eye opening {opening:.2f}", fill=(0, 0, 0))
    return band


def main() -> None:
    from head360cli.drive.sample import sample_heads, write_samples
    from head360cli.fitting.pipeline import fit_photo

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        from skimage import data

        photo = work / "astronaut.png"
        Image.fromarray(data.astronaut()).save(photo)
        fit_photo(photo, work / "astronaut.h360", preset="fast")
        fit_photo(photo, work / "astronaut_no_lids.h360", preset="fast", closed_lids=False)
        (sampled,) = write_samples(sample_heads(1, seed=0), work)
        (bare,) = write_samples(sample_heads(1, seed=0, lids=False), work, "bare")
        heads = {"sampled head 0, no lid change": bare,
                 "sampled head 0, lid change": sampled,
                 "fitted astronaut, no lid change": work / "astronaut_no_lids.h360",
                 "fitted astronaut, lid change": work / "astronaut.h360"}
        by_size = {size: _frames(size, heads) for size in SIZES}
    names = list(by_size[SIZES[0]])
    label_w, head_h = 190, 18
    sheet = Image.new("RGB", (label_w + TILE[0] * 2 * len(SIZES),
                              head_h + TILE[1] * len(names)), "white")
    draw = ImageDraw.Draw(sheet)
    for j, size in enumerate(SIZES):
        for c, state in enumerate(("eyes open", "eyes closed")):
            draw.text((label_w + (2 * j + c) * TILE[0] + 4, 3), f"{state}, {size} px",
                      fill=(0, 0, 0))
    for i, name in enumerate(names):
        draw.text((4, head_h + i * TILE[1] + TILE[1] // 2 - 6), name, fill=(0, 0, 0))
        for j, size in enumerate(SIZES):
            for c, frame in enumerate(by_size[size][name]):
                sheet.paste(_tile(frame), (label_w + (2 * j + c) * TILE[0],
                                           head_h + i * TILE[1]))
    FIGURE.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(FIGURE)
    print(f"wrote {FIGURE}")


if __name__ == "__main__":
    main()

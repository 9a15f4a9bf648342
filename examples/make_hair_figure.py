"""Regenerate examples/figures/hairlines_before_after.png: fitted heads from the front,
both sides and behind, with the stepped hairlines the deferred generator drew before
0.5.2 and the soft ones it draws since.

The heads: scikit-image's astronaut photo (public domain, NASA) and, where
``../shared/data`` holds them, the frontal photos of Pointing'04 persons 2 and 4 (curly
hair; N. Gourier, D. Hall, J. L. Crowley, Pointing 2004, ICPR Workshop). Each photo is
fitted once per kind of hairline. Run from the repository root (about two minutes on 2
CPU cores):

    python examples/make_hair_figure.py
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

OUT = Path("examples/figures/hairlines_before_after.png")
YAWS = (0.0, -90.0, 90.0, 180.0)
SIZE = 160


def photos(work: Path) -> list[tuple[str, Path]]:
    """``(label, path)`` of the photos to fit."""
    from skimage import data

    from head360cli.bench.multiview import read_pointing04
    from head360cli.paths import shared_data_dir

    astronaut = work / "astronaut.png"
    Image.fromarray(data.astronaut()).save(astronaut)
    out: list[tuple[str, Path]] = [("astronaut", astronaut)]
    shared = shared_data_dir()
    folder = None if shared is None else shared / "multiview" / "pointing04"
    if folder is not None and (folder / "index.csv").is_file():
        rows = read_pointing04(folder)
        for person in (2, 4):
            out += [(f"person {person}", r["path"]) for r in rows
                    if r["person"] == person and r["series"] == 1 and r["tilt_deg"] == 0
                    and r["pan_deg"] == 0]
    return out


def views(head_file: Path) -> np.ndarray:
    """``(4, SIZE, SIZE, 3)`` uint8: the head from :data:`YAWS`."""
    import cv2

    from head360cli.drive.views import head_framing, view_cameras, view_intrinsics
    from head360cli.fitting.pipeline import load_head_renderer
    from head360cli.model.head_render import to_uint8

    head = load_head_renderer(head_file, precision="fp32")
    rgb = to_uint8(head.render(view_cameras(YAWS, 0.0, head_framing(head)),
                               view_intrinsics(head.size)))
    return np.stack([cv2.resize(x, (SIZE, SIZE), interpolation=cv2.INTER_AREA) for x in rgb])


def main() -> None:
    from head360cli.drive.views import grid_image
    from head360cli.fitting.pipeline import fit_photo
    from head360cli.model.deferred import DeferredGenerator

    images, labels = [], []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for name, photo in photos(work):
            for soft, kind in ((False, "stepped"), (True, "soft")):
                # the stepped hairlines are drawn by switching the generator's rule back
                DeferredGenerator.soft_hairlines = soft
                head = work / f"{len(images)}.h360"
                fit_photo(photo, head, preset="fast")
                images.extend(views(head))
                labels += [f"{name} {kind} {yaw:+.0f}" for yaw in YAWS]
        DeferredGenerator.soft_hairlines = True
    OUT.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(grid_image(np.stack(images), labels, cols=len(YAWS))).save(OUT)
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()

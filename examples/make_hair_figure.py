"""Regenerate examples/figures/hair_before_after.png: fitted heads from the front, both
sides and behind, with the hair as 0.5.2 fitted it (the silhouettes' first style as
built, the nearest of ten named colours, the generator's smooth strands) and as it is
fitted now (since 0.5.3 the first styles ranked with their shapes fitted, contradicted
tails and buns demoted, the ends raised and the thickness fitted by direction, the
colour matched by render; since 0.5.4 the photo's hair in the hair's texture; since 0.5.5
see-through strand ends). The second row of each photo is labelled with the version
that drew it.

The photos: scikit-image's astronaut (public domain, NASA) and, where ``../shared/data``
holds them, Tom Cruise's portrait, the frontal photo of Pointing'04 person 4 (curly hair;
N. Gourier, D. Hall, J. L. Crowley, Pointing 2004, ICPR Workshop) and Figaro-1k's
Frame00041 (long straight hair; M. Svanera et al., Figaro, ICIP 2016). Each photo is
fitted both ways; the first column is the fit's own crop of the photo. Run from the
repository root (about three minutes on 2 CPU cores):

    python examples/make_hair_figure.py
"""

from __future__ import annotations

import contextlib
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

OUT = Path("examples/figures/hair_before_after.png")
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
    if shared is None:
        return out
    cruise = shared / "faces" / "Tom_Cruise_avp_2014_4.jpg"
    if cruise.is_file():
        out.append(("Tom Cruise", cruise))
    folder = shared / "multiview" / "pointing04"
    if (folder / "index.csv").is_file():
        out += [("Pointing'04 person 4", r["path"]) for r in read_pointing04(folder)
                if r["person"] == 4 and r["series"] == 1 and r["tilt_deg"] == 0
                and r["pan_deg"] == 0]
    figaro = shared / "hair_more" / "figaro" / "Frame00041-org.jpg"
    if figaro.is_file():
        out.append(("Figaro 00041", figaro))
    return out


@contextlib.contextmanager
def as_before():
    """Fit as 0.5.2 did: no candidates ranked with shapes, no length or thickness
    fitted, the named colour kept (the steps switched off where the fit looks them
    up)."""
    from head360cli.fitting import hair_class, hair_shape
    from head360cli.synth.hair import WARP_BINS

    saved = (hair_shape.CANDIDATES, hair_shape.fit_hair_shape,
             hair_class.match_colour_by_render)
    hair_shape.CANDIDATES = 0
    hair_shape.fit_hair_shape = lambda *a, **k: (0.0, hair_shape.HairShape(
        np.ones(WARP_BINS), 0.0, 0.0))
    hair_class.match_colour_by_render = lambda render, photo, hair, start, rounds=0: \
        np.asarray(start, np.float32)
    try:
        yield
    finally:
        (hair_shape.CANDIDATES, hair_shape.fit_hair_shape,
         hair_class.match_colour_by_render) = saved


def views(head_file: Path) -> np.ndarray:
    """``(5, SIZE, SIZE, 3)`` uint8: the fit's photo crop, then the head from
    :data:`YAWS`."""
    import cv2

    from head360cli.drive.views import head_framing, view_cameras, view_intrinsics
    from head360cli.fitting.pipeline import load_head_renderer
    from head360cli.model.head_render import to_uint8

    preview = np.asarray(Image.open(head_file.with_name(head_file.stem + "_preview.png")))
    crop = preview[:, :preview.shape[0], :3]
    head = load_head_renderer(head_file, precision="fp32")
    rgb = to_uint8(head.render(view_cameras(YAWS, 0.0, head_framing(head)),
                               view_intrinsics(head.size)))
    return np.stack([cv2.resize(x, (SIZE, SIZE), interpolation=cv2.INTER_AREA)
                     for x in [crop, *rgb]])


def main() -> None:
    from head360cli.drive.views import grid_image
    from head360cli.fitting.config import FitConfig
    from head360cli.fitting.pipeline import fit_photo

    images, labels = [], []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for name, photo in photos(work):
            from head360cli.version import __version__

            for kind in ("0.5.2", __version__):
                head = work / f"{len(images)}.h360"
                config = FitConfig(preset="fast", hair_texture=kind != "0.5.2")
                with as_before() if kind == "0.5.2" else contextlib.nullcontext():
                    summary = fit_photo(photo, head, config)
                images.extend(views(head))
                style = summary["hair_style"]["name"]
                labels += [f"{name}, {kind}"] + [f"{style} {yaw:+.0f}" for yaw in YAWS]
    OUT.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(grid_image(np.stack(images), labels, cols=len(YAWS) + 1)).save(OUT)
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()

"""Regenerate the README's fitting pictures from scikit-image's astronaut photo:

- ``examples/figures/fit_astronaut.png``: ``head360 demo``'s preview (photo crop, fitted
  front view, views at -45, 45 and 90 degrees yaw, the back);
- ``examples/figures/parse_astronaut.png``: ``head360 parse-hair``'s overlay (hair red,
  face blue), downscaled to 256 pixels.

Run from the repository root (about 20 s on 2 CPU cores):

    python examples/make_fit_figures.py
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from PIL import Image
from skimage import data

from head360cli.fitting.pipeline import fit_photo, parse_photo

FIGURES = Path("examples/figures")


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        photo = Path(tmp) / "astronaut.png"
        Image.fromarray(data.astronaut()).save(photo)
        fit = fit_photo(photo, Path(tmp) / "astronaut.h360")
        Image.open(fit["files"]["preview"]).save(FIGURES / "fit_astronaut.png",
                                                 optimize=True)
        parse = parse_photo(photo, tmp)
        Image.open(parse["overlay"]).resize((256, 256), Image.Resampling.LANCZOS).save(
            FIGURES / "parse_astronaut.png", optimize=True)
    print(f"wrote {FIGURES / 'fit_astronaut.png'} and {FIGURES / 'parse_astronaut.png'}")


if __name__ == "__main__":
    main()

"""Regenerate examples/figures/fit_shape_astronaut.png, the README's shape-fit picture.

Fits scikit-image's astronaut photo (public domain, NASA) with ``head360 fit --stage
shape`` and crops the overlay around the face. Run from the repository root:

    python examples/make_fit_figure.py
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import skimage.data
import skimage.transform

OUT = Path("examples/figures/fit_shape_astronaut.png")
SIZE = 320


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        photo = Path(tmp) / "astronaut.png"
        iio.imwrite(photo, skimage.data.astronaut())
        subprocess.run([sys.executable, "-m", "head360cli", "fit", str(photo), "--stage",
                        "shape", "-o", tmp, "-q"], check=True)
        overlay = iio.imread(Path(tmp) / "astronaut_overlay.png")
    # The face and a margin: the fitted mesh reaches beyond the detector's box.
    y0, y1, x0, x1 = 41, 201, 140, 300
    crop = overlay[y0:y1, x0:x1]
    small = skimage.transform.resize(crop, (SIZE, SIZE), anti_aliasing=True)
    iio.imwrite(OUT, (small * 255).round().astype(np.uint8))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()

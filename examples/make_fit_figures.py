"""Regenerate the fitting pictures of the README and docs/decisions.md from scikit-image's
astronaut photo:

- ``examples/figures/fit_astronaut.png``: ``head360 demo``'s preview (photo crop, fitted
  front view, views at -45, 45 and 90 degrees yaw, the back);
- ``examples/figures/parse_astronaut.png``: ``head360 parse-hair``'s overlay (hair red,
  face blue), downscaled to 256 pixels;
- ``examples/figures/texture_grid.png``: the fitted face at its own expression, neutral,
  jaw open and eyes closed, with the neural texture fitted texel by texel (top, as head360
  did before 2026-12-03) and on the coarse grid with a smooth fine layer (bottom, the default);
- ``examples/figures/light_astronaut.png``: the photo under a bluish light (its channels
  times 0.7, 0.85 and 1.2), the head fitted to it without the light's colour (as head360
  did before 2026-12-05) and with it;
- ``examples/figures/grey_astronaut.png``: the photo in greyscale, the head fitted to its
  colours (as head360 did before 2026-12-05: a grey face) and to its grey (the skin's colour the
  model's), each from the front and turned 45 degrees.

Run from the repository root (about a minute on 2 CPU cores):

    python examples/make_fit_figures.py
"""

from __future__ import annotations

import dataclasses
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image
from skimage import data

from head360cli.fitting import texture
from head360cli.fitting.pipeline import fit_photo, load_head_renderer, parse_photo

FIGURES = Path("examples/figures")

EXPRESSIONS = ({}, {"jawOpen": 0.6}, {"eyeBlinkLeft": 1.0, "eyeBlinkRight": 1.0})
"""Expressions of the texture figure's columns after the fitted one (neutral first)."""


def _faces(head: Path) -> np.ndarray:
    """The head from the front at its fitted expression and each of :data:`EXPRESSIONS`,
    cropped to the face, side by side, each pixel doubled."""
    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.mesh.arkit52 import INDEX
    from head360cli.model.head_render import to_uint8

    r = load_head_renderer(head, precision="fp32")
    cam, k = view_cameras(0.0, 0.0), view_intrinsics(r.size)
    tiles = [to_uint8(r.render(cam, k))[0]]
    for expr in EXPRESSIONS:
        w = np.zeros(52)
        for name, value in expr.items():
            w[INDEX[name]] = value
        tiles.append(to_uint8(r.render(cam, k, w))[0])
    face = np.concatenate([t[75:195, 68:188] for t in tiles], 1)
    return face.repeat(2, 0).repeat(2, 1)  # pixels doubled, so the stripes show


def texture_figure(photo: Path, work: Path) -> None:
    """``texture_grid.png``: the astronaut fitted (fast preset) texel by texel and with
    the default coarse grid and fine layer."""
    fast = texture.PRESETS["fast"]
    rows = []
    for name, cfg in (("texel", dataclasses.replace(fast, texture_stride=1, fine_smooth=0)),
                      ("grid", fast)):
        texture.PRESETS["fast"] = cfg
        try:
            fit_photo(photo, work / f"{name}.h360")
        finally:
            texture.PRESETS["fast"] = fast
        rows.append(_faces(work / f"{name}.h360"))
    Image.fromarray(np.concatenate(rows, 0)).save(FIGURES / "texture_grid.png",
                                                  optimize=True)


LIGHT = (0.7, 0.85, 1.2)
"""The bluish light of the light figure: the photo's red, green and blue times these."""


def light_figure(work: Path) -> None:
    """``light_astronaut.png``: photo crop | fitted front without the light | with it."""
    photo = work / "blue.png"
    blue = np.clip(data.astronaut() * np.array(LIGHT), 0, 255).round().astype(np.uint8)
    Image.fromarray(blue).save(photo)
    fast = texture.PRESETS["fast"]
    tiles = []
    for name, cfg in (("unlit", dataclasses.replace(fast, gain=False)), ("lit", fast)):
        texture.PRESETS["fast"] = cfg
        try:
            fit = fit_photo(photo, work / f"{name}.h360")
        finally:
            texture.PRESETS["fast"] = fast
        sheet = np.asarray(Image.open(fit["files"]["preview"]))
        size = sheet.shape[0]
        if not tiles:
            tiles.append(sheet[:, :size])  # the photo's crop
        tiles.append(sheet[:, size:2 * size])  # the fitted front view
    Image.fromarray(np.concatenate(tiles, 1)).save(FIGURES / "light_astronaut.png",
                                                   optimize=True)


def grey_figure(work: Path) -> None:
    """``grey_astronaut.png``: the grey photo's crop | fitted in colour, front and -45
    degrees | fitted in grey, the same views."""
    photo = work / "grey.png"
    Image.fromarray(data.astronaut()).convert("L").save(photo)
    invert = texture.invert_texture
    tiles = []
    for name in ("colour", "grey"):
        if name == "colour":  # as before 2026-12-05: the grey photo's RGB fitted
            texture.invert_texture = lambda *a, **k: invert(
                *a[:7], dataclasses.replace(a[7], grey=False), *a[8:], **k)
        try:
            fit = fit_photo(photo, work / f"{name}.h360")
        finally:
            texture.invert_texture = invert
        sheet = np.asarray(Image.open(fit["files"]["preview"]).convert("RGB"))
        size = sheet.shape[0]
        if not tiles:
            tiles.append(sheet[:, :size])  # the photo's crop
        tiles.append(sheet[:, size:3 * size])  # the fitted front and -45 degree views
    Image.fromarray(np.concatenate(tiles, 1)).save(FIGURES / "grey_astronaut.png",
                                                   optimize=True)


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
        texture_figure(photo, Path(tmp))
        light_figure(Path(tmp))
        grey_figure(Path(tmp))
    print(f"wrote {FIGURES / 'fit_astronaut.png'}, {FIGURES / 'parse_astronaut.png'}, "
          f"{FIGURES / 'texture_grid.png'}, {FIGURES / 'light_astronaut.png'} and "
          f"{FIGURES / 'grey_astronaut.png'}")


if __name__ == "__main__":
    main()

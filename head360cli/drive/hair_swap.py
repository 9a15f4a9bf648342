"""Give a head another hairstyle or hair colour, and show the styles on offer.

The hair is separate from the head (the generator's hair branch), so a swap only rewrites
the head file's ``hair_style`` and ``hair_color``: the face is rendered by the head branch
alone and does not change (``head360 bench animate`` measures that).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from head360cli.errors import BadInputError

__all__ = ["list_styles", "parse_colour", "style_sheet", "swap_hair"]


_COLOUR_SPELLINGS = {"gray": "grey", "blond": "blonde", "darkbrown": "dark brown",
                     "lightbrown": "light brown"}
"""Other spellings of the colour names (the option is ``--color`` too), written without
spaces, to the names of :data:`~head360cli.synth.hair.HAIR_COLOURS`."""


def parse_colour(text) -> tuple[str, np.ndarray]:
    """A hair colour from a SynHead-P colour name (``"dark brown"``; ``"gray"`` and
    ``"blond"`` are taken for ``"grey"`` and ``"blonde"``), an sRGB hex code
    (``"#6b4423"`` or ``"#642"``) or three linear RGB numbers in [0, 1]
    (``"0.2,0.1,0.05"``, or from Python a sequence or array of three).

    Returns:
        ``(name, linear RGB (3,))``; the name is the nearest SynHead-P colour's.

    Raises:
        BadInputError: None of those forms.
    """
    from head360cli.fitting.hair_class import nearest_colour_name
    from head360cli.synth.hair import HAIR_COLOURS

    if not isinstance(text, str):  # numbers from Python: read as the R,G,B text form
        values = np.asarray(text, dtype=object).reshape(-1)
        text = ",".join(str(v) for v in values) if len(values) == 3 else repr(text)
    name = " ".join(text.strip().lower().replace("_", " ").replace("-", " ").split())
    name = _COLOUR_SPELLINGS.get(name.replace(" ", ""), name)
    if name in HAIR_COLOURS:
        return name, np.asarray(HAIR_COLOURS[name], np.float64)
    t = text.strip().lower()  # numbers keep their signs
    if t.startswith("#") and len(t) == 4:  # #rgb: each digit twice, as in CSS
        t = "#" + "".join(c * 2 for c in t[1:])
    rgb = None
    if t.startswith("#") and len(t) == 7:
        try:
            srgb = np.array([int(t[i:i + 2], 16) for i in (1, 3, 5)]) / 255.0
        except ValueError:
            srgb = None
        if srgb is not None:
            from head360cli.io.colour import srgb_to_linear

            rgb = srgb_to_linear(srgb)
    elif t.count(",") == 2:
        try:
            rgb = np.array([float(v) for v in t.split(",")])
        except ValueError:
            rgb = None
        if rgb is not None and not (np.isfinite(rgb).all() and (rgb >= 0).all()
                                    and (rgb <= 1).all()):
            raise BadInputError(f"expected linear RGB numbers in [0, 1], found {text!r}")
    if rgb is None:
        raise BadInputError(f"expected a hair colour name ({', '.join(HAIR_COLOURS)}), a "
                            f"hex code like #6b4423 or R,G,B in [0, 1], found {text!r}")
    return nearest_colour_name(rgb), rgb


def list_styles() -> list[dict[str, Any]]:
    """The 30 SynHead-P hairstyles: ``{"id", "name", "figaro"}`` each."""
    from head360cli.synth.hair import HAIRSTYLES, figaro_class

    return [{"id": i, "name": s.name, "figaro": figaro_class(i)}
            for i, s in enumerate(HAIRSTYLES)]


def swap_hair(head_path: str | Path, out: str | Path, style: int | str | None = None,
              colour: str | Any = None) -> dict[str, Any]:
    """Write a copy of a head file wearing hairstyle ``style`` (an id or a name, see
    :func:`~head360cli.synth.hair.style_index`) and/or ``colour`` (see
    :func:`parse_colour`).

    Raises:
        BadInputError: Neither a style nor a colour given, an unknown style or colour, or
            ``out`` not a ``.h360`` name in an existing folder.
        FileFormatError: Not a head file, or one without a head's arrays.
    """
    import dataclasses

    from head360cli.io.atomic import check_file_target
    from head360cli.io.headfile import HEAD_ARRAYS, read_head, write_head
    from head360cli.synth.hair import HAIRSTYLES, style_index

    if style is None and colour is None:
        raise BadInputError("expected --hair and/or --color, found neither")
    if style is not None:
        style = style_index(int(style) if isinstance(style, np.integer) else style)
    if colour is not None:
        parse_colour(colour)  # before any file is read
    if Path(out).suffix.lower() != ".h360":
        raise BadInputError(f"expected an output name ending in .h360, found {str(out)!r}")
    check_file_target(out)
    head = read_head(head_path, required=HEAD_ARRAYS)
    arrays = dict(head.arrays)
    info = dict(head.info)
    before = {"hair_style": int(arrays["hair_style"]),
              "hair_color": np.asarray(arrays["hair_color"], float).round(4).tolist()}
    if style is not None:
        if int(style) != before["hair_style"]:
            # the fitted style's shape, not the new one's
            arrays.pop("hair_scale", None)
            arrays.pop("hair_end_shift", None)
        arrays["hair_style"] = np.array(int(style), np.int64)
        info["hair_style_name"] = HAIRSTYLES[int(style)].name
    if colour is not None:
        name, rgb = parse_colour(colour)
        arrays["hair_color"] = rgb.astype(np.float32)
        info["hair_color_name"] = name
    info["hair_swapped_from"] = before
    write_head(dataclasses.replace(head, arrays=arrays, info=info), out)
    k = int(arrays["hair_style"])
    return {"head": str(out), "hair_style": {"id": k, "name": HAIRSTYLES[k].name},
            "hair_color": np.asarray(arrays["hair_color"], float).round(4).tolist(),
            "from": before}


def style_sheet(renderer, out: str | Path, yaw: float = 30.0, size: int = 128,
                progress: Any = None) -> Path:
    """A PNG contact sheet of a head wearing each of the 30 styles (in its own colour),
    seen from ``yaw`` degrees, ``size`` pixels per tile."""
    from PIL import Image

    from head360cli.drive.views import grid_image, head_framing, view_cameras, view_intrinsics
    from head360cli.io.atomic import atomic_path, check_file_target

    check_file_target(out)  # a missing folder or a read-only file: before 30 renders
    styles = list_styles()
    k = view_intrinsics(renderer.size)
    tiles = []
    for i, s in enumerate(styles):
        r = renderer.with_hair(s["id"], renderer.hair_colour)
        cam = view_cameras(yaw, 0.0, head_framing(r))  # long styles and an afro whole
        frame = next(r.frames(cam, np.zeros((1, 52)), k))[0]
        tiles.append(np.asarray(Image.fromarray(frame).resize((size, size),
                                                               Image.LANCZOS)))
        if progress:
            progress("styles", i + 1, len(styles))
    sheet = grid_image(np.stack(tiles), [f"{s['id']} {s['name']}" for s in styles], cols=6)
    with atomic_path(out) as tmp:
        Image.fromarray(sheet).save(tmp, format="PNG")
    return Path(out)

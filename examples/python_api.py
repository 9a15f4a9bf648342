"""head360 from Python: fit a photo, render views, drive the head with an ARKit stream,
give it another hairstyle and export it as a mesh, with the functions the commands call.

    python examples/python_api.py PHOTO_OR_HEAD OUT_DIR [--size N] [--end SECONDS]

PHOTO_OR_HEAD is a photo (fitted first, as ``head360 fit`` does) or a ``.h360`` head
file. OUT_DIR (made if missing) receives me.h360 (for a photo), views.png, talk.mp4,
me_bob.h360 and me.glb. tests/test_examples_python_api.py runs it on a small head.
"""

from __future__ import annotations

import argparse
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
STREAM = REPO / "examples" / "smile_blink_livelinkface.csv"


def main(source: str | Path, out_dir: str | Path, size: int = 256,
         end: float | None = None) -> dict[str, str]:
    from PIL import Image

    import head360cli as h
    from head360cli.drive.bake import export_head
    from head360cli.drive.hair_swap import swap_hair
    from head360cli.drive.views import grid_image
    from head360cli.synth.hair import style_index

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = {}

    # 1. a head: fit the photo (landmarks, shape, hair, texture) unless a head is given
    head = Path(source)
    if head.suffix.lower() != ".h360":
        summary = h.fit(head, out / "me.h360", preset="fast")
        print(f"fitted {head.name}: hair {summary['hair_style']['name']}, "
              f"face PSNR {summary['psnr_face_input_view']:.1f} dB")
        head = files["head"] = out / "me.h360"

    # 2. views by yaw (degrees, 180 the back) and pitch, one ARKit expression for all
    renderer = h.load_head(head, size=size)
    smile = {"mouthSmileLeft": 0.8, "mouthSmileRight": 0.8}
    frames = h.render(renderer, yaws=[0.0, 45.0, 90.0, 180.0], pitch=10.0, expression=smile)
    Image.fromarray(grid_image(frames)).save(out / "views.png")
    files["views"] = out / "views.png"

    # 3. animation: an ARKit stream (any CSV the commands read), its timing kept
    result = h.animate(renderer, STREAM, out / "talk.mp4", end=end)
    print(f"animated {result['frames']} frames at {result['render_fps']:.1f} frames/s")
    files["video"] = out / "talk.mp4"

    # 4. another hairstyle and colour: a new head file, the face unchanged
    swap_hair(head, out / "me_bob.h360", style=style_index("bob"), colour="blonde")
    files["swapped"] = out / "me_bob.h360"

    # 5. a mesh with the 52 ARKit blendshapes as morph targets, for Blender or three.js
    export_head(renderer, out / "me.glb", texture_size=256)
    files["mesh"] = out / "me.glb"
    return {k: str(v) for k, v in files.items()}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", help="a photo to fit, or a .h360 head file")
    parser.add_argument("out_dir")
    parser.add_argument("--size", type=int, default=256, help="image size of the renders")
    parser.add_argument("--end", type=float, default=None,
                        help="animate the bundled stream up to this second only")
    args = parser.parse_args()
    for what, path in main(args.source, args.out_dir, args.size, args.end).items():
        print(f"{what:8s} {path}")

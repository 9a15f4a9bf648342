"""The commands that use a head: ``render``, ``animate``, ``swap-hair``, ``sample``,
``export-mesh`` and ``export-onnx``."""

from __future__ import annotations

import contextlib
import math
import sys
from collections.abc import Iterator
from pathlib import Path

import click

from head360cli.cli.base import (
    STREAM_FPS,
    InputPath,
    OutputPath,
    check_size,
    cli,
    common_options,
    cpu_only_warning,
    current_settings,
    drop_stdout,
    emit,
    progress_printer,
    refuse_given,
    stdin_path,
    warn,
    warn_unused,
)
from head360cli.errors import BadInputError

_HEAD = InputPath(dir_okay=False)


ANIMATE_SAMPLES = 8
"""Default samples per ray for animation with a hex-plane generator: 38.2 dB against a
32-sample render (12 samples: 43.0 dB) at 1.5x the frame rate. A deferred generator
animates with its own samples per pixel."""


def _renderer(head: str, samples: int | None, size: int | None, precision: str = "auto",
              device: str | None = None):
    """The head's renderer on ``device`` (default: ``--device``)."""
    from head360cli.devices import resolve_device
    from head360cli.fitting.pipeline import load_head_renderer

    if samples is not None and not 1 <= samples <= 64:
        raise BadInputError(f"expected --samples between 1 and 64, found {samples}")
    check_size(size)
    if not Path(head).exists():  # a pipe (<(...)) is read like a file
        from head360cli.io.sources import missing

        raise missing(head, f"head file {head!r} does not exist")
    try:
        return load_head_renderer(head, device or str(resolve_device(current_settings().device)),
                                  samples=samples, size=size, precision=precision)
    except ValueError as exc:  # an image size the generator cannot make
        raise BadInputError(str(exc)) from None


def _quality_options(f):
    f = click.option("--samples", type=int, default=None,
                     help="Samples per pixel, 1, 2 or 4 (default: the generator's, 2); "
                     "fewer is faster. (Per ray for a hex-plane generator.)")(f)
    f = click.option("--size", type=int, default=None,
                     help="Image width and height in pixels, even (default 256).")(f)
    f = click.option("--precision", type=click.Choice(["auto", "fp32", "bf16"]),
                     default="auto", show_default=True,
                     help="Decoders and RefineNet in bfloat16 (auto: where the CPU or GPU "
                     "has it; images within 1/100 of fp32's) or float32.")(f)
    return click.option("--no-hair", is_flag=True, help="Render the head bald.")(f)


def _backend_options(f):
    f = click.option("--onnx", "onnx_path", default="generator.onnx", show_default=True,
                     type=InputPath(dir_okay=False),
                     help="With --backend onnx: the graph from head360 export-onnx (its "
                     "samples per ray and size are used).")(f)
    return click.option("--backend", type=click.Choice(["torch", "onnx"]), default="torch",
                        show_default=True,
                        help="Render with torch, or with onnxruntime and an exported graph "
                        "(same images to 1e-5).")(f)


def _backend_renderer(head: str, backend: str, onnx_path: str, samples: int | None,
                      size: int | None, precision: str):
    """The head's renderer; with ``backend == "onnx"`` its frames come from onnxruntime
    (samples and size as fixed in the graph; the user's, if given, must agree)."""
    if backend == "torch":
        return _renderer(head, samples, size, precision)
    from head360cli.errors import ModelMismatchError
    from head360cli.export.onnx import OnnxFrameRunner
    from head360cli.paths import generator_hash

    if not Path(onnx_path).is_file():
        raise BadInputError(f"ONNX graph {onnx_path!r} does not exist (run head360 "
                            "export-onnx first, or pass --onnx FILE)")
    runner = OnnxFrameRunner(onnx_path)
    fixed = {"--samples": (samples, runner.meta["samples"]), "--size": (size, runner.size)}
    for name, (asked, graph) in fixed.items():
        if asked is not None and asked != graph:
            raise BadInputError(f"expected {name} {graph} (fixed in {onnx_path}), found "
                                f"{asked}")
    if precision == "bf16":
        raise BadInputError("expected --precision auto or fp32 with --backend onnx (the "
                            "graph is float32), found bf16")
    made_with = runner.meta.get("generator_sha256")
    if made_with is not None and made_with != generator_hash():
        raise ModelMismatchError(f"{onnx_path} was exported from another generator than "
                                 "the installed one: export it again")
    r = _renderer(head, runner.meta["samples"], runner.size, "fp32")
    r.use_runner(runner)
    return r


def _check_stdout_image(turntable: bool) -> None:
    """Refuse ``render -o -`` where standard output cannot take the PNG: a turntable (a
    video), ``--json`` (which prints there too) or a terminal (binary bytes on screen).

    Raises:
        BadInputError: One of those, said in one line.
    """
    if turntable:
        raise BadInputError("expected a file or folder for a --turntable video, found '-' "
                            "(standard output takes one view or a grid, as PNG)")
    if current_settings().json:
        raise BadInputError("expected -o FILE with --json, found '-': the image and the "
                            "JSON would both go to standard output")
    stdout = sys.stdout
    if stdout is None or not hasattr(stdout, "buffer") or stdout.isatty():
        raise BadInputError("expected standard output redirected or piped for -o - "
                            "(> view.png or | another command), found a terminal")


def _write_stdout_png(image) -> None:
    """Write ``image (H, W, 3)`` uint8 to standard output as one PNG, encoded first, so
    a failed encode writes nothing.

    Raises:
        BadInputError: Standard output cannot be written (a full disk behind ``>``).
    """
    import io

    from PIL import Image

    data = io.BytesIO()
    Image.fromarray(image).save(data, format="PNG")
    try:
        sys.stdout.buffer.write(data.getvalue())
        sys.stdout.buffer.flush()
    except BrokenPipeError:
        raise  # a reader that stopped reading (| head -c 8): not an error, see cli._run
    except OSError as exc:
        drop_stdout()
        raise BadInputError(f"cannot write the image to standard output: "
                            f"{exc.strerror or exc}") from None


@cli.command()
@click.argument("head", type=_HEAD, callback=stdin_path("a head file"))
@click.option("-o", "--out", required=True, type=OutputPath(),
              help="Output: .png (or .jpg) for a view or a grid, or - for a PNG on "
              "standard output; .mp4, .gif or a folder for --turntable.")
@click.option("--turntable", is_flag=True, help="A video turning once around the head.")
@click.option("--frames", default=48, show_default=True, help="Turntable frames.")
@click.option("--fps", default=24.0, show_default=True, help="Turntable frame rate.")
@click.option("--yaw", default=0.0, show_default=True,
              help="Degrees; 0 = the canonical frontal view, + shows the head's left side "
                   "(a turntable starts there).")
@click.option("--pitch", default=0.0, show_default=True, help="Degrees; + looks from above.")
@click.option("--views", default=None,
              help="A PNG grid of views: yaws '0,45,90' or yaw:pitch pairs '0:0,90:20'.")
@click.option("--expr", default=None,
              help="ARKit expression, e.g. 'JawOpen=0.8,EyeBlinkLeft=1', or 'photo': the "
                   "fitted photo's own (default neutral; a fitted head's eyes rest at the "
                   "photo's openness and blink from it).")
@_quality_options
@_backend_options
@common_options
def render(head: str, out: str, turntable: bool, frames: int, fps: float, yaw: float,
           pitch: float, views: str | None, expr: str | None, samples: int | None,
           size: int | None, precision: str, no_hair: bool, backend: str,
           onnx_path: str) -> None:
    """Render a head: one view, a grid of views, or a turntable.

    \b
    Examples:
      head360 render me.h360 -o front.png
      head360 render me.h360 --yaw 45 --pitch 10 --size 512 -o view.png
      head360 render me.h360 --expr JawOpen=0.8,EyeBlinkLeft=1 -o smile.png
      head360 render me.h360 --expr photo -o as_photographed.png
      head360 render me.h360 --views 0,45,90,180,270 -o views.png
      head360 render me.h360 --turntable --frames 96 -o turn.mp4
      head360 render me.h360 --backend onnx --onnx generator.onnx -o front.png
      head360 render me.h360 --yaw 30 -o - | display -     a PNG on standard output
      cat me.h360 | head360 render - --turntable -o turn.mp4   a head on standard input
    """
    import numpy as np

    from head360cli.drive.views import (
        check_angles,
        grid_image,
        parse_expression,
        parse_views,
        view_cameras,
        view_intrinsics,
        write_turntable,
    )

    w = None if expr == "photo" else parse_expression(expr)
    check_angles(yaw, pitch)
    if turntable and views is not None:
        raise BadInputError("expected --turntable or --views, found both")
    if views is not None:
        refuse_given(("yaw", "pitch"), "with --views (it gives every view's angles)")
    if turntable and not 1 <= frames <= 3600:
        raise BadInputError(f"expected --frames between 1 and 3600, found {frames}")
    if not turntable:
        warn_unused(("frames", "fps"), "without --turntable")
    to_stdout = out == "-"
    if to_stdout:
        _check_stdout_image(turntable)
    image_format = "PNG" if to_stdout else {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG"}.get(
        Path(out).suffix.lower())
    if not turntable and image_format is None:
        raise BadInputError(f"expected a .png or .jpg output for a view, found {out!r} (use "
                            "--turntable for a video)")
    if turntable:  # refused now, not after the head is loaded
        from head360cli.io.video import check_video_target

        check_video_target(out)
    elif not to_stdout:
        from head360cli.io.atomic import check_file_target

        check_file_target(out)
    pairs = parse_views(views) if views is not None else [(yaw, pitch)]  # before the load
    r = _backend_renderer(head, backend, onnx_path, samples, size, precision)
    if w is None:
        from head360cli.drive.views import photo_expression

        w = photo_expression(r.expression)
    if turntable:
        write_turntable(r, out, frames, pitch, fps, expression=w,
                        progress=progress_printer(), hair=not no_hair, yaw=yaw)
        emit({"out": out, "frames": frames}, f"wrote {out} ({frames} frames)")
        return
    from PIL import Image

    from head360cli.drive.views import GRID_COLUMNS, check_grid_size, head_framing
    from head360cli.io.atomic import atomic_path

    check_grid_size(len(pairs), r.size)
    cams = view_cameras([p[0] for p in pairs], [p[1] for p in pairs],
                        head_framing(r, not no_hair))
    frames_ = np.concatenate(list(r.frames(cams, np.broadcast_to(w, (len(pairs), 52)),
                                           view_intrinsics(r.size), hair=not no_hair)))
    image = frames_[0] if len(pairs) == 1 else grid_image(
        frames_, [f"{y:g}/{p:g}" for y, p in pairs], cols=min(len(pairs), GRID_COLUMNS))
    if to_stdout:
        _write_stdout_png(image)
        return
    with atomic_path(out) as tmp:
        Image.fromarray(image).save(tmp, format=image_format,
                                    **({"quality": 95} if image_format == "JPEG" else {}))
    emit({"out": out, "views": [list(p) for p in pairs]},
          f"wrote {out} ({len(pairs)} view{'s' if len(pairs) > 1 else ''})")


@cli.command()
@click.argument("head", type=_HEAD, required=False,
                callback=stdin_path("a head file"))
@click.option("--arkit", default=None, type=InputPath(allow_dash=True),
              help="ARKit-52 CSV stream (Live Link Face, MediaPipe names, generic), or - "
              "for standard input.")
@click.option("--video", default=None, type=InputPath(allow_dash=True),
              help="Instead of --arkit: a video (or folder of frames, or - for standard "
              "input) whose face is tracked and drives the head as it is read.")
@click.option("--side-by-side", is_flag=True,
              help="With --video: each input frame beside the animated head.")
@click.option("-o", "--out", default=None, type=OutputPath(),
              help="Video: .mp4, .gif, or a folder for PNG frames (default, without "
              "--mesh-sequence: <stream stem>.mp4, never over an existing file).")
@click.option("--mesh-sequence", "mesh_dir", default=None, type=OutputPath(),
              help="Also write one OBJ per frame into this new folder.")
@click.option("--head-pose", is_flag=True, help="Apply the stream's head rotation.")
@click.option("--fps", type=float, default=None,
              help="Resample to this frame rate (default: the stream's own).")
@click.option("--start", type=float, default=None, help="Start at this second.")
@click.option("--end", type=float, default=None, help="Stop before this second.")
@click.option("--smooth", type=float, default=0.0, show_default=True,
              help="Gaussian smoothing of the weights, sigma in seconds (e.g. 0.03).")
@click.option("--yaw", default=0.0, show_default=True, help="Camera yaw, degrees.")
@click.option("--pitch", default=0.0, show_default=True, help="Camera pitch, degrees.")
@click.option("--on-bad", type=click.Choice(["error", "skip", "hold"]), default="hold",
              show_default=True, help="Bad cells in the stream: stop, drop the row, or "
              "hold the last good value.")
@STREAM_FPS
@click.option("--exact", is_flag=True,
              help="Hex-plane generators: decode every point of every frame (by default, "
              "with a still camera, points whose inputs moved by at most 1e-3 keep their "
              "colour). The deferred generator's frames are exact either way.")
@click.option("--face", type=click.IntRange(min=0), default=0, show_default=True,
              help="With --video: which face to follow when several show (0 = the "
                   "largest, 1 = the next...).")
@click.option("--workers", type=int, default=None,
              help="Processes that render frames on a CPU (default: one per core, at "
              "most 4, for takes of 64 frames or more; 1: this process alone). On 2 "
              "cores two one-thread processes render 1.3-1.5x the frames of one.")
@click.option("--batch", type=int, default=None,
              help="Frames per generator call (default: 1 on a CPU, 32 on a GPU). On a GPU "
              "fewer need less memory (32: 2.8 GiB) and more can be faster (an H200 "
              "rendered 836 frames/s at 32, 1070 at 64).")
@_quality_options
@_backend_options
@common_options
def animate(head: str | None, arkit: str | None, video: str | None, side_by_side: bool,
            out: str | None, mesh_dir: str | None, head_pose: bool,
            fps: float | None, start: float | None, end: float | None, smooth: float,
            yaw: float, pitch: float, on_bad: str, stream_fps: float | None,
            face: int, workers: int | None, batch: int | None,
            samples: int | None, size: int | None, exact: bool, precision: str,
            no_hair: bool, backend: str, onnx_path: str) -> None:
    """Drive a head with an ARKit-52 blendshape stream, or with a face tracked in a video.

    Only the mesh is recomputed per frame, and with a still camera only the parts of the
    head it moved are decoded again; frames stream to the encoder, so memory does not grow
    with the length of the take. Without HEAD, the model's mean head is driven (to try a
    stream before any photo is fitted). With --video, frames are tracked and rendered a
    few at a time in this process (--start, --end, --fps for a folder and --on-bad apply
    to the video; for the worker processes' speed, 'head360 track' first).

    \b
    Examples:
      head360 animate me.h360 --arkit take.csv -o talk.mp4
      head360 animate --arkit take.csv -o mean.mp4         the mean head
      head360 animate me.h360 --arkit take.csv --head-pose --start 2 --end 8 -o clip.gif
      head360 animate me.h360 --arkit take.csv --fps 30 --smooth 0.03 -o talk.mp4
      cat take.csv | head360 animate me.h360 --arkit - -o talk.mp4
      head360 animate me.h360 --arkit take.csv --mesh-sequence frames/
      head360 animate me.h360 --arkit take.csv --backend onnx --onnx gen.onnx -o talk.mp4
      head360 animate me.h360 --video clip.mp4 --side-by-side -o both.mp4
    """
    from head360cli.drive.animate import AnimateConfig
    from head360cli.drive.animate import animate as run
    from head360cli.io.arkit import read_arkit_csv

    if (arkit is None) == (video is None):
        raise BadInputError("expected one driver, --arkit STREAM or --video CLIP, found "
                            + ("both" if arkit else "neither"))
    source = arkit if arkit is not None else video
    if head == "/dev/stdin" and source in ("-", "/dev/stdin"):
        raise BadInputError("expected at most one input on standard input, found both the "
                            f"head and {'--arkit' if arkit else '--video'}: give one of "
                            "them as a file")
    if video is not None and mesh_dir is not None:
        raise BadInputError("expected --mesh-sequence with --arkit, found it with --video: "
                            "track the video first (head360 track) and animate the stream")
    if side_by_side and video is None:
        raise BadInputError("expected --side-by-side with --video, found it with --arkit")
    if out is None and mesh_dir is None:  # as fit names its head after the photo
        from head360cli.io.sources import input_stem

        out = f"{'stream' if source == '-' else input_stem(source)}.mp4"
        if Path(out).exists():  # a name the user did not choose never replaces a file
            raise BadInputError(f"expected -o OUT (the default {out} exists already)")
    from head360cli.io.video import MAX_FPS, MIN_FPS

    if fps is not None and not MIN_FPS <= fps <= MAX_FPS:
        raise BadInputError(f"expected --fps between {MIN_FPS:g} and {MAX_FPS:g}, found {fps}")
    if not 0 <= smooth <= 5:
        raise BadInputError(f"expected --smooth between 0 and 5 seconds, found {smooth}")
    if workers is not None and not 1 <= workers <= 64:
        raise BadInputError(f"expected --workers between 1 and 64, found {workers}")
    if batch is not None and not 1 <= batch <= 1024:
        raise BadInputError(f"expected --batch between 1 and 1024, found {batch}")
    check_size(size)
    from head360cli.drive.views import check_angles

    check_angles(yaw, pitch)  # as render
    for name, value in (("--start", start), ("--end", end)):
        if value is not None and not (math.isfinite(value) and value >= 0):
            raise BadInputError(f"expected {name} in seconds from the stream's start (0 or "
                                f"more), found {value}")
    # a GPU named outright (--device auto is known only once torch is imported, which
    # the worker processes' start should not wait for)
    on_gpu = current_settings().device.strip().lower().startswith("cuda")
    if workers is not None and workers > 1:  # processes render one-frame batches on a CPU
        why = ("--batch above 1" if batch is not None and batch > 1 else
               "--backend onnx" if backend == "onnx" else
               f"--device {current_settings().device}" if on_gpu else
               "no video (-o)" if out is None else None)
        if why is not None:
            warn(f"--workers {workers} is not used with {why}: this process renders "
                  "every frame")
    if video is not None:
        refuse_given(("smooth", "stream_fps", "workers", "batch"),
                     "with --video (the tracker filters its readings; this process renders)")
        _animate_video(head, video, out, side_by_side, head_pose, fps, start, end, yaw,
                       pitch, on_bad, no_hair, backend, onnx_path, samples, size, exact,
                       precision, face)
        return
    assert arkit is not None
    refuse_given(("face",), "with --arkit (a stream holds one face's weights)")
    if arkit != "-" and not Path(arkit).exists():  # a pipe (<(...)) is read like a file
        from head360cli.io.sources import missing

        raise missing(arkit, f"ARKit stream {arkit!r} does not exist")
    if arkit == "-":
        from head360cli.io.sources import check_stdin

        check_stdin("an ARKit stream")
    # "-": standard input, decoded as a file
    stream = read_arkit_csv(arkit, on_bad=on_bad, fps=stream_fps)
    for warning in stream.warnings:
        warn(warning)
    cfg = AnimateConfig(fps=fps, start=start, end=end, smooth=smooth, head_pose=head_pose,
                        yaw=yaw, pitch=pitch, hair=not no_hair, workers=workers,
                        batch=batch)
    # given the loader, run() starts the processes that render frames on a CPU before
    # it loads the head (with --device auto on a GPU machine they end unused)
    on_cpu = backend == "torch" and not on_gpu
    with _head_or_mean(head) as path:

        def load():
            return _animate_renderer(path, backend, onnx_path, samples, size, precision,
                                     exact)

        res = run(load if on_cpu else load(), stream, out, cfg, mesh_dir=mesh_dir,
                  progress=progress_printer())
    for warning in res.get("warnings", []):
        warn(warning)
    text = (f"animated {res['frames']} frames ({res['duration_s']:.2f} s at "
            f"{res['fps']:.2f} fps)")
    if "render_fps" in res:
        text += f", rendered at {res['render_fps']:.1f} frames/s"
        if res.get("workers", 1) > 1:
            text += f" by {res['workers']} processes"
    if "decoded_share" in res:
        text += f" ({100 * res['decoded_share']:.0f} % of the points decoded, the rest kept)"
    emit(res, text + "".join(f"\n  wrote {p}" for p in res["files"].values()))


@cli.command("swap-hair")
@click.argument("head", type=_HEAD, required=False,
                callback=stdin_path("a head file"))
@click.option("--hair", "hair_style", default=None,
              help="Hairstyle name (bob, 'long wavy'...) or id 0-29.")
@click.option("--color", "--colour", "colour", default=None,
              help="Hair colour: a name (black, 'dark brown', blonde...), #rrggbb, or "
              "linear R,G,B in [0, 1].")
@click.option("-o", "--out", default=None, type=OutputPath(),
              help="The new head file (with HEAD), or the contact sheet PNG (with --list).")
@click.option("--list", "list_", is_flag=True,
              help="List the 30 hairstyles; with -o, also render a contact sheet of them "
              "(on HEAD, or on the mean sampled head).")
@common_options
def swap_hair(head: str | None, hair_style: str | None, colour: str | None,
              out: str | None, list_: bool) -> None:
    """Give a head another hairstyle and/or hair colour; the face stays as it was.

    \b
    Examples:
      head360 swap-hair --list
      head360 swap-hair me.h360 --list -o styles.png
      head360 swap-hair me.h360 --hair bob -o me_bob.h360
      head360 swap-hair me.h360 --hair 17 --color blonde -o me_17.h360
    """
    from head360cli.drive.hair_swap import list_styles, style_sheet
    from head360cli.drive.hair_swap import swap_hair as run

    if list_:
        warn_unused(("hair_style", "colour"), "with --list")
        styles = list_styles()
        result = {"styles": styles}
        text = "\n".join(f"{s['id']:2d}  {s['name']:18s} ({s['figaro']})" for s in styles)
        if out is not None:
            if Path(out).suffix.lower() != ".png":
                raise BadInputError(f"expected a .png contact sheet, found {out!r}")
            from head360cli.io.atomic import check_file_target

            check_file_target(out)  # before the head is loaded
            r = _mean_head_renderer() if head is None else _renderer(head, None, None)
            style_sheet(r, out, progress=progress_printer())
            result["sheet"] = out
            text += f"\nwrote {out}"
        emit(result, text)
        return
    if head is None:
        raise BadInputError("expected a head file (or --list), found none")
    if out is None:
        raise BadInputError("expected -o NEW.h360 for the swapped head")
    from head360cli.synth.hair import HAIRSTYLES, style_index

    style = None if hair_style is None else style_index(hair_style)
    res = run(head, out, style, colour)
    was = int(res["from"]["hair_style"])
    if colour is not None and res["hair_style"]["id"] == 0:
        warn("the head is bald (style 0): --color shows once it wears a hairstyle "
              "(swap-hair --hair NAME)")
    emit(res, f"wrote {out}: hair {res['hair_style']['name']} (was "
          f"{HAIRSTYLES[was].name}, style {was})")


@contextlib.contextmanager
def _head_or_mean(head: str | None) -> Iterator[str]:
    """The head file to animate: ``head``, or the model's mean head in a temporary folder
    (removed when the block ends) when none was given."""
    if head is not None:
        yield head
        return
    import tempfile

    warn("no HEAD given: driving the model's mean head (fit yours with head360 fit "
         "PHOTO and give the .h360)")
    with tempfile.TemporaryDirectory(prefix="head360-mean-") as scratch:
        yield str(_mean_head_file(Path(scratch)))


def _animate_renderer(head: str, backend: str, onnx_path: str, samples: int | None,
                      size: int | None, precision: str, exact: bool):
    """The renderer ``animate`` drives: ``--samples`` or animate's default (a graph's own
    with ``--backend onnx``); ``--exact`` turns off the reuse of decoded points."""
    r = _backend_renderer(head, backend, onnx_path, samples, size, precision)
    if samples is None and backend != "onnx" and r.gen.kind == "hexplane":
        r.samples = ANIMATE_SAMPLES
    if exact:
        r.reuse = None
    return r


def _animate_video(head: str | None, video: str, out: str, side_by_side: bool,
                   head_pose: bool, fps: float | None, start: float | None,
                   end: float | None, yaw: float, pitch: float, on_bad: str, no_hair: bool,
                   backend: str, onnx_path: str, samples: int | None, size: int | None,
                   exact: bool, precision: str, face: int = 0) -> None:
    """``animate --video``: track and render in one pass (see
    :func:`head360cli.drive.animate.animate_video`)."""
    from head360cli.drive.animate import AnimateConfig, animate_video
    from head360cli.perception.track import TrackConfig

    track = TrackConfig(face=face, start=start, end=end, on_bad=on_bad, fps=fps)
    cfg = AnimateConfig(head_pose=head_pose, yaw=yaw, pitch=pitch, hair=not no_hair)
    with _head_or_mean(head) as path:
        renderer = _animate_renderer(path, backend, onnx_path, samples, size, precision,
                                     exact)
        res = animate_video(renderer, video, out, cfg, track, side_by_side,
                            progress=progress_printer())
    for warning in res.get("warnings", []):
        warn(warning)
    emit(res, f"tracked and animated {res['frames']} frames ({res['duration_s']:.2f} s at "
              f"{res['fps']:.2f} fps; a face in {res['frames_with_face']} of "
              f"{res['frames_decoded']}), {res['render_fps']:.1f} frames/s\n  wrote {out}")


def _mean_head_file(folder: Path) -> Path:
    """The model's mean head (seed 0's hairstyle and colour, lids fitted) as a head file
    in ``folder``."""
    from head360cli.drive.sample import sample_heads
    from head360cli.io.headfile import write_head

    return write_head(sample_heads(1, seed=0, scale=0.0)[0], folder / "mean.h360")


def _mean_head_renderer(device: str | None = None):
    """The model's mean head, bald, on ``device`` (default: ``--device``)."""
    from head360cli.devices import resolve_device
    from head360cli.drive.sample import sample_heads
    from head360cli.model.head_render import HeadRenderer
    from head360cli.model.train import load_generator

    device = device or str(resolve_device(current_settings().device))
    head = sample_heads(1, scale=0.0, device=device, lids=False)[0]  # still views
    gen, _ = load_generator(device=device)
    import torch

    a = head.arrays
    return HeadRenderer(gen, a["shape"], torch.as_tensor(a["texture"]), 0,
                        a["hair_color"])


@cli.command()
@click.option("-n", "--count", type=int, default=None,
              help="How many heads.  [default: 8; 1 when -o names a .h360 file]")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Random seed.")
@click.option("--spread", default=1.0, show_default=True,
              help="Spread around the mean head (0 = the mean head, 1 = the prior's).")
@click.option("--bald", is_flag=True, help="No hair.")
@click.option("-o", "--out", "out_dir", default="samples", show_default=True,
              type=OutputPath(),
              help="Folder for the heads (sample_000.h360...) and samples.png, or one "
                   "NAME.h360 file (its picture beside it as NAME.png).")
@click.option("--no-lid-fit", is_flag=True,
              help="Skip fitting each head's closed eyelids (about 1 s a head): closed "
              "eyes then render as the generator draws them, a dark smudge.")
@common_options
def sample(count: int | None, seed: int, spread: float, bald: bool, out_dir: str,
           no_lid_fit: bool) -> None:
    """Draw random heads from the model and render them side by side.

    Each head gets the texture change that closes its eyelids as it blinks, as a fit
    does.

    \b
    Examples:
      head360 sample
      head360 sample -n 16 --seed 3 -o crowd/
      head360 sample --seed 7 -o stranger.h360
    """
    import numpy as np
    import torch
    from PIL import Image

    from head360cli.devices import resolve_device
    from head360cli.drive.sample import sample_heads, sample_names
    from head360cli.drive.views import grid_image, view_cameras, view_intrinsics
    from head360cli.io.atomic import atomic_paths
    from head360cli.io.headfile import write_head
    from head360cli.model.head_render import HeadRenderer
    from head360cli.model.train import load_generator

    out = Path(out_dir)
    one_file = out.suffix.lower() == ".h360"
    if count is None:
        count = 1 if one_file else 8
    if not 1 <= count <= 1000:
        raise BadInputError(f"expected --count between 1 and 1000, found {count}")
    if one_file and count != 1:
        raise BadInputError(f"expected -n 1 with one head file ({out}), found -n {count}; "
                            f"give a folder for several heads")
    if one_file and out.is_dir():
        raise BadInputError(f"expected a head file to write, found a folder: {out}")
    if not one_file and out.exists() and not out.is_dir():
        raise BadInputError(f"expected a folder for the heads, found a file: {out}")
    if not one_file:
        from head360cli.io.atomic import check_folder_name

        check_folder_name(out)
    from head360cli.io.images import check_companion_png, png_info

    sheet = out.with_suffix(".png") if one_file else out / "samples.png"
    if not _sampled_before(out if one_file else out / "sample_000.h360"):
        check_companion_png(sheet, "picture of the heads")  # NAME.png may be the user's photo
    device = str(resolve_device(current_settings().device))
    heads = sample_heads(count, seed, spread, bald, device, lids=not no_lid_fit)
    gen, _ = load_generator(device=device)
    cam = view_cameras(20.0, 0.0)
    tiles = []
    for h in heads:
        a = h.arrays
        r = HeadRenderer(gen, a["shape"], torch.as_tensor(a["texture"]),
                         int(a["hair_style"]), a["hair_color"])
        tiles.append(next(r.frames(cam, np.zeros((1, 52)), view_intrinsics(r.size)))[0])
    # the heads and their picture are renamed into place together, once all are written
    paths = [out] if one_file else sample_names(count, out)
    (out.parent if one_file else out).mkdir(parents=True, exist_ok=True)
    with atomic_paths(*paths, sheet) as tmps:
        for head, tmp in zip(heads, tmps[:-1], strict=True):
            write_head(head, tmp)
        Image.fromarray(grid_image(np.stack(tiles), cols=min(count, 8))).save(
            tmps[-1], format="PNG", pnginfo=png_info())
    emit({"heads": [str(p) for p in paths], "sheet": str(sheet)},
          f"wrote {out} and {sheet}" if one_file
          else f"wrote {count} heads into {out}/ and {sheet}")


def _sampled_before(head: Path) -> bool:
    """Whether ``head`` is a head file ``sample`` wrote (its info says ``sampled``): the
    picture beside it is then that run's, written before pictures carried head360's PNG
    mark."""
    from head360cli.io.headfile import read_head

    if not head.is_file():
        return False
    try:
        return "sampled" in read_head(head).info
    except Exception:  # not a head file: the picture's own mark decides
        return False


@cli.command("export-mesh")
@click.argument("head", type=_HEAD, callback=stdin_path("a head file"))
@click.option("-o", "--out", required=True, type=OutputPath(dir_okay=False),
              help=".glb (52 ARKit morph targets, baked texture) or .obj (+ .mtl, .png).")
@click.option("--texture-size", default=512, show_default=True,
              help="Baked texture width and height.")
@click.option("--no-hair", is_flag=True, help="Leave the hair mesh out.")
@common_options
def export_mesh(head: str, out: str, texture_size: int, no_hair: bool) -> None:
    """Export a head as a mesh for Blender, three.js or a game engine.

    The appearance is baked from renders into a colour texture (head) and vertex colours
    (hair). In the GLB the 52 ARKit blendshapes are named morph targets.

    \b
    Examples:
      head360 export-mesh me.h360 -o me.glb
      head360 export-mesh me.h360 -o me.obj --texture-size 1024
    """
    from head360cli.drive.bake import export_head

    if not 64 <= texture_size <= 4096:
        raise BadInputError(f"expected --texture-size between 64 and 4096, found "
                            f"{texture_size}")
    if Path(out).suffix.lower() not in (".glb", ".obj"):
        raise BadInputError(f"expected a .glb or .obj output, found {out!r}")
    from head360cli.io.atomic import check_file_target

    check_file_target(out)  # before the head is loaded
    r = _renderer(head, None, None)
    res = export_head(r, out, texture_size, hair=not no_hair, progress=progress_printer())
    parts = ", ".join(f"{name} {n} vertices" for name, n in res["part_vertices"].items())
    emit(res, f"wrote {', '.join(res['files'])} ({parts}; {res['faces']} head triangles, "
          f"{res['morph_targets']} morph targets)")


@cli.command("export-onnx")
@click.option("-o", "--out", default="generator.onnx", show_default=True,
              type=OutputPath(dir_okay=False),
              help="The graph with hair; the bald graph goes beside it (NAME_bald.onnx).")
@click.option("--head", "head", default=None, type=_HEAD,
              help="Trace with this head and write its per-head inputs "
              "(<head>_inputs.npz) for a torch-free runner (default: the mean head).")
@click.option("--samples", type=int, default=None,
              help="Samples per pixel, 1, 2 or 4 (per ray for a hex-plane generator), "
                   "fixed in the graph (default: the generator's own).")
@click.option("--size", type=int, default=256, show_default=True,
              help="Image size, fixed in the graph.")
@common_options
def export_onnx_cmd(out: str, head: str | None, samples: int | None, size: int) -> None:
    """Export the per-frame generator (rasterization included) to ONNX for onnxruntime.

    Inputs per frame: the mesh vertices, the neural texture, the camera and, for the hair
    graph, the hair mesh and its planes; output: the RGB image. The runner class
    head360cli.export.onnx.OnnxFrameRunner calls it without torch. The graph is traced
    on the CPU whatever --device says: it is the same graph for any device.

    \b
    Examples:
      head360 export-onnx -o generator.onnx
      head360 export-onnx --head me.h360 --samples 1 -o me.onnx
    """
    from head360cli.export.onnx import export_onnx, head_inputs
    from head360cli.io.sources import input_stem

    check_size(size)
    if samples is not None and not 1 <= samples <= 64:
        raise BadInputError(f"expected --samples between 1 and 64, found {samples}")
    # the graph is the same for any device, and torch's exporter failed to trace a CUDA
    # renderer (a data-dependent size in the hair planes' grid_sample; torch 2.11 on an
    # H200) where it traced the same renderer on that machine's CPU in 51 s
    cpu_only_warning("export-onnx", "traces")
    if head is not None:
        own = _renderer(head, samples, size, "fp32", device="cpu")  # read once: maybe a pipe
        # the bald graph needs no hair; a bald head traces the hair graph wearing bob
        r = own if own.hair is not None else own.with_hair(11, own.hair_colour)
    else:
        r = _mean_head_renderer(device="cpu")
        try:
            r.gen.image_size(size)  # raises now for a size the generator cannot make
        except ValueError as exc:
            raise BadInputError(str(exc)) from None
        if samples is not None:
            if r.gen.kind == "deferred" and samples not in (1, 2, 4):
                raise BadInputError(f"expected --samples 1, 2 or 4 (samples a pixel), "
                                    f"found {samples}")
            r.samples = samples
        r.size = size
        r = r.with_hair(11, r.hair_colour)
    inputs = None  # the head's arrays for a torch-free runner, one set with the graphs
    if head is not None:
        inputs = (Path(out).with_name(f"{input_stem(head)}_inputs.npz"), head_inputs(own))
    res = export_onnx(r, out, progress=progress_printer(), inputs=inputs)
    per = "pixel" if r.gen.kind == "deferred" else "ray"
    emit(res, f"exported in {res['seconds']:.0f} s ({r.samples} samples per {per}, "
          f"{size}x{size}): " + ", ".join(res["files"]))

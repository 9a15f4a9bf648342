"""The commands that read a photo or a video: ``fit``, ``parse-hair``, ``classify-hair``,
``demo`` and ``track``."""

from __future__ import annotations

from pathlib import Path

import click

from head360cli.cli.base import (
    DETECTOR,
    FACE_NUMBER,
    HAIR_PARSER,
    NO_PRIOR,
    PHOTO,
    InputPath,
    OutputPath,
    cli,
    common_options,
    cpu_only_warning,
    current_settings,
    emit,
    emit_to_stderr,
    progress_printer,
    warn,
    warn_unused,
)
from head360cli.errors import BadInputError


@cli.command()
@PHOTO
@click.option("--stage", type=click.Choice(["all", "shape"]), default="all", show_default=True,
              help="How far to go. all: every stage, writing a head file; shape: landmarks, "
              "pose, identity and expression of the parametric head only.")
@click.option("-o", "--out", default=None, type=OutputPath(),
              help="The head file (default <photo stem>.h360); with --stage shape, the "
              "output folder (default head360-out).")
@click.option("--preset", type=click.Choice(["fast", "quality"]), default="fast",
              show_default=True, help="Texture inversion effort.")
@click.option("--hair", "hair_style", default=None,
              help="Use this hairstyle (name such as bob or 'long wavy', or id 0-29; an "
              "unknown name lists them all) instead of the classifier's choice.")
@click.option("--face", default="0", show_default=True,
              help="Which face: 0 = the largest, 1 = the next... ('all' with --stage shape).")
@DETECTOR
@click.option("--focal", type=float, default=None,
              help="Focal length in pixels (default: from EXIF, else a 50 mm-equivalent "
              "lens).")
@click.option("--distance", type=click.FloatRange(min=0.0, min_open=True), default=None,
              help="The camera's distance to the head in metres, when known (a rig): fixes "
              "the head's size, which landmarks alone hardly tell from its distance.")
@click.option("--no-lid-fit", is_flag=True,
              help="Keep the inversion's eyelids: skip refitting the texels a blink moves "
              "(closed eyes then render as a dark smudge that hardly reads as closed).")
@HAIR_PARSER
@NO_PRIOR
@common_options
def fit(photo: str, stage: str, out: str | None, preset: str, hair_style: str | None,
        face: str, detector: str, focal: float | None, distance: float | None,
        no_lid_fit: bool, hair_parser: str, no_prior: bool) -> None:
    """Fit a head to a photo.

    Every stage: face and landmarks, shape fit, hair parsing, hairstyle and hair colour,
    bald target, neural-texture inversion, closed eyelids. Writes the head file, a preview
    PNG (photo | fitted front | three other views | back) and a JSON summary with timings
    per stage.

    With --stage shape: writes the mesh (OBJ with UVs), an overlay PNG (detected landmarks
    green, fitted red, mesh wireframe) and the parameters as JSON.

    \b
    Examples:
      head360 fit photo.jpg                      -> photo.h360, photo_preview.png, photo.json
      head360 fit photo.jpg -o me.h360 --preset quality
      head360 fit photo.jpg --hair bob --json
      head360 fit profile.jpg --no-prior          hair parsed by colour and landmarks alone
      head360 fit rig_photo.jpg --distance 1.0 --focal 2400
      head360 fit photo.jpg --stage shape -o out/
      curl -s URL | head360 fit - -o me.h360     a photo on standard input
      head360 fit group.jpg --stage shape --face all --json > faces.json
    """

    if face != "all" and not face.isdigit():
        raise BadInputError(f"expected --face N or all, found {face!r}")
    if stage == "shape":
        from head360cli.fitting.pipeline import fit_shape_photo

        warn_unused(("preset", "hair_style", "no_lid_fit", "hair_parser", "no_prior"),
                    "with --stage shape")

        result = fit_shape_photo(photo, out or "head360-out",
                                 face=face if face == "all" else int(face),
                                 detector=detector, focal=focal, distance=distance)
        faces = result.get("faces", [result])
        lines = []
        for r in faces:
            pose = r["pose"]
            top = sorted(r["expression"].items(), key=lambda kv: -kv[1])[:3]
            lines.append(
                f"face {r['face']}: yaw {pose['yaw']:.1f}, pitch {pose['pitch']:.1f}, roll "
                f"{pose['roll']:.1f} deg; strongest expressions "
                + ", ".join(f"{n} {w:.2f}" for n, w in top)
                + f"; fit {1000 * r['timings']['fit']:.1f} ms")
            lines += [f"  wrote {p}" for p in r["files"].values()]
        emit(result, "\n".join(lines))
        return
    if face == "all":
        raise BadInputError("expected one face number for a full fit, found 'all' (use "
                            "--stage shape for every face)")
    if hair_parser == "segmenter":
        warn_unused(("no_prior",), "with --hair-parser segmenter")
    from head360cli.devices import resolve_device
    from head360cli.fitting.config import FitConfig
    from head360cli.fitting.pipeline import fit_photo
    from head360cli.io.sources import input_stem
    from head360cli.synth.hair import style_index

    config = FitConfig(preset=preset, face=int(face), detector=detector, focal=focal,
                       distance=distance,
                       hair_style=None if hair_style is None else style_index(hair_style),
                       learned_prior=not no_prior, hair_parser=hair_parser,
                       closed_lids=not no_lid_fit,
                       device=str(resolve_device(current_settings().device)))
    target = out or f"{input_stem(photo)}.h360"
    result = fit_photo(photo, target, config, progress=progress_printer())
    for warning in result["warnings"]:
        warn(warning)
    t = result["timings"]
    text = (f"fitted {photo}: yaw {result['pose']['yaw']:.1f} deg, hair "
            f"{result['hair_style']['name']} ({result['hair_color_name']}), face PSNR "
            f"{result['psnr_face_input_view']:.2f} dB at the input view"
            f"{' (in grey)' if result['inversion']['fitted_in'] == 'grey' else ''}, "
            f"{t['total']:.1f} s (" + ", ".join(f"{k} {v:.1f}" for k, v in t.items()
                                                 if k != "total") + ")\n"
            + "\n".join(f"  wrote {Path(p).resolve()}" for p in result["files"].values()))
    if out is None and Path(photo).is_file() and \
            Path(photo).parent.resolve() != Path.cwd().resolve():
        text += ("\n  (named after the photo, in the current folder, not the photo's: "
                 "-o PATH writes elsewhere)")
    emit(result, text)


@cli.command("parse-hair")
@PHOTO
@click.option("-o", "--out", "out_dir", default="head360-out", show_default=True,
              type=OutputPath(file_okay=False), help="Output folder.")
@FACE_NUMBER
@DETECTOR
@HAIR_PARSER
@NO_PRIOR
@common_options
def parse_hair_cmd(photo: str, out_dir: str, face: int, detector: str,
                   hair_parser: str, no_prior: bool) -> None:
    """Hair and face-skin masks of a photo.

    Writes <stem>_hair.png and <stem>_face.png (single channel, the photo's size, 255
    inside) and <stem>_parse.png (hair red, face blue). Without a detectable face the hair
    is kept to the fitted face's head. By default MediaPipe's hair segmentation network
    reads the photo and its mirror image; the face below the brows is never hair, and
    only hair connected to the face's head counts. --hair-parser grabcut parses by
    colour from the landmarks instead, guided by a small network trained on the
    synthetic corpus (models/hair_prior.pt).

    \b
    Examples:
      head360 parse-hair photo.jpg -o masks/
      head360 parse-hair photo.jpg --hair-parser grabcut --no-prior  colour and landmarks
      head360 parse-hair photo.jpg --json     {"hair_mask": ..., "face_mask": ..., "overlay": ...}
    """
    from head360cli.fitting.pipeline import parse_photo

    cpu_only_warning("parse-hair", "parses")
    if hair_parser == "segmenter":
        warn_unused(("no_prior",), "with --hair-parser segmenter")
    r = parse_photo(photo, out_dir, face=face, detector=detector, learned_prior=not no_prior,
                    hair_parser=hair_parser)
    for warning in r["warnings"]:
        warn(warning)
    emit(r, f"hair {100 * r['hair_fraction']:.1f}% and face {100 * r['face_fraction']:.1f}% "
          f"of the image{'' if r['seeded'] else _unseeded(r)}; wrote "
          f"{r['hair_mask']}, {r['face_mask']}, {r['overlay']}")


def _unseeded(r: dict) -> str:
    """How ``parse-hair``'s line names a parse without landmarks."""
    return (" (no frontal face: colour and a face in profile)" if r["profile_face"]
            else " (no face found: colour only)")


@cli.command("classify-hair")
@PHOTO
@click.option("--top", default=3, show_default=True, help="How many styles to list.")
@FACE_NUMBER
@DETECTOR
@HAIR_PARSER
@NO_PRIOR
@common_options
def classify_hair_cmd(photo: str, top: int, face: int, detector: str,
                      hair_parser: str, no_prior: bool) -> None:
    """The SynHead-P hairstyles that best match a photo's hair, and its colour.

    Each of the 30 styles is fitted to the photo's fitted head and rasterized from its
    camera; the score is the overlap of that silhouette with the parsed hair, leaving out
    the strip below the chin that the body hides. Styles that differ only behind the
    head (ponytails, bun, braid) have the same silhouette from the front: the output says
    which share the first one's.

    \b
    Examples:
      head360 classify-hair photo.jpg
      head360 classify-hair photo.jpg --top 5 --json
    """
    from head360cli.fitting.pipeline import classify_photo

    if not 1 <= top <= 30:
        raise BadInputError(f"expected --top between 1 and 30, found {top}")
    if hair_parser == "segmenter":
        warn_unused(("no_prior",), "with --hair-parser segmenter")
    r = classify_photo(photo, face=face, detector=detector, top=top,
                       learned_prior=not no_prior, hair_parser=hair_parser)
    for warning in r["warnings"]:
        warn(warning)
    lines = [f"{i + 1}. {c['name']} (id {c['id']}): score {c['score']:.3f}, "
             f"overlap {c['iou']:.3f}"
             + (" (the same silhouette as 1. from this view)"
                if i and c["same_silhouette_as_first"] else "")
             for i, c in enumerate(r["top"])]
    if not r["hair_matches_a_style"]:
        lines.append("the parsed hair matches no hairstyle: ranked as no hair")
    lines.append(f"hair colour: {r['hair_color_name']} (linear RGB "
                 + ", ".join(f"{c:.3f}" for c in r["hair_color"])
                 + "; by the tone curve: head360 fit also compares renders)")
    emit(r, "\n".join(lines))


@cli.command()
@click.option("-o", "--out", "out_dir", default="head360-demo", show_default=True,
              type=OutputPath(file_okay=False), help="Output folder.")
@click.option("--preset", type=click.Choice(["fast", "quality"]), default="fast",
              show_default=True, help="Texture inversion effort.")
@click.option("--frames", default=48, show_default=True, help="Turntable frames.")
@common_options
def demo(out_dir: str, preset: str, frames: int) -> None:
    """Fit the astronaut photo that ships with scikit-image and render a turntable.

    Writes astronaut.png, astronaut.h360, its preview and JSON summary, and turntable.mp4
    (an animated GIF when no ffmpeg is installed) into the output folder.

    \b
    Examples:
      head360 demo
      head360 demo -o demo/ --preset quality --frames 96
    """
    from head360cli.devices import resolve_device
    from head360cli.fitting.pipeline import run_demo

    if not 4 <= frames <= 720:
        raise BadInputError(f"expected --frames between 4 and 720, found {frames}")
    r = run_demo(out_dir, preset=preset, frames=frames,
                 device=str(resolve_device(current_settings().device)),
                 progress=progress_printer())
    emit(r, f"fitted the astronaut in {r['fit']['timings']['total']:.1f} s; hair "
          f"{r['fit']['hair_style']['name']}; wrote "
          + ", ".join([*r["fit"]["files"].values(), r["turntable"]]))


@cli.command()
@click.argument("source", metavar="INPUT", type=InputPath(exists=True, allow_dash=True))
@click.option("-o", "--out", required=True, type=OutputPath(dir_okay=False, allow_dash=True),
              help="The CSV stream to write (written whole at the end, never half); - for "
                   "standard output (the summary then goes to standard error).")
@click.option("--format", "fmt", type=click.Choice(["livelinkface", "mediapipe", "generic"]),
              default="livelinkface", show_default=True,
              help="livelinkface: Timecode, BlendshapeCount, the app's 52 columns and 9 "
                   "rotations; mediapipe: timestamp_ms and MediaPipe's names and order; "
                   "generic: time in seconds and the 52 ARKit names.")
@click.option("--smooth", type=float, default=1.5, show_default=True,
              help="One Euro filter cutoff in Hz when still (lower: smoother); 0: off.")
@click.option("--face", type=click.IntRange(min=0), default=0, show_default=True,
              help="Which face when several show: 0 = the largest, 1 = the next...")
@click.option("--start", type=float, default=None, help="Seconds into the input to start.")
@click.option("--end", type=float, default=None, help="Stop before this second of the input.")
@click.option("--on-bad", type=click.Choice(["hold", "skip", "error"]), default="hold",
              show_default=True,
              help="A frame without a face: hold the last reading, skip the frame, or stop.")
@click.option("--fps", type=float, default=None,
              help="Frame rate of a folder of frames (default 30), or in place of a video's.")
@click.option("--stills", is_flag=True,
              help="Every frame is a photo of its own: searched whole, never smoothed with "
                   "another (a cut in a video, or between unrelated photos, is found "
                   "without it).")
@common_options
def track(source: str, out: str, fmt: str, smooth: float, face: int, start: float | None,
          end: float | None, on_bad: str, fps: float | None, stills: bool) -> None:
    """Track a face through a video into an ARKit-52 stream: 52 blendshape weights, head
    and eye rotations, at the video's frame rate.

    INPUT is a video (mp4, mov, webm, gif, ...), a folder of frames (read in name order),
    or - for a video on standard input. The stream reads back with 'head360 inspect' and
    drives 'head360 animate --arkit'.

    \b
    Examples:
      head360 track clip.mp4 -o take.csv
      head360 track frames/ --fps 25 --format generic -o take.csv
      cat clip.webm | head360 track - -o take.csv --smooth 0 --json
      head360 track clip.mp4 -o take.csv && head360 animate me.h360 --arkit take.csv -o me.mp4
      head360 track clip.mp4 -o - | head360 animate me.h360 --arkit - -o me.mp4
      head360 track portraits/ --stills --format generic -o scores.csv
    """
    from head360cli.io.arkit import write_arkit_csv
    from head360cli.io.atomic import check_file_target
    from head360cli.perception.track import TrackConfig, track_video

    to_stdout = out == "-"
    if not to_stdout and Path(out).suffix.lower() not in (".csv", ".txt"):
        raise BadInputError(f"expected an output ending in .csv (or - for standard output), "
                            f"found {out!r}")
    cfg = TrackConfig(face=face, start=start, end=end, smooth=smooth, on_bad=on_bad, fps=fps,
                      stills=stills)
    if not to_stdout:
        check_file_target(out)  # before the video is read
    cpu_only_warning("track", "tracks")
    show = progress_printer()
    bar = None if show is None else (lambda done, total: show("track", done, total))
    stream, summary = track_video(source, cfg, progress=bar)
    flavor = {"livelinkface": "livelinkface", "mediapipe": "mediapipe", "generic": "arkit"}[fmt]
    if to_stdout:  # the whole text at once, as a file is written whole
        import io

        text = io.StringIO()
        write_arkit_csv(stream, text, flavor=flavor)
        click.echo(text.getvalue(), nl=False)
    else:
        write_arkit_csv(stream, out, flavor=flavor)
    for message in summary["warnings"]:
        warn(message)
    summary["out"], summary["format"] = out, fmt
    cuts = summary["cuts"]
    line = (f"tracked {summary['frames_with_face']} of {summary['frames']} frames "
            + (f"in {cuts + 1} shots " if cuts else "")
            + f"({summary['tracking_fps']:g} frames/s tracking, "
            f"{summary['fps_all_in']:g} with decoding) -> "
            f"{'standard output' if to_stdout else out}")
    if to_stdout:  # standard output carries the stream: the summary goes beside it
        emit_to_stderr(summary, line)
    else:
        emit(summary, line)

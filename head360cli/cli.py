"""The ``head360`` command line: parses, calls the library, prints. Nothing else.

Heavy modules (torch, OpenCV, dlib) are imported inside the commands, so ``head360 --help``
starts instantly. Errors from the :mod:`head360cli.errors` family become one line on
stderr and their own exit code; ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from head360cli import __version__
from head360cli.errors import EXIT_CODES, BadInputError, Head360Error, is_out_of_memory

__all__ = ["cli", "main"]

EPILOG_EXIT_CODES = (
    "Exit codes: 0 ok, 1 internal error, 2 usage error, 3 bad input, 4 no face found, "
    "5 bad file format, 6 model mismatch, 7 model or package not installed, 8 out of memory, "
    "129 hung up, 130 interrupted, 143 terminated."
)


@dataclasses.dataclass
class Settings:
    """Options shared by every subcommand (given before or after the subcommand name)."""

    device: str = "cpu"
    """Torch device: cpu, cuda, cuda:N or auto."""
    quiet: bool = False
    """No progress bars and no warnings on stderr."""
    json: bool = False
    """Print one machine-readable JSON object on stdout instead of text."""
    debug: bool = False
    """Show full tracebacks for errors."""


def _settings() -> Settings:
    ctx = click.get_current_context()
    root = ctx.find_root()
    if not isinstance(root.obj, Settings):
        root.obj = Settings()
    return root.obj


def _set(field: str) -> Callable[[click.Context, click.Parameter, Any], Any]:
    def callback(ctx: click.Context, param: click.Parameter, value: Any) -> Any:
        # A flag given anywhere wins; --device given later overrides an earlier one.
        if value is None or value is False:
            return value
        setattr(_settings(), field, value)
        return value

    return callback


class InputPath(click.Path):
    """A file or folder head360 reads. click's own checks refused one that is missing
    (where ``exists``), of the wrong kind or unreadable as a usage error (exit 2, three
    lines), where the commands' own checks say a missing file in one line, exit 3; this
    type refuses each as :class:`BadInputError` does. Without ``exists``, a missing
    input is left to the command, which says so in its own words."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(readable=False, **kwargs)

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None
                ) -> Any:
        if value != "-" or not self.allow_dash:
            name, text = _param_name(param), repr(os.fspath(value))
            if not os.path.exists(value):
                if self.exists:
                    from head360cli.io.sources import missing

                    raise missing(value, f"{text} ({name}) does not exist")
            else:
                error = _kind_error(self, value, name, text)
                if error is not None:
                    raise error
                if not os.access(value, os.R_OK):
                    raise BadInputError(f"cannot read {text} ({name}): permission denied")
        return super().convert(value, param, ctx)


class OutputPath(click.Path):
    """A file or folder head360 writes (or makes). click refused an existing one of the
    wrong kind (a folder for a file) as a usage error, and an existing write-only one as
    unreadable; this type says the first as :class:`BadInputError` does and leaves the
    second to the writers' own checks."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(readable=False, **kwargs)

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None
                ) -> Any:
        if os.path.exists(value):
            error = _kind_error(self, value, _param_name(param), repr(os.fspath(value)))
            if error is not None:
                raise error
        return super().convert(value, param, ctx)


def _param_name(param: click.Parameter | None) -> str:
    """How an error names ``param``: ``--arkit`` for an option, ``HEAD`` for an argument."""
    if isinstance(param, click.Option):
        return param.opts[0]
    return param.human_readable_name if param is not None else "input"


def _kind_error(path_type: click.Path, value: Any, name: str, text: str
                ) -> BadInputError | None:
    """The error for an existing ``value`` that is a folder where ``path_type`` takes
    files only, or a file where it takes folders only; ``None`` if it is the right kind."""
    if os.path.isdir(value) and not path_type.dir_okay:
        return BadInputError(f"expected a file for {name}, found a folder: {text}")
    if not os.path.isdir(value) and not path_type.file_okay:
        return BadInputError(f"expected a folder for {name}, found a file: {text}")
    return None


def _stdin_path(what: str) -> Callable[[click.Context, click.Parameter, Any], Any]:
    """A click callback that reads an input argument of ``-`` (``what``: "a photo") from
    standard input, through ``/dev/stdin`` as any pipe is read (outputs named after it
    are called ``pipe``); refused when standard input is a terminal."""

    def callback(ctx: click.Context, param: click.Parameter, value: Any) -> Any:
        if value != "-":
            return value
        from head360cli.io.sources import check_stdin

        check_stdin(what)
        if not os.path.exists("/dev/stdin"):
            raise BadInputError(f"expected {what} in a file: this system has no /dev/stdin "
                                "to read '-' from")
        return "/dev/stdin"

    return callback


PHOTO = click.argument("photo", type=InputPath(dir_okay=False),
                       callback=_stdin_path("a photo"))
"""The photo argument of fit, parse-hair and classify-hair: a file, a pipe or ``-``."""


def common_options(f: Callable[..., Any]) -> Callable[..., Any]:
    """Add --device/--quiet/--json/--debug to a command (they also work on the group)."""
    options = [
        click.option("--device", default=None, expose_value=False, callback=_set("device"),
                     help="Torch device: cpu (default), cuda, cuda:N or auto."),
        click.option("--quiet", "-q", is_flag=True, default=False, expose_value=False,
                     callback=_set("quiet"), help="No progress bars or warnings."),
        click.option("--json", "json_", is_flag=True, default=False, expose_value=False,
                     callback=_set("json"), help="Print one JSON object on stdout."),
        click.option("--debug", is_flag=True, default=False, expose_value=False,
                     callback=_set("debug"), help="Show tracebacks for errors."),
    ]
    for option in reversed(options):
        f = option(f)
    return f


def _emit(result: dict[str, Any], text: str) -> None:
    """Print ``result`` as JSON under --json, else ``text``.

    Raises:
        BadInputError: Standard output cannot be written (``> result.json`` on a full
            disk): said in one line, where it was a traceback under --json.
    """
    if _settings().json:
        from head360cli.io.jsontext import dumps

        text = dumps(result)
    try:
        click.echo(text.rstrip("\n"))
    except BrokenPipeError:
        raise  # a reader that has stopped reading (| head): not an error, see _run
    except OSError as exc:
        _drop_stdout()
        raise BadInputError(f"cannot write the result to standard output: "
                            f"{exc.strerror or exc}") from None


def _drop_stdout() -> None:
    """Send what is left for standard output nowhere, once writing it failed: the text
    still buffered would fail again when Python flushes it at exit, printed as an
    exception and exit 120."""
    with contextlib.suppress(OSError, ValueError):
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 (kept open until the exit)


def _warn(message: str) -> None:
    if not _settings().quiet:
        click.echo(f"head360: warning: {message}", err=True)


def _unused(names: tuple[str, ...], why: str) -> None:
    """Warn about the options among ``names`` (parameter names) that were given on the
    command line but do nothing ``why`` (for example "with --stage shape"): a user
    should not think they took effect."""
    from click.core import ParameterSource

    ctx = click.get_current_context()
    flags = [p.opts[0] for p in ctx.command.params if p.name in names
             and ctx.get_parameter_source(p.name) is not ParameterSource.DEFAULT]
    if flags:
        _warn(f"{' and '.join(flags)} {'is' if len(flags) == 1 else 'are'} not used {why}")


def _cpu_only(command: str, does: str = "measures") -> None:
    """Warn that ``command`` ``does`` (measures, renders, ...) on the CPU when --device
    names another device (every command takes --device; these would otherwise ignore it
    silently)."""
    device = _settings().device
    if device and device.lower() != "cpu":
        _warn(f"{command} {does} on the CPU; --device {device} is not used")


@click.group(
    context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100},
    epilog=EPILOG_EXIT_CODES,
)
@click.version_option(__version__, "--version", "-V", prog_name="head360",
                      message="%(prog)s %(version)s")
@common_options
def cli() -> None:
    """head360: one photo to an animatable head you can render in 360 degrees.

    \b
    Examples:
      head360 info                      versions, devices, installed models
      head360 inspect take.csv          what an ARKit stream, image or head file holds
      head360 inspect take.csv --json   the same as one JSON object
    """
    _settings()
    _check_working_folder()


def _check_working_folder() -> None:
    """Refuse a current folder that was deleted (a batch script's ``rm -rf`` of the
    folder it runs in). torch cannot be imported there: oneMKL stopped the process with
    "FATAL ERROR: Cannot load libtorch_cpu.so", exit 2, as if the install were broken;
    and no relative name can be read or written there anyway."""
    try:
        os.getcwd()
    except FileNotFoundError:
        raise BadInputError("expected a current folder that exists, found it deleted: "
                            "cd to an existing folder and run again") from None


@cli.command()
@common_options
def info() -> None:
    """Versions of the libraries, devices, and which model files are installed.

    \b
    Examples:
      head360 info
      head360 info --json | python -m json.tool
    """
    from head360cli.devices import resolve_device
    from head360cli.report import environment_report

    report = environment_report()
    report["device"] = str(resolve_device(_settings().device))
    lines = [f"head360 {report['head360']}  (Python {report['python']}, {report['platform']})"]
    lines.append("packages:")
    for name, version in report["packages"].items():
        lines.append(f"  {name:<13} {version or 'not installed'}")
    lines.append("devices:")
    for d in report["devices"]:
        extra = f"{d['threads']} threads" if d["name"] == "cpu" else (
            f"{d['model']}, {d['memory_gib']} GiB")
        lines.append(f"  {d['name']:<13} {extra}")
    lines.append(f"  selected      {report['device']}")
    telemetry = {True: " (usage telemetry on)", False: " (usage telemetry off)"}.get(
        report["onnxruntime_telemetry"], "")
    lines.append(f"  onnxruntime   {', '.join(report['onnxruntime_providers']) or 'none'}"
                 f"{telemetry}")
    lines.append(f"models ({report['models_dir']}):")
    if not report["models"]:
        lines.append("  (no model files installed yet)")
    for m in report["models"]:
        line = f"  {m['name']:<24} {m['bytes'] / 1e6:8.2f} MB  file sha256 {m['sha256'][:16]}"
        if "model_hash" in m:
            line += f"  model {m['model_hash'][:16]}"
        lines.append(line)
    lines.append("dlib weights (face-recognition-models):")
    for key, path in report["dlib_models"].items():
        lines.append(f"  {key:<20} {'present' if path else 'MISSING'}")
    lines.append(f"shared evaluation data: {report['shared_data'] or 'not found'}")
    lines.append(f"cache: {report['cache'] or 'off (HEAD360_CACHE empty, or no home folder)'}")
    _emit(report, "\n".join(lines))


def _format_stream(r: dict[str, Any]) -> str:
    lines = [
        f"{r['path']}: ARKit stream ({r['format']})",
        f"  frames       {r['frames']}",
        f"  frame rate   {r['fps']:g} fps" + (
            f" (timecodes at {r['nominal_fps']:g})" if r["nominal_fps"] else ""),
        f"  duration     {r['duration_s']:.3f} s",
        f"  blendshapes  {len(r['columns_found'])} of 52 found",
    ]
    if r["columns_missing"]:
        lines.append(f"  missing      {', '.join(r['columns_missing'])}")
    if r["columns_ignored"]:
        lines.append(f"  ignored      {', '.join(r['columns_ignored'])}")
    if "head_rotation_deg" in r:
        rot = r["head_rotation_deg"]
        lines.append("  head pose    " + ", ".join(
            f"{k} {v['min']:.1f}..{v['max']:.1f} deg" for k, v in rot.items()))
    if r.get("plot"):
        lines.append(f"  plot         {r['plot']}")
    lines.append(f"  {'blendshape':<22}{'min':>8}{'mean':>8}{'max':>8}")
    for name, s in r["blendshapes"].items():
        lines.append(f"  {name:<22}{s['min']:8.3f}{s['mean']:8.3f}{s['max']:8.3f}")
    return "\n".join(lines)


def _format_image(r: dict[str, Any]) -> str:
    return "\n".join([
        f"{r['path']}: image ({r['format']})",
        f"  size         {r['width']}x{r['height']} ({r['megapixels']} MP), mode {r['mode']}",
        f"  orientation  {r['orientation']} ({r['orientation_name']}); shown as "
        f"{r['display_size'][0]}x{r['display_size'][1]}",
        f"  frames       {r['frames']}",
        f"  colours      {_colours(r.get('colour_profile'), r.get('converted'))}",
        *([f"  tone         {r['tone']}"
           + (" (fit fits its grey; the skin's colour comes from the model)"
              if r["tone"] == "greyscale" else "")] if r.get("tone") else []),
        f"  file size    {r['bytes']} bytes",
        f"  pixels       {r.get('problem') or 'decoded without error'}",
    ])


def _colours(profile: str | None, converted: bool | None) -> str:
    """How ``inspect`` names an image's colour profile, and what loading does with it."""
    if profile is None:
        return "sRGB (no colour profile)"
    if profile == "unreadable":
        return "a colour profile that cannot be read (taken as sRGB)"
    if not converted:
        return f"profile {profile!r} (sRGB's: read as it is)"
    return f"profile {profile!r} (converted to sRGB on load)"


def _format_head(r: dict[str, Any]) -> str:
    meta = r["metadata"]
    lines = [
        f"{r['path']}: head360 head file, format version {meta['format_version']}",
        f"  model        {meta['model_hash']}",
        f"  created      {meta['created']} by {meta['created_by']}",
        "  arrays:",
    ]
    for name, a in r["arrays"].items():
        shape = "x".join(map(str, a["shape"])) or "scalar"
        lines.append(f"    {name:<14} {shape:<16} {a['dtype']}")
    for key, value in meta.get("info", {}).items():
        lines.append(f"  {key:<12} {value}")
    return "\n".join(lines)


def _format_model(r: dict[str, Any]) -> str:
    fmt = r["format"]
    lines = [f"{r['path']}: {fmt} ({r['bytes']} bytes, sha256 {r['sha256'][:16]})"]
    if fmt == "head360-generator":
        lines += [f"  model hash   {r['model_hash']} ("
                  f"{'the installed generator' if r['installed'] else 'not the installed one'}"
                  f"; head files record it)",
                  f"  trained      {r['step']} steps, {r['identities']} identities, "
                  f"{r['parameters']:,} parameters"]
    elif fmt == "head360-train":
        lines.append(f"  checkpoint   step {r['step']}, {r['parameters']:,} parameters")
    elif fmt == "head360-bilinear":
        lines.append(f"  model hash   {r['model_hash']} (head files record it)")
        lines += [f"  {k:<14} {'x'.join(map(str, v)) or 'scalar'}"
                  for k, v in r["arrays"].items()]
    elif fmt in ("head360-onnx", "onnx"):
        lines += [f"  input        {k} {v}" for k, v in r["inputs"].items()]
        lines += [f"  output       {k} {v}" for k, v in r["outputs"].items()]
        for key, value in (r["export"] or {}).items():
            lines.append(f"  {key:<12} {value}")
    else:  # the hair prior
        lines.append(f"  network      {r['parameters']:,} parameters")
    for key in ("generator_config", "train_config", "config"):
        for k, v in (r.get(key) or {}).items():
            lines.append(f"  {k:<12} {v}")
    return "\n".join(lines)


def _format_mesh(r: dict[str, Any]) -> str:
    if r["format"] == "obj":
        return (f"{r['path']}: Wavefront OBJ ({r['bytes']} bytes)\n"
                f"  geometry     {r['vertices']} vertices, {r['triangles']} triangles, "
                f"{r['uvs']} texture coordinates, {r['normals']} normals\n"
                f"  materials    {', '.join(r['material_libraries']) or 'none'}")
    lines = [f"{r['path']}: glTF binary ({r['bytes']} bytes"
             + (f", written by {r['generator']})" if r["generator"] else ")")]
    for m in r["meshes"]:
        targets = m["morph_targets"]
        named = m["morph_target_names"]
        lines.append(f"  mesh {m['name'] or '(unnamed)':<8} {m['vertices']} vertices, "
                     f"{m['triangles']} triangles, {targets} morph targets"
                     + (f" ({named[0]} ... {named[-1]})" if named else ""))
    for t in r["textures"]:
        size = "x".join(map(str, t["size"])) if t["size"] else "size unknown"
        lines.append(f"  texture      {size} {t['mime'] or ''}".rstrip())
    return "\n".join(lines)


@cli.command()
@click.argument("file", type=InputPath(dir_okay=False, allow_dash=True))
@click.option("--on-bad", type=click.Choice(["error", "skip", "hold"]), default="error",
              show_default=True, help="ARKit streams: what to do with NaN, empty or "
              "non-numeric cells and malformed rows.")
@click.option("--plot", type=OutputPath(dir_okay=False), default=None,
              help="ARKit streams: also draw the most active blendshapes and the head "
              "rotation over time into this PNG.")
@common_options
def inspect(file: str, on_bad: str, plot: str | None) -> None:
    """Tell what FILE is and holds: an ARKit stream, an image, a head file, a model file
    or an exported mesh.

    For an ARKit CSV stream: frames, frame rate, duration, columns found, missing or
    ignored, and min/mean/max per blendshape. For an image: size, mode, EXIF orientation,
    and whether its pixels decode.
    For a head file: its metadata and arrays. For head360's model files (generator
    weights, training checkpoints, the hair prior, the bilinear model, ONNX graphs): their
    format, configuration and the model hash head files record; nothing in them is run.
    For a .glb: its meshes, morph targets and textures; for an .obj, counts of its
    records. FILE may be - (standard input) or a pipe (<(...)), whose content says which
    it is.

    \b
    Examples:
      head360 inspect examples/smile_blink_livelinkface.csv
      head360 inspect photo.jpg --json
      head360 inspect take.csv --plot take.png
      head360 inspect models/generator.pt     which generator, trained how long
      head360 inspect me.glb                  morph targets and texture of an export
      cat take.csv | head360 inspect - --on-bad skip
    """
    from head360cli.report import inspect_file

    result = inspect_file(file, on_bad=on_bad, plot=plot)
    if result["kind"] != "arkit_stream":
        what = {"image": "an image", "head": "a head", "model": "a model file",
                "mesh": "a mesh"}[result["kind"]]
        _unused(("on_bad",), f"for {what}")
    for w in result.get("warnings", []):
        _warn(w)
    formatter = {"arkit_stream": _format_stream, "image": _format_image,
                 "head": _format_head, "model": _format_model,
                 "mesh": _format_mesh}[result["kind"]]
    _emit(result, formatter(result))


@cli.command()
@click.argument("outdir", type=OutputPath(file_okay=False))
@click.option("--identities", "-n", default=100, show_default=True,
              help="Identities to write.")
@click.option("--expressions", "-e", default=4, show_default=True,
              help="Per identity: neutral + (E-1) ARKit shapes at weight 1, rotating over "
              "identities; 53 = all 52 for everyone.")
@click.option("--views", "-v", default=24, show_default=True,
              help="Cameras per expression from the 72-camera rig (72 = all).")
@click.option("--size", default=256, show_default=True, help="Image width and height.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Corpus seed.")
@click.option("--split", type=click.Choice(["train", "test"]), default="train",
              show_default=True, help="test: held-out identities from other seeds.")
@click.option("--start", default=0, show_default=True,
              help="Index of the first identity (write a split in parts).")
@click.option("--samples", type=click.Choice(["1", "2", "4"]), default="2",
              show_default=True, help="Antialiasing samples per pixel.")
@click.option("--preview", is_flag=True,
              help="Only write contact sheets (identities x views, the 52 expressions, "
              "the 30 hairstyles) into OUTDIR.")
@common_options
def synth(outdir: str, identities: int, expressions: int, views: int, size: int, seed: int,
          split: str, start: int, samples: str, preview: bool) -> None:
    """Write the SynHead-P synthetic head corpus (deterministic from --seed) into OUTDIR.

    Each view is rendered with and without hair, with hair and face masks; index.jsonl
    lists identity, expression weights, hairstyle, hair colour and camera for every image.
    An interrupted run resumes: finished identities are skipped.

    \b
    Examples:
      head360 synth corpus/                       100 identities x 4 expressions x 24 views
      head360 synth corpus/ --split test -n 10    10 held-out identities
      head360 synth corpus/ -n 100 -e 53 -v 72    the full SynHead100-sized corpus
      head360 synth previews/ --preview           contact sheets only
    """
    from head360cli.progress import progress_bar

    _cpu_only("synth", "renders")
    settings = _settings()
    if preview:
        from head360cli.synth.corpus import write_previews

        paths = write_previews(outdir, seed=seed, split=split)
        _emit({"previews": paths}, "\n".join(f"wrote {p}" for p in paths))
        return
    from head360cli.synth.corpus import CorpusConfig, write_corpus

    cfg = CorpusConfig(identities=identities, expressions=expressions, views=views,
                       size=size, seed=seed, split=split, samples=int(samples), start=start)
    summary = write_corpus(
        cfg, outdir,
        progress=lambda it, total: progress_bar(it, total, "identities",
                                                enabled=not settings.quiet))
    # Two images (with and without hair) per view written this run; skipped ones cost nothing.
    per_view = summary["seconds"] / max(1, 2 * summary["views_written"])
    summary["ms_per_image_all_in"] = round(1000 * per_view, 1)  # incl. building heads
    _emit(summary, f"wrote {summary['identities_written']} identities "
                   f"({summary['identities_skipped']} already there), {summary['views']} "
                   f"views in the index, {summary['seconds']:.1f} s -> {summary['index']}")


NO_PRIOR = click.option(
    "--no-prior", is_flag=True,
    help="Parse the hair by colour and landmarks alone, without the learned hair prior.")
"""The ``--no-prior`` flag of fit, parse-hair and classify-hair."""

DETECTOR_HELP = ("dlib face detector: hog is fast; cnn finds harder and smaller faces, "
                 "slower; auto runs hog, then cnn on a copy at most 640 px long (about "
                 "2 s) only if hog finds no face.")
"""The help of ``--detector`` (fit, parse-hair, classify-hair)."""


def _progress_printer():
    """Progress of a fit's stages: one tqdm bar per stage on stderr, shown only on a
    terminal and without --quiet (the convention of :mod:`head360cli.progress`)."""
    if _settings().quiet or not sys.stderr.isatty():
        return None
    from tqdm import tqdm

    state: dict[str, Any] = {"stage": None, "bar": None}

    def show(stage: str, step: int, total: int) -> None:
        if stage != state["stage"]:
            if state["bar"] is not None:
                state["bar"].close()
            state["stage"] = stage
            state["bar"] = tqdm(total=total, desc=f"{stage:9s}", file=sys.stderr,
                                dynamic_ncols=True, leave=False)
        bar = state["bar"]
        bar.total = total
        bar.update(step - bar.n)

    return show


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
@click.option("--detector", type=click.Choice(["auto", "hog", "cnn"]), default="hog",
              show_default=True, help=DETECTOR_HELP)
@click.option("--focal", type=float, default=None,
              help="Focal length in pixels (default: from EXIF, else a 50 mm-equivalent "
              "lens).")
@click.option("--distance", type=click.FloatRange(min=0.0, min_open=True), default=None,
              help="The camera's distance to the head in metres, when known (a rig): fixes "
              "the head's size, which landmarks alone hardly tell from its distance.")
@click.option("--no-lid-fit", is_flag=True,
              help="Keep the inversion's eyelids: skip refitting the texels a blink moves "
              "(closed eyes then render as a dark smudge that hardly reads as closed).")
@NO_PRIOR
@common_options
def fit(photo: str, stage: str, out: str | None, preset: str, hair_style: str | None,
        face: str, detector: str, focal: float | None, distance: float | None,
        no_lid_fit: bool, no_prior: bool) -> None:
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
    from head360cli.errors import BadInputError

    if face != "all" and not face.isdigit():
        raise BadInputError(f"expected --face N or all, found {face!r}")
    if stage == "shape":
        from head360cli.fitting.pipeline import fit_shape_photo

        _unused(("preset", "hair_style", "no_lid_fit", "no_prior"), "with --stage shape")

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
        _emit(result, "\n".join(lines))
        return
    if face == "all":
        raise BadInputError("expected one face number for a full fit, found 'all' (use "
                            "--stage shape for every face)")
    from head360cli.devices import resolve_device
    from head360cli.fitting.pipeline import fit_photo
    from head360cli.io.sources import input_stem
    from head360cli.synth.hair import style_index

    style = None if hair_style is None else style_index(hair_style)
    target = out or f"{input_stem(photo)}.h360"
    result = fit_photo(photo, target, preset=preset, face=int(face), detector=detector,
                       focal=focal, device=str(resolve_device(_settings().device)),
                       hair_style=style, distance=distance, progress=_progress_printer(),
                       learned_prior=not no_prior, closed_lids=not no_lid_fit)
    for warning in result["warnings"]:
        _warn(warning)
    t = result["timings"]
    text = (f"fitted {photo}: yaw {result['pose']['yaw']:.1f} deg, hair "
            f"{result['hair_style']['name']} ({result['hair_color_name']}), face PSNR "
            f"{result['psnr_face_input_view']:.2f} dB at the input view"
            f"{' (in grey)' if result['inversion']['fitted_in'] == 'grey' else ''}, "
            f"{t['total']:.1f} s (" + ", ".join(f"{k} {v:.1f}" for k, v in t.items()
                                                 if k != "total") + ")\n"
            + "\n".join(f"  wrote {p}" for p in result["files"].values()))
    _emit(result, text)


@cli.command("parse-hair")
@PHOTO
@click.option("-o", "--out", "out_dir", default="head360-out", show_default=True,
              type=OutputPath(file_okay=False), help="Output folder.")
@click.option("--face", default=0, show_default=True, type=click.IntRange(min=0),
              help="Which face (0 = the largest).")
@click.option("--detector", type=click.Choice(["auto", "hog", "cnn"]), default="hog",
              show_default=True, help=DETECTOR_HELP)
@NO_PRIOR
@common_options
def parse_hair_cmd(photo: str, out_dir: str, face: int, detector: str,
                   no_prior: bool) -> None:
    """Hair and face-skin masks of a photo.

    Writes <stem>_hair.png and <stem>_face.png (single channel, the photo's size, 255
    inside) and <stem>_parse.png (hair red, face blue). Without a detectable face the hair
    is parsed from colour alone ("seeded": false), keeping out the skin of a face in
    profile where OpenCV's profile cascade finds one ("profile_face": true). With a
    face, a small network trained on the synthetic corpus (models/hair_prior.pt) says
    where hair probably is first.

    \b
    Examples:
      head360 parse-hair photo.jpg -o masks/
      head360 parse-hair photo.jpg --no-prior  colour and landmarks only
      head360 parse-hair photo.jpg --json     {"hair_mask": ..., "face_mask": ..., "overlay": ...}
    """
    from head360cli.fitting.pipeline import parse_photo

    _cpu_only("parse-hair", "parses")
    r = parse_photo(photo, out_dir, face=face, detector=detector, learned_prior=not no_prior)
    for warning in r["warnings"]:
        _warn(warning)
    _emit(r, f"hair {100 * r['hair_fraction']:.1f}% and face {100 * r['face_fraction']:.1f}% "
          f"of the image{'' if r['seeded'] else _unseeded(r)}; wrote "
          f"{r['hair_mask']}, {r['face_mask']}, {r['overlay']}")


def _unseeded(r: dict) -> str:
    """How ``parse-hair``'s line names a parse without landmarks."""
    return (" (no frontal face: colour and a face in profile)" if r["profile_face"]
            else " (no face found: colour only)")


@cli.command("classify-hair")
@PHOTO
@click.option("--top", default=3, show_default=True, help="How many styles to list.")
@click.option("--face", default=0, show_default=True, type=click.IntRange(min=0),
              help="Which face (0 = the largest).")
@click.option("--detector", type=click.Choice(["auto", "hog", "cnn"]), default="hog",
              show_default=True, help=DETECTOR_HELP)
@NO_PRIOR
@common_options
def classify_hair_cmd(photo: str, top: int, face: int, detector: str,
                      no_prior: bool) -> None:
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
    from head360cli.errors import BadInputError
    from head360cli.fitting.pipeline import classify_photo

    if not 1 <= top <= 30:
        raise BadInputError(f"expected --top between 1 and 30, found {top}")
    r = classify_photo(photo, face=face, detector=detector, top=top,
                       learned_prior=not no_prior)
    for warning in r["warnings"]:
        _warn(warning)
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
    _emit(r, "\n".join(lines))


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
    from head360cli.errors import BadInputError
    from head360cli.fitting.pipeline import run_demo

    if not 4 <= frames <= 720:
        raise BadInputError(f"expected --frames between 4 and 720, found {frames}")
    r = run_demo(out_dir, preset=preset, frames=frames,
                 device=str(resolve_device(_settings().device)),
                 progress=_progress_printer())
    _emit(r, f"fitted the astronaut in {r['fit']['timings']['total']:.1f} s; hair "
          f"{r['fit']['hair_style']['name']}; wrote "
          + ", ".join([*r["fit"]["files"].values(), r["turntable"]]))


@cli.command("build-model")
@click.option("--corpus", type=click.Choice(["synthead-p", "ict", "synthead100"]),
              default="synthead-p", show_default=True, help="Where the meshes come from.")
@click.option("--path", type=InputPath(exists=True), default=None,
              help="ICT-FaceKit npz/folder or SynHead100-style folder.")
@click.option("--identities", "-n", default=100, show_default=True,
              help="Training identities.")
@click.option("--rank", default=50, show_default=True, help="Identity codes kept (HOSVD).")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="SynHead-P seed.")
@click.option("--held-out", default=20, show_default=True,
              help="Identities kept out of the model to measure it.")
@click.option("-o", "--out", default=None, type=OutputPath(dir_okay=False),
              help="Output .npz (default: models/bilinear.npz for SynHead-P; required for "
              "external corpora, which are never shipped).")
@click.option("--calibrate", type=InputPath(exists=True, file_okay=False), default=None,
              help="Folder of dlib landmark XML files: learn where the 68 landmarks sit on "
              "the template from those faces.")
@common_options
def build_model_cmd(corpus: str, path: str | None, identities: int, rank: int, seed: int,
                    held_out: int, out: str | None, calibrate: str | None) -> None:
    """Build the bilinear head model (identity HOSVD, 52 ARKit blendshapes kept).

    \b
    Examples:
      head360 build-model --calibrate ../shared/data/faces  models/bilinear.npz
      head360 build-model --corpus ict --path ../shared/data/ict-facekit -o ict.npz
    """
    from head360cli.mesh.build import build_model

    _cpu_only("build-model", "builds")
    if out is None:
        if corpus != "synthead-p":
            from head360cli.errors import BadInputError

            raise BadInputError(f"--corpus {corpus} needs -o: external corpora are not "
                                "written into models/")
        from head360cli.paths import models_dir

        out = str(models_dir() / "bilinear.npz")
    s = build_model(corpus, path, identities, rank, seed, out, held_out, calibrate)
    lines = [f"wrote {s['out']} ({s['bytes'] / 1e6:.1f} MB, sha256 {s['sha256'][:16]}) from "
             f"{s['identities']} {corpus} identities, rank {s['rank']}, {s['seconds']} s",
             "reconstruction error, all 53 meshes per identity (mean / p99 / max mm):",
             "  training  " + " / ".join(str(v) for v in s["train_error"].values())]
    if "held_out_error" in s:
        lines.append(f"  held out ({s['held_out']}) " + " / ".join(
            str(v) for v in s["held_out_error"].values()))
    _emit(s, "\n".join(lines))


PRESETS = {
    "cpu": {},
    "gpu": {"texture_res": 256, "plane_res": 128, "render_res": 128, "samples": 12,
            "hidden": 128, "refine_width": 64, "generator_width": 256},
    "tiny": {"texture_res": 16, "plane_res": 16, "render_res": 16, "image_res": 32,
             "samples": 4, "hidden": 16, "refine_width": 8, "generator_width": 32,
             "hair_texture_res": 8},
}


@cli.command()
@click.argument("run_dir", type=OutputPath(file_okay=False))
@click.option("--preset", type=click.Choice(list(PRESETS)), default="cpu", show_default=True,
              help="Generator size: cpu (trains in about an hour on 2 cores), gpu, or tiny "
                   "(tests).")
@click.option("--steps", default=3000, show_default=True, help="Optimiser steps.")
@click.option("--minutes", default=0.0, show_default=True,
              help="Stop after this much training time (0: no limit; for equal budgets).")
@click.option("--batch", default=4, show_default=True, help="Views per step and process.")
@click.option("--identities", "-n", default=100, show_default=True,
              help="SynHead-P training heads.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Corpus and training seed.")
@click.option("--planes", type=click.Choice(["hex", "tri"]), default="hex", show_default=True,
              help="Feature planes: six (hex) or three (tri, the ablation).")
@click.option("--no-refine", is_flag=True, help="Without the RefineNet (the ablation).")
@click.option("--no-detach", is_flag=True,
              help="Without hair detachment: every view with its hair (the ablation).")
@click.option("--no-hair", is_flag=True, help="Head branch only, trained on bald views.")
@click.option("--lr", default=2e-3, show_default=True, help="Learning rate of the networks.")
@click.option("--group", default=1, show_default=True,
              help="Views per head in a batch, rendered together (faster data).")
@click.option("--workers", default=1, show_default=True,
              help="Processes that build the corpus heads before training.")
@click.option("--featured-share", default=0.25, show_default=True,
              help="Share of expressions with a blink or jawOpen at 0.7-1 on top (random "
                   "expressions rarely close the eyes).")
@click.option("--export", "export", type=OutputPath(dir_okay=False), default=None,
              help="Also write the shippable weights here (e.g. models/generator.pt).")
@click.option("--init", "init", type=InputPath(dir_okay=False, exists=True), default=None,
              help="Start a new run from these generator weights (their configuration "
                   "replaces --preset and the ablation flags).")
@common_options
def train(run_dir: str, preset: str, steps: int, minutes: float, batch: int,
          identities: int, seed: int, planes: str, no_refine: bool, no_detach: bool,
          no_hair: bool, lr: float, group: int, workers: int, featured_share: float,
          export: str | None, init: str | None) -> None:
    """Train the generator on SynHead-P (resumes a run folder that has a checkpoint).

    \b
    Examples:
      head360 train runs/cpu --export models/generator.pt
      head360 train runs/tri --planes tri --minutes 20
      head360 train runs/gpu --preset gpu --device cuda --batch 16 --steps 6000
      head360 train runs/more --init models/generator.pt --device cuda --minutes 10
      torchrun --nproc_per_node 2 -m head360cli train runs/ddp --steps 100
    """
    from head360cli.devices import resolve_device
    from head360cli.model.config import GeneratorConfig
    from head360cli.model.train import CHECKPOINT, TrainConfig, save_generator
    from head360cli.model.train import train as run_training

    if steps < 1 or batch < 1 or identities < 1:
        raise BadInputError(f"expected --steps, --batch and --identities >= 1, found "
                            f"{steps}, {batch} and {identities}")
    if not 0.0 <= featured_share <= 1.0:
        raise BadInputError(f"expected --featured-share in [0, 1], found {featured_share}")
    if group < 1 or workers < 1:
        raise BadInputError(f"expected --group and --workers >= 1, found {group} and {workers}")
    _check_rate_and_minutes(lr, minutes)
    device = str(resolve_device(_settings().device))
    resuming = (Path(run_dir) / CHECKPOINT).is_file()
    if resuming:  # the checkpoint's configuration replaces all but these
        _unused(("preset", "planes", "no_refine", "no_hair", "batch", "identities", "seed",
                 "lr", "group", "workers", "featured_share", "no_detach", "init"),
                f"when resuming {run_dir} (its checkpoint's configuration is used)")
    elif init is not None:  # the initial weights' configuration replaces these
        _unused(("preset", "planes", "no_refine", "no_hair"),
                "with --init (the weights' own configuration is used)")
    gen_cfg = GeneratorConfig(**PRESETS[preset], planes=planes, refine=not no_refine,
                              hair=not no_hair)
    cfg = TrainConfig(identities=identities, seed=seed, steps=steps, minutes=minutes,
                      batch=batch, lr=lr, detach=not no_detach, group=group,
                      workers=workers, featured_share=featured_share, init=init or "")
    last = run_training(run_dir, cfg, gen_cfg, device=device, progress=not _settings().quiet)
    result: dict[str, Any] = {"run": run_dir, "last": last}
    trained = "l1" in last  # a resumed run at --steps already trains nothing
    result["trained"] = trained
    if not trained:
        _warn(f"{run_dir} is at step {last['step']} already (--steps {steps}): nothing was "
              "trained; give a larger --steps to go on")
    if export and int(os.environ.get("RANK", "0")) == 0:
        result["export"] = save_generator(Path(run_dir) / CHECKPOINT, export)
    _emit(result, (f"trained to step {last['step']}: L1 {last['l1']}" if trained else
                   f"at step {last['step']}, as before")
          + (f"; wrote {export}" if export else ""))


def _check_rate_and_minutes(lr: float, minutes: float) -> None:
    """A training command's ``--lr`` (finite, above 0) and ``--minutes`` (0: no limit)."""
    import math

    if not (math.isfinite(lr) and lr > 0):
        raise BadInputError(f"expected a finite --lr > 0, found {lr}")
    if not (math.isfinite(minutes) and minutes >= 0):
        raise BadInputError(f"expected --minutes >= 0 (0: no limit), found {minutes}")


@cli.command("train-hair-prior")
@click.option("-o", "--out", default=None, type=OutputPath(dir_okay=False),
              help="Output weights (default: models/hair_prior.pt).")
@click.option("--heads", default=600, show_default=True, help="Corpus heads rendered.")
@click.option("--views", default=5, show_default=True, help="Random views per head.")
@click.option("--seed", type=click.IntRange(min=0), default=3, show_default=True,
              help="Corpus and training seed (the bench uses 0, parse development 1 and 2).")
@click.option("--steps", default=2400, show_default=True, help="Optimiser steps.")
@click.option("--minutes", default=0.0, show_default=True,
              help="Also stop after this much training time (0: no limit).")
@click.option("--batch", default=24, show_default=True, help="Crops per step.")
@click.option("--width", default=16, show_default=True,
              help="Channels of the network's first level.")
@click.option("--frame-share", default=0.0, show_default=True,
              help="Share of crops cut to a random rectangle with its edge repeated beyond "
                   "it, as a photo's edge is in the crop of a face that fills the photo.")
@click.option("--hat-share", default=0.0, show_default=True,
              help="Share of crops with a hat drawn over the head, not hair in the target.")
@click.option("--init", "init", default=None, type=InputPath(dir_okay=False),
              help="Start from this hair prior's weights (fine-tuning) instead of random "
                   "ones.")
@click.option("--lr", default=2e-3, show_default=True,
              help="Learning rate at the start (it decays linearly to 5 % of it).")
@common_options
def train_hair_prior_cmd(out: str | None, heads: int, views: int, seed: int, steps: int,
                         minutes: float, batch: int, width: int, frame_share: float,
                         hat_share: float, init: str | None, lr: float) -> None:
    """Train the learned hair prior that guides hair parsing, on corpus renders.

    About 3 minutes of rendering and 20 of training on 2 CPU cores with the defaults.
    Ctrl-C stops after the step it is on with a checkpoint (OUT's name with .resume.pt,
    also written every 100 steps); the same command then resumes from it.

    \b
    Examples:
      head360 train-hair-prior                      writes models/hair_prior.pt
      head360 train-hair-prior --steps 200 -o try.pt
      head360 train-hair-prior --init models/hair_prior.pt --steps 600 --lr 5e-4 -o tuned.pt
    """
    from head360cli.devices import resolve_device
    from head360cli.fitting.hair_prior import FILE_NAME, HairPriorConfig, save_hair_prior
    from head360cli.fitting.hair_prior_train import (
        HairPriorTrainConfig,
        resume_path,
        train_hair_prior,
    )

    if min(heads, views, steps, batch, width) < 1:
        raise BadInputError(f"expected --heads, --views, --steps, --batch and --width >= 1, "
                            f"found {heads}, {views}, {steps}, {batch} and {width}")
    for name, share in (("--frame-share", frame_share), ("--hat-share", hat_share)):
        if not 0.0 <= share <= 1.0:
            raise BadInputError(f"expected {name} in [0, 1], found {share}")
    _check_rate_and_minutes(lr, minutes)
    if init is not None and not Path(init).is_file():
        raise BadInputError(f"hair prior {init!r} (--init) does not exist")
    if out is None:
        from head360cli.paths import models_dir

        out = str(models_dir() / FILE_NAME)
    if Path(out).suffix.lower() != ".pt":
        raise BadInputError(f"expected a hair prior output ending in .pt, found {out!r}")
    from head360cli.io.atomic import check_file_target

    checkpoint = resume_path(out)
    for target in (out, checkpoint):  # an existing, writable folder: before the renders
        check_file_target(target)
    device = str(resolve_device(_settings().device))
    if device != "cpu":
        _warn("train-hair-prior trains on the CPU (the renders are CPU work)")
    cfg = HairPriorTrainConfig(heads=heads, views=views, seed=seed, steps=steps,
                               minutes=minutes, batch=batch, frame_share=frame_share,
                               hat_share=hat_share, init=init or "", lr=lr)
    quiet = _settings().quiet
    prior, summary = train_hair_prior(
        cfg, HairPriorConfig(width=width), progress=not quiet, checkpoint=checkpoint,
        log=None if quiet else (lambda line: click.echo(line, err=True)))
    save_hair_prior(prior, out, summary)
    checkpoint.unlink(missing_ok=True)  # the run is done: nothing to resume
    summary["out"] = out
    _emit(summary, f"trained the hair prior for {summary['steps']} steps "
          f"({summary['render_seconds']} s rendering, {summary['train_seconds']} s training, "
          f"final loss {summary['final_loss']}); wrote {out}")


@cli.group()
def bench() -> None:
    """Speed-against-error benchmarks; each writes JSON and a Markdown table.

    \b
    Examples:
      head360 bench all                      every stage, then bench.md and bench.png
      head360 bench all --quick              the same, small (minutes)
      head360 bench summary                  the table and plot from results already there
      head360 bench synth -n 10 --out bench/
    """


@bench.command("synth")
@click.option("--identities", "-n", default=100, show_default=True,
              help="Identities in the timed corpus subset.")
@click.option("--out", "out_dir", default="bench-results", show_default=True,
              type=OutputPath(file_okay=False), help="Where the JSON and Markdown go.")
@common_options
def bench_synth_cmd(identities: int, out_dir: str) -> None:
    """Corpus renderer: ms per 256x256 view by antialiasing samples and batch size, and
    the time to write a corpus subset (target: at most 50 ms per view on 2 cores)."""
    from head360cli.bench.report import save
    from head360cli.bench.synth import bench_synth

    _cpu_only("bench synth")
    if identities < 1:
        from head360cli.errors import BadInputError

        raise BadInputError(f"expected --identities >= 1, found {identities}")
    result, md = bench_synth(identities=identities)
    result["files"] = save(result, md, out_dir, "synth")
    _emit(result, md + f"\n\nwrote {', '.join(result['files'])}")


@bench.command("fit-shape")
@click.option("--trials", default=200, show_default=True,
              help="Synthetic faces (random identity, expression and pose).")
@click.option("--out", "out_dir", default="bench-results", show_default=True,
              type=OutputPath(file_okay=False), help="Where the JSON and Markdown go.")
@common_options
def bench_fit_shape_cmd(trials: int, out_dir: str) -> None:
    """Landmark shape fit: vertex and pose error on synthetic faces by yaw, NME of dlib's
    and the fitted landmarks on the real photos in ../shared/data, and fit time."""
    from head360cli.bench.fit_shape import bench_fit_shape
    from head360cli.bench.report import save

    _cpu_only("bench fit-shape")
    if trials < 1:  # zero trials failed after the real-photo part, as an internal error
        raise BadInputError(f"expected --trials >= 1, found {trials}")
    result, md = bench_fit_shape(trials=trials)
    result["files"] = save(result, md, out_dir, "fit_shape")
    _emit(result, md + f"\n\nwrote {', '.join(result['files'])}")


@bench.command("fit")
@click.option("--identities", default=2, show_default=True,
              help="Held-out synthetic heads fitted from one frontal render.")
@click.option("--preset", "presets", multiple=True, type=click.Choice(["fast", "quality"]),
              help="Presets to measure (repeat; default both).")
@click.option("--no-sweep", is_flag=True, help="Skip the inversion-steps sweep.")
@click.option("--stability", default=3, show_default=True,
              help="Noisy copies of each stability photo (see --stability-photos) "
                   "fitted again (0: none).")
@click.option("--stability-photos", default=1, show_default=True,
              help="How many of the real photos get --stability noisy copies each; with "
                   "several, the means over them are compared draw by draw.")
@click.option("--synthetic-noise", default=0, show_default=True,
              help="Fit the synthetic heads again from this many copies of their "
                   "renders, each value moved by one grey level (0: none).")
@click.option("--corpus-seed", default=0, show_default=True,
              help="Corpus seed of the held-out synthetic heads (0: the bench's; others "
                   "for development).")
@click.option("--out", "out_dir", default="bench-results", show_default=True,
              type=OutputPath(file_okay=False), help="Where the JSON and Markdown go.")
@common_options
def bench_fit_cmd(identities: int, presets: tuple[str, ...], no_sweep: bool,
                  stability: int, stability_photos: int, synthetic_noise: int,
                  corpus_seed: int, out_dir: str) -> None:
    """Single-image fitting: hair parsing IoU, hairstyle accuracy, 72-view PSNR/SSIM of
    synthetic fits, face PSNR and dlib descriptor distance on real photos, time, and how
    far a fit moves when the photo moves by one grey level.

    \b
    Examples:
      head360 bench fit
      head360 bench fit --preset fast --identities 1 --no-sweep --stability 0
      head360 bench fit --preset fast --identities 6 --corpus-seed 1 --no-sweep
      head360 bench fit --preset fast --no-sweep --stability-photos 6   how far the
                                               means move with one grey level of noise
      head360 bench fit --preset quality --no-sweep --stability 0 --synthetic-noise 3
      head360 bench fit --device cuda          the fits on the GPU (dlib still needed)
    """
    from head360cli.bench.fit import bench_fit
    from head360cli.bench.report import save
    from head360cli.devices import resolve_device

    device = str(resolve_device(_settings().device))
    if identities < 1:
        raise BadInputError(f"expected --identities >= 1, found {identities}")
    if stability < 0:
        raise BadInputError(f"expected --stability >= 0, found {stability}")
    if stability_photos < 0:
        raise BadInputError(f"expected --stability-photos >= 0, found {stability_photos}")
    if synthetic_noise < 0:
        raise BadInputError(f"expected --synthetic-noise >= 0, found {synthetic_noise}")
    if corpus_seed < 0:
        raise BadInputError(f"expected --corpus-seed >= 0, found {corpus_seed}")
    result, md = bench_fit(identities=identities, presets=presets or ("fast", "quality"),
                           sweep=() if no_sweep else (5, 10, 20, 40), stability=stability,
                           stability_photos=stability_photos,
                           synthetic_noise=synthetic_noise,
                           corpus_seed=corpus_seed, device=device,
                           progress=None if _settings().quiet else
                           (lambda t: click.echo(f"bench fit: {t}", err=True)))
    result["files"] = save(result, md, out_dir, "fit")
    _emit(result, md + f"\n\nwrote {', '.join(result['files'])}")


@bench.command("generator")
@click.option("--weights", "weights", multiple=True, type=InputPath(dir_okay=False),
              help="Generator weights; repeat to compare (labelled by file name). "
                   "Default: models/generator.pt.")
@click.option("--train-ids", default=6, show_default=True,
              help="Training identities scored on held-out views and hair swap.")
@click.option("--test-ids", default=2, show_default=True,
              help="Held-out identities (codes fitted with the generator frozen; 0: none).")
@click.option("--fit-steps", default=40, show_default=True,
              help="Code-fitting steps per held-out identity.")
@click.option("--cameras", default=8, show_default=True,
              help="Held-out cameras per head (of 24 around it).")
@click.option("--no-speed", is_flag=True, help="Skip the timing and the speed sweep.")
@click.option("--out", "out_dir", default="bench-results", show_default=True,
              type=OutputPath(file_okay=False), help="Where the JSON and Markdown go.")
@click.option("--name", default="generator", show_default=True,
              help="File name of the results (<name>.json, <name>.md).")
@common_options
def bench_generator_cmd(weights: tuple[str, ...], train_ids: int, test_ids: int,
                        fit_steps: int, cameras: int, no_speed: bool, out_dir: str,
                        name: str) -> None:
    """Generator: PSNR and SSIM on held-out views, held-out identities and hair swap,
    frame time, and speed against quality for samples per ray and plane resolution.

    \b
    Examples:
      head360 bench generator
      head360 bench generator --weights a/hex.pt --weights a/tri.pt --no-speed --test-ids 0
      head360 bench generator --device cuda --train-ids 2 --test-ids 0
    """
    from head360cli.bench.generator import bench_generator
    from head360cli.bench.report import save
    from head360cli.devices import resolve_device

    if train_ids < 1 or test_ids < 0 or fit_steps < 0 or not 1 <= cameras <= 24:
        raise BadInputError(f"expected --train-ids >= 1, --test-ids >= 0, --fit-steps >= 0 "
                            f"and 1 <= --cameras <= 24, found {train_ids}, {test_ids}, "
                            f"{fit_steps} and {cameras}")
    device = str(resolve_device(_settings().device))
    result, md = bench_generator(list(weights) or None, train_ids, test_ids, fit_steps,
                                 cameras, speed=not no_speed, device=device,
                                 progress=not _settings().quiet)
    result["files"] = save(result, md, out_dir, name)
    _emit(result, md + f"\n\nwrote {', '.join(result['files'])}")


# The subcommands that use a head (render, animate, swap-hair, sample, export-mesh).
from head360cli import cli_drive  # noqa: E402,F401  (registers them on `cli`)


def _restore_help(command: click.Command) -> None:
    """Give ``command`` and its subcommands back the help texts that ``python -OO`` (or
    ``PYTHONOPTIMIZE=2``) dropped with every docstring: each command's docstring, read
    from its module's source. Without it, ``head360 fit --help`` under ``-OO`` showed
    the options and neither what the command does nor its examples."""
    import ast
    import inspect

    modules: dict[str, dict[str, str]] = {}
    todo = [command]
    while todo:
        cmd = todo.pop()
        if isinstance(cmd, click.Group):
            todo += cmd.commands.values()
        if cmd.help is not None or cmd.callback is None:
            continue
        code = getattr(inspect.unwrap(cmd.callback), "__code__", None)
        if code is None:
            continue
        if code.co_filename not in modules:
            try:
                tree = ast.parse(Path(code.co_filename).read_text(encoding="utf-8"))
            except (OSError, SyntaxError, ValueError):  # no source beside the bytecode
                tree = ast.Module(body=[], type_ignores=[])
            modules[code.co_filename] = {
                node.name: ast.get_docstring(node, clean=False) or ""
                for node in tree.body if isinstance(node, ast.FunctionDef)}
        cmd.help = modules[code.co_filename].get(code.co_name) or None


if sys.flags.optimize >= 2:
    _restore_help(cli)

# --------------------------------------------------------------------------- entry point


def _address_space_limit() -> str:
    """`` (at most N MiB: ulimit -v)`` where the process's address space is limited."""
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    except (ImportError, OSError, ValueError):  # no such limit on this system
        return ""
    return "" if soft == resource.RLIM_INFINITY else \
        f" (at most {soft / 2**20:.0f} MiB: ulimit -v)"


def _memory_shortfall(exc: BaseException) -> str:
    """What an out-of-memory error says, in a few words: a GPU's first two sentences
    ("CUDA out of memory. Tried to allocate 2.00 GiB"), the size a CPU allocation asked
    for, or the error's own start."""
    import re

    text = " ".join(str(exc).split())
    asked = re.search(r"tried to allocate (\d+) bytes", text)
    if asked:
        return f"the CPU could not allocate {int(asked.group(1)) / 2**30:.1f} GiB"
    if "out of memory" in text.lower():
        return ". ".join(text.split(". ")[:2])[:160]
    return text[:160] or type(exc).__name__


def _failed(kind: str, message: str, code: int, debug: bool, as_json: bool,
            label: str = "error", hint: str = "") -> int:
    """Report the exception being handled as one line on stderr (``head360: LABEL:
    MESSAGE HINT``), its traceback first with ``--debug``, and as JSON on stdout with
    ``--json``; return the exit ``code``."""
    if debug:
        import traceback

        traceback.print_exc()
    with contextlib.suppress(OSError):  # standard error full or closed: the code remains
        click.echo(f"head360: {label}: {message}{hint}", err=True)
    if as_json:
        _error_json(kind, message, code)
    return code


def _error_json(kind: str, message: str, code: int) -> None:
    """Print the error as JSON on standard output, if it can be written."""
    try:
        print(json.dumps({"ok": False, "error": {"type": kind, "message": message,
                                                 "exit_code": code}}), flush=True)
    except OSError:
        _drop_stdout()


class _Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, ``timeout``, a batch system) or SIGHUP (the terminal or ssh
    session closed), raised in the main thread as an interrupt is, so that half-written
    outputs are removed and spawned processes ended; by default Python dies at once and
    leaves both behind.

    Attributes:
        signum: The signal's number.
    """

    signum = 15  # SIGTERM's


def _on_terminate(signum, frame) -> None:
    exc = _Terminated()
    exc.signum = signum
    raise exc


def _stop_signals() -> list[int]:
    """The signals :func:`_on_terminate` handles: SIGTERM, and SIGHUP where there is one
    and it is not ignored (``nohup`` ignores it, and it must stay so)."""
    import signal

    found = [signal.SIGTERM]
    hup = getattr(signal, "SIGHUP", None)
    if hup is not None and signal.getsignal(hup) is not signal.SIG_IGN:
        found.append(hup)
    return found


def main(argv: list[str] | None = None) -> int:
    """Run the CLI and return its exit code (see ``head360 --help`` for the codes)."""
    import signal
    import threading

    args = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args
    as_json = "--json" in args
    _open_closed_outputs()
    for stream in (sys.stdout, sys.stderr):  # a name the terminal's encoding lacks
        if hasattr(stream, "reconfigure"):   # (an emoji, in Latin-1) is escaped, not
            with contextlib.suppress(Exception):  # an internal error after the work
                stream.reconfigure(errors="backslashreplace")
    handles = threading.current_thread() is threading.main_thread()  # only it may
    previous = {sig: signal.signal(sig, _on_terminate) for sig in _stop_signals()} \
        if handles else {}
    try:
        return _run(args, debug, as_json)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _open_closed_outputs() -> None:
    """Point a closed standard output or error (``2>&-``, a daemon's) at ``os.devnull``.
    Python makes ``sys.stderr`` None then, and the first progress line was an internal
    error that lost the work; the descriptor itself is opened too, so spawned processes
    and ffmpeg inherit one that works."""
    for fd, name in ((1, "stdout"), (2, "stderr")):
        if getattr(sys, name) is not None:
            continue
        try:
            os.fstat(fd)
        except OSError:  # closed: the lowest free descriptor, or this one by dup2
            null = os.open(os.devnull, os.O_WRONLY)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)
        with contextlib.suppress(OSError):
            setattr(sys, name, open(fd, "w", closefd=False))  # noqa: SIM115 (for the run)


def _run(args: list[str], debug: bool, as_json: bool) -> int:
    try:
        cli.main(args=args, prog_name="head360", standalone_mode=False)
        return 0
    except click.exceptions.Exit as exc:
        return int(exc.exit_code)
    except click.ClickException as exc:
        exc.show()
        if as_json:
            _error_json("UsageError", exc.format_message(), exc.exit_code)
        return int(exc.exit_code)
    except (click.Abort, KeyboardInterrupt) as exc:  # click turns the interrupt into Abort
        if isinstance(exc, _Terminated) or isinstance(exc.__cause__, _Terminated):
            import signal

            stop = exc if isinstance(exc, _Terminated) else exc.__cause__
            if stop.signum != signal.SIGTERM:  # SIGHUP: the terminal may be gone too
                with contextlib.suppress(OSError):
                    click.echo("head360: hung up", err=True)
                return EXIT_CODES["hangup"]
            click.echo("head360: terminated", err=True)
            return EXIT_CODES["terminated"]
        click.echo("head360: interrupted", err=True)
        return EXIT_CODES["interrupted"]
    except Head360Error as exc:
        return _failed(type(exc).__name__, str(exc), exc.exit_code, debug, as_json)
    except BrokenPipeError:
        return 0  # e.g. `head360 inspect x.csv | head`
    except OSError as exc:
        import errno

        if exc.errno == errno.ENAMETOOLONG:  # a name no check before the work caught
            from head360cli.io.atomic import short_name

            name = Path(str(exc.filename or "")).name
            shown = f": {short_name(name)}" if name else ""
            return _failed("BadInputError", f"file name too long{shown}: use a shorter name",
                           EXIT_CODES["BadInputError"], debug, as_json)
        named = exc.filename2 or exc.filename  # a rename's target, not its temporary file
        where = f" ({named})" if named else ""
        if exc.errno in (errno.EACCES, errno.EPERM):  # one no check before the work caught
            return _failed("BadInputError", f"{exc.strerror or exc}{where}: check the "
                           f"file's and its folder's permissions",
                           EXIT_CODES["BadInputError"], debug, as_json)
        if exc.errno not in (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG):
            return _internal(exc, debug, as_json)
        todo = {errno.EROFS: "write elsewhere",
                errno.EFBIG: "past the file system's or the shell's file-size limit (ulimit "
                             "-f): write elsewhere"}.get(exc.errno,
                                                         "free space or write elsewhere")
        return _failed("BadInputError", f"{exc.strerror or exc}{where}: {todo} (nothing "
                       "half-written was kept)", EXIT_CODES["BadInputError"], debug, as_json)
    except Exception as exc:
        return _internal(exc, debug, as_json)


def _internal(exc: Exception, debug: bool, as_json: bool) -> int:
    """Report an exception no head360 error class names: out of memory, else a bug."""
    if is_out_of_memory(exc) and "failed to map segment" in str(exc):
        # a library that could not be mapped: no option asks for less of that
        message = (f"out of memory ({_memory_shortfall(exc)}): head360's libraries need "
                   f"more memory than this process may have{_address_space_limit()}: "
                   f"raise the limit or free memory")
        return _failed("OutOfMemory", message, EXIT_CODES["out_of_memory"], debug, as_json)
    if is_out_of_memory(exc):  # not a bug: a resource the user can free or ask less of
        message = (f"out of memory ({_memory_shortfall(exc)}): ask for less at once (a "
                   f"smaller --size or --samples; animate: fewer frames a call, --batch), "
                   f"free memory, or use another --device")
        return _failed("OutOfMemory", message, EXIT_CODES["out_of_memory"], debug, as_json)
    if isinstance(exc, RuntimeError) and "can't start new thread" in str(exc):
        # Python's own thread refused (EAGAIN): a limit of the system, not a bug
        message = ("cannot start a thread: the limit on processes and threads (ulimit -u, "
                   "a container's pids limit) is reached; raise it or run fewer jobs")
        return _failed("BadInputError", message, BadInputError.exit_code, debug, as_json)
    message = " ".join(f"{type(exc).__name__}: {exc}".split())
    return _failed("InternalError", message, EXIT_CODES["internal"], debug, as_json,
                   label="internal error",
                   hint=" (run with --debug for the traceback; please report it)")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

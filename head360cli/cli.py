"""The ``head360`` command line: parses, calls the library, prints. Nothing else.

Heavy modules (torch, OpenCV, dlib) are imported inside the commands, so ``head360 --help``
starts instantly. Errors from the :mod:`head360cli.errors` family become one line on
stderr and their own exit code; ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from collections.abc import Callable
from typing import Any

import click

from head360cli import __version__
from head360cli.errors import EXIT_CODES, Head360Error

__all__ = ["cli", "main"]

EPILOG_EXIT_CODES = (
    "Exit codes: 0 ok, 1 internal error, 2 usage error, 3 bad input, 4 no face found, "
    "5 bad file format, 6 model mismatch, 7 model not installed, 130 interrupted."
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
    """Print ``result`` as JSON under --json, else ``text``."""
    if _settings().json:
        click.echo(json.dumps(result, indent=None, sort_keys=False))
    else:
        click.echo(text.rstrip("\n"))


def _warn(message: str) -> None:
    if not _settings().quiet:
        click.echo(f"head360: warning: {message}", err=True)


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
    lines.append(f"  onnxruntime   {', '.join(report['onnxruntime_providers']) or 'none'}")
    lines.append(f"models ({report['models_dir']}):")
    if not report["models"]:
        lines.append("  (no model files installed yet)")
    for m in report["models"]:
        lines.append(f"  {m['name']:<24} {m['bytes'] / 1e6:8.2f} MB  sha256 {m['sha256'][:16]}")
    lines.append("dlib weights (face-recognition-models):")
    for key, path in report["dlib_models"].items():
        lines.append(f"  {key:<20} {'present' if path else 'MISSING'}")
    lines.append(f"shared evaluation data: {report['shared_data'] or 'not found'}")
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
        f"  file size    {r['bytes']} bytes",
    ])


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


@cli.command()
@click.argument("file", type=click.Path(dir_okay=False, allow_dash=True))
@click.option("--on-bad", type=click.Choice(["error", "skip", "hold"]), default="error",
              show_default=True, help="ARKit streams: what to do with NaN, empty or "
              "non-numeric cells and malformed rows.")
@click.option("--plot", type=click.Path(dir_okay=False), default=None,
              help="ARKit streams: also draw the most active blendshapes and the head "
              "rotation over time into this PNG.")
@common_options
def inspect(file: str, on_bad: str, plot: str | None) -> None:
    """Tell what FILE is and holds: an ARKit stream, an image or a head file.

    For an ARKit CSV stream: frames, frame rate, duration, columns found, missing or
    ignored, and min/mean/max per blendshape. For an image: size, mode, EXIF orientation.
    For a head file: its metadata and arrays. FILE may be - to read a stream from stdin.

    \b
    Examples:
      head360 inspect examples/smile_blink_livelinkface.csv
      head360 inspect photo.jpg --json
      head360 inspect take.csv --plot take.png
      cat take.csv | head360 inspect - --on-bad skip
    """
    from head360cli.report import inspect_file

    result = inspect_file(file, on_bad=on_bad, plot=plot)
    for w in result.get("warnings", []):
        _warn(w)
    formatter = {"arkit_stream": _format_stream, "image": _format_image,
                 "head": _format_head}[result["kind"]]
    _emit(result, formatter(result))


# --------------------------------------------------------------------------- entry point


def _error_json(kind: str, message: str, code: int) -> None:
    print(json.dumps({"ok": False, "error": {"type": kind, "message": message,
                                             "exit_code": code}}))


def main(argv: list[str] | None = None) -> int:
    """Run the CLI and return its exit code (see ``head360 --help`` for the codes)."""
    args = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args
    as_json = "--json" in args
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
    except (click.Abort, KeyboardInterrupt):
        click.echo("head360: interrupted", err=True)
        return EXIT_CODES["interrupted"]
    except Head360Error as exc:
        if debug:
            import traceback

            traceback.print_exc()
        click.echo(f"head360: error: {exc}", err=True)
        if as_json:
            _error_json(type(exc).__name__, str(exc), exc.exit_code)
        return exc.exit_code
    except BrokenPipeError:
        return 0  # e.g. `head360 inspect x.csv | head`
    except Exception as exc:
        if debug:
            import traceback

            traceback.print_exc()
        message = " ".join(f"{type(exc).__name__}: {exc}".split())
        click.echo(f"head360: internal error: {message} (run with --debug for the traceback; "
                   "please report it)", err=True)
        if as_json:
            _error_json("InternalError", message, EXIT_CODES["internal"])
        return EXIT_CODES["internal"]


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

"""What every ``head360`` command shares: the command group, the global options
(``--device``, ``--quiet``, ``--json``, ``--debug``), path types that accept pipes
and ``-``, and printing results, warnings and progress."""

from __future__ import annotations

import contextlib
import dataclasses
import os
import sys
from collections.abc import Callable
from typing import Any

import click

from head360cli.errors import BadInputError
from head360cli.fitting.config import DETECTORS
from head360cli.version import __version__

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
    overwrite: bool = False
    """Let an output replace one of the command's own input files."""


def current_settings() -> Settings:
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
        setattr(current_settings(), field, value)
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


def stdin_path(what: str) -> Callable[[click.Context, click.Parameter, Any], Any]:
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
                       callback=stdin_path("a photo"))
"""The photo argument of fit, parse-hair and classify-hair: a file, a pipe or ``-``."""


def _set_threads(ctx: click.Context, param: click.Parameter, value: int | None) -> None:
    """``--threads N``: cap the thread counts before torch or OpenCV is imported."""
    if value is not None:
        from head360cli.threads import configure_threads

        configure_threads(value)


def _guard_inputs(f: Callable[..., Any]) -> Callable[..., Any]:
    """``f`` run with its command's input files protected: an output that is one of them
    (by path, link or inode) is refused unless ``--overwrite``
    (:func:`~head360cli.io.atomic.protect_inputs`)."""
    import functools

    @functools.wraps(f)
    def guarded(*args: Any, **kwargs: Any) -> Any:
        from head360cli.io.atomic import protect_inputs

        ctx = click.get_current_context()
        inputs = []
        for param in ctx.command.params:
            if isinstance(param.type, InputPath) and ctx.params.get(param.name) is not None:
                value = ctx.params[param.name]
                inputs += list(value) if isinstance(value, tuple | list) else [value]
        with protect_inputs(inputs, current_settings().overwrite):
            return f(*args, **kwargs)

    return guarded


def common_options(f: Callable[..., Any]) -> Callable[..., Any]:
    """Add --device/--quiet/--json/--debug/--threads/--overwrite to a command (they also
    work on the group), and protect its input files from its outputs."""
    f = _guard_inputs(f)
    options = [
        click.option("--device", default=None, expose_value=False, callback=_set("device"),
                     help="Torch device: cpu (default), cuda, cuda:N or auto."),
        click.option("--quiet", "-q", is_flag=True, default=False, expose_value=False,
                     callback=_set("quiet"), help="No progress bars or warnings."),
        click.option("--json", "json_", is_flag=True, default=False, expose_value=False,
                     callback=_set("json"), help="Print one JSON object on stdout."),
        click.option("--debug", is_flag=True, default=False, expose_value=False,
                     callback=_set("debug"), help="Show tracebacks for errors."),
        click.option("--threads", type=click.IntRange(min=1), default=None,
                     expose_value=False, callback=_set_threads,
                     help="Most threads to run (default: the CPUs this process may use; "
                     "also $HEAD360_THREADS). 1 for each of several jobs side by side."),
        click.option("--overwrite", is_flag=True, default=False, expose_value=False,
                     callback=_set("overwrite"),
                     help="Let an output replace one of the command's input files."),
    ]
    for option in reversed(options):
        f = option(f)
    return f


def emit(result: dict[str, Any], text: str) -> None:
    """Print ``result`` as JSON under --json, else ``text``.

    Raises:
        BadInputError: Standard output cannot be written (``> result.json`` on a full
            disk): said in one line, where it was a traceback under --json.
    """
    if current_settings().json:
        from head360cli.io.jsontext import dumps

        text = dumps(result)
    try:
        click.echo(text.rstrip("\n"))
    except BrokenPipeError:
        raise  # a reader that has stopped reading (| head): not an error, see _run
    except OSError as exc:
        drop_stdout()
        raise BadInputError(f"cannot write the result to standard output: "
                            f"{exc.strerror or exc}") from None


def emit_to_stderr(result: dict[str, Any], text: str) -> None:
    """:func:`emit` on standard error, for a command whose standard output carries its
    data (``track -o -``); nothing under ``--quiet`` unless ``--json``."""
    settings = current_settings()
    if settings.json:
        from head360cli.io.jsontext import dumps

        click.echo(dumps(result), err=True)
    elif not settings.quiet:
        click.echo(text.rstrip("\n"), err=True)


def drop_stdout() -> None:
    """Send what is left for standard output nowhere, once writing it failed: the text
    still buffered would fail again when Python flushes it at exit, printed as an
    exception and exit 120."""
    with contextlib.suppress(OSError, ValueError):
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 (kept open until the exit)


def warn(message: str) -> None:
    if not current_settings().quiet:
        click.echo(f"head360: warning: {message}", err=True)


def warn_unused(names: tuple[str, ...], why: str) -> None:
    """Warn about the options among ``names`` (parameter names) that were given on the
    command line but do nothing ``why`` (for example "with --stage shape"): a user
    should not think they took effect."""
    from click.core import ParameterSource

    ctx = click.get_current_context()
    flags = [p.opts[0] for p in ctx.command.params if p.name in names
             and ctx.get_parameter_source(p.name) is not ParameterSource.DEFAULT]
    if flags:
        warn(f"{' and '.join(flags)} {'is' if len(flags) == 1 else 'are'} not used {why}")


def check_size(size: int | None, name: str = "--size") -> None:
    """Refuse an image size no generator renders, before anything is loaded: one
    wording for every command that takes one.

    Raises:
        BadInputError: ``size`` is not an even number from 32 to 2048.
    """
    if size is not None and not (32 <= size <= 2048 and size % 2 == 0):
        raise BadInputError(f"expected {name} a multiple of 2 between 32 and 2048, found "
                            f"{size}")


def refuse_given(names: tuple[str, ...], why: str) -> None:
    """Refuse the options among ``names`` (parameter names) that were given on the
    command line though they conflict ``why`` (for example "with --views"), in one line.

    Raises:
        BadInputError: Naming each such option.
    """
    from click.core import ParameterSource

    ctx = click.get_current_context()
    flags = [p.opts[0] for p in ctx.command.params if p.name in names
             and ctx.get_parameter_source(p.name) is not ParameterSource.DEFAULT]
    if flags:
        raise BadInputError(f"expected no {' or '.join(flags)} {why}, found "
                            f"{' and '.join(flags)}")


def cpu_only_warning(command: str, does: str = "measures") -> None:
    """Warn that ``command`` ``does`` (measures, renders, ...) on the CPU when --device
    names another device (every command takes --device; these would otherwise ignore it
    silently)."""
    device = current_settings().device
    if device and device.lower() != "cpu":
        warn(f"{command} {does} on the CPU; --device {device} is not used")


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
    current_settings()
    _check_working_folder()
    from head360cli.threads import configure_threads

    configure_threads()  # from $HEAD360_THREADS and the CPUs: before torch is imported


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


HAIR_PARSER = click.option(
    "--hair-parser", type=click.Choice(["segmenter", "grabcut"]), default="segmenter",
    show_default=True,
    help="segmenter: MediaPipe's hair segmentation network, kept to the fitted face; "
         "grabcut: GrabCut seeded by the landmarks and skin colour, with the learned "
         "corpus prior.")
"""The ``--hair-parser`` option of fit, parse-hair and classify-hair."""

NO_PRIOR = click.option(
    "--no-prior", is_flag=True,
    help="With --hair-parser grabcut: parse by colour and landmarks alone, without the "
         "learned hair prior.")
"""The ``--no-prior`` flag of fit, parse-hair and classify-hair."""

DETECTOR_HELP = ("Face detector: auto runs YuNet, then BlazeFace if YuNet finds no face, "
                 "and reads each face with the 478-point face mesh; yunet or blazeface "
                 "alone; hog or cnn: dlib's detectors and 68-point predictor (slower, "
                 "research-only training data).")
"""The help of ``--detector`` (fit, parse-hair, classify-hair)."""

DETECTOR = click.option("--detector", type=click.Choice(list(DETECTORS)), default="auto",
                        show_default=True, help=DETECTOR_HELP)
"""The ``--detector`` option of fit, parse-hair and classify-hair."""

FACE_NUMBER = click.option("--face", default=0, show_default=True, type=click.IntRange(min=0),
                           help="Which face (0 = the largest).")
"""The ``--face`` option of parse-hair and classify-hair (fit's also takes ``all``)."""

STREAM_FPS = click.option(
    "--stream-fps", type=click.FloatRange(min=0.0, min_open=True), default=None,
    help="The stream's own frame rate, for Live Link Face timecodes that cannot tell it "
    "(a take shorter than a second) or a frame-numbered CSV.")
"""The ``--stream-fps`` option of animate and inspect."""

BENCH_OUT = click.option("--out", "out_dir", default="bench-results", show_default=True,
                         type=OutputPath(file_okay=False),
                         help="Where the JSON and Markdown go.")
"""The ``--out`` folder of the ``bench`` commands."""


def progress_printer():
    """Progress of a fit's stages: one tqdm bar per stage on stderr, shown only on a
    terminal and without --quiet (the convention of :mod:`head360cli.progress`)."""
    if current_settings().quiet or not sys.stderr.isatty():
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

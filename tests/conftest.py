"""Shared fixtures: the CLI runner and the optional real evaluation data."""

from __future__ import annotations

import os
import signal
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

# Property tests draw new random examples on every run, which is how they find bugs (a
# CI run found the ARKit reader's rounding bug). CI (the CI variable set, as .ci/run
# does) draws the same examples every run, so that a build fails for a change, not for
# a draw; run locally without it to explore.
if os.environ.get("CI"):
    from hypothesis import settings

    settings.register_profile("ci", derandomize=True)
    settings.load_profile("ci")

# The suite tests what Ctrl-C does. A shell without job control starts a background job
# (`.ci/run &`) with SIGINT ignored, which Python and head360 then leave ignored, as they
# should: every Ctrl-C test failed. The suite puts the default back for itself and the
# processes it starts.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@dataclass
class CliResult:
    code: int
    out: str
    err: str


@pytest.fixture
def run_cli(capsys):
    """Run ``head360 ARGS...`` in-process; return exit code, stdout and stderr."""
    from head360cli.cli import main

    def run(*args: str) -> CliResult:
        capsys.readouterr()
        code = main([str(a) for a in args])
        captured = capsys.readouterr()
        return CliResult(code, captured.out, captured.err)

    return run


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data``; tests that need it are skipped cleanly when it is absent."""
    from head360cli.paths import shared_data_dir

    path = shared_data_dir()
    if path is None:
        pytest.skip("../shared/data is not present on this machine")
    return path


@pytest.fixture(scope="session")
def head_file(tmp_path_factory) -> Path:
    """A head file drawn from the shipped model (seed 0, with hair): as good as a fitted
    head for rendering, animation, swaps and export, without a fit's seconds."""
    from head360cli.drive.sample import sample_heads, write_samples

    head = sample_heads(1, seed=0)[0]
    assert int(head.arrays["hair_style"]) != 0
    return write_samples([head], tmp_path_factory.mktemp("head"))[0]


@dataclass
class FittedHead:
    """A whole fit of scikit-image's astronaut photo by ``head360 fit --json``."""

    photo: Path
    head: Path
    summary: dict
    """The JSON the command printed."""
    code: int
    err: str


@pytest.fixture(scope="session")
def fitted_astronaut(tmp_path_factory) -> FittedHead:
    """One whole fit (fast preset, about 12 s), made once per test run for the tests that
    need a fitted head or check what a fit writes; they are marked ``slow``."""
    import contextlib
    import io
    import json

    from PIL import Image
    from skimage import data

    from head360cli.cli import main

    folder = tmp_path_factory.mktemp("fitted")
    photo = folder / "astronaut.png"
    Image.fromarray(data.astronaut()).save(photo)
    head = folder / "me.h360"
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["fit", str(photo), "-o", str(head), "--json", "--quiet"])
    summary = json.loads(out.getvalue()) if code == 0 else {}
    return FittedHead(photo, head, summary, code, err.getvalue())


@pytest.fixture
def pipe(tmp_path):
    """``pipe(data, name)``: a named pipe that a thread fills with ``data`` once and then
    closes, as a shell's ``<(...)`` does; readers see no size and cannot seek."""
    import threading

    feeders = []

    def make(data: bytes, name: str = "fifo") -> Path:
        path = tmp_path / name
        os.mkfifo(path)

        def feed() -> None:
            with open(path, "wb") as f:  # blocks until a reader opens the pipe
                f.write(data)

        thread = threading.Thread(target=feed, daemon=True)
        thread.start()
        feeders.append((path, thread))
        return path

    yield make
    for path, thread in feeders:
        if thread.is_alive():  # nothing read it: open it once so the writer can finish
            fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
            thread.join(timeout=5)
            os.close(fd)
        thread.join(timeout=5)

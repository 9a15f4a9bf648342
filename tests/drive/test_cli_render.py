"""``head360 render``: a view, a grid, an expression, a turntable; clear errors."""

from __future__ import annotations

import json
import os
import sys

import numpy as np
import pytest
from PIL import Image


def test_render_view_grid_and_expression(run_cli, head_file, tmp_path):
    out = tmp_path / "v.png"
    r = run_cli("render", head_file, "--yaw", "30", "--size", "64", "--samples", "4",
                "-o", out)
    assert r.code == 0, r.err
    assert Image.open(out).size == (64, 64)
    r = run_cli("render", head_file, "--views", "0,90:20,180", "--size", "64",
                "--samples", "4", "-o", tmp_path / "g.png", "--json")
    assert r.code == 0 and json.loads(r.out)["views"] == [[0, 0], [90, 20], [180, 0]]
    w, h = Image.open(tmp_path / "g.png").size
    assert w == 3 * 64 and h > 64
    neutral = np.asarray(Image.open(out)).astype(int)
    run_cli("render", head_file, "--yaw", "30", "--size", "64", "--samples", "4",
            "--expr", "JawOpen=1", "-o", tmp_path / "jaw.png")
    jaw = np.asarray(Image.open(tmp_path / "jaw.png")).astype(int)
    assert np.abs(jaw - neutral).max() > 40  # the mouth opened
    # a JPEG of the same view: the same picture to compression's error
    r = run_cli("render", head_file, "--yaw", "30", "--size", "64", "--samples", "4",
                "-o", tmp_path / "v.jpg")
    assert r.code == 0, r.err
    jpeg = Image.open(tmp_path / "v.jpg")
    assert jpeg.format == "JPEG" and jpeg.size == (64, 64)
    assert np.abs(np.asarray(jpeg).astype(int) - neutral).mean() < 3


def test_render_turntable_and_errors(run_cli, head_file, tmp_path):
    r = run_cli("render", head_file, "--turntable", "--frames", "3", "--size", "64",
                "--samples", "2", "-o", tmp_path / "t.gif")
    assert r.code == 0, r.err
    assert Image.open(tmp_path / "t.gif").n_frames == 3
    cases = [
        (["--expr", "Nose=1"], "ARKit"),
        (["--pitch", "100"], "pitch"),
        (["--size", "63"], "multiple of 2"),
        (["--turntable", "--views", "0"], "both"),
        (["--views", ""], "expected at least one view, found ''"),  # was one front view
        (["--views", " , "], "expected at least one view"),
    ]
    for extra, words in cases:
        r = run_cli("render", head_file, *extra, "-o", tmp_path / "x.png")
        assert r.code == 3 and words in r.err, (extra, r.err)
        assert not (tmp_path / "x.png").exists()
    r = run_cli("render", head_file, "-o", tmp_path / "x.mp4")
    assert r.code == 3 and "--turntable" in r.err
    r = run_cli("render", tmp_path / "none.h360", "-o", tmp_path / "x.png")
    assert r.code == 3
    bad = tmp_path / "bad.h360"
    bad.write_bytes(b"not a head")
    r = run_cli("render", bad, "-o", tmp_path / "x.png")
    assert r.code == 5


def test_render_precision_option(run_cli, head_file, tmp_path):
    images = []
    for precision in ("fp32", "bf16"):
        out = tmp_path / f"{precision}.png"
        r = run_cli("render", head_file, "--size", "64", "--samples", "4", "--precision",
                    precision, "-o", out)
        assert r.code == 0, r.err
        images.append(np.asarray(Image.open(out)).astype(int))
    assert np.abs(images[0] - images[1]).max() <= 12
    assert run_cli("render", head_file, "--precision", "fp16", "-o", tmp_path / "x.png"
                   ).code == 2


def test_outputs_that_cannot_be_written_are_refused_before_the_head_loads(
        run_cli, head_file, tmp_path, monkeypatch):
    """A missing folder, a folder given for a file or a non-empty frame folder is refused
    before any work: the loaders here fail the test if they are reached (animating to a
    taken mesh folder used to load the head and bake its texture, 16 s, first)."""
    import head360cli.cli.head as cli_head
    from head360cli.io.arkit import ArkitStream, write_arkit_csv

    def loaded(*args, **kwargs):
        raise AssertionError("the head was loaded before the output was checked")

    monkeypatch.setattr(cli_head, "_backend_renderer", loaded)
    monkeypatch.setattr(cli_head, "_renderer", loaded)
    stream = tmp_path / "s.csv"
    write_arkit_csv(ArkitStream(np.zeros((2, 52), np.float32), np.arange(2) / 30, 30.0),
                    stream)
    taken = tmp_path / "taken"
    taken.mkdir()
    (taken / "keep.txt").write_text("the user's")
    cases = [
        (["render", head_file, "-o", tmp_path / "no" / "v.png"], "does not exist"),
        (["render", head_file, "-o", tmp_path / "taken.png"], None),
        (["render", head_file, "--turntable", "-o", taken], "holding files"),
        (["render", head_file, "--turntable", "-o", tmp_path / "no" / "t.mp4"],
         "does not exist"),
        (["export-mesh", head_file, "-o", tmp_path / "no" / "h.glb"], "does not exist"),
        (["animate", head_file, "--arkit", stream, "-o", taken], "holding files"),
        (["animate", head_file, "--arkit", stream, "-o", tmp_path / "no" / "a.mp4"],
         "does not exist"),
        (["animate", head_file, "--arkit", stream, "--mesh-sequence", taken], "holding files"),
    ]
    (tmp_path / "taken.png").mkdir()  # a folder where the view's file should go
    for args, words in cases:
        r = run_cli(*args)
        assert r.code == 3, (args, r.err)
        assert words is None or words in r.err, (args, r.err)
    assert "found a folder" in run_cli(*cases[1][0]).err
    assert [p.name for p in taken.iterdir()] == ["keep.txt"]
    assert not (tmp_path / "no").exists()


def test_turntable_honours_no_hair_and_starts_at_yaw(run_cli, head_file, tmp_path):
    """--no-hair reached single views only: a turntable with it wore the hair (it was not
    passed on). --yaw is where the turn starts; --frames and --fps without --turntable
    are said to be unused."""
    import imageio.v3 as iio

    def turn(name, *extra):
        r = run_cli("render", head_file, "--turntable", "--frames", "2", "--size", "64",
                    "--samples", "2", "-o", tmp_path / name, *extra)
        assert r.code == 0, r.err
        return np.stack([iio.imread(p) for p in sorted((tmp_path / name).iterdir())])

    hair, bald = turn("hair"), turn("bald", "--no-hair")
    assert hair.shape == bald.shape == (2, 64, 64, 3)
    assert np.abs(hair.astype(int) - bald).max() > 50  # the hair is gone
    start = turn("start", "--yaw", "180")  # frames at 180 and 360: the default's, swapped
    assert np.abs(start[0].astype(int) - hair[1]).max() <= 2
    assert np.abs(start[1].astype(int) - hair[0]).max() <= 2
    for extra in (["--no-hair"], ["--yaw", "180"]):  # the same options on single views
        r = run_cli("render", head_file, "--size", "64", "--samples", "2", *extra,
                    "-o", tmp_path / "v.png")
        assert r.code == 0 and "warning" not in r.err
    r = run_cli("render", head_file, "--frames", "10", "--fps", "5", "--size", "64",
                "--samples", "2", "-o", tmp_path / "w.png")
    assert r.code == 0
    assert "--frames and --fps are not used without --turntable" in r.err


def test_commands_without_the_generator_installed_say_what_is_missing(run_cli, head_file,
                                                                      tmp_path, monkeypatch):
    """render and animate read the generator's hash first, straight from the file: a
    models folder without generator.pt ended them in an internal error
    (FileNotFoundError) instead of exit 7."""
    empty = tmp_path / "models"
    empty.mkdir()
    monkeypatch.setenv("HEAD360_MODELS", str(empty))
    r = run_cli("render", head_file, "--size", "64", "-o", tmp_path / "v.png")
    assert r.code == 7 and "generator weights not found" in r.err, r.err
    assert not (tmp_path / "v.png").exists()


def test_unwritable_folders_and_a_full_disk_are_clear_errors(run_cli, head_file, tmp_path,
                                                             monkeypatch):
    """An output folder no file can be made in failed after the work as an internal
    error (PermissionError); so did a full disk (OSError ENOSPC)."""
    import errno
    import os

    from PIL import Image

    from head360cli.io import atomic

    def refuse(*args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied")

    with monkeypatch.context() as m:
        m.setattr(atomic.tempfile, "mkstemp", refuse)
        r = run_cli("render", head_file, "--size", "64", "-o", tmp_path / "v.png")
    assert r.code == 3 and "cannot write into output folder" in r.err, r.err
    assert "Permission denied" in r.err

    def full(self, fp, *args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(fp))

    monkeypatch.setattr(Image.Image, "save", full)
    r = run_cli("render", head_file, "--size", "64", "-o", tmp_path / "v.png")
    assert r.code == 3 and "No space left on device" in r.err and "free space" in r.err
    assert list(tmp_path.iterdir()) == []  # the temporary file is gone too


@pytest.mark.slow
def test_a_file_size_limit_is_a_clear_error(run_cli, head_file, tmp_path, monkeypatch):
    """EFBIG (a FAT32 stick's 4 GiB, or ``ulimit -f``) was an internal error; a turntable
    whose encoder the limit stopped was reported written, cut off, exit 0."""
    import errno
    import os
    import resource
    import subprocess
    import sys

    from PIL import Image

    def too_large(self, fp, *args, **kwargs):
        raise OSError(errno.EFBIG, os.strerror(errno.EFBIG), str(fp))

    with monkeypatch.context() as m:
        m.setattr(Image.Image, "save", too_large)
        r = run_cli("render", head_file, "--size", "64", "-o", tmp_path / "v.png")
    assert r.code == 3 and "File too large" in r.err and "ulimit -f" in r.err, r.err
    assert list(tmp_path.iterdir()) == []

    hard = resource.getrlimit(resource.RLIMIT_FSIZE)[1]
    run = subprocess.run(
        [sys.executable, "-m", "head360cli", "render", str(head_file), "--turntable",
         "--frames", "6", "--size", "64", "-o", str(tmp_path / "t.mp4")],
        capture_output=True, text=True, timeout=300,
        preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (3000, hard)))
    assert run.returncode == 3, run.stderr
    assert "file-size limit" in run.stderr and "wrote" not in run.stdout
    assert list(tmp_path.iterdir()) == []


def test_a_name_too_long_for_the_file_system_is_exit_3(run_cli, head_file, tmp_path):
    """An output or input name over the limit was an internal error (ENAMETOOLONG)."""
    import os

    long = "b" * (os.pathconf(tmp_path, "PC_NAME_MAX") + 5)
    for args in (("render", head_file, "--turntable", "--frames", "2", "--size", "32", "-o",
                  tmp_path / f"{long}.mp4"),
                 ("export-mesh", head_file, "-o", tmp_path / f"{long}.glb"),
                 ("inspect", tmp_path / f"{long}.csv")):
        r = run_cli(*args)
        assert r.code == 3 and len(r.err.strip().splitlines()) == 1, (args[0], r.err)
        assert "name" in r.err and "..." in r.err, r.err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
@pytest.mark.skipif(not os.path.exists("/dev/stdin"), reason="no /dev/stdin")
def test_a_head_on_standard_input_is_given_as_dash(head_file, tmp_path):
    """``cat me.h360 | head360 render -`` was "no such file: '-'"; with the stream on
    standard input too, animate says which one to give as a file."""
    import subprocess
    import sys

    out = tmp_path / "v.png"
    run = subprocess.run([sys.executable, "-m", "head360cli", "render", "-", "--size", "32",
                          "-o", str(out)], input=head_file.read_bytes(), capture_output=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr
    assert Image.open(out).size == (32, 32)
    run = subprocess.run([sys.executable, "-m", "head360cli", "animate", "-", "--arkit", "-",
                          "-o", str(tmp_path / "a.mp4")], input=head_file.read_bytes(),
                         capture_output=True, text=False, timeout=300)
    assert run.returncode == 3 and b"found both the head and --arkit" in run.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.png"]


@pytest.mark.skipif(os.name != "posix", reason="POSIX permissions")
def test_inputs_and_outputs_without_permission_are_one_line_exit_3(run_cli, head_file,
                                                                   tmp_path, monkeypatch):
    """An input without read permission was click's usage error (exit 2, three lines),
    where a missing one is one line, exit 3; a stream's was exit 5. Another user's output
    in a sticky folder (/tmp) failed at the rename after the work: an internal error
    naming the temporary file. As root every file is readable and the folder's owner
    rule does not apply, so as root the test asks as another user would (uid 12345,
    reading the permission bits)."""
    import errno
    import shutil

    import head360cli.io.atomic as atomic

    head = tmp_path / "h.h360"
    shutil.copy(head_file, head)
    stream = tmp_path / "s.csv"
    stream.write_text("Timecode,BlendShapeCount,JawOpen\n00:00:00:00.000,52,0.5\n")
    for path in (head, stream):
        os.chmod(path, 0)
    if os.geteuid() == 0:
        monkeypatch.setattr(os, "access", lambda path, mode: bool(
            os.stat(path).st_mode & (0o400 if mode == os.R_OK else 0o200)))
        monkeypatch.setattr(os, "geteuid", lambda: 12345)
    for args, path, name in ((("render", head, "-o", tmp_path / "v.png"), head, "(HEAD)"),
                             (("inspect", head), head, "(FILE)"),
                             (("animate", tmp_path / "x.h360", "--arkit", stream), stream,
                              "(--arkit)")):
        r = run_cli(*args)
        assert r.code == 3 and r.err.strip().splitlines() == [
            f"head360: error: cannot read {str(path)!r} {name}: permission denied"], r.err
    os.chmod(head, 0o644)
    sticky = tmp_path / "shared"
    sticky.mkdir()
    (sticky / "v.png").write_text("someone's")
    os.chmod(sticky, 0o1777)
    if os.geteuid() != 12345:  # not root: the files are this user's; ask as another
        monkeypatch.setattr(os, "geteuid", lambda: os.getuid() + 1)
    r = run_cli("render", head, "--size", "32", "-o", sticky / "v.png")
    assert r.code == 3 and "another user's, in a folder where only a file's owner" in r.err
    assert (sticky / "v.png").read_text() == "someone's"
    # a permission error no check before the work caught names the output, not the
    # temporary file the rename was from
    monkeypatch.undo()

    def refused(src, dst):
        raise PermissionError(errno.EPERM, "Operation not permitted", str(src), None,
                              str(dst))

    monkeypatch.setattr(atomic.os, "replace", refused)
    r = run_cli("render", head, "--size", "32", "-o", tmp_path / "w.png")
    assert r.code == 3 and r.err.strip().splitlines() == [
        f"head360: error: Operation not permitted ({tmp_path / 'w.png'}): check the file's "
        f"and its folder's permissions"], r.err


@pytest.mark.slow
def test_a_view_goes_to_standard_output_with_dash(head_file, tmp_path):
    """``render -o -`` writes the PNG of the view to standard output, the same pixels as
    ``-o view.png``, and nothing else there (no "wrote ..." line)."""
    import io
    import subprocess
    import sys

    args = [sys.executable, "-m", "head360cli", "render", str(head_file), "--yaw", "20",
            "--size", "32", "--samples", "4"]
    run = subprocess.run([*args, "-o", "-"], capture_output=True, timeout=300)
    assert run.returncode == 0, run.stderr
    piped = Image.open(io.BytesIO(run.stdout))
    assert piped.format == "PNG" and piped.size == (32, 32)
    run = subprocess.run([*args, "-o", str(tmp_path / "v.png")], capture_output=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr
    assert np.array_equal(np.asarray(piped), np.asarray(Image.open(tmp_path / "v.png")))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.png"]


def test_dash_is_refused_where_standard_output_cannot_take_a_png(run_cli, head_file,
                                                                 monkeypatch):
    r = run_cli("render", head_file, "--size", "32", "-o", "-", "--json")
    assert r.code == 3 and "both go to standard output" in r.err
    r = run_cli("render", head_file, "--turntable", "--frames", "2", "-o", "-")
    assert r.code == 3 and "--turntable video, found '-'" in r.err
    monkeypatch.setattr(sys.stdout, "isatty", lambda: True)  # a terminal: no binary there
    r = run_cli("render", head_file, "--size", "32", "-o", "-")
    assert r.code == 3 and "found a terminal" in r.err
    assert r.out == ""


@pytest.mark.slow
def test_a_fitted_head_is_neutral_by_default_and_smiles_with_expr_photo(
        run_cli, fitted_astronaut, tmp_path):
    """The astronaut smiles (mouthSmile about 1 in the fit's expression): rendered by
    default her head is neutral; ``--expr photo`` gives her smile back, and it equals
    rendering her own weights by name."""
    from head360cli.io.headfile import read_head
    from head360cli.mesh.arkit52 import ARKIT52, INDEX

    head = read_head(fitted_astronaut.head)
    own = np.asarray(head.arrays["expression"], np.float64)
    assert own[[INDEX["mouthSmileLeft"], INDEX["mouthSmileRight"]]].mean() > 0.5
    args = ("--size", "64", "--samples", "4")
    run_cli("render", fitted_astronaut.head, *args, "-o", tmp_path / "n.png")
    r = run_cli("render", fitted_astronaut.head, *args, "--expr", "photo",
                "-o", tmp_path / "p.png")
    assert r.code == 0, r.err
    neutral, photo = (np.asarray(Image.open(tmp_path / f)).astype(int)
                      for f in ("n.png", "p.png"))
    assert np.abs(photo - neutral).max() > 40  # the smile came back
    named = ",".join(f"{n}={own[i]:.6f}" for i, n in enumerate(ARKIT52)
                     if own[i] > 0 and not n.startswith(("eyeBlink", "eyeSquint", "eyeWide")))
    run_cli("render", fitted_astronaut.head, *args, "--expr", named, "-o", tmp_path / "b.png")
    by_name = np.asarray(Image.open(tmp_path / "b.png")).astype(int)
    assert np.abs(by_name - photo).max() <= 2


def test_options_that_conflict_are_refused_in_one_line(run_cli, head_file, tmp_path):
    """--views gives every view's angles, so a --yaw beside it would be dropped; --video
    tracks and filters its own readings, so --stream-fps or --smooth would do nothing.
    Each is refused before anything is loaded, and nothing is written."""
    out = tmp_path / "v.png"
    r = run_cli("render", head_file, "--views", "0,90", "--yaw", "45", "-o", out)
    assert r.code == 3 and "expected no --yaw with --views" in r.err
    assert len(r.err.strip().splitlines()) == 1 and not out.exists()
    r = run_cli("animate", head_file, "--video", tmp_path / "none.mp4", "--stream-fps",
                "30", "-o", tmp_path / "a.mp4")
    assert r.code == 3 and "expected no --stream-fps with --video" in r.err
    assert len(r.err.strip().splitlines()) == 1 and not (tmp_path / "a.mp4").exists()


def test_image_sizes_are_checked_before_loading_with_one_wording(run_cli, head_file, tmp_path,
                                                                 monkeypatch):
    """--size 255 (odd) and --size -2 (below the range) say the same thing, before the
    head or the generator is loaded, in render, animate and export-onnx alike."""
    import head360cli.fitting.pipeline as pipeline

    def refuse(*args, **kwargs):
        raise AssertionError("loaded before the size was checked")

    monkeypatch.setattr(pipeline, "load_head_renderer", refuse)
    (tmp_path / "s.csv").write_text("time,jawOpen\n0,0.1\n0.1,0.5\n")
    for size in ("255", "-2", "4096"):
        wanted = f"expected --size a multiple of 2 between 32 and 2048, found {size}"
        for args in (("render", head_file, "-o", tmp_path / "v.png"),
                     ("animate", head_file, "--arkit", tmp_path / "s.csv", "-o",
                      tmp_path / "a.mp4"),
                     ("export-onnx", "-o", tmp_path / "g.onnx")):
            r = run_cli(*args, "--size", size)
            assert r.code == 3 and wanted in r.err, (args, r.err)

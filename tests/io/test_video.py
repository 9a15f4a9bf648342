"""Frame writers: mp4, GIF and PNG folders; streaming, even sizes, atomic outputs."""

from __future__ import annotations

import os
import stat
import tracemalloc

import numpy as np
import pytest

from head360cli.errors import BadInputError
from head360cli.io.atomic import atomic_dir, atomic_path
from head360cli.io.video import VideoWriter, output_kind, write_video


def frames(n: int, w: int = 33, h: int = 21):
    for i in range(n):
        f = np.zeros((h, w, 3), dtype=np.uint8)
        f[..., 0] = (i * 20) % 256
        f[:, : (i % w) + 1, 1] = 255
        yield f


def read_back(path):
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    count = sum(1 for _ in reader)
    return meta, count


def test_output_kind_by_name(tmp_path):
    assert output_kind("a.mp4") == "mp4"
    assert output_kind("a.MOV") == "mp4"
    assert output_kind("a.gif") == "gif"
    assert output_kind("frames/") == "png"
    assert output_kind("frames") == "png"
    assert output_kind(tmp_path) == "png"
    with pytest.raises(BadInputError, match=r"\.mp4 \(\.m4v, \.mov\), \.gif or a folder"):
        output_kind("a.avi")


def test_mp4_pads_odd_sizes_to_even_and_keeps_every_frame(tmp_path):
    out = tmp_path / "clip.mp4"
    assert write_video(frames(12), out, fps=24) == 12
    meta, count = read_back(out)
    assert meta["size"] == (34, 22)
    assert meta["fps"] == pytest.approx(24)
    assert count == 12
    assert [p.name for p in tmp_path.iterdir()] == ["clip.mp4"]


def test_mp4_content_survives_encoding(tmp_path):
    out = tmp_path / "flat.mp4"
    flat = [np.full((32, 32, 3), v, dtype=np.uint8) for v in (40, 120, 200)]
    write_video(flat, out, fps=10)
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(out))
    next(reader)
    got = [np.frombuffer(b, dtype=np.uint8).mean() for b in reader]
    np.testing.assert_allclose(got, [40, 120, 200], atol=3)


def test_mp4_says_how_its_colours_are_encoded(tmp_path):
    """The stream was untagged, so a player guessed its matrix (many take an HD video for
    BT.709, the encoding was BT.601's); it says BT.601's matrix, limited range, sRGB's
    primaries and transfer, and saturated colours come back through a decoder that reads
    the tags."""
    import subprocess

    import imageio_ffmpeg

    colours = np.array([[230, 40, 40], [40, 200, 60], [30, 60, 220], [220, 180, 140]],
                       np.uint8)
    frame = np.repeat(np.repeat(colours[None], 32, 0), 32, 1)  # four 32-pixel blocks
    out = tmp_path / "colours.mp4"
    write_video([frame] * 3, out, fps=10, quality=10)
    ffmpeg = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(out)],
                           capture_output=True, text=True)
    assert "yuv420p(tv, smpte170m/bt709/iec61966-2-1" in ffmpeg.stderr, ffmpeg.stderr
    reader = imageio_ffmpeg.read_frames(str(out))
    next(reader)
    got = np.frombuffer(next(reader), np.uint8).reshape(32, 128, 3)
    centres = got[16, 16::32].astype(int)
    assert np.abs(centres - colours).max() <= 6, centres


def test_gif_streams_with_exact_flat_colours(tmp_path):
    import imageio.v3 as iio

    out = tmp_path / "clip.gif"
    write_video(frames(6), out, fps=10)
    back = iio.imread(out)
    assert back.shape[:3] == (6, 21, 33)
    assert tuple(back[3, 0, 0, :3]) == (60, 255, 0)


def _gif_durations(path) -> list[int]:
    from PIL import Image

    out = []
    with Image.open(path) as im:
        for i in range(im.n_frames):
            im.seek(i)
            out.append(im.info["duration"])
    return out


def test_a_gif_faster_than_browsers_play_is_refused(tmp_path):
    """At 60 fps the frames were stored as 20, 10, 20 ms...: browsers show a frame of 10
    ms for 100, so the GIF played several times too slowly. 50 fps is the limit."""
    assert set(_gif_durations(_write(tmp_path / "a.gif", 50))) == {20}
    with pytest.raises(BadInputError, match="at most 50 frames per second for a GIF"):
        VideoWriter(tmp_path / "b.gif", fps=60)
    _write(tmp_path / "c.mp4", 60)  # an mp4 keeps any rate
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.gif", "c.mp4"]


def _write(path, fps):
    write_video(frames(4), path, fps=fps)
    return path


def test_png_folder(tmp_path):
    out = tmp_path / "frames"
    write_video(frames(5), out, fps=10)
    names = sorted(p.name for p in out.iterdir())
    assert names == [f"frame_{i:06d}.png" for i in range(5)]
    with pytest.raises(BadInputError, match="holding files"):
        write_video(frames(2), out, fps=10)
    write_video(frames(2), out, fps=10, overwrite=True)
    assert len(list(out.iterdir())) == 2


def test_float_and_grey_frames_are_accepted(tmp_path):
    out = tmp_path / "f"
    write_video([np.full((4, 4), 0.5), np.ones((4, 4, 3))], out)
    from PIL import Image

    assert np.asarray(Image.open(out / "frame_000000.png")).max() == 128


@pytest.mark.parametrize("name", ["fail.mp4", "fail.gif", "failframes"])
def test_failure_midway_leaves_nothing(tmp_path, name):
    def broken():
        yield from frames(3)
        raise RuntimeError("renderer crashed")

    with pytest.raises(RuntimeError, match="renderer crashed"):
        write_video(broken(), tmp_path / name, fps=10)
    assert list(tmp_path.iterdir()) == []


def test_failure_keeps_the_previous_output(tmp_path):
    out = tmp_path / "keep.mp4"
    write_video(frames(3), out, fps=10)
    before = out.read_bytes()
    with pytest.raises(BadInputError, match="expected 33x21"):
        write_video([*frames(2), np.zeros((10, 10, 3), np.uint8)], out, fps=10)
    assert out.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["keep.mp4"]


_SIZE_LIMITED = """
import resource, sys
import numpy as np
from head360cli.errors import BadInputError
from head360cli.io.video import write_video
resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
noise = (np.random.default_rng(0).integers(0, 256, (24, 128, 128, 3), np.uint8))
try:
    write_video(iter(noise), sys.argv[1], fps=24)
except BadInputError as exc:
    print("refused:", exc)
else:
    print("written")
"""


@pytest.mark.skipif(not hasattr(os, "fork"), reason="the file-size limit is POSIX's")
@pytest.mark.parametrize("name", ["noise.mp4", "noise.gif"])
def test_an_encoder_that_cannot_finish_the_file_is_an_error(tmp_path, name):
    """Under a 20 kB file-size limit (as a full disk or a FAT32 stick's 4 GiB does for
    larger files) ffmpeg is stopped part-way. The writer used to rename the cut-off mp4
    into place, over the previous one, and report it written."""
    import subprocess
    import sys

    out = tmp_path / name
    out.write_bytes(b"the previous output")
    run = subprocess.run([sys.executable, "-c", _SIZE_LIMITED, str(out)], capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith("refused:"), run.stdout
    assert "file-size limit" in run.stdout and repr(str(out)) in run.stdout
    assert out.read_bytes() == b"the previous output"
    assert [p.name for p in tmp_path.iterdir()] == [name]


def test_an_ffmpeg_failure_is_one_line_with_its_message(tmp_path):
    """A failure that is not the output's disk names ffmpeg's own last message."""
    from head360cli.io.video import _Encoder

    enc = _Encoder(tmp_path / "x.mp4", tmp_path / "shown.mp4", 32, 32, 10.0,
                   ["-vcodec", "no_such_encoder"], "error")
    with pytest.raises(RuntimeError, match=r"ffmpeg could not write .*shown\.mp4.* \(exit "
                       r"status [1-9]\d*\): .*[Ee]ncoder not found") as info:
        for _ in range(50):  # ffmpeg exits at once; the pipe breaks on a write or the close
            enc.send(np.zeros((32, 32, 3), np.uint8))
        enc.close()
    assert "\n" not in str(info.value)


_FAKE_FFMPEG = """#!{python}
import sys
args = sys.argv[1:]
sys.stdin.buffer.read()
frames = {frames!r}  # None: a progress report that could not be written
if frames is not None:
    with open(args[args.index("-progress") + 1], "w") as f:
        f.write("frame={frames}\\nprogress=end\\n")
with open(args[-1], "wb") as f:
    f.write(b"a header and no frames")
sys.stderr.write({message!r} + "\\n")
sys.exit({code})
"""


@pytest.mark.skipif(os.name != "posix", reason="a fake ffmpeg as a script")
@pytest.mark.parametrize("code, frames, message, error, says", [
    (0, 0, "[out#0/mp4] Output file is empty, nothing was encoded", RuntimeError,
     r"ffmpeg encoded 0 of the 3 frames of .*: \[out#0/mp4\] Output file is empty"),
    (0, 2, "", RuntimeError, "ffmpeg encoded 2 of the 3 frames of .*: no message"),
    (245, 0, "[vost#0:0/libx264] pthread_create() failed: Resource temporarily unavailable",
     BadInputError, r"could not start its threads .*ulimit -u.*nothing half-written"),
])
def test_an_encoder_that_exits_0_without_every_frame_is_an_error(tmp_path, monkeypatch,
                                                                  code, frames, message,
                                                                  error, says):
    """Under a limit on processes (``ulimit -u``, a container's pids limit) ffmpeg could
    not start its scaler's threads, encoded no frame and exited 0: the animation was a
    261-byte mp4 with no frames, exit 0. ffmpeg's own count of the frames it encoded is
    now checked against those sent, and its refused threads say which limit to raise."""
    import sys

    import imageio_ffmpeg

    fake = tmp_path / "ffmpeg"
    fake.write_text(_FAKE_FFMPEG.format(python=sys.executable, frames=frames,
                                        message=message, code=code))
    fake.chmod(0o755)
    monkeypatch.setattr(imageio_ffmpeg, "get_ffmpeg_exe", lambda: str(fake))
    out = tmp_path / "take.mp4"
    out.write_bytes(b"the previous take")
    with pytest.raises(error, match=says):
        write_video((np.zeros((16, 16, 3), np.uint8) for _ in range(3)), out, fps=10)
    assert out.read_bytes() == b"the previous take"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ffmpeg", "take.mp4"]


@pytest.mark.skipif(os.name != "posix", reason="a fake ffmpeg as a script")
def test_an_encoder_without_a_progress_report_is_judged_by_its_exit_status(tmp_path,
                                                                           monkeypatch):
    """A full temporary folder leaves ffmpeg's progress report empty: the frame count
    is then unknown, not 0, and a video ffmpeg finished is kept as before."""
    import sys

    import imageio_ffmpeg

    fake = tmp_path / "ffmpeg"
    fake.write_text(_FAKE_FFMPEG.format(python=sys.executable, frames=None, message="",
                                        code=0))
    fake.chmod(0o755)
    monkeypatch.setattr(imageio_ffmpeg, "get_ffmpeg_exe", lambda: str(fake))
    out = tmp_path / "take.mp4"
    assert write_video((np.zeros((16, 16, 3), np.uint8) for _ in range(3)), out,
                       fps=10) == 3
    assert out.read_bytes() == b"a header and no frames"


@pytest.mark.parametrize("exe", ["missing", "not_a_program"])
def test_an_ffmpeg_that_cannot_run_is_exit_7(tmp_path, monkeypatch, exe):
    """IMAGEIO_FFMPEG_EXE naming a missing file (or imageio-ffmpeg's binary gone) was an
    internal error to report (FileNotFoundError), exit 1; a file that is no program
    said only "Permission denied"."""
    from head360cli.errors import ModelNotFoundError

    path = tmp_path / exe
    if exe == "not_a_program":
        path.write_text("not ffmpeg")
    monkeypatch.setenv("IMAGEIO_FFMPEG_EXE", str(path))
    out = tmp_path / "take.mp4"
    with pytest.raises(ModelNotFoundError, match=rf"cannot run ffmpeg '.*{exe}', named by "
                                                 r"IMAGEIO_FFMPEG_EXE, to write videos \("
                                                 r".*\): point it at an ffmpeg program"):
        write_video((np.zeros((16, 16, 3), np.uint8) for _ in range(3)), out, fps=10)
    assert not out.exists()
    monkeypatch.delenv("IMAGEIO_FFMPEG_EXE")
    monkeypatch.setattr("imageio_ffmpeg.get_ffmpeg_exe", lambda: str(path))
    with pytest.raises(ModelNotFoundError, match="reinstall imageio-ffmpeg"):
        write_video((np.zeros((16, 16, 3), np.uint8) for _ in range(3)), out, fps=10)

    def none_found():
        raise RuntimeError("No ffmpeg exe could be found. Install ffmpeg on your system, "
                           "or set the IMAGEIO_FFMPEG_EXE environment variable.")

    monkeypatch.setattr("imageio_ffmpeg.get_ffmpeg_exe", none_found)
    with pytest.raises(ModelNotFoundError, match=r"no ffmpeg to write videos \(No ffmpeg "
                                                 r"exe could be found.*\): reinstall"):
        write_video((np.zeros((16, 16, 3), np.uint8) for _ in range(3)), out, fps=10)
    assert sorted(p.name for p in tmp_path.iterdir()) == ([exe] if path.exists() else [])


def test_bad_arguments(tmp_path):
    with pytest.raises(BadInputError, match="does not exist"):
        VideoWriter(tmp_path / "nope" / "a.mp4")
    with pytest.raises(BadInputError, match="positive frame rate"):
        VideoWriter(tmp_path / "a.mp4", fps=0)
    for quality in (-1, 52, 18.5, True):
        with pytest.raises(BadInputError, match=r"quality .* from 0 to 51"):
            VideoWriter(tmp_path / "a.mp4", quality=quality)
    with pytest.raises(BadInputError, match="no frames"):
        write_video([], tmp_path / "empty.mp4")
    with pytest.raises(BadInputError, match=r"shape \(H, W, 3\)"):
        write_video([np.zeros((4, 4, 2))], tmp_path / "x.mp4")
    assert list(tmp_path.iterdir()) == []


def test_memory_does_not_grow_with_the_number_of_frames(tmp_path):
    """400 frames of 256x256 are 79 MB raw; streaming keeps the peak near one frame."""

    def many():
        f = np.zeros((256, 256, 3), dtype=np.uint8)
        for i in range(400):
            f[:] = i % 256
            yield f

    tracemalloc.start()
    write_video(many(), tmp_path / "long.mp4", fps=60)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert peak < 5_000_000
    assert read_back(tmp_path / "long.mp4")[1] == 400


def test_atomic_path_and_dir(tmp_path):
    target = tmp_path / "a.txt"
    with atomic_path(target) as tmp:
        assert tmp.suffix == ".txt" and tmp.parent == tmp_path
        tmp.write_text("done")
    assert target.read_text() == "done"
    with pytest.raises(ValueError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise ValueError
    assert target.read_text() == "done"
    with atomic_dir(tmp_path / "d") as d:
        (d / "x").write_text("1")
    assert (tmp_path / "d" / "x").read_text() == "1"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "d"]
    # A target in a missing folder is refused on entry, before anything is written.
    with pytest.raises(BadInputError, match="does not exist"):
        atomic_path(tmp_path / "no" / "x").__enter__()
    assert not (tmp_path / "no").exists()
    # so is a folder given for the file, which is left as it was
    with pytest.raises(BadInputError, match="found a folder"):
        atomic_path(tmp_path / "d").__enter__()
    assert (tmp_path / "d" / "x").read_text() == "1"


@pytest.mark.skipif(not hasattr(os, "symlink") or os.name != "posix",
                    reason="symbolic links are POSIX's here")
def test_an_output_that_is_a_symbolic_link_is_written_where_it_leads(tmp_path):
    """``-o latest.mp4`` where latest.mp4 links to a file elsewhere: the new output was
    renamed onto the link, which became a plain file, and the file it led to kept the old
    output. A shell's ``>`` and ffmpeg write through the link; so does head360 now, for
    files, videos, frame folders and links to a file not made yet."""
    real, links = tmp_path / "real", tmp_path / "links"
    real.mkdir()
    links.mkdir()
    (real / "a.txt").write_text("old")
    (links / "a.txt").symlink_to(real / "a.txt")
    with atomic_path(links / "a.txt") as tmp:
        assert tmp.parent == real  # a rename within the file system of the file
        tmp.write_text("new")
    (links / "new.txt").symlink_to("../real/new.txt")  # relative, to no file yet
    with atomic_path(links / "new.txt") as tmp:
        tmp.write_text("made")
    (links / "v.mp4").symlink_to(real / "v.mp4")
    write_video(frames(3), links / "v.mp4", fps=10)
    (real / "frames").mkdir()
    (links / "frames").symlink_to(real / "frames", target_is_directory=True)
    write_video(frames(2), links / "frames", fps=10, overwrite=True)
    with atomic_dir(links / "frames", overwrite=True) as d:
        (d / "x").write_text("1")
    from head360cli.io.atomic import check_file_target

    (links / "lost.png").symlink_to(real / "gone" / "x.png")  # checked where it leads
    with pytest.raises(BadInputError, match=r"gone' does not exist"):
        check_file_target(links / "lost.png")
    assert all(p.is_symlink() for p in links.iterdir())
    assert (real / "a.txt").read_text() == "new" and (real / "new.txt").read_text() == "made"
    assert read_back(real / "v.mp4")[1] == 3
    assert [p.name for p in (real / "frames").iterdir()] == ["x"]
    assert sorted(p.name for p in real.iterdir()) == ["a.txt", "frames", "new.txt", "v.mp4"]


def test_atomic_paths_renames_a_set_only_when_every_file_is_written(tmp_path):
    from head360cli.io.atomic import atomic_paths

    a, b, c = tmp_path / "a.h360", tmp_path / "a.png", tmp_path / "a.json"
    with atomic_paths(a, b, c) as tmps:
        assert [t.suffix for t in tmps] == [".h360", ".png", ".json"]
        for t, text in zip(tmps, "123", strict=True):
            t.write_text(text)
    assert [p.read_text() for p in (a, b, c)] == ["1", "2", "3"]
    with pytest.raises(OSError, match="disk full"), atomic_paths(a, b, c) as tmps:
        tmps[0].write_text("new 1")
        tmps[1].write_text("new 2")
        raise OSError("disk full")  # at the last file
    assert [p.read_text() for p in (a, b, c)] == ["1", "2", "3"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.h360", "a.json", "a.png"]


def test_names_near_the_file_system_s_limit(tmp_path):
    """A name a few bytes under the limit was refused ("cannot write into output folder:
    File name too long") because its temporary name was longer; one over it was an
    internal error from ``is_dir``."""
    limit = os.pathconf(tmp_path, "PC_NAME_MAX")
    near = "n" * (limit - 8)
    with atomic_path(tmp_path / f"{near}.png") as tmp:
        tmp.write_text("x")
    with atomic_dir(tmp_path / near) as d:
        (d / "f").write_text("y")
    assert write_video(frames(2), tmp_path / f"{near}.mp4", fps=10) == 2
    assert sorted(len(p.name) for p in tmp_path.iterdir()) == [limit - 8, limit - 4,
                                                               limit - 4]
    over = "o" * limit + ".mp4"
    for make in (lambda: atomic_path(tmp_path / over).__enter__(),
                 lambda: VideoWriter(tmp_path / over),
                 lambda: write_video(frames(2), tmp_path / ("o" * (limit + 1) + "/"))):
        with pytest.raises(BadInputError, match=f"at most {limit} bytes, found"):
            make()


def test_the_next_write_removes_what_a_killed_run_left(tmp_path):
    """A run killed outright (SIGKILL, the out-of-memory killer) leaves its temporary
    file or folder, hidden; they used to stay for good, a partial mp4 perhaps gigabytes."""
    import subprocess
    import sys
    import time

    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    dead = int(gone.stdout)  # a process that has ended
    hour_ago = time.time() - 2 * 3600
    left = {
        "dead_old": tmp_path / f".out.{dead}-abc123.tmp.mp4",
        "dead_old_dir": tmp_path / f".frames.{dead}-xyz.tmp",
        "dead_new": tmp_path / f".out.{dead}-new.tmp.mp4",  # may be another host's, writing
        "alive_old": tmp_path / f".out.{os.getppid()}-par.tmp.mp4",
        "other_output": tmp_path / f".other.{dead}-abc.tmp.mp4",
        "not_ours": tmp_path / ".out.tmp.mp4",
    }
    for key, path in left.items():
        if key.endswith("_dir"):
            path.mkdir()
            (path / "frame_000000.png").write_bytes(b"x")
        else:
            path.write_bytes(b"partial")
        if key != "dead_new":
            os.utime(path, (hour_ago, hour_ago))
    write_video(frames(2), tmp_path / "out.mp4", fps=10)
    write_video(frames(2), tmp_path / "frames", fps=10)
    kept = {key for key, path in left.items() if path.exists()}
    assert kept == {"dead_new", "alive_old", "other_output", "not_ours"}
    assert sorted(p.name for p in (tmp_path / "frames").iterdir()) == [
        "frame_000000.png", "frame_000001.png"]


@pytest.fixture
def umask_027():
    """Run with a umask that a shared machine might set, then put the old one back."""
    old = os.umask(0o027)
    yield 0o027
    os.umask(old)


@pytest.mark.parametrize("name", ["clip.mp4", "clip.gif", "frames/"])
def test_outputs_get_the_usual_permissions(tmp_path, umask_027, name):
    """Videos, GIFs and frame folders are created as a plain write would create them
    (the temporary file or folder they start as is private): 0o640 files, 0o750
    folders under umask 027."""
    from head360cli.io.atomic import current_umask

    assert current_umask() == umask_027
    write_video(frames(3), tmp_path / name, fps=10)
    out = tmp_path / name.rstrip("/")
    assert stat.S_IMODE(out.stat().st_mode) == (0o750 if out.is_dir() else 0o640)
    with atomic_dir(tmp_path / "d") as d:
        (d / "x").write_text("1")
    assert stat.S_IMODE((tmp_path / "d").stat().st_mode) == 0o750
    with atomic_path(tmp_path / "a.txt") as tmp:
        tmp.write_text("done")
    assert stat.S_IMODE((tmp_path / "a.txt").stat().st_mode) == 0o640


@pytest.mark.skipif(os.name != "posix", reason="POSIX permission bits")
@pytest.mark.parametrize("mode", [0o600, 0o664])
def test_a_replaced_output_keeps_its_permissions(tmp_path, mode):
    """``chmod 600 me.h360`` then ``swap-hair me.h360 -o me.h360``: the new file was made
    anew with the umask's mode, readable by all (0o644); a write into the file keeps its
    mode, and so does head360's rename now, for files, sets, videos and frame folders."""
    from head360cli.io.atomic import atomic_paths

    names = ("a.txt", "b.txt", "c.txt", "v.mp4", "frames")
    for name in names[:4]:
        (tmp_path / name).write_text("old")
    (tmp_path / "frames").mkdir()
    for name in names:
        os.chmod(tmp_path / name, mode | (0o111 if name == "frames" else 0))
    with atomic_path(tmp_path / "a.txt") as tmp:
        tmp.write_text("new")
    with atomic_paths(tmp_path / "b.txt", tmp_path / "c.txt") as tmps:
        for tmp in tmps:
            tmp.write_text("new")
    write_video(frames(2), tmp_path / "v.mp4", fps=10)
    write_video(frames(2), tmp_path / "frames", fps=10, overwrite=True)
    for name in names:
        want = mode | (0o111 if name == "frames" else 0)
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == want, name
    assert (tmp_path / "c.txt").read_text() == "new" and read_back(tmp_path / "v.mp4")[1] == 2


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes")
def test_a_named_pipe_as_output_is_refused_and_left_as_it_is(tmp_path):
    """``mkfifo view.png; viewer view.png & head360 render -o view.png``: the render was
    renamed over the pipe, which became a plain file, and the reader waited for ever."""
    from head360cli.io.atomic import check_file_target

    for name in ("view.png", "turn.mp4"):
        os.mkfifo(tmp_path / name)
    for make in (lambda: atomic_path(tmp_path / "view.png").__enter__(),
                 lambda: check_file_target(tmp_path / "view.png"),
                 lambda: VideoWriter(tmp_path / "turn.mp4")):
        with pytest.raises(BadInputError, match="found a named pipe"):
            make()
    assert all(stat.S_ISFIFO(p.lstat().st_mode) for p in tmp_path.iterdir())
    assert len(list(tmp_path.iterdir())) == 2


@pytest.mark.skipif(os.name != "posix", reason="POSIX permission bits")
def test_a_read_only_output_is_refused_and_kept(tmp_path, monkeypatch):
    """A file made read-only to keep it (``chmod a-w final.mp4``) was replaced: the
    rename needs only the folder's permission, where a shell's ``>`` refuses. Root may
    write any file (``os.access`` says so), so as root the test asks as another user
    would, from the permission bits."""
    import head360cli.io.atomic as atomic

    for name in ("final.png", "final.mp4"):
        (tmp_path / name).write_text("mine")
        os.chmod(tmp_path / name, 0o444)
    if os.geteuid() == 0:
        monkeypatch.setattr(atomic.os, "access", lambda path, mode: bool(
            os.stat(path).st_mode & 0o200) or mode != os.W_OK)
    for make in (lambda: atomic_path(tmp_path / "final.png").__enter__(),
                 lambda: atomic.check_file_target(tmp_path / "final.png"),
                 lambda: VideoWriter(tmp_path / "final.mp4")):
        with pytest.raises(BadInputError, match="read-only: give another name, or make"):
            make()
    assert {p.name: p.read_text() for p in tmp_path.iterdir()} == {
        "final.png": "mine", "final.mp4": "mine"}
    os.chmod(tmp_path / "final.png", 0o644)  # writable again: replaced
    with atomic_path(tmp_path / "final.png") as tmp:
        tmp.write_text("new")
    assert (tmp_path / "final.png").read_text() == "new"

"""Animation: head-pose cameras, stream preparation, frames out, memory-flat streaming."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
import torch

from head360cli.drive.animate import (
    HEAD_PIVOT,
    AnimateConfig,
    animate,
    head_pose_cameras,
    prepare_stream,
)
from head360cli.errors import BadInputError
from head360cli.io.arkit import ArkitStream
from head360cli.mesh.arkit52 import INDEX


def _stream(n=30, fps=30.0, rotation=False):
    w = np.zeros((n, 52), np.float32)
    w[:, INDEX["jawOpen"]] = np.linspace(0, 1, n)
    rot = np.zeros((n, 3), np.float32) if rotation else None
    if rotation:
        rot[:, 0] = np.linspace(0, 0.5, n)
    return ArkitStream(w, np.arange(n) / fps, fps, head_rotation=rot)


def test_zero_head_rotation_keeps_the_camera():
    from head360cli.drive.views import view_cameras

    base = view_cameras(20.0, 5.0)[0]
    cams = head_pose_cameras(np.zeros((3, 3)), base)
    torch.testing.assert_close(cams, base[None].expand(3, 4, 4), atol=1e-6, rtol=0)


def test_head_yaw_equals_the_camera_turning_the_other_way():
    """A head turned to its left by 30 degrees about a vertical axis through the pivot is
    seen by the front camera as a still head is seen from 30 degrees to its right."""
    from head360cli.drive.views import view_cameras

    base = view_cameras(0.0, 0.0)[0]
    cam = head_pose_cameras(np.array([[np.radians(30), 0, 0]]), base)[0]
    # the camera's position relative to the pivot turned by -30 degrees about +y
    rel = cam[:3, 3].double().numpy() - np.array(HEAD_PIVOT)
    rel0 = base[:3, 3].double().numpy() - np.array(HEAD_PIVOT)
    assert np.linalg.norm(rel) == pytest.approx(np.linalg.norm(rel0), abs=1e-6)
    assert np.degrees(np.arctan2(rel[0], rel[2])) == pytest.approx(-30.0, abs=1e-4)
    # pitching down (positive pitch) puts the camera above the head
    down = head_pose_cameras(np.array([[0, np.radians(20), 0]]), base)[0]
    assert down[1, 3] > base[1, 3] + 0.05


def test_prepare_stream_cuts_resamples_and_checks():
    s = _stream(60, 30.0, rotation=True)
    out = prepare_stream(s, AnimateConfig(fps=15.0, start=0.5, end=1.5))
    assert out.fps == 15.0 and out.num_frames == 15
    assert out.weights[0, INDEX["jawOpen"]] == pytest.approx(15 / 59, abs=1e-6)
    with pytest.raises(BadInputError, match="after --start"):
        prepare_stream(s, AnimateConfig(start=1.0, end=0.5))
    with pytest.raises(BadInputError, match="head rotation"):
        prepare_stream(_stream(), AnimateConfig(head_pose=True))
    # dropped frames keep their time: a gap of 10 frames is bridged, not skipped
    gap = _stream(40)
    keep = np.r_[0:15, 25:40]
    gap = ArkitStream(gap.weights[keep], gap.timestamps[keep], 30.0)
    assert prepare_stream(gap, AnimateConfig()).num_frames == 40


def test_prepare_stream_refuses_rates_and_lengths_no_video_has():
    """Two frames 1e5 s apart made a video at 1e-5 fps (1e300 s: an internal error in
    the encoder); resampling them at --fps 1 filled memory (an internal error)."""
    w = np.zeros((2, 52), np.float32)
    apart = ArkitStream(w, np.array([0.0, 1e5]), 1e-5)
    with pytest.raises(BadInputError, match=r"1 to 240 frames per second, found 1e-05 "
                       r"\(frames 1e\+05 s apart; a time column in milliseconds"):
        prepare_stream(apart, AnimateConfig())
    with pytest.raises(BadInputError, match=r"found 1000 \(frames 0.001 s apart\)"):
        prepare_stream(ArkitStream(w, np.array([0.0, 1e-3]), 1000.0), AnimateConfig())
    with pytest.raises(BadInputError, match=r"at most 2000000 frames, found 3e\+06 "
                       r"\(1e\+05 s at 30 fps\): cut it"):
        prepare_stream(apart, AnimateConfig(fps=30.0))
    assert prepare_stream(apart, AnimateConfig(fps=1.0, end=10.0)).num_frames == 1


def test_animate_renders_each_frame_and_follows_the_jaw(head_file, tmp_path):
    import imageio.v3 as iio

    from head360cli.fitting.pipeline import load_head_renderer

    r = load_head_renderer(head_file, samples=4, size=64)
    res = animate(r, _stream(6, rotation=True), tmp_path / "frames",
                  AnimateConfig(head_pose=True))
    assert res["frames"] == 6 and res["render_fps"] > 0
    frames = [iio.imread(p) for p in sorted((tmp_path / "frames").iterdir())]
    assert len(frames) == 6
    # the mouth opens and the head turns: frames differ, first from last the most
    d = [np.abs(f.astype(int) - frames[0]).mean() for f in frames]
    assert d[-1] > d[1] > 0
    with pytest.raises(BadInputError):
        animate(r, _stream(), None)


def test_a_60_fps_take_into_a_gif_is_resampled_to_a_rate_browsers_play(head_file,
                                                                        tmp_path):
    """A 60 fps take written as a GIF had frames of 10 ms, which browsers show for 100:
    animate now halves the rate (with a warning); an explicit rate over 50 is refused
    before any frame is rendered."""
    from PIL import Image

    from head360cli.fitting.pipeline import load_head_renderer

    r = load_head_renderer(head_file, samples=2, size=32)
    res = animate(r, _stream(12, fps=60.0), tmp_path / "a.gif", AnimateConfig(workers=1))
    assert (res["frames"], res["fps"]) == (6, 30.0)
    assert any("resampled to 30" in w for w in res["warnings"])
    with Image.open(tmp_path / "a.gif") as im:
        assert im.n_frames == 6
    with pytest.raises(BadInputError, match="at most 50 frames per second for a GIF"):
        animate(r, _stream(12, fps=60.0), tmp_path / "b.gif", AnimateConfig(fps=60.0))
    res = animate(r, _stream(4, fps=60.0), tmp_path / "c.mp4", AnimateConfig(workers=1))
    assert res["fps"] == 60.0 and "warnings" not in res  # an mp4 keeps the take's rate
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.gif", "c.mp4"]


def test_frames_do_not_accumulate(head_file):
    """The generator of frames keeps nothing: a long run allocates no more than a short
    one (tracemalloc over numpy and Python; torch's CPU tensors are freed per batch)."""
    import tracemalloc

    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.fitting.pipeline import load_head_renderer

    r = load_head_renderer(head_file, samples=2, size=32)
    k = view_intrinsics(32)

    def peak(n):
        cams = view_cameras(0.0, 0.0).expand(n, 4, 4)
        w = np.zeros((n, 52), np.float32)
        tracemalloc.start()
        for _ in r.frames(cams, w, k):
            pass
        p = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return p

    peak(2)
    assert peak(40) < 2 * peak(4) + 200_000


def test_cli_animate_reads_stdin_and_writes_a_gif(run_cli, head_file, tmp_path,
                                                   monkeypatch):
    from head360cli.io.arkit import write_arkit_csv

    buf = io.StringIO()
    write_arkit_csv(_stream(8), buf)
    monkeypatch.setattr("sys.stdin", io.StringIO(buf.getvalue()))
    out = tmp_path / "a.gif"
    r = run_cli("animate", head_file, "--arkit", "-", "-o", out, "--size", "64",
                "--samples", "2", "--fps", "10", "--json")
    assert r.code == 0, r.err
    import json

    res = json.loads(r.out)
    assert res["frames"] == 3 and out.is_file()  # 8 frames at 30 fps = 0.233 s -> 3 at 10


def test_cli_animate_reads_a_utf16_take_from_stdin(run_cli, head_file, tmp_path,
                                                   monkeypatch):
    """Standard input went to the CSV reader as text in the locale's encoding: a UTF-16
    take (Excel's "Unicode text") piped in failed on a header of NULs and escapes."""
    from head360cli.io.arkit import write_arkit_csv

    buf = io.StringIO()
    write_arkit_csv(_stream(8), buf)
    data = buf.getvalue().replace(",", "\t").encode("utf-16")
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(data)))
    out = tmp_path / "a.mp4"
    r = run_cli("animate", head_file, "--arkit", "-", "-o", out, "--size", "32",
                "--samples", "2", "--json", "--workers", "1")
    assert r.code == 0, r.err
    assert json.loads(r.out)["frames"] == 8 and out.is_file()


def test_cli_animate_and_render_read_pipes(run_cli, head_file, tmp_path, pipe):
    """``--arkit <(...)`` and a head given as ``<(...)``: a pipe is no file, has no size
    and is read once; it was refused as "does not exist"."""
    from head360cli.io.arkit import write_arkit_csv

    buf = io.StringIO()
    write_arkit_csv(_stream(8), buf)
    out = tmp_path / "a.gif"
    r = run_cli("animate", pipe(head_file.read_bytes(), "head"), "--arkit",
                pipe(buf.getvalue().encode(), "take"), "-o", out, "--size", "64",
                "--samples", "2", "--fps", "10", "--json")
    assert r.code == 0, r.err
    assert json.loads(r.out)["frames"] == 3 and out.is_file()
    r = run_cli("render", pipe(head_file.read_bytes(), "again"), "-o", tmp_path / "v.png",
                "--size", "64", "--samples", "2")
    assert r.code == 0, r.err
    assert (tmp_path / "v.png").stat().st_size > 0


def test_cli_animate_exact_decodes_every_point_and_agrees(run_cli, head_file, tmp_path):
    """With a still camera the deferred generator draws what no frame moves once, which
    changes nothing; --exact (which turns off a hex-plane generator's reuse of decoded
    points) gives the same frames, and neither reports a share of decoded points."""
    import imageio.v3 as iio

    from head360cli.io.arkit import write_arkit_csv

    write_arkit_csv(_stream(6), tmp_path / "s.csv")
    got = {}
    for name, extra in (("reuse", ()), ("exact", ("--exact",))):
        r = run_cli("animate", head_file, "--arkit", tmp_path / "s.csv", "-o",
                    tmp_path / name, "--size", "64", "--samples", "4", "--json", *extra)
        assert r.code == 0, r.err
        assert json.loads(r.out).get("decoded_share") is None
        got[name] = np.stack([iio.imread(p) for p in sorted((tmp_path / name).iterdir())])
    assert got["reuse"].shape == got["exact"].shape == (6, 64, 64, 3)
    assert np.abs(got["reuse"].astype(int) - got["exact"]).max() <= 1


def test_cli_animate_batch_renders_the_same_frames(run_cli, head_file, tmp_path):
    """--batch N renders N frames a generator call (a GPU's way; a small GPU takes fewer,
    a large one more): the frames agree with one-a-call rendering to a level (that one
    draws what no frame moves once), and an impossible batch is refused."""
    import imageio.v3 as iio

    from head360cli.io.arkit import write_arkit_csv

    write_arkit_csv(_stream(5), tmp_path / "s.csv")
    got = {}
    for name, extra in (("one", ()), ("three", ("--batch", "3"))):
        r = run_cli("animate", head_file, "--arkit", tmp_path / "s.csv", "-o",
                    tmp_path / name, "--size", "64", "--samples", "4", "--json", *extra)
        assert r.code == 0, r.err
        res = json.loads(r.out)
        assert res["workers"] == 1
        assert "gpu_peak_mib" not in res  # a GPU's memory peak, reported there only
        assert "decoded_share" not in res  # a hex-plane generator's reuse only
        got[name] = np.stack([iio.imread(p) for p in sorted((tmp_path / name).iterdir())])
    assert got["one"].shape == got["three"].shape == (5, 64, 64, 3)
    assert np.abs(got["one"].astype(int) - got["three"]).max() <= 1
    assert not np.array_equal(got["three"][0], got["three"][-1])  # the jaw opened
    r = run_cli("animate", head_file, "--arkit", tmp_path / "s.csv", "-o",
                tmp_path / "zero", "--batch", "0")
    assert r.code == 3 and "--batch between 1 and 1024, found 0" in r.err
    assert not (tmp_path / "zero").exists()
    r = run_cli("animate", head_file, "--arkit", tmp_path / "s.csv", "-o",
                tmp_path / "both", "--size", "64", "--samples", "4", "--batch", "3",
                "--workers", "2")
    assert r.code == 0, r.err  # one process batches: the workers are said to be unused
    assert "--workers 2 is not used with --batch above 1" in r.err
    # --device auto may be the CPU (it is here): no claim that the workers go unused
    r = run_cli("animate", head_file, "--arkit", tmp_path / "s.csv", "-o",
                tmp_path / "auto", "--size", "64", "--samples", "4", "--workers", "2",
                "--device", "auto")
    assert r.code == 0, r.err
    assert "not used" not in r.err


def test_cli_animate_out_of_memory_midway_leaves_no_video(run_cli, head_file, tmp_path,
                                                          monkeypatch):
    """A GPU that runs out of memory a few frames in (simulated: torch's error raised by
    the renderer after two frames): exit 8 with the --batch hint, and no video file."""
    from head360cli.io.arkit import write_arkit_csv
    from head360cli.model.head_render import HeadRenderer

    write_arkit_csv(_stream(6), tmp_path / "s.csv")
    real = HeadRenderer.frames

    def frames(self, *args, **kwargs):
        for i, f in enumerate(real(self, *args, **kwargs)):
            if i == 2:
                raise torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 2.00 GiB")
            yield f

    monkeypatch.setattr(HeadRenderer, "frames", frames)
    r = run_cli("animate", head_file, "--arkit", tmp_path / "s.csv", "-o",
                tmp_path / "a.mp4", "--size", "64", "--samples", "4", "--workers", "1")
    assert r.code == 8, r.err
    assert "CUDA out of memory" in r.err and "--batch" in r.err
    assert list(tmp_path.iterdir()) == [tmp_path / "s.csv"]


def test_cli_animate_errors(run_cli, head_file, tmp_path):
    r = run_cli("animate", head_file, "--arkit", tmp_path / "none.csv", "-o",
                tmp_path / "a.mp4")
    assert r.code == 3 and "does not exist" in r.err
    bad = tmp_path / "bad.csv"
    bad.write_text("foo,bar\n1,2\n")
    r = run_cli("animate", head_file, "--arkit", bad, "-o", tmp_path / "a.mp4")
    assert r.code == 3 and not (tmp_path / "a.mp4").exists()
    good = tmp_path / "good.csv"
    good.write_text("time,jawOpen\n0,0.1\n0.1,0.5\n")
    for args, says in ((("--pitch", "95"), "pitch within +-90 degrees, found 0.0, 95.0"),
                       (("--yaw", "nan"), "finite yaw"),
                       (("--start", "-1"), "--start in seconds from the stream's start"),
                       (("--end", "nan"), "--end in seconds"),
                       # 0 was taken for "not given" and rendered at 8 samples, where
                       # render refuses it
                       (("--samples", "0"), "--samples between 1 and 64, found 0")):
        r = run_cli("animate", head_file, "--arkit", good, "-o", tmp_path / "a.mp4", *args)
        assert r.code == 3 and says in r.err, (args, r.err)
        assert not (tmp_path / "a.mp4").exists()


def test_cli_animate_names_its_video_after_the_stream_and_can_drive_the_mean_head(
        run_cli, tmp_path, monkeypatch):
    """'head360 animate --arkit stream.csv', as the design card writes it, asked for a
    HEAD and for -o; it now drives the model's mean head into stream.mp4 (never over an
    existing file)."""
    import imageio_ffmpeg

    monkeypatch.chdir(tmp_path)
    (tmp_path / "stream.csv").write_text("time,jawOpen\n0,0.1\n0.05,0.9\n0.1,0.2\n")
    r = run_cli("animate", "--arkit", "stream.csv", "--size", "32", "--samples", "2")
    assert r.code == 0, r.err
    assert "no HEAD given: driving the model's mean head" in r.err
    reader = imageio_ffmpeg.read_frames(str(tmp_path / "stream.mp4"))
    assert next(reader)["size"] == (32, 32) and sum(1 for _ in reader) == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["stream.csv", "stream.mp4"]
    r = run_cli("animate", "--arkit", "stream.csv", "--size", "32")
    assert r.code == 3 and "the default stream.mp4 exists already" in r.err


def test_head_motion_is_rigid_about_the_pivot():
    from head360cli.drive.animate import head_motion

    m = head_motion(np.array([[0.3, -0.2, 0.1], [0.0, 0.0, 0.0]]))
    np.testing.assert_allclose(m[1], np.eye(4), atol=1e-12)
    r = m[0, :3, :3]
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    np.testing.assert_allclose(m[0, :3, :3] @ HEAD_PIVOT + m[0, :3, 3], HEAD_PIVOT,
                               atol=1e-12)


def test_cli_animate_stream_full_of_nan(run_cli, head_file, tmp_path):
    from head360cli.mesh.arkit52 import ARKIT52

    path = tmp_path / "nan.csv"
    path.write_text("time," + ",".join(ARKIT52) + "\n"
                    + "".join(f"{i / 30}," + ",".join(["nan"] * 52) + "\n" for i in range(4)))
    r = run_cli("animate", head_file, "--arkit", path, "-o", tmp_path / "h.gif",
                "--size", "32", "--samples", "2")
    assert r.code == 0 and "held the previous frame's value for 208" in r.err
    r = run_cli("animate", head_file, "--arkit", path, "-o", tmp_path / "e.gif",
                "--on-bad", "error")
    assert r.code == 3 and "line 2" in r.err and not (tmp_path / "e.gif").exists()


def test_extreme_expression_and_vertical_views_stay_finite(head_file):
    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.fitting.pipeline import load_head_renderer

    r = load_head_renderer(head_file, samples=2, size=32)
    cams = view_cameras(np.array([0.0, 0.0, 0.0]), np.array([90.0, -90.0, 0.0]))
    w = np.ones((3, 52))
    img = r.render(cams, view_intrinsics(32), w)
    assert torch.isfinite(img).all() and (img < 0.9).any(dim=1).flatten(1).any(1).all()


@pytest.mark.parametrize(("field", "value", "says"), [
    ("smooth", -1.0, "smooth >= 0 seconds, found -1.0"),
    ("smooth", float("nan"), "smooth >= 0 seconds, found nan"),
    ("fps", float("nan"), "fps from 1 to 240 or None, found nan"),
    ("fps", 0.5, "fps from 1 to 240 or None, found 0.5"),
    ("start", -1.0, "start >= 0 seconds or None, found -1.0"),
    ("end", float("inf"), "end >= 0 seconds or None, found inf"),
    ("pitch", 100.0, "pitch within [+]-90 degrees, found 0.0, 100.0"),
    ("batch", 0, "batch >= 1 or None, found 0"),
    ("workers", -1, "workers >= 1 or None, found -1"),
])
def test_animate_config_refuses_what_no_take_renders_with(field, value, says):
    """From Python, smooth=-1 or NaN rendered unsmoothed, start=-1 from the start and
    workers=0 with the automatic count, where the CLI refuses each option."""
    with pytest.raises(BadInputError, match=says):
        AnimateConfig(**{field: value})
    AnimateConfig(fps=30, start=0, end=1.5, smooth=0.05, yaw=-720.0, pitch=-90, batch=np.int64(2),
                  workers=1)

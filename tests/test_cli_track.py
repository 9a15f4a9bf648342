"""``head360 track`` and ``head360 animate --video``: what they write, the inputs they
refuse, and the round trip animate -> track -> animate -> track."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.perception.test_track import _astronaut_frames


@pytest.fixture(scope="module")
def face_frames(tmp_path_factory):
    """A folder of 8 frames of the astronaut moving about (320 x 240)."""
    import cv2

    folder = tmp_path_factory.mktemp("face")
    for i, frame in enumerate(_astronaut_frames(8)):
        cv2.imwrite(str(folder / f"{i:04d}.png"), frame[:, :, ::-1])
    return folder


@pytest.mark.parametrize(("fmt", "kind"), [("livelinkface", "livelinkface"),
                                           ("mediapipe", "mediapipe"), ("generic", "arkit")])
def test_track_writes_a_stream_inspect_reads(run_cli, face_frames, tmp_path, fmt, kind):
    out = tmp_path / "take.csv"
    r = run_cli("--json", "track", face_frames, "-o", out, "--format", fmt, "--fps", "25")
    assert r.code == 0, r.err
    summary = json.loads(r.out)
    assert summary["frames"] == summary["frames_with_face"] == 8
    assert summary["detections"] == 1 and summary["tracking_fps"] > 0
    r = run_cli("--json", "inspect", out)
    assert r.code == 0, r.err
    info = json.loads(r.out)
    assert info["frames"] == 8 and info["format"] == kind
    assert info["fps"] == pytest.approx(25.0, rel=1e-3)
    from head360cli.io.arkit import read_arkit_csv
    from head360cli.mesh.arkit52 import INDEX

    stream = read_arkit_csv(out)
    assert stream.weights[:, INDEX["mouthSmileLeft"]].min() > 0.3  # the astronaut smiles
    assert stream.head_rotation is not None and np.abs(stream.head_rotation).max() < 0.5


def test_track_writes_a_stream_to_standard_output(run_cli, face_frames):
    """``-o -``: the CSV on standard output (to pipe into ``animate --arkit -``), the
    summary on standard error, JSON there too under --json."""
    import io

    from head360cli.io.arkit import read_arkit_csv

    r = run_cli("track", face_frames, "-o", "-", "--fps", "25")
    assert r.code == 0, r.err
    stream = read_arkit_csv(io.StringIO(r.out))
    assert stream.num_frames == 8 and stream.warnings == []
    assert "tracked 8 of 8 frames" in r.err and "standard output" in r.err
    r = run_cli("--json", "track", face_frames, "-o", "-", "--fps", "25", "--format",
                "generic")
    assert r.code == 0 and r.out.startswith("time,")
    assert json.loads(r.err.strip().splitlines()[-1])["out"] == "-"


def test_track_refuses_inputs_that_hold_no_face_or_no_video(run_cli, tmp_path):
    import cv2

    out = tmp_path / "take.csv"
    out.write_text("the user's own file\n")
    blank = tmp_path / "blank"
    blank.mkdir()
    for i in range(3):
        cv2.imwrite(str(blank / f"{i}.png"), np.full((120, 160, 3), 200, np.uint8))
    r = run_cli("track", blank, "-o", out)
    assert r.code == 4 and "found none in the 3 frames" in r.err
    assert len(r.err.strip().splitlines()) == 1
    (tmp_path / "text.mp4").write_bytes(b"no video here " * 50)
    r = run_cli("track", tmp_path / "text.mp4", "-o", out)
    assert r.code == 5 and "cannot open" in r.err
    cv2.imwrite(str(blank / "3.png"), np.full((121, 160, 3), 200, np.uint8))
    r = run_cli("track", blank, "-o", out, "--on-bad", "skip")
    assert r.code in (3, 4)  # three blank frames first, then the odd size or no face
    r = run_cli("track", blank, "-o", tmp_path / "take.txt.gz")
    assert r.code == 3 and "expected an output ending in .csv" in r.err
    assert out.read_text() == "the user's own file\n"  # never half-written or replaced
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blank", "take.csv", "text.mp4"]


def test_animate_video_puts_the_input_beside_the_head(run_cli, head_file, face_frames,
                                                     tmp_path):
    import cv2

    out = tmp_path / "both.mp4"
    r = run_cli("--json", "animate", head_file, "--video", face_frames, "--fps", "10",
                "--side-by-side", "-o", out)
    assert r.code == 0, r.err
    res = json.loads(r.out)
    assert res["frames"] == res["frames_with_face"] == 8 and res["fps"] == 10.0
    cap = cv2.VideoCapture(str(out))
    ok, frame = cap.read()
    assert ok and frame.shape[0] == 256 and frame.shape[1] == 342 + 256  # 320x240 -> 342
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 8
    r = run_cli("animate", head_file, "--video", face_frames, "--arkit", "x.csv", "-o", out)
    assert r.code == 3 and "found both" in r.err
    r = run_cli("animate", head_file, "-o", out)
    assert r.code == 3 and "found neither" in r.err
    r = run_cli("animate", head_file, "--video", face_frames, "--mesh-sequence",
                tmp_path / "m")
    assert r.code == 3 and "--mesh-sequence" in r.err
    blank = tmp_path / "blank"
    blank.mkdir()
    for i in range(3):
        cv2.imwrite(str(blank / f"{i}.png"), np.full((120, 160, 3), 200, np.uint8))
    r = run_cli("animate", head_file, "--video", blank, "-o", tmp_path / "none.mp4")
    assert r.code == 4 and "found none in the 3 frames" in r.err
    assert not (tmp_path / "none.mp4").exists()


@pytest.mark.slow
def test_animate_track_animate_again_gives_the_same_weights(run_cli, head_file, tmp_path):
    """A take with jawOpen, blinks and a turning head animates a head; its frames tracked
    give weights W1, which follow the take (r 0.95 for jawOpen, 0.97 and 0.99 for the
    blinks and 1.00 for the yaw when written). W1 animates the head again and tracking
    that video gives W2: within 0.2 of W1 on average over the shapes the take moves and
    0.45 at the 95th percentile (0.13 and 0.29 when written: rendering and reading back is
    not the identity, the generator's expressions read weaker than they are driven), and
    the head's yaw and roll within 5 degrees, its pitch within 6.5."""
    from head360cli.io.arkit import ArkitStream, read_arkit_csv, write_arkit_csv
    from head360cli.mesh.arkit52 import INDEX

    n, fps = 24, 16.0
    t = np.arange(n) / fps
    w = np.zeros((n, 52), np.float32)
    w[:, INDEX["jawOpen"]] = 0.4 + 0.35 * np.sin(2 * np.pi * t / 1.5)
    w[:, INDEX["eyeBlinkLeft"]] = w[:, INDEX["eyeBlinkRight"]] = (np.abs(t - 0.75) < 0.1)
    rot = np.zeros((n, 3), np.float32)
    rot[:, 0] = 0.25 * np.sin(2 * np.pi * t / 1.5)
    write_arkit_csv(ArkitStream(w, t, fps, head_rotation=rot), tmp_path / "s0.csv")
    steps = [("animate", head_file, "--arkit", tmp_path / "s0.csv", "--head-pose", "-o",
              tmp_path / "a.mp4"),
             ("track", tmp_path / "a.mp4", "-o", tmp_path / "w1.csv", "--smooth", "0"),
             ("animate", head_file, "--arkit", tmp_path / "w1.csv", "--head-pose", "-o",
              tmp_path / "b.mp4"),
             ("track", tmp_path / "b.mp4", "-o", tmp_path / "w2.csv", "--smooth", "0")]
    for step in steps:
        r = run_cli("--quiet", *step)
        assert r.code == 0, (step[0], r.err)
    w1, w2 = read_arkit_csv(tmp_path / "w1.csv"), read_arkit_csv(tmp_path / "w2.csv")
    assert w1.num_frames == w2.num_frames == n
    moved = [INDEX[k] for k in ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight")]
    for j in moved:
        assert np.corrcoef(w[:, j], w1.weights[:, j])[0, 1] > 0.8
    assert np.corrcoef(rot[:, 0], w1.head_rotation[:, 0])[0, 1] > 0.95  # the same sign
    diff = np.abs(w2.weights[:, moved] - w1.weights[:, moved])
    assert diff.mean() < 0.2 and np.percentile(diff, 95) < 0.45, diff.mean(0)
    turn = np.degrees(np.abs(w2.head_rotation - w1.head_rotation)).mean(0)
    # yaw and roll within 5 degrees (1.8 and 1.1); the pitch is read about 5 degrees
    # apart (4.6 with stepped hairlines, 5.0 with soft ones): the tracker reads head360's
    # heads as seen from above by about that much (bench synth: +5.3 degrees), once per pass
    assert turn[0] < 5.0 and turn[2] < 5.0 and turn[1] < 6.5, turn


def test_track_reads_a_video_on_standard_input(face_frames, tmp_path):
    import os
    import subprocess
    import sys

    import cv2

    from head360cli.io.video import VideoWriter

    clip = tmp_path / "clip.mp4"
    with VideoWriter(clip, fps=25.0) as writer:
        for p in sorted(face_frames.glob("*.png")):
            writer.write(cv2.imread(str(p))[:, :, ::-1])
    out = tmp_path / "take.csv"
    spool = tmp_path / "spool"  # where the copy of standard input goes
    spool.mkdir()
    env = {**os.environ, "TMPDIR": str(spool)}
    r = subprocess.run([sys.executable, "-m", "head360cli", "track", "-", "-o", str(out),
                        "--json", "--quiet"], input=clip.read_bytes(), capture_output=True,
                       timeout=120, env=env)
    assert r.returncode == 0, r.stderr.decode()
    summary = json.loads(r.stdout)
    assert summary["input"] == "standard input" and summary["frames_with_face"] == 8
    assert summary["fps"] == pytest.approx(25.0)
    assert not list(spool.iterdir())  # no temporary copy left behind


def test_a_face_number_beyond_the_faces_found_says_how_many_there_were(run_cli, face_frames,
                                                                       tmp_path, head_file):
    """--face 3 on a one-face clip: not "found none" but how many faces there were, in
    track and in animate --video (which takes --face too)."""
    r = run_cli("track", face_frames, "-o", tmp_path / "t.csv", "--face", "3")
    assert r.code == 4 and "found at most 1 face in a frame" in r.err, r.err
    assert "--face counts from 0" in r.err and len(r.err.strip().splitlines()) == 1
    r = run_cli("animate", head_file, "--video", face_frames, "--face", "3", "--fps", "10",
                "-o", tmp_path / "a.mp4")
    assert r.code == 4 and "found at most 1 face in a frame" in r.err, r.err
    assert not (tmp_path / "a.mp4").exists()


def test_a_broken_or_empty_video_is_one_line_without_ffmpegs_log(run_cli, tmp_path):
    """A video cut short (no 'moov atom') gives head360's line alone, not FFmpeg's log
    before it; an empty file says it is empty. --debug lets FFmpeg's lines through."""
    import subprocess
    import sys

    import imageio.v3 as iio

    whole = tmp_path / "whole.mp4"
    iio.imwrite(whole, np.random.default_rng(0).integers(0, 255, (10, 64, 64, 3), np.uint8),
                fps=10)
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(whole.read_bytes()[:whole.stat().st_size // 2])
    (tmp_path / "empty.mp4").write_bytes(b"")
    # a child process: FFmpeg writes to the process's own stderr, past pytest's capture
    import os

    from head360cli.io.frames import FFMPEG_LOG

    env = {k: v for k, v in os.environ.items() if k != FFMPEG_LOG}
    run = [sys.executable, "-m", "head360cli", "track"]
    got = subprocess.run([*run, str(cut), "-o", str(tmp_path / "t.csv")],
                         capture_output=True, text=True, timeout=120, env=env)
    assert got.returncode == 5 and got.stderr.count("\n") == 1, got.stderr
    assert "moov" not in got.stderr and got.stderr.startswith("head360: error:")
    got = subprocess.run([*run, str(tmp_path / "empty.mp4"), "-o", str(tmp_path / "t.csv")],
                         capture_output=True, text=True, timeout=120, env=env)
    assert got.returncode == 5 and "an empty file" in got.stderr, got.stderr
    assert got.stderr.count("\n") == 1
    got = subprocess.run([*run, str(cut), "-o", str(tmp_path / "t.csv"), "--debug"],
                         capture_output=True, text=True, timeout=120, env=env)
    # (OpenCV's logger, which carries FFmpeg's lines once their level is set, writes
    # them to standard output)
    assert "moov atom not found" in got.stdout + got.stderr


def test_inspect_tells_what_a_video_holds(run_cli, face_frames, tmp_path):
    """Frames, rate, size, duration, the rotation its metadata asks for, and the faces in
    its first frame (the README says inspect tells what any input holds)."""
    import imageio.v3 as iio

    clip = tmp_path / "clip.mp4"
    iio.imwrite(clip, np.stack([iio.imread(p) for p in sorted(face_frames.iterdir())]),
                fps=25)
    r = run_cli("--json", "inspect", clip)
    assert r.code == 0, r.err
    info = json.loads(r.out)
    assert info["kind"] == "video" and info["frames"] == 8 and info["fps"] == 25.0
    assert (info["width"], info["height"]) == (320, 240) and info["duration_s"] == 0.32
    assert info["rotation_deg"] == 0 and info["faces_in_frame_0"] == 1
    r = run_cli("inspect", clip)
    assert "8 at 25 fps (0.32 s)" in r.out and "1 face(s) found" in r.out


def test_animate_video_skipping_faceless_frames_keeps_the_timing(run_cli, head_file,
                                                                face_frames, tmp_path):
    """--on-bad skip: a frame without a face is written blank, not left out, so the
    video lines up with the clip beside it (2.00 s came out of a 3.00 s clip)."""
    import shutil

    import cv2
    import imageio.v3 as iio

    clip = tmp_path / "clip"
    clip.mkdir()
    for i in range(3):
        cv2.imwrite(str(clip / f"{i:04d}.png"), np.full((240, 320, 3), 200, np.uint8))
    for i, p in enumerate(sorted(face_frames.iterdir())):
        shutil.copy(p, clip / f"{i + 3:04d}.png")
    out = tmp_path / "both"
    r = run_cli("--json", "animate", head_file, "--video", clip, "--fps", "10",
                "--on-bad", "skip", "--side-by-side", "--size", "64", "-o", out)
    assert r.code == 0, r.err
    res = json.loads(r.out)
    assert res["frames"] == 11 and res["frames_skipped"] == 3
    assert res["duration_s"] == pytest.approx(1.1)
    frames = [iio.imread(p) for p in sorted(out.iterdir())]
    assert len(frames) == 11
    head = [f[:, -64:] for f in frames]
    assert all(h.min() == 255 for h in head[:3])  # blank where the clip has no face
    assert all(h.min() < 200 for h in head[3:])


def test_stills_and_cuts_are_not_smoothed_together(run_cli, face_frames, tmp_path):
    """A folder of frames is one shot unless --stills (said in a warning); with --stills
    every frame is read on its own, as with no filter at all; a jump of the face (a cut
    to another framing) starts the filter again; the summary counts the cuts."""
    import csv
    import shutil

    import cv2

    def smiles(path):
        return [float(r["mouthSmileLeft"]) for r in csv.DictReader(open(path))]

    out = tmp_path / "t.csv"
    r = run_cli("--json", "track", face_frames, "-o", out, "--format", "generic")
    assert r.code == 0 and json.loads(r.out)["cuts"] == 0
    assert "give --stills for separate photos" in r.err
    r = run_cli("--json", "track", face_frames, "-o", out, "--format", "generic", "--stills")
    assert r.code == 0 and json.loads(r.out)["cuts"] == 7 and "--stills" not in r.err
    stills = smiles(out)
    run_cli("track", face_frames, "-o", out, "--format", "generic", "--smooth", "0")
    # (each still is found afresh, not followed from the last frame's crop: the mesh
    # reads its frame from a slightly other crop, 0.034 apart at most here)
    assert stills == pytest.approx(smiles(out), abs=0.05)
    # the same frames, the second half zoomed out to half size: a cut at frame 4
    cut = tmp_path / "cut"
    cut.mkdir()
    for i, p in enumerate(sorted(face_frames.iterdir())):
        if i < 4:
            shutil.copy(p, cut / p.name)
        else:
            img = cv2.imread(str(p))
            small = cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2))
            canvas = np.full_like(img, 128)
            canvas[:small.shape[0], :small.shape[1]] = small
            cv2.imwrite(str(cut / p.name), canvas)
    r = run_cli("--json", "track", cut, "-o", out)
    assert r.code == 0 and json.loads(r.out)["cuts"] == 1, r.out

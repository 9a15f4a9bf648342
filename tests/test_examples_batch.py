"""The batch scripts in examples/batch: parallel runs that survive a bad input and say
how many failed, and the CSV collector."""

from __future__ import annotations

import csv
import io
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import REPO

pytestmark = pytest.mark.skipif(shutil.which("bash") is None or shutil.which("xargs") is None,
                                reason="needs bash and xargs")


def _env():
    env = dict(os.environ)
    env["PATH"] = os.path.dirname(sys.executable) + os.pathsep + env.get("PATH", "")
    return env


def _collect(out):
    p = subprocess.run([sys.executable, str(REPO / "examples/batch/collect.py"), str(out)],
                       capture_output=True, text=True, check=True)
    return list(csv.DictReader(io.StringIO(p.stdout)))


@pytest.mark.slow
def test_fit_folder_keeps_going_and_counts_failures(tmp_path):
    from PIL import Image
    from skimage import data

    photos = tmp_path / "photos"
    photos.mkdir()
    Image.fromarray(data.astronaut()).save(photos / "astronaut.png")
    (photos / "broken.jpg").write_text("not a photo")
    Image.new("RGB", (64, 64), "white").save(photos / "blank.png")  # no face
    # two photos with one name: each once wrote over the other's outputs
    Image.new("RGB", (64, 64), "grey").save(photos / "twin.png")
    (photos / "twin.jpg").write_text("not a photo either")
    # the other formats head360 reads (the script once listed only jpg, jpeg and png)
    Image.new("RGB", (64, 64), "white").save(photos / "wall.webp")
    Image.new("RGB", (64, 64), "white").save(photos / "scan.tif")
    (photos / "IMG_0001.HEIC").write_text("not a photo")
    (photos / "notes.txt").write_text("not a photo, and not listed")
    out = tmp_path / "out"
    p = subprocess.run(["bash", str(REPO / "examples/batch/fit_folder.sh"), str(photos),
                        str(out), "2"], capture_output=True, text=True, env=_env())
    assert p.returncode == 7, p.stderr  # seven of eight failed
    assert "ran 8 photo(s), 7 failed" in p.stderr
    assert (out / "astronaut.h360").is_file()
    rows = {r["name"]: r for r in _collect(out)}
    assert rows["astronaut"]["ok"] == "True" and rows["astronaut"]["hair_style"]
    assert rows["broken"]["ok"] == "False" and rows["broken"]["error_type"]
    assert rows["blank"]["error_type"] == "NoFaceError"
    assert rows["twin_png"]["error_type"] == "NoFaceError"
    assert rows["twin_jpg"]["error_type"] == "FileFormatError"
    assert rows["wall"]["error_type"] == rows["scan"]["error_type"] == "NoFaceError"
    assert rows["IMG_0001"]["error_type"] == "FileFormatError"
    assert sorted((out / "failed.txt").read_text().split()) == sorted(
        str(photos / n) for n in ("blank.png", "broken.jpg", "twin.png", "twin.jpg",
                                  "wall.webp", "scan.tif", "IMG_0001.HEIC"))


@pytest.mark.slow
def test_animate_heads_one_stream_many_heads(tmp_path, head_file):
    heads = tmp_path / "heads"
    heads.mkdir()
    shutil.copy(head_file, heads / "a.h360")
    shutil.copy(head_file, heads / "b.h360")
    (heads / "bad.h360").write_bytes(b"not a head")
    out = tmp_path / "out"
    p = subprocess.run(["bash", str(REPO / "examples/batch/animate_heads.sh"), str(heads),
                        str(REPO / "examples/smile_blink_livelinkface.csv"), str(out), "2",
                        "--", "--end", "0.11", "--size", "32", "--samples", "2"],
                       capture_output=True, text=True, env=_env())
    assert p.returncode == 1, p.stderr
    assert "ran 3 head(s), 1 failed" in p.stderr
    assert (out / "a.mp4").is_file() and (out / "b.mp4").is_file()
    rows = {r["name"]: r for r in _collect(out)}
    assert rows["a"]["ok"] == "True" and rows["a"]["frames"] == "7"
    assert rows["bad"]["ok"] == "False" and rows["bad"]["error_type"] == "FileFormatError"


def test_scripts_explain_their_usage():
    for script in ("fit_folder.sh", "animate_heads.sh"):
        p = subprocess.run(["bash", str(REPO / "examples/batch" / script)],
                           capture_output=True, text=True)
        assert p.returncode == 2 and "usage:" in p.stderr
    p = subprocess.run([sys.executable, str(REPO / "examples/batch/collect.py")],
                       capture_output=True, text=True)
    assert p.returncode == 2 and "usage:" in p.stderr


def test_side_by_side_times_a_fit_alone_and_several_at_once(tmp_path):
    """The script that measures fits side by side: one alone, then two at once, each
    with the options given after ``--``, every time printed, nothing left behind. A
    stand-in ``head360`` that writes its output and logs its arguments takes the fits'
    place: the script's part is the timing and the bookkeeping (a real fit's own outputs
    are checked by the fit's tests, and the folder script's test runs one)."""
    import re

    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    log = tmp_path / "calls.log"
    stand_in = bin_dir / "head360"
    stand_in.write_text("#!/usr/bin/env bash\n"
                        f"echo \"$*\" >> {log}\n"
                        "while [ $# -gt 0 ]; do [ \"$1\" = -o ] && : > \"$2\"; shift; done\n"
                        "sleep 0.2\n"
                        "echo '{\"ok\": true}'\n")
    stand_in.chmod(0o755)
    run_in = tmp_path / "run"
    run_in.mkdir()
    photo = run_in / "astronaut.png"
    photo.write_bytes(b"a photo")
    env = _env()
    env["PATH"] = str(bin_dir) + os.pathsep + env["PATH"]
    p = subprocess.run(["bash", str(REPO / "examples/batch/side_by_side.sh"), str(photo), "2",
                        "--", "--threads", "1"], capture_output=True, text=True, env=env,
                       cwd=run_in, timeout=60)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert re.fullmatch(r"alone: \d+\.\d s", lines[0]), lines
    assert [re.sub(r"[\d.]+ s$", "T", line) for line in lines[1:3]] == [
        "side by side 1 of 2: T", "side by side 2 of 2: T"]
    assert re.fullmatch(r"2 fits side by side: \d+\.\d s in all", lines[3]), lines
    calls = log.read_text().splitlines()
    assert len(calls) == 3
    assert all(re.fullmatch(rf"--threads 1 fit {re.escape(str(photo))} -o \S+\.h360 --quiet "
                            r"--json", c) for c in calls), calls
    assert len({c.split()[5] for c in calls}) == 3  # each fit its own output
    assert sorted(q.name for q in run_in.iterdir()) == ["astronaut.png"]
    assert not any(Path(c.split()[5]).parent.exists() for c in calls)  # its folder removed

"""Inputs that are pipes: ``is_pipe``, ``existing`` and ``readable``, and each reader
given a pipe."""

from __future__ import annotations

import io
import os

import numpy as np
import pytest
from PIL import Image

from head360cli.errors import BadInputError, FileFormatError
from head360cli.io.arkit import read_arkit_csv
from head360cli.io.headfile import HeadFile, read_head, write_head
from head360cli.io.images import describe_image, load_image
from head360cli.io.sources import NamedBytes, existing, is_pipe, readable
from head360cli.mesh.arkit52 import INDEX


def _png(pixels: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(pixels).save(buf, format="PNG")
    return buf.getvalue()


def test_is_pipe_tells_pipes_from_files_and_folders(tmp_path, pipe):
    f = tmp_path / "f.txt"
    f.write_text("x")
    p = pipe(b"x")
    assert is_pipe(p)
    assert not is_pipe(f) and not is_pipe(tmp_path) and not is_pipe(tmp_path / "missing")
    assert p.read_bytes() == b"x"  # and it reads like one (the feeder finishes)


def test_readable_reads_a_pipe_once_and_passes_files_on(tmp_path, pipe):
    f = tmp_path / "f.bin"
    f.write_bytes(b"abc")
    assert readable(f) == (f, 3)
    source, size = readable(pipe(b"hello pipe"))
    assert isinstance(source, NamedBytes) and size == 10
    assert source.read() == b"hello pipe" and source.name.endswith("fifo")
    again = readable(source)  # what is read already is not read again
    assert again[0] is source and again[1] == 10


def test_images_load_from_a_pipe_like_the_file(tmp_path, pipe):
    rng = np.random.default_rng(0)
    pixels = rng.integers(0, 256, (24, 40, 3), dtype=np.uint8)
    data = _png(pixels)
    got = load_image(pipe(data, "photo"))
    np.testing.assert_array_equal(got.pixels, pixels)
    d = describe_image(pipe(data, "again"))
    assert (d["width"], d["height"], d["bytes"]) == (40, 24, len(data))
    assert d["path"].endswith("again")


def test_an_empty_pipe_is_an_empty_image(pipe):
    with pytest.raises(FileFormatError, match="found an empty file"):
        load_image(pipe(b""))


def test_head_files_and_streams_read_from_pipes(tmp_path, pipe):
    head = write_head(HeadFile(arrays={"shape": np.arange(5, dtype=np.float32)}),
                      tmp_path / "h.h360")
    got = read_head(pipe(head.read_bytes()))
    np.testing.assert_array_equal(got.arrays["shape"], np.arange(5, dtype=np.float32))
    stream = read_arkit_csv(pipe(b"time,jawOpen\n0,0.25\n0.1,0.75\n", "take"))
    assert stream.num_frames == 2
    np.testing.assert_allclose(stream.weights[:, INDEX["jawOpen"]], [0.25, 0.75])


def test_existing_says_what_is_missing_or_a_folder(tmp_path):
    f = tmp_path / "f.png"
    f.write_bytes(b"x")
    assert existing(str(f), "an image file") == f
    with pytest.raises(BadInputError, match=r"no such file: '.*nope\.png'"):
        existing(tmp_path / "nope.png", "an image file")
    with pytest.raises(BadInputError, match="expected a head file, found a folder"):
        existing(tmp_path, "a head file")
    buf = NamedBytes(b"abc", "pipe")
    assert existing(buf, "anything") is buf


@pytest.mark.skipif(not hasattr(os, "symlink"), reason="symbolic links")
def test_a_broken_symbolic_link_says_why_it_is_missing(tmp_path, run_cli, head_file):
    """``ls`` lists a dangling link or a loop of links, and "no such file" alone read as
    a wrong name."""
    (tmp_path / "photo.jpg").symlink_to(tmp_path / "moved.jpg")
    (tmp_path / "loop.csv").symlink_to(tmp_path / "loop.csv")
    with pytest.raises(BadInputError, match=r"no such file: '.*photo\.jpg' \(a symbolic "
                                            r"link to '.*moved\.jpg', which does not "
                                            r"exist\)$"):
        existing(tmp_path / "photo.jpg", "an image file")
    with pytest.raises(BadInputError, match=r"\(a loop of symbolic links\)$"):
        existing(tmp_path / "loop.csv", "a stream")
    r = run_cli("animate", head_file, "--arkit", tmp_path / "loop.csv", "-o",
                tmp_path / "a.mp4")
    assert r.code == 3 and r.err.strip().endswith("does not exist (a loop of symbolic "
                                                  "links)"), r.err


def test_input_stem_names_outputs_after_the_input(tmp_path, pipe):
    from head360cli.io.sources import input_stem

    f = tmp_path / "me.jpg"
    f.write_bytes(b"x")
    assert input_stem(f) == "me"
    named = pipe(b"x", "take.csv")  # a named pipe keeps its name
    assert input_stem(named) == "take"
    assert named.read_bytes() == b"x"
    anonymous = pipe(b"y", "63")  # as /dev/fd/63 from <(...)
    assert input_stem(anonymous) == "pipe"
    assert anonymous.read_bytes() == b"y"


def test_the_exif_focal_length_comes_with_the_pixels_even_from_a_pipe(tmp_path, pipe):
    """The fit's focal length is read from the image as it is loaded: a second opening of
    a pipe finds it empty (the EXIF focal was lost) or waits for a writer forever."""
    img = Image.fromarray(np.zeros((16, 24, 3), np.uint8))
    exif = img.getexif()
    exif.get_ifd(0x8769)[0xA405] = 52  # FocalLengthIn35mmFilm
    buf = io.BytesIO()
    img.save(buf, format="JPEG", exif=exif)
    f = tmp_path / "lens.jpg"
    f.write_bytes(buf.getvalue())
    assert load_image(f).focal_35mm == 52.0
    assert load_image(pipe(buf.getvalue(), "lens")).focal_35mm == 52.0
    assert load_image(pipe(_png(np.zeros((4, 4, 3), np.uint8)), "plain")).focal_35mm is None


def test_inputs_read_whole_are_bounded(tmp_path, pipe, monkeypatch, run_cli, head_file):
    """``--arkit /dev/zero``, or an endless pipe, was read until the memory ran out (the
    process was killed); a CSV larger than the bound is refused by its size, unread."""
    from head360cli.io import sources

    monkeypatch.setattr(sources, "MAX_READ_BYTES", 1000)
    big = tmp_path / "big.csv"
    big.write_text("time,jawOpen\n" + "0.1,0.5\n" * 200)
    for source in (big, pipe(big.read_bytes(), "fifo.csv"), "/dev/zero"):
        with pytest.raises(BadInputError, match=r"at most 9\.3\d*e-07 GiB .* found more"):
            read_arkit_csv(source)
    with pytest.raises(BadInputError, match="found more"):
        readable("/dev/zero")
    r = run_cli("animate", head_file, "--arkit", "/dev/zero", "-o", tmp_path / "x.mp4")
    assert r.code == 3 and "read whole into memory" in r.err, r.err
    r = run_cli("inspect", "/dev/zero")
    assert r.code == 3 and "read whole into memory" in r.err, r.err
    small = tmp_path / "small.csv"
    small.write_text("time,jawOpen\n0,0.5\n0.1,0.6\n")
    assert read_arkit_csv(small).weights[1, INDEX["jawOpen"]] == pytest.approx(0.6)

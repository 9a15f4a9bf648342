"""Random heads: reproducible, valid head files, spread controls variety."""

from __future__ import annotations

import numpy as np
import pytest

from head360cli.drive.sample import sample_heads
from head360cli.errors import BadInputError


@pytest.mark.slow
def test_samples_are_reproducible_and_varied():
    a = sample_heads(3, seed=4)
    b = sample_heads(3, seed=4)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.arrays["shape"], y.arrays["shape"])
        np.testing.assert_array_equal(x.arrays["texture"], y.arrays["texture"])
    assert np.abs(a[0].arrays["shape"] - a[1].arrays["shape"]).max() > 0.01
    mean = sample_heads(2, seed=1, scale=0.0, bald=True)
    np.testing.assert_allclose(mean[0].arrays["shape"], mean[1].arrays["shape"])
    assert int(mean[0].arrays["hair_style"]) == 0
    for bad in ({"n": 0}, {"n": 1, "scale": -1.0}):
        with pytest.raises(BadInputError):
            sample_heads(**bad)


@pytest.mark.slow
def test_cli_sample_writes_heads_and_a_sheet(run_cli, tmp_path):
    from head360cli.io.headfile import read_head

    r = run_cli("sample", "-n", "2", "--seed", "3", "-o", tmp_path / "s")
    assert r.code == 0, r.err
    heads = sorted((tmp_path / "s").glob("*.h360"))
    assert len(heads) == 2 and (tmp_path / "s" / "samples.png").is_file()
    assert read_head(heads[0]).arrays["texture"].ndim == 3


@pytest.mark.slow
def test_a_full_disk_at_the_picture_leaves_no_sampled_heads(run_cli, tmp_path, monkeypatch):
    """The heads were renamed into place before their picture was written, so a full disk
    at the picture left them without it (or beside an earlier run's)."""
    import errno
    import os

    from PIL import Image

    real = Image.Image.save

    def full_at_the_picture(self, fp, *args, **kwargs):
        if str(fp).endswith(".png"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(fp))
        return real(self, fp, *args, **kwargs)

    monkeypatch.setattr(Image.Image, "save", full_at_the_picture)
    for out in (tmp_path / "s", tmp_path / "one.h360"):
        r = run_cli("sample", "-n", "2" if out.suffix == "" else "1", "-o", out)
        assert r.code == 3 and "No space left" in r.err, r.err
    assert [p for p in tmp_path.rglob("*") if p.is_file()] == []


def test_cli_sample_to_one_head_file_and_its_checks(run_cli, tmp_path):
    from PIL import Image

    from head360cli.io.headfile import read_head

    out = tmp_path / "one.h360"
    r = run_cli("sample", "--seed", "3", "-o", out)
    assert r.code == 0, r.err
    assert out.is_file() and read_head(out).arrays["texture"].ndim == 3
    assert Image.open(tmp_path / "one.png").size == (256, 256)
    assert not list(tmp_path.glob("sample_*"))  # no folder of heads besides
    # Several heads into one file, a folder named like a head file, a file as the folder.
    (tmp_path / "d.h360").mkdir()
    (tmp_path / "f").write_text("keep me")
    for args, found in ((("-n", "2", "-o", tmp_path / "two.h360"), "found -n 2"),
                        (("-o", tmp_path / "d.h360"), "found a folder"),
                        (("-o", tmp_path / "f"), "found a file")):
        r = run_cli("sample", *args)
        assert r.code == 3 and found in r.err, (args, r.err)
    assert not (tmp_path / "two.h360").exists()
    assert (tmp_path / "f").read_text() == "keep me"


def test_cli_sample_does_not_write_its_picture_over_a_photo(run_cli, tmp_path):
    """``sample -o me.h360`` wrote its picture as me.png over the user's photo of that
    name; a picture an earlier sample wrote is replaced, as before."""
    from PIL import Image

    photo = tmp_path / "me.png"
    Image.new("RGB", (8, 8), (200, 150, 100)).save(photo)
    before = photo.read_bytes()
    r = run_cli("sample", "-o", tmp_path / "me.h360", "--no-lid-fit")
    assert r.code == 3 and "head360 did not write there" in r.err, r.err
    assert photo.read_bytes() == before and not (tmp_path / "me.h360").exists()
    r = run_cli("sample", "-o", tmp_path / "again.h360", "--no-lid-fit")
    assert r.code == 0, r.err
    r = run_cli("sample", "-o", tmp_path / "again.h360", "--no-lid-fit", "--seed", "1")
    assert r.code == 0, r.err
    folder = tmp_path / "heads"
    folder.mkdir()
    (folder / "samples.png").write_bytes(before)
    r = run_cli("sample", "-n", "1", "-o", folder, "--no-lid-fit")
    assert r.code == 3 and "samples.png" in r.err and not list(folder.glob("*.h360"))
    # an earlier version's run: its picture has no mark, but the head beside it was sampled
    Image.new("RGB", (8, 8)).save(tmp_path / "again.png")
    r = run_cli("sample", "-o", tmp_path / "again.h360", "--no-lid-fit", "--seed", "2")
    assert r.code == 0, r.err


def test_writing_no_samples_is_refused(tmp_path):
    """Before, write_samples([]) made an empty folder and returned no paths."""
    from head360cli.drive.sample import write_samples

    with pytest.raises(ValueError, match="at least one head"):
        write_samples([], tmp_path / "none")
    assert not (tmp_path / "none").exists()

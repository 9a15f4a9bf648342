"""Hair swap: colours, the head file rewrite, the face left unchanged, the style list."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from head360cli.drive.hair_swap import list_styles, parse_colour, swap_hair
from head360cli.errors import BadInputError


def test_parse_colour_forms():
    name, rgb = parse_colour("Dark-Brown")
    assert name == "dark brown" and rgb == pytest.approx([0.12, 0.075, 0.045])
    name, rgb = parse_colour("#ffffff")
    assert rgb == pytest.approx([1.0, 1.0, 1.0]) and name in ("white", "platinum")
    _, rgb = parse_colour("#808080")
    assert rgb == pytest.approx([0.2158605] * 3, abs=1e-6)  # sRGB 0.502 -> linear
    _, rgb = parse_colour("0.5, 0.2,0.1")
    assert rgb == pytest.approx([0.5, 0.2, 0.1])
    _, rgb = parse_colour("#888")  # CSS's short form: #888888
    assert rgb == pytest.approx(parse_colour("#888888")[1])
    assert parse_colour("  dark   brown ")[0] == "dark brown"
    # American spellings (the option is --color) and names run together were refused
    assert [parse_colour(t)[0] for t in ("gray", "Blond", "darkbrown", "LightBrown")] == [
        "grey", "blonde", "dark brown", "light brown"]
    for bad in ("purple", "#12345", "#gg0000", "1,2,3", "0.1,0.2", "#ggg"):
        with pytest.raises(BadInputError):
            parse_colour(bad)
    # a minus sign was read as a separator of names: -0.1 became 0.1
    with pytest.raises(BadInputError, match=r"in \[0, 1\], found '-0\.1,0,0'"):
        parse_colour("-0.1,0,0")


def test_list_styles():
    styles = list_styles()
    assert len(styles) == 30 and styles[0]["name"] == "bald"
    assert {s["figaro"] for s in styles} <= {"straight", "wavy", "curly", "kinky",
                                             "braids", "dreadlocks", "short-men"}


def test_swap_rewrites_only_the_hair(head_file, tmp_path):
    from head360cli.io.headfile import read_head

    out = tmp_path / "new.h360"
    res = swap_hair(head_file, out, style=9, colour="blonde")
    a, b = read_head(head_file), read_head(out)
    assert int(b.arrays["hair_style"]) == 9 and res["hair_style"]["id"] == 9
    assert b.arrays["hair_color"] == pytest.approx([0.70, 0.55, 0.32])
    for key in a.arrays:
        if key not in ("hair_style", "hair_color"):
            np.testing.assert_array_equal(a.arrays[key], b.arrays[key])
    assert b.model_hash == a.model_hash
    assert b.info["hair_swapped_from"]["hair_style"] == int(a.arrays["hair_style"])
    with pytest.raises(BadInputError):
        swap_hair(head_file, tmp_path / "x.h360")


def test_swap_drops_the_fitted_style_s_shape_with_the_style(head_file, tmp_path):
    """The thickness by direction fitted to a style is that style's: another style
    leaves it behind, a colour alone keeps it; the hair's detail texture goes with
    every style."""
    from head360cli.io.headfile import read_head, write_head
    from head360cli.synth.hair import WARP_BINS

    head = read_head(head_file)
    head.arrays["hair_scale"] = np.full(WARP_BINS, 1.5, np.float32)
    head.arrays["hair_end_shift"] = np.array(-0.02, np.float32)
    head.arrays["hair_detail"] = np.full((32, 32, 3), 0.8, np.float16)
    shaped = write_head(head, tmp_path / "shaped.h360")
    style = int(head.arrays["hair_style"])
    swap_hair(shaped, tmp_path / "recoloured.h360", style=style, colour="red")
    assert {"hair_scale", "hair_end_shift"} <= set(
        read_head(tmp_path / "recoloured.h360").arrays)
    swap_hair(shaped, tmp_path / "restyled.h360", style=style % 29 + 1)
    restyled = read_head(tmp_path / "restyled.h360").arrays
    assert not {"hair_scale", "hair_end_shift"} & set(restyled)
    # the photo's strands are the person's hair, whatever its style and colour
    np.testing.assert_array_equal(restyled["hair_detail"], head.arrays["hair_detail"])


def test_library_swap_takes_names_numbers_and_refuses_unknown_styles(head_file, tmp_path):
    """From Python, style 99 was an IndexError, -1 wore the last style until the file
    check refused it, and a colour tuple an AttributeError."""
    res = swap_hair(head_file, tmp_path / "a.h360", style="bob", colour=(0.5, 0.2, 0.1))
    assert res["hair_style"]["name"] == "bob"
    assert res["hair_color"] == pytest.approx([0.5, 0.2, 0.1])
    res = swap_hair(head_file, tmp_path / "b.h360", style=np.int64(3),
                    colour=np.array([0.1, 0.1, 0.1]))
    assert res["hair_style"]["id"] == 3
    for style, colour, message in ((99, None, "hairstyle id between 0 and 29 or one of: "
                                               "bald, .*; found 99$"),
                                   (-1, None, "between 0 and 29 or one of: .*; found -1$"),
                                   ("-1", None, "between 0 and 29 or one of: .*; found -1$"),
                                   ("perm", None, "between 0 and 29 or one of: .*; "
                                                  "found 'perm'"),
                                   (None, (2.0, 0, 0), r"in \[0, 1\], found '2.0,0,0'"),
                                   (None, (0.1, 0.2), "found '[(]0.1, 0.2[)]'")):
        with pytest.raises(BadInputError, match=message):
            swap_hair(head_file, tmp_path / "c.h360", style=style, colour=colour)
    assert not (tmp_path / "c.h360").exists()


def test_swap_leaves_the_face_unchanged(head_file):
    """Pixels no hair covers in either render are the head branch's alone: identical."""
    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.fitting.pipeline import load_head_renderer

    r = load_head_renderer(head_file, samples=4, size=64, precision="fp32")
    cams = view_cameras(np.array([0.0, 40.0]), 0.0)
    w = np.zeros((2, 52))
    k = view_intrinsics(64)
    own = np.concatenate(list(r.frames(cams, w, k))).astype(int)
    bald = np.concatenate(list(r.frames(cams, w, k, hair=False))).astype(int)
    other = np.concatenate(list(r.with_hair(0 if r.hair_style != 0 else 5, r.hair_colour)
                                .frames(cams, w, k))).astype(int)
    face = ((np.abs(own - bald).max(-1) == 0) & (np.abs(other - bald).max(-1) == 0)
            & (bald.min(-1) < 250))
    assert face.sum() > 200
    assert np.abs(own - other)[face].max() == 0


def test_cli_swap_hair(run_cli, head_file, tmp_path):
    r = run_cli("swap-hair", "--list", "--json")
    assert r.code == 0 and len(json.loads(r.out)["styles"]) == 30
    assert "warning" not in r.err
    r = run_cli("swap-hair", "--list", "--hair", "bob", "--colour", "blonde")
    assert r.code == 0 and "--hair and --color are not used with --list" in r.err
    out = tmp_path / "bob.h360"
    r = run_cli("swap-hair", head_file, "--hair", "bob", "--color", "#6b4423", "-o", out)
    assert r.code == 0 and out.is_file() and "bob" in r.out
    r = run_cli("swap-hair", out, "--hair", "afro", "-o", tmp_path / "afro.h360")
    assert r.code == 0 and "hair afro (was bob, style 11)" in r.out, r.out
    r = run_cli("swap-hair", head_file, "--hair", "mohawk2", "-o", tmp_path / "x.h360")
    assert r.code == 3 and "long wavy" in r.err and not (tmp_path / "x.h360").exists()
    r = run_cli("swap-hair", head_file, "--hair", "bob")
    assert r.code == 3
    r = run_cli("swap-hair", head_file, "--hair", "bald", "--color", "red", "-o",
                tmp_path / "bald.h360")
    assert r.code == 0 and "the head is bald (style 0): --color shows once" in r.err
    for wrong in ("bob.png", "bob"):  # a head file under an image's name, or none
        r = run_cli("swap-hair", head_file, "--hair", "bob", "-o", tmp_path / wrong)
        assert r.code == 3 and "ending in .h360" in r.err and not (tmp_path / wrong).exists()
    r = run_cli("swap-hair", head_file, "--hair", "bob", "-o", tmp_path / "no" / "bob.h360")
    assert r.code == 3 and "does not exist" in r.err


@pytest.mark.slow
def test_contact_sheet_shows_the_30_styles(head_file, tmp_path):
    from PIL import Image

    from head360cli.drive.hair_swap import style_sheet
    from head360cli.fitting.pipeline import load_head_renderer

    r = load_head_renderer(head_file, samples=2, size=32)
    out = style_sheet(r, tmp_path / "styles.png", size=32)
    sheet = np.asarray(Image.open(out).convert("RGB")).astype(int)
    assert sheet.shape[1] == 6 * 32 and sheet.shape[0] > 5 * 32
    tiles = [sheet[row * (sheet.shape[0] // 5):row * (sheet.shape[0] // 5) + 32,
                   col * 32:(col + 1) * 32] for row in range(5) for col in range(6)]
    # bald (0) and an afro (9) differ; every tile shows a head on white
    assert np.abs(tiles[0] - tiles[9]).mean() > 3
    assert all(t.min() < 200 for t in tiles)


def test_a_contact_sheet_that_cannot_be_written_is_refused_before_the_renders(
        run_cli, head_file, tmp_path, monkeypatch):
    """swap-hair --list -o nodir/sheet.png rendered the 30 styles (54 s on 2 cores) before
    saying that the folder did not exist."""
    import head360cli.drive.hair_swap as hair_swap
    import head360cli.drive.views as views
    from head360cli.fitting.pipeline import load_head_renderer

    rendered = []  # the sheet's camera is made before its renders
    monkeypatch.setattr(views, "view_cameras", lambda *a: rendered.append(1) or 1 / 0)
    r = run_cli("swap-hair", "--list", head_file, "-o", tmp_path / "no" / "sheet.png")
    assert r.code == 3 and "'" + str(tmp_path / "no") + "' does not exist" in r.err
    os.mkfifo(tmp_path / "sheet.png")
    with pytest.raises(BadInputError, match="found a named pipe"):
        hair_swap.style_sheet(load_head_renderer(head_file, samples=2, size=32),
                              tmp_path / "sheet.png")
    assert rendered == []


@pytest.mark.slow
def test_cli_contact_sheet_without_a_head_uses_the_mean_head(run_cli, tmp_path):
    from PIL import Image

    out = tmp_path / "styles.png"
    r = run_cli("swap-hair", "--list", "-o", out)
    assert r.code == 0, r.err
    assert Image.open(out).size[0] == 6 * 128
    r = run_cli("swap-hair", "--list", "-o", tmp_path / "styles.jpg")
    assert r.code == 3 and not (tmp_path / "styles.jpg").exists()


def test_listing_the_styles_does_not_load_torch():
    """swap-hair --list took 2.0 s, 1.2 of them importing torch for a list of 30 names
    (the Figaro mapping lived beside the classifier); 0.25 s now."""
    import subprocess
    import sys

    code = ("import sys; from head360cli.cli import main; code = main(['swap-hair', "
            "'--list']); sys.exit(code if 'torch' not in sys.modules else 9)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.splitlines()[9].split() == ["9", "afro", "(kinky)"]

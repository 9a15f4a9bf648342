"""``head360 fit`` (every stage), ``parse-hair``, ``classify-hair`` and ``demo`` on
scikit-image's astronaut photo (ships with scikit-image, so these always run)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from head360cli.errors import BadInputError


@pytest.fixture(scope="module")
def astronaut(tmp_path_factory):
    from skimage import data

    path = tmp_path_factory.mktemp("photos") / "astronaut.png"
    Image.fromarray(data.astronaut()).save(path)
    return path


def _inside_changed(head) -> bool:
    """Whether a fitted head's texture inside the mouth differs from its code's."""
    import torch

    from head360cli.fitting.texture import region_texels
    from head360cli.model.train import load_generator

    gen, _ = load_generator()
    with torch.no_grad():
        code = torch.from_numpy(head.arrays["texture_code"])[None]
        generated = gen.texture(code)[0].numpy()
    inside = region_texels(generated.shape[-1]).numpy()
    return bool((head.arrays["texture"][:, inside] != generated[:, inside]).any())


@pytest.mark.slow
def test_lips_counted_closed_keep_the_generated_inside_of_the_mouth(
        run_cli, astronaut, tmp_path, monkeypatch):
    """With every gap counted as closed, the astronaut's fit keeps the code's texture on
    the inside of her mouth (the full fit above checks the other way), and says so."""
    import dataclasses

    from head360cli.fitting import texture
    from head360cli.io.headfile import read_head

    monkeypatch.setitem(texture.PRESETS, "fast",
                        dataclasses.replace(texture.PRESETS["fast"], closed_mouth=1.0))
    out = tmp_path / "closed.h360"
    r = run_cli("fit", astronaut, "-o", out, "--json", "--quiet")
    assert r.code == 0, r.err
    s = json.loads(r.out)
    assert s["inversion"]["mouth_inside"] == "generated"
    assert not _inside_changed(read_head(out))
    assert s["psnr_face_input_view"] > 20.0


@pytest.mark.slow
@pytest.mark.slow
def test_the_summary_s_crop_map_gives_the_photo_the_head_was_fitted_in(fitted_astronaut):
    """``crop.affine`` takes the photo to the crop the head file's pose and intrinsics
    render: the preview's first panel is that crop."""
    import cv2
    from PIL import Image

    s = fitted_astronaut.summary
    size = s["crop"]["size"]
    photo = np.asarray(Image.open(fitted_astronaut.photo).convert("RGB"))
    crop = cv2.warpAffine(photo, np.array(s["crop"]["affine"]), (size, size),
                          flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    preview = np.asarray(Image.open(s["files"]["preview"]).convert("RGB"))
    assert np.abs(crop.astype(int) - preview[:, :size].astype(int)).mean() < 1.0


def test_full_fit_writes_head_preview_and_summary(fitted_astronaut):
    from head360cli.io.headfile import read_head

    out = fitted_astronaut.head
    tmp_path = out.parent
    assert fitted_astronaut.code == 0, fitted_astronaut.err
    s = fitted_astronaut.summary
    assert set(s["timings"]) >= {"detect", "shape", "parse", "classify", "bald_target",
                                 "invert", "hair_placement", "hair_texture", "preview",
                                 "write", "total"}
    assert s["files"] == {"head": str(out), "preview": str(tmp_path / "me_preview.png"),
                          "summary": str(tmp_path / "me.json")}
    assert json.loads((tmp_path / "me.json").read_text()) == s
    assert s["warnings"] == []  # one face, 90 px wide, in colour, frontal
    assert s["device"] == "cpu"
    assert s["hair_parse"]["parser"] == "segmenter"
    assert s["hair_parse"]["learned_prior"] is False  # the GrabCut parser's only
    # Short hair, light colour, a face fitted well at the input view. Twin tails, the
    # unshaped silhouettes' first since the face mesh's shape fit, hang where her photo
    # shows her suit: contradicted, never worn
    assert s["hair_style"]["name"] in {"pixie", "side swept", "curly short", "crew", "bob",
                                       "side part", "bangs"}
    assert s["hair_color_name"] in {"blonde", "light brown", "brown", "auburn"}
    assert s["hair_color_chosen_by"] == "render"  # she has hair, and it shows
    # the style worn is the first of the ranking reported
    assert s["hair_candidates"][0]["id"] == s["hair_style"]["id"]
    # matched to her hair by render, not snapped to a named colour (the name is the nearest)
    from head360cli.fitting.hair_class import nearest_colour_name
    from head360cli.synth.hair import HAIR_COLOURS

    assert nearest_colour_name(np.array(s["hair_color"])) == s["hair_color_name"]
    assert np.abs(np.array(s["hair_color"]) - HAIR_COLOURS[s["hair_color_name"]]).max() > 0.01
    assert s["psnr_face_input_view"] > 21.0
    assert s["inversion"]["loss_last"] < s["inversion"]["loss_first"]
    head = read_head(out)
    # the lips' gap decides whether the mouth's inside keeps the generated texture
    from head360cli.fitting.texture import PRESETS

    closed = s["inversion"]["mouth_opening"] < PRESETS["fast"].closed_mouth
    assert 0 <= s["inversion"]["mouth_opening"] < 0.3
    assert s["inversion"]["mouth_inside"] == ("generated" if closed else "fitted")
    assert _inside_changed(head) == (not closed)
    # the photo's light, fitted with the texture, kept in the head and named in the summary
    np.testing.assert_allclose(head.arrays["colour_gain"], s["light"], atol=1e-4)
    assert all(0.5 < g < 2.0 for g in s["light"])
    assert head.arrays["texture"].shape[0] == 16 and np.isfinite(head.arrays["texture"]).all()
    assert int(head.arrays["hair_style"]) == s["hair_style"]["id"]
    # the hair placement: on the grid and saved in the head
    from head360cli.fitting.hair_class import PLACEMENT_BACK, PLACEMENT_UP

    placed = s["hair_style"]
    assert placed["offset_mm"]["up"] / 1e3 in np.round(PLACEMENT_UP, 6)
    assert placed["offset_mm"]["forward"] / 1e3 in np.round(PLACEMENT_BACK, 6)
    np.testing.assert_allclose(head.arrays["hair_offset"] * 1e3, [
        0.0, placed["offset_mm"]["up"], placed["offset_mm"]["forward"]], atol=1e-3)
    # It scores silhouette IoU less the parsed face its hair covers (place_hair, tested in
    # test_hair_class), so a shift may give up a little IoU to uncover the face; unmoved,
    # the two IoUs are one.
    if placed["offset_mm"]["up"] == 0 and placed["offset_mm"]["forward"] == 0:
        assert placed["iou_placed"] == placed["iou_unplaced"]
    assert min(placed["iou_placed"], placed["iou_unplaced"]) > 0.3
    # the ends raised where her hair ends higher, on the grid and saved with the head
    from head360cli.fitting.hair_shape import END_SHIFTS, SCALE_RANGE

    assert placed["end_shift_mm"] / 1e3 in np.round(END_SHIFTS, 6)
    np.testing.assert_allclose(head.arrays.get("hair_end_shift", 0.0) * 1e3,
                               placed["end_shift_mm"], atol=1e-3)
    # the thickness by direction: kept only when it gains IoU, saved with the head

    if "hair_scale" in head.arrays:
        assert placed["iou_scaled"] >= placed["iou_placed"] - 0.05  # less face covered
        lo, hi = head.arrays["hair_scale"].min(), head.arrays["hair_scale"].max()
        assert SCALE_RANGE[0] - 1e-6 <= lo <= hi <= SCALE_RANGE[1] + 1e-6
        np.testing.assert_allclose(placed["scale_range"], [lo, hi], atol=1e-3)
    else:  # a scale that gains less than MIN_GAIN is not kept
        assert placed["iou_scaled"] is None and placed["scale_range"] is None
    # the hair's texture from her photo: its strands and spread of colour, median near
    # her hair's own, in the head file at DETAIL_RES
    from head360cli.fitting.hair_texture import DETAIL_RES, MAX_DETAIL

    detail = head.arrays["hair_detail"].astype(np.float32)
    assert detail.shape == (DETAIL_RES, DETAIL_RES, 3)
    assert 0.6 < float(np.median(detail)) < 1.5 and detail.max() <= MAX_DETAIL
    assert np.quantile(detail, 0.9) > 1.2 * np.quantile(detail, 0.1)
    # with the texture's brightness matched by render, her hair renders as her photo's at
    # its view (CIEDE2000 of the medians 1.3 on D; 9.4 unmatched)
    import torch
    from skimage import data

    from head360cli.bench.hair import hair_colour_difference, segmented_hair
    from head360cli.fitting.pipeline import load_head_renderer
    from head360cli.fitting.texture import crop_image
    from head360cli.model.head_render import to_uint8

    size = s["crop"]["size"]
    crop = crop_image(data.astronaut(), np.array(s["crop"]["affine"]), size)
    worn = load_head_renderer(out, precision="fp32", size=size)
    rgb, _, hair = worn.render(torch.as_tensor(head.arrays["pose"])[None],
                               torch.as_tensor(head.arrays["intrinsics"]), hair_alpha=True)
    assert hair_colour_difference(to_uint8(rgb)[0], hair[0, 0].numpy() > 0.5, crop,
                                  segmented_hair(crop)) < 3.0
    preview = Image.open(tmp_path / "me_preview.png")
    assert preview.size == (6 * 256, 256)


@pytest.mark.slow
def test_fit_errors_leave_nothing_behind(run_cli, tmp_path):
    from skimage import data

    wall = tmp_path / "wall.png"
    Image.fromarray(np.full((200, 300, 3), 128, np.uint8)).save(wall)
    r = run_cli("fit", wall, "-o", tmp_path / "x.h360")
    assert r.code == 4 and "no face" in r.err
    coffee = tmp_path / "coffee.png"
    Image.fromarray(data.coffee()).save(coffee)
    assert run_cli("fit", coffee, "-o", tmp_path / "x.h360").code == 4
    assert run_cli("fit", wall, "-o", tmp_path / "x.obj").code == 3
    assert run_cli("fit", wall, "-o", tmp_path / "nowhere" / "x.h360").code == 3
    assert run_cli("fit", wall, "--hair", "beehive", "-o", tmp_path / "x.h360").code == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["coffee.png", "wall.png"]


@pytest.mark.slow
def test_a_full_disk_at_the_last_file_leaves_no_part_of_the_set(run_cli, astronaut, tmp_path,
                                                               monkeypatch):
    """Each command's files were renamed into place one by one, so a full disk at the last
    one (the fit's summary, the shape fit's parameters, parse-hair's overlay) left the new
    head and preview, mesh and overlay, or masks, beside no summary or an earlier run's."""
    import errno
    import os

    real_text, real_save = Path.write_text, Image.Image.save

    def full(path):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    def write_text(self, *args, **kwargs):
        if self.suffix == ".json" and self.parent == tmp_path:
            full(self)
        return real_text(self, *args, **kwargs)

    def save(self, fp, *args, **kwargs):
        if "_parse." in str(fp):
            full(fp)
        return real_save(self, fp, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", write_text)
    monkeypatch.setattr(Image.Image, "save", save)
    for args in (("fit", astronaut, "-o", tmp_path / "me.h360"),
                 ("fit", astronaut, "--stage", "shape", "-o", tmp_path),
                 ("parse-hair", astronaut, "-o", tmp_path)):
        r = run_cli(*args, "--quiet")
        assert r.code == 3 and "No space left" in r.err, (args, r.err)
        assert list(tmp_path.iterdir()) == [], args


def test_a_fit_does_not_replace_its_photo_or_a_json_it_did_not_write(run_cli, astronaut,
                                                                     tmp_path):
    """``fit me_preview.png -o me.h360`` wrote its preview over the photo, and ``fit
    photo.jpg`` replaced a ``photo.json`` beside it (a LabelMe annotation, say). Both are
    refused before any work; an earlier fit's summary is replaced as before."""
    from head360cli.fitting.pipeline import FIT_SUMMARY_KEYS, check_fit_outputs

    photo = tmp_path / "me_preview.png"
    photo.write_bytes(astronaut.read_bytes())
    r = run_cli("fit", photo, "-o", tmp_path / "me.h360")
    # refused as the command's own input (the output check that says "the preview"
    # comes after it)
    assert r.code == 3 and "an output other than the inputs" in r.err, r.err
    assert photo.read_bytes() == astronaut.read_bytes()
    labelme = tmp_path / "astronaut.json"
    labelme.write_text('{"version": "5.0.1", "shapes": []}')
    r = run_cli("fit", astronaut, "-o", tmp_path / "astronaut.h360")
    assert r.code == 3 and "to be an earlier fit's summary" in r.err, r.err
    assert labelme.read_text() == '{"version": "5.0.1", "shapes": []}'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["astronaut.json", "me_preview.png"]
    for text in ("not json", "[1, 2]", '{"photo": "a.jpg"}'):
        labelme.write_text(text)
        with pytest.raises(BadInputError, match="earlier fit's summary"):
            check_fit_outputs(astronaut, tmp_path / "astronaut.h360")
    labelme.write_text(json.dumps(dict.fromkeys(FIT_SUMMARY_KEYS, 0)))
    check_fit_outputs(astronaut, tmp_path / "astronaut.h360")  # an earlier fit's: replaced
    # a preview head360 wrote is replaced; a picture of the same name it did not write is not
    from head360cli.io.images import png_info

    preview = tmp_path / "astronaut_preview.png"
    Image.new("RGB", (4, 4)).save(preview, pnginfo=png_info())
    check_fit_outputs(astronaut, tmp_path / "astronaut.h360")
    Image.new("RGB", (4, 4)).save(preview)
    with pytest.raises(BadInputError, match=r"preview as .*head360 did not write"):
        check_fit_outputs(astronaut, tmp_path / "astronaut.h360")
    # an earlier version's fit: its preview has no mark, but its summary names it
    labelme.write_text(json.dumps({**dict.fromkeys(FIT_SUMMARY_KEYS, 0),
                                   "files": {"preview": str(preview)}}))
    check_fit_outputs(astronaut, tmp_path / "astronaut.h360")
    # empty files hold nothing to lose: ``head360 --json fit ... > astronaut.json`` was
    # refused, the shell having made the file before head360 ran
    labelme.write_text("")
    preview.write_bytes(b"")
    check_fit_outputs(astronaut, tmp_path / "astronaut.h360")
    from head360cli.io.atomic import empty_file

    assert empty_file(labelme) and empty_file(preview) and not empty_file(tmp_path)
    assert not empty_file(tmp_path / "none.json")
    if hasattr(os, "mkfifo"):  # a pipe also reads as size 0, and is refused elsewhere
        os.mkfifo(tmp_path / "pipe.json")
        assert not empty_file(tmp_path / "pipe.json")


@pytest.mark.slow
def test_parse_and_classify_hair(run_cli, astronaut, tmp_path):
    r = run_cli("parse-hair", astronaut, "-o", tmp_path, "--json")
    assert r.code == 0, r.err
    out = json.loads(r.out)
    hair = np.array(Image.open(out["hair_mask"]))
    face = np.array(Image.open(out["face_mask"]))
    assert hair.shape == face.shape == (512, 512) and hair.dtype == np.uint8
    assert set(np.unique(hair)) <= {0, 255} and set(np.unique(face)) <= {0, 255}
    # Hair on the crown, face skin on the cheeks and nose (rows 150-180).
    assert hair[40:80, 180:280].mean() > 230 and face[150:180, 210:260].mean() > 180
    assert Image.open(out["overlay"]).size == (512, 512)
    assert out["hair_parser"] == "segmenter" and out["learned_prior"] is False
    assert out["profile_face"] is False
    # The GrabCut parser agrees (hair IoU 0.953 measured); without its learned prior the
    # astronaut's hair is plain against her backdrop and both GrabCut parses agree
    # (measured: 1 pixel of 262,144 differs).
    from head360cli.fitting.hair_parse import mask_iou

    r = run_cli("parse-hair", astronaut, "-o", tmp_path / "gc", "--json", "--hair-parser",
                "grabcut")
    grabcut = json.loads(r.out)
    assert r.code == 0 and grabcut["learned_prior"] is True
    gc_hair = np.array(Image.open(grabcut["hair_mask"]))
    assert mask_iou(gc_hair > 0, hair > 0) > 0.9
    r = run_cli("parse-hair", astronaut, "-o", tmp_path / "alone", "--json", "--hair-parser",
                "grabcut", "--no-prior")
    alone = json.loads(r.out)
    assert r.code == 0 and alone["learned_prior"] is False
    assert (np.array(Image.open(alone["hair_mask"])) != gc_hair).mean() < 0.001
    r = run_cli("classify-hair", astronaut, "--json", "--hair-parser", "grabcut", "--no-prior")
    assert r.code == 0 and json.loads(r.out)["top"][0]["name"] != "bald"
    r = run_cli("classify-hair", astronaut, "--json", "--top", "5")
    c = json.loads(r.out)
    assert len(c["top"]) == 5 and c["top"][0]["score"] >= c["top"][-1]["score"]
    assert c["top"][0]["name"] != "bald"
    assert c["top"][0]["same_silhouette_as_first"] is True
    assert c["hair_matches_a_style"] is True
    from head360cli.synth.hair import HAIR_COLOURS

    np.testing.assert_allclose(c["hair_color"], HAIR_COLOURS[c["hair_color_name"]], atol=1e-4)
    assert len(c["hair_color_estimate"]) == 3
    assert c["hair_color_chosen_by"] == "tone curve"  # no generator in classify-hair
    assert run_cli("classify-hair", astronaut, "--top", "0").code == 3
    speck = tmp_path / "speck.png"
    Image.fromarray(np.zeros((3, 3, 3), np.uint8)).save(speck)
    r = run_cli("parse-hair", speck, "-o", tmp_path / "speck")
    assert r.code == 3 and "found 3x3" in r.err and not (tmp_path / "speck").exists()
    strip = tmp_path / "strip.png"  # loaded at 4096x8: the message named that size alone
    Image.fromarray(np.zeros((10, 5120, 3), np.uint8)).save(strip)
    r = run_cli("parse-hair", strip, "-o", tmp_path / "strip")
    assert r.code == 3 and "found 5120x10 (4096x8 once its longer side is brought to 4096)" \
        in r.err, r.err
    # one pixel wide: its width kept at 1, so the scale read 1.0 and the message named the
    # loaded 1x4096 as if it were the file's size
    needle = tmp_path / "needle.png"
    Image.fromarray(np.zeros((40000, 1, 3), np.uint8)).save(needle)
    r = run_cli("parse-hair", needle, "-o", tmp_path / "needle")
    assert r.code == 3 and "found 1x40000 (1x4096 once its longer side" in r.err, r.err


@pytest.mark.slow
def test_parse_hair_of_a_pipe_names_its_masks_pipe(run_cli, astronaut, tmp_path, pipe):
    """A photo from ``<(...)`` (``/dev/fd/63``) is parsed as the file is, and its masks are
    called ``pipe_*`` rather than after the descriptor's number."""
    r = run_cli("parse-hair", pipe(astronaut.read_bytes(), "63"), "-o", tmp_path / "p",
                "--json")
    assert r.code == 0, r.err
    out = json.loads(r.out)
    assert Path(out["hair_mask"]).name == "pipe_hair.png"
    r = run_cli("parse-hair", astronaut, "-o", tmp_path / "f", "--json")
    from_file = json.loads(r.out)
    assert np.array_equal(np.array(Image.open(out["hair_mask"])),
                          np.array(Image.open(from_file["hair_mask"])))


@pytest.mark.slow
@pytest.mark.skipif(not Path("/dev/stdin").exists(), reason="no /dev/stdin")
def test_a_photo_on_standard_input_is_given_as_dash(astronaut, tmp_path):
    """``curl URL | head360 parse-hair -`` was "no such file: '-'" (streams and inspect
    took ``-``, photos only ``/dev/stdin``). Piped or redirected, the masks are the file's,
    named ``pipe_*``; with nothing on standard input, an empty photo (exit 5)."""
    import subprocess
    import sys

    masks = {}
    for how in ("piped", "redirected"):
        cmd = [sys.executable, "-m", "head360cli", "parse-hair", "-", "-o",
               str(tmp_path / how), "--json", "--quiet"]
        if how == "piped":
            run = subprocess.run(cmd, input=astronaut.read_bytes(), capture_output=True,
                                 timeout=300)
        else:
            with open(astronaut, "rb") as f:
                run = subprocess.run(cmd, stdin=f, capture_output=True, timeout=300)
        assert run.returncode == 0, run.stderr
        out = json.loads(run.stdout)
        assert Path(out["hair_mask"]).name == "pipe_hair.png"
        masks[how] = np.array(Image.open(out["hair_mask"]))
    assert np.array_equal(masks["piped"], masks["redirected"]) and masks["piped"].any()
    run = subprocess.run([sys.executable, "-m", "head360cli", "classify-hair", "-"],
                         stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=300)
    assert run.returncode == 5 and "empty" in run.stderr, run.stderr


@pytest.mark.slow
def test_parse_hair_says_it_found_a_face_in_profile(run_cli, tmp_path):
    """A held-out corpus head turned 65 degrees, parsed by GrabCut: no face for dlib, a
    face in profile for the cascade, whose skin is the face mask (before, the face was
    parsed as hair)."""
    from tests.fitting.test_hair_parse import _corpus_view

    photo = tmp_path / "side.png"
    rgb, hair, _ = _corpus_view(65.0)
    Image.fromarray(rgb).save(photo)
    gc = ("--hair-parser", "grabcut", "--detector", "hog")
    r = run_cli("parse-hair", photo, "-o", tmp_path / "out", "--json", *gc)
    assert r.code == 0, r.err
    out = json.loads(r.out)
    assert out["seeded"] is False and out["profile_face"] is True
    assert out["face_fraction"] > 0.02
    face = np.array(Image.open(out["face_mask"])) > 0
    parsed = np.array(Image.open(out["hair_mask"])) > 0
    assert not (face & hair).any() and (parsed & hair).sum() > 0.9 * hair.sum()
    r = run_cli("parse-hair", photo, "-o", tmp_path / "out", *gc)
    assert r.code == 0 and "no frontal face: colour and a face in profile" in r.out


@pytest.mark.slow
def test_parse_hair_finds_a_cut_face(run_cli, tmp_path):
    """The astronaut cut off below the nose, as hair close-ups cut faces: the default
    detector finds her face, and the parse agrees with the whole photo's over the same
    window (measured 0.97); dlib's HOG finds no face there, nor dlib's CNN on this copy,
    and the parse without a face agrees too (the segmenter needs no face)."""
    from skimage import data

    from head360cli.fitting.hair_parse import mask_iou

    img = data.astronaut()
    whole, cut = tmp_path / "whole.png", tmp_path / "cut.png"
    Image.fromarray(img).save(whole)
    Image.fromarray(np.ascontiguousarray(img[:140, 80:360])).save(cut)

    def parse(photo, *extra):
        r = run_cli("parse-hair", photo, "-o", tmp_path / photo.stem / "-".join(extra),
                    "--json", *extra)
        assert r.code == 0, r.err
        out = json.loads(r.out)
        return out, np.array(Image.open(out["hair_mask"])) > 0

    out, ref = parse(whole)
    assert out["face_detector"] == "blazeface"
    out, found = parse(cut)
    assert out["seeded"] is True and out["face_detector"] in ("blazeface", "yunet")
    assert mask_iou(found, ref[:140, 80:360]) > 0.9
    out, alone = parse(cut, "--detector", "hog")
    assert out["seeded"] is False and out["face_detector"] is None
    assert mask_iou(alone, ref[:140, 80:360]) > 0.8


@pytest.mark.slow
def test_a_face_lying_on_its_side_fits_like_the_upright_one(run_cli, astronaut, tmp_path):
    """The astronaut turned a quarter turn (the same square image): the face mesh reads
    her as she lies, in a crop levelled by her eyes, and the fit runs in that frame
    turned upright (``face_turn_degrees`` 90), so its yaw and pitch are the upright
    photo's and its roll a quarter turn away (within two degrees: the crop's levelling
    resamples the pixels); parse-hair finds her too."""
    from head360cli.fitting.landmarks import turned_image

    lying = tmp_path / "lying.png"
    Image.fromarray(turned_image(np.array(Image.open(astronaut).convert("RGB")), -90.0)[0]
                    ).save(lying)

    def shape(photo):
        r = run_cli("fit", "--stage", "shape", photo, "-o", tmp_path / photo.stem, "--json")
        assert r.code == 0, r.err
        return json.loads(r.out)

    a, b = shape(astronaut), shape(lying)
    assert a["face_turn_degrees"] == 0.0 and b["face_turn_degrees"] == 90.0
    assert abs(a["pose"]["yaw"] - b["pose"]["yaw"]) < 2.0
    assert abs(a["pose"]["pitch"] - b["pose"]["pitch"]) < 2.0  # measured 1.18
    assert abs(b["pose"]["roll"] - a["pose"]["roll"] - 90.0) < 2.0
    # parse-hair finds her the same way: its hair mask is the upright parse's, turned
    # (measured IoU 0.944; parsed without her face, 0.000)
    masks = []
    for photo in (astronaut, lying):
        r = run_cli("parse-hair", photo, "-o", tmp_path / f"{photo.stem}_parse", "--json")
        assert r.code == 0, r.err
        out = json.loads(r.out)
        masks.append(np.array(Image.open(out["hair_mask"])) > 0)
    assert out["seeded"] is True and out["face_turn_degrees"] == 90.0
    from head360cli.fitting.hair_parse import mask_iou

    assert mask_iou(masks[1], np.rot90(masks[0], -1)) > 0.9


@pytest.mark.slow
def test_demo_writes_a_turntable(run_cli, tmp_path):
    import imageio

    # an earlier version's preview, without head360's PNG mark: the demo's folder is its
    # own, so the demo runs again over it (fit would refuse it beside a user's photo)
    Image.new("RGB", (6, 1)).save(tmp_path / "astronaut_preview.png")
    r = run_cli("demo", "-o", tmp_path, "--frames", "4", "--json", "--quiet")
    assert r.code == 0, r.err
    out = json.loads(r.out)
    reader = imageio.get_reader(out["turntable"])
    count = sum(1 for _ in reader)
    assert count == 4
    assert (tmp_path / "astronaut.h360").is_file()


# --------------------------------------------------------------------- hard inputs


def _stage(path, detector="auto"):
    """The photo's stages up to the shape fit: ``((image, face, shape fit, model),
    warnings)``."""
    from head360cli.fitting import stages
    from head360cli.fitting.config import FitConfig

    warnings: list[str] = []
    cfg = FitConfig(detector=detector)
    seen = stages.detect_face(stages.load_photo(path, cfg, warnings), cfg, warnings)
    shape = stages.fit_shape(seen, cfg, warnings)
    return (seen.image, seen.face, shape.fit, shape.model), warnings


@pytest.mark.slow
def test_greyscale_fifty_megapixel_photo_fits_with_a_warning(run_cli, tmp_path):
    """A 50-megapixel greyscale JPEG: decoded at reduced size, fitted, warned about."""
    from skimage import data

    grey = Image.fromarray(data.astronaut()).convert("L")
    big = tmp_path / "big.jpg"
    grey.resize((7072, 7072), Image.Resampling.BILINEAR).save(big, quality=85)
    r = run_cli("fit", big, "-o", tmp_path / "big.h360", "--json")
    assert r.code == 0, r.err
    s = json.loads(r.out)
    assert s["image_size"] == [7072, 7072]  # 50.0 megapixels
    assert any("greyscale" in w for w in s["warnings"]) and "greyscale" in r.err
    c = np.array(s["hair_color_estimate"])
    assert np.ptp(c) < 0.05  # grey hair from a grey photo
    assert s["light"] is None  # a grey photo shows no light's colour
    assert np.isfinite(s["psnr_face_input_view"]) and s["psnr_face_input_view"] > 18
    # its grey fitted, its colour the model's skin: the front view's face is not grey
    assert s["inversion"]["fitted_in"] == "grey"
    preview = np.asarray(Image.open(s["files"]["preview"]).convert("RGB")).astype(float)
    side = preview.shape[0]
    face = preview[side * 3 // 8:side * 5 // 8, side + side * 3 // 8:side + side * 5 // 8]
    # red over blue in grey levels: 66 measured, 28 when the grey was fitted in colour
    # the model's warm skin, red well above blue (the deferred generator's: 44.6 levels)
    assert (face[..., 0] - face[..., 2]).mean() > 35, face.mean((0, 1))


@pytest.mark.slow
def test_a_colour_face_in_a_grey_scene_is_not_a_grey_photo(tmp_path):
    """A colour face on under 1 % of a grey photo: the photo passes as greyscale, but
    the face's box does not, so no greyscale warning (nor a grey fit)."""
    from skimage import data

    from head360cli.io.images import load_image

    canvas = np.full((3000, 3000, 3), 128, np.uint8)
    canvas[1000:1300, 1000:1300] = data.astronaut()[0:300, 100:400]  # her face
    path = tmp_path / "scene.png"
    Image.fromarray(canvas).save(path)
    assert load_image(path).greyscale  # the whole photo is
    _, warnings = _stage(path)
    assert not any("greyscale" in w for w in warnings), warnings


def test_small_faces_are_refused_or_warned(tmp_path):
    from skimage import data

    from head360cli.errors import BadInputError, NoFaceError

    photo = Image.fromarray(data.astronaut())
    tiny = tmp_path / "tiny.png"
    photo.resize((128, 128), Image.Resampling.LANCZOS).save(tiny)  # face ~28 px
    with pytest.raises((BadInputError, NoFaceError), match=r"pixels wide|no face"):
        _stage(tiny)
    small = tmp_path / "small.png"
    photo.resize((300, 300), Image.Resampling.LANCZOS).save(small)  # face ~53 px
    _, warnings = _stage(small)
    assert any("pixels wide" in w for w in warnings)


@pytest.mark.slow
@pytest.mark.shared_data
def test_hair_that_matches_no_style_classifies_as_no_hair(run_cli, shared_data):
    """A development VOC photo (not the bench's) whose parse finds a patch of the
    neighbour's hair beside the largest face: every style overlaps it by under 0.01, and
    the widest (afro) ranked first; now it ranks as no hair, and the output says why."""
    photo = shared_data / "faces" / "2008_002079.jpg"
    # the GrabCut parser with dlib's landmarks finds the neighbour's patch; the segmenter
    # keeps hair to the fitted face
    old = ("--hair-parser", "grabcut", "--detector", "hog")
    r = run_cli("classify-hair", photo, "--json", *old)
    assert r.code == 0, r.err
    c = json.loads(r.out)
    assert c["hair_matches_a_style"] is False and c["top"][0]["name"] == "bald"
    assert max(t["iou"] for t in c["top"]) < 0.1
    r = run_cli("classify-hair", photo, *old)
    assert "matches no hairstyle" in r.out


@pytest.mark.shared_data
def test_several_faces_fit_the_largest_with_a_warning(shared_data):
    _, warnings = _stage(shared_data / "faces" / "bald_guys.jpg")
    assert any("faces found" in w for w in warnings)


@pytest.mark.shared_data
def test_profile_view_is_fitted_with_a_warning(shared_data):
    """AFLW2000 image00475 is turned 65.6 degrees (its labels); the face mesh's landmarks
    make it 64 (dlib's made it about 43), which the default threshold (the fit's yaw)
    warns about; the frontal image00050 (0.9 degrees) gets no warning; image00251 (-54.7
    degrees, pitched), which dlib's HOG did not find, is found and fitted turned; with
    ``--detector hog`` it is still a clear no-face error with a hint."""
    from head360cli.errors import NoFaceError

    folder = shared_data / "landmarks68" / "aflw2000"
    (_, _, fit, _), warnings = _stage(folder / "image00475.jpg")
    yaw = fit.euler_degrees()["yaw"]
    assert 55 < abs(yaw) < 75
    assert [w for w in warnings if "profile view" in w] == [
        f"profile view (fitted yaw {yaw:.0f} degrees, likely turned further): the far side "
        "of the face comes from the model, and the pose and hairstyle may be off"]
    _, warnings = _stage(folder / "image00050.jpg")
    assert warnings == []
    (_, _, fit, _), _ = _stage(folder / "image00251.jpg")
    assert 35 < abs(fit.euler_degrees()["yaw"]) < 75
    with pytest.raises(NoFaceError, match="--detector auto, or cnn"):
        _stage(folder / "image00251.jpg", detector="hog")


def test_a_known_camera_distance_is_kept(run_cli, astronaut, tmp_path):
    def distance(*extra):
        r = run_cli("fit", "--stage", "shape", astronaut, "-o", tmp_path, "--json", *extra)
        assert r.code == 0, r.err
        return json.loads(r.out)["pose"]["distance"]

    free = distance()
    assert distance("--distance", "0.8") == pytest.approx(0.8, abs=1e-3)
    assert abs(free - 0.8) > 0.05  # the option changed the fit
    r = run_cli("fit", "--stage", "shape", astronaut, "-o", tmp_path, "--distance", "-1")
    assert r.code == 2 and "distance" in r.err.lower()



@pytest.mark.parametrize("stage", ["shape", "all"])
@pytest.mark.parametrize("focal", ["-5", "nan", "0"])
def test_a_focal_length_that_is_not_positive_is_refused_before_any_work(
        run_cli, astronaut, tmp_path, stage, focal):
    """--focal -5 failed deep in the inversion ("expected a visible face region"), --focal
    nan as an internal error, and 0 meant the default; now each is refused at once."""
    out = tmp_path / ("x.h360" if stage == "all" else "shape")
    r = run_cli("fit", "--stage", stage, astronaut, "-o", out, "--focal", focal)
    assert r.code == 3, r.err
    assert f"expected a positive focal length in pixels, found {float(focal)}" in r.err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("stage", ["shape", "all"])
@pytest.mark.parametrize("focal", ["10", "1e9"])
def test_a_focal_length_no_lens_has_is_refused_before_the_fit(
        run_cli, astronaut, tmp_path, stage, focal):
    """On the 512-pixel astronaut, --focal 10 ended in "expected a visible face region"
    and --focal 1e9 in an internal error (a singular matrix)."""
    out = tmp_path / ("x.h360" if stage == "all" else "shape")
    r = run_cli("fit", "--stage", stage, astronaut, "-o", out, "--focal", focal)
    assert r.code == 3, r.err
    assert (f"expected a focal length between 57 and 56889 pixels for this 512x512 photo "
            f"(a 4-4000 mm lens in 35 mm terms), found {float(focal):g}") in r.err
    assert list(tmp_path.iterdir()) == []


def test_check_focal_bounds_scale_with_the_image():
    from head360cli.errors import BadInputError
    from head360cli.fitting.shape import check_focal

    check_focal(None, 640, 480)
    check_focal(4 / 36 * 640, 640, 480)  # the bounds themselves are lenses
    check_focal(4000 / 36 * 640, 480, 640)
    for focal in (4 / 36 * 640 * 0.99, 4000 / 36 * 640 * 1.01):
        with pytest.raises(BadInputError, match="640x480"):
            check_focal(focal, 640, 480)


def test_an_exif_focal_no_lens_has_falls_back_to_50_mm():
    from head360cli.fitting.shape import default_focal

    assert default_focal(720, 360, 24.0) == pytest.approx(24 / 36 * 720)
    for broken in (None, 0.0, 1.0, 65535.0):
        assert default_focal(720, 360, broken) == pytest.approx(50 / 36 * 720)


def test_the_fit_holds_the_eyes_landmarks():
    """The camera refinement's held landmarks are iBUG 36-47 (the eyes) among the 51
    inner-face points ``fit`` anchors it with."""
    from head360cli.fitting.stages import INNER_EYES, inner_landmarks
    from head360cli.mesh.bilinear import load_bilinear

    model = load_bilinear()
    posed = model.vertices(np.zeros(model.rank), np.zeros(52))
    detected = np.arange(136, dtype=np.float64).reshape(68, 2)
    points, pixels = inner_landmarks(model, posed, detected, np.eye(2, 3), "cpu")
    assert INNER_EYES.shape == (51,) and INNER_EYES.sum() == 12
    np.testing.assert_allclose(points.numpy()[INNER_EYES],
                               model.landmark_points(posed)[36:48], atol=1e-6)
    np.testing.assert_allclose(pixels.numpy()[INNER_EYES], detected[36:48])


def test_the_shape_stage_says_which_whole_fit_options_it_does_not_use(run_cli, astronaut,
                                                                      tmp_path):
    """--stage shape fits landmarks, pose and identity only: --preset, --hair, --no-prior
    and --no-lid-fit given with it were silently dropped; now a warning names them."""
    r = run_cli("fit", "--stage", "shape", astronaut, "-o", tmp_path, "--preset", "quality",
                "--hair", "bob", "--no-lid-fit")
    assert r.code == 0, r.err
    assert ("--preset and --hair and --no-lid-fit are not used with --stage shape"
            in r.err)
    r = run_cli("fit", "--stage", "shape", astronaut, "-o", tmp_path, "--detector", "hog")
    assert r.code == 0 and "not used" not in r.err  # the detector is the shape stage's


def test_a_parse_without_the_installed_hair_prior_says_so(run_cli, astronaut, tmp_path,
                                                          monkeypatch):
    """Without models/hair_prior.pt the GrabCut parse ran by colour and landmarks alone,
    saying so only in the JSON's learned_prior: false."""
    import shutil

    from head360cli.fitting import hair_prior, pipeline
    from head360cli.paths import models_dir

    assert pipeline.PRIOR_FILE == hair_prior.FILE_NAME
    models = tmp_path / "models"
    models.mkdir()
    for f in models_dir().iterdir():
        if f.is_file() and f.name != hair_prior.FILE_NAME:
            shutil.copy(f, models / f.name)
    monkeypatch.setenv("HEAD360_MODELS", str(models))
    hair_prior.default_hair_prior.cache_clear()  # loaded by earlier tests in this process
    r = run_cli("parse-hair", astronaut, "-o", tmp_path / "p", "--json", "--hair-parser",
                "grabcut")
    hair_prior.default_hair_prior.cache_clear()  # not this models folder's None for later
    assert r.code == 0, r.err
    assert "the hair prior is not installed" in r.err
    assert json.loads(r.out)["learned_prior"] is False
    r = run_cli("parse-hair", astronaut, "-o", tmp_path / "q", "--hair-parser", "grabcut",
                "--no-prior")
    assert r.code == 0 and "not installed" not in r.err


@pytest.mark.slow
def test_classify_hair_and_parse_hair_pass_on_the_photo_s_warnings(run_cli, astronaut,
                                                                   tmp_path):
    """classify-hair dropped the photo stage's warnings (greyscale, several faces, a
    small face...), which fit prints; and a GIF or TIFF of several frames was read at its
    first frame without a word."""
    grey = tmp_path / "grey.png"
    Image.open(astronaut).convert("L").save(grey)
    r = run_cli("classify-hair", grey, "--json")
    assert r.code == 0 and "greyscale photo" in r.err
    assert any("greyscale" in w for w in json.loads(r.out)["warnings"])
    frames = tmp_path / "two.gif"
    first = Image.open(astronaut).convert("RGB")
    first.save(frames, save_all=True, append_images=[Image.new("RGB", first.size)])
    r = run_cli("parse-hair", frames, "-o", tmp_path / "p")
    assert r.code == 0 and "two.gif holds 2 frames; the first is used" in r.err
    r = run_cli("classify-hair", frames)
    assert r.code == 0 and "two.gif holds 2 frames; the first is used" in r.err
    junk = tmp_path / "junk.png"  # a colour profile littlecms cannot read
    first.save(junk, icc_profile=b"not a profile")
    r = run_cli("parse-hair", junk, "-o", tmp_path / "p")
    assert r.code == 0 and "junk.png has a colour profile head360 cannot use" in r.err


def test_the_shape_fit_refuses_a_face_that_is_no_number_from_python(astronaut, tmp_path):
    """fit_shape_photo(face="x") was int()'s ValueError; the CLI checked its own option."""
    from head360cli.fitting.pipeline import fit_shape_photo

    for face, found in (("x", "'x'"), (-1, "-1"), ("-1", "'-1'"), (1.5, "1.5")):
        with pytest.raises(BadInputError, match=f"face number >= 0 or 'all', found {found}"):
            fit_shape_photo(astronaut, tmp_path / "out", face=face)
    assert not (tmp_path / "out").exists()


def test_a_preview_or_summary_that_cannot_be_replaced_is_refused_before_the_fit(
        tmp_path, monkeypatch):
    """A read-only ``me_preview.png`` (or a named pipe for ``me.json``) was found only
    when the three files were renamed, after the whole fit; the photo here is never
    opened (it does not exist)."""
    import os

    from head360cli.fitting.pipeline import fit_photo

    (tmp_path / "me_preview.png").write_bytes(b"kept")
    os.chmod(tmp_path / "me_preview.png", 0o444)
    if os.geteuid() == 0:  # root may write any file: ask as another user would
        monkeypatch.setattr(os, "access", lambda path, mode: bool(
            os.stat(path).st_mode & 0o200) or mode != os.W_OK)
    with pytest.raises(BadInputError, match=r"me_preview\.png' read-only"):
        fit_photo(tmp_path / "no-such-photo.jpg", tmp_path / "me.h360")
    os.chmod(tmp_path / "me_preview.png", 0o644)
    os.mkfifo(tmp_path / "me.json")
    with pytest.raises(BadInputError, match=r"me\.json', found a named pipe"):
        fit_photo(tmp_path / "no-such-photo.jpg", tmp_path / "me.h360")
    assert (tmp_path / "me_preview.png").read_bytes() == b"kept"


def test_parse_hair_checks_its_three_names_before_the_parse(tmp_path, monkeypatch):
    """A photo whose name is 250 characters long fits the file system, its
    ``<stem>_parse.png`` overlay does not; and an existing mask may be a named pipe. Both
    were found when the masks were renamed, after the parse; the photo is never opened
    here (it does not exist)."""
    import os

    from head360cli.fitting.pipeline import parse_photo

    limit = os.pathconf(tmp_path, "PC_NAME_MAX")
    photo = tmp_path / ("p" * (limit - 5) + ".jpg")  # name fits; "_parse.png" does not
    for out in (tmp_path / "new", tmp_path):  # a folder to be made, one that exists
        with pytest.raises(BadInputError, match=f"at most {limit} bytes"):
            parse_photo(photo, out)
    os.mkfifo(tmp_path / "me_face.png")
    with pytest.raises(BadInputError, match="found a named pipe"):
        parse_photo(tmp_path / "me.jpg", tmp_path)
    assert [p.name for p in tmp_path.iterdir()] == ["me_face.png"]

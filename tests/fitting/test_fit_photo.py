"""``head360 fit`` (every stage), ``parse-hair``, ``classify-hair`` and ``demo`` on
scikit-image's astronaut photo (ships with scikit-image, so these always run)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image


@pytest.fixture(scope="module")
def astronaut(tmp_path_factory):
    from skimage import data

    path = tmp_path_factory.mktemp("photos") / "astronaut.png"
    Image.fromarray(data.astronaut()).save(path)
    return path


def test_full_fit_writes_head_preview_and_summary(run_cli, astronaut, tmp_path):
    from head360cli.io.headfile import read_head

    out = tmp_path / "me.h360"
    r = run_cli("fit", astronaut, "-o", out, "--json", "--quiet")
    assert r.code == 0, r.err
    s = json.loads(r.out)
    assert set(s["timings"]) >= {"detect", "shape", "parse", "classify", "bald_target",
                                 "invert", "preview", "write", "total"}
    assert s["files"] == {"head": str(out), "preview": str(tmp_path / "me_preview.png"),
                          "summary": str(tmp_path / "me.json")}
    assert json.loads((tmp_path / "me.json").read_text()) == s
    # Short hair, light colour, a face fitted well at the input view.
    assert s["hair_style"]["name"] in {"pixie", "side swept", "curly short", "crew", "bob",
                                       "side part", "bangs"}
    assert s["hair_color_name"] in {"blonde", "light brown", "brown", "auburn"}
    assert s["psnr_face_input_view"] > 21.0
    assert s["inversion"]["loss_last"] < s["inversion"]["loss_first"]
    head = read_head(out)
    assert head.arrays["texture"].shape[0] == 16 and np.isfinite(head.arrays["texture"]).all()
    assert int(head.arrays["hair_style"]) == s["hair_style"]["id"]
    preview = Image.open(tmp_path / "me_preview.png")
    assert preview.size == (6 * 256, 256)


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
    r = run_cli("classify-hair", astronaut, "--json", "--top", "5")
    c = json.loads(r.out)
    assert len(c["top"]) == 5 and c["top"][0]["score"] >= c["top"][-1]["score"]
    assert c["top"][0]["name"] != "bald"
    assert run_cli("classify-hair", astronaut, "--top", "0").code == 3


def test_demo_writes_a_turntable(run_cli, tmp_path):
    import imageio

    r = run_cli("demo", "-o", tmp_path, "--frames", "4", "--json", "--quiet")
    assert r.code == 0, r.err
    out = json.loads(r.out)
    reader = imageio.get_reader(out["turntable"])
    count = sum(1 for _ in reader)
    assert count == 4
    assert (tmp_path / "astronaut.h360").is_file()

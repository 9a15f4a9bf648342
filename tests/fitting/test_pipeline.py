"""``head360 fit --stage shape`` on real photos (skipped without ../shared/data)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

pytestmark = pytest.mark.shared_data


def test_fit_writes_mesh_overlay_and_params(run_cli, shared_data, tmp_path):
    import trimesh

    photo = shared_data / "faces" / "Tom_Cruise_avp_2014_4.jpg"
    r = run_cli("fit", photo, "--stage", "shape", "-o", tmp_path, "--json")
    assert r.code == 0, r.err
    out = json.loads(r.out)
    for key in ("landmarks_detected", "landmarks_fitted", "face_box", "shape", "expression",
                "pose", "timings"):
        assert key in out
    det, fitted = np.array(out["landmarks_detected"]), np.array(out["landmarks_fitted"])
    assert det.shape == fitted.shape == (68, 2)
    assert (det >= 0).all() and (det[:, 0] < 565).all() and (det[:, 1] < 800).all()
    box = out["face_box"]
    span = np.sqrt((box[2] - box[0]) * (box[3] - box[1]))
    assert np.linalg.norm(det - fitted, axis=1).mean() < 0.06 * span
    assert set(out["pose"]) >= {"yaw", "pitch", "roll", "translation", "focal"}
    assert len(out["expression"]) == 52 and len(out["shape"]) == 50
    from head360cli.mesh.bilinear import load_bilinear

    model = load_bilinear()
    lines = Path(out["files"]["mesh"]).read_text().splitlines()
    assert sum(line.startswith("v ") for line in lines) == model.num_vertices
    assert sum(line.startswith("vt ") for line in lines) == len(model.uv)
    assert sum(line.startswith("f ") for line in lines) == len(model.faces)
    # trimesh opens it (splitting vertices along UV seams, as OBJ readers do).
    mesh = trimesh.load(out["files"]["mesh"], process=False, force="mesh")
    assert len(mesh.faces) == len(model.faces)
    assert Image.open(out["files"]["overlay"]).size == (565, 800)
    assert json.loads(Path(out["files"]["params"]).read_text())["face"] == 0


@pytest.mark.slow
def test_landmarks_are_in_pixels_of_the_image_on_disk(run_cli, shared_data, tmp_path):
    """A 6x upscaled copy is downscaled on load; results map back to its own pixels."""
    photo = shared_data / "faces" / "Tom_Cruise_avp_2014_4.jpg"
    big = tmp_path / "big.jpg"
    img = Image.open(photo)
    img.resize((img.width * 6, img.height * 6), Image.Resampling.BICUBIC).save(big, quality=95)
    def fit(path, out):
        return json.loads(run_cli("fit", "--stage", "shape", path, "-o", out, "--json").out)

    small, large = fit(photo, tmp_path / "a"), fit(big, tmp_path / "b")
    a = np.array(small["landmarks_detected"]) * 6
    b = np.array(large["landmarks_detected"])
    assert np.abs(a - b).mean() < 12.0  # pixels of the 3390 x 4800 image
    assert large["image_size"] == [3390, 4800]


def test_no_face_and_bad_face_numbers(run_cli, shared_data, tmp_path):
    import skimage.data
    import skimage.io

    coffee = tmp_path.parent / "coffee.png"
    skimage.io.imsave(coffee, skimage.data.coffee())
    r = run_cli("fit", "--stage", "shape", coffee, "-o", tmp_path)
    assert r.code == 4 and "no face" in r.err
    photo = shared_data / "faces" / "Tom_Cruise_avp_2014_4.jpg"
    assert run_cli("fit", "--stage", "shape", photo, "--face", "7", "-o", tmp_path).code == 4
    assert run_cli("fit", "--stage", "shape", photo, "--face", "x", "-o", tmp_path).code == 3
    assert list(tmp_path.iterdir()) == []  # nothing half-written


@pytest.mark.slow
def test_several_faces(run_cli, shared_data, tmp_path):
    r = run_cli("fit", "--stage", "shape", shared_data / "faces" / "bald_guys.jpg", "--face",
                "all", "-o", tmp_path, "--json")
    faces = json.loads(r.out)["faces"]
    assert len(faces) >= 5
    areas = [(f["face_box"][2] - f["face_box"][0]) * (f["face_box"][3] - f["face_box"][1])
             for f in faces]
    assert areas == sorted(areas, reverse=True)  # largest first

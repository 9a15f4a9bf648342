"""Scanned skin: reading a scan, laying it over a head, its layers and how the texture
takes them."""

import numpy as np
import pytest

from head360cli.errors import BadInputError
from head360cli.synth.skin import _similarity, align_scan, read_scan, skin_layers


def _rotation(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def test_similarity_recovers_scale_rotation_and_shift():
    rng = np.random.default_rng(0)
    src = rng.normal(size=(30, 3))
    rot = _rotation(25.0)
    dst = 0.4 * src @ rot.T + np.array([0.1, -0.2, 0.3])
    scale, r, t = _similarity(src, dst)
    assert scale == pytest.approx(0.4, abs=1e-9)
    np.testing.assert_allclose(r, rot, atol=1e-9)
    np.testing.assert_allclose(t, [0.1, -0.2, 0.3], atol=1e-9)


def test_align_scan_puts_the_scan_landmarks_on_the_head():
    """A scan that is the head turned, scaled and bent a little lands on the head: its
    inner landmarks exactly (the warp interpolates them), the other points closer than
    the similarity alone puts them."""
    from head360cli.synth.skin import Scan

    rng = np.random.default_rng(1)
    head = rng.normal(scale=0.05, size=(300, 3))
    ids = rng.choice(300, 68, replace=False)
    bent = head + 0.002 * np.sin(head * 20)
    scan_verts = 3.0 * bent @ _rotation(-10).T + 1.0
    scan = Scan(scan_verts, np.zeros((0, 3), int), np.zeros((0, 2)), np.zeros((0, 3), int),
                np.zeros((1, 1, 3), np.uint8))
    moved = align_scan(scan, scan_verts[ids], head, ids)
    np.testing.assert_allclose(moved[ids[17:]], head[ids[17:]], atol=1e-6)
    scale, rot, shift = _similarity(scan_verts[ids[17:]], head[ids[17:]])
    rigid = scale * scan_verts @ rot.T + shift
    warped_mm = 1000 * np.linalg.norm(moved - head, axis=1).mean()
    rigid_mm = 1000 * np.linalg.norm(rigid - head, axis=1).mean()
    assert warped_mm < 0.5 * rigid_mm  # 0.27 against 0.63 mm when written


def test_skin_layers_keep_detail_and_flat_colour():
    atlas = np.zeros((64, 64, 3), np.uint8)
    atlas[8:56, 8:56] = (200, 150, 120)
    atlas[30, 30] = (100, 75, 60)  # one dark dot: a pore
    fine, mid = skin_layers(atlas, 64)
    assert fine.shape == mid.shape == (64, 64, 3)
    assert fine[30, 30].mean() < 0.75  # the dot stays dark
    np.testing.assert_allclose(fine[20, 45], 1.0, atol=0.02)  # flat skin: no change
    np.testing.assert_allclose(mid[20, 45], 1.0, atol=0.02)
    assert (fine[:4] == 1).all() and (mid[:4] == 1).all()  # empty texels: no change


def test_texture_takes_the_detail_on_its_own_tone():
    """The scan's layers change the skin's texels, not the identity's skin tone."""
    from head360cli.synth.appearance import paint_texture, sample_appearance
    from head360cli.synth.identity import sample_identity
    from head360cli.synth.sculpt import build_head, topology

    ident = sample_identity(3)
    look = sample_appearance(3, ident)
    verts, frame = build_head(ident)
    rng = np.random.default_rng(2)
    fine = np.clip(1 + 0.15 * rng.standard_normal((128, 128, 3)), 0.6, 1.4).astype(np.float32)
    mid = np.ones((128, 128, 3), np.float32)
    plain = paint_texture(verts, topology(), frame, ident, look, 128)
    scanned = paint_texture(verts, topology(), frame, ident, look, 128, scan=(fine, mid))
    changed = np.abs(scanned - plain).mean(-1) > 0.01
    assert changed.mean() > 0.2
    np.testing.assert_allclose(scanned.reshape(-1, 3).mean(0), plain.reshape(-1, 3).mean(0),
                               atol=0.02)


def test_read_scan_splits_quads_and_refuses_a_folder_without_one(tmp_path):
    import cv2

    (tmp_path / "head.obj").write_text(
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "f 1/1 2/2 3/3 4/4\n")
    cv2.imwrite(str(tmp_path / "lambertian.jpg"), np.full((8, 8, 3), 90, np.uint8))
    scan = read_scan(tmp_path, texture_side=16)
    assert scan.faces.tolist() == [[0, 1, 2], [0, 2, 3]]
    assert scan.texture.shape == (16, 16, 3)
    with pytest.raises(BadInputError, match=r"head\.obj"):
        read_scan(tmp_path / "nothing")

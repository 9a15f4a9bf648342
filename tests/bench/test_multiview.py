"""bench multiview's parts: the real photos' foreground, turning the fitted head, bins."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from head360cli.bench.multiview import _bins, foreground_mask, orbit


def test_foreground_is_the_head_on_a_wall_lit_from_one_side_with_a_bright_panel():
    h, w = 240, 320
    wall = np.linspace(190, 170, w)[None, :, None].repeat(h, 0).repeat(3, 2)
    wall[:, 280:] = 250  # a white panel on the right
    yy, xx = np.mgrid[0:h, 0:w]
    head = ((xx - 150) / 60.0) ** 2 + ((yy - 110) / 80.0) ** 2 <= 1.0
    img = wall.copy()
    img[head] = (90, 60, 40)  # hair and skin, darker than the wall
    face = head & (((xx - 150) / 35.0) ** 2 + ((yy - 125) / 45.0) ** 2 <= 1.0)
    img[face] = (205, 170, 150)  # skin near the wall's own colour: a hole, filled
    mask = foreground_mask(img.astype(np.uint8))
    iou = (mask & head).sum() / (mask | head).sum()
    assert iou > 0.97


def test_an_empty_wall_has_no_foreground():
    img = np.full((60, 80, 3), 180, np.uint8)
    assert not foreground_mask(img).any()


@pytest.mark.parametrize("yaw", [-90.0, -30.0, 45.0, 180.0])
def test_orbit_turns_a_camera_as_the_rig_places_one_at_that_yaw(yaw):
    from head360cli.geometry.cameras import camera_on_sphere

    front = camera_on_sphere(torch.tensor([0.0]), torch.tensor([0.0]), 1.0,
                             target=(0.0, -0.03, 0.0))[0].numpy()
    turned = camera_on_sphere(torch.tensor([yaw]), torch.tensor([0.0]), 1.0,
                              target=(0.0, -0.03, 0.0))[0].numpy()
    np.testing.assert_allclose(orbit(front, yaw), turned, atol=1e-5)


def test_bins_count_faces_where_the_real_photo_has_one():
    pans = [{"pan": 15, "render_face": True, "real_face": True, "distance": 0.4,
             "real_to_front": 0.3, "iou": 0.9},
            {"pan": -45, "render_face": False, "real_face": True, "distance": None,
             "real_to_front": 0.5, "iou": 0.8},
            {"pan": 60, "render_face": True, "real_face": False, "distance": None,
             "real_to_front": None, "iou": 0.7},
            {"pan": -90, "render_face": False, "real_face": False, "distance": None,
             "real_to_front": None, "iou": None}]
    people = [{"presets": {"fast": {"pans": pans}}}]
    b = {x["yaw"]: x for x in _bins(people, "fast")}
    assert b["15-45"]["distance"] == 0.4 and b["15-45"]["distances"] == 1
    assert b["15-45"]["found_where_real"] == [1, 2]
    assert b["15-45"]["real_to_front"] == pytest.approx(0.4)
    assert b["60"]["found_where_real"] == [0, 0] and b["60"]["found_render"] == [1, 1]
    assert b["75-90"]["iou"] is None and b["75-90"]["found_real"] == [0, 1]
    assert b["15-90"]["iou"] == pytest.approx(0.8)


def test_without_the_shared_photos_it_says_so(run_cli, tmp_path, monkeypatch):
    monkeypatch.setenv("HEAD360_SHARED_DATA", str(tmp_path))
    r = run_cli("bench", "multiview", "--out", tmp_path / "out")
    assert r.code == 3, r.err
    assert "multiview/pointing04" in r.err and len(r.err.strip().splitlines()) == 1


def test_hair_bins_count_reads_where_the_real_photo_has_hair():
    from head360cli.bench.multiview import _hair_bins

    def pan(p, real, iou, de, read, steps):
        return {"pan": p, "real_hair": real, "hair_iou": iou, "hair_delta_e": de,
                "hair_read": read, "hair_steps": steps}

    pans = [pan(0, True, 0.9, 4.0, True, 0), pan(30, True, 0.7, 8.0, False, 2),
            pan(-90, True, 0.5, None, None, 0), pan(90, False, 1.0, None, None, 1)]
    b = {x["yaw"]: x for x in _hair_bins([{"presets": {"fast": {"pans": pans}}}], "fast")}
    assert b["0"]["hair_iou"] == 0.9 and b["0"]["read_where_real"] == [1, 1]
    assert b["15-45"]["hair_delta_e"] == 8.0 and b["15-45"]["steps"] == 2
    # a render without hair where the real photo has some is not read as hair
    assert b["90"]["read_where_real"] == [0, 1] and b["90"]["colours"] == 0
    assert b["90"]["views_with_steps"] == 1 and b["90"]["hair_iou"] == pytest.approx(0.75)
    assert b["15-90"]["views"] == 3 and b["15-90"]["read_where_real"] == [0, 2]

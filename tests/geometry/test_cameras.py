"""Cameras: look-at frames, the 72-camera rig, projection conventions."""

from __future__ import annotations

import math

import pytest
import torch

from head360cli.geometry.cameras import (
    RIG_DISTANCE,
    RIG_TARGET,
    camera_on_sphere,
    intrinsics_from_fov,
    invert_rigid,
    look_at,
    orbit,
    project,
    rig72,
    view_angles,
)


def test_rig_has_72_cameras_pitch_major_every_15_degrees():
    c2w, yaw, pitch = rig72()
    assert c2w.shape == (72, 4, 4)
    assert yaw[:24].tolist() == [15.0 * k for k in range(24)]
    assert pitch.unique().tolist() == [-20.0, 0.0, 20.0]
    assert torch.allclose(c2w[:, :3, 3].norm(dim=-1), torch.ones(72) * 1.0, atol=0.05)


def test_camera_frames_are_orthonormal_and_look_at_the_target():
    c2w = camera_on_sphere(torch.tensor([0.0, 37.0, 90.0, 200.0, 10.0]),
                           torch.tensor([0.0, 10.0, -30.0, 45.0, 90.0]), 1.3,
                           target=(0.0, 0.0, 0.0))
    rot = c2w[:, :3, :3]
    assert torch.allclose(rot.transpose(1, 2) @ rot, torch.eye(3).expand(5, 3, 3), atol=1e-5)
    assert torch.allclose(torch.det(rot), torch.ones(5), atol=1e-5)  # right-handed
    forward = rot[:, :, 2]
    to_target = -torch.nn.functional.normalize(c2w[:, :3, 3], dim=-1)
    assert torch.allclose(forward, to_target, atol=1e-5)


def test_yaw_convention_front_and_subjects_left():
    c2w = camera_on_sphere(torch.tensor([0.0, 90.0]), torch.tensor([0.0, 0.0]), 1.0,
                           target=(0.0, 0.0, 0.0))
    assert torch.allclose(c2w[0, :3, 3], torch.tensor([0.0, 0.0, 1.0]), atol=1e-6)
    assert torch.allclose(c2w[1, :3, 3], torch.tensor([1.0, 0.0, 0.0]), atol=1e-6)
    # Image "down" is world -y for level cameras.
    assert torch.allclose(c2w[:, 1, 1], torch.tensor([-1.0, -1.0]), atol=1e-6)


def test_projection_centre_and_sides():
    k = intrinsics_from_fov(30.0, 64, 48)
    c2w = look_at(torch.tensor([[0.0, 0.0, 2.0]]), torch.zeros(3))
    pts = torch.tensor([[[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]]])
    pix, depth = project(pts, c2w, k)
    assert torch.allclose(pix[0, 0], torch.tensor([32.0, 24.0]))
    assert torch.allclose(depth, torch.full((1, 3), 2.0))
    # Facing the subject, world +x (the subject's left) appears on the image's right.
    assert pix[0, 1, 0] > 32.0
    assert pix[0, 2, 1] < 24.0  # world up is image up
    f = 0.5 * 48 / math.tan(math.radians(15))
    assert pix[0, 1, 0] == pytest.approx(32.0 + f * 0.1 / 2.0, abs=1e-4)


def test_invert_rigid_and_orbit():
    c2w = orbit(12, pitch_deg=15.0)
    eye = torch.eye(4).expand(12, 4, 4)
    assert torch.allclose(invert_rigid(c2w) @ c2w, eye, atol=1e-5)
    assert torch.allclose(c2w[:, 1, 3], c2w[0, 1, 3].expand(12))  # constant height


def test_straight_down_view_is_well_defined():
    c2w = camera_on_sphere(torch.tensor([0.0]), torch.tensor([90.0]), 1.0)
    assert torch.isfinite(c2w).all()
    assert torch.allclose(torch.det(c2w[0, :3, :3]), torch.tensor(1.0), atol=1e-5)


def test_view_angles_invert_camera_on_sphere():
    yaw = torch.tensor([0.0, 30.0, -75.0, 170.0, 45.0])
    pitch = torch.tensor([0.0, 10.0, -20.0, 35.0, -60.0])
    for dist, target in ((RIG_DISTANCE, RIG_TARGET), (0.6, (0.01, 0.0, -0.02))):
        got_yaw, got_pitch = view_angles(camera_on_sphere(yaw, pitch, dist, target))
        torch.testing.assert_close(got_yaw, yaw, atol=1e-3, rtol=0)
        torch.testing.assert_close(got_pitch, pitch, atol=1e-3, rtol=0)
    # the frontal rig camera: both 0; a camera above looks down (pitch > 0)
    _, down = view_angles(camera_on_sphere(torch.tensor([0.0]), torch.tensor([12.0]), 1.0))
    assert down.item() == pytest.approx(12.0, abs=1e-3)

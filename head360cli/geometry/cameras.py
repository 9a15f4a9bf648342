"""Cameras as pure batched functions: look-at, intrinsics, the 72-camera rig, orbits.

Conventions (see DESIGN): world is right-handed, +y up, the face looks along +z, metres.
A camera is a 4x4 camera-to-world matrix whose columns are the camera's x (right), y (down)
and z (forward) axes and its centre, as in OpenCV, plus 3x3 intrinsics. Pixel centres sit at
``+0.5``: pixel ``(row i, column j)`` covers the point ``(j + 0.5, i + 0.5)``.

Yaw 0 looks at the face; positive yaw moves the camera towards +x, the subject's left, so it
shows the head's left side. Positive pitch raises the camera (it looks down on the head).
"""

from __future__ import annotations

import math

import torch

from head360cli.geometry.rig import (
    RIG_DISTANCE,
    RIG_FOV_DEG,
    RIG_PITCHES_DEG,
    RIG_TARGET,
    RIG_YAWS_DEG,
)

__all__ = [
    "RIG_DISTANCE",
    "RIG_FOV_DEG",
    "RIG_PITCHES_DEG",
    "RIG_TARGET",
    "RIG_YAWS_DEG",
    "camera_on_sphere",
    "intrinsics_from_fov",
    "invert_rigid",
    "look_at",
    "orbit",
    "project",
    "rig72",
    "view_angles",
]


def look_at(eye: torch.Tensor, target: torch.Tensor, up: torch.Tensor | None = None
            ) -> torch.Tensor:
    """Camera-to-world matrices of cameras at ``eye`` looking at ``target``.

    Args:
        eye: ``(B, 3)`` camera centres.
        target: ``(B, 3)`` or ``(3,)`` points looked at.
        up: ``(3,)`` world up (default +y). Must not be parallel to the viewing direction.

    Returns:
        ``(B, 4, 4)`` camera-to-world, OpenCV axes (x right, y down, z forward).
    """
    target = target.expand_as(eye)
    if up is None:
        up = torch.tensor([0.0, 1.0, 0.0], dtype=eye.dtype, device=eye.device)
    forward = torch.nn.functional.normalize(target - eye, dim=-1)
    right = torch.nn.functional.normalize(torch.cross(forward, up.expand_as(eye), dim=-1), dim=-1)
    down = torch.cross(forward, right, dim=-1)
    c2w = torch.zeros(eye.shape[0], 4, 4, dtype=eye.dtype, device=eye.device)
    c2w[:, :3, 0] = right
    c2w[:, :3, 1] = down
    c2w[:, :3, 2] = forward
    c2w[:, :3, 3] = eye
    c2w[:, 3, 3] = 1.0
    return c2w


def invert_rigid(c2w: torch.Tensor) -> torch.Tensor:
    """Invert ``(..., 4, 4)`` rigid transforms (rotation + translation) exactly."""
    rot = c2w[..., :3, :3]
    t = c2w[..., :3, 3:]
    out = torch.zeros_like(c2w)
    out[..., :3, :3] = rot.transpose(-1, -2)
    out[..., :3, 3:] = -rot.transpose(-1, -2) @ t
    out[..., 3, 3] = 1.0
    return out


def intrinsics_from_fov(fov_y_deg: float, width: int, height: int,
                        dtype: torch.dtype = torch.float32,
                        device: torch.device | str | None = None) -> torch.Tensor:
    """``(3, 3)`` pinhole intrinsics with square pixels and the centre of the image.

    Args:
        fov_y_deg: Vertical field of view in degrees.
        width: Image width in pixels.
        height: Image height in pixels.
    """
    f = 0.5 * height / math.tan(math.radians(fov_y_deg) / 2)
    return torch.tensor([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]],
                        dtype=dtype, device=device)


def camera_on_sphere(yaw_deg: torch.Tensor, pitch_deg: torch.Tensor, distance: float,
                     target: tuple[float, float, float] = RIG_TARGET) -> torch.Tensor:
    """Cameras on a sphere around ``target`` looking at it.

    Args:
        yaw_deg: ``(B,)`` yaw in degrees (0 = in front of the face, + = subject's left).
        pitch_deg: ``(B,)`` pitch in degrees (+ = above).
        distance: Radius in metres.
        target: The centre looked at.

    Returns:
        ``(B, 4, 4)`` camera-to-world matrices.
    """
    yaw = torch.deg2rad(yaw_deg)
    pitch = torch.deg2rad(pitch_deg)
    tgt = torch.tensor(target, dtype=yaw.dtype, device=yaw.device)
    eye = torch.stack([torch.sin(yaw) * torch.cos(pitch), torch.sin(pitch),
                       torch.cos(yaw) * torch.cos(pitch)], dim=-1) * distance + tgt
    # Straight above or below, "up" is undefined: use the face direction instead.
    vertical = pitch.abs() > math.radians(89.9)
    c2w = look_at(eye, tgt)
    if bool(vertical.any()):
        alt = look_at(eye, tgt, torch.tensor([0.0, 0.0, 1.0], dtype=yaw.dtype,
                                             device=yaw.device))
        c2w = torch.where(vertical[:, None, None], alt, c2w)
    return c2w


def view_angles(c2w: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The yaw and pitch in degrees from which cameras ``c2w (B, 4, 4)`` look: those of
    :func:`camera_on_sphere` for cameras it made, whatever their distance and target
    (only the line of sight counts).

    Returns:
        ``(yaw (B,), pitch (B,))`` in degrees (yaw 0: in front of the face, + = subject's
        left; pitch + = looking down from above).
    """
    forward = c2w[..., :3, 2]
    pitch = torch.rad2deg(torch.asin((-forward[..., 1]).clamp(-1.0, 1.0)))
    yaw = torch.rad2deg(torch.atan2(-forward[..., 0], -forward[..., 2]))
    return yaw, pitch


def rig72(dtype: torch.dtype = torch.float32, device: torch.device | str | None = None
          ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The 72-camera training rig: 3 pitches x 24 yaws (every 15 degrees).

    Returns:
        ``(c2w (72, 4, 4), yaw_deg (72,), pitch_deg (72,))``, pitch-major: camera
        ``k = 24 * p + y``.
    """
    pitch = torch.tensor(RIG_PITCHES_DEG, dtype=dtype, device=device).repeat_interleave(24)
    yaw = torch.tensor(RIG_YAWS_DEG, dtype=dtype, device=device).repeat(3)
    return camera_on_sphere(yaw, pitch, RIG_DISTANCE), yaw, pitch


def orbit(frames: int, pitch_deg: float = 0.0, distance: float = RIG_DISTANCE,
          start_yaw_deg: float = 0.0, dtype: torch.dtype = torch.float32
          ) -> torch.Tensor:
    """``(frames, 4, 4)`` cameras turning once around the head (a turntable)."""
    yaw = start_yaw_deg + torch.arange(frames, dtype=dtype) * (360.0 / frames)
    return camera_on_sphere(yaw, torch.full_like(yaw, pitch_deg), distance)


def project(points: torch.Tensor, c2w: torch.Tensor, intrinsics: torch.Tensor
            ) -> tuple[torch.Tensor, torch.Tensor]:
    """Project world points to pixels.

    Args:
        points: ``(B, N, 3)`` world points.
        c2w: ``(B, 4, 4)`` camera-to-world.
        intrinsics: ``(B, 3, 3)`` or ``(3, 3)``.

    Returns:
        ``(pixels (B, N, 2), depth (B, N))``: OpenCV pixel coordinates (x right, y down)
        and the depth along the camera's z axis. Points behind the camera have depth <= 0
        and meaningless pixels.
    """
    # R^T (p - t) written out element by element rather than as a matrix product: the
    # result is then rounded the same way by torch and by onnxruntime (whose GEMM kernels
    # sum in another order), so an exported rasterizer covers the same pixels.
    rot = c2w[:, None, :3, :3]
    d = points - c2w[:, None, :3, 3]
    cam = (d[..., 0:1] * rot[..., 0, :] + d[..., 1:2] * rot[..., 1, :]
           + d[..., 2:3] * rot[..., 2, :])
    depth = cam[..., 2]
    safe = torch.where(depth.abs() < 1e-9, torch.full_like(depth, 1e-9), depth)
    k = intrinsics.expand(points.shape[0], 3, 3)
    x = k[:, None, 0, 0] * cam[..., 0] / safe + k[:, None, 0, 2]
    y = k[:, None, 1, 1] * cam[..., 1] / safe + k[:, None, 1, 2]
    return torch.stack([x, y], dim=-1), depth

"""The 72-camera rig's constants, without torch: numpy-only code (the landmark shape fit)
reads them too. :mod:`head360cli.geometry.cameras` builds the rig's cameras from them."""

from __future__ import annotations

__all__ = ["RIG_DISTANCE", "RIG_FOV_DEG", "RIG_PITCHES_DEG", "RIG_TARGET", "RIG_YAWS_DEG"]

RIG_PITCHES_DEG = (-20.0, 0.0, 20.0)
"""The rig's three camera heights (degrees above the horizon)."""
RIG_YAWS_DEG = tuple(float(15 * k) for k in range(24))
"""The rig's 24 yaw angles, every 15 degrees starting at the front."""
RIG_DISTANCE = 1.0
"""Distance from the rig's cameras to their target, metres."""
RIG_FOV_DEG = 24.0
"""Vertical field of view of the rig's cameras, degrees (0.43 m of height at the target)."""
RIG_TARGET = (0.0, -0.03, 0.0)
"""Point the rig looks at: a little below the head centre, to frame head, neck and hair.
The shape fit measures the camera's distance to the head from this point."""

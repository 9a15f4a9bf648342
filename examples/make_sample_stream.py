"""Regenerate examples/smile_blink_livelinkface.csv, the bundled ARKit-52 sample stream.

A 4-second, 60 fps take written by head360's own CSV writer in the Live Link Face layout:
two blinks, a smile that builds and fades, speech-like jaw movement, a brow raise and a
slow head turn. Run from the repository root:

    python examples/make_sample_stream.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from head360cli.io.arkit import ArkitStream, write_arkit_csv
from head360cli.mesh.arkit52 import INDEX, NUM_BLENDSHAPES

FPS = 60.0
SECONDS = 4.0


def bump(t: np.ndarray, centre: float, width: float) -> np.ndarray:
    """A smooth 0..1..0 pulse."""
    return np.exp(-0.5 * ((t - centre) / width) ** 2)


def make_stream() -> ArkitStream:
    t = np.arange(int(FPS * SECONDS)) / FPS
    w = np.zeros((len(t), NUM_BLENDSHAPES), dtype=np.float64)
    blink = bump(t, 0.8, 0.05) + bump(t, 2.9, 0.05)
    w[:, INDEX["eyeBlinkLeft"]] = blink
    w[:, INDEX["eyeBlinkRight"]] = blink
    smile = np.clip((t - 1.0) / 0.6, 0, 1) * np.clip((3.4 - t) / 0.6, 0, 1)
    w[:, INDEX["mouthSmileLeft"]] = 0.8 * smile
    w[:, INDEX["mouthSmileRight"]] = 0.75 * smile
    w[:, INDEX["cheekSquintLeft"]] = 0.4 * smile
    w[:, INDEX["cheekSquintRight"]] = 0.38 * smile
    talk = (t > 0.3) & (t < 2.2)
    w[:, INDEX["jawOpen"]] = np.where(talk, 0.25 + 0.25 * np.sin(2 * np.pi * 4.5 * t), 0.02)
    w[:, INDEX["mouthClose"]] = np.where(talk, 0.05, 0.0)
    brow = bump(t, 3.3, 0.25)
    w[:, INDEX["browInnerUp"]] = 0.7 * brow
    w[:, INDEX["browOuterUpLeft"]] = 0.5 * brow
    w[:, INDEX["browOuterUpRight"]] = 0.5 * brow
    head = np.zeros((len(t), 3), dtype=np.float32)
    head[:, 0] = np.radians(15.0) * np.sin(2 * np.pi * t / SECONDS)  # yaw
    head[:, 1] = np.radians(4.0) * np.sin(2 * np.pi * t / 2.0)  # pitch
    return ArkitStream(
        weights=np.clip(w, 0, 1).astype(np.float32),
        timestamps=t,
        fps=FPS,
        nominal_fps=FPS,
        head_rotation=head,
        eye_rotation=np.zeros((len(t), 6), dtype=np.float32),
    )


if __name__ == "__main__":
    out = Path(__file__).resolve().parent / "smile_blink_livelinkface.csv"
    write_arkit_csv(make_stream(), out, flavor="livelinkface", decimals=4,
                    start_seconds=12 * 3600.0)
    print(f"wrote {out}")

"""Face tracking: head and eye rotations, the One Euro filter, the tracker on a moving face
and the policies for frames without one."""

from __future__ import annotations

import numpy as np
import pytest

from head360cli.errors import NoFaceError
from head360cli.perception.track import (
    FaceTracker,
    OneEuroFilter,
    TrackConfig,
    _canonical,
    eye_rotation,
    head_rotation,
    track_video,
)


@pytest.mark.parametrize("angles", [(0.3, 0.0, 0.0), (0.0, 0.25, 0.0), (0.0, 0.0, -0.2),
                                    (-0.4, 0.15, 0.1)])
def test_head_rotation_reads_back_a_turned_canonical_face(angles):
    """The canonical face turned by head_motion's rotation (the convention animate
    applies) and seen as the mesh gives points (pixels, y down, depth smaller nearer)
    reads back as the same yaw, pitch and roll."""
    from head360cli.drive.animate import head_motion

    rot = head_motion(np.array([angles]))[0, :3, :3]
    turned = _canonical() @ rot.T
    seen = np.zeros((478, 3))
    seen[:468] = turned * np.array([6.0, -6.0, -6.0]) + np.array([320.0, 240.0, 0.0])
    np.testing.assert_allclose(head_rotation(seen), angles, atol=1e-5)


def test_eye_rotation_turns_both_eyes_the_same_way():
    from head360cli.mesh.arkit52 import INDEX

    w = np.zeros(52, np.float32)
    # both eyes look towards the head's left: the left eye out, the right eye in
    w[INDEX["eyeLookOutLeft"]] = w[INDEX["eyeLookInRight"]] = 1.0
    w[INDEX["eyeLookDownLeft"]] = w[INDEX["eyeLookDownRight"]] = 0.5
    e = eye_rotation(w)
    assert e[0] == pytest.approx(e[3]) and e[0] != 0
    assert e[1] == pytest.approx(e[4]) == pytest.approx(0.263, abs=1e-3)
    assert e[2] == e[5] == 0


def test_one_euro_steadies_a_still_signal_and_follows_a_fast_one():
    rng = np.random.default_rng(0)
    t = np.arange(200) / 60.0
    still = 0.5 + 0.03 * rng.standard_normal(200)
    f = OneEuroFilter(1.5, 2.0)
    out = np.array([f(ti, np.array([x]))[0] for ti, x in zip(t, still, strict=True)])
    assert out[50:].std() < 0.4 * still[50:].std()
    # a blink: 0 -> 1 within two frames; the filter passes most of it at once
    step = np.where(t < 1.0, 0.0, 1.0)
    f = OneEuroFilter(1.5, 2.0)
    out = np.array([f(ti, np.array([x]))[0] for ti, x in zip(t, step, strict=True)])
    first = int(np.argmax(t >= 1.0))
    assert out[first + 3] > 0.8
    slow = OneEuroFilter(1.5, 0.0)  # without the speed term it lags
    lag = np.array([slow(ti, np.array([x]))[0] for ti, x in zip(t, step, strict=True)])
    assert lag[first + 3] < 0.6


def _astronaut_frames(count: int, blank_first: int = 0) -> list[np.ndarray]:
    import cv2
    from skimage import data

    face = cv2.resize(data.astronaut(), (240, 240), interpolation=cv2.INTER_AREA)
    frames = []
    for i in range(count):
        frame = np.full((240, 320, 3), 200, np.uint8)
        if i >= blank_first:
            dx = int(30 + 20 * np.sin(i / 4))
            frame[:, dx:dx + 240] = face
        frames.append(frame)
    return frames


def test_the_tracker_follows_a_moving_face_and_detects_it_once():
    from head360cli.mesh.arkit52 import INDEX

    tracker = FaceTracker()
    readings = [tracker(f) for f in _astronaut_frames(12)]
    assert all(r is not None for r in readings)
    assert [r.detected for r in readings].count(True) == 1
    smiles = [r.weights[INDEX["mouthSmileLeft"]] for r in readings]
    assert min(smiles) > 0.5  # the astronaut smiles in every frame
    assert all(abs(np.degrees(r.head[0])) < 15 for r in readings)
    assert tracker(np.full((240, 320, 3), 200, np.uint8)) is None  # lost: searched again


@pytest.fixture(scope="module")
def blank_then_face(tmp_path_factory):
    """A folder of 10 frames: 3 without a face, then the astronaut."""
    import cv2

    folder = tmp_path_factory.mktemp("frames")
    for i, frame in enumerate(_astronaut_frames(10, blank_first=3)):
        cv2.imwrite(str(folder / f"{i:04d}.png"), frame[:, :, ::-1])
    return folder


def test_frames_without_a_face_are_held_skipped_or_stop_the_run(blank_then_face):
    stream, summary = track_video(blank_then_face, TrackConfig(fps=10.0))
    assert stream.num_frames == 10 and summary["frames_held"] == 3
    np.testing.assert_array_equal(stream.weights[0], stream.weights[3])  # held from the first
    assert stream.fps == pytest.approx(10.0)
    assert any("no face in 3 of 10 frames" in w for w in summary["warnings"])
    skipped, summary = track_video(blank_then_face, TrackConfig(fps=10.0, on_bad="skip"))
    assert skipped.num_frames == 7 and summary["frames_skipped"] == 3
    assert skipped.timestamps[-1] == pytest.approx(0.6)
    with pytest.raises(NoFaceError, match=r"frame 0 \(0.000 s\)"):
        track_video(blank_then_face, TrackConfig(on_bad="error"))
    with pytest.raises(NoFaceError, match="found none in the 2 frames"):  # 0 and 0.1 s
        track_video(blank_then_face, TrackConfig(fps=10.0, end=0.2))


def test_track_config_refuses_settings_no_run_tracks_with():
    from head360cli.errors import BadInputError

    for kwargs, says in (({"face": -1}, "--face"), ({"smooth": -1}, "--smooth"),
                         ({"on_bad": "drop"}, "--on-bad"), ({"start": 2, "end": 1}, "--end")):
        with pytest.raises(BadInputError, match=says):
            TrackConfig(**kwargs)

"""The template: regions and the 68 iBUG landmark vertices."""

from __future__ import annotations

import numpy as np

from head360cli.mesh.template import CONTOUR_LANDMARKS, REGION_NAMES, template
from head360cli.synth.identity import mean_identity
from head360cli.synth.sculpt import build_head


def test_every_region_is_used():
    t = template()
    counts = np.bincount(t.region, minlength=len(REGION_NAMES))
    assert (counts > 20).all(), dict(zip(REGION_NAMES, counts, strict=True))


def test_landmarks_are_68_distinct_vertices_on_their_features():
    t = template()
    verts, frame = build_head(mean_identity())
    lm = t.landmarks
    assert lm.shape == (68,) and len(set(lm.tolist())) == 68
    region = [REGION_NAMES[r] for r in t.region[lm]]
    assert all(r in ("lips", "mouth_interior") for r in region[48:68]), region[48:68]
    assert all(r in ("nose", "face") for r in region[27:36])
    p = verts[lm]
    # The nose tip (30) stands out furthest; brows sit above the eyes; eyes around their
    # centres; the chin (8) is the lowest point.
    assert np.argmax(p[:, 2]) == 30
    assert p[17:27, 1].min() > p[36:48, 1].max()
    for ids, centre in ((range(36, 42), frame.eye_centres[1]), (range(42, 48),
                                                                  frame.eye_centres[0])):
        d = np.linalg.norm(p[list(ids), :2] - centre[:2], axis=1)
        assert (d < frame.eye_half_width + 0.002).all()
    assert p[8, 1] <= p[:17, 1].min() + 1e-9  # 7-9 share the chin's lowest row
    # Image order: x increases along the jaw, along each brow, over each upper lid.
    for seq in (range(0, 17), range(17, 22), range(22, 27), range(36, 40), range(42, 46),
                range(48, 55)):
        assert (np.diff(p[list(seq), 0]) > 0).all(), list(seq)
    assert tuple(range(17)) == CONTOUR_LANDMARKS


def test_landmarks_are_left_right_mirrors():
    """iBUG pairs (e.g. 36 and 45, the outer eye corners) are mirror vertices."""
    t = template()
    pairs = [(0, 16), (8, 8), (17, 26), (21, 22), (36, 45), (39, 42), (31, 35), (48, 54),
             (51, 51), (60, 64)]
    for a, b in pairs:
        assert t.mirror[t.landmarks[a]] == t.landmarks[b], (a, b)

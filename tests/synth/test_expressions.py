"""The 52 blendshapes: mirror pairs, locality, real mouth and lid motion, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from head360cli.mesh.arkit52 import ARKIT52, INDEX, MIRROR
from head360cli.mesh.template import REGION_NAMES, template
from head360cli.synth.expressions import blendshape_deltas
from head360cli.synth.identity import mean_identity, sample_identity
from head360cli.synth.sculpt import build_head, topology

# Where each shape may move the head (>= 95 % of its total displacement must fall here).
FACE = {"face", "nose", "lips", "mouth_interior"}
ALLOWED = {name: FACE for name in ARKIT52}
ALLOWED.update({n: FACE | {"teeth", "tongue", "neck"} for n in
                ("jawOpen", "jawLeft", "jawRight", "jawForward", "mouthClose")})
ALLOWED.update({n: {"eyes"} for n in ARKIT52 if n.startswith("eyeLook")})
ALLOWED.update({n: {"face"} for n in ARKIT52 if n.startswith(("eyeBlink", "eyeSquint",
                                                                "eyeWide"))})
# Brows also move the glabella at the top of the nasal bridge.
ALLOWED.update({n: {"face", "nose"} for n in ARKIT52 if n.startswith("brow")})
ALLOWED["tongueOut"] = {"tongue"}


@pytest.fixture(scope="module", params=[0, 5])
def head(request):
    p = sample_identity(request.param) if request.param else mean_identity()
    verts, frame = build_head(p)
    return verts, frame, blendshape_deltas(verts, frame)


def test_every_shape_moves_something_finite(head):
    _, _, deltas = head
    assert deltas.shape == (52, topology().num_vertices, 3)
    assert np.isfinite(deltas).all()
    peak = np.linalg.norm(deltas, axis=2).max(axis=1)
    assert (peak > 0.0015).all(), [ARKIT52[i] for i in np.nonzero(peak <= 0.0015)[0]]
    assert peak.max() < 0.045  # nothing moves more than 4.5 cm (the open jaw: ~4 cm)


def test_left_right_pairs_mirror_each_other(head):
    """On an asymmetric identity the pairs still mirror to within 1 % of their peak."""
    _, _, deltas = head
    mirror = topology().mirror
    flip = np.array([-1.0, 1.0, 1.0])
    for name in ARKIT52:
        if name.endswith("Left"):
            left, right = deltas[INDEX[name]], deltas[INDEX[MIRROR[name]]]
            err = np.abs(right - left[mirror] * flip).max()
            assert err <= 0.01 * np.abs(left).max(), name


def test_each_shape_stays_in_its_region(head):
    _, _, deltas = head
    region = template().region
    for name in ARKIT52:
        amount = np.linalg.norm(deltas[INDEX[name]], axis=1)
        allowed = np.isin(region, [REGION_NAMES.index(r) for r in ALLOWED[name]])
        share = amount[allowed].sum() / amount.sum()
        assert share >= 0.95, (name, round(float(share), 3))


def test_jaw_opens_the_mouth_and_lids_close(head):
    verts, _, deltas = head
    lm = template().landmarks
    w = np.zeros(52)
    w[INDEX["jawOpen"]] = 1.0
    opened = verts + np.tensordot(w, deltas, 1)
    gap = opened[lm[62], 1] - opened[lm[66], 1]  # inner upper vs inner lower lip
    assert 0.025 < gap < 0.045
    assert abs(verts[lm[62], 1] - verts[lm[66], 1]) < 1e-9  # closed at rest
    for blink, upper, lower in (("eyeBlinkRight", 37, 41), ("eyeBlinkLeft", 44, 46)):
        w = np.zeros(52)
        w[INDEX[blink]] = 1.0
        closed = verts + np.tensordot(w, deltas, 1)
        rest = verts[lm[upper], 1] - verts[lm[lower], 1]
        now = closed[lm[upper], 1] - closed[lm[lower], 1]
        assert rest > 0.009 and now < 0.003, (blink, rest, now)


def test_deltas_are_deterministic():
    p = sample_identity(11)
    a = blendshape_deltas(*build_head(p))
    b = blendshape_deltas(*build_head(p))
    assert a.tobytes() == b.tobytes()

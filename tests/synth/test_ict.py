"""ICT-FaceKit's expressions carried onto the template: the shipped fields are what the
command makes, lips and lids part where they should, pairs mirror exactly."""

from __future__ import annotations

import numpy as np
import pytest

from head360cli.errors import FileFormatError
from head360cli.mesh.arkit52 import ARKIT52, INDEX, MIRROR
from head360cli.mesh.template import template
from head360cli.paths import models_dir, shared_data_dir
from head360cli.synth.expressions import (
    FROM_TEMPLATE,
    blendshape_deltas,
    load_fields,
    procedural_deltas,
    save_fields,
)
from head360cli.synth.identity import mean_identity, sample_identity
from head360cli.synth.sculpt import build_head, topology

ICT = shared_data_dir() / "ict-facekit" if shared_data_dir() else None
needs_ict = pytest.mark.skipif(ICT is None or not ICT.is_dir(),
                               reason="needs ../shared/data/ict-facekit")


@pytest.fixture(scope="module")
def built():
    from head360cli.synth.ict import build_expressions

    return build_expressions(ICT)


@needs_ict
def test_shipped_fields_are_what_build_expressions_makes(built):
    shipped = load_fields(models_dir() / "expressions.npz")
    np.testing.assert_allclose(shipped["deltas"], built["deltas"], atol=2e-5)  # float16
    assert shipped["meta"]["source_sha256"] == built["meta"]["source_sha256"]


@needs_ict
def test_alignment_and_jaw_are_those_of_a_real_face(built):
    meta = built["meta"]
    assert meta["landmark_error_mm_before_warp"] < 6.0  # similarity alone, 52 points
    assert 20.0 < meta["jaw_rotation_degrees"]["jawOpen"] < 30.0  # ICT's jaw: 25 degrees
    assert 0.85 < meta["scale"] < 1.0


@needs_ict
def test_pairs_mirror_exactly_and_template_shapes_are_left_out(built):
    d = built["deltas"]
    mirror, flip = topology().mirror, np.array([-1.0, 1.0, 1.0])
    for name in ARKIT52:
        np.testing.assert_allclose(d[INDEX[MIRROR[name]]], d[INDEX[name]][mirror] * flip,
                                   atol=1e-12, err_msg=name)
    for name in FROM_TEMPLATE:
        assert not d[INDEX[name]].any(), name


@needs_ict
def test_open_jaw_parts_the_lips_and_takes_teeth_and_tongue(built):
    lm, topo = template().landmarks, topology()
    d = built["deltas"][INDEX["jawOpen"]]
    upper, lower = d[lm[62]], d[lm[66]]  # inner lips, middle
    assert np.linalg.norm(upper) < 0.006 and lower[1] < -0.02  # the lower lip drops 2+ cm
    teeth = np.arange(*topo.parts["teeth_lower"])
    drop = d[teeth, 1].mean()
    assert drop < -0.01 and not d[np.arange(*topo.parts["teeth_upper"])].any()
    # the smile lifts the corner of its own side only
    smile = built["deltas"][INDEX["mouthSmileLeft"]]
    assert smile[lm[54], 1] > 0.003 and abs(smile[lm[48], 1]) < 0.001


def test_fields_file_round_trips_and_refuses_other_files(tmp_path):
    rng = np.random.default_rng(0)
    d = np.zeros((52, 40, 3))
    d[3, 5:9] = rng.normal(0, 0.01, (4, 3))
    d[20, 0] = [0.001, 0.0, -0.002]
    out = tmp_path / "fields.npz"
    save_fields({"deltas": d, "meta": {"format": 1}}, out)
    back = load_fields(out)
    np.testing.assert_allclose(back["deltas"], d, atol=1e-5)
    assert back["meta"] == {"format": 1}
    bad = tmp_path / "other.npz"
    np.savez(bad, x=np.zeros(3))
    with pytest.raises(FileFormatError, match="not a head360 expressions file"):
        load_fields(bad)


def test_each_head_takes_the_fields_at_its_own_size_with_its_own_blinks():
    shipped = load_fields(models_dir() / "expressions.npz")["deltas"]
    for identity in (mean_identity(), sample_identity(7)):
        verts, frame = build_head(identity)
        d = blendshape_deltas(verts, frame, "scanned")
        own = procedural_deltas(verts, frame)
        np.testing.assert_array_equal(blendshape_deltas(verts, frame), own)  # the default
        np.testing.assert_array_equal(d[INDEX["eyeBlinkLeft"]], own[INDEX["eyeBlinkLeft"]])
        j = INDEX["mouthSmileLeft"]
        ratio = np.linalg.norm(d[j]) / np.linalg.norm(shipped[j])
        assert 0.8 < ratio < 1.2
        assert np.linalg.norm(d[INDEX["eyeBlinkLeft"]], axis=1).max() > 0.005
        eyes = np.arange(*topology().parts["eye_l"])
        assert np.linalg.norm(d[INDEX["eyeLookInLeft"]][eyes], axis=1).max() > 0.002


@pytest.fixture(scope="module")
def identities():
    from head360cli.synth.ict import build_identities

    return build_identities(ICT)


@needs_ict
def test_shipped_identity_fields_are_what_build_identities_makes(identities):
    shipped = load_fields(models_dir() / "identities.npz", "identities")
    np.testing.assert_allclose(shipped["deltas"], identities["deltas"], atol=2e-5)  # float16
    assert shipped["meta"]["source_sha256"] == identities["meta"]["source_sha256"]
    assert shipped["deltas"].shape[0] == 100
    with pytest.raises(FileFormatError, match="expected expressions format 1, found "
                                              "identities"):
        load_fields(models_dir() / "identities.npz")


@needs_ict
def test_identity_fields_move_rigid_parts_rigidly_and_spare_the_neck(identities):
    d, topo, tpl = identities["deltas"], topology(), template()
    for part in ("eye_l", "eye_r", "teeth_upper", "teeth_lower", "tongue", "ear_l"):
        ids = np.arange(*topo.parts[part])
        np.testing.assert_allclose(d[:, ids], d[:, ids[:1]].repeat(len(ids), 1),
                                   atol=1e-12, err_msg=part)
    # the lids move with their eyeball, so each head's own blink still closes them
    verts, frame = build_head(mean_identity())
    blink = np.linalg.norm(procedural_deltas(verts, frame)[INDEX["eyeBlinkLeft"]], axis=1) > 0
    ball = d[:, topo.parts["eye_l"][0]]
    np.testing.assert_allclose(d[:, blink], ball[:, None].repeat(blink.sum(), 1), atol=1e-12)
    # ICT's scale: the first component moves the face by millimetres, the neck's foot not
    face = tpl.region == 1
    rms = np.sqrt((np.linalg.norm(d[0][face], axis=1) ** 2).mean())
    assert 0.002 < rms < 0.006
    foot = verts[:, 1] < verts[:, 1].min() + 0.01
    assert not d[:, foot].any()


@needs_ict
def test_scanned_heads_vary_as_icts_faces_without_folding():
    import dataclasses

    from head360cli.synth.scanned import SCULPT_KEEP, scanned_identity

    faces = topology().faces

    def normals(x):
        return np.cross(x[faces[:, 1]] - x[faces[:, 0]], x[faces[:, 2]] - x[faces[:, 0]])

    heads = [scanned_identity(sample_identity(s), s) for s in range(8)]
    for s, (verts, deltas) in enumerate(heads):
        params = sample_identity(s)
        sculpt, _ = build_head(dataclasses.replace(
            mean_identity(), **{k: getattr(params, k) for k in SCULPT_KEEP}))
        n0 = normals(sculpt)
        ok = np.linalg.norm(n0, axis=1) > 1e-10
        assert ((normals(verts)[ok] * n0[ok]).sum(1) > 0).all()  # no triangle turns over
        assert deltas.shape == (52, *verts.shape)
    face = template().region == 1
    spread = np.std([v[face] for v, _ in heads], axis=0)
    assert 0.002 < np.linalg.norm(spread, axis=1).mean() < 0.012
    # the same draw makes the same head
    np.testing.assert_array_equal(scanned_identity(sample_identity(3), 3)[0], heads[3][0])


@needs_ict
def test_build_identities_command_writes_the_fields_and_refuses_other_suffixes(run_cli,
                                                                               tmp_path):
    out = tmp_path / "ids.npz"
    r = run_cli("build-identities", ICT, "-o", out, "--json")
    assert r.code == 0, r.err
    shipped = load_fields(models_dir() / "identities.npz", "identities")["deltas"]
    np.testing.assert_array_equal(load_fields(out, "identities")["deltas"], shipped)
    bad = run_cli("build-identities", ICT, "-o", tmp_path / "ids.txt")
    assert bad.code == 3 and "expected an output ending in .npz" in bad.err
    assert not (tmp_path / "ids.txt").exists()

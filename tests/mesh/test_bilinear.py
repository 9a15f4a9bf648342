"""The bilinear model: build, torch/numpy agreement, exact spans, mirror, storage, errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from head360cli.errors import FileFormatError, ModelNotFoundError
from head360cli.mesh.arkit52 import MIRROR_INDEX
from head360cli.mesh.bilinear import BilinearHead, build_bilinear, load_bilinear
from head360cli.mesh.build import reconstruction_error
from head360cli.mesh.corpora import synthead_p

FLIP = np.array([-1.0, 1.0, 1.0])


@pytest.fixture(scope="module")
def corpus():
    it, topo = synthead_p(8, seed=5)
    return list(it), topo


def reflect(neutral, deltas, vm):
    return neutral[vm] * FLIP, deltas[list(MIRROR_INDEX)][:, vm] * FLIP


def test_full_rank_reproduces_the_training_identities(corpus):
    ids, topo = corpus
    model = build_bilinear(ids, 7, topo)
    err = reconstruction_error(model, ids)
    # Exact up to the sparse blocks, which drop displacements below 1 micrometre.
    assert err["max_mm"] < 0.01


def surface_landmarks(model, rng):
    """The model with its landmarks on random points of the first 68 triangles."""
    bary = rng.uniform(0.05, 1, (68, 3))
    return model.with_landmarks(model.landmarks, model.faces[:68], bary / bary.sum(1,
                                                                                  keepdims=True))


def test_torch_matches_numpy_and_is_differentiable(corpus):
    ids, topo = corpus
    rng = np.random.default_rng(0)
    model = surface_landmarks(build_bilinear(ids, 4, topo), rng)
    head = BilinearHead(model, dtype=torch.float64)
    s = rng.normal(size=(3, 4)) * np.sqrt(np.diag(model.code_cov))
    w = rng.uniform(0, 1, (3, 52))
    st = torch.tensor(s, requires_grad=True)
    out = head.vertices(st, torch.tensor(w))
    for b in range(3):
        np.testing.assert_allclose(out[b].detach().numpy(), model.vertices(s[b], w[b]),
                                   atol=1e-9)
    lm = head.landmarks(st, torch.tensor(w))
    assert lm.shape == (3, 68, 3)
    np.testing.assert_allclose(lm[1].detach().numpy(),
                               model.landmark_points(model.vertices(s[1], w[1])), atol=1e-9)
    lm.sum().backward()
    assert st.grad is not None and st.grad.abs().sum() > 0


def test_mirror_is_exact_on_a_mirror_closed_corpus(corpus):
    ids, topo = corpus
    vm = topo["vertex_mirror"]
    both = ids + [reflect(n, d, vm) for n, d in ids]
    model = build_bilinear(both, len(both) - 1, topo)
    head = BilinearHead(model, dtype=torch.float64)
    rng = np.random.default_rng(1)
    s = torch.tensor(rng.normal(size=(2, model.rank)) * 0.01)
    w = torch.tensor(rng.uniform(0, 1, (2, 52)))
    ms, mw = head.mirror(s, w)
    original = head.vertices(s, w).numpy()
    mirrored = head.vertices(ms, mw).numpy()
    assert np.abs(mirrored - original[:, vm] * FLIP).max() < 1e-6


def test_stored_model_costs_under_a_tenth_of_a_millimetre(corpus, tmp_path):
    ids, topo = corpus
    model = build_bilinear(ids, 7, topo)
    sha = model.save(tmp_path / "m.npz")
    stored = load_bilinear(tmp_path / "m.npz")
    assert stored.meta["sha256"] == sha and len(sha) == 64
    # Without a surface embedding the landmarks are their vertices.
    np.testing.assert_array_equal(stored.landmark_tri[:, 0], model.landmarks)
    np.testing.assert_array_equal(stored.landmark_bary, np.eye(3)[np.zeros(68, int)])
    # Rebuilding the same model gives the same hash, though the zip's bytes differ.
    assert build_bilinear(ids, 7, topo).save(tmp_path / "again.npz") == sha
    rng = np.random.default_rng(2)
    std = np.sqrt(np.diag(model.code_cov))
    for _ in range(5):
        s = rng.uniform(-3, 3, 7) * std
        w = rng.uniform(0, 1, 52)
        diff = np.abs(stored.vertices(s, w) - model.vertices(s, w)).max()
        assert diff < 1e-4  # metres


def test_surface_landmarks_survive_storage_and_older_files_load(corpus, tmp_path):
    ids, topo = corpus
    model = surface_landmarks(build_bilinear(ids, 3, topo), np.random.default_rng(8))
    model.save(tmp_path / "m.npz")
    stored = load_bilinear(tmp_path / "m.npz")
    np.testing.assert_array_equal(stored.landmark_tri, model.landmark_tri)
    np.testing.assert_allclose(stored.landmark_bary, model.landmark_bary, atol=1e-7)
    mean = model.neutral_mean.astype(np.float64)
    expected = (model.landmark_bary[:, :, None] * mean[model.landmark_tri]).sum(1)
    np.testing.assert_allclose(stored.landmark_points(mean), expected, atol=1e-6)
    # A file from before surface landmarks (no landmark_tri/landmark_bary) still loads.
    with np.load(tmp_path / "m.npz") as npz:
        old = {k: npz[k] for k in npz.files if not k.startswith("landmark_")}
    np.savez(tmp_path / "old.npz", **old)
    loaded = load_bilinear(tmp_path / "old.npz")
    np.testing.assert_allclose(loaded.landmark_points(mean), mean[model.landmarks])


def test_load_errors(tmp_path):
    with pytest.raises(ModelNotFoundError, match="build-model"):
        load_bilinear(tmp_path / "missing.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(FileFormatError):
        load_bilinear(bad)
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(FileFormatError, match="bilinear"):
        load_bilinear(tmp_path / "other.npz")


def test_another_format_or_a_newer_version_is_refused_even_under_python_O(corpus,
                                                                          tmp_path):
    """The format and version were checked with ``assert``, which ``python -O`` (and
    PYTHONOPTIMIZE=1) drops: a newer version's model file then loaded as if it were
    this one's, and without -O the message said only "AssertionError()"."""
    import json
    import subprocess
    import sys

    from head360cli.mesh.bilinear import MODEL_FORMAT

    ids, topo = corpus
    build_bilinear(ids, 3, topo).save(tmp_path / "m.npz")
    with np.load(tmp_path / "m.npz") as npz:
        data = {k: npz[k] for k in npz.files}
    meta = json.loads(str(data["__meta__"]))
    for name, change in (("newer", {"format_version": MODEL_FORMAT + 1}),
                         ("other", {"format": "someone-else"})):
        np.savez(tmp_path / f"{name}.npz", **{**data, "__meta__": np.array(json.dumps(
            {**meta, **change}))})
    with pytest.raises(FileFormatError, match=rf"version {MODEL_FORMAT + 1}; head360 "
                                              rf"reads 'head360-bilinear' up to version "
                                              rf"{MODEL_FORMAT}"):
        load_bilinear(tmp_path / "newer.npz")
    with pytest.raises(FileFormatError, match="format 'someone-else'"):
        load_bilinear(tmp_path / "other.npz")
    code = ("import sys; from head360cli.errors import FileFormatError;"
            "from head360cli.mesh.bilinear import read_model_file\n"
            "try:\n read_model_file(sys.argv[1])\nexcept FileFormatError as e:\n"
            " print('refused:', e)")
    r = subprocess.run([sys.executable, "-O", "-c", code, str(tmp_path / "newer.npz")],
                       capture_output=True, text=True, timeout=120)
    assert r.stdout.startswith("refused:"), (r.stdout, r.stderr)


def test_loads_of_one_file_share_read_only_arrays_until_it_changes(corpus, tmp_path):
    ids, topo = corpus
    path = tmp_path / "m.npz"
    first_sha = build_bilinear(ids, 5, topo).save(path)
    a, b = load_bilinear(path), load_bilinear(path)
    assert a.neutral_basis is b.neutral_basis  # read once
    with pytest.raises(ValueError, match="read-only"):
        a.expr_basis[0, 0, 0] = 1.0
    s, w = np.linspace(-1, 1, 5) * 1e-3, np.full(52, 0.3)
    np.testing.assert_array_equal(a.vertices(s, w), b.vertices(s, w))
    a.neutral_mean[0, 0] = 1.0  # the small arrays are each load's own
    assert b.neutral_mean[0, 0] != 1.0
    a.meta["note"] = "mine"  # each load has its own metadata
    assert "note" not in b.meta and b.meta["sha256"] == first_sha
    # The float64 bases are numpy's own widening of the float16 ones, value for value.
    np.testing.assert_array_equal(a.__dict__["_f64"]["eb"],
                                  a.expr_basis.astype(np.float64).reshape(5, -1))
    # Rewritten (another rank, so another size), the file is read again.
    second_sha = build_bilinear(ids, 3, topo).save(path)
    c = load_bilinear(path)
    assert c.rank == 3 and c.meta["sha256"] == second_sha != first_sha
    assert a.rank == 5  # the models loaded before keep their arrays


def test_shipped_model_loads_and_has_the_papers_shape():
    model = load_bilinear()
    assert model.rank == 50 and model.meta["identities"] == 100
    assert model.neutral_basis.dtype == np.float16
    assert np.allclose(model.code_mean, 0, atol=1e-6)


@pytest.mark.shared_data
def test_ict_facekit_reader(shared_data):
    from head360cli.mesh.corpora import ict_facekit

    it, topo = ict_facekit(shared_data / "ict-facekit")
    neutral, deltas = next(it)
    assert neutral.shape == (26719, 3) and deltas.shape == (52, 26719, 3)
    width = np.ptp(neutral[:, 0])
    assert 0.15 < width < 0.3  # metres: a head, not centimetres
    from head360cli.mesh.arkit52 import INDEX

    assert np.abs(deltas[INDEX["tongueOut"]]).max() == 0  # ICT has no tongue shape
    assert np.abs(deltas[INDEX["browInnerUp"]]).max() > 0  # merged from its halves
    assert len(topo["landmarks"]) == 68 and topo["faces"].shape[1] == 3
    assert (topo["vertex_mirror"][topo["vertex_mirror"]] == np.arange(26719)).mean() > 0.95


@pytest.mark.slow
@pytest.mark.shared_data
def test_shipped_model_is_what_its_command_builds(shared_data, tmp_path):
    """models/bilinear.npz must match its model card's command with the current code (a
    change to the fitter changes the landmark calibration, so the file must be rebuilt)."""
    import dataclasses

    from head360cli.mesh.build import build_model

    build_model(out=tmp_path / "b.npz", calibrate=shared_data / "faces")
    built, shipped = load_bilinear(tmp_path / "b.npz"), load_bilinear()
    for field in dataclasses.fields(built):  # the metadata records the path as given
        if field.name != "meta":
            # Exact but for round-off: BLAS sums in a thread-dependent order, and a
            # code mean that is zero by construction came out -1.8e-16 against -2.0e-16
            # on a loaded machine.
            np.testing.assert_allclose(getattr(built, field.name),
                                       getattr(shipped, field.name), rtol=1e-9,
                                       atol=1e-12, err_msg=field.name)


def test_deltas_are_each_shapes_move_exactly(corpus):
    ids, topo = corpus
    model = build_bilinear(ids, 4, topo)
    s = np.array([0.4, -0.2, 0.1, 0.05]) * np.sqrt(np.diag(model.code_cov))
    neutral, deltas = model.deltas(s)
    np.testing.assert_array_equal(neutral, model.vertices(s, np.zeros(52)))
    assert deltas.shape == (52, *neutral.shape)
    for k in (0, 9, 17, 24, 51):  # bit for bit what vertices() gives, shape by shape
        np.testing.assert_array_equal(deltas[k],
                                      model.vertices(s, np.eye(52)[k]) - neutral)
    assert np.abs(deltas).max() > 1e-3  # the shapes do move the mesh


@pytest.mark.parametrize(("identities", "held_out"), [(-1, 20), (1, 20), (10, -3)])
def test_build_refuses_counts_that_cannot_make_a_model(tmp_path, identities, held_out):
    from head360cli.errors import BadInputError
    from head360cli.mesh.build import build_model

    with pytest.raises(BadInputError, match=f"found {identities} and {held_out}"):
        build_model(identities=identities, held_out=held_out, out=tmp_path / "b.npz")
    assert not (tmp_path / "b.npz").exists()


def test_build_refuses_an_output_it_could_not_write_before_the_work(tmp_path):
    """``build-model -o b.txt`` built for a minute and wrote the model under a text name;
    an unwritable folder was found only at the end."""
    import os

    from head360cli.errors import BadInputError
    from head360cli.mesh.build import build_model

    with pytest.raises(BadInputError, match=r"ending in \.npz, found .*b\.txt"):
        build_model(identities=2, held_out=0, out=tmp_path / "b.txt")
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        if not os.access(locked, os.W_OK):  # root writes anywhere: nothing to refuse
            with pytest.raises(BadInputError):
                build_model(identities=2, held_out=0, out=locked / "new" / "b.npz")
    finally:
        locked.chmod(0o700)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["locked"]
    assert not any(locked.iterdir())


def test_build_with_scanned_expressions_moves_as_the_scans_do(tmp_path):
    """``--expressions scanned``: the model's shapes are the shipped scanned fields (at each
    head's size), not the procedural ones; other corpora bring their own and refuse it."""
    from head360cli.errors import BadInputError
    from head360cli.mesh.arkit52 import INDEX
    from head360cli.mesh.build import build_model
    from head360cli.synth.expressions import shipped_fields

    out = tmp_path / "b.npz"
    summary = build_model(identities=3, rank=2, held_out=0, out=out, expressions="scanned")
    model = load_bilinear(out)
    assert "--expressions scanned" in model.meta["command"] and summary["rank"] == 2
    smile = model.vertices(model.code_mean, np.eye(52)[INDEX["mouthSmileLeft"]]) - \
        model.vertices(model.code_mean, np.zeros(52))
    field = shipped_fields("expressions")[INDEX["mouthSmileLeft"]]
    cos = (smile * field).sum() / np.linalg.norm(smile) / np.linalg.norm(field)
    assert cos > 0.99  # the scanned field, scaled by the head's eye span
    with pytest.raises(BadInputError, match="are for --corpus synthead-p; found --corpus ict"):
        build_model(corpus="ict", path=tmp_path, out=tmp_path / "c.npz",
                    expressions="scanned")


def test_build_in_the_scanned_identity_space_spans_icts_faces(tmp_path):
    """``--identity-space scanned``: the identity basis is ICT's shape space (its first
    component lies in the model's span)."""
    from head360cli.errors import BadInputError
    from head360cli.mesh.build import build_model
    from head360cli.synth.expressions import shipped_fields

    out = tmp_path / "b.npz"
    build_model(identities=12, rank=10, held_out=0, out=out, expressions="scanned",
                identity_space="scanned")
    model = load_bilinear(out)
    assert "--identity-space scanned" in model.meta["command"]
    basis = model.neutral_basis.astype(np.float64).reshape(10, -1)
    q, _ = np.linalg.qr(basis.T)
    first = shipped_fields("identities")[0].reshape(-1)  # ICT's largest component
    kept = np.linalg.norm(q.T @ first) / np.linalg.norm(first)
    assert kept > 0.6  # 12 random ICT faces, 10 codes: the main direction is spanned
    with pytest.raises(BadInputError, match="expected --identity-space sculpted or scanned"):
        build_model(identities=3, rank=2, held_out=0, out=tmp_path / "c.npz",
                    identity_space="scans")

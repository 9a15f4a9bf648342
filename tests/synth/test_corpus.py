"""The corpus writer: deterministic bytes, resuming, index contents, masks, bad options."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest
from PIL import Image

from head360cli.errors import BadInputError, FileFormatError
from head360cli.synth.corpus import CorpusConfig, expressions_for, views_for, write_corpus

TINY = CorpusConfig(identities=2, expressions=2, views=3, size=48, seed=3, samples=1)


def digest(folder):
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_same_seed_gives_identical_bytes(tmp_path):
    write_corpus(TINY, tmp_path / "a")
    write_corpus(TINY, tmp_path / "b")
    a, b = digest(tmp_path / "a"), digest(tmp_path / "b")
    assert a == b
    assert sum(name.endswith(".png") for name in a) == 2 * 2 * 3 * 4


def test_index_describes_every_view(tmp_path):
    summary = write_corpus(TINY, tmp_path)
    lines = [json.loads(line) for line in (tmp_path / "index.jsonl").read_text().splitlines()]
    assert summary["views"] == len(lines) == 12
    for rec in lines:
        for key in ("image", "bald", "hair_mask", "face_mask"):
            assert (tmp_path / rec[key]).is_file()
        assert len(rec["camera"]["c2w"]) == 16 and len(rec["camera"]["intrinsics"]) == 9
        assert rec["split"] == "train" and rec["width"] == 48
    rgba = np.asarray(Image.open(tmp_path / lines[0]["image"]))
    assert rgba.shape == (48, 48, 4)
    hair = np.asarray(Image.open(tmp_path / lines[0]["hair_mask"]))
    face = np.asarray(Image.open(tmp_path / lines[0]["face_mask"]))
    # Masks lie inside the alpha, and hair and face do not overlap.
    alpha = rgba[..., 3].astype(int) + 1
    assert (hair <= alpha).all() and (face <= alpha).all()
    assert (np.minimum(hair, face) < 3).all()
    # Heads are balanced by sex: identity 0 female, identity 1 male.
    metas = [json.loads((tmp_path / f"train/id000{i}/meta.json").read_text()) for i in (0, 1)]
    assert [m["params"]["sex"] for m in metas] == [0.0, 1.0]


def test_resume_skips_finished_identities(tmp_path):
    first = write_corpus(CorpusConfig(**{**TINY.__dict__, "identities": 1}), tmp_path)
    assert first["identities_written"] == 1
    (tmp_path / "train" / "id0001").mkdir()  # a leftover of an interrupted run
    second = write_corpus(TINY, tmp_path)
    assert (second["identities_written"], second["identities_skipped"]) == (1, 1)
    assert second["views"] == 12
    assert (first["views_written"], second["views_written"]) == (6, 6)


def test_other_settings_in_the_same_folder_are_refused(tmp_path):
    write_corpus(TINY, tmp_path)
    with pytest.raises(FileFormatError, match="another folder"):
        write_corpus(CorpusConfig(**{**TINY.__dict__, "size": 64}), tmp_path)


def test_test_split_uses_other_identities(tmp_path):
    write_corpus(TINY, tmp_path)
    write_corpus(CorpusConfig(**{**TINY.__dict__, "split": "test"}), tmp_path)
    train = json.loads((tmp_path / "train/id0000/meta.json").read_text())["params"]
    test = json.loads((tmp_path / "test/id0000/meta.json").read_text())["params"]
    assert train != test


def test_expression_and_view_selection():
    expr = [expressions_for(i, 53) for i in range(2)]
    assert expr[0][0] == {} and len(expr[0]) == 53
    assert {next(iter(e)) for e in expr[0][1:]} == {next(iter(e)) for e in expr[1][1:]}
    covered = {next(iter(e)) for i in range(13) for e in expressions_for(i, 5)[1:]}
    assert len(covered) == 52  # rotating shapes cover all 52 over identities
    assert views_for(CorpusConfig(views=72), 0, 0) == list(range(72))
    v = views_for(TINY, 0, 1)
    assert len(v) == 3 and v == views_for(TINY, 0, 1)


@pytest.mark.parametrize("bad", [{"identities": 0}, {"expressions": 54}, {"views": 0},
                                 {"size": 8}, {"split": "val"}, {"samples": 3},
                                 {"seed": -1}, {"identities": 2.5}, {"size": 48.5},
                                 {"identities": True}, {"start": "1"}])
def test_bad_settings(tmp_path, bad):
    """Each bad field is refused when the configuration is made, so no folder or
    ``corpus.json`` is left behind (``seed=-1`` used to fail in numpy after writing one)."""
    with pytest.raises(BadInputError, match="expected"):
        write_corpus(CorpusConfig(**{**TINY.__dict__, **bad}), tmp_path / "c")
    assert not (tmp_path / "c").exists()


def test_cli_synth(run_cli, tmp_path):
    r = run_cli("synth", tmp_path / "c", "-n", "1", "-e", "1", "-v", "2", "--size", "32",
                "--json")
    assert r.code == 0, r.err
    summary = json.loads(r.out)
    assert summary["views"] == 2 and summary["identities_written"] == 1
    assert summary["ms_per_image_all_in"] == pytest.approx(1000 * summary["seconds"] / 4,
                                                           abs=0.06)
    assert run_cli("synth", tmp_path / "c", "--views", "99").code == 3
    # A resumed run prices only the images it wrote, not those it skipped.
    r = run_cli("synth", tmp_path / "c", "-n", "3", "-e", "1", "-v", "2", "--size", "32",
                "--json")
    resumed = json.loads(r.out)
    assert (resumed["views"], resumed["views_written"]) == (6, 4)
    assert resumed["ms_per_image_all_in"] == pytest.approx(1000 * resumed["seconds"] / 8,
                                                           abs=0.06)


def test_contact_sheets(tmp_path):
    from head360cli.synth.corpus import write_previews

    paths = write_previews(tmp_path, size=32, identities=2)
    sizes = {p.rsplit("/", 1)[-1]: Image.open(p).size for p in paths}
    assert sizes == {"preview_identities.png": (6 * 32, 2 * 32),
                     "preview_expressions.png": (9 * 32, 6 * 32),
                     "preview_hairstyles.png": (10 * 32, 3 * 32)}
    sheet = np.asarray(Image.open(paths[2]))
    assert sheet.std() > 10  # heads were drawn, not a blank sheet


def test_contact_sheets_are_one_set(tmp_path, monkeypatch):
    """A run that fails (or is stopped) at the last sheet leaves an earlier run's three
    sheets as they were; before, the first two were already replaced by new ones."""
    import head360cli.synth.hair as hair
    import head360cli.synth.scene  # noqa: F401  (binds the real build_hair for the heads)
    from head360cli.synth.corpus import write_previews

    names = ("preview_identities.png", "preview_expressions.png", "preview_hairstyles.png")
    for name in names:
        (tmp_path / name).write_bytes(b"earlier sheet")

    def stopped(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(hair, "build_hair", stopped)  # the hairstyle sheet's first step
    with pytest.raises(KeyboardInterrupt):
        write_previews(tmp_path, size=32, identities=1)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == \
        dict.fromkeys(names, b"earlier sheet")

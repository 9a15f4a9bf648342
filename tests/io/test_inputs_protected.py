"""An output that names one of the command's inputs is refused unless --overwrite: by
path, by a symbolic link and by a hard link."""

from __future__ import annotations

import os

import pytest

from head360cli.errors import BadInputError
from head360cli.io.atomic import atomic_path, check_file_target, protect_inputs


def test_outputs_that_are_inputs_are_refused(tmp_path):
    photo = tmp_path / "clip.mp4"
    photo.write_bytes(b"the user's clip")
    link, hard = tmp_path / "link.mp4", tmp_path / "hard.mp4"
    link.symlink_to(photo)
    os.link(photo, hard)
    with protect_inputs([photo]):
        for target in (photo, link, hard):
            with pytest.raises(BadInputError, match=r"an output other than the inputs.*"
                                                    r"--overwrite"):
                check_file_target(target)
            with pytest.raises(BadInputError), atomic_path(target) as tmp:
                tmp.write_bytes(b"render")
        with atomic_path(tmp_path / "other.mp4") as tmp:  # any other output is fine
            tmp.write_bytes(b"render")
    assert photo.read_bytes() == b"the user's clip"
    with protect_inputs([photo], allow=True), atomic_path(photo) as tmp:
        tmp.write_bytes(b"render")
    assert photo.read_bytes() == b"render"
    with atomic_path(photo) as tmp:  # outside a command: nothing protected
        tmp.write_bytes(b"again")


def test_swap_hair_onto_its_own_head_file_needs_overwrite(run_cli, head_file, tmp_path):
    head = tmp_path / "me.h360"
    head.write_bytes(head_file.read_bytes())
    before = head.read_bytes()
    r = run_cli("swap-hair", head, "--hair", "3", "-o", head)
    assert r.code == 3 and "an output other than the inputs" in r.err
    assert "--overwrite" in r.err and len(r.err.strip().splitlines()) == 1
    assert head.read_bytes() == before
    r = run_cli("swap-hair", head, "--hair", "3", "-o", head, "--overwrite")
    assert r.code == 0, r.err
    assert head.read_bytes() != before

"""Torch files read as data only: what each way of failing says."""

from __future__ import annotations

import pytest
import torch

from head360cli.errors import FileFormatError
from head360cli.io.torchfile import load_data


class _RunsCode:
    """Unpickling this would call ``print``: code a file could run on load."""

    def __reduce__(self):
        return (print, ("ran",))


def test_data_loads_and_each_failure_is_one_line_that_says_which(tmp_path):
    torch.save({"w": torch.ones(2), "n": 3}, tmp_path / "ok.pt")
    assert load_data(tmp_path / "ok.pt", "weights")["n"] == 3
    torch.save({"a": _RunsCode()}, tmp_path / "code.pt")
    (tmp_path / "text.pt").write_bytes(b"not a checkpoint")  # no pickle at all
    (tmp_path / "cut.pt").write_bytes((tmp_path / "ok.pt").read_bytes()[:200])
    said = {}
    for name in ("code", "text", "cut"):
        with pytest.raises(FileFormatError) as info:
            load_data(tmp_path / f"{name}.pt", "weights")
        said[name] = str(info.value)
        assert "\n" not in said[name] and "\x1b" not in said[name]
    assert "could run code" in said["code"]
    # text bytes used to be reported as objects that could run code
    assert "torch cannot read (Unsupported operand" in said["text"], said["text"]
    assert "torch cannot read" in said["cut"]

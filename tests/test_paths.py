"""Where head360 looks for its files."""

from pathlib import Path

from head360cli.paths import cache_dir


def test_cache_dir_order(tmp_path, monkeypatch):
    monkeypatch.setenv("HEAD360_CACHE", str(tmp_path / "mine"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir() == tmp_path / "mine"
    monkeypatch.setenv("HEAD360_CACHE", "")
    assert cache_dir() is None  # set but empty: no cache
    monkeypatch.delenv("HEAD360_CACHE")
    assert cache_dir() == tmp_path / "xdg" / "head360"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache_dir() == Path(tmp_path / "home" / ".cache" / "head360")
    assert not (tmp_path / "home").exists()  # made only when a file is written


def test_info_names_the_cache(run_cli, tmp_path, monkeypatch):
    import json

    monkeypatch.setenv("HEAD360_CACHE", str(tmp_path / "c"))
    assert json.loads(run_cli("info", "--json").out)["cache"] == str(tmp_path / "c")
    monkeypatch.setenv("HEAD360_CACHE", "")
    assert json.loads(run_cli("info", "--json").out)["cache"] is None
    assert "cache: off" in run_cli("info").out

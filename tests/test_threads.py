"""Thread counts from the CPUs the process may use, capped by the user: several fits side
by side on 2 cores took 125-190 s each instead of 10 while OpenMP's threads spun."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from head360cli.errors import BadInputError
from head360cli.threads import LIBRARY_VARIABLES, configure_threads, cpu_quota, thread_budget
from tests.conftest import REPO


def test_cgroup_quotas_are_read_in_both_versions(tmp_path, monkeypatch):
    v2 = tmp_path / "v2"
    v2.mkdir()
    (v2 / "cpu.max").write_text("150000 100000\n")
    assert cpu_quota(v2) == pytest.approx(1.5)
    (v2 / "cpu.max").write_text("max 100000\n")
    assert cpu_quota(v2) is None
    v1 = tmp_path / "v1"
    (v1 / "cpu").mkdir(parents=True)
    (v1 / "cpu" / "cpu.cfs_quota_us").write_text("300000\n")
    (v1 / "cpu" / "cpu.cfs_period_us").write_text("100000\n")
    assert cpu_quota(v1) == pytest.approx(3.0)
    (v1 / "cpu" / "cpu.cfs_quota_us").write_text("-1\n")
    assert cpu_quota(v1) is None
    assert cpu_quota(tmp_path / "none") is None


def test_the_budget_is_the_cpus_at_most_the_cap(monkeypatch):
    import head360cli.threads as threads

    monkeypatch.setattr(threads, "_affinity", lambda: 16)
    monkeypatch.setattr(threads, "cpu_quota", lambda: 2.5)  # a container's quota
    monkeypatch.delenv("HEAD360_THREADS", raising=False)
    assert thread_budget() == 3
    assert thread_budget(cap=2) == 2 and thread_budget(cap=64) == 3
    monkeypatch.setenv("HEAD360_THREADS", "1")
    assert thread_budget() == 1
    for bad in ("0", "two", "-3"):
        monkeypatch.setenv("HEAD360_THREADS", bad)
        with pytest.raises(BadInputError, match="HEAD360_THREADS to be a whole number"):
            thread_budget()


def test_configure_keeps_the_user_s_variables_unless_threads_is_given(monkeypatch):
    import head360cli.threads as threads

    monkeypatch.setattr(threads, "_affinity", lambda: 2)
    monkeypatch.setattr(threads, "cpu_quota", lambda: None)
    for name in (*LIBRARY_VARIABLES, "OMP_WAIT_POLICY", "HEAD360_THREADS"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "5")
    assert configure_threads() == 2
    assert os.environ["OMP_NUM_THREADS"] == "5"  # the user's
    assert os.environ["MKL_NUM_THREADS"] == os.environ["OPENCV_FOR_THREADS_NUM"] == "2"
    assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE"
    assert configure_threads(1) == 1
    assert all(os.environ[name] == "1" for name in LIBRARY_VARIABLES)
    assert os.environ["HEAD360_THREADS"] == "1"


def _info_threads(*args: str, **env: str) -> int:
    code = "import sys; from head360cli.cli import main; sys.exit(main(sys.argv[1:]))"
    clean = {k: v for k, v in os.environ.items()
             if k not in (*LIBRARY_VARIABLES, "HEAD360_THREADS", "OMP_WAIT_POLICY")}
    out = subprocess.run([sys.executable, "-c", code, *args, "info", "--json"],
                         capture_output=True, text=True, check=True, cwd=REPO,
                         env={**clean, **env})
    return json.loads(out.stdout)["devices"][0]["threads"]


def test_torch_starts_with_the_budget_and_the_cap(monkeypatch):
    from head360cli.threads import thread_budget as budget

    monkeypatch.delenv("HEAD360_THREADS", raising=False)
    assert _info_threads() == budget()
    assert _info_threads("--threads", "1") == 1
    assert _info_threads(HEAD360_THREADS="1") == 1


def test_render_processes_never_outnumber_the_cap(monkeypatch):
    from head360cli.drive.parallel import MIN_FRAMES, auto_workers

    monkeypatch.setenv("HEAD360_THREADS", "1")
    assert auto_workers(10 * MIN_FRAMES, "cpu") == 1

"""What bench results record about the machine."""

from __future__ import annotations

import os

from head360cli.bench.report import machine
from head360cli.devices import fast_bfloat16


def test_machine_names_the_cpu_and_whether_it_has_bfloat16():
    m = machine()
    assert isinstance(m["cpu"], str)
    assert m["cpu_bf16"] is fast_bfloat16("cpu")
    assert m["cpu_cores"] == os.cpu_count() and m["torch_threads"] >= 1
    if os.path.exists("/proc/cpuinfo"):
        with open("/proc/cpuinfo") as f:
            names = [line for line in f if line.startswith("model name")]
        if names:
            assert m["cpu"] == names[0].split(":", 1)[1].strip()


def test_per_generator_runs_once_per_weights_file_with_it_installed(tmp_path):
    """``--weights A --weights B``: the same bench twice, each with one file standing for
    the installed generator (what fits and renders load, and the hash head files record),
    the results keyed by file name; no weights: one run as it was."""
    from head360cli.bench.report import per_generator
    from head360cli.paths import generator_hash, installed_generator

    a, b = tmp_path / "old.pt", tmp_path / "new.pt"
    a.write_bytes(b"a")
    b.write_bytes(b"b")
    seen = []

    def run(label):
        seen.append((label, installed_generator().name, generator_hash()[:8]))
        return {"label": label}, f"ran {label}"

    result, md = per_generator((str(a), str(b)), run)
    assert [s[:2] for s in seen] == [("old", "old.pt"), ("new", "new.pt")]
    assert seen[0][2] != seen[1][2]
    assert result == {"generators": {"old": {"label": "old"}, "new": {"label": "new"}}}
    assert md.index("## Generator old") < md.index("ran old") < md.index("## Generator new")
    assert installed_generator().name == "generator.pt"  # restored
    assert per_generator((), run) == ({"label": None}, "ran None")

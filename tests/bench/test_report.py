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

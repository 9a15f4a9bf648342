"""``head360cli.devices``: device names, bfloat16 and the GPU memory peak."""

from __future__ import annotations

import pytest
import torch

from head360cli.devices import gpu_peak_mib, resolve_device
from head360cli.errors import BadInputError


def test_gpu_peak_is_torch_s_high_water_mark_in_mib_and_none_on_a_cpu(monkeypatch):
    seen = []

    def peak(device):
        seen.append(device)
        return 3 * 2**30 + 2**19  # 3 GiB and half a MiB

    monkeypatch.setattr(torch.cuda, "max_memory_allocated", peak)
    assert gpu_peak_mib("cpu") is None and gpu_peak_mib(torch.device("cpu")) is None
    assert seen == []  # no CUDA call for a CPU
    assert gpu_peak_mib("cuda:1") == 3072.5
    assert seen == [torch.device("cuda:1")]


def test_resolve_device_refuses_names_and_missing_cuda(monkeypatch):
    assert resolve_device(" CPU ") == torch.device("cpu")
    with pytest.raises(BadInputError, match="expected --device cpu, cuda, cuda:N or auto"):
        resolve_device("gpu")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert resolve_device("auto") == torch.device("cpu")
    with pytest.raises(BadInputError, match="no CUDA device is available"):
        resolve_device("cuda:0")

"""Turning the ``--device`` option into a torch device (torch is imported late)."""

from __future__ import annotations

import re

from head360cli.errors import BadInputError

__all__ = ["fast_bfloat16", "gpu_peak_mib", "resolve_device"]

_PATTERN = re.compile(r"^(cpu|cuda|auto)(:\d+)?$")


def resolve_device(name: str):  # -> torch.device
    """Validate a device name and return the ``torch.device``.

    Args:
        name: ``cpu``, ``cuda``, ``cuda:N`` or ``auto`` (CUDA when present, else CPU).

    Raises:
        BadInputError: For another name, or CUDA asked for where there is none.
    """
    text = name.strip().lower()
    if not _PATTERN.match(text) or text.startswith(("cpu:", "auto:")):
        raise BadInputError(f"expected --device cpu, cuda, cuda:N or auto, found {name!r}")
    import torch

    if text == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if text.startswith("cuda"):
        if not torch.cuda.is_available():
            raise BadInputError(f"--device {name} asked for CUDA, but no CUDA device is available")
        index = int(text.split(":")[1]) if ":" in text else 0
        if index >= torch.cuda.device_count():
            raise BadInputError(
                f"--device {name}: expected a CUDA index below {torch.cuda.device_count()}, "
                f"found {index}"
            )
    return torch.device(text)


def fast_bfloat16(device) -> bool:
    """Whether ``device`` computes bfloat16 matrix products natively (CUDA GPUs that
    support it; CPUs with the AVX-512 BF16 or AMX instructions), where it is faster than
    float32. Elsewhere bfloat16 is emulated and slower."""
    import torch

    device = torch.device(device)
    if device.type == "cuda":
        return bool(torch.cuda.is_bf16_supported())
    try:
        with open("/proc/cpuinfo") as f:
            flags = f.read()
    except OSError:  # not Linux: be safe
        return False
    return "avx512_bf16" in flags or "amx_bf16" in flags


def gpu_peak_mib(device) -> float | None:
    """The most GPU memory torch has held on ``device`` in this process, in MiB (its
    allocations, not the driver's reserve); ``None`` on a CPU."""
    import torch

    device = torch.device(device)
    if device.type != "cuda":
        return None
    return round(torch.cuda.max_memory_allocated(device) / 2**20, 1)


def usable_cpus() -> int:
    """CPU cores this process may use: its affinity mask and its cgroup's CPU quota, at
    most the user's cap (``HEAD360_THREADS``, ``--threads``; :mod:`head360cli.threads`)."""
    from head360cli.threads import thread_budget

    return thread_budget()

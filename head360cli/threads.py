"""How many threads head360 runs: the CPUs the process may really use, capped by the user.

torch (OpenMP), OpenCV and onnxruntime each start a thread per core they see, and
OpenMP's threads spin while they wait for each other. On a machine busy with other work
(or several fits side by side, as batch scripts run them) the spinning took a fit from
10 to 125-190 s on 2 cores. The command line therefore sets, before any of those
libraries is imported: as many threads as the process may use (its affinity mask and
its cgroup's CPU quota, at most ``HEAD360_THREADS`` or ``--threads``), and passive
waiting for OpenMP's threads. Variables the user set are left alone, unless
``--threads`` asks otherwise.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from head360cli.errors import BadInputError

__all__ = ["THREADS_VARIABLE", "configure_threads", "cpu_quota", "thread_budget"]

THREADS_VARIABLE = "HEAD360_THREADS"
"""The environment variable that caps head360's threads (``--threads`` sets it too)."""

LIBRARY_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENCV_FOR_THREADS_NUM")
"""The thread counts torch (OpenMP, MKL) and OpenCV read when they start."""


def cpu_quota(root: str | os.PathLike[str] = "/sys/fs/cgroup") -> float | None:
    """CPUs the process's cgroup may use (``cpu.max`` of cgroup v2, or ``cpu.cfs_quota_us``
    over ``cpu.cfs_period_us`` of v1), ``None`` without a quota or outside Linux."""
    root = Path(root)
    candidates = []
    try:
        for line in Path("/proc/self/cgroup").read_text().splitlines():
            number, _, rest = line.partition(":")
            _, _, path = rest.partition(":")
            if number == "0" and path.strip("/"):  # v2: the process's own group
                candidates.append(root / path.strip("/") / "cpu.max")
    except OSError:
        pass
    candidates.append(root / "cpu.max")
    for f in candidates:
        try:
            quota, period = f.read_text().split()[:2]
        except (OSError, ValueError):
            continue
        if quota == "max":
            return None
        return float(quota) / float(period) if float(period) > 0 else None
    try:
        quota = float((root / "cpu" / "cpu.cfs_quota_us").read_text())
        period = float((root / "cpu" / "cpu.cfs_period_us").read_text())
    except (OSError, ValueError):
        return None
    return quota / period if quota > 0 and period > 0 else None


def _affinity() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def _cap(text: str | None, where: str) -> int | None:
    """A positive thread cap read from ``text`` (``None``: no cap).

    Raises:
        BadInputError: ``text`` is not a whole number of at least 1.
    """
    if text is None or not text.strip():
        return None
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise BadInputError(f"expected {where} to be a whole number >= 1, found {text!r}")
    return value


def thread_budget(cap: int | None = None) -> int:
    """Threads for this process: the CPUs it may use (affinity and cgroup quota, rounded
    up), at most ``cap``, else at most ``$HEAD360_THREADS``.

    Raises:
        BadInputError: ``$HEAD360_THREADS`` is set but not a whole number >= 1.
    """
    cpus = _affinity()
    quota = cpu_quota()
    if quota is not None:
        cpus = min(cpus, max(1, math.ceil(quota)))
    if cap is None:
        cap = _cap(os.environ.get(THREADS_VARIABLE), THREADS_VARIABLE)
    return max(1, min(cpus, cap) if cap is not None else cpus)


def configure_threads(cap: int | None = None) -> int:
    """Set the thread counts torch and OpenCV will start with, and passive waiting for
    OpenMP's threads; call before they are imported. With ``cap`` (``--threads``), it
    wins over the variables the user set; without, those are kept. Returns the budget.

    Raises:
        BadInputError: As :func:`thread_budget`.
    """
    budget = thread_budget(cap)
    if cap is not None:
        os.environ[THREADS_VARIABLE] = str(cap)
    for name in LIBRARY_VARIABLES:
        if cap is not None or name not in os.environ:
            os.environ[name] = str(budget)
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    return budget

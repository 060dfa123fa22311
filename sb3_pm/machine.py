"""What a run was computed on: the record ``machine.yml`` beside a run's ``config.yml``.

A seeded run repeats bit for bit on the same kind of machine, but not across machines: torch
picks its CPU kernels by the instruction sets the processor has (AVX2, AVX-512, ...), and kernels
of different widths add in different orders, so the last bits of a forward pass differ and
training amplifies them into another team (docs/METHOD.md, "Threads and random streams"). The
record says which CPU, kernels and library versions a run used, so that a figure that does not
repeat elsewhere can be told apart from a bug.
"""

from __future__ import annotations

import functools
import os
import platform
from pathlib import Path
from typing import Any

#: The record's file name inside a run folder or a sweep cell.
MACHINE_RECORD = "machine.yml"


def usable_cores() -> int:
    """How many cores this process may run on (its CPU affinity on Linux, else every core)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def cpu_model() -> str:
    """The processor's model name (``/proc/cpuinfo`` on Linux, else :func:`platform.processor`)."""
    cpuinfo = Path("/proc/cpuinfo")
    try:
        for line in cpuinfo.read_text(encoding="utf-8", errors="replace").splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def package_versions() -> dict[str, str]:
    """Versions of sb3_pm and the packages a run or a saved team depends on, as plain strings
    (torch's version is a ``str`` subclass that YAML would not write); ``sb3_contrib`` if installed."""
    import gymnasium
    import numpy as np
    import pettingzoo
    import stable_baselines3
    import torch

    from sb3_pm.version import __version__

    versions = {
        "sb3_pm": __version__,
        "stable_baselines3": str(stable_baselines3.__version__),
        "torch": str(torch.__version__),
        "numpy": str(np.__version__),
        "gymnasium": str(gymnasium.__version__),
        "pettingzoo": str(pettingzoo.__version__),
        "python": platform.python_version(),
    }
    try:
        import sb3_contrib

        versions["sb3_contrib"] = str(sb3_contrib.__version__)
    except ImportError:  # pragma: no cover
        pass
    return versions


def machine_record() -> dict[str, Any]:
    """``{key: value}``: the :func:`package_versions`, the platform, CPU model and count, and
    torch's CPU kernel level and threads (plain strings and ints, for YAML)."""
    import torch

    return {
        **package_versions(),
        "platform": platform.platform(),
        "cpu": cpu_model(),
        "cpu_count": os.cpu_count() or 0,
        # the widest vector instructions torch's CPU kernels use here (e.g. AVX2, AVX512)
        "torch_cpu_capability": str(torch.backends.cpu.get_cpu_capability()),
        "torch_threads": int(torch.get_num_threads()),
    }


def write_machine_record(folder: Path) -> Path:
    """Write :func:`machine_record` to ``folder / MACHINE_RECORD`` atomically; returns the path."""
    import yaml

    from sb3_pm.files import write_atomic

    path = Path(folder) / MACHINE_RECORD
    write_atomic(path, yaml.safe_dump(machine_record(), sort_keys=False))
    return path


def release_freed_memory() -> None:
    """Give the memory the C allocator holds freed back to the system (glibc's ``malloc_trim``).

    A learner's update phase on a large site allocates hundreds of MB of activations in its own
    thread, and glibc keeps what a thread frees in that thread's arena: twelve learners on a
    1,000-node site then held several GB between their updates. Elsewhere (no glibc) this does
    nothing.
    """
    trim = _malloc_trim()
    if trim is not None:
        trim(0)


@functools.lru_cache(maxsize=1)
def _malloc_trim() -> Any:
    """glibc's ``malloc_trim``, loaded once (every learner update calls it), or ``None``."""
    try:
        import ctypes

        return getattr(ctypes.CDLL("libc.so.6"), "malloc_trim", None)
    except OSError:
        return None


__all__ = [
    "MACHINE_RECORD",
    "cpu_model",
    "machine_record",
    "package_versions",
    "release_freed_memory",
    "write_machine_record",
]


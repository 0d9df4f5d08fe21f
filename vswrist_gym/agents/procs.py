"""The training process: torch threads, the library versions stored with every result, and whether a process
recorded in run.json still runs (pid, host and start time, so that a recycled pid is not taken for it)."""

from __future__ import annotations

import os
import platform
import sys
from importlib import metadata
from pathlib import Path

import numpy as np


def limit_threads(n: int = 1) -> None:
    """One torch thread per process: the machines here have few cores shared by several processes. A core install
    (no torch) has no torch threads to limit."""
    try:
        import torch
    except ImportError:
        return
    torch.set_num_threads(n)


def _version(module: str, dist: str) -> str | None:
    """A library's version without importing it (torch takes seconds): the loaded module's own where it is
    loaded, else the installed distribution's; None where it is not installed (a core install has no torch)."""
    loaded = sys.modules.get(module)
    if loaded is not None and getattr(loaded, "__version__", None):
        return str(loaded.__version__)
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def versions() -> dict:
    """Versions of the libraries that determine a result, stored with every run and every evaluation."""
    import mujoco

    return {"vswrist_gym": _version("vswrist_gym", "vswrist-gym") or "unknown", "mujoco": mujoco.__version__,
            "gymnasium": _version("gymnasium", "gymnasium"),
            "stable_baselines3": _version("stable_baselines3", "stable-baselines3"),
            "torch": _version("torch", "torch"), "numpy": np.__version__, "python": platform.python_version(),
            "platform": platform.platform(), "cpu_count": os.cpu_count()}


def steps_done(run_dir: Path, prefix: str = "") -> int:
    """Environment steps of finished training episodes in the Monitor logs whose name starts with `prefix`
    (cheap progress for a process that is running, or was killed, without asking it)."""
    total = 0
    for f in (Path(run_dir) / "monitor").glob(f"{prefix}*.monitor.csv"):
        try:
            lines = f.read_text().splitlines()[2:]
            total += sum(int(float(line.split(",")[1])) for line in lines if line.count(",") >= 2)
        except (OSError, ValueError, IndexError):
            pass
    return total


def _proc_start_ticks(pid: int) -> int | None:
    """Start time of process `pid` in clock ticks since boot (Linux /proc), which tells a recycled pid apart."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        return int(stat.rsplit(")", 1)[1].split()[19])
    except (OSError, ValueError, IndexError):
        return None


def this_process() -> dict:
    """What identifies the training process in run.json: pid, host, and the process start time where known."""
    return {"pid": os.getpid(), "host": platform.node(), "proc_start": _proc_start_ticks(os.getpid())}


def process_alive(record: dict) -> bool | None:
    """Whether the process recorded in run.json still runs: True / False, or None when it ran on another host
    (its pid means nothing here). A pid that exists but started at another time is a recycled pid: not alive."""
    pid = record.get("pid")
    if not isinstance(pid, int) or pid <= 0:
        return False
    if record.get("host") not in (None, platform.node()):
        return None
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # exists, owned by someone else
    started = record.get("proc_start")
    now = _proc_start_ticks(pid)
    return not (started is not None and now is not None and now != started)

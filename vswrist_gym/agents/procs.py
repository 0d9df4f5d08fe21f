"""The training process: torch threads, the library versions stored with every result, and whether a process
recorded in run.json still runs (pid, host and start time, so that a recycled pid is not taken for it)."""

from __future__ import annotations

import os
import platform
from pathlib import Path

import numpy as np


def limit_threads(n: int = 1) -> None:
    """One torch thread per process: the machines here have few cores shared by several processes."""
    import torch

    torch.set_num_threads(n)


def versions() -> dict:
    """Versions of the libraries that determine a result, stored with every run and every evaluation."""
    import gymnasium
    import mujoco
    import stable_baselines3
    import torch

    try:
        from importlib.metadata import version

        own = version("vswrist-gym")
    except Exception:  # noqa: BLE001 - not installed as a distribution: report unknown, never fail a run
        own = "unknown"
    return {"vswrist_gym": own, "mujoco": mujoco.__version__, "gymnasium": gymnasium.__version__,
            "stable_baselines3": stable_baselines3.__version__, "torch": torch.__version__,
            "numpy": np.__version__, "python": platform.python_version(), "platform": platform.platform(),
            "cpu_count": os.cpu_count()}


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

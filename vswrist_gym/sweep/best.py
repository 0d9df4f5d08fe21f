"""Write a searched hyperparameter entry into a hyperparameter file that `vswrist train --config` reads.

Kept apart on purpose: the entry goes through the hyperparameter module's own reader and validator, so when the
file format changes only this function follows it.
"""

from __future__ import annotations

from pathlib import Path

import yaml


def write_best_entry(path: str | Path, algo: str, env_id: str, entry: dict, comment: str = "") -> Path:
    """Put `entry` under `env_id` in the YAML file `path` (other entries kept; the file is created if absent),
    after checking it with `hparams.resolve_entry`; the written file is read back with `hparams.load_config`."""
    from vswrist_gym.agents.hparams import load_config, load_file, resolve_entry
    from vswrist_gym.agents.runs import atomic_write_text

    path = Path(path)
    resolve_entry(algo, env_id, entry, source=str(path))
    data = load_file(path) if path.is_file() else {}
    data[env_id] = entry
    head = "".join(f"# {line}\n" for line in comment.splitlines()) if comment else ""
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, head + yaml.safe_dump(data, sort_keys=False))
    load_config(algo, env_id, path)
    return path

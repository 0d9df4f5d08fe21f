"""A run directory's own description: config.yaml (the resolved entry, re-runnable as is), run.json (commands,
status, history), the seed check, and run keys overridden on the command line."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

from vswrist_gym.agents.fileio import RunDirError, atomic_write_text
from vswrist_gym.agents.hparams import ConfigError, RunConfig, resolve_entry


SEED_MAX = 2**32 - 1  # NumPy's and stable-baselines3's seeds are unsigned 32-bit integers


def check_seed(seed, name: str = "--seed") -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= int(seed) <= SEED_MAX:
        raise ConfigError(f"{name} must be an integer in [0, 2**32 - 1 = {SEED_MAX}] (the range NumPy and "
                          f"stable-baselines3 accept), got {seed}")
    return int(seed)


def write_config(run_dir: Path, cfg: RunConfig, seed: int) -> None:
    doc = {"env_id": cfg.env_id, "algo": cfg.algo, "seed": seed, "source": cfg.source,
           "hyperparameters": cfg.to_yaml_dict()}
    atomic_write_text(run_dir / "config.yaml", yaml.safe_dump(doc, sort_keys=False))


def read_config(run_dir: Path) -> tuple[RunConfig, int]:
    path = Path(run_dir) / "config.yaml"
    if not path.is_file():
        raise RunDirError(f"{run_dir} is not a run directory: {path.name} is missing (create one with vswrist train)")
    try:
        doc = yaml.safe_load(path.read_text())
        cfg = resolve_entry(doc["algo"], doc["env_id"], doc["hyperparameters"], source=str(path))
        return cfg, int(doc["seed"])
    except (yaml.YAMLError, KeyError, TypeError, ConfigError) as exc:
        raise RunDirError(f"{path} is corrupted or from an incompatible version: {exc}") from None


def update_run_json(run_dir: Path, **fields) -> dict:
    path = Path(run_dir) / "run.json"
    doc = json.loads(path.read_text()) if path.is_file() else {}
    for key, value in fields.items():
        if key == "command":
            doc.setdefault("commands", []).append(value)
        elif key == "history":
            doc.setdefault("history", []).append(value)
        else:
            doc[key] = value
    atomic_write_text(path, json.dumps(doc, indent=2))
    return doc


def override(cfg: RunConfig, **changes) -> RunConfig:
    """A copy of the config with run keys changed (None means keep)."""
    changes = {k: v for k, v in changes.items() if v is not None}
    return replace(cfg, **changes)

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
    from vswrist_gym.agents import hparams
    from vswrist_gym.agents.runs import atomic_write_text

    path = Path(path)
    hparams.resolve_entry(algo, env_id, entry, source=str(path))
    section_name = getattr(hparams, "RUN_SECTION", None)  # files whose run settings live in their own section
    if path.is_file():
        doc = yaml.safe_load(path.read_text())
        hparams.load_file(path)  # a clear error when the existing file is not a hyperparameter file
    else:
        doc = {}
    data = {k: v for k, v in doc.items() if k != section_name}
    section = dict(doc.get(section_name) or {}) if section_name else {}
    if section_name:
        keys = set(getattr(hparams, "SECTION_KEYS", ()))
        settings = {k: v for k, v in entry.items() if k in keys}
        entry = {k: v for k, v in entry.items() if k not in keys}
        section.pop(env_id, None)
        if settings:
            section[env_id] = settings
    data[env_id] = entry
    if section:
        data[section_name] = section
    head = "".join(f"# {line}\n" for line in comment.splitlines()) if comment else ""
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, head + yaml.safe_dump(data, sort_keys=False))
    hparams.load_config(algo, env_id, path)
    return path

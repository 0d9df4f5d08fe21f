"""The lookup of the trained policies shipped inside the package (``vswrist_gym/pretrained/``, one folder per
task and track: ``<Task>_<track>/``).

Each folder is a trimmed ``vswrist train`` run directory (``config.yaml``, ``run.json``, ``model.zip``,
``vecnormalize.npz``: no checkpoints, logs or learning curves), so ``runs.TrainedAgent`` loads it as it loads any
run, with the run's own action mode and normalisation statistics; beside them its model card (``CARD.md`` and the
machine-readable ``card.json``: training command, commit, budget, evaluation against the best constant
stiffness on the same episodes, per-episode returns for the replay test). The folders are written by
``python -m vswrist_gym.tools.ship_policies``.

On the command line a shipped policy is ``--agent pretrained:<Task>[:<track>]`` (``vswrist evaluate``, ``video``,
``view``); without a track, the one shipped for that task (the only one, or ``full`` where both ship).
"""

from __future__ import annotations

import json
from pathlib import Path

from vswrist_gym import task_name
from vswrist_gym.agents.hparams import TRACKS, ConfigError

PREFIX = "pretrained:"
ROOT = Path(__file__).resolve().parents[1] / "pretrained"  # the folders, package data
CARD_FILE = "card.json"
# what a shipped folder holds: a loadable run directory plus its card; nothing else is packaged
RUN_FILES = ("config.yaml", "run.json", "model.zip", "vecnormalize.npz")
CARD_FILES = (CARD_FILE, "CARD.md")


def folder_name(task: str, track: str) -> str:
    return f"{task}_{track}"


def shipped(root: Path | None = None) -> dict[tuple[str, str], Path]:
    """{(task, track): folder} of every shipped policy (a folder with its run's config.yaml and model.zip)."""
    root = ROOT if root is None else Path(root)
    found = {}
    for folder in sorted(p for p in root.iterdir() if p.is_dir() and "_" in p.name):
        task, _, track = folder.name.rpartition("_")
        if track in TRACKS and (folder / "model.zip").is_file() and (folder / "config.yaml").is_file():
            found[(task, track)] = folder
    return found


def describe(found: dict[tuple[str, str], Path]) -> str:
    return ", ".join(f"{task}:{track}" for task, track in found) or "none"


def default_track(task: str, found: dict[tuple[str, str], Path]) -> str | None:
    """The track used when none is named: the only one shipped for the task, else 'full' (the first of TRACKS)."""
    tracks = [tr for tr in TRACKS if (task, tr) in found]
    return tracks[0] if tracks else None


def is_spec(text: str) -> bool:
    return text.startswith(PREFIX)


def resolve(text: str, root: Path | None = None) -> Path:
    """The folder of ``pretrained:<Task>[:<track>]``; a one-line ConfigError listing what ships otherwise."""
    found = shipped(root)
    rest = text[len(PREFIX):] if is_spec(text) else text
    parts = rest.split(":")
    if not parts[0] or len(parts) > 2:
        raise ConfigError(f"--agent {text}: write pretrained:<Task>[:<track>]; shipped: {describe(found)}")
    try:
        task = task_name(parts[0])
    except ValueError:
        raise ConfigError(f"--agent {text}: unknown task {parts[0]!r}; shipped: {describe(found)}") from None
    if len(parts) == 2:
        track = parts[1]
        if track not in TRACKS:
            raise ConfigError(f"--agent {text}: track must be one of {', '.join(TRACKS)}, got {track!r}; "
                              f"shipped: {describe(found)}")
    else:
        track = default_track(task, found)
        if track is None:
            raise ConfigError(f"--agent {text}: no policy ships for {task}; shipped: {describe(found)}")
    if (task, track) not in found:
        raise ConfigError(f"--agent {text}: no {track}-track policy ships for {task}; shipped: {describe(found)}")
    return found[(task, track)]


def card(task: str, track: str | None = None, root: Path | None = None) -> dict:
    """The model card (card.json) of a shipped policy."""
    folder = resolve(f"{PREFIX}{task}" + (f":{track}" if track else ""), root)
    return json.loads((folder / CARD_FILE).read_text())

"""Trained policies shipped inside the package, one folder per task and track: ``<Task>_<track>/`` (what each
holds: ``vswrist_gym.agents.shipped``, which finds and resolves them). The names below are that module's, for
the commands that write and read the folders."""

from vswrist_gym.agents.shipped import (CARD_FILE, CARD_FILES, PREFIX, ROOT, RUN_FILES, card,  # noqa: F401
                                        default_track, describe, folder_name, is_spec, resolve, shipped)

"""The README's task pictures: rendered by a committed command, one per task, all present and referenced."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import vswrist_gym

ROOT = Path(__file__).resolve().parents[1]
FIGURES = ROOT / "docs" / "figures" / "tasks"


def test_every_task_has_a_committed_picture_in_the_readme():
    readme = (ROOT / "README.md").read_text()
    assert "python -m vswrist_gym.tools.pictures --out docs/figures/tasks/" in readme
    for task in vswrist_gym.TASKS:
        path = FIGURES / f"{task}.png"
        assert path.is_file() and path.stat().st_size < 150_000, path  # small: palette PNGs
        assert f"docs/figures/tasks/{task}.png" in readme, task


def test_pictures_command_renders_the_task(tmp_path, headless_gl):
    """A small frame of the same scene: not blank, and the task's object changes it (the frame at step 0 and
    at the picture step differ, since the tool has moved to the object)."""
    from vswrist_gym.tools import pictures

    a = pictures.frame("Polish", step=0, width=80, height=60)
    b = pictures.frame("Polish", width=80, height=60)
    assert a.shape == b.shape == (60, 80, 3)
    assert a.std() > 10 and b.std() > 10  # floor, sky and bodies: far from one colour
    assert np.abs(a.astype(int) - b.astype(int)).max() > 50
    assert pictures.main(["--out", str(tmp_path), "--tasks", "VSWrist/Drill-v2"]) == 0
    from PIL import Image

    with Image.open(tmp_path / "Drill.png") as im:
        assert im.size == (640, 480) and im.mode == "P"

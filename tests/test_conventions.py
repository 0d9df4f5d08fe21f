"""Package conventions: version, typing marker, changelog, and task names that every command accepts."""

from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
import tomllib
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import pytest

import vswrist_gym

ROOT = Path(__file__).resolve().parents[1]


def cli(*args, timeout=300) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONWARNINGS": "ignore::DeprecationWarning"}
    return subprocess.run([sys.executable, "-m", "vswrist_gym.cli", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout, env=env)


def test_version_agrees_everywhere():
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    try:
        installed = version("vswrist-gym")
    except PackageNotFoundError:
        pytest.skip("vswrist-gym is not installed (a bare source tree): no metadata to compare")
    assert vswrist_gym.__version__ == installed == declared
    res = cli("--version")
    assert res.returncode == 0 and res.stdout.strip() == f"vswrist-gym {declared}"


def test_typed_marker_is_shipped():
    assert (ROOT / "vswrist_gym" / "py.typed").is_file()
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    assert "py.typed" in data["vswrist_gym"]


def test_changelog_states_the_env_versioning_rule():
    text = (ROOT / "CHANGELOG.md").read_text()
    assert "bumps `N`" in text and "dynamics" in text and "observations" in text and "rewards" in text
    # every registered id carries a version, as the rule needs
    assert all(i.rsplit("-v", 1)[1].isdigit() for i in vswrist_gym.ENV_IDS)


def test_task_name_takes_both_forms():
    for full in vswrist_gym.ENV_IDS:
        short = full.split("/")[1].rsplit("-v", 1)[0]
        assert vswrist_gym.task_name(full) == vswrist_gym.task_name(short) == short
    for bad in ("Polishh", "VSWrist/Polish-v9", "polish", ""):
        with pytest.raises(ValueError, match="full id"):
            vswrist_gym.task_name(bad)


def test_short_names_mean_the_newest_version():
    """A short name is its task's highest registered version; a full id keeps its own version."""
    by_task = {}
    for full in vswrist_gym.ENV_IDS:
        short, version = full.split("/")[1].rsplit("-v", 1)
        by_task.setdefault(short, []).append(int(version))
    assert set(vswrist_gym.TASKS) == set(by_task)
    for short, versions in by_task.items():
        newest = f"VSWrist/{short}-v{max(versions)}"
        assert vswrist_gym.LATEST[short] == vswrist_gym.resolve_id(short) == newest
        assert vswrist_gym.newest_task_name(newest) == short
        for v in versions:
            assert vswrist_gym.resolve_id(f"VSWrist/{short}-v{v}") == f"VSWrist/{short}-v{v}"
    assert vswrist_gym.LATEST["Polish"] == "VSWrist/Polish-v1"
    with pytest.raises(ValueError, match="not the newest version of Polish") as exc:
        vswrist_gym.newest_task_name("VSWrist/Polish-v0")
    assert "\n" not in str(exc.value)
    for bad in ("Polishh", "VSWrist/Polish-v9", ""):
        with pytest.raises(ValueError, match="full id"):
            vswrist_gym.resolve_id(bad)


# every command-line tool that takes tasks, as a module with main(argv) and its task option
TASK_CLIS = [("vswrist_gym.tools.bench", "--tasks"), ("vswrist_gym.tools.probe", "--tasks"),
             ("vswrist_gym.tools.closure", "--tasks"), ("vswrist_gym.tools.soak", "--tasks"),
             ("vswrist_gym.tools.video", "--task"), ("vswrist_gym.tools.view", "--task"),
             ("vswrist_gym.tools.pictures", "--tasks")]


@pytest.mark.parametrize("module,option", TASK_CLIS)
def test_every_task_option_parses_with_task_name(module, option, capsys):
    """An unknown name is refused by the shared parser (its message offers the full-id form), so both forms go
    through the same function; the commands that resolve ids themselves are checked end to end below."""
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError:
        pytest.skip(f"{module} is not in this tree")
    with pytest.raises(SystemExit) as exc:
        mod.main([option, "NoSuchTask"])
    assert exc.value.code == 2
    assert "or its full id" in capsys.readouterr().err


@pytest.mark.parametrize("module", ["vswrist_gym.tools.bench", "vswrist_gym.tools.probe", "vswrist_gym.tools.closure",
                                    "vswrist_gym.tools.soak", "vswrist_gym.tools.pictures"])
def test_tools_that_run_the_newest_versions_refuse_an_older_id(module, capsys):
    """They take short names for the newest version; an older id is a one-line error, never swapped for it."""
    mod = importlib.import_module(module)
    with pytest.raises(SystemExit) as exc:
        mod.main(["--tasks", "VSWrist/Polish-v0"])
    assert exc.value.code == 2
    assert "not the newest version of Polish" in capsys.readouterr().err


def test_train_evaluate_compare_take_both_forms(tmp_path):
    """The same agent on the same episode under the short name and the full id gives the same numbers."""
    returns = []
    for name in ("Polish", "VSWrist/Polish-v1"):
        out = tmp_path / name.replace("/", "_")
        res = cli("evaluate", "--task", name, "--agent", "analytic:0", "--episodes", "1", "--seeds", "0",
                  "--out", out)
        assert res.returncode == 0, res.stderr
        returns.append(json.loads((out / "metrics.json").read_text())["episodes"][0]["return"])
    assert returns[0] == returns[1]
    from vswrist_gym.agents.train import task_id

    assert task_id("Polish") == task_id("VSWrist/Polish-v1") == "VSWrist/Polish-v1"
    assert task_id("VSWrist/Polish-v0") == "VSWrist/Polish-v0"  # an older version stays itself

"""The light core install: the environments, the simulator and the analytic baseline without the [train] extra.

Each check runs in a fresh interpreter, because this test process has long since imported torch. A core install is
imitated by a meta-path hook that refuses every module of the [train] extra, as an interpreter without them would.
"""

import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import vswrist_gym

ROOT = Path(vswrist_gym.__file__).resolve().parents[1]  # the tested tree, also where another copy is installed
# the import names of the [train] extra's distributions (torch, stable-baselines3, sb3-contrib, tensorboard, ...)
TRAIN_MODULES = ("torch", "stable_baselines3", "sb3_contrib", "tensorboard", "matplotlib", "tqdm", "rich")
# README.md and .ci/run run the suite with exactly this line (pinned torch first: pip then never takes a CUDA build)
TEST_COMMAND = 'python3 -m pip install "torch==2.13.0" -e ".[test]" && python3 -m pytest -n 2 -q'

BLOCK = f"""
import importlib.abc, sys
class _NoTrainExtra(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {TRAIN_MODULES!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
sys.meta_path.insert(0, _NoTrainExtra())
"""


def _python(code: str, *args: str, block: bool = False, cwd: Path | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONWARNINGS": "ignore"}
    return subprocess.run([sys.executable, "-c", (BLOCK if block else "") + code, *args], capture_output=True,
                          text=True, env=env, cwd=cwd or ROOT, timeout=300)


def _vswrist(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return _python("import sys\nfrom vswrist_gym.cli import main\nsys.exit(main(sys.argv[1:]))", *args, block=True,
                   cwd=cwd)


def test_environments_never_import_the_training_stack():
    """Importing the package, gym.make of every registered id and gym.make_vec of each: no torch, no SB3."""
    code = f"""
import json, sys
import gymnasium as gym
import vswrist_gym
ids = [i for i in gym.registry if i.startswith("VSWrist/")]
for i in ids:
    env = gym.make(i)
    env.reset(seed=0)
    env.step(env.action_space.sample())
    env.close()
    venv = gym.make_vec(i, 2)
    venv.reset(seed=0)
    venv.step(venv.action_space.sample())
    venv.close()
print(json.dumps({{"ids": ids, "loaded": sorted({{m.split(".")[0] for m in sys.modules}} & set({TRAIN_MODULES!r}))}}))
"""
    r = _python(code)
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout.strip().splitlines()[-1])
    assert len(doc["ids"]) >= 6  # one id per task at least: LoadHold, Polish, Impact, Insertion, Drill, Hammer
    assert doc["loaded"] == []


def test_environments_work_without_the_train_extra():
    r = _python("import gymnasium as gym, vswrist_gym\nenv = gym.make('VSWrist/Polish')\nenv.reset(seed=0)\n"
                "print(env.step(env.action_space.sample())[1])", block=True)
    assert r.returncode == 0, r.stderr
    float(r.stdout.strip())  # a reward


def test_core_dependencies_leave_the_training_stack_to_the_extra():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]

    def names(reqs):
        return {req.split(";")[0].split("[")[0].split("=")[0].split(">")[0].split("<")[0].strip().lower()
                for req in reqs}

    core = names(project["dependencies"])
    extras = project["optional-dependencies"]
    assert {"numpy", "mujoco", "gymnasium", "pyyaml"} <= core
    assert not core & {"torch", "stable-baselines3", "sb3-contrib", "tensorboard", "matplotlib", "tqdm", "rich"}
    assert {"torch", "stable-baselines3", "sb3-contrib"} <= names(extras["train"])
    assert "vswrist-gym[train,stats]" in extras["test"] and "vswrist-gym[train]" in extras["sweep"]


def test_analytic_evaluation_and_video_run_on_a_core_install(tmp_path, headless_gl):
    r = _vswrist("evaluate", "--task", "LoadHold", "--agent", "analytic", "--episodes", "1", "--seeds", "0",
                 "--out", str(tmp_path / "eval"), cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    assert len(doc["episodes"]) == 1
    r = _vswrist("video", "--task", "LoadHold", "--agent", "analytic", "--out", str(tmp_path / "ep.mp4"),
                 "--width", "64", "--height", "48", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "ep.mp4").stat().st_size > 0
    r = _vswrist("info", cwd=tmp_path)  # the analytic model: stiffness range and the kinematics self-check
    assert r.returncode == 0 and "(ok)" in r.stdout, r.stderr


@pytest.mark.parametrize("args", [
    ("train", "--task", "Polish", "--algo", "ppo", "--out", "run"),
    ("compare", "--task", "Polish", "--out", "cmp"),
    ("evaluate", "--task", "Polish", "--agent", "pretrained:Polish", "--out", "eval"),
])
def test_training_commands_name_the_train_extra_in_one_line(tmp_path, args):
    r = _vswrist(*args, cwd=tmp_path)
    assert r.returncode == 2
    err = r.stderr.strip()
    assert "\n" not in err and "[train]" in err and "pip install" in err, err
    assert list(tmp_path.iterdir()) == []  # refused before writing anything


def test_ci_runs_the_readme_test_command():
    lines = [line.strip() for line in (ROOT / ".ci" / "run").read_text().splitlines()]
    assert TEST_COMMAND in lines

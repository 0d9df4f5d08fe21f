"""The shipped hyperparameter files in RL Zoo itself: `python -m rl_zoo3.train --conf-file` trains from them
unchanged, and the model it writes replays through `vswrist evaluate` and `vswrist video` exactly as through
`rl_zoo3.enjoy` (same action mode, same normalisation statistics), or is refused in one line."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from vswrist_gym.agents import hparams

pytest.importorskip("rl_zoo3")

TASK = "VSWrist/Polish-v1"
FOLDER = "VSWrist-Polish-v1"  # rl_zoo3's folder name for the id
EVAL_SEED = 1_000_000  # `vswrist evaluate` resets episode 0 of seed 0 with this seed (protocol.reset_seed)


def run(*args, cwd, timeout=300) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONWARNINGS": "ignore::DeprecationWarning"}
    res = subprocess.run([sys.executable, *map(str, args)], capture_output=True, text=True, cwd=cwd,
                         timeout=timeout, env=env)
    return res


@pytest.fixture(scope="module")
def zoo_run(tmp_path_factory) -> Path:
    """2,000 PPO steps on Polish with rl_zoo3, from the shipped file, with the flags its `vswrist:` section names."""
    cwd = tmp_path_factory.mktemp("zoo")
    args = hparams.zoo_train_args("ppo", TASK)
    res = run("-m", "rl_zoo3.train", *args, "-n", "2000", "--seed", "0", "--device", "cpu", "-f", "logs",
              "--num-threads", "1", cwd=cwd)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-3000:]
    folder = cwd / "logs" / "ppo" / f"{FOLDER}_1"
    assert (folder / f"{FOLDER}.zip").is_file() and (folder / FOLDER / "vecnormalize.pkl").is_file()
    return folder


@pytest.fixture(scope="module")
def zoo_return(zoo_run, tmp_path_factory) -> float:
    """The return of `vswrist evaluate` on the zoo run, episode 0 of seed 0."""
    out = tmp_path_factory.mktemp("zoo_eval")
    res = run("-m", "vswrist_gym.cli", "evaluate", "--task", "Polish", "--agent", zoo_run, "--seeds", "0",
              "--episodes", "1", "--out", out / "ev", cwd=out)
    assert res.returncode == 0, res.stderr
    return json.loads((out / "ev" / "metrics.json").read_text())["episodes"][0]["return"]


def test_sac_file_loads_in_rl_zoo(tmp_path):
    """sac.yaml too: 200 steps, below learning_starts, so only loading and building are exercised."""
    res = run("-m", "rl_zoo3.train", *hparams.zoo_train_args("sac", TASK), "-n", "200", "--seed", "0",
              "--device", "cpu", "-f", "logs", "--num-threads", "1", cwd=tmp_path)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-3000:]
    assert (tmp_path / "logs" / "sac" / f"{FOLDER}_1" / f"{FOLDER}.zip").is_file()


def enjoy_returns(logs, cwd, algo: str = "ppo") -> list[float]:
    """The episode returns ``rl_zoo3.enjoy`` prints for experiment 1 of ``algo`` on TASK under ``logs``
    (deterministic, the evaluation reset seed; RL Zoo's own loading of the model and its statistics)."""
    res = run("-m", "rl_zoo3.enjoy", "--algo", algo, "--env", TASK, "--gym-packages", "vswrist_gym",
              "-f", logs, "--exp-id", "1", "-n", "150", "--no-render", "--deterministic",
              "--device", "cpu", "--seed", EVAL_SEED, cwd=cwd)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-3000:]
    enjoy = [float(x) for x in re.findall(r"Episode Reward: (-?[\d.]+)", res.stdout)]
    assert enjoy, res.stdout[-2000:]
    return enjoy


def test_zoo_model_replays_as_in_rl_zoo_enjoy(zoo_run, zoo_return, tmp_path, request):
    """rl_zoo3.enjoy (RL Zoo's own loading of the model, its env_kwargs and its vecnormalize.pkl), `vswrist
    evaluate` and `vswrist video` on the same reset seed give the same return; what cannot be replayed faithfully
    is refused in one line. (One test, so that the xdist workers train the run once.)"""
    enjoy = enjoy_returns(zoo_run.parent.parent, tmp_path)
    assert zoo_return == pytest.approx(enjoy[0], abs=0.006)  # enjoy prints two decimals
    # the same through the model file's path, which resolves to its experiment folder
    res = run("-m", "vswrist_gym.cli", "evaluate", "--task", TASK, "--agent", zoo_run / f"{FOLDER}.zip",
              "--seeds", "0", "--episodes", "1", "--out", tmp_path / "ev2", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert json.loads((tmp_path / "ev2" / "metrics.json").read_text())["episodes"][0]["return"] == zoo_return

    # refused: another action mode than the run's, a model file outside its run folder, a run of another task
    import gymnasium as gym

    from vswrist_gym.agents.runs import RunDirError, TrainedAgent

    agent = TrainedAgent(zoo_run)
    assert agent.cfg.env_kwargs["action_mode"] == "residual"  # from ppo.yaml's entry, through config.yml
    env = gym.make(TASK)  # the default posture_stiffness mode: same spaces, other meaning of the actions
    try:
        with pytest.raises(RunDirError, match="action_mode: trained with 'residual'"):
            agent.check_env(env)
    finally:
        env.close()
    shutil.copy(zoo_run / f"{FOLDER}.zip", tmp_path / "model.zip")
    res = run("-m", "vswrist_gym.cli", "video", "--task", TASK, "--agent", tmp_path / "model.zip",
              "--out", tmp_path / "v.mp4", cwd=tmp_path)
    assert res.returncode == 2 and "model file alone" in res.stderr and "Traceback" not in res.stderr
    res = run("-m", "vswrist_gym.cli", "video", "--task", "Drill", "--agent", zoo_run, "--out", tmp_path / "v.mp4",
              cwd=tmp_path)
    assert res.returncode == 2 and "Polish" in res.stderr and "Traceback" not in res.stderr

    # the video, where this machine renders offscreen
    request.getfixturevalue("headless_gl")  # skips the rest (only) where there is no OpenGL
    res = run("-m", "vswrist_gym.cli", "video", "--task", TASK, "--agent", zoo_run, "--seed", EVAL_SEED,
              "--width", "64", "--height", "48", "--out", tmp_path / "v.mp4", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    shown = float(re.search(r"return (-?[\d.]+)", res.stdout).group(1))
    assert shown == pytest.approx(zoo_return, abs=0.006)


@pytest.mark.slow  # wiring only: the viewer's own test (test_view.py) and the agent checks above run by default
def test_zoo_model_in_the_viewer(zoo_run, tmp_path):
    """`vswrist view --agent` takes the same run folders, under Xvfb where it is installed."""
    if shutil.which("xvfb-run") is None:
        pytest.skip("Xvfb is not installed (apt-get install xvfb)")
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    res = subprocess.run(["xvfb-run", "-a", "-s", "-screen 0 1280x1024x24", sys.executable, "-m", "vswrist_gym.cli",
                          "view", "--task", "Polish", "--agent", str(zoo_run), "--duration", "2", "--speed", "4"],
                         capture_output=True, text=True, timeout=180, env=env, cwd=tmp_path)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    assert int(re.search(r"(\d+) control steps", res.stdout)[1]) > 0


def test_zoo_folder_reading_without_training(tmp_path):
    """RL Zoo's config.yml / args.yml as rl_zoo3 writes them (yaml.dump of OrderedDicts), read without running
    anything: the entry and env_kwargs as enjoy reads them, keys that only shape training ignored, keys that change
    the policy's inputs refused, and any other Python tag refused."""
    from collections import OrderedDict

    import yaml

    from vswrist_gym.agents.runs import RunDirError, read_zoo_run

    folder = tmp_path / "ppo" / f"{FOLDER}_1"
    params = folder / FOLDER
    params.mkdir(parents=True)

    def write(hyper: dict, env_kwargs=None):
        (params / "config.yml").write_text(yaml.dump(OrderedDict(sorted(hyper.items()))))
        (params / "args.yml").write_text(yaml.dump(OrderedDict([("algo", "ppo"), ("env", TASK),
                                                                ("env_kwargs", env_kwargs), ("seed", 7)])))

    entry = {"n_timesteps": 100, "policy": "MlpPolicy", "env_kwargs": {"action_mode": "residual"},
             "normalize": {"gamma": 0.95, "norm_obs": True, "norm_reward": False},
             "policy_kwargs": "dict(features_extractor_class=MyExtractor)", "noise_type": "normal"}
    write(entry)
    assert "!!python/object/apply:collections.OrderedDict" in (params / "config.yml").read_text()
    cfg, seed, found = read_zoo_run(folder)
    assert (cfg.env_id, cfg.algo, seed, found) == (TASK, "ppo", 7, params)
    assert cfg.env_kwargs == {"action_mode": "residual"} and cfg.normalize == {"norm_obs": True, "norm_reward": False}
    write(entry, env_kwargs={"action_mode": "motor"})  # --env-kwargs on rl_zoo3's command line win, as in enjoy
    assert read_zoo_run(folder)[0].env_kwargs == {"action_mode": "motor"}
    write({**entry, "frame_stack": 4})  # replayed with the stacking rl_zoo3 trained with
    assert read_zoo_run(folder)[0].frame_stack == 4
    write({**entry, "env_wrapper": "gymnasium.wrappers.TimeAwareObservation"})
    with pytest.raises(RunDirError, match="env_wrapper"):
        read_zoo_run(folder)
    (params / "config.yml").write_text("!!python/object/apply:os.system ['echo pwned']\n")
    with pytest.raises(RunDirError, match="not readable"):
        read_zoo_run(folder)


def test_frame_stacked_zoo_run_replays_as_in_enjoy(tmp_path):
    """RL Zoo's `frame_stack` key: rl_zoo3 trains with VecFrameStack (after VecNormalize) and enjoy replays with
    it; `vswrist evaluate` on the same reset seed, which stacks in the agent, gives enjoy's return."""
    import yaml

    entry = dict(hparams.load_file(hparams.default_config_path("ppo"))[TASK])
    entry.update(frame_stack=3, n_envs=2, n_steps=64, batch_size=64, n_epochs=1)
    conf = tmp_path / "fs.yaml"
    conf.write_text(yaml.safe_dump({TASK: entry}))
    res = run("-m", "rl_zoo3.train", "--algo", "ppo", "--env", TASK, "--gym-packages", "vswrist_gym", "--conf-file",
              conf, "--vec-env", "dummy", "--eval-freq", "-1", "-n", "256", "--seed", "0", "--device", "cpu",
              "-f", "logs", "--num-threads", "1", cwd=tmp_path)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-3000:]
    folder = tmp_path / "logs" / "ppo" / f"{FOLDER}_1"
    enjoy = enjoy_returns(folder.parent.parent, tmp_path)
    res = run("-m", "vswrist_gym.cli", "evaluate", "--task", TASK, "--agent", folder, "--seeds", "0",
              "--episodes", "1", "--out", tmp_path / "ev", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    doc = json.loads((tmp_path / "ev" / "metrics.json").read_text())
    assert doc["episodes"][0]["return"] == pytest.approx(enjoy[0], abs=0.006)  # enjoy prints two decimals


def test_recurrent_zoo_run_replays_as_in_enjoy(tmp_path):
    """RL Zoo's ppo_lstm (sb3-contrib's RecurrentPPO) from the shipped configs/ppo_lstm.yaml: rl_zoo3 trains it,
    enjoy replays it carrying the LSTM state, and `vswrist evaluate` on the same reset seed gives enjoy's return."""
    import yaml

    entry = dict(hparams.load_file(hparams.default_config_path("ppo_lstm"))[TASK])
    entry.update(n_envs=2, n_steps=64, batch_size=64, n_epochs=1)
    conf = tmp_path / "lstm.yaml"
    conf.write_text(yaml.safe_dump({TASK: entry}))
    res = run("-m", "rl_zoo3.train", "--algo", "ppo_lstm", "--env", TASK, "--gym-packages", "vswrist_gym",
              "--conf-file", conf, "--vec-env", "dummy", "--eval-freq", "-1", "-n", "256", "--seed", "0",
              "--device", "cpu", "-f", "logs", "--num-threads", "1", cwd=tmp_path)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-3000:]
    folder = tmp_path / "logs" / "ppo_lstm" / f"{FOLDER}_1"
    enjoy = enjoy_returns(folder.parent.parent, tmp_path, algo="ppo_lstm")
    res = run("-m", "vswrist_gym.cli", "evaluate", "--task", TASK, "--agent", folder, "--seeds", "0",
              "--episodes", "1", "--out", tmp_path / "ev", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    doc = json.loads((tmp_path / "ev" / "metrics.json").read_text())
    assert doc["episodes"][0]["return"] == pytest.approx(enjoy[0], abs=0.006)  # enjoy prints two decimals


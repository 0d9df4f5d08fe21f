"""Training, evaluation and comparison: hyperparameter files, statistics, checkpoints, and the three commands
run end to end as subprocesses with tiny budgets, as a user calls them."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from vswrist_gym.agents import hparams, protocol, runs

TASK = "VSWrist/LoadHold-v0"
PIPELINE_TASK = "Pendulum-v1"  # a standard Gymnasium task: tests the pipeline without the VS-Wrist simulator


def vswrist(*args, cwd=None, timeout=300) -> subprocess.CompletedProcess:
    """Run `vswrist ...` as a user would (a fresh interpreter, through the CLI entry point)."""
    env = {**os.environ, "PYTHONWARNINGS": "ignore::DeprecationWarning"}  # MUJOCO_GL: as conftest's import set it
    return subprocess.run([sys.executable, "-m", "vswrist_gym.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=timeout, env=env)


def _registered_vswrist() -> list[str]:
    import gymnasium as gym

    import vswrist_gym  # noqa: F401

    return sorted(k for k in gym.registry if k.startswith("VSWrist/"))


# ------------------------------------------------------------------------------------------- hyperparameter files


# besides the packaged configs/<algo>.yaml, the studies' own algorithm files (experiments/<study>/<algo>.yaml),
# whose entries were run for committed tables
EXPERIMENTS = Path(__file__).resolve().parents[1] / "experiments"


def _files(algo: str) -> list[Path]:
    return [hparams.default_config_path(algo), *sorted(EXPERIMENTS.glob(f"*/{algo}.yaml"))]


def _entries():
    for algo in hparams.ALGO_NAMES:
        for path in _files(algo):
            for env_id in hparams.load_file(path):
                yield pytest.param(algo, env_id, path, id=f"{algo}-{path.parent.name}-{env_id}")


def _same(actual, expected) -> bool:
    if callable(actual) and not isinstance(expected, str):
        actual = actual(1.0)  # SB3 turns numbers into constant schedules; value at the start of training
    if hasattr(actual, "frequency"):  # TrainFreq(frequency, unit)
        actual = actual.frequency
    if isinstance(expected, str) and expected.startswith("lin_"):
        return math.isclose(actual(1.0), float(expected[4:])) and actual(0.0) == 0.0
    if isinstance(expected, float) or isinstance(actual, float):
        return math.isclose(float(actual), float(expected))
    return actual == expected


def _rl_zoo_eval(text: str):
    """RL Zoo's own reading of a policy_kwargs string (rl_zoo3's exp_manager evaluates it with torch.nn as nn): the
    independent reference the package's eval-free parser is checked against. Only the shipped files go through it."""
    import torch as th
    import torch.nn as nn

    return eval(text, {"__builtins__": {}, "dict": dict, "nn": nn, "th": th})  # noqa: S307 - trusted test input


@pytest.mark.parametrize("algo,env_id,path", list(_entries()))
def test_every_hyperparameter_key_is_used(algo, env_id, path):
    """Each key of each entry either configures the run or ends up, with its value, in the constructed model."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    entries, section = hparams.read_file(path)
    raw = entries[env_id]
    cfg = hparams.load_config(algo, env_id, path)
    run_keys = set(raw) & set(hparams.ZOO_RUN_KEYS)
    algo_keys = set(raw) - run_keys
    assert set(cfg.algo_kwargs) == algo_keys
    # the settings RL Zoo has no key for come from the `vswrist:` section, never from the entry
    assert not set(raw) & set(hparams.SECTION_KEYS)
    for key, value in section[env_id].items():
        assert getattr(cfg, key) == value, key
    # policy_kwargs: the package's parser gives what RL Zoo's eval gives
    if "policy_kwargs" in raw:
        assert isinstance(raw["policy_kwargs"], str)  # RL Zoo's notation
        assert cfg.policy_kwargs == _rl_zoo_eval(raw["policy_kwargs"])
    venv = DummyVecEnv([runs.EnvFactory(env_id, cfg.env_kwargs)])
    try:
        model = hparams.algo_class(algo)(cfg.policy, runs.wrap_frame_stack(runs.wrap_normalize(venv, cfg),
                                                                          cfg.frame_stack),
                                         policy_kwargs=cfg.policy_kwargs or None, device="cpu", **cfg.algo_kwargs)
        assert model.observation_space.shape[-1] == cfg.frame_stack * venv.observation_space.shape[-1]
        for key in algo_keys:
            assert _same(getattr(model, key), raw[key]), f"{algo} {env_id}: {key}"
        # run keys: values reach the resolved config unchanged (they are consumed by train(), tested end to end below)
        for key in run_keys - {"normalize", "policy_kwargs"}:
            assert getattr(cfg, key) == raw[key], key
        if "normalize" in raw:
            assert (cfg.normalize is not None) == bool(raw["normalize"])
            assert (model.get_vec_normalize_env() is not None) == bool(raw["normalize"])
        for key, value in cfg.policy_kwargs.items():
            if key == "activation_fn":
                assert any(isinstance(m, value) for m in model.policy.modules())
                others = {nn for nn in (type(m) for m in model.policy.modules())
                          if nn.__module__ == "torch.nn.modules.activation"}
                if algo == "sac" and raw.get("use_sde"):
                    # SB3's SAC actor clips the gSDE mean with a Hardtanh (clip_mean): not a hidden activation
                    others = {nn for nn in others if nn.__name__ != "Hardtanh"}
                assert others == {value}, others
            elif key == "log_std_init":
                # SAC keeps it in the actor, and uses it only with gSDE (else log_std is a layer, and this fails)
                log_std = model.policy.actor.log_std if algo == "sac" else model.policy.log_std
                assert np.allclose(log_std.detach().numpy(), value)
            else:
                assert model.policy_kwargs[key] == value, key
        if "net_arch" in cfg.policy_kwargs:
            layers = [m.out_features for m in model.policy.modules() if m.__class__.__name__ == "Linear"]
            arch = cfg.policy_kwargs["net_arch"]
            hidden = arch if isinstance(arch, list) else arch.get("pi", [])
            assert all(h in layers for h in hidden)
    finally:
        venv.close()


def test_every_vswrist_task_has_ppo_and_sac_entries():
    ids = _registered_vswrist()
    if not ids:
        pytest.skip("no VSWrist environments registered yet")
    for algo in hparams.ALGO_NAMES:
        entries = hparams.load_file(hparams.default_config_path(algo))
        assert set(ids) <= set(entries), f"{algo}.yaml lacks {sorted(set(ids) - set(entries))}"


def test_unknown_and_bad_keys_are_named():
    entry = {"n_timesteps": 100, "n_step": 64}
    with pytest.raises(hparams.ConfigError, match="n_step"):
        hparams.resolve_entry("ppo", "Pendulum-v1", entry)
    with pytest.raises(hparams.ConfigError, match="n_envs"):
        hparams.resolve_entry("ppo", "Pendulum-v1", {"n_timesteps": 100, "n_envs": 0})
    with pytest.raises(hparams.ConfigError, match="activation_fn"):
        hparams.resolve_entry("sac", "Pendulum-v1", {"n_timesteps": 100, "policy_kwargs": {"activation_fn": "nn.Tanh"}})
    with pytest.raises(hparams.ConfigError, match="env_wrapper"):
        hparams.resolve_entry("ppo", "Pendulum-v1", {"n_timesteps": 100, "env_wrapper": "gymnasium.wrappers.X"})
    with pytest.raises(hparams.ConfigError, match="algo"):
        hparams.resolve_entry("td3", "Pendulum-v1", {"n_timesteps": 100})


@pytest.mark.parametrize("algo,key,value,match", [
    ("ppo", "learning_rate", "6e-4", "decimal point"),  # YAML 1.1 reads an exponent without a point as text
    ("sac", "batch_size", "abc", "must be a number"),
    ("ppo", "use_sde", "yes", "true or false"),
])
def test_numeric_arguments_of_the_wrong_type_are_named(algo, key, value, match):
    with pytest.raises(hparams.ConfigError, match=f"'{key}' {match}|{match}"):
        hparams.resolve_entry(algo, "Pendulum-v1", {"n_timesteps": 100, key: value})


def test_numeric_checks_leave_sb3s_other_forms_alone():
    cfg = hparams.resolve_entry("sac", "Pendulum-v1", {"n_timesteps": 100, "ent_coef": "auto_0.1",
                                                       "train_freq": [1, "episode"], "learning_rate": "lin_3e-4"})
    assert cfg.algo_kwargs["ent_coef"] == "auto_0.1" and cfg.algo_kwargs["train_freq"] == [1, "episode"]


@pytest.mark.parametrize("text", [
    "dict(a=__import__('os').system('echo pwned'))",   # a call other than dict(...)
    "dict(activation_fn=nn.Module)",                    # a name outside the allow-list
    "dict(activation_fn=nn.Tanh.__subclasses__)",       # attribute access past an allowed name
    "dict(**{'a': 1})", "dict({'a': 1})",               # unpacking and positional arguments
    "dict(a=lambda: 1)", "dict(a=[x for x in ()])", "dict(a=1 + 1)", "dict(a=os)",
    "dict(a=1", "[64, 64]", "nn.Tanh",                  # not a dict(...) expression
])
def test_policy_kwargs_strings_outside_the_grammar_are_refused(text):
    with pytest.raises(hparams.ConfigError, match="policy_kwargs"):
        hparams.parse_dict_string("policy_kwargs", text)


def test_policy_kwargs_strings_read_as_rl_zoo_reads_them():
    """RL Zoo notation, including forms the shipped files do not use, against RL Zoo's own evaluation."""
    for text in ["dict(net_arch=[256, 256])", "dict(log_std_init=-2, ortho_init=False, activation_fn=nn.ReLU, "
                 "net_arch=dict(pi=[256, 256], vf=[256, 256]))", "dict(net_arch=dict(pi=[64], qf=[400, 300]), "
                 "optimizer_class=th.optim.AdamW, optimizer_kwargs=dict(eps=1e-5, betas=(0.9, 0.999)))",
                 "{'net_arch': [8], 'squash_output': True, 'features_extractor_kwargs': None}", "dict()"]:
        assert hparams.parse_dict_string("policy_kwargs", text) == _rl_zoo_eval(text), text
    cfg = hparams.resolve_entry("ppo", "Pendulum-v1", {"n_timesteps": 10,
                                                       "normalize": "dict(norm_obs=True, norm_reward=False)"})
    assert cfg.normalize == {"norm_obs": True, "norm_reward": False}
    with pytest.raises(hparams.ConfigError, match="normalize"):
        hparams.resolve_entry("ppo", "Pendulum-v1", {"n_timesteps": 10, "normalize": "dict(norm_obs=nn.Tanh)"})


def test_run_settings_section(tmp_path):
    """The `vswrist:` section carries what RL Zoo takes as flags; it may not repeat an entry key or name a key or id
    the file does not have."""
    f = tmp_path / "ppo.yaml"
    entry = {"n_timesteps": 100, "n_envs": 1}
    f.write_text(yaml.safe_dump({"Pendulum-v1": entry, "vswrist": {"Pendulum-v1": {"eval_freq": 20,
                                                                                   "keep_checkpoints": 3}}}))
    cfg = hparams.load_config("ppo", "Pendulum-v1", f)
    assert (cfg.eval_freq, cfg.keep_checkpoints) == (20, 3)
    assert hparams.load_file(f) == {"Pendulum-v1": entry}
    args = hparams.zoo_train_args("ppo", "Pendulum-v1", f)
    assert args[args.index("--eval-freq") + 1] == "20" and args[args.index("--conf-file") + 1] == str(f)
    for section, match in [({"Pendulum-v1": {"n_steps": 64}}, "n_steps"), ({"CartPole-v1": {"eval_freq": 5}},
                                                                            "CartPole-v1")]:
        f.write_text(yaml.safe_dump({"Pendulum-v1": entry, "vswrist": section}))
        with pytest.raises(hparams.ConfigError, match=match):
            hparams.load_config("ppo", "Pendulum-v1", f)
    f.write_text(yaml.safe_dump({"Pendulum-v1": {**entry, "eval_freq": 10},
                                 "vswrist": {"Pendulum-v1": {"eval_freq": 20}}}))
    with pytest.raises(hparams.ConfigError, match="both"):
        hparams.load_config("ppo", "Pendulum-v1", f)


def test_files_of_the_earlier_format_still_load(tmp_path):
    """Run directories and user files written before the RL Zoo format (run settings inside the entry,
    activation_fn as a plain name) resolve to the same settings."""
    import torch.nn as nn

    cfg = hparams.resolve_entry("ppo", TASK, {"n_timesteps": 100, "vec_env": "dummy", "eval_freq": 50,
                                              "policy_kwargs": {"net_arch": [8], "activation_fn": "tanh"}})
    assert cfg.vec_env == "dummy" and cfg.eval_freq == 50
    assert cfg.policy_kwargs == {"net_arch": [8], "activation_fn": nn.Tanh}


def test_documented_rl_zoo_command_matches_the_file():
    """docs/training.md's rl_zoo3 command carries the flags the `vswrist:` section gives for Polish."""
    doc = (Path(__file__).resolve().parents[1] / "docs" / "training.md").read_text()
    command = doc[doc.index("python -m rl_zoo3.train"):].split("\n\n")[0].split("```")[0].replace("\\\n", " ")
    words = command.split()
    args = hparams.zoo_train_args("ppo", "VSWrist/Polish-v1")
    for flag, value in zip(args[::2], args[1::2]):
        assert flag in words, flag
        shown = words[words.index(flag) + 1]
        assert shown == value or (flag == "--conf-file" and value.endswith(shown)), (flag, shown, value)


def test_linear_schedule_is_parsed_not_evaluated():
    cfg = hparams.resolve_entry("ppo", "Pendulum-v1", {"n_timesteps": 10, "learning_rate": "lin_3e-4"})
    lr = cfg.algo_kwargs["learning_rate"]
    assert lr(1.0) == pytest.approx(3e-4) and lr(0.5) == pytest.approx(1.5e-4)
    with pytest.raises(hparams.ConfigError, match="lin_"):
        hparams.resolve_entry("ppo", "Pendulum-v1", {"n_timesteps": 10, "learning_rate": "lin___import__('os')"})


# ------------------------------------------------------------------------------------------- statistics


# Two-sided 95 % (t_0.975) and 99 % (t_0.995) critical values as printed in Student-t tables (e.g. Montgomery &
# Runger, Applied Statistics and Probability for Engineers, Table V), three decimals.
T_TABLE = [(0.975, 1, 12.706), (0.975, 2, 4.303), (0.975, 3, 3.182), (0.975, 4, 2.776), (0.975, 5, 2.571),
           (0.975, 9, 2.262), (0.975, 10, 2.228), (0.975, 19, 2.093), (0.975, 29, 2.045), (0.975, 40, 2.021),
           (0.995, 1, 63.657), (0.995, 4, 4.604), (0.995, 9, 3.250), (0.95, 4, 2.132), (0.9, 9, 1.383)]


@pytest.mark.parametrize("p,df,expected", T_TABLE)
def test_t_quantile_matches_printed_tables(p, df, expected):
    assert protocol.t_quantile(p, df) == pytest.approx(expected, abs=5.01e-4)  # the table's rounding


def test_t_quantile_tends_to_normal():
    assert protocol.t_quantile(0.975, 100000) == pytest.approx(1.95996, abs=1e-4)


def test_mean_ci_by_hand():
    ci = protocol.mean_ci([1.0, 2.0, 3.0])  # s = 1, half width = t(0.975, 2) / sqrt(3)
    assert ci["mean"] == 2.0
    assert ci["high"] - 2.0 == pytest.approx(4.3027 / math.sqrt(3), rel=1e-4)
    single = protocol.mean_ci([5.0])
    assert single["mean"] == 5.0 and math.isnan(single["low"])


def test_protocol_seeds_are_shared_and_distinct():
    seeds = {protocol.reset_seed(s, i) for s in range(5) for i in range(20)}
    assert len(seeds) == 100 and min(seeds) >= protocol.EVAL_SEED_BASE


# ------------------------------------------------------------------------------------------- checkpoints


def test_interrupted_checkpoint_never_becomes_latest(tmp_path, monkeypatch):
    """A failure while writing a checkpoint leaves the previous one as latest, loadable, and no partial folder."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv

    venv = DummyVecEnv([runs.EnvFactory("Pendulum-v1", {})])
    model = PPO("MlpPolicy", venv, n_steps=64, batch_size=32, n_epochs=1, device="cpu")
    model.learn(64)
    first = runs.save_checkpoint(tmp_path, model, None)
    model.learn(64, reset_num_timesteps=False)

    def broken(_model):
        raise OSError("disk full (simulated)")

    from vswrist_gym.agents import checkpoints

    monkeypatch.setattr(checkpoints, "model_bytes", broken)
    with pytest.raises(OSError):
        runs.save_checkpoint(tmp_path, model, None)
    assert runs.latest_checkpoint(tmp_path) == first
    assert [p.name for p in (tmp_path / "checkpoints").iterdir() if p.is_dir()] == [first.name]
    monkeypatch.undo()
    loaded = runs.load_model(first / "model.zip", "ppo")
    assert loaded.num_timesteps == 64
    # a truncated latest.json falls back to the newest complete checkpoint
    (tmp_path / "checkpoints" / "latest.json").write_text('{"step": 12')
    assert runs.latest_checkpoint(tmp_path) == first
    venv.close()


def test_corrupted_model_file_is_a_clear_error(tmp_path):
    bad = tmp_path / "model.zip"
    bad.write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(runs.RunDirError, match="corrupted"):
        runs.load_model(bad, "ppo")
    with pytest.raises(runs.RunDirError, match="not found"):
        runs.load_model(tmp_path / "missing.zip", "sac")


# ------------------------------------------------------------------------------------------- end to end


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory):
    """`vswrist train` with a tiny budget, a batch of 2 worlds and VecNormalize (as in configs/ppo.yaml)."""
    out = tmp_path_factory.mktemp("train") / "ppo_run"
    res = vswrist("train", "--task", TASK, "--algo", "ppo", "--timesteps", "2048", "--seed", "3",
                  "--n-envs", "2", "--out", out)
    assert res.returncode == 0, res.stderr
    return out


def test_train_writes_a_self_describing_run_dir(trained_run):
    for name in ("config.yaml", "run.json", "model.zip", "vecnormalize.npz", "checkpoints/latest.json",
                 "eval/evaluations.npz"):
        assert (trained_run / name).exists(), name
    doc = json.loads((trained_run / "run.json").read_text())
    assert doc["seed"] == 3 and doc["status"] == "finished" and doc["num_timesteps"] >= 2048
    assert set(doc["versions"]) >= {"mujoco", "gymnasium", "stable_baselines3", "torch"}
    assert "--timesteps 2048" in doc["commands"][0]
    cfg = yaml.safe_load((trained_run / "config.yaml").read_text())
    assert cfg["env_id"] == TASK and cfg["hyperparameters"]["n_timesteps"] == 2048
    assert cfg["hyperparameters"]["n_envs"] == 2
    assert cfg["hyperparameters"]["env_kwargs"]["action_mode"] == "residual"  # from configs/ppo.yaml
    assert list((trained_run / "tb").iterdir()), "no TensorBoard log"
    logs = list((trained_run / "monitor").glob("*.monitor.csv"))
    assert len(logs) == 1  # one VecMonitor log for the batch
    episodes = len(logs[0].read_text().splitlines()) - 2  # a JSON header line and the CSV header
    assert episodes >= 2 * (2048 // 2 // 150)  # both worlds' episodes of 150 steps (3 s at 50 Hz)
    with np.load(trained_run / "eval" / "evaluations.npz") as ev:
        assert len(ev["timesteps"]) >= 1


def test_train_with_a_process_per_env_on_request(tmp_path):
    out = tmp_path / "subproc_run"
    res = vswrist("train", "--task", TASK, "--algo", "ppo", "--timesteps", "256", "--n-envs", "2", "--vec-env",
                  "subproc", "--out", out)
    assert res.returncode == 0, res.stderr
    assert len(list((out / "monitor").glob("*.monitor.csv"))) == 2  # one Monitor per SubprocVecEnv worker
    assert yaml.safe_load((out / "config.yaml").read_text())["hyperparameters"]["vec_env"] == "subproc"


def test_evaluate_a_run_dir_later_and_resume(trained_run, tmp_path):
    out = tmp_path / "eval"
    res = vswrist("evaluate", "--task", TASK, "--agent", trained_run, "--episodes", "2", "--seeds", "0", "1",
                  "--out", out)
    assert res.returncode == 0, res.stderr
    doc = json.loads((out / "metrics.json").read_text())
    assert len(doc["episodes"]) == 4 and doc["training_seed"] == 3
    rows = (out / "metrics.csv").read_text().strip().splitlines()
    assert len(rows) == 5 and "return" in rows[0]
    # the same episodes under the same protocol give the same numbers (deterministic policy, seeded resets)
    res2 = vswrist("evaluate", "--task", TASK, "--agent", trained_run, "--episodes", "2", "--seeds", "0", "1",
                   "--out", tmp_path / "eval2")
    assert res2.returncode == 0, res2.stderr
    again = json.loads((tmp_path / "eval2" / "metrics.json").read_text())
    assert [e["return"] for e in again["episodes"]] == [e["return"] for e in doc["episodes"]]
    # per-seed mean and CI recomputed from the CSV rows: an independent path through the numbers
    returns = [float(r.split(",")[4]) for r in rows[1:]]
    per_seed = [np.mean(returns[:2]), np.mean(returns[2:])]
    assert doc["summary"]["return"]["mean"] == pytest.approx(np.mean(per_seed))


def test_video_replays_a_run_dir_as_evaluate_does(trained_run, tmp_path, headless_gl):
    """`vswrist video --agent RUN` drives the run's own action mode (residual) with its own statistics: the same
    return as `vswrist evaluate` on the same reset seed (episode 0 of evaluation seed 0)."""
    import re

    res = vswrist("evaluate", "--task", TASK, "--agent", trained_run, "--episodes", "1", "--seeds", "0",
                  "--out", tmp_path / "ev")
    assert res.returncode == 0, res.stderr
    expected = json.loads((tmp_path / "ev" / "metrics.json").read_text())["episodes"][0]["return"]
    res = vswrist("video", "--task", TASK, "--agent", trained_run / "model.zip", "--seed",
                  protocol.reset_seed(0, 0), "--width", "64", "--height", "48", "--out", tmp_path / "v.mp4")
    assert res.returncode == 0, res.stderr
    assert float(re.search(r"return (-?[\d.]+)", res.stdout)[1]) == pytest.approx(expected, abs=0.006)


def test_resume_continues_from_the_last_checkpoint(trained_run, tmp_path):
    import shutil

    run = tmp_path / "resumed"
    shutil.copytree(trained_run, run)
    res = vswrist("train", "--task", TASK, "--algo", "ppo", "--timesteps", "4096", "--out", run, "--resume",
                  "--no-progress")
    assert res.returncode == 0, res.stderr
    doc = json.loads((run / "run.json").read_text())
    assert doc["num_timesteps"] >= 4096 and len(doc["commands"]) == 2 and doc["seed"] == 3
    with np.load(run / "eval" / "evaluations.npz") as ev:
        assert ev["timesteps"][0] <= 2048 < ev["timesteps"][-1]  # history kept across the resume


def test_ctrl_c_leaves_a_complete_checkpoint_that_resumes(tmp_path):
    """Ctrl-C (SIGINT to the whole process group, workers included) saves a checkpoint; --resume continues it."""
    import signal
    import time

    out = tmp_path / "run"
    env = {**os.environ, "PYTHONWARNINGS": "ignore::DeprecationWarning"}
    proc = subprocess.Popen([sys.executable, "-m", "vswrist_gym.cli", "train", "--task", TASK, "--algo", "ppo",
                             "--timesteps", "1000000", "--out", str(out), "--no-progress"], start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        deadline = time.time() + 120
        while time.time() < deadline:  # wait until the workers have finished a few episodes
            logs = list((out / "monitor").glob("*.csv")) if (out / "monitor").is_dir() else []
            if logs and sum(f.read_text().count("\n") for f in logs) > 8:
                break
            time.sleep(0.3)
        os.killpg(proc.pid, signal.SIGINT)
        output, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, output
    doc = json.loads((out / "run.json").read_text())
    assert doc["status"] == "interrupted" and "Traceback" not in output
    latest = runs.latest_checkpoint(out)
    assert latest is not None and runs.load_model(latest / "model.zip", "ppo").num_timesteps == doc["num_timesteps"]
    assert not list((out / "checkpoints").glob(".tmp_*"))
    res = vswrist("train", "--task", TASK, "--algo", "ppo", "--timesteps", str(doc["num_timesteps"] + 1024),
                  "--out", out, "--resume", "--no-progress")
    assert res.returncode == 0, res.stderr
    assert json.loads((out / "run.json").read_text())["status"] == "finished"


def test_missing_or_corrupted_model_gives_a_clear_error(trained_run, tmp_path):
    import shutil

    run = tmp_path / "broken"
    shutil.copytree(trained_run, run)
    (run / "model.zip").write_bytes(b"\x00" * 100)
    res = vswrist("evaluate", "--task", TASK, "--agent", run, "--episodes", "1", "--seeds", "0",
                  "--out", tmp_path / "e")
    assert res.returncode == 2 and "corrupted" in res.stderr and "Traceback" not in res.stderr
    (run / "model.zip").unlink()
    res = vswrist("evaluate", "--task", TASK, "--agent", run, "--episodes", "1", "--seeds", "0",
                  "--out", tmp_path / "e")
    assert res.returncode == 2 and "not found" in res.stderr and "Traceback" not in res.stderr
    res = vswrist("evaluate", "--task", TASK, "--agent", tmp_path / "nowhere", "--episodes", "1",
                  "--out", tmp_path / "e")
    assert res.returncode == 2 and "not found" in res.stderr and "Traceback" not in res.stderr
    res = vswrist("train", "--task", TASK, "--algo", "ppo", "--out", trained_run)
    assert res.returncode == 2 and "--resume" in res.stderr


def test_bad_agent_specs_give_clear_errors(tmp_path):
    res = vswrist("evaluate", "--task", TASK, "--agent", "analytic:2", "--episodes", "1", "--out", tmp_path / "e")
    assert res.returncode == 2 and "[-1, 1]" in res.stderr and "Traceback" not in res.stderr
    res = vswrist("evaluate", "--task", "NoSuchTask", "--agent", "analytic", "--episodes", "1", "--out", tmp_path / "e")
    assert res.returncode == 2 and "VSWrist/LoadHold-v0" in res.stderr and "Traceback" not in res.stderr


def test_bad_env_kwargs_are_a_clear_error_before_anything_is_written(tmp_path):
    cfg = tmp_path / "ppo.yaml"
    cfg.write_text(yaml.safe_dump({TASK: {"n_timesteps": 100, "n_envs": 2, "env_kwargs": {"action_mode": "wobble"}}}))
    res = vswrist("train", "--task", TASK, "--algo", "ppo", "--config", cfg, "--out", tmp_path / "run")
    assert res.returncode == 2 and "action_mode" in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "run").exists()


def test_evaluate_writes_a_video(tmp_path, headless_gl):
    video = tmp_path / "episode.mp4"
    res = vswrist("evaluate", "--task", TASK, "--agent", "analytic:0", "--episodes", "1", "--seeds", "0",
                  "--out", tmp_path / "e", "--video", video)
    assert res.returncode == 0, res.stderr
    import imageio

    length = json.loads((tmp_path / "e" / "metrics.json").read_text())["episodes"][0]["length"]
    reader = imageio.get_reader(video)
    try:
        assert reader.count_frames() == length + 1  # the reset frame and one per step
        assert reader.get_meta_data()["fps"] == pytest.approx(50.0)  # the default 50 Hz control rate
    finally:
        reader.close()


def test_compare_end_to_end(tmp_path):
    args = ["compare", "--task", TASK, "--seeds", "0", "1", "--episodes", "1", "--ppo-timesteps", "512",
            "--sac-timesteps", "200", "--stiffness", "-1", "1", "--out", tmp_path / "cmp", "--no-progress",
            "--n-envs", "1"]
    res = vswrist(*args)
    assert res.returncode == 0, res.stderr
    assert "95 %" in res.stdout and "| PPO |" in res.stdout and "| SAC |" in res.stdout
    for name in ("table.md", "summary.json", "learning_curves.png", "traces.png"):
        assert (tmp_path / "cmp" / name).stat().st_size > 0, name
    summary = json.loads((tmp_path / "cmp" / "summary.json").read_text())
    assert summary["rows"]["PPO"]["return"]["n"] == 2
    assert set(summary["rows"]) == {"PPO", "SAC", "analytic:-1.00", "analytic:+1.00"}
    assert summary["verdicts"]["best_baseline"] in ("analytic:-1.00", "analytic:+1.00")
    # the analytic rows are the same episodes as `vswrist evaluate --agent analytic:1` (one protocol)
    res = vswrist("evaluate", "--task", TASK, "--agent", "analytic:1", "--episodes", "1", "--seeds", "0", "1",
                  "--out", tmp_path / "ev")
    assert res.returncode == 0, res.stderr
    ev = json.loads((tmp_path / "ev" / "metrics.json").read_text())
    assert ev["summary"]["return"]["mean"] == pytest.approx(summary["rows"]["analytic:+1.00"]["return"]["mean"])
    # a second call loads the trained runs instead of training again, and trains only the new seed (in process)
    seeds_at = args.index("--seeds")
    args[seeds_at + 1:seeds_at + 3] = ["0", "1", "2"]
    res = vswrist(*args, "--jobs", "1")
    assert res.returncode == 0, res.stderr
    assert res.stderr.count("loaded") == 4 and "ppo seed 2] train" in res.stderr  # what it did: diagnostics
    summary = json.loads((tmp_path / "cmp" / "summary.json").read_text())
    assert summary["rows"]["PPO"]["return"]["n"] == 3 and summary["rows"]["SAC"]["return"]["n"] == 3


# ------------------------------------------------------------------------------------------- tracks


def _track_rollout(env_id: str, track: str, posture_action: float) -> np.ndarray:
    import gymnasium as gym

    cfg = hparams.with_track(hparams.load_config("ppo", env_id), track)
    env = gym.make(env_id, **cfg.env_kwargs)
    env.reset(seed=5)
    out = []
    for _ in range(15):
        a = np.array([posture_action] * 3 + [0.3], dtype=np.float32)
        _, _, _, _, info = env.step(a)
        # the wrist's state (the observation also echoes the action itself, prev_action)
        out.append([*env.unwrapped.sim.posture(), info["lam"], info["contact_force"], info["elastic_energy"]])
    env.close()
    return np.array(out)


@pytest.mark.parametrize("env_id", ["VSWrist/Polish-v1", "VSWrist/LoadHold-v0"])
def test_stiffness_track_ignores_the_posture_outputs(env_id):
    """On the stiffness track the posture reference is the task's: policies that differ only in their posture
    outputs give the same episode; on the full track they do not."""
    a, b = _track_rollout(env_id, "stiffness", -0.8), _track_rollout(env_id, "stiffness", 0.8)
    np.testing.assert_array_equal(a, b)
    a, b = _track_rollout(env_id, "full", -0.8), _track_rollout(env_id, "full", 0.8)
    assert np.abs(a - b).max() > 1e-3


def test_track_of_entries_and_bad_tracks():
    assert hparams.track_of(hparams.load_config("ppo", "VSWrist/Polish-v1").env_kwargs) == "full"
    assert hparams.track_of(hparams.load_config("ppo", "VSWrist/Hammer-v0").env_kwargs) == "stiffness"
    assert hparams.track_of({"action_mode": "posture_stiffness"}) == "custom"
    with pytest.raises(hparams.ConfigError, match="posture_scale"):  # a stiffness-only entry has no full track
        hparams.with_track(hparams.load_config("ppo", "VSWrist/Hammer-v0"), "full")
    with pytest.raises(hparams.ConfigError, match="track must be one of"):
        hparams.with_track(hparams.load_config("ppo", "VSWrist/Polish-v1"), "posture")


def test_train_on_the_stiffness_track_and_refuse_a_mixed_resume(tmp_path):
    out = tmp_path / "stiff_run"
    res = vswrist("train", "--task", TASK, "--algo", "ppo", "--timesteps", "256", "--n-envs", "2", "--track",
                  "stiffness", "--out", out)
    assert res.returncode == 0, res.stderr
    kwargs = yaml.safe_load((out / "config.yaml").read_text())["hyperparameters"]["env_kwargs"]
    assert hparams.track_of(kwargs) == "stiffness"
    res = vswrist("train", "--task", TASK, "--algo", "ppo", "--timesteps", "512", "--track", "full", "--resume",
                  "--out", out)
    assert res.returncode == 2 and "stiffness-track run, not full" in res.stderr
    assert res.stderr.strip().count("\n") == 0


@pytest.mark.parametrize("env_id, middle", [("VSWrist/Throw-v0", "reward"), ("VSWrist/Polish-v1", "contact_force")])
def test_traces_show_the_contact_force_only_where_the_task_has_contact(env_id, middle):
    """`traces.png`'s middle panel: the contact force where an episode touches something (Polish presses its tool
    on a surface), the step reward where the force is 0 throughout (Throw has nothing to touch)."""
    import gymnasium as gym

    from vswrist_gym.agents.compare import trace_signals

    env = gym.make(env_id, action_mode="residual")  # a zero action: the analytic baseline at the task's constant
    env.reset(seed=0)
    forces, rewards = [], []
    for _ in range(env.unwrapped.episode_steps):
        _, r, term, trunc, info = env.step(np.zeros(env.action_space.shape, dtype=np.float32))
        forces.append(float(info["contact_force"]))
        rewards.append(float(r))
        if term or trunc:
            break
    env.close()
    assert (max(forces) > 0.0) == (middle == "contact_force")
    trace = {"time": list(range(len(forces))), "posture_error": forces, "contact_force": forces, "lam": forces,
             "reward": rewards}
    keys = [key for key, _ in trace_signals({"agent": trace, "absent": None})]
    assert keys == ["posture_error", middle, "lam"]

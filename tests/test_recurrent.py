"""Recurrent PPO (`--algo ppo_lstm`, sb3-contrib's RecurrentPPO): trained, resumed and evaluated as PPO is, with the
LSTM state carried from step to step and reset at every episode's start."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest

import vswrist_gym  # noqa: F401
from vswrist_gym.agents import hparams, protocol
from vswrist_gym.agents.evaluate import AgentSpec

TASK = "VSWrist/LoadHold-v0"


def vswrist(*args, timeout=300) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONWARNINGS": "ignore::DeprecationWarning"}
    return subprocess.run([sys.executable, "-m", "vswrist_gym.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env=env)


@pytest.fixture(scope="module")
def lstm_run(tmp_path_factory):
    """`vswrist train --algo ppo_lstm` with a tiny budget: 2 worlds x 64 steps per rollout, 4 rollouts."""
    out = tmp_path_factory.mktemp("lstm") / "run"
    res = vswrist("train", "--task", TASK, "--algo", "ppo_lstm", "--timesteps", "512", "--seed", "2",
                  "--n-envs", "2", "--out", out, "--no-progress")
    assert res.returncode == 0, res.stderr
    return out


def _agent(run, env):
    return AgentSpec(str(run)).make(env)


def test_the_run_is_a_recurrent_policy_and_evaluates_deterministically(lstm_run, tmp_path):
    from sb3_contrib import RecurrentPPO

    env = gym.make(TASK, **AgentSpec(str(lstm_run)).env_kwargs)
    agent = _agent(lstm_run, env)
    assert isinstance(agent.model, RecurrentPPO)
    assert agent.model.policy.lstm_actor.hidden_size == 64  # configs/ppo_lstm.yaml's lstm_hidden_size
    env.close()
    doc = json.loads((lstm_run / "run.json").read_text())
    assert doc["status"] == "finished" and doc["num_timesteps"] >= 512
    outs = []
    for name in ("a", "b"):
        res = vswrist("evaluate", "--task", TASK, "--agent", lstm_run, "--episodes", "2", "--seeds", "0",
                      "--out", tmp_path / name)
        assert res.returncode == 0, res.stderr
        outs.append([e["return"] for e in json.loads((tmp_path / name / "metrics.json").read_text())["episodes"]])
    assert outs[0] == outs[1] and len(outs[0]) == 2


def test_evaluation_carries_the_state_within_an_episode(lstm_run):
    """The protocol's return equals a hand-written loop that carries the LSTM state and differs from one that drops
    it every step: the memory is used, and used as in training (state reset only at the episode's start)."""
    env = gym.make(TASK, **AgentSpec(str(lstm_run)).env_kwargs)
    agent = _agent(lstm_run, env)
    seed = protocol.reset_seed(0, 0)
    record, _ = protocol.run_episode(env, agent, seed)

    def by_hand(carry: bool) -> float:
        obs, _ = env.reset(seed=seed)
        state, start, total, done = None, np.ones(1, dtype=bool), 0.0, False
        while not done:
            action, new_state = agent.predict(obs, state=state if carry else None, episode_start=start,
                                              deterministic=True)
            state, start = new_state, np.zeros(1, dtype=bool)
            obs, r, term, trunc, _ = env.step(action)
            total += r
            done = term or trunc
        return total

    assert record["return"] == pytest.approx(by_hand(carry=True), rel=1e-12, abs=1e-9)
    assert abs(by_hand(carry=False) - record["return"]) > 1e-6
    # `vswrist video` drives the agent through video.stateful_policy: the protocol's episode too
    from vswrist_gym.tools.video import stateful_policy

    policy = stateful_policy(agent)
    obs, _ = env.reset(seed=seed)
    total, done = 0.0, False
    while not done:
        obs, r, term, trunc, _ = env.step(policy(obs))
        total, done = total + r, term or trunc
    assert total == pytest.approx(record["return"], rel=1e-12, abs=1e-9)
    env.close()


def test_episode_starts_are_flagged_exactly_at_each_first_step():
    """Both evaluation paths (episode after episode, and a seed's episodes as one batch) tell the agent that an
    episode starts on its first step and on no other, for every world of a batch."""

    class Spy:
        def __init__(self, env):
            self.calls = []
            self.act = np.zeros(env.action_space.shape[-1], dtype=np.float32)

        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            self.calls.append(np.asarray(episode_start, dtype=bool).copy())
            n = 1 if obs.ndim == 1 else obs.shape[0]
            return (self.act if obs.ndim == 1 else np.tile(self.act, (n, 1))), ("state", len(self.calls))

    env = gym.make(TASK, config={"episode_s": 0.2})
    steps = env.unwrapped.episode_steps
    spy = Spy(env)
    for k in range(2):
        protocol.run_episode(env, spy, protocol.reset_seed(0, k))
    flags = np.array([c[0] for c in spy.calls])
    assert len(flags) == 2 * steps and flags.sum() == 2 and flags[0] and flags[steps]
    venv = gym.make_vec(TASK, num_envs=3, vectorization_mode="vector_entry_point", config={"episode_s": 0.2})
    spy = Spy(env)
    protocol.run_episodes_batched(venv, spy, protocol.reset_seed(0, 0))
    flags = np.array(spy.calls)
    assert flags.shape == (steps, 3) and flags[0].all() and not flags[1:].any()
    venv.close()
    env.close()


def test_resume_continues_the_recurrent_run(lstm_run, tmp_path):
    """--resume loads the RecurrentPPO checkpoint and trains on to the new budget, in the same run record."""
    import shutil

    shutil.copytree(lstm_run, tmp_path / "r")
    res = vswrist("train", "--task", TASK, "--algo", "ppo_lstm", "--timesteps", "768", "--out", tmp_path / "r",
                  "--resume", "--no-progress")
    doc = json.loads((tmp_path / "r" / "run.json").read_text()) if res.returncode == 0 else {}
    assert (doc.get("num_timesteps", 0) >= 768, len(doc.get("commands", [])), doc.get("seed")) == (True, 2, 2), \
        res.stderr
    # the second invocation starts where the first ended, not from step 0 (a restart would also reach 768)
    first = json.loads((lstm_run / "run.json").read_text())["num_timesteps"]
    assert 0 < first < 768 and doc["start_step"] == first


def test_a_batch_of_worlds_keeps_one_state_per_world(lstm_run):
    """The batched evaluation (the episodes of a seed as the worlds of one batch, one LSTM state per row) gives
    the returns of the same episodes run one after another with a single state each."""
    spec = AgentSpec(str(lstm_run))
    records = {batch: protocol.evaluate(TASK, spec.make, [0], 3, env_kwargs=spec.env_kwargs, batch=batch)[0]
               for batch in (True, False)}
    returns = {batch: [r["return"] for r in recs] for batch, recs in records.items()}
    assert len(set(returns[False])) == 3  # three different episodes, so a mixed-up row would show
    assert returns[True] == pytest.approx(returns[False], rel=1e-6, abs=1e-6)


def test_compare_trains_and_tables_the_recurrent_agent(tmp_path):
    """`vswrist compare --algos ppo_lstm` trains it (its own budget flag), evaluates it on the baseline's episodes
    and puts it in the table."""
    res = vswrist("compare", "--task", TASK, "--algos", "ppo_lstm", "--seeds", "0", "--episodes", "1",
                  "--ppo-lstm-timesteps", "256", "--n-envs", "2", "--stiffness", "1", "--jobs", "1",
                  "--out", tmp_path / "cmp", "--no-progress")
    assert res.returncode == 0, res.stderr
    summary = json.loads((tmp_path / "cmp" / "summary.json").read_text())
    assert set(summary["rows"]) == {"PPO_LSTM", "analytic:+1.00"} and summary["rows"]["PPO_LSTM"]["return"]["n"] == 1
    run = json.loads((tmp_path / "cmp" / "runs" / "ppo_lstm_seed0" / "run.json").read_text())
    assert run["num_timesteps"] >= 256 and "| PPO_LSTM |" in res.stdout


def test_algorithm_and_policy_errors_name_the_allowed_values():
    with pytest.raises(hparams.ConfigError, match="ppo_lstm"):
        hparams.algo_class("lstm")
    with pytest.raises(hparams.ConfigError, match="MlpLstmPolicy"):
        hparams.resolve_entry("ppo_lstm", TASK, {"n_timesteps": 100, "policy": "MlpPolicy"})
    with pytest.raises(hparams.ConfigError, match="'MlpPolicy'"):
        hparams.resolve_entry("ppo", TASK, {"n_timesteps": 100, "policy": "MlpLstmPolicy"})
    res = vswrist("compare", "--task", "LoadHold", "--algos", "lstm")
    assert res.returncode == 2 and "ppo_lstm" in res.stderr and "Traceback" not in res.stderr
